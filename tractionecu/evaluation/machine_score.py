"""Scorecard of a machine-level run (:mod:`tractionecu.estimation.machine`) against simulation truth.

The machine-level estimator claims one adhesion for the machine, μ = ΣF_h / ΣF_z, so it is scored
against that: the truth's per-wheel μ_i weighted by the wheel loads F_z,i of ``truth.csv`` (columns
``fz_FL..RR``; a truth without them: front wheels F_zf/2, rear (ΣF_z − F_zf)/2 with ΣF_z the weight of
the recording's vehicle).  Every other figure is :func:`~.scoring.scorecard`'s on that μ: the mean
absolute relative error, ρ_s, the μ(s) curve's R² per soil, the re-convergence.  Added:

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
    rho = np.asarray(arrays["rho_s"], dtype=float)
    st = np.asarray(arrays["status"], dtype=np.int64)
    sc["rho_s_reported_fraction"] = float(np.isfinite(rho).mean()) if rho.size else 0.0
    sc["draft_not_separated_fraction"] = float(((st & DRAFT_NOT_SEPARATED) != 0).mean()) if st.size else 0.0
    return sc
