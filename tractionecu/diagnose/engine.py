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
from ..model.effects import (EFFECTS, LIBRARY, SENSOR_FAULTS, TYRE_CARCASS_SHARE_RANGE, TYRE_DEFLECTION_RATIO_RANGE,
                             tyre_pressure_terms)
from ..recording.reader import Recording
from . import data as _data
from .candidates import CANDIDATES, NOMINAL
from .channels import DRAFT_SPEED_SMOOTH_S, MU0_NOMINAL, Channel, build_channels
from .features import Features, compute
from .fit import FitResult, HeldOut, Problem, fit, held_out, refine_intervals, restrict, score
from .lifted import lifted_draft_channel, shape_check
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
MAX_EFFECTS = 4
"""Most effects the forward stepwise augmentation adds to the nominal model."""
TRADE_OFF_CORR = 0.8
"""Two fitted parameters of different effects whose estimates correlate beyond this trade off (ambiguous pair)."""
CHARACTERISTIC = {"relaxation": ("sigma_m", 0.05, 3.0), "drivetrain": ("eta", 0.80, 1.0)}
"""Effects every machine has, with the range of a healthy one: tyre relaxation lengths of
agricultural tyres (about 0.3–2 m, a fraction to a few rolling radii) and drivetrain efficiencies
(0.8–0.95 mechanical transmissions, 0.9–0.97 hub drives).  Found at such a size they are reported as
characteristics of the machine (like the load transfer of the nominal model), not as faults."""
RELEVANT_F2 = 0.15
"""Smallest share of a signal's held-out mismatch a fault must explain to be named: Cohen's f² =
SSE_null/SSE_effect − 1 on at least one channel (0.15 is Cohen's 1988 "medium" effect, a held-out RMSE
reduction of 7 %).  The held-out score S grows with the recording's length for a fixed f² (S ≈ ½ n_eff
ln(1 + f²)), so on a long recording a term that takes up a sliver of a mismatch of the nominal model
passes :data:`DETECT_LLR`: on an hour of healthy ``paper-three-soils`` runs a rear mass of +466 kg
scored 24 with f² = 0.013 on the speed equation (231 → 229 N held out), riding on the slip coefficient k_s of the
motion resistance, which takes up the soil steps inside the 40-m field cells of ρ_s."""
GENERALISES = {"tyre_pressure": "wheel_radius"}
"""Effect → the simpler effect whose term it contains (and explains as one of its causes)."""
POOL = 6
"""Candidates tried at each step of the augmentation (the best by their single-step score)."""
POOL_MIN_SCORE = 1.0
"""... among those whose single-step held-out score exceeds this."""
WHITE_P = 0.05
"""A channel's residual counts as noise when its Ljung–Box p-value exceeds this ..."""
WHITE_NIS = 0.9
"""... and its NIS coverage of the χ²(1) 95 % bound reaches this."""


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
    effects: list[dict] = field(default_factory=list)
    """Every named effect (stepwise, then fitted jointly), nominal terms and detected sensor faults."""
    joint: FitResult | None = None
    joint_heldout: HeldOut | None = None
    steps: list[dict] = field(default_factory=list)
    """The stepwise augmentation: per step the best addition, its score and why it stopped."""
    open_world: dict = field(default_factory=dict)

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


OFFSET_REVERSE_MIN_S = 10.0
"""Reversing [s] on each axle, in the slip channel's rows, that makes a drive-torque offset testable.  Forwards
the offset is the tyre's zero-slip traction ratio μ_0 and a constant resistance; in reverse μ_0 and the motion
resistance turn with the travel and the offset keeps its sign.  Ten seconds is one headland's reverse (8–12 m
at 0.8–1.2 m/s); the figure was set before any recording was diagnosed with it."""


def _reverse_seconds(problem: Problem) -> float:
    """Seconds of reversing in the slip channel's rows, the fewer of the two axles' (0 without the channel)."""
    ch = problem.channels.get("slip")
    sg = getattr(ch, "sg", None)
    rate = problem.feat.frame.rate_hz
    if sg is None or not rate > 0.0:
        return 0.0
    rev = sg < 0.0
    rear = ch.wi >= 2
    return float(min(np.count_nonzero(rev & ~rear), np.count_nonzero(rev & rear))) / (2.0 * rate)


MIN_DRIVING_S = 4.0 * DRAFT_SPEED_SMOOTH_S
"""Driving [s] (moving rows with the force balance's signals) below which no effect is tested: the held-out
test needs four time blocks (:func:`.features.held_out_folds`), each no shorter than the longest window a
channel averages over (the draft's speed regressor, :data:`.channels.DRAFT_SPEED_SMOOTH_S`), or one fold's
rows carry the other's data.  A 3-s start from rest named an axle-load offset before this rule."""


def _testability(problem: Problem, feat: Features) -> dict[str, str]:
    """Reason each candidate cannot be tested (missing signals, too little driving), or '' when it can."""
    fr = feat.frame
    out = {}
    reverse_s = _reverse_seconds(problem)
    driving_s = float(np.count_nonzero(feat.valid)) / fr.rate_hz if fr.rate_hz > 0 else 0.0
    for name, cand in CANDIDATES.items():
        chans = problem.acting(cand)
        reason = ""
        if driving_s < MIN_DRIVING_S:
            reason = (f"the recording holds {driving_s:.1f} s of driving; a held-out test needs at least "
                      f"{MIN_DRIVING_S:.0f} s (four blocks no shorter than the {DRAFT_SPEED_SMOOTH_S:.0f}-s "
                      "window the draft's speed is averaged over)")
        elif not chans:
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
        elif name in NOMINAL:
            reason = ("part of the nominal model: every tractor pulling from a hitch transfers load; "
                      + ("the heights are fitted from the front-axle load" if "front_load" in problem.channels
                         else "modelled from the vehicle file's hitch and centre-of-gravity heights"))
        elif name == "draft_offset" and fr.fdx is None:
            reason = "no draft signal"
        elif name == "axle_load_offset" and "front_load" not in problem.channels:
            reason = "no measured front-axle load"
        elif name == "torque_offset" and MU0_NOMINAL and reverse_s < OFFSET_REVERSE_MIN_S:
            reason = ("in forward driving a torque offset per axle is the tyre's zero-slip traction ratio of the "
                      "nominal model (μ_0 = b/(r F_z), fitted per axle) plus a constant resistance (ρ_s): not "
                      "separable; in reverse both turn with the travel and the offset does not, but this recording "
                      f"reverses for {reverse_s:.0f} s (at least {OFFSET_REVERSE_MIN_S:.0f} s "
                      "needed); check the torque reading at standstill with the drive unloaded")
        elif name == "clock_skew" and fr.v_gps_source != "gnss":
            reason = ("no GNSS in this recording: the radar's ground speed that stands in for it is on the CAN "
                      "clock, so there is no second clock to skew")
        elif name == "clock_skew" and fr.rate_hz < 5.0:
            reason = f"sample rate {fr.rate_hz:.1f} Hz is too low to resolve a clock offset"
        out[name] = reason
    return out


