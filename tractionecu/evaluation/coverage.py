"""Does the reported uncertainty hold the truth?  Coverage of μ and ρ_s, and sensor errors to test it.

:func:`coverage` scores the reported standard uncertainties of a run
(``sigma_mu``, ``sigma_rho_s`` of :class:`~tractionecu.estimation.estimator.Estimate`)
against simulation truth:

``mu_within_2sigma``
    share of (valid sample, wheel) pairs with |μ̂ − μ| ≤ 2 σ_μ, from the first
    valid estimate on (samples not ``valid`` are left out: they claim nothing);
``rho_within_2sigma``
    the same for ρ_s;
``*_filter_only``
    the same with the filter's own √P (``P_diag``), for comparison;
``mu_mean_abs_rel_error``, ``rho_s_mean_abs_error``
    as in :mod:`.scoring` (|μ| ≥ 0.05), over the same valid samples;
``radius_scale``, ``radius_halfwidth``, ``radius_applied``
    the rolling-radius calibration at the end of the run (front, rear).

:func:`biased_trace` puts sensor errors inside tolerance on a truth trace
of the project's simulator (a gain and an offset per drive torque, a zero
offset and a gain of each load pin, each drawn uniformly within the
:class:`~tractionecu.config.SensorSpec` tolerances), for use until a truth
model with its own sensor errors is available; GNSS latency and a rolling
radius error are the simulator's effects ``gps_latency`` and
``wheel_radius``.  The draws use the configured tolerances, so a run with
them tests the propagation (:mod:`tractionecu.estimation.uncertainty`),
not the tolerance figures themselves.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..config import SensorSpec
from .scoring import Truth


def coverage(arrays: dict[str, Any], truth: Truth, *, k: float = 2.0, mu_rel_floor: float = 0.05) -> dict[str, Any]:
    """Coverage of the reported k·σ bands of μ and ρ_s against truth (module doc).

    ``arrays``: ``t`` (n,), ``mu``, ``sigma_mu`` (n, 4), ``rho_s``, ``sigma_rho_s`` (n,), ``P_diag`` (n, 10),
    ``valid`` (n,); optional ``radius_scale``, ``radius_halfwidth``, ``radius_applied`` (n, 2).
    """
    t = np.asarray(arrays["t"], dtype=float)
    kk = np.clip(np.searchsorted(truth.t, t + 1e-9, side="right") - 1, 0, len(truth.t) - 1)
    valid = np.asarray(arrays["valid"], dtype=bool)
    out: dict[str, Any] = {}
    if not valid.any():
        out["error"] = "the estimator never converged"
        return out
    mu_e = np.asarray(arrays["mu"], dtype=float)[valid]
    mu_t = truth.mu[kk][valid]
    s_mu = np.asarray(arrays["sigma_mu"], dtype=float)[valid]
    p_mu = np.sqrt(np.asarray(arrays["P_diag"], dtype=float)[valid][:, 5:9])
    rho_e = np.asarray(arrays["rho_s"], dtype=float)[valid]
    rho_t = truth.rho_s_paper[kk][valid]         # eq. 8's ρ_s (.scoring module doc)
    s_rho = np.asarray(arrays["sigma_rho_s"], dtype=float)[valid]
    p_rho = np.sqrt(np.asarray(arrays["P_diag"], dtype=float)[valid][:, 9])
    err = np.abs(mu_e - mu_t)
    out["samples"] = int(valid.sum())
    out["mu_within_2sigma"] = float(np.mean(err <= k * s_mu))
    out["mu_within_2sigma_filter_only"] = float(np.mean(err <= k * p_mu))
    out["mu_within_2sigma_per_wheel"] = np.mean(err <= k * s_mu, axis=0).tolist()
    rerr = np.abs(rho_e - rho_t)
    out["rho_within_2sigma"] = float(np.mean(rerr <= k * s_rho))
    out["rho_within_2sigma_filter_only"] = float(np.mean(rerr <= k * p_rho))
    big = np.abs(mu_t) >= mu_rel_floor
    out["mu_mean_abs_rel_error"] = float(np.mean(err[big] / np.abs(mu_t[big]))) if big.any() else math.nan
    out["rho_s_mean_abs_error"] = float(np.mean(rerr))
    out["sigma_mu_mean"] = float(np.mean(s_mu))
    out["sigma_mu_filter_mean"] = float(np.mean(p_mu))
    out["sigma_rho_mean"] = float(np.mean(s_rho))
    for key in ("radius_scale", "radius_halfwidth", "radius_applied"):
        if key in arrays:
            out[key] = np.asarray(arrays[key], dtype=float)[-1].tolist()
    return out


def biased_trace(tr: Any, sensors: SensorSpec, rng: np.random.Generator) -> tuple[Any, dict[str, Any]]:
    """A copy of truth trace ``tr`` whose measured inputs carry errors inside the sensor tolerances.

    Drive torque i: M_meas = (1 + g_i) M + o_i, g_i ~ U(±torque_gain_tol_rel), o_i ~ U(±torque_offset_tol_nm);
    front-axle load and draft: F_meas = (1 + g) F + o with the load pins' gain and offset tolerances.
    Returns the trace (``md``, ``fzf``, ``fdx`` replaced) and the draws.
    """
    sp = sensors
    g = rng.uniform(-sp.torque_gain_tol_rel, sp.torque_gain_tol_rel, 4)
    o = rng.uniform(-sp.torque_offset_tol_nm, sp.torque_offset_tol_nm, 4)
    ag = rng.uniform(-sp.axle_gain_tol_rel, sp.axle_gain_tol_rel)
    ao = rng.uniform(-sp.axle_offset_tol_n, sp.axle_offset_tol_n)
    dg = rng.uniform(-sp.draft_gain_tol_rel, sp.draft_gain_tol_rel)
    do = rng.uniform(-sp.draft_offset_tol_n, sp.draft_offset_tol_n)
    md = tr.md * (1.0 + g) + o
    draws = {"torque_gain": g.tolist(), "torque_offset_nm": o.tolist(), "axle_gain": float(ag),
             "axle_offset_n": float(ao), "draft_gain": float(dg), "draft_offset_n": float(do)}
    return dataclasses.replace(tr, md=md, fzf=tr.fzf * (1.0 + ag) + ao, fdx=tr.fdx * (1.0 + dg) + do), draws


def radius_scenario(eps: float, seed: int = 0) -> Any:
    """A run for the rolling-radius calibration on the project's simulator: 130 m of transport at 3 m/s with
    the implement raised (low slip), then 70 m of work at 2.5 m/s on the paper's firm stubble; the tyres roll
    (1 + ``eps``) × the nominal radius (effect ``wheel_radius``)."""
    from dataclasses import replace

    from ..sim.field import Field
    from ..sim.plan import straight
    from ..sim.scenarios import PAPER_SOILS
    from ..sim.simulator import Scenario

    plan = straight(0.0, 10.0, 0.0, 200.0, 2.5)
    d = plan.s
    plan = replace(plan, work=(d > 130.0) & (d < plan.length - 3.0), v_target=np.where(d < 130.0, 3.0, 2.5))
    return Scenario("transport-then-work", Field([PAPER_SOILS[0]]), plan, seed=seed,
                    effects={"wheel_radius": {"epsilon": eps}})


def work_errors(arrays: dict[str, Any], truth: Truth, mu_work: float = 0.2) -> dict[str, float]:
    """Slip mean absolute error and μ mean absolute relative error over the valid samples in work
    (mean true μ above ``mu_work``)."""
    t = np.asarray(arrays["t"], dtype=float)
    k = np.clip(np.searchsorted(truth.t, t + 1e-9, side="right") - 1, 0, len(truth.t) - 1)
    mu_t = truth.mu[k]
    work = np.asarray(arrays["valid"], dtype=bool) & (mu_t.mean(axis=1) > mu_work)
    if not work.any():
        return {"work_samples": 0, "slip_mae": math.nan, "mu_rel_error": math.nan}
    return {"work_samples": int(work.sum()),
            "slip_mae": float(np.mean(np.abs(arrays["slip"][work] - truth.slip[k][work]))),
            "mu_rel_error": float(np.mean(np.abs(arrays["mu"][work] - mu_t[work]) / np.abs(mu_t[work])))}
