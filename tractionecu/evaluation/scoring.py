"""Scorecard of an estimator run against simulation truth (issue 3 metrics; paper section 5).

Definitions (all over the estimator's fixed-rate output; the truth sample
used for an estimate at time t is the latest truth sample at or before t):

``mu_mean_abs_rel_error``
    mean over wheels and time of |μ̂ − μ|/|μ|, from the first convergence on
    (first estimate with ``valid``).  Relative error is undefined at μ ≈ 0
    (coasting, braking to the headland speed), so samples with
    |μ| < ``mu_rel_floor`` are left out; their share is reported as
    ``mu_rel_excluded_fraction`` and the plain ``mu_mean_abs_error`` covers
    every sample.
``mu_mean_rel_bias``, ``mu_mean_bias``
    the signed mean of (μ̂ − μ)/|μ| over the samples of ``mu_mean_abs_rel_error``,
    and the signed mean of μ̂ − μ per wheel (4,) over every sample after the
    first convergence: what of the error is a bias rather than noise or lag.
``rho_s_mean_abs_error``
    mean |ρ̂_s − ρ_s| from the first convergence on, with ρ_s as eq. 8 has
    it: the soil's rolling-resistance force over the weight m g.  The
    physical truth's ``truth.csv`` writes ρ_s per unit of wheel load,
    Σρ_s,i F_z,i / ΣF_z,i (``tractionecu.sim.physical``), and ΣF_z =
    m g cos θ + F_dx tan β carries the vertical part of the implement's pull;
    :func:`read_truth` turns it into eq. 8's, ρ_s ΣF_z/(ΣF_z − F_dx tan β)
    (``Truth.rho_s_eq8``; cos θ ≈ 1, within 0.05 % of ρ_s on grades up to
    3 %).  The paper truth's ρ_s is eq. 8's already.
``r2_mu_curve``
    per soil name (the soil under the GPS antenna): the paper's "average
    representative μ(s) characteristic" a̅·g_class(s), a̅ the mean identified
    a while on that soil (after the first convergence) and the class the most
    frequently reported one, against the true a·g_true(s); R² = 1 − SS_res/SS_tot
    over s ∈ [0, 0.4] (401 points).  Where most of the soil's samples report a
    fitted shape (curve path ``shape:<form>``), the mean of those curves, and a
    tabulated true curve where the truth has one (:mod:`.curve_score`).
``slip_span``
    per soil name, the 5–95 % span of its true slips in work (:func:`slip_spans`): the R² target applies
    from ``R2_TARGET_SLIP_SPAN`` on.
``reconvergence_s``
    worst over soil changes (after the first convergence) of the time from
    the change until every wheel's |μ̂ − μ|/|μ| < 5 % and stays so for
    ``hold_s``; 0 when it never left the band.  Samples under the floor
    count as within the band.
``nis_within_95``
    share of updates whose NIS lies inside the two-sided 95 % χ² interval of
    its degrees of freedom.
"""

from __future__ import annotations

import csv
import math
import tomllib
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from ..model.vehicle import WHEELS
from .curve_score import identified_curve, true_curve

S_GRID = np.linspace(0.0, 0.4, 401)
"""Slip grid of the R² comparison [-] (issue 3: 0–0.4)."""


@dataclass
class Truth:
    """Truth columns of ``truth.csv`` plus the soil table of ``truth.toml``."""

    t: NDArray[np.float64]
    mu: NDArray[np.float64]
    rho_s: NDArray[np.float64]
    a: NDArray[np.float64]
    soil_id: NDArray[np.int64]
    soil_name: list[str]
    slip: NDArray[np.float64]
    v: NDArray[np.float64]
    soils: dict[str, dict[str, Any]]
    """name -> {"soil_class": str, "a": float, "rho_s": float} (and ``mu_curve_s``, ``mu_curve``: a
    tabulated true μ(s) for a truth model whose curve is none of the classes)."""
    rho_s_eq8: NDArray[np.float64] | None = None
    """ρ_s as eq. 8 has it (rolling-resistance force over m g) where ``rho_s`` is not (module doc); None: the same."""

    @property
    def rho_s_paper(self) -> NDArray[np.float64]:
        """ρ_s in eq. 8's terms (module doc): ``rho_s_eq8`` when the truth file's ρ_s is per unit of wheel load."""
        return self.rho_s if self.rho_s_eq8 is None else self.rho_s_eq8