LEVEL_AT_CENTROID = {"clock_skew": ("offset_s", "rate_ppm", 1e-6)}
"""Effects with a level that drifts linearly in time, level(t) = x_level + scale · x_rate · t: (level
parameter, rate parameter, scale).  The level at t = 0 trades off with the rate when the data that carry it
are few and spread (a clock's shift is seen only where the speed changes), so each interval alone may reach
zero while the shift itself is well measured.  It is tested, and reported, where the data hold it best: at
the time t* of least variance of the level (:func:`level_at_centroid`)."""
LIBRARY_LEVEL_NAME = {"clock_skew": "clock shift δ(t)"}
"""The drifting level's name in the report."""


def level_at_centroid(fr: FitResult, name: str) -> dict | None:
    """``{"t_s", "value", "ci95"}`` of a drifting level (:data:`LEVEL_AT_CENTROID`) at the time t* = −C_lr /
    (s C_rr) where its variance C_ll + 2 s t C_lr + s² t² C_rr is least (the information-weighted centroid
    of the fit's data), with the sandwich's 95 % half-width scaled by the larger widening the refined
    intervals of the two parameters have over theirs; None where the fit has no such level or no finite
    covariance."""
    spec = LEVEL_AT_CENTROID.get(name)
    if spec is None or fr.cov is None:
        return None
    lvl, rate, sc = spec
    try:
        i, j = fr.names.index(f"{name}.{lvl}"), fr.names.index(f"{name}.{rate}")
    except ValueError:
        return None
    c = np.asarray(fr.cov, dtype=float)
    cll, clr, crr = c[i, i], c[i, j], c[j, j]
    if not (np.isfinite([cll, clr, crr]).all() and cll > 0.0 and crr > 0.0):
        return None
    t_star = -clr / (sc * crr)
    var = max(cll - clr * clr / crr, 0.0)
    ci = fr.ci95_by.get(name, fr.ci95)
    widen = 1.0
    for k, v in ((lvl, cll), (rate, crr)):
        lo, hi = ci.get(k, (math.nan, math.nan))
        if math.isfinite(lo) and math.isfinite(hi):
            widen = max(widen, (hi - lo) / (2.0 * 1.959964 * math.sqrt(v)))
    xs = fr.effects.get(name, fr.params) if fr.effects else fr.params
    value = float(xs[lvl]) + sc * float(xs[rate]) * t_star
    half = 1.959964 * widen * math.sqrt(var)
    return {"t_s": float(t_star), "value": value, "ci95": (value - half, value + half)}


def tyre_law_note(p_ratio: float) -> str:
    """The report's note beside a fitted tyre pressure: the radius change the data measure, and the tyre law's
    ranges behind the pressure's interval (:func:`.intervals.tyre_law_extension`)."""
    eps = tyre_pressure_terms(p_ratio)[0]
    return (f"tyre_pressure: the data measure its rolling-radius change, ε = {eps:+.4f}; the pressure that made "
            "it depends on the tyre, so the interval of p/p_0 holds every pressure giving the same radius within "
            f"δ_0/r_0 {TYRE_DEFLECTION_RATIO_RANGE[0]:.2f}–{TYRE_DEFLECTION_RATIO_RANGE[1]:.2f} and a carcass "
            f"share {TYRE_CARCASS_SHARE_RANGE[0]:.2f}–{TYRE_CARCASS_SHARE_RANGE[1]:.2f}")


