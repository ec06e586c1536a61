"""Efficiency and advice over a replay, and their score against a simulation's truth.

:func:`run_advice` feeds a replay's per-step arrays (``pipeline.replay``) at
10 Hz into an :class:`~.engine.AdviceEngine`, as the service does, and keeps
the series (η, s* and its interval, η*, flags) and every recommendation
given.  :func:`score_against_truth` compares them, soil by soil, with the
optimum of the true curve (``truth.toml``: class, a, ρ_s of each soil) and
with the true η (eq. 7 from the true μ and slip of ``truth.csv``):

* ``s_star_err``: median of the reported s* minus the true optimum [-];
* ``eta_star_err``: median of the reported η(s*) minus the true η(s*) [-];
* ``eta_err``: median of the reported η minus the true η at the same time [-].

Samples within ``settle_s`` of a soil change are left out (the curve's
smoothing needs that long to follow a new soil).
"""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np

from .efficiency import eta_machine, true_optimum
from .engine import AdviceEngine
from .rules import AdviceSettings


def run_advice(arrays: dict[str, Any], vehicle: Any, settings: AdviceSettings | None = None,
               every: int = 10) -> dict[str, Any]:
    """Feed every ``every``-th estimate of a replay to an :class:`AdviceEngine`; series and advice."""
    eng = AdviceEngine(vehicle, settings)
    t = np.asarray(arrays["t"], dtype=float)
    idx = np.arange(0, len(t), every)
    keys = ("eta", "eta_front", "eta_rear", "eta_star", "s_star", "s_star_lo", "s_star_hi", "slip", "pull_n",
            "pull_at_s_star_n")
    out: dict[str, Any] = {k: np.full(len(idx), math.nan) for k in keys}
    out["t"] = t[idx]
    out["flags"] = np.zeros(len(idx), dtype=np.int64)
    events: list[dict[str, Any]] = []
    active: set[str] = set()
    cls = arrays["soil_class"]
    curves = arrays.get("curve")
    for j, k in enumerate(idx.tolist()):
        e = SimpleNamespace(t=float(t[k]), mu=arrays["mu"][k], slip=arrays["slip"][k], rho_s=float(arrays["rho_s"][k]),
                            v=float(arrays["v"][k]), P_diag=arrays["P_diag"][k], a=float(arrays["a"][k]),
                            soil_class=str(cls[k]), status=int(arrays["status"][k]), valid=bool(arrays["valid"][k]),
                            curve=None if curves is None else curves[k])
        rep = eng.feed(e)
        for name in keys:
            out[name][j] = getattr(rep, name)
        out["flags"][j] = rep.flags
        now = {r.kind for r in eng.advice}
        for r in eng.advice:
            if r.kind not in active:
                events.append({"t": float(t[k]), **r.as_dict()})
        active = now
    out["advice"] = events
    return out


def score_against_truth(series: dict[str, Any], truth: Any, vehicle: Any, settle_s: float = 10.0) -> dict[str, Any]:
    """Per-soil errors of s*, η(s*) and η against the truth (module doc)."""
    t = series["t"]
    k = np.clip(np.searchsorted(truth.t, t, side="left"), 0, len(truth.t) - 1)
    soil = np.asarray(truth.soil_id)[k]
    names = [truth.soil_name[i] for i in k.tolist()]
    change_t = truth.t[np.flatnonzero(np.diff(truth.soil_id)) + 1] if len(truth.t) > 1 else np.array([])
    settled = np.ones(len(t), dtype=bool)
    for tc in change_t.tolist():
        settled &= ~((t >= tc) & (t < tc + settle_s))
    w = vehicle.weight_n
    out: dict[str, Any] = {}
    for sid in sorted(set(soil.tolist())):
        sel = (soil == sid) & settled & (np.asarray(truth.v)[k] > 1.0)
        if not sel.any():
            continue
        name = names[int(np.flatnonzero(soil == sid)[0])]
        info = truth.soils.get(name)
        if info is None:
            continue
        s_true, e_true = true_optimum(info["a"], info["rho_s"], vehicle.rho_t, info["soil_class"])
        eta_true = np.full(len(t), math.nan)
        for j in np.flatnonzero(sel).tolist():
            kk = k[j]
            fzf = w * vehicle.static_front_fraction
            fz = np.array([fzf / 2, fzf / 2, (w - fzf) / 2, (w - fzf) / 2])
            eta_true[j] = eta_machine(truth.mu[kk], truth.slip[kk], fz, truth.rho_s[kk], vehicle.rho_t)
        s_est = series["s_star"][sel]
        ok = np.isfinite(s_est)
        de = (series["eta"] - eta_true)[sel]
        out[name] = {
            "s_star_true": s_true, "eta_star_true": e_true,
            "s_star": float(np.median(s_est[ok])) if ok.any() else math.nan,
            "s_star_err": float(np.median(s_est[ok]) - s_true) if ok.any() else math.nan,
            "eta_star_err": float(np.median(series["eta_star"][sel][ok]) - e_true) if ok.any() else math.nan,
            "eta_err": float(np.nanmedian(de)) if np.isfinite(de).any() else math.nan,
            "eta_abs_err_p95": float(np.nanpercentile(np.abs(de), 95)) if np.isfinite(de).any() else math.nan,
            "s_star_valid_share": float(ok.mean()),
            "samples": int(sel.sum()),
        }
    return out