def read_truth(csv_path: str | Path, toml_path: str | Path | None = None) -> Truth:
    """Read ``truth.csv`` (and ``truth.toml`` for the soil classes, if present)."""
    with open(csv_path, newline="", encoding="utf-8") as fh:
        head = next(csv.reader(fh))
    col = {k: i for i, k in enumerate(head)}
    numeric = ["t", *(f"mu_{w}" for w in WHEELS), "rho_s", "a", "soil_id", *(f"slip_{w}" for w in WHEELS), "v"]
    missing = [k for k in [*numeric, "soil_name"] if k not in col]
    if missing:
        raise ValueError(f"{Path(csv_path).name} is not the truth file of tractionecu simulate (no column "
                         + ", ".join(missing) + ")")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)          # a truth file with no rows
        # numpy's reader (quoted fields as in the csv module); floats parse as float() does
        vals = np.loadtxt(csv_path, delimiter=",", skiprows=1, usecols=[col[k] for k in numeric], dtype=float,
                          quotechar='"', encoding="utf-8", ndmin=2)
        names = np.loadtxt(csv_path, delimiter=",", skiprows=1, usecols=[col["soil_name"]], dtype=str,
                           quotechar='"', encoding="utf-8", ndmin=1).tolist()
    c = {k: vals[:, i].copy() for i, k in enumerate(numeric)}

    soils: dict[str, dict[str, Any]] = {}
    rho_eq8 = None
    if toml_path is not None and Path(toml_path).is_file():
        data = tomllib.loads(Path(toml_path).read_text(encoding="utf-8"))
        pull = data.get("physical", {}).get("hitch", {}).get("pull_angle_deg")
        fz_cols = [f"fz_{w}" for w in WHEELS]
        if pull is not None and all(k in col for k in fz_cols) and "fdx" in col:
            # the physical truth's ρ_s is per unit of wheel load; eq. 8's is per unit of weight (module doc)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)
                ld = np.loadtxt(csv_path, delimiter=",", skiprows=1, usecols=[col[k] for k in fz_cols + ["fdx"]],
                                dtype=float, quotechar='"', encoding="utf-8", ndmin=2)
            sum_fz = ld[:, :4].sum(axis=1)
            weight = sum_fz - ld[:, 4] * math.tan(math.radians(float(pull)))
            rho_eq8 = c["rho_s"] * sum_fz / np.where(weight > 0.0, weight, np.nan)
        for s in data.get("soils", []):
            soils[s["name"]] = {"soil_class": s.get("soil_class", "stubble"), "a": float(s["a"]), "rho_s": float(s["rho_s"]),
                                **{k: s[k] for k in ("mu_curve_s", "mu_curve") if k in s}}   # tabulated true μ(s)
    return Truth(
        t=c["t"], mu=np.column_stack([c[f"mu_{w}"] for w in WHEELS]), rho_s=c["rho_s"], a=c["a"],
        soil_id=c["soil_id"].astype(np.int64), soil_name=names,
        slip=np.column_stack([c[f"slip_{w}"] for w in WHEELS]), v=c["v"], soils=soils, rho_s_eq8=rho_eq8)


def r_squared(y_hat: NDArray[np.float64], y: NDArray[np.float64]) -> float:
    """Coefficient of determination of y_hat against y [-]."""
    ss_res = float(np.sum((y - y_hat) ** 2))
    ss_tot = float(np.sum((y - np.mean(y)) ** 2))
    return 1.0 - ss_res / ss_tot if ss_tot > 0 else math.nan


R2_TARGET_SLIP_SPAN = 0.04
"""Issue 13's μ(s) target (R² ≥ 0.98) holds for a soil whose true slips in work span at least this much [-]
(5–95 %, :func:`slip_spans`): over a narrower span the data hold one working point, not a curve."""


def slip_spans(truth: Truth, ranges: bool = False) -> dict[str, Any]:
    """Per soil name, the 5–95 % span of the true slips while working (|μ| ≥ 0.15, |v| ≥ 0.5 m/s) [-], NaN
    where the soil has no such sample; with ``ranges`` the (5 %, 95 %) slips themselves."""
    out: dict[str, Any] = {}
    names = np.array(truth.soil_name, dtype=object)
    for name in sorted(set(truth.soil_name)):
        m = (names == name)[:, None] & (np.abs(truth.mu) >= 0.15) & (np.abs(truth.v)[:, None] >= 0.5)
        s = np.abs(truth.slip[m])
        lo, hi = (float(np.percentile(s, 5)), float(np.percentile(s, 95))) if s.size else (math.nan, math.nan)
        out[name] = (lo, hi) if ranges else hi - lo
    return out