def _excludes_null(fr: FitResult, name: str | None = None) -> bool:
    """True when some parameter's 95 % interval of effect ``name`` (default: the fit's only one)
    lies outside its negligible band around the null value (for a drifting level, also the level where
    the data hold it, :func:`level_at_centroid`)."""
    name = name or fr.candidate
    cand = CANDIDATES[name]
    ci = fr.ci95_by.get(name, fr.ci95)
    # front_share is meaningful only through delta_kg; a drifting level's band is its level parameter's
    tests = [(p, ci.get(p.name, (math.nan, math.nan))) for p in cand.fitted if p.name != "front_share"]
    lv = level_at_centroid(fr, name)
    if lv is not None:
        tests.append((next(q for q in cand.fitted if q.name == LEVEL_AT_CENTROID[name][0]), lv["ci95"]))
    for p, (lo, hi) in tests:
        if math.isfinite(lo) and math.isfinite(hi) and (lo > p.null + p.negligible or hi < p.null - p.negligible):
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
    lifted = lifted_draft_channel(feat)
    if lifted is not None:
        channels.append(lifted)
    problem = Problem(feat, channels)
    # Does the draft sensor's zero (its reading with the implement lifted) follow the library's
    # offset-and-drift line?  Another shape (a step) is outside the library: located, never named.
    problem.lifted_shape = shape_check(lifted)
    notes = list(fr.notes) + list(feat.notes)
    testable = _testability(problem, feat)
    null = held_out(problem, None)

    results: list[CandidateResult] = []
    for name in CANDIDATES:
        if testable[name]:
            results.append(CandidateResult(name, False, testable[name]))
            continue
        f = fit(problem, name)
        ho = held_out(problem, name, x_start=f.x)
        sc, per = score(problem, null, ho)
        _calibrate(f, ho.fold_params)
        if not (sc > POOL_MIN_SCORE) and name != "grade":
            # Never detected, never in the stepwise pool, never the focus of a plot: its held-out
            # residuals (every channel's rows) are not kept, so that a long recording's candidates do
            # not hold a copy each (12 MB per candidate at 4 hours).
            ho.resid = {}
        cr = CandidateResult(name, True, "", sc, per, f, ho)
        cr.detected = bool(sc >= DETECT_LLR and f.ok is not None and _excludes_null(f))
        side = _implausible_bound(f, name)
        if cr.detected and side:
            cr.detected = False
            cr.reason = (f"fits on the {side} of its range: not a plausible size of this effect; the mismatch it "
                         "takes up is left to the search for a missing term (open world)")
            notes.append(f"{name}: {cr.reason}")
        worse = (_contradicted(per) or _unseparated(name, per) or _other_shape(problem, name)
                 or ("" if name in CHARACTERISTIC else _irrelevant(null, ho)))
        if cr.detected and worse:
            cr.detected = False
            cr.reason = worse
            notes.append(f"{name} (held-out {sc:.1f}): {worse}")
        results.append(cr)
    results.sort(key=lambda r: (not r.testable, -(r.score if math.isfinite(r.score) else -1e18)))

    detected = [r for r in results if r.detected]
    grade_res = next((r for r in results if r.name == "grade"), None)
    gcheck = _grade_check(problem, feat, grade_res)
    ambiguous: list[str] = []
    chosen: list[str] = []
    causes: list[str] = []
    consistent: dict[str, list[str]] = {}
    steps: list[dict] = []
    withdrawn: list[dict] = []
    joint = None
    joint_ho = None
    if results and not any(r.testable for r in results):
        # Nothing could be tested (too short, signals missing): not the verdict of a healthy machine.
        verdict, effect = "untestable", None
    elif not detected:
        if gcheck.get("material") and not gcheck.get("separable"):
            verdict, effect = "ambiguous", None
            ambiguous = ["grade", "constant resistance (soil rolling resistance ρ_s or a constant draft)"]
        else:
            verdict, effect = "none", None
    else:
        best = detected[0]
        margin = max(DETECT_LLR, AMBIGUOUS_FRACTION * best.score)
        close = [r for r in detected[1:] if best.score - r.score < margin]
        # What every machine has explains the mismatch as well as a fault: the characteristic is chosen
        # and the faults that score as well are recorded as consistent with it, never named.
        chars = [r for r in [best] + close if r.name in CHARACTERISTIC and _healthy(r.name, r.fit)]
        if chars and best.name not in CHARACTERISTIC:
            ch0 = chars[0]
            consistent[ch0.name] = [r.name for r in [best] + close if r.name != ch0.name and r.name not in CHARACTERISTIC]
            best = ch0
            close = [r for r in close if r.name in CHARACTERISTIC and r.name != ch0.name]
        elif best.name in CHARACTERISTIC and _healthy(best.name, best.fit):
            consistent[best.name] = [r.name for r in close if r.name not in CHARACTERISTIC]
            close = [r for r in close if r.name in CHARACTERISTIC]
        chosen, joint, joint_ho, steps = _stepwise(problem, results, best, null, consistent)
        # A close competitor that the augmentation did not add as a separate effect explains the same
        # mismatch: the recording cannot tell the two apart.
        rivals = [r.name for r in close if r.name not in chosen]
        if best.name not in chosen:
            # The backward pass dropped the first step's fault (a later one explains its structure):
            # what tied with it at that step is no rival of the model kept.
            rivals = []
        # A cause the library models through another effect's term (low tyre pressure through a
        # radius error): when the two tie, the data show the term, not its cause; the simpler one is
        # named and the cause is mentioned.
        for r_name in list(rivals):
            if GENERALISES.get(r_name) == best.name:
                rivals.remove(r_name)
                causes.append(r_name)
        if best.name in GENERALISES and rivals == [GENERALISES[best.name]]:
            causes.append(best.name)
            best = next(r for r in detected if r.name == GENERALISES[best.name])
            chosen, joint, joint_ho, steps = _stepwise(problem, results, best, null, consistent)
            rivals = []
        if rivals:
            verdict, effect = "ambiguous", None
            ambiguous = [best.name] + rivals
        else:
            verdict, effect = "effect", best.name
        # What every machine has, at a healthy size, is characterised, not a fault (the verdict names
        # the first fault the augmentation chose, or none).
        faults = [n for n in chosen if not _healthy(n, joint)]
        if verdict == "effect" and effect not in faults:
            verdict, effect = ("effect", faults[0]) if faults else ("none", None)
        # The reported fit's intervals: profile likelihood and block jackknife (fit.refine_intervals).
        refine_intervals(problem, joint)
        # A fault added by a later step whose reported interval reaches its absence is withdrawn by the
        # naming rule below; while it stays in the model it keeps the structure it took up from the
        # candidate that explains it (a front mass taking up the level of the front-axle load blocked the
        # axle-load offset).  The augmentation is re-run without it, as often as a fault is withdrawn.
        excluded: list[str] = []
        for _ in range(MAX_EFFECTS):
            weak = [n for n in chosen[1:] if not _healthy(n, joint) and joint is not None
                    and n in joint.ci95_by and not _excludes_null(joint, n)]
            if not weak:
                break
            for n in weak:
                iv = ", ".join(f"{k} [{_fmt(lo)}, {_fmt(hi)}]" for k, (lo, hi) in joint.ci95_by[n].items()
                               if k != "front_share")
                sc_n = next((s.get("score") for s in steps if s.get("added") == n), None) or 0.0
                units = {q.name: q.unit for q in LIBRARY[n].params}
                withdrawn.append({
                    "name": n, "kind": "sensor_fault" if n in SENSOR_FAULTS else "effect", "named": False,
                    "not_significant": True, "withdrawn": True, "score": sc_n, "formula": LIBRARY[n].formula,
                    "plain": CANDIDATES[n].plain, "trades_off_with": [],
                    "parameters": {k: {"value": v, "ci95": list(joint.ci95_by[n][k]) if k in joint.ci95_by[n] else None,
                                       "unit": units.get(k, "")} for k, v in joint.effects[n].items()}})
                notes.append(f"{n}: held-out score {sc_n:.1f}, but its 95 % interval ({iv}) reaches the value at "
                             "which it vanishes: not named; the augmentation is re-run without it")
                steps.append({"step": len(steps) + 1, "withdrawn": n,
                              "why": f"its 95 % interval ({iv}) reaches the value at which it vanishes; the "
                                     "augmentation is re-run without it"})
            excluded += weak
            chosen, joint, joint_ho, steps2 = _stepwise(problem, results, best, null, consistent, exclude=excluded)
            steps += steps2
            faults = [n for n in chosen if not _healthy(n, joint)]
            if verdict == "effect":
                verdict, effect = ("effect", faults[0]) if faults else ("none", None)
            refine_intervals(problem, joint)
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
    d = Diagnosis(fr.source, verdict, effect, ambiguous, statement, results, problem, null, stats_before,
                  stats_after, cps, lead, regs, ev, gcheck, notes)
    d.joint, d.joint_heldout, d.steps = joint, joint_ho, steps
    d.effects = _effect_list(d, chosen, ambiguous)
    d.effects += [w for w in withdrawn if not any(e["name"] == w["name"] for e in d.effects)]
    # A fault added by a step that another fault improved as much: ambiguous between them.
    amb_step = next((e for e in d.effects if e.get("ambiguous_with") and e["name"] == d.effect), None)
    if amb_step is not None:
        d.verdict, d.effect = "ambiguous", None
        d.ambiguous_between = [amb_step["name"]] + amb_step["ambiguous_with"]
        d.statement = (_statement("ambiguous", None, d.ambiguous_between, results, lead, ev, problem, gcheck)
                       + "  (They take up the same structure: a torque-sensor gain on one axle and a mass on "
                       "that axle both change its adhesion from the torque balance alike.)"
                       if {"mass", "torque_gain"} <= set(d.ambiguous_between) else
                       _statement("ambiguous", None, d.ambiguous_between, results, lead, ev, problem, gcheck))
    # A fault whose estimate trades off with a characteristic found at a healthy size (|correlation| ≥
    # TRADE_OFF_CORR in the joint fit) is not separated from what every machine has: not named.
    chars_ok = {e["name"] for e in d.effects if e["kind"] == "characteristic"}
    for e in d.effects:
        if e["kind"] not in ("effect", "sensor_fault") or not e.get("named") or e["name"] == "wheel_speed_hold":
            continue
        with_char = [t for t in e.get("trades_off_with", []) if t["with"] in chars_ok]
        if with_char:
            e["named"] = False
            e["explained_by"] = with_char
            consistent.setdefault(with_char[0]["with"], []).append(e["name"])
            chosen_faults = [x for x in chosen if x != e["name"]]
            d.notes.append(f"{e['name']} trades off with {with_char[0]['with']} (correlation "
                           f"{with_char[0]['correlation']:+.2f}): not separated from the machine's characteristic")
            if d.effect == e["name"]:
                rest = [x["name"] for x in d.effects if x["kind"] in ("effect", "sensor_fault") and x.get("named")
                        and x["name"] != e["name"] and x["name"] in chosen_faults]
                d.verdict, d.effect = ("effect", rest[0]) if rest else ("none", None)
                if d.verdict == "none":
                    d.statement = ("No fault named: the mismatch the library's effects take up is explained as well "
                                   "by the machine's characteristics at a healthy size (below).")
                else:
                    d.statement = _statement(d.verdict, d.effect, ambiguous, results, lead, ev, problem, gcheck)

    def unname(e: dict, flag: str, note: str, if_none: str) -> None:
        """Report effect ``e`` without naming it (``flag`` says why, ``note`` in the notes); a verdict it was
        moves to the next named fault the augmentation chose, else none with the statement ``if_none``."""
        e["named"] = False
        e[flag] = True
        d.notes.append(note)
        if d.effect == e["name"]:
            rest = [x["name"] for x in d.effects if x["kind"] in ("effect", "sensor_fault") and x.get("named")
                    and x["name"] in chosen]
            d.verdict, d.effect = ("effect", rest[0]) if rest else ("none", None)
            d.statement = (_statement(d.verdict, d.effect, ambiguous, results, lead, ev, problem, gcheck)
                           if rest else if_none)

    # A fault is named only when the 95 % interval it is reported with (the joint fit's, profile
    # likelihood and block jackknife) still excludes its negligible band: detection asked that of the
    # sandwich interval, and a name whose calibrated interval reaches the effect's absence is not a finding
    # (a rear mass taken up from a few pass-end accelerations of a recording whose time blocks disagree).
    for e in d.effects:
        if (e["kind"] not in ("effect", "sensor_fault") or not e.get("named") or e["name"] == "wheel_speed_hold"
                or joint is None or e["name"] not in joint.ci95_by or _excludes_null(joint, e["name"])):
            continue
        iv = "; ".join(f"{k} [{_fmt(v['ci95'][0])}, {_fmt(v['ci95'][1])}]" for k, v in e["parameters"].items()
                       if v.get("ci95") and k != "front_share")
        unname(e, "not_significant",
               f"{e['name']}: held-out score {e.get('score') or 0.0:.1f}, but its 95 % interval ({iv}) reaches the "
               "value at which it vanishes: not named",
               "No fault named: the best explanation's 95 % interval reaches the value at which it vanishes "
               f"({e['name']}: {iv}).")
    # A fault none of whose parameters is identified (every 95 % interval spans nearly its library range, as at
    # a bound) says nothing about the machine: it is not named (a draft reading frozen at 150 s was the headline
    # "effect: drivetrain", η = 0.6 [0.5, 0.977], with its interval reported as not identified).
    for e in d.effects:
        ps = [v for v in e.get("parameters", {}).values() if v.get("ci95") is not None]
        if (e["kind"] not in ("effect", "sensor_fault") or not e.get("named") or e["name"] == "wheel_speed_hold"
                or not ps or any(v.get("identified") is not False for v in ps)):
            continue
        iv = "; ".join(f"{k} [{_fmt(v['ci95'][0])}, {_fmt(v['ci95'][1])}]" for k, v in e["parameters"].items()
                       if v.get("ci95"))
        unname(e, "not_identified",
               f"{e['name']}: held-out score {e.get('score') or 0.0:.1f}, but no parameter is identified (its 95 % "
               f"interval spans nearly the library's range: {iv}): not named",
               f"No fault named: the best explanation, {e['name']}, is not identified by this recording (its 95 % "
               f"interval spans nearly its whole range: {iv}).")
    # The named effect's parameters in the statement are the reported ones (the joint fit's calibrated
    # intervals of the effects list), not the candidate's own fit: the two disagreed (b_rear 383 [243, 523]
    # in the statement, [68, 690] in the list, for a true 200).
    if d.verdict == "effect" and d.effect is not None:
        e0 = next((x for x in d.effects if x["name"] == d.effect), None)
        if e0 is not None and any(v.get("ci95") for v in e0.get("parameters", {}).values()):
            d.statement = _statement(d.verdict, d.effect, ambiguous, results, lead, ev, problem, gcheck,
                                     fitted=e0["parameters"])
    for e in d.effects:
        alts = [a for a in consistent.get(e["name"], [])
                if a not in chosen or any(x["name"] == a and not x.get("named") for x in d.effects)]
        if alts and e["kind"] == "characteristic":
            e["consistent_with"] = alts
            d.notes.append(f"{e['name']} at a healthy size explains the mismatch as well as "
                           f"{', '.join(alts)}: what every machine has is chosen, no fault is named")
    for c in causes:
        cr = d.candidate(c)
        ps = ", ".join(f"{k} = {_fmt(v)}" for k, v in (cr.fit.params.items() if cr and cr.fit else []))
        d.statement += (f"  A possible cause: {CANDIDATES[c].plain} ({ps}) explains it as well (held-out score "
                        f"{cr.score:.1f}); the recording cannot tell the cause from the term.")
        d.notes.append(f"{c} fits as well as {GENERALISES[c]} (its term); named: {GENERALISES[c]}")
    for e in d.effects:
        if e["name"] == "tyre_pressure" and "p_ratio" in e.get("parameters", {}):
            d.notes.append(tyre_law_note(float(e["parameters"]["p_ratio"]["value"])))
    named = [e for e in d.effects if e["kind"] in ("effect", "sensor_fault") and e.get("named")]
    if len(named) > 1:
        d.statement += "  Several effects at once: " + "; ".join(_effect_words(e) for e in named) + "."
    chars = [e for e in d.effects if e["kind"] == "characteristic"]
    if chars:
        d.statement += ("  Characteristics of this machine (what every machine has, at a healthy size; not "
                        "faults): " + "; ".join(_effect_words(e) for e in chars) + ".")
    from .openworld import open_world

    d.open_world = open_world(d)
    if d.open_world.get("statement"):
        d.statement += "  " + d.open_world["statement"]
    sh = getattr(problem, "lifted_shape", None) or {}
    if sh:
        d.open_world["lifted_draft"] = sh
    if sh.get("statement"):
        d.open_world["structure_remains"] = True
        d.open_world["finding"] = True
        d.statement += "  " + sh["statement"]
        d.notes.append(sh["statement"])
    if d.verdict == "none":
        # The verdict agrees with what the report holds: a sensor fault found by a data check is named (it was
        # in ``effects`` as named while the verdict said none), and a located finding of the open world (one
        # wheel against its partner, the lifted draft's shape, a significant generic model taking 30 % of the
        # held-out RMSE) is "unexplained", never the healthy machine's "none".  A residual merely above its
        # noise level is said in the statement; a healthy realistic plant shows that too.
        checked = next((e for e in d.effects if e.get("detected_by") == "data check" and e.get("named")), None)
        if checked is not None:
            d.verdict, d.effect = "effect", checked["name"]
            rest = ("No effect of the model improves the held-out fit" + d.statement[len(NO_MISMATCH):]
                    if d.statement.startswith(NO_MISMATCH) else d.statement)
            d.statement = f"{checked['plain']}: {_effect_words(checked)}.  " + rest
        elif d.open_world.get("finding"):
            d.verdict = "unexplained"
            for head in (NO_MISMATCH, "No fault named"):
                if d.statement.startswith(head):
                    d.statement = ("Mismatch that no library effect explains (below); no library effect named"
                                   + d.statement[len(head):])
                    break
    return d


