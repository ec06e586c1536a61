"""Write a diagnosis: ``report.json``, ``report.md`` and PNG figures.

``report.json`` keys (a contract):

- ``verdict``: ``"effect"``, ``"none"``, ``"ambiguous"``, ``"unexplained"`` when no library effect is named
  but the open world located a finding (``open_world.finding``: one wheel against its partner, the lifted
  draft's shape, or a generic model of significant terms taking 30 % of the held-out RMSE; located and
  quantified in the statement), or ``"untestable"`` when nothing could be tested
  (a recording too short, or without the signals any effect acts on; for the engine-level analysis, not even
  its slip model: never a healthy machine's verdict; ``tractionecu diagnose`` exits 4 then);
- ``effect``: the named effect or null; ``ambiguous_between``: the tied explanations;
- ``candidates``: ranked list, each ``{name, score, testable, detected, reason, per_channel, parameters}``;
- ``parameters``: ``{name: {"value", "ci95": [lo, hi], "unit"}}`` of the named (or leading
  ambiguous) effect;
- ``signals``: per channel ``{rmse_before, rmse_after, r2_before, r2_after, ljung_box_p_before,
  ljung_box_p_after, nis_coverage_before, nis_coverage_after, noise_sigma, unit, signal}`` on
  held-out data (NIS coverage: share inside the χ²(1) 95 % bound, see :mod:`.locate`);
- ``locate``: lead channel, change points, regimes, signature correlations;
- ``effects``: every effect the diagnosis reports, in rank order, each ``{name, kind, named,
  score, formula, plain, parameters: {p: {value, ci95, unit, at_bound}}, trades_off_with: [{with,
  correlation}]}``; ``kind`` is ``effect`` or ``sensor_fault`` (named by the forward stepwise
  augmentation and fitted jointly), ``characteristic`` (healthy-size relaxation or drivetrain
  efficiency: what every machine has), ``nominal`` (the load transfer of the nominal model) or
  ``sensor_fault`` found by a data check (wheel-speed hold);
- ``steps``: the augmentation, step by step, and why it stopped;
- ``open_world``: structure left after the named effects (channel, where, when, how big) and the
  held-out sparse regression of it on measured signals (:mod:`.openworld`);
- ``statement``, ``grade_check``, ``notes``, and ``estimator`` when the innovation view ran (``{"skipped": why}``
  when replay cannot run the recording: the signals its profile needs are missing).

Figures: ``residual_before_after.png``, ``residual_map.png``, ``ranking.png``.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from contextlib import contextmanager
from dataclasses import asdict
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ..model.effects import EFFECTS, LIBRARY
from .candidates import CANDIDATES
from .engine import DETECT_LLR, Diagnosis
from .locate import per_time


def _num(v: Any) -> Any:
    if isinstance(v, (np.floating, float)):
        return None if not math.isfinite(float(v)) else float(v)
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, dict):
        return {str(k): _num(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_num(x) for x in v]
    if isinstance(v, np.ndarray):
        return [_num(x) for x in v.tolist()]
    return v


def _params(d: Diagnosis, name: str | None) -> dict:
    if name is None:
        return {}
    c = d.candidate(name)
    if c is None or c.fit is None:
        return {}
    out = {}
    units = {p.name: p.unit for p in LIBRARY[name].params}
    for k, v in c.fit.params.items():
        lo, hi = c.fit.ci95.get(k, (math.nan, math.nan))
        entry = {"value": v, "ci95": [lo, hi], "unit": units.get(k, "")}
        if k not in c.fit.ci95:
            entry["held"] = True
        out[k] = entry
    return out


def to_json(d: Diagnosis, estimator: dict | None = None) -> dict:
    """The report as a JSON-ready dict (module doc)."""
    cands = []
    for c in d.candidates:
        cands.append({"name": c.name, "score": c.score if c.testable else None, "testable": c.testable,
                      "detected": c.detected, "reason": c.reason, "per_channel": c.per_channel,
                      "parameters": _params(d, c.name) if c.testable else {},
                      "formula": LIBRARY[c.name].formula})
    lead_param = d.effect or (d.ambiguous_between[0] if d.ambiguous_between and d.ambiguous_between[0] in EFFECTS else None)
    signals = {}
    for ch, sb in d.stats_before.items():
        sa = d.stats_after[ch]
        signals[ch] = {"signal": sb["signal"], "unit": sb["unit"], "n": sb["n"],
                       "rmse_before": sb["rmse"], "rmse_after": sa["rmse"],
                       "r2_before": sb["r2"], "r2_after": sa["r2"],
                       "ljung_box_p_before": sb["ljung_box_p"], "ljung_box_p_after": sa["ljung_box_p"],
                       "nis_coverage_before": sb["nis_coverage_95"], "nis_coverage_after": sa["nis_coverage_95"],
                       "noise_sigma": sb["noise_sigma"]}
    out = {
        "source": d.source,
        "verdict": d.verdict,
        "effect": d.effect,
        "ambiguous_between": d.ambiguous_between,
        "statement": d.statement,
        "candidates": cands,
        "parameters": _params(d, lead_param),
        "parameters_of": lead_param,
        "signals": signals,
        "locate": {
            "lead_channel": d.lead_channel,
            "change_points": [asdict(c) for c in d.change_points],
            "regimes": [asdict(r) for r in d.regimes],
            "signature_correlation": d.evidence,
        },
        "grade_check": d.grade_check,
        "detect_threshold": DETECT_LLR,
        "notes": d.notes,
        "effects": d.effects,
        "steps": d.steps,
        "open_world": d.open_world,
    }
    if estimator is not None:
        out["estimator"] = estimator
    return _num(out)


# --------------------------------------------------------------------------- figures
def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_before_after(d: Diagnosis, path: Path) -> None:
    plt = _plt()
    focus = d.winner or (d.candidate(d.ambiguous_between[0]) if d.ambiguous_between and
                         d.ambiguous_between[0] in CANDIDATES else None)
    chans = [c for c in d.problem.channels if focus is None or d.stats_before[c]["rmse"] != d.stats_after[c]["rmse"]]
    if focus is not None and focus.per_channel:
        chans = sorted(chans, key=lambda c: -focus.per_channel.get(c, 0.0))[:3] or [d.lead_channel]
    else:
        chans = [d.lead_channel] if d.lead_channel else list(d.problem.channels)[:1]
    if not chans:                      # nothing was tested (too short a drive): the figure says so
        fig, ax = plt.subplots(figsize=(11, 3.0))
        ax.text(0.5, 0.5, "no residual: nothing in this recording could be tested", ha="center",
                transform=ax.transAxes)
        ax.set_axis_off()
        fig.savefig(path, dpi=90)
        plt.close(fig)
        return
    fig, axes = plt.subplots(len(chans), 1, figsize=(11, 3.0 * len(chans)), squeeze=False)
    fr = d.features.frame
    for ax, cname in zip(axes[:, 0], chans):
        ch = d.problem.channels[cname]
        rb = d.null_heldout.resid[cname]
        idx, mb = per_time(ch, rb)
        ax.plot(fr.t[idx], mb, lw=0.6, color="tab:red", label=f"before (nominal model): RMSE {d.stats_before[cname]['rmse']:.3g}")
        if focus is not None and focus.heldout is not None:
            ra = focus.heldout.resid[cname]
            idx2, ma = per_time(ch, ra)
            ax.plot(fr.t[idx2], ma, lw=0.6, color="tab:blue",
                    label=f"after (+ {focus.name}): RMSE {d.stats_after[cname]['rmse']:.3g}")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_ylabel(f"{cname} [{ch.unit}]")
        ax.set_title(ch.signal, fontsize=9)
        ax.legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("time [s] (held-out residual: each half predicted from a fit on the other)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_map(d: Diagnosis, path: Path) -> None:
    plt = _plt()
    fr = d.features.frame
    fig, ax = plt.subplots(figsize=(7, 6))
    if d.lead_channel is None or fr.x is None:
        ax.text(0.5, 0.5, "no positions in this recording", ha="center", transform=ax.transAxes)
    else:
        ch = d.problem.channels[d.lead_channel]
        idx, r = per_time(ch, d.null_heldout.resid[d.lead_channel])
        ok = np.isfinite(fr.x[idx]) & np.isfinite(fr.y[idx])
        lim = float(np.nanpercentile(np.abs(r), 98)) or 1.0
        sc = ax.scatter(fr.x[idx][ok], fr.y[idx][ok], c=r[ok], s=6, cmap="coolwarm", vmin=-lim, vmax=lim)
        fig.colorbar(sc, ax=ax, label=f"{d.lead_channel} residual before [{ch.unit}]")
        for cp in d.change_points:
            if cp.x_m is not None:
                ax.plot(cp.x_m, cp.y_m, "kx", ms=8)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("east [m]")
        ax.set_ylabel("north [m]")
        ax.set_title("where the nominal model disagrees (x: change points)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_ranking(d: Diagnosis, path: Path) -> None:
    plt = _plt()
    rows = [c for c in d.candidates if c.testable]
    fig, ax = plt.subplots(figsize=(8, 0.45 * max(len(rows), 2) + 1.2))
    names = [c.name for c in rows][::-1]
    scores = [c.score for c in rows][::-1]
    colors = ["tab:green" if c.detected else "tab:gray" for c in rows][::-1]
    ax.barh(names, scores, color=colors)
    ax.axvline(DETECT_LLR, color="tab:red", ls="--", lw=1, label=f"detection threshold {DETECT_LLR:.0f}")
    ax.set_xscale("symlog", linthresh=10)
    ax.set_xlabel("held-out log-likelihood ratio against the nominal model")
    untested = [c.name for c in d.candidates if not c.testable]
    title = f"verdict: {d.verdict}" + (f" — {d.effect}" if d.effect else "")
    if d.ambiguous_between:
        title += " — " + " vs ".join(d.ambiguous_between)[:80]
    ax.set_title(title, fontsize=9)
    if untested:
        ax.text(0.99, 0.01, "not testable: " + ", ".join(untested), transform=ax.transAxes, ha="right",
                va="bottom", fontsize=7)
    ax.legend(loc="lower right", fontsize=8, bbox_to_anchor=(1.0, 0.08))
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


# --------------------------------------------------------------------------- markdown
def to_markdown(rep: dict) -> str:
    L = [f"# Diagnosis of `{rep['source']}`", ""]
    L.append(f"**Verdict: {rep['verdict']}**" + (f" — `{rep['effect']}`" if rep["effect"] else ""))
    if rep["ambiguous_between"]:
        L.append(f"(ambiguous between {' and '.join(rep['ambiguous_between'])})")
    L += ["", rep["statement"], ""]
    if rep["parameters"]:
        L += [f"## Fitted parameters of `{rep['parameters_of']}` (95 % interval, autocorrelation-robust)", "",
              "| parameter | value | 95 % interval | unit |", "|---|---|---|---|"]
        for k, p in rep["parameters"].items():
            ci = p["ci95"]
            cis = "held (not separable)" if p.get("held") else (
                f"[{ci[0]:.4g}, {ci[1]:.4g}]" if ci[0] is not None and ci[1] is not None else "—")
            L.append(f"| {k} | {p['value']:.4g} | {cis} | {p['unit']} |")
        L.append("")
    effs = rep.get("effects") or []
    if effs:
        L += ["## Effects (stepwise, fitted jointly; 95 % intervals)", "",
              "| rank | effect | kind | parameters | trades off with |", "|---|---|---|---|---|"]
        for k, e in enumerate(effs, 1):
            ps = []
            for pn, p in (e.get("parameters") or {}).items():
                v = p.get("value")
                ci = p.get("ci95")
                txt = f"{pn} = {v:.4g}" if isinstance(v, (int, float)) else f"{pn} = {v}"
                if ci and ci[0] is not None and ci[1] is not None:
                    txt += f" [{ci[0]:.4g}, {ci[1]:.4g}]"
                if p.get("at_bound"):
                    txt += f" (at the {p['at_bound']} bound)"
                ps.append(txt + (f" {p['unit']}" if p.get("unit") else ""))
            lv = e.get("level_at_centroid")
            if lv:
                ps.append(f"{lv['parameter']} at t = {lv['t_s']:.0f} s, where the data hold it best: "
                          f"{lv['value']:.4g} [{lv['ci95'][0]:.4g}, {lv['ci95'][1]:.4g}]")
            tr = ", ".join(f"{t['with']} (r = {t['correlation']:+.2f})" for t in e.get("trades_off_with") or [])
            kind = (e["kind"] + (" (ambiguous)" if e.get("ambiguous") else "")
                    + (" (not named: its 95 % interval reaches its absence"
                       + ("; the augmentation was re-run without it)" if e.get("withdrawn") else ")")
                       if e.get("not_significant") else ""))
            L.append(f"| {k} | {e['name']} | {kind} | {'; '.join(ps)} | {tr or '—'} |")
        L.append("")
    ow = rep.get("open_world") or {}
    if ow.get("statement"):
        L += ["## Open world: what the library leaves unexplained", "", ow["statement"], ""]
    L += ["## Signals (held-out: each half predicted from a fit on the other half)", "",
          "| channel | what | RMSE before | RMSE after | R² before | R² after | Ljung–Box p before | after "
          "| NIS coverage before | after |",
          "|---|---|---|---|---|---|---|---|---|---|"]

    def f(v, fmt=".3g"):
        return "—" if v is None else format(v, fmt)

    for ch, s in rep["signals"].items():
        L.append(f"| {ch} [{s['unit']}] | {s['signal']} | {f(s['rmse_before'])} | {f(s['rmse_after'])} | "
                 f"{f(s['r2_before'], '.3f')} | {f(s['r2_after'], '.3f')} | {f(s['ljung_box_p_before'], '.2g')} | "
                 f"{f(s['ljung_box_p_after'], '.2g')} | {f(s.get('nis_coverage_before'), '.3f')} | "
                 f"{f(s.get('nis_coverage_after'), '.3f')} |")
    L += ["", "## Candidates (held-out log-likelihood ratio against the nominal model)", "",
          "| rank | effect | score | detected | strongest channel | formula |", "|---|---|---|---|---|---|"]
    k = 0
    for c in rep["candidates"]:
        if not c["testable"]:
            continue
        k += 1
        top = max(c["per_channel"], key=lambda q: c["per_channel"][q]) if c["per_channel"] else "—"
        L.append(f"| {k} | {c['name']} | {f(c['score'], '.1f')} | {'yes' if c['detected'] else 'no'} | {top} | "
                 f"{c['formula']} |")
    unt = [c for c in rep["candidates"] if not c["testable"]]
    if unt:
        L += ["", "Not testable with the signals of this recording:", ""]
        L += [f"- `{c['name']}`: {c['reason']}" for c in unt]
    loc = rep["locate"]
    L += ["", "## Where, when, under which regime", ""]
    if loc["lead_channel"]:
        L.append(f"Lead channel: `{loc['lead_channel']}`.")
    if loc["signature_correlation"]:
        L.append("Correlation of its residual (before) with signatures: " + ", ".join(
            f"{k} {v:+.2f}" for k, v in loc["signature_correlation"].items()) + ".")
    if loc["change_points"]:
        L += ["", "Change points of the residual level:", ""]
        for cp in loc["change_points"]:
            where = f" at ({cp['x_m']:.0f}, {cp['y_m']:.0f}) m" if cp["x_m"] is not None else ""
            L.append(f"- t = {cp['t_s']:.1f} s{where}: {cp['level_before']:.3g} → {cp['level_after']:.3g}")
    if loc["regimes"]:
        L += ["", "| regime | group | n | mean before | RMS before | mean after | RMS after |", "|---|---|---|---|---|---|---|"]
        for r in loc["regimes"]:
            L.append(f"| {r['name']} | {r['group']} | {r['n']} | {f(r['mean_before'])} | {f(r['rms_before'])} | "
                     f"{f(r['mean_after'])} | {f(r['rms_after'])} |")
    est = rep.get("estimator")
    if est:
        L += ["", "## Estimator innovations (second view)", ""]
        for k2, v in est.items():
            L.append(f"- {k2}: {v}")
    if rep["notes"]:
        L += ["", "## Notes", ""] + [f"- {n}" for n in rep["notes"]]
    L += ["", "Figures: `residual_before_after.png`, `residual_map.png`, `ranking.png`.", ""]
    return "\n".join(L)


@contextmanager
def staged(out: str | Path) -> Iterator[Path]:
    """A folder inside ``out`` that the report and its figures are written into, moved over the earlier ones
    once all are written (``report.json`` last): a diagnosis interrupted while writing (Ctrl-C, a figure that
    fails) leaves the earlier report with its own figures, never a new report beside an earlier one's figures."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    stage = out / ".report.partial"
    shutil.rmtree(stage, ignore_errors=True)
    stage.mkdir()
    try:
        yield stage
        for p in sorted(stage.iterdir(), key=lambda q: q.name == "report.json"):
            os.replace(p, out / p.name)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def write(d: Diagnosis, out: str | Path, estimator: dict | None = None) -> dict:
    """Write report.json, report.md and the figures into ``out`` (through :func:`staged`); returns the JSON
    dict."""
    rep = to_json(d, estimator)
    with staged(out) as st:
        (st / "report.json").write_text(json.dumps(rep, indent=2, ensure_ascii=False), encoding="utf-8")
        (st / "report.md").write_text(to_markdown(rep), encoding="utf-8")
        plot_before_after(d, st / "residual_before_after.png")
        plot_map(d, st / "residual_map.png")
        plot_ranking(d, st / "ranking.png")
    return rep


