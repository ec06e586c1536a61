"""Scorecard of a machine-level run (:mod:`tractionecu.estimation.machine`) against simulation truth.

The machine-level estimator claims one adhesion for the machine, μ = ΣF_h / ΣF_z, so it is scored
against that: the truth's per-wheel μ_i weighted by the wheel loads F_z,i of ``truth.csv`` (columns
``fz_FL..RR``; a truth without them: front wheels F_zf/2, rear (ΣF_z − F_zf)/2 with ΣF_z the weight of
the recording's vehicle).  Every other figure is :func:`~.scoring.scorecard`'s on that μ: the mean
absolute relative error, ρ_s, the μ(s) curve's R² per soil, the re-convergence.  Added:

ρ_s is compared with eq. 8's (:attr:`~.scoring.Truth.rho_s_paper`: the rolling-resistance force over m g,
as the machine-level filter's state; the physical truth file's ρ_s is per unit of wheel load m g + F_dx tan β).

Population: the μ and ρ_s errors are over the estimates the product reports as **valid** (``valid``: no
invalid status bit, in particular not ``machine_mu_unsupported`` -- gear shift, front axle decoupled, low
torque -- and not ``not_converged``), truth μ ≥ ``mu_rel_floor`` for the relative error; the share of the
steps that are valid is given beside them, and the error over every step after the first convergence
(valid or not) as well, so that a figure is never read without its population:

``mu_population``
    the population of ``mu_mean_abs_rel_error`` in words.
``valid_fraction``
    share of the steps after the first convergence that are valid.
``mu_mean_abs_rel_error_all``, ``mu_mean_abs_error_all``, ``rho_s_mean_abs_error_all``
    the same errors over every step after the first convergence.
``level``
    ``"machine"``.
``rho_s_reported_fraction``
    share of the steps that report a number for ρ_s (0 without a draft sensor: ρ_s is never reported).
``draft_not_separated_fraction``
    share of the steps flagged ``rho_s_and_draft_not_separated``.
"""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from ..config import G
from ..estimation.estimator import DRAFT_NOT_SEPARATED, MACHINE_LEVEL
from ..model.vehicle import WHEELS
from .scoring import Truth, scorecard

__all__ = ["is_machine_level", "machine_mu_truth", "machine_scorecard"]


def is_machine_level(arrays: dict[str, Any]) -> bool:
    """True when the run's estimates carry the machine-level status bit."""
    st = np.asarray(arrays.get("status", []), dtype=np.int64)
    return bool(st.size and np.any(st & MACHINE_LEVEL))


def machine_mu_truth(truth: Truth, csv_path: str | Path, mass_kg: float) -> np.ndarray:
    """ΣF_h/ΣF_z of the truth (module doc), one value per truth row."""
    with open(csv_path, newline="", encoding="utf-8") as fh:
        head = next(csv.reader(fh))
    fz_cols = [f"fz_{w}" for w in WHEELS]
    if all(c in head for c in fz_cols):
        fz = np.loadtxt(csv_path, delimiter=",", skiprows=1, usecols=[head.index(c) for c in fz_cols],
                        ndmin=2, quotechar='"', encoding="utf-8")
    else:
        fzf = np.loadtxt(csv_path, delimiter=",", skiprows=1, usecols=[head.index("fzf")], ndmin=1,
                         quotechar='"', encoding="utf-8")
        rear = 0.5 * (mass_kg * G - fzf)
        fz = np.column_stack([0.5 * fzf, 0.5 * fzf, rear, rear])
    return (truth.mu * fz).sum(axis=1) / np.maximum(fz.sum(axis=1), 1e-9)


def machine_scorecard(arrays: dict[str, Any], truth: Truth, csv_path: str | Path, mass_kg: float) -> dict[str, Any]:
    """The machine-level scorecard (module doc)."""
    mu_m = machine_mu_truth(truth, csv_path, mass_kg)
    sc = scorecard(arrays, dataclasses.replace(truth, mu=np.repeat(mu_m[:, None], 4, axis=1)))
    sc["level"] = "machine"
    if "error" not in sc:
        t = np.asarray(arrays["t"], dtype=float)
        valid = np.asarray(arrays["valid"], dtype=bool)
        i0 = int(np.argmax(valid))
        k = np.clip(np.searchsorted(truth.t, t + 1e-9, side="right") - 1, 0, len(truth.t) - 1)
        mu_t = mu_m[k]
        mu_e = np.asarray(arrays["mu"], dtype=float)[:, 2]          # the same μ on every wheel
        err = np.abs(mu_e - mu_t)
        floor = sc["mu_rel_floor"]
        after = np.arange(len(t)) >= i0
        m = valid & after & (np.abs(mu_t) >= floor)
        for key in ("mu_mean_abs_rel_error", "mu_mean_abs_error", "rho_s_mean_abs_error"):
            sc[key + "_all"] = sc[key]
        sc["mu_mean_abs_rel_error"] = float(np.mean(err[m] / np.abs(mu_t[m]))) if m.any() else float("nan")
        sc["mu_mean_abs_error"] = float(np.mean(err[valid & after]))
        rho_e = np.asarray(arrays["rho_s"], dtype=float)
        mr = valid & after & np.isfinite(rho_e)
        rho_t = truth.rho_s_paper[k]                                  # eq. 8's: resistance over m g
        sc["rho_s_mean_abs_error"] = (float(np.mean(np.abs(rho_e[mr] - rho_t[mr]))) if mr.any()
                                      else float("nan"))
        sc["valid_fraction"] = float(valid[after].mean())
        sc["mu_population"] = (f"valid estimates after the first convergence ({100 * sc['valid_fraction']:.1f} % "
                               f"of those steps), truth mu >= {floor:g}")
    rho = np.asarray(arrays["rho_s"], dtype=float)
    st = np.asarray(arrays["status"], dtype=np.int64)
    sc["rho_s_reported_fraction"] = float(np.isfinite(rho).mean()) if rho.size else 0.0
    sc["draft_not_separated_fraction"] = float(((st & DRAFT_NOT_SEPARATED) != 0).mean()) if st.size else 0.0
    return sc