def _calibrate(f: FitResult, fold_params: list) -> None:
    """Widen the 95 % intervals to what the two held-out folds disagree by (in place).

    The HAC sandwich is right when the model is; on a plant that is not the nominal model the
    estimate also moves with the stretch of data it sees.  Each fold fit uses half the data, so
    under the model E[(x̂_0 − x̂_1)²] = 4 Var(x̂); the standard error used is
    max(SE_HAC, |x̂_0 − x̂_1|/2).  An estimate on a bound of the library's range keeps a one-sided
    interval reaching the bound (flagged in ``at_bound``), never an interval pinned to it.
    """
    if len(fold_params) != 2:
        return
    cands = [CANDIDATES[n] for n in (f.names and [x.split(".")[0] for x in f.names] or [f.candidate])]
    seen = []
    for nm in (f.names or tuple(f"{f.candidate}.{p.name}" for p in CANDIDATES[f.candidate].fitted)):
        en, pn = nm.split(".", 1)
        if nm in seen:
            continue
        seen.append(nm)
        p = next(q for q in CANDIDATES[en].fitted if q.name == pn)
        vals = []
        for fp in fold_params:
            d = fp.get(en, fp) if isinstance(fp.get(en, None), dict) else fp
            if pn in d:
                vals.append(float(d[pn]))
        se = f.se_by.get(en, {}).get(pn, math.nan)
        if len(vals) == 2:
            se_f = abs(vals[0] - vals[1]) / 2.0
            se = max(se, se_f) if math.isfinite(se) else se_f
        if not math.isfinite(se):
            continue
        x = float(f.effects[en][pn])
        lo, hi = max(p.lo, x - 1.96 * se), min(p.hi, x + 1.96 * se)
        side = f.at_bound.get(en, {}).get(pn, "")
        if side == "upper":
            hi = p.hi
        elif side == "lower":
            lo = p.lo
        f.se_by.setdefault(en, {})[pn] = se
        f.ci95_by.setdefault(en, {})[pn] = (lo, hi)
        if len(cands) == 1 or f.candidate == en:
            f.se[pn] = se
            f.ci95[pn] = (lo, hi)