def nis_bounds(dof: NDArray[np.int64], p: float = 0.95) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Two-sided χ² interval [lo, hi] of probability p for each degree of freedom."""
    lo = chi2.ppf((1 - p) / 2, np.maximum(dof, 1))
    hi = chi2.ppf(1 - (1 - p) / 2, np.maximum(dof, 1))
    return lo, hi


def scorecard(est: dict[str, NDArray[Any]], truth: Truth, *, mu_rel_floor: float = 0.05, band: float = 0.05,
              hold_s: float = 1.0) -> dict[str, Any]:
    """Compute the scorecard from estimator output arrays (see module doc).

    ``est`` keys: ``t`` (n,), ``mu`` (n, 4), ``rho_s``, ``a``, ``soil_class`` (list of str),
    ``nis``, ``nis_dof``, ``valid`` (n,).
    """
    t = est["t"]
    k = np.clip(np.searchsorted(truth.t, t + 1e-9, side="right") - 1, 0, len(truth.t) - 1)
    mu_t = truth.mu[k]
    rho_t = truth.rho_s_paper[k]
    soil = truth.soil_id[k]
    mu_e = est["mu"]
    valid = np.asarray(est["valid"], dtype=bool)
    out: dict[str, Any] = {}
    if not valid.any():
        out["error"] = "the estimator never converged"
        return out
    i0 = int(np.argmax(valid))
    out["t_first_convergence_s"] = float(t[i0] - t[0])
    sl = slice(i0, None)
    err = np.abs(mu_e[sl] - mu_t[sl])
    big = np.abs(mu_t[sl]) >= mu_rel_floor
    rel = np.where(big, err / np.maximum(np.abs(mu_t[sl]), 1e-12), np.nan)
    out["mu_mean_abs_rel_error"] = float(np.nanmean(rel))
    out["mu_rel_floor"] = mu_rel_floor
    out["mu_rel_excluded_fraction"] = float(1.0 - big.mean())
    # means over the steps with an estimate: a step of a filter restarting after a gap holds NaN, and one NaN
    # made every plain mean NaN ("no rho_s reported" for a run with 3 NaN steps in 3701)
    out["mu_mean_abs_error"] = float(np.nanmean(err))
    sgn = mu_e[sl] - mu_t[sl]
    out["mu_mean_rel_bias"] = float(np.nanmean(np.where(big, sgn / np.maximum(np.abs(mu_t[sl]), 1e-12), np.nan)))
    out["mu_mean_bias"] = [float(b) for b in np.nanmean(sgn, axis=0)]
    rho_err = np.abs(est["rho_s"][sl] - rho_t[sl])
    out["rho_s_mean_abs_error"] = float(np.nanmean(rho_err)) if np.isfinite(rho_err).any() else math.nan
    out["steps_without_estimate"] = int(np.sum(~np.isfinite(mu_e[sl]).all(axis=1)))

    # μ(s) curve per soil (paper Fig. 5 and its R²)
    r2: dict[str, float] = {}
    curves: dict[str, dict[str, Any]] = {}
    names = truth.soil_name
    id_to_name = {int(truth.soil_id[j]): names[j] for j in range(len(names))}
    a_e = est["a"]
    cls_e = est["soil_class"]
    for sid in sorted(set(soil[sl].tolist())):
        name = id_to_name[sid]
        m = (soil == sid) & valid & np.isfinite(a_e)
        m[:i0] = False
        info = truth.soils.get(name, {"soil_class": "stubble", "a": float(np.median(truth.a[truth.soil_id == sid]))})
        mu_true_curve = true_curve(info, S_GRID)
        if not m.any():
            r2[name] = math.nan
            continue
        # the class path's a̅·g_class(s), or the mean fitted shape on the shape path (.curve_score)
        mu_id_curve, ident = identified_curve(np.flatnonzero(m), a_e, cls_e, est.get("curve"), S_GRID)
        r2[name] = r_squared(mu_id_curve, mu_true_curve)
        curves[name] = {**ident, "a_true": info["a"], "class_true": info["soil_class"]}
    out["r2_mu_curve"] = r2
    spans = slip_spans(truth)
    out["slip_span"] = {name: spans.get(name, math.nan) for name in r2}
    out["curves"] = curves

    # reconvergence after soil changes
    rel_all = np.abs(mu_e - mu_t) / np.maximum(np.abs(mu_t), 1e-12)
    inband = np.all((rel_all < band) | (np.abs(mu_t) < mu_rel_floor), axis=1)
    changes = np.flatnonzero(np.diff(soil) != 0) + 1
    changes = changes[changes > i0]
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.01
    hold = max(1, int(round(hold_s / dt)))
    worst = 0.0
    per_change = []
    # run-length of "in band from here on" (number of consecutive in-band samples starting at i)
    run = np.zeros(len(t) + 1, dtype=np.int64)
    for i in range(len(t) - 1, -1, -1):
        run[i] = run[i + 1] + 1 if inband[i] else 0
    for c in changes:
        end = len(t)
        ok = np.flatnonzero(run[c:end] >= np.minimum(hold, end - np.arange(c, end)))
        rt = float(t[c + ok[0]] - t[c]) if ok.size else float(t[-1] - t[c])
        per_change.append(rt)
        worst = max(worst, rt)
    out["reconvergence_s"] = worst
    out["n_soil_changes"] = int(len(changes))
    out["reconvergence_per_change_s"] = per_change

    # NIS consistency
    dof = np.asarray(est["nis_dof"], dtype=np.int64)
    nis = np.asarray(est["nis"], dtype=float)
    u = dof > 0
    lo, hi = nis_bounds(dof[u])
    out["nis_within_95"] = float(np.mean((nis[u] >= lo) & (nis[u] <= hi))) if u.any() else math.nan
    out["nis_mean_per_dof"] = float(np.mean(nis[u] / dof[u])) if u.any() else math.nan
    return out
