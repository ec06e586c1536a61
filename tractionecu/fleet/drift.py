"""Drift across the fleet: per machine, how its parameters move over the season.

Series (one value with a 95 % half-width per recording):

* ``radius_scale_front`` / ``radius_scale_rear`` — the self-calibrated rolling-radius scale the replay
  reports (:mod:`tractionecu.estimation.calibration`; a tyre that wears or loses pressure rolls smaller);
* every parameter of the effects diagnosis names as ``effect.parameter`` (``torque_gain.k_front``,
  ``torque_offset.b_rear_nm``, ``wheel_radius.epsilon``, …; interval from its ``ci95``);
* ``rho_s@<field>`` — the field's soil rolling resistance from the samples the map accepted (block
  means, :func:`tractionecu.fleet.tasks.rho_s_of_field`).

Per machine and series the recordings of one date are pooled (inverse-variance weights, σ = hw/1.96);
the trend is a weighted least-squares line against the date (slope per day).  A series **moved beyond
its interval** when the pooled intervals of its first and last date do not overlap: |x_last − x_first|
> hw_first + hw_last.  A ρ_s that moves may be the soil (moisture, tillage), not the machine; the
report says so and lists it apart.
"""

from __future__ import annotations

import datetime as _dt
import math
from typing import Any

import numpy as np

Z95 = 1.959963984540054


def series_rows(recordings: Any, diagnosis: Any | None) -> list[dict[str, Any]]:
    """(machine, series, date, value, hw95, recording) rows from the recordings table (replay rows) and
    the diagnosis table (pandas DataFrames; ``diagnosis`` may be None)."""
    rows: list[dict[str, Any]] = []
    if recordings is not None and len(recordings):
        rp = recordings[(recordings["kind"] == "replay") & (recordings["status"] == "ok")]
        for r in rp.to_dict("records"):
            for axle in ("front", "rear"):
                v, hw = r.get(f"radius_scale_{axle}"), r.get(f"radius_hw95_{axle}")
                if _finite(v) and _finite(hw):
                    rows.append({"machine": r["machine"], "series": f"radius_scale_{axle}", "date": r["date"],
                                 "value": float(v), "hw95": float(hw), "recording": r["path"]})
            v, hw = r.get("rho_s_mean"), r.get("rho_s_hw95")
            if _finite(v) and _finite(hw):
                rows.append({"machine": r["machine"], "series": f"rho_s@{r.get('field') or '?'}", "date": r["date"],
                             "value": float(v), "hw95": float(hw), "recording": r["path"]})
    if diagnosis is not None and len(diagnosis):
        d = diagnosis[(diagnosis["kind"] == "effect") & (diagnosis["parameter"] != "")]
        for r in d.to_dict("records"):
            lo, hi, v = r.get("ci95_lo"), r.get("ci95_hi"), r.get("value")
            if _finite(v) and _finite(lo) and _finite(hi):
                rows.append({"machine": r["machine"], "series": f"{r['effect']}.{r['parameter']}", "date": r["date"],
                             "value": float(v), "hw95": max(float(hi) - float(v), float(v) - float(lo)),
                             "recording": r["recording"]})
    return rows


def _finite(x: Any) -> bool:
    try:
        return x is not None and math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


def _pool(values: np.ndarray, hw: np.ndarray) -> tuple[float, float]:
    """Inverse-variance pooled value and its 95 % half-width."""
    s = np.maximum(hw / Z95, 1e-300)
    w = 1.0 / s**2
    return float(np.sum(w * values) / np.sum(w)), float(Z95 / math.sqrt(np.sum(w)))


def _day(d: str) -> float:
    try:
        return float(_dt.date.fromisoformat(d).toordinal())
    except ValueError:
        return math.nan


def drift_table(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per machine and series: dates, first and last pooled value with half-width, slope per day
    and ``moved`` (module doc)."""
    out = []
    keys = sorted({(r["machine"], r["series"]) for r in rows})
    for machine, series in keys:
        rs = [r for r in rows if r["machine"] == machine and r["series"] == series]
        dates = sorted({r["date"] for r in rs})
        pooled = []
        for d in dates:
            sel = [r for r in rs if r["date"] == d]
            pooled.append((d, *_pool(np.array([r["value"] for r in sel]), np.array([r["hw95"] for r in sel]))))
        (d0, v0, h0), (d1, v1, h1) = pooled[0], pooled[-1]
        x = np.array([_day(d) for d, _, _ in pooled])
        y = np.array([v for _, v, _ in pooled])
        w = 1.0 / np.maximum(np.array([h for _, _, h in pooled]) / Z95, 1e-300) ** 2
        slope = math.nan
        if len(pooled) >= 2 and np.all(np.isfinite(x)):
            xm = np.sum(w * x) / np.sum(w)
            den = np.sum(w * (x - xm) ** 2)
            if den > 0:
                slope = float(np.sum(w * (x - xm) * (y - np.sum(w * y) / np.sum(w))) / den)
        out.append({"machine": machine, "series": series, "recordings": len(rs), "dates": len(dates),
                    "first_date": d0, "first_value": v0, "first_hw95": h0, "last_date": d1, "last_value": v1,
                    "last_hw95": h1, "change": v1 - v0, "slope_per_day": slope,
                    "moved": bool(len(pooled) >= 2 and abs(v1 - v0) > h0 + h1)})
    return out


def report_markdown(table: list[dict[str, Any]]) -> str:
    """The short drift report: the machines whose parameters moved beyond their interval, then every
    series."""
    moved = [r for r in table if r["moved"] and not r["series"].startswith("rho_s@")]
    soil = [r for r in table if r["moved"] and r["series"].startswith("rho_s@")]
    lines = ["# Drift across the fleet", ""]
    if moved:
        names = sorted({r["machine"] for r in moved})
        lines.append(f"Machines whose parameters moved beyond their interval: {', '.join(names)}.")
        lines.append("")
        for r in moved:
            lines.append(f"- **{r['machine']}** `{r['series']}`: {r['first_value']:.4g} ± {r['first_hw95']:.2g} "
                         f"({r['first_date']}) → {r['last_value']:.4g} ± {r['last_hw95']:.2g} ({r['last_date']})")
    else:
        lines.append("No machine's parameters moved beyond their interval.")
    if soil:
        lines += ["", "Fields whose ρ_s moved (the soil may have changed, not the machine):"]
        for r in soil:
            lines.append(f"- {r['machine']} `{r['series']}`: {r['first_value']:.4g} ± {r['first_hw95']:.2g} "
                         f"({r['first_date']}) → {r['last_value']:.4g} ± {r['last_hw95']:.2g} ({r['last_date']})")
    lines += ["", "| machine | series | recordings | first (date) | last (date) | slope per day | moved |",
              "|---|---|---|---|---|---|---|"]
    for r in table:
        sl = "" if math.isnan(r["slope_per_day"]) else f"{r['slope_per_day']:.3g}"
        lines.append(f"| {r['machine']} | {r['series']} | {r['recordings']} | {r['first_value']:.4g} ± "
                     f"{r['first_hw95']:.2g} ({r['first_date']}) | {r['last_value']:.4g} ± {r['last_hw95']:.2g} "
                     f"({r['last_date']}) | {sl} | {'yes' if r['moved'] else 'no'} |")
    return "\n".join(lines) + "\n"


__all__ = ["drift_table", "report_markdown", "series_rows"]
