"""Figures of a replay: the paper's Fig. 6 (μ per wheel and ρ_s over time) and Fig. 5 (μ(s) per soil).

Drawn with matplotlib (the ``maps`` extra), imported only when a figure is drawn.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ..model.mucurve import SOIL_CLASSES, curve_class
from ..model.vehicle import WHEELS
from .scoring import S_GRID, Truth

TRUTH_STYLE = dict(color="black", lw=1.8, ls="--", zorder=3, label="true")
"""Fig. 6's truth: dashed, thicker and drawn over the estimate, so it shows where the two coincide."""
ESTIMATE_STYLE = dict(color="tab:blue", lw=1.0, alpha=0.85, zorder=2, label="AUKF-FS")


def plot_run(out: Path, arrays: dict[str, Any], truth: Truth | None, sc: dict[str, Any] | None) -> list[str]:
    """Write the paper's Fig. 6 (μ per wheel and ρ_s over time) and Fig. 5 (μ(s) per soil) as PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = arrays["t"]
    if len(t) == 0:                     # no step to draw (a recording with no estimator step)
        return []
    tr = t - t[0]
    paths = []
    fig, axes = plt.subplots(5, 1, figsize=(10, 11), sharex=True)
    if truth is not None:
        k = np.clip(np.searchsorted(truth.t, t + 1e-9, side="right") - 1, 0, len(truth.t) - 1)
    for i, w in enumerate(WHEELS):
        ax = axes[i]
        if truth is not None:
            ax.plot(tr, truth.mu[k, i], **TRUTH_STYLE)
        ax.plot(tr, arrays["mu"][:, i], **ESTIMATE_STYLE)
        ax.set_ylabel(f"μ {w} [-]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right")
    ax = axes[4]
    if truth is not None:
        ax.plot(tr, truth.rho_s[k], **TRUTH_STYLE)
    ax.plot(tr, arrays["rho_s"], **ESTIMATE_STYLE)
    ax.set_ylabel("ρ_s [-]")
    ax.set_xlabel("t [s]")
    ax.grid(alpha=0.3)
    fig.suptitle("Adhesion per wheel and soil rolling resistance (paper Fig. 6)")
    paths.append(_save(plt, fig, out / "fig6_mu_rho.png"))

    if sc and sc.get("curves"):
        fig, ax = plt.subplots(figsize=(7, 5))
        colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        for j, (name, c) in enumerate(sc["curves"].items()):
            col = colors[j % len(colors)]
            ax.plot(S_GRID, SOIL_CLASSES[c["class_true"]].mu(S_GRID, c["a_true"]), color=col, lw=2.5, alpha=0.45,
                    label=f"{name} true (a={c['a_true']:.2f})")
            ax.plot(S_GRID, curve_class(c["class_identified"]).mu(S_GRID, c["a_identified"]), color=col, lw=1.2,
                    ls="--", label=f"{name} identified (a={c['a_identified']:.3f}, R²={sc['r2_mu_curve'][name]:.4f})")
        ax.set_xlabel("slip s [-]")
        ax.set_ylabel("μ [-]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
        ax.set_title("Identified vs true μ(s) per soil (paper Fig. 5)")
        paths.append(_save(plt, fig, out / "fig5_mu_curves.png"))
    return paths


def _save(plt: Any, fig: Any, path: Path) -> str:
    """Lay out, write (110 dpi) and close one figure; return its path."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)


# ----------------------------------------------------------------------------- efficiency and the run report
def _vehicle_of(rec: Any) -> Any:
    from ..config import VehicleParams, load_vehicle

    p = getattr(rec, "vehicle_toml_path", None)
    return load_vehicle(p) if p is not None else VehicleParams()