def plot_reduced(rep: dict, fr, out: Path) -> None:
    """Figures of the reduced (engine-level export) diagnosis: ground-speed residual before/after,
    the residual on the map, the slip–traction points with the fitted μ(s) curve, and the ranking."""
    from ..config import G
    from ..model.mucurve import SOIL_CLASSES
    from .channels import _CurveInverse
    from .reduced import MIN_SPEED

    plt = _plt()
    out = Path(out)
    sm = rep.get("slip_model")
    ok = None
    if sm is not None and fr.has("engine_torque", "engine_speed", "v_wheel_bus", "v_gps"):
        ok = (np.isfinite(fr.engine_torque) & np.isfinite(fr.engine_speed) & np.isfinite(fr.v_wheel_bus)
              & np.isfinite(fr.v_gps) & (fr.v_wheel_bus > MIN_SPEED))
    fig, axes = plt.subplots(2, 1, figsize=(11, 6))
    if ok is not None and ok.any():
        vw, vg = fr.v_wheel_bus[ok], fr.v_gps[ok]
        mu = fr.engine_torque[ok] * fr.engine_speed[ok] / vw / (fr.vehicle.mass_kg * G)
        inv = _CurveInverse(SOIL_CLASSES[sm["soil_class"]])
        a, eps = sm["a"]["value"], sm["epsilon"]["value"]
        pred = vw * (1 + eps) * (1 - inv(mu / a))
        axes[0].plot(fr.t[ok], vg - vw, lw=0.7, color="tab:red", label="before: model without slip (v_g − v_w)")
        axes[0].plot(fr.t[ok], vg - pred, lw=0.7, color="tab:blue", label="after: μ(s) curve")
        axes[0].axhline(0, color="k", lw=0.5)
        axes[0].set_xlabel("time [s]")
        axes[0].set_ylabel("ground-speed residual [m/s]")
        axes[0].legend(fontsize=8)
        s = 1 - vg / vw
        axes[1].plot(s, mu, ".", ms=3, label="export samples")
        ss = np.linspace(0, max(0.3, float(np.nanmax(s))), 200)
        axes[1].plot(1 - (1 + eps) * (1 - ss), a * SOIL_CLASSES[sm["soil_class"]].g(ss), "k-",
                     label=f"μ(s), {sm['soil_class']}, a = {a:.2f}, ε = {eps:.3f}")
        axes[1].set_xlabel("measured slip 1 − v_g/v_w [-]")
        axes[1].set_ylabel("traction ratio μ = T_e ω_e/(v_w m g) [-]")
        axes[1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "residual_before_after.png", dpi=90)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(7, 6))
    if ok is not None and ok.any() and fr.x is not None and np.isfinite(fr.x[ok]).any():
        r = fr.v_gps[ok] - fr.v_wheel_bus[ok]
        sc = ax.scatter(fr.x[ok], fr.y[ok], c=r, s=8, cmap="coolwarm")
        fig.colorbar(sc, ax=ax, label="v_g − v_w before [m/s]")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("east [m]")
        ax.set_ylabel("north [m]")
    else:
        ax.text(0.5, 0.5, "no positions in this export", ha="center", transform=ax.transAxes)
    fig.tight_layout()
    fig.savefig(out / "residual_map.png", dpi=90)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(8, 4))
    names = ["slip (μ(s) curve)"] + [c["name"] for c in rep["candidates"] if c["testable"]]
    scores = [sm["score"] if sm else 0.0] + [c["score"] for c in rep["candidates"] if c["testable"]]
    ax.barh(names[::-1], scores[::-1], color="tab:gray")
    ax.axvline(DETECT_LLR, color="tab:red", ls="--", lw=1)
    ax.set_xscale("symlog", linthresh=10)
    ax.set_xlabel("held-out log-likelihood ratio")
    ax.set_title("not testable: " + ", ".join(c["name"] for c in rep["candidates"] if not c["testable"]), fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "ranking.png", dpi=90)
    plt.close(fig)