UNIDENTIFIED_SHARE = 0.9
"""A 95 % interval spanning this share of the parameter's library range says nothing: the parameter is
reported as *not identified* (never as a finding, never counted as covering the truth)."""


def identified(effect: str, param: str, lo: float, hi: float) -> bool:
    """True when the 95 % interval [lo, hi] of ``effect.param`` is narrower than
    :data:`UNIDENTIFIED_SHARE` of the parameter's range in the library (and finite)."""
    cand = CANDIDATES.get(effect)
    p = next((q for q in cand.fitted if q.name == param), None) if cand is not None else None
    if p is None or not (math.isfinite(lo) and math.isfinite(hi)):
        return False
    return bool(hi - lo < UNIDENTIFIED_SHARE * (p.hi - p.lo))


def _healthy(name: str, f: FitResult | None) -> bool:
    """True for a characteristic effect (:data:`CHARACTERISTIC`) whose fitted value is in the healthy range."""
    if name not in CHARACTERISTIC or f is None:
        return False
    key, lo, hi = CHARACTERISTIC[name]
    v = (f.effects.get(name) or f.params).get(key, math.nan)
    return bool(lo <= v <= hi)


def _white(problem: Problem, ho: HeldOut) -> bool:
    """Every channel's held-out residual is consistent with noise (whiteness and NIS coverage)."""
    for c, ch in problem.channels.items():
        if ch.extra.get("data_check"):
            continue   # a data check (the lifted draft), not a balance of the model
        r = ho.resid[c]
        ok = np.isfinite(r)
        if ok.sum() < 20:
            continue
        sigma = noise_sigma(ch, r)
        if not (ljung_box_p(r[ok]) > WHITE_P and nis_coverage(ch, r, sigma) >= WHITE_NIS):
            return False
    return True


SEPARATING = {
    "mass": (("speed", "front_load"),
             "is a term a force-scale error of the drive (torque-sensor gain, drivetrain efficiency) shares"),
    "axle_load_offset": (("front_load",),
                         "comes through the wheel loads it shifts, from structure another term leaves there"),
}
"""Effect → (the channels where its term is not a copy of another effect's, what its gain elsewhere is).

A mass acts on the GNSS speed channel only as the scale 1/(m + Δm) of the integrated net force, which a
force-scale error of the drive (torque-sensor gain, drivetrain efficiency) reproduces; the speed equation holds
its inertia Δm dv/dt against the measured force itself and the front-axle pin its static share.

A front-axle load sensor's offset is an error of that one reading: the front-load channel compares the reading
itself with the nominal split.  Elsewhere it acts only through the wheel loads the reading sets (rolling radii,
the slip channel's rear loads), where it lends a mass's front share a free lever: on a healthy-pin recording of a
machine 800 kg heavier than its file (the realistic suite's phys_mass_drift) a −16.6 kN offset beside a mass of
2000 kg wholly on the front axle won 12 on the GNSS speed and 16 on the slip channel while the pin's own channel
lost 1.6; without it the mass is 1159 kg [701, 1620] with a front share of 0.27 [0.16, 0.44] (truth 800, 0.4)."""


def _unseparated(name: str, per_channel: dict[str, float]) -> str:
    """Why effect ``name`` is not separated from the effects its other channels cannot tell it from, or ''.

    An effect with separating channels (:data:`SEPARATING`) must raise their held-out log-likelihood;
    evidence from the other channels alone is evidence of a term several effects share."""
    sep = SEPARATING.get(name)
    if not sep:
        return ""
    chans, elsewhere = sep
    gain = sum(per_channel.get(c, 0.0) for c in chans)
    if gain > 0.0:
        return ""
    return (f"no support where it is separable ({' and '.join(chans)}: {gain:+.1f} held out); its gain elsewhere "
            f"{elsewhere}, so it is not named")


def _irrelevant(null: HeldOut, cand: HeldOut) -> str:
    """Why a candidate explains too little of every signal to be named (:data:`RELEVANT_F2`), or ''."""
    f2 = {c: s0 / cand.sse[c] - 1.0 for c, s0 in null.sse.items() if s0 > 0 and cand.sse.get(c, 0.0) > 0}
    if not f2:
        return ""
    c, best = max(f2.items(), key=lambda kv: kv[1])
    if best >= RELEVANT_F2:
        return ""
    return (f"explains too little of any signal to be the cause: on its best channel ({c}) the held-out RMSE "
            f"falls by {100 * (1 - (1 + best) ** -0.5):.1f} % (f² = {best:.3f} < {RELEVANT_F2:g}); its score comes "
            "from the recording's length, not from the size of what it explains, so it is not named")