def plot_efficiency(out: Path, rec: Any, arrays: dict[str, Any], truth: Truth | None) -> tuple[list[str], dict[str, Any]]:
    """The η-and-s* figure (``fig_efficiency.png``) and the run's HTML report (``report.html``).

    The replay's estimates go through the same :class:`~tractionecu.advice.engine.AdviceEngine` as
    in the service (10 Hz); with truth, the true optimum of each soil and the true η are drawn too.
    Returns the paths and the efficiency series (:func:`~tractionecu.advice.evaluate.run_advice`).
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..advice.efficiency import eta_machine, true_optimum
    from ..advice.evaluate import run_advice

    vehicle = _vehicle_of(rec)
    series = run_advice(arrays, vehicle)
    t = series["t"]
    tr = t - t[0] if len(t) else t
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    true_eta = true_s = true_e = None
    if truth is not None and len(truth.t):
        k = np.clip(np.searchsorted(truth.t, t, side="left"), 0, len(truth.t) - 1)
        w = vehicle.weight_n
        fzf = w * vehicle.static_front_fraction
        fz = np.array([fzf / 2, fzf / 2, (w - fzf) / 2, (w - fzf) / 2])
        true_eta = np.array([eta_machine(truth.mu[j], truth.slip[j], fz, truth.rho_s[j], vehicle.rho_t) for j in k])
        opt = {n: true_optimum(s["a"], s["rho_s"], vehicle.rho_t, s["soil_class"]) for n, s in truth.soils.items()}
        if opt:
            names = [truth.soil_name[j] for j in k]
            true_s = np.array([opt.get(n, (np.nan, np.nan))[0] for n in names])
            true_e = np.array([opt.get(n, (np.nan, np.nan))[1] for n in names])
    ax1.plot(tr, series["eta"], color="tab:green", lw=1.0, label="η now (estimated)")
    ax1.plot(tr, series["eta_star"], color="tab:orange", lw=1.2, label="η(s*) (identified curve)")
    if true_eta is not None:
        ax1.plot(tr, true_eta, color="black", lw=1.0, ls=":", label="η true")
    if true_e is not None:
        ax1.plot(tr, true_e, **{**TRUTH_STYLE, "label": "η(s*) true"})
    ax1.set_ylabel("traction efficiency η [-]")
    ax1.set_ylim(0.3, 1.0)
    ax1.grid(alpha=0.3)
    ax1.legend(loc="lower right", fontsize=8)
    ax2.fill_between(tr, series["s_star_lo"], series["s_star_hi"], color="tab:orange", alpha=0.25,
                     label="s* 95 % interval")
    ax2.plot(tr, series["s_star"], color="tab:orange", lw=1.2, label="s* (identified curve)")
    ax2.plot(tr, series["slip"], color="tab:blue", lw=0.8, alpha=0.8, label="slip now (load-weighted)")
    if true_s is not None:
        ax2.plot(tr, true_s, **{**TRUTH_STYLE, "label": "s* true"})
    for e in series["advice"]:
        ax2.axvline(e["t"] - t[0], color="tab:red", lw=0.8, alpha=0.6)
    ax2.set_ylabel("slip [-]")
    ax2.set_ylim(0.0, max(0.2, float(np.nanmax(series["slip"])) * 1.1 if np.isfinite(series["slip"]).any() else 0.2))
    ax2.set_xlabel("t [s]")
    ax2.grid(alpha=0.3)
    ax2.legend(loc="upper right", fontsize=8)
    fig.suptitle("Traction efficiency (paper eq. 7) and the optimal slip s*")
    paths = [_save(plt, fig, out / "fig_efficiency.png")]
    paths.append(write_report(out, rec, arrays, series, true_eta))
    return paths, series


def _png_data(path: Path) -> str:
    import base64

    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def _track_svg(rec: Any, t: np.ndarray, values: np.ndarray, label: str) -> str:
    """The GNSS track as an SVG polyline of segments coloured by ``values`` (at times ``t``)."""
    import html

    gps = getattr(rec, "gps", None)
    if gps is None or len(getattr(gps, "t", [])) < 2:
        return "<p>No GNSS track in this recording.</p>"
    ok = np.isfinite(gps.lat) & np.isfinite(gps.lon)
    if ok.sum() < 2:
        return "<p>No GNSS position in this recording.</p>"
    lat, lon, gt = gps.lat[ok], gps.lon[ok], gps.t[ok]
    lat0 = float(np.mean(lat))
    x = np.radians(lon - lon[0]) * 6371008.8 * np.cos(np.radians(lat0))
    y = np.radians(lat - lat[0]) * 6371008.8
    step = max(1, len(x) // 3000)
    x, y, gt = x[::step], y[::step], gt[::step]
    v = np.interp(gt, t, values, left=np.nan, right=np.nan) if len(t) else np.full(len(gt), np.nan)
    fin = v[np.isfinite(v)]
    v0, v1 = (float(np.percentile(fin, 2)), float(np.percentile(fin, 98))) if fin.size else (0.0, 1.0)
    span = (v1 - v0) or 1.0
    W, H, P = 720.0, 420.0, 10.0
    sx = (W - 2 * P) / max(float(np.ptp(x)), 1.0)
    sy = (H - 2 * P) / max(float(np.ptp(y)), 1.0)
    s = min(sx, sy)
    H = max(float(np.ptp(y)) * s + 2 * P, 60.0)          # as tall as the track needs
    X = P + (x - x.min()) * s
    Y = H - P - (y - y.min()) * s
    segs = []
    for i in range(len(X) - 1):
        if not np.isfinite(v[i]):
            col = "#888"
        else:
            u = min(max((v[i] - v0) / span, 0.0), 1.0)
            col = f"hsl({240 - 240 * u:.0f},80%,45%)"
        segs.append(f'<line x1="{X[i]:.1f}" y1="{Y[i]:.1f}" x2="{X[i+1]:.1f}" y2="{Y[i+1]:.1f}" stroke="{col}"/>')
    return (f'<svg viewBox="0 0 {W:.0f} {H:.0f}" width="{W:.0f}" height="{H:.0f}" stroke-width="3" '
            f'stroke-linecap="round" style="background:#f6f6f6">{"".join(segs)}</svg>'
            f"<p>{html.escape(label)}: blue {v0:.3f} … red {v1:.3f} (2–98 % of the run); grey: not given. "
            f"{float(np.ptp(x)):.0f} m × {float(np.ptp(y)):.0f} m.</p>")


def write_report(out: Path, rec: Any, arrays: dict[str, Any], series: dict[str, Any],
                 true_eta: np.ndarray | None = None) -> str:
    """``report.html``: one self-contained page (figures embedded) with the map of η and s* along the
    track, the curves (Figs. 5 and 6), efficiency over the run and the advice with its numbers."""
    import html
    import json

    def f(x: Any, d: int = 3) -> str:
        try:
            v = float(x)
        except (TypeError, ValueError):
            return "-"
        return f"{v:.{d}f}" if np.isfinite(v) else "-"

    t = series["t"]
    valid = np.isfinite(series["s_star"])
    rows = [("recording", html.escape(str(getattr(rec, "path", "")))),
            ("duration [s]", f(t[-1] - t[0], 1) if len(t) else "-"),
            ("median η now", f(np.nanmedian(series["eta"])) if np.isfinite(series["eta"]).any() else "-"),
            ("median η(s*)", f(np.nanmedian(series["eta_star"])) if valid.any() else "-"),
            ("median efficiency lost", f(np.nanmedian(series["eta_star"] - series["eta"]))
             if (valid & np.isfinite(series["eta"])).any() else "-"),
            ("median s*", f(np.nanmedian(series["s_star"])) if valid.any() else "-"),
            ("share of the run with s* given", f(valid.mean() if len(valid) else math.nan, 2)),
            ("recommendations", str(len(series["advice"])))]
    if true_eta is not None and np.isfinite(true_eta).any():
        rows.append(("median |η − η true|", f(np.nanmedian(np.abs(series["eta"] - true_eta)))))
    figs = []
    for name, cap in (("fig_efficiency.png", "Traction efficiency and the optimal slip s*"),
                      ("fig5_mu_curves.png", "Identified vs true μ(s) per soil (paper Fig. 5)"),
                      ("fig6_mu_rho.png", "Adhesion per wheel and soil rolling resistance (paper Fig. 6)")):
        p = out / name
        if p.exists():
            figs.append(f'<figure><img src="{_png_data(p)}" alt="{html.escape(cap)}"><figcaption>'
                        f'{html.escape(cap)} ({html.escape(name)})</figcaption></figure>')
    advice = "".join(
        f"<li>t = {f(e['t'] - t[0], 1)} s: {html.escape(e['text'])}<details><summary>the numbers it rests on"
        f"</summary><pre>{html.escape(json.dumps(e['evidence'], indent=1))}</pre></details></li>"
        for e in series["advice"]) or "<li>none</li>"
    body = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>tractionecu run report</title>
<style>body{{font:14px/1.4 system-ui,sans-serif;max-width:1100px;margin:1em auto;padding:0 1em}}
td,th{{padding:.1em .8em;text-align:left}} img{{max-width:100%}} figure{{margin:1em 0}}
h2{{border-bottom:1px solid #ccc}}</style></head><body>
<h1>tractionecu run report</h1>
<table>{"".join(f"<tr><th>{k}</th><td>{v}</td></tr>" for k, v in rows)}</table>
<h2>Map: traction efficiency along the track</h2>
{_track_svg(rec, t, series["eta"], "η now")}
<h2>Map: optimal slip s* along the track</h2>
{_track_svg(rec, t, series["s_star"], "s*")}
<h2>Advice</h2><ul>{advice}</ul>
<h2>Efficiency and curves</h2>
{"".join(figs)}
<p>η = κ/(κ + ρ)(1 − s), κ = μ − ρ_s, ρ = ρ_s + ρ_t (paper eq. 7), for the machine the wheels' drawbar
power over their drive power; s* maximises η on the identified μ(s) curve; its interval is two standard
errors from the curve parameters' and ρ_s's uncertainty.</p>
</body></html>
"""
    path = out / "report.html"
    path.write_text(body, encoding="utf-8")
    return str(path)
