"""Diagnosis of one recording: locate the mismatch, name the missing physics, fit it.

Decision rule
-------------
Every candidate effect the recording's signals can test is fitted and
scored on held-out data (:mod:`.fit`).  With S_e the held-out
log-likelihood ratio of effect e against the null:

1. *detected*: S_e ≥ :data:`DETECT_LLR` and the 95 % interval of at least
   one parameter lies outside the negligible band around the value at which
   the effect vanishes (:mod:`.candidates`);
2. no detection → verdict ``none``, unless an effect whose driver is
   observed (the GNSS altitude shows a material grade) cannot be separated
   from the nominal model's free constants in this recording → verdict
   ``ambiguous`` between that effect and a constant resistance;
3. the best detected effect wins unless another detected one scores within
   max(:data:`DETECT_LLR`, :data:`AMBIGUOUS_FRACTION` · S_best) of it →
   ``ambiguous`` between the two.

Diagnosis reads only what a real logger records (never ``truth.*``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config import G, VehicleParams
from ..model.effects import EFFECTS
from ..recording.reader import Recording
from . import data as _data
from .candidates import CANDIDATES
from .channels import Channel, build_channels
from .features import Features, compute
from .fit import FitResult, HeldOut, Problem, fit, held_out, score
from .locate import ChangePoint, Regime, change_points, channel_stats, evidence, ljung_box_p, nis_coverage, noise_sigma, regimes

DETECT_LLR = 10.0
"""Held-out log-likelihood ratio an effect needs to count as detected (a likelihood ratio of e^10)."""
AMBIGUOUS_FRACTION = 0.2
"""Two detected effects whose scores differ by less than this share of the best are ambiguous."""
GRADE_MATERIAL_N = 300.0
"""RMS grade force [N] above which an observed grade matters (≈ 0.5 % grade at 6.3 t)."""
GRADE_SEPARABLE_Z = 4.0
"""A grade counts as separable when scale 1 and scale 0 differ by this many standard errors."""
ALT_ERROR_M = 1.0
"""Assumed GNSS vertical error [m] when no second pass can calibrate it (DGPS class)."""


@dataclass
class CandidateResult:
    name: str
    testable: bool
    reason: str = ""
    score: float = math.nan
    per_channel: dict[str, float] = field(default_factory=dict)
    fit: FitResult | None = None
    heldout: HeldOut | None = None
    detected: bool = False


@dataclass
class Diagnosis:
    source: str
    verdict: str
    effect: str | None
    ambiguous_between: list[str]
    statement: str
    candidates: list[CandidateResult]
    problem: Problem
    null_heldout: HeldOut
    stats_before: dict[str, dict]
    stats_after: dict[str, dict]
    change_points: list[ChangePoint]
    lead_channel: str | None
    regimes: list[Regime]
    evidence: dict[str, float]
    grade_check: dict
    notes: list[str]

    @property
    def features(self) -> Features:
        return self.problem.feat

    def candidate(self, name: str) -> CandidateResult | None:
        for c in self.candidates:
            if c.name == name:
                return c
        return None

    @property
    def winner(self) -> CandidateResult | None:
        if self.effect is None:
            return None
        return self.candidate(self.effect)


def _testability(problem: Problem, feat: Features) -> dict[str, str]:
    """Reason each candidate cannot be tested (missing signals), or '' when it can."""
    fr = feat.frame
    out = {}
    for name, cand in CANDIDATES.items():
        chans = problem.acting(cand)
        reason = ""
        if not chans:
            reason = "no signal in this recording carries its signature"
        elif name == "grade" and feat.theta is None:
            reason = (feat.grade.method if feat.grade is not None
                      else "no GNSS altitude/position: the slope along the track is unknown")
        elif name == "draft_speed" and "draft" not in problem.channels:
            reason = "no draft signal in work"
        elif name == "load_transfer" and (fr.fdx is None or "front_load" not in problem.channels):
            reason = "needs the front-axle load and the draft"
        elif name == "relaxation" and fr.rate_hz < 5.0:
            reason = f"sample rate {fr.rate_hz:.1f} Hz is too low for a lag of a few tenths of a second"
        elif name == "gps_latency" and fr.rate_hz < 5.0:
            reason = f"sample rate {fr.rate_hz:.1f} Hz is too low to resolve a GNSS latency"
        out[name] = reason
    return out


def _excludes_null(fr: FitResult) -> bool:
    cand = CANDIDATES[fr.candidate]
    for p in cand.fitted:
        lo, hi = fr.ci95.get(p.name, (math.nan, math.nan))
        if not (math.isfinite(lo) and math.isfinite(hi)):
            continue
        if p.name == "front_share":
            continue  # meaningful only through delta_kg
        if lo > p.null + p.negligible or hi < p.null - p.negligible:
            return True
    return False


def _grade_check(problem: Problem, feat: Features, res: CandidateResult | None) -> dict:
    """Is an observed grade material, and can this recording separate it from a constant resistance?"""
    out: dict = {"material": False, "separable": True}
    if res is None or not res.testable or feat.theta is None or "speed" not in problem.channels:
        return out
    ch = problem.channels["speed"]
    m = feat.frame.vehicle.mass_kg
    th = np.nan_to_num(feat.theta)
    fg = G * m * np.sin(th[ch.tidx])
    rms = float(np.sqrt(np.mean(fg * fg)))
    lam = feat.grade.reliability if feat.grade is not None else math.nan
    # Relief along the track versus the altitude error.
    relief = math.nan
    if feat.frame.alt is not None:
        alt = feat.frame.alt[feat.valid & np.isfinite(feat.frame.alt)]
        if alt.size > 10:
            lo, hi = np.percentile(alt, [5, 95])
            relief = float(hi - lo)
    if math.isfinite(lam):
        real = lam >= 0.5
    else:
        real = math.isfinite(relief) and relief >= 4.0 * ALT_ERROR_M
    material = bool(real and rms >= GRADE_MATERIAL_N)
    # Separable: the grade regressor keeps variance after the cell constants are removed, and the
    # fit tells scale 1 from scale 0.
    cells = ch.cell
    xm = np.bincount(cells, weights=fg, minlength=ch.ncell) / np.maximum(np.bincount(cells, minlength=ch.ncell), 1)
    perp = fg - xm[cells]
    share = float(np.sqrt(np.mean(perp * perp)) / rms) if rms > 0 else 0.0
    se = res.fit.se.get("scale", math.inf) if res.fit is not None else math.inf
    z = 1.0 / se if se and math.isfinite(se) and se > 0 else 0.0
    separable = bool(share >= 0.3 and z >= GRADE_SEPARABLE_Z)
    out.update({"material": material, "separable": separable, "rms_force_n": rms, "relief_m": relief,
                "reliability": lam, "share_beyond_constants": share, "z_scale": z,
                "method": feat.grade.method if feat.grade is not None else ""})
    return out


def diagnose(source: str | Path | Recording | _data.Frame, vehicle: VehicleParams | str | Path | None = None) -> Diagnosis:
    """Run the whole diagnosis on a recording (directory, Recording or prepared Frame)."""
    fr = source if isinstance(source, _data.Frame) else _data.load(source, vehicle)
    feat = compute(fr)
    channels = build_channels(feat)
    problem = Problem(feat, channels)
    notes = list(fr.notes) + list(feat.notes)
    testable = _testability(problem, feat)
    null = held_out(problem, None)

    results: list[CandidateResult] = []
    for name in CANDIDATES:
        if testable[name]:
            results.append(CandidateResult(name, False, testable[name]))
            continue
        ho = held_out(problem, name)
        sc, per = score(problem, null, ho)
        f = fit(problem, name)
        cr = CandidateResult(name, True, "", sc, per, f, ho)
        cr.detected = bool(sc >= DETECT_LLR and f.ok is not None and _excludes_null(f))
        results.append(cr)
    results.sort(key=lambda r: (not r.testable, -(r.score if math.isfinite(r.score) else -1e18)))

    detected = [r for r in results if r.detected]
    grade_res = next((r for r in results if r.name == "grade"), None)
    gcheck = _grade_check(problem, feat, grade_res)
    ambiguous: list[str] = []
    if not detected:
        if gcheck.get("material") and not gcheck.get("separable"):
            verdict, effect = "ambiguous", None
            ambiguous = ["grade", "constant resistance (soil rolling resistance ρ_s or a constant draft)"]
        else:
            verdict, effect = "none", None
    else:
        best = detected[0]
        margin = max(DETECT_LLR, AMBIGUOUS_FRACTION * best.score)
        close = [r for r in detected[1:] if best.score - r.score < margin]
        if close:
            verdict, effect = "ambiguous", None
            ambiguous = [best.name] + [r.name for r in close]
        else:
            verdict, effect = "effect", best.name

    # Locate: the channel that disagrees most (the winner's strongest channel, else the worst by LB).
    lead = None
    focus = detected[0] if detected else None
    if focus is not None and focus.per_channel:
        lead = max(focus.per_channel, key=lambda c: focus.per_channel[c])
    elif problem.channels:
        lead = min(problem.channels, key=lambda c: ljung_box_p(null.resid[c]) if np.isfinite(null.resid[c]).any() else 1.0)
    stats_before, stats_after = _signal_stats(problem, null, (focus.heldout if focus else None))
    cps: list[ChangePoint] = []
    regs: list[Regime] = []
    ev: dict[str, float] = {}
    if lead is not None:
        ch = problem.channels[lead]
        rb = null.resid[lead]
        ra = focus.heldout.resid[lead] if focus is not None and focus.heldout is not None else None
        cps = change_points(feat, ch, rb)
        regs = regimes(feat, ch, rb, ra)
        ev = evidence(feat, ch, rb)
    statement = _statement(verdict, effect, ambiguous, results, lead, ev, problem, gcheck)
    return Diagnosis(fr.source, verdict, effect, ambiguous, statement, results, problem, null, stats_before,
                     stats_after, cps, lead, regs, ev, gcheck, notes)


def _signal_stats(problem: Problem, null: HeldOut, cand: HeldOut | None) -> tuple[dict, dict]:
    before, after = {}, {}
    for c, ch in problem.channels.items():
        rb = null.resid[c]
        sb = channel_stats(rb)
        sst = _sst(problem, ch)
        sigma = noise_sigma(ch, rb)
        before[c] = {"rmse": sb.rmse, "ljung_box_p": sb.ljung_box_p, "n": sb.n,
                     "nis_coverage_95": nis_coverage(ch, rb, sigma), "noise_sigma": sigma,
                     "r2": 1.0 - (sb.rmse ** 2 * sb.n) / sst if sst > 0 else math.nan, "unit": ch.unit,
                     "signal": ch.signal}
        ra = cand.resid[c] if cand is not None else rb
        sa = channel_stats(ra)
        after[c] = {"rmse": sa.rmse, "ljung_box_p": sa.ljung_box_p, "n": sa.n,
                    "nis_coverage_95": nis_coverage(ch, ra, sigma), "noise_sigma": sigma,
                    "r2": 1.0 - (sa.rmse ** 2 * sa.n) / sst if sst > 0 else math.nan, "unit": ch.unit,
                    "signal": ch.signal}
    return before, after


def _sst(problem: Problem, ch: Channel) -> float:
    tot = 0.0
    for fold in (0, 1):
        rows = ch.fold == fold
        if not rows.any():
            continue
        y, _ = ch.parts({}, rows)
        tot += float(np.sum((y - y.mean()) ** 2))
    return tot


def _fmt(v: float) -> str:
    return f"{v:.3g}"


def _statement(verdict, effect, ambiguous, results, lead, ev, problem, gcheck) -> str:
    if verdict == "none":
        best = next((r for r in results if r.testable), None)
        extra = f" (best candidate {best.name}, held-out score {best.score:.1f} < {DETECT_LLR:.0f})" if best else ""
        return "No significant mismatch: no effect from the library improves the held-out fit" + extra + "."
    if verdict == "ambiguous":
        if ambiguous and ambiguous[0] == "grade" and len(ambiguous) == 2 and "constant" in ambiguous[1]:
            return ("Ambiguous between grade and a constant resistance: the GNSS altitude shows a material slope "
                    f"(grade force ≈ {gcheck.get('rms_force_n', math.nan):.0f} N RMS), but in this recording it "
                    "does not vary within the field cells nor flip with pass direction, so m g sin θ, soil "
                    "rolling resistance ρ_s and a constant draft are the same force.  Drive the slope in both "
                    "directions or over changing grade to separate them.")
        return "Ambiguous between " + " and ".join(ambiguous) + ": their held-out scores are within the margin."
    r = next(x for x in results if x.name == effect)
    cand = CANDIDATES[effect]
    ps = ", ".join(f"{k} = {_fmt(r.fit.params[k])} [{_fmt(r.fit.ci95[k][0])}, {_fmt(r.fit.ci95[k][1])}]"
                   for k in r.fit.ci95)
    sig = ", ".join(f"{k} r = {v:+.2f}" for k, v in sorted(ev.items(), key=lambda kv: -abs(kv[1]))[:3])
    where = f"the {lead} residual" if lead else "the residual"
    return (f"{cand.plain}: {EFFECTS[effect].formula}.  Evidence: {where} ({problem.channels[lead].signal}) "
            f"correlates with {sig}; held-out score {r.score:.1f}.  Fitted {ps}.")