def _other_shape(problem: Problem, name: str) -> str:
    """Why a draft-sensor offset is not the library's b_0 + b_1 t, or '': its readings with the implement
    lifted (the sensor's zero, :mod:`.lifted`) follow no straight line in time."""
    sh = getattr(problem, "lifted_shape", None) or {}
    if name != "draft_offset" or sh.get("linear", True):
        return ""
    a, b = sh["jump_between_s"]
    return (f"the draft reading with the implement lifted does not follow b_0 + b_1 t (χ² = {sh['chi2']:.0f} on "
            f"{sh['dof']} degrees of freedom; it moves from {sh['level_before_n'] / 1000:.2f} to "
            f"{sh['level_after_n'] / 1000:.2f} kN between t = {a:.0f} and {b:.0f} s): another shape of the "
            "sensor's error, outside the library, so it is not named")


def _contradicted(per_channel: dict[str, float]) -> str:
    """Why a candidate is contradicted by a signal, or ''.

    An effect acts on every channel in whose equation its term appears; fitted where it is real, it
    improves each of them or leaves it as it was.  One that lowers some channel's held-out
    log-likelihood by :data:`DETECT_LLR` or more (the evidence a detection asks for, the other way) is
    fitted to structure elsewhere at that channel's expense: it is not the explanation.  (A rear
    torque reading 7 % low was taken up by a rear mass of +1.7 t through the GNSS speed channel, +27,
    while the speed equation, where a mass acts through its inertia directly, lost 15.)"""
    bad = {c: v for c, v in per_channel.items() if v <= -DETECT_LLR}
    if not bad:
        return ""
    c, v = min(bad.items(), key=lambda kv: kv[1])
    return (f"contradicted by the {c} channel, whose held-out log-likelihood it lowers by {-v:.1f}: its "
            "term does not describe that signal, so it is not named")


def _implausible_bound(f: FitResult, name: str) -> str:
    """'lower bound' / 'upper bound' when a parameter of effect ``name`` in fit ``f`` sits on a bound of
    the library's range that is not the value at which the effect vanishes (the front-axle share of a
    mass change is a share: 0 and 1 are physical), else ''."""
    cand = CANDIDATES[name]
    for p in cand.fitted:
        side = f.at_bound.get(name, {}).get(p.name, "")
        if not side or p.name == "front_share":
            continue
        bound = p.lo if side == "lower" else p.hi
        if abs(bound - p.null) > 1e-9 * max(1.0, abs(p.hi - p.lo)):
            return f"{side} bound ({p.name} = {bound:g})"
    return ""


def _stepwise(problem: Problem, results: list[CandidateResult], first: CandidateResult,
              null: HeldOut, consistent: dict[str, list[str]] | None = None, exclude: list[str] | tuple = ()
              ) -> tuple[list[str], FitResult, HeldOut, list[dict]]:
    """Forward stepwise augmentation of the nominal model (issue: several effects at once).

    Start from the best detected single effect; at each step add the candidate that most improves
    the held-out log-likelihood of the current model (its effects re-fitted jointly with the new
    one on each fold), refit all chosen effects jointly on all data, and keep the addition only when
    its held-out score reaches :data:`DETECT_LLR` and its interval in the joint fit excludes the
    negligible band.  Stop when no addition qualifies, when every channel's residual is consistent
    with noise (:func:`_white`) or after :data:`MAX_EFFECTS`.  Faults in ``exclude`` (withdrawn because
    their reported interval reached their absence) are not tried.
    """
    chosen = [first.name]
    cur_fit = first.fit
    cur_ho = first.heldout
    steps = [{"step": 1, "added": first.name, "score": first.score, "against": "nominal model"}]
    # The pool: candidates with some evidence of their own against the nominal model, best first
    # (at most POOL; an effect without any single-step evidence rarely earns a place later).
    pool = [r.name for r in results if r.testable and r.name != first.name and math.isfinite(r.score)
            and r.score > POOL_MIN_SCORE and r.name not in exclude][:POOL]
    while len(chosen) < MAX_EFFECTS and pool:
        if _white(problem, cur_ho):
            steps.append({"step": len(chosen) + 1, "stopped": "every channel's residual is consistent with noise"})
            break
        start = {n: _xs(cur_fit, n) for n in chosen}
        trials = []
        for name in pool:
            ho = held_out(problem, tuple(chosen + [name]), start=start)
            sc, per = score(problem, cur_ho, ho)
            trials.append((sc, name, ho, per))
        trials.sort(key=lambda t: -t[0])
        sc, name, ho, per = trials[0]
        if sc < DETECT_LLR:
            steps.append({"step": len(chosen) + 1, "stopped": f"best addition {name} improves the held-out "
                          f"log-likelihood by {sc:.1f} < {DETECT_LLR:.0f}"})
            break
        from .fit import Joint

        margin = max(DETECT_LLR, AMBIGUOUS_FRACTION * sc)
        near = [t for t in trials[1:] if sc - t[0] < margin]
        alt_char = next((t for t in near if t[1] in CHARACTERISTIC and t[0] >= DETECT_LLR), None)
        if name not in CHARACTERISTIC and alt_char is not None:
            jc = fit(problem, Joint(tuple(chosen + [alt_char[1]]), start))
            _calibrate(jc, alt_char[2].fold_params)
            if _healthy(alt_char[1], jc):
                # A characteristic at a healthy size explains the step as well as a fault.
                if consistent is not None:
                    consistent.setdefault(alt_char[1], []).append(name)
                sc, name, ho, per = alt_char
                chosen.append(name)
                pool.remove(name)
                cur_fit, cur_ho = jc, ho
                steps.append({"step": len(chosen), "added": name, "score": sc, "against": "+".join(chosen[:-1]),
                              "consistent_with": [trials[0][1]]})
                continue
        jf = fit(problem, Joint(tuple(chosen + [name]), start))
        _calibrate(jf, ho.fold_params)
        side = _implausible_bound(jf, name)
        if side:
            steps.append({"step": len(chosen) + 1, "stopped": f"best addition {name} (held-out {sc:.1f}) fits on "
                          f"the {side}: not a plausible size"})
            pool.remove(name)
            continue
        # The rules a fault must pass alone hold for an addition too, against the model it joins: among
        # them the relevance of what it explains (a clock shift that took up 0.5 % of the GNSS speed's
        # mismatch was added at step 2 though the same rule had kept it from being named alone).
        worse = (_contradicted(per) or _unseparated(name, per) or _other_shape(problem, name)
                 or ("" if name in CHARACTERISTIC else _irrelevant(cur_ho, ho)))
        if worse and name not in CHARACTERISTIC:
            steps.append({"step": len(chosen) + 1, "stopped": f"best addition {name} (held-out {sc:.1f}): {worse}"})
            pool.remove(name)
            continue
        if not _excludes_null(jf, name):
            steps.append({"step": len(chosen) + 1, "stopped": f"best addition {name} (held-out {sc:.1f}) is "
                          "negligible in the joint fit"})
            pool.remove(name)
            continue
        chosen.append(name)
        pool.remove(name)
        cur_fit, cur_ho = jf, ho
        step = {"step": len(chosen), "added": name, "score": sc, "against": "+".join(chosen[:-1]),
                "per_channel": {c: round(float(v), 2) for c, v in per.items() if v}}
        # Other faults that improve this step as much (within the margin) explain the same structure:
        # the recording cannot tell which one it is.
        rivals = [t[1] for t in near if t[1] not in CHARACTERISTIC and t[1] != name]
        if rivals and name not in CHARACTERISTIC:
            step["ambiguous_with"] = rivals
        steps.append(step)
    if len(chosen) > 1:
        chosen, cur_fit, cur_ho = _prune(problem, results, chosen, cur_fit, cur_ho, steps)
    if chosen == [first.name]:
        return chosen, first.fit, first.heldout, steps
    if len(chosen) == 1:
        one = next(r for r in results if r.name == chosen[0])
        return chosen, one.fit, one.heldout, steps
    return chosen, cur_fit, cur_ho, steps


def _prune(problem: Problem, results: list[CandidateResult], chosen: list[str], cur_fit: FitResult,
           cur_ho: HeldOut, steps: list[dict]) -> tuple[list[str], FitResult, HeldOut]:
    """Backward pass of the augmentation: every fault must earn its place beside the others.

    A fault entered when it improved the held-out log-likelihood of the model *at that step* by
    :data:`DETECT_LLR`; a later addition can explain the same structure better (a front-axle load
    offset, added after a front mass that took up the same level of the measured load).  Each fault
    of the joint model is therefore removed in turn and the model without it re-fitted on the folds;
    the fault whose removal costs least is dropped when that cost is below :data:`DETECT_LLR` (the
    same evidence the forward step asks for), and the pass repeats.  Characteristics at a healthy
    size are never dropped (they are the machine's, not findings).

    A dropped fault whose estimate traded off (|correlation| ≥ :data:`TRADE_OFF_CORR`) with a fault that
    stays, and that stayed cheap to remove too (the data need one of the two, not both), is recorded
    as ambiguous with it (``ambiguous_with`` and ``trade_off`` on the step that added the one kept):
    the recording cannot tell which of the two it is.
    """
    from .fit import Joint

    by_added = {s["added"]: s for s in steps if "added" in s}
    while len(chosen) > 1:
        faults = [n for n in chosen if not _healthy(n, cur_fit)]
        if not faults:
            break
        trials = []
        for n in faults:
            rest = tuple(m for m in chosen if m != n)
            start = {m: _xs(cur_fit, m) for m in rest}
            if len(rest) == 1:
                ho = held_out(problem, rest[0], x_start=start[rest[0]])
            else:
                ho = held_out(problem, rest, start=start)
            sc, _ = score(problem, ho, cur_ho)
            trials.append((sc, n, rest, start, ho))
        trials.sort(key=lambda t: t[0])
        sc, n, rest, start, ho = trials[0]
        if sc >= DETECT_LLR:
            break
        corr = {b: c for (a, b), c in _corr_pairs(cur_fit).items() if a == n}
        corr.update({a: c for (a, b), c in _corr_pairs(cur_fit).items() if b == n})
        tied = [t[1] for t in trials[1:] if t[0] < DETECT_LLR and abs(corr.get(t[1], 0.0)) >= TRADE_OFF_CORR]
        if len(rest) == 1:
            one = next(r for r in results if r.name == rest[0])
            jf = one.fit
            ho = one.heldout
        else:
            jf = fit(problem, Joint(rest, start))
            _calibrate(jf, ho.fold_params)
        chosen = list(rest)
        cur_fit, cur_ho = jf, ho
        step = {"step": len(steps) + 1, "removed": n, "score": sc, "against": "+".join(chosen),
                "why": f"removing {n} costs {sc:.1f} < {DETECT_LLR:.0f} of held-out log-likelihood beside "
                       + "+".join(chosen)}
        if tied:
            keep = tied[0]
            step["ambiguous_with"] = keep
            step["correlation"] = corr[keep]
            s_keep = by_added.get(keep)
            if s_keep is not None and keep not in CHARACTERISTIC:
                s_keep["ambiguous_with"] = list(s_keep.get("ambiguous_with", [])) + [n]
                s_keep.setdefault("trade_off", {})[n] = corr[keep]
        steps.append(step)
    return chosen, cur_fit, cur_ho


def _corr_pairs(jf: FitResult | None) -> dict[tuple[str, str], float]:
    """Largest correlation (by magnitude) between the estimates of two different effects of a joint fit,
    ``{(effect_i, effect_j): r}`` with i before j in the fit's order."""
    out: dict[tuple[str, str], float] = {}
    if jf is None:
        return out
    cov = jf.cov
    if cov is None or not cov.size or not np.all(np.isfinite(np.diag(cov))):
        return out
    sd = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    cr = cov / np.outer(sd, sd)
    for i, ni in enumerate(jf.names):
        for j, nj in enumerate(jf.names):
            ei, ej = ni.split(".")[0], nj.split(".")[0]
            if j <= i or ei == ej:
                continue
            if abs(cr[i, j]) > abs(out.get((ei, ej), 0.0)):
                out[(ei, ej)] = float(cr[i, j])
    return out


def _xs(f: FitResult, name: str) -> np.ndarray:
    """The fitted values of effect ``name`` in a (joint) fit, in the candidate's parameter order."""
    eff = f.effects.get(name) or f.params
    return np.array([eff[p.name] for p in CANDIDATES[name].fitted])


def _level_words(parameter: str, lv: dict | None) -> str:
    """"; <parameter> at t = … s, where the data hold it best: v [lo, hi]" (empty without a level)."""
    if not lv:
        return ""
    return (f"; {parameter} at t = {lv['t_s']:.0f} s, where the data hold it best: {_fmt(lv['value'])} "
            f"[{_fmt(lv['ci95'][0])}, {_fmt(lv['ci95'][1])}]")


def _effect_words(e: dict) -> str:
    lv = e.get("level_at_centroid")
    at = _level_words(lv["parameter"], lv) if lv else ""
    ps = ", ".join(f"{k} = {_fmt(v['value']) if isinstance(v['value'], (int, float)) else v['value']}"
                   + (f" [{_fmt(v['ci95'][0])}, {_fmt(v['ci95'][1])}]"
                                                   if v.get("ci95") and v["ci95"][0] is not None else "")
                   + (f" (at its {v['at_bound']} bound)" if v.get("at_bound") else "")
                   + (" (not identified: the interval spans its range)" if v.get("identified") is False else "")
                   for k, v in e.get("parameters", {}).items()) + at
    return f"{e['name']} ({ps})" if ps else e["name"]


def _effect_list(d: "Diagnosis", chosen: list[str], ambiguous: list[str]) -> list[dict]:
    """The report's ``effects`` list: named effects from the joint fit, ambiguous pairs with their
    correlation, the nominal model's load transfer, and sensor faults found by data checks."""
    out: list[dict] = []
    jf = d.joint
    if jf is not None:
        # Correlations between parameters of different effects in the joint fit.
        corr_pairs = _corr_pairs(jf)
        steps = {s["added"]: s for s in d.steps if "added" in s}
        for rank, name in enumerate(chosen):
            params = {}
            units = {p.name: p.unit for p in LIBRARY[name].params}
            for k, v in jf.effects[name].items():
                if name in jf.ci95_by and k in jf.ci95_by[name]:
                    lo, hi = jf.ci95_by[name][k]
                    params[k] = {"value": v, "ci95": [lo, hi], "unit": units.get(k, ""),
                                 "at_bound": jf.at_bound.get(name, {}).get(k, ""),
                                 "identified": identified(name, k, lo, hi)}
                else:
                    params[k] = {"value": v, "ci95": None, "unit": units.get(k, ""), "held": True}
            amb = [{"with": (b if a == name else a), "correlation": c} for (a, b), c in corr_pairs.items()
                   if name in (a, b) and abs(c) >= TRADE_OFF_CORR]
            kind = ("characteristic" if _healthy(name, jf) else
                    "sensor_fault" if name in SENSOR_FAULTS else "effect")
            out.append({"name": name, "kind": kind,
                        "named": d.verdict != "ambiguous" or name != chosen[0],
                        "rank": rank + 1, "score": steps.get(name, {}).get("score"),
                        "formula": LIBRARY[name].formula, "plain": CANDIDATES[name].plain,
                        "parameters": params, "trades_off_with": amb})
            lv = level_at_centroid(jf, name)
            if lv is not None:
                out[-1]["level_at_centroid"] = {"parameter": LIBRARY_LEVEL_NAME[name], "t_s": lv["t_s"],
                                                "value": lv["value"], "ci95": list(lv["ci95"])}
    if jf is not None:
        for e in out:
            rv = steps.get(e["name"], {}).get("ambiguous_with") if e["name"] in chosen else None
            # A rival that a later step added in its own right is present too, not an alternative.
            rv = [r for r in (rv or []) if r not in chosen]
            if rv and e["kind"] != "characteristic":
                e["named"], e["ambiguous"], e["ambiguous_with"] = False, True, list(rv)
                ambiguous = list(ambiguous) + [r for r in rv if r not in ambiguous]
                # A rival the backward pass dropped for trading off with this one: their correlation.
                for r, c in steps.get(e["name"], {}).get("trade_off", {}).items():
                    if r in rv and not any(t["with"] == r for t in e["trades_off_with"]):
                        e["trades_off_with"].append({"with": r, "correlation": c})
    for name in ambiguous:
        if name in CANDIDATES and not any(e["name"] == name for e in out):
            c = d.candidate(name)
            tr = [{"with": s["added"], "correlation": s["trade_off"][name]} for s in d.steps
                  if "added" in s and name in s.get("trade_off", {})]
            out.append({"name": name, "kind": "sensor_fault" if name in SENSOR_FAULTS else "effect", "named": False,
                        "ambiguous": True, "score": c.score if c else None, "formula": LIBRARY[name].formula,
                        "plain": CANDIDATES[name].plain, "parameters": {}, "trades_off_with": tr})
    for e in out:
        if e["name"] in ambiguous:
            e["ambiguous"] = True
    fl = d.problem.channels.get("front_load")
    # When nothing could be tested (too little driving) no heights are fitted: fitted to those few rows they
    # would be reported with intervals as if they meant something (h_cg −0.04 m [−0.055, −0.027] on a 3-s start).
    if fl is not None and any(c.testable for c in d.candidates):
        eff = jf.effects if jf is not None else {}
        out.append({"name": "load_transfer", "kind": "nominal", "named": False,
                    "formula": LIBRARY["load_transfer"].formula,
                    "plain": "part of the nominal model: heights fitted from the front-axle load",
                    "parameters": fl.nominal_heights(restrict(eff, fl))})
    elif d.features.frame.fzf_modelled:
        veh = d.features.frame.vehicle
        out.append({"name": "load_transfer", "kind": "nominal", "named": False,
                    "formula": LIBRARY["load_transfer"].formula,
                    "plain": "part of the nominal model: modelled from the vehicle file (no front-axle load signal)",
                    "parameters": {"h_hitch_m": {"value": veh.hitch_height_m, "ci95": None, "unit": "m", "held": True},
                                   "h_cg_m": {"value": veh.cg_height_m, "ci95": None, "unit": "m", "held": True}}})
    for f in d.features.sensor_faults:
        out.append({"name": "wheel_speed_hold", "kind": "sensor_fault", "named": True, "detected_by": "data check",
                    "formula": LIBRARY["wheel_speed_hold"].formula, "plain": f"wheel-speed {f['kind']} on {f['wheel']}",
                    "parameters": {"wheel": {"value": f["wheel"], "unit": ""},
                                   "t0_s": {"value": f["t0_s"], "unit": "s"},
                                   "duration_s": {"value": f["duration_s"], "unit": "s"}}})
    return out


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


NO_MISMATCH = "No significant mismatch: no effect from the library improves the held-out fit"
"""The head of the statement of the verdict none (:func:`_statement`)."""


def _statement(verdict, effect, ambiguous, results, lead, ev, problem, gcheck, fitted: dict | None = None) -> str:
    """The report's statement for ``verdict``; ``fitted``: the named effect's parameters as the effects list
    reports them (value, ci95), else the candidate's own fit's."""
    if verdict == "untestable":
        reasons = list(dict.fromkeys(r.reason for r in results if not r.testable))
        if len(reasons) == 1:
            return f"Cannot diagnose: {reasons[0]}."
        return ("Cannot diagnose: no effect of the library can be tested here ("
                + "; ".join(f"{r.name}: {r.reason}" for r in results if not r.testable) + ").")
    if verdict == "none":
        # the best candidate that could have been the verdict (the characteristics are reported beside it: they
        # are the machine's, not findings)
        best = next((r for r in results if r.testable and r.name not in CHARACTERISTIC), None)
        if best is None:
            extra = ""
        elif best.score < DETECT_LLR:
            extra = f" (best candidate {best.name}, held-out score {best.score:.1f} < {DETECT_LLR:.0f})"
        else:
            why = best.reason or "its interval in the fit does not exclude its absence"
            extra = f" (best candidate {best.name}, held-out score {best.score:.1f}, not named: {why})"
        return NO_MISMATCH + extra + "."
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
    if fitted is not None:
        ps = ", ".join(f"{k} = {_fmt(v['value'])} [{_fmt(v['ci95'][0])}, {_fmt(v['ci95'][1])}]"
                       for k, v in fitted.items() if v.get("ci95") and v["ci95"][0] is not None)
    else:
        ps = ", ".join(f"{k} = {_fmt(r.fit.params[k])} [{_fmt(r.fit.ci95[k][0])}, {_fmt(r.fit.ci95[k][1])}]"
                       for k in r.fit.ci95)
    if effect in LEVEL_AT_CENTROID:
        ps += _level_words(LIBRARY_LEVEL_NAME[effect], level_at_centroid(r.fit, effect))
    sig = ", ".join(f"{k} r = {v:+.2f}" for k, v in sorted(ev.items(), key=lambda kv: -abs(kv[1]))[:3])
    where = f"the {lead} residual" if lead else "the residual"
    return (f"{cand.plain}: {LIBRARY[effect].formula}.  Evidence: {where} ({problem.channels[lead].signal}) "
            f"correlates with {sig}; held-out score {r.score:.1f}.  Fitted {ps}.")
