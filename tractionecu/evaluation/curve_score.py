"""The identified and the true μ(s) of one soil for the R² of :mod:`.scoring` (paper section 5, Fig. 5).

The paper compares, per soil, "an average representative μ(s) characteristic calculated from the UKF
estimates" with the true one by R² (its figures 0.857 / 0.996 / 0.983).  The estimator reports its
curve per step on one of two paths (:mod:`tractionecu.estimation.curve`):

* ``class:<name>``: a·g_class(s).  The representative curve is the paper's: a̅·g(s), a̅ the mean
  identified a over the soil's class-path samples and g the most frequently reported class (as before the shape
  path existed, so class-path figures do not move);
* ``shape:<form>``: a fitted shape.  The representative curve is the mean of the identified curves
  μ̂_j(s) over the samples on the shape path (any form), which for one class reduces to a̅·g(s).

The shape path is scored when most of the soil's samples report a fitted shape (of any form;
``curve_path`` names the most frequent form), else the class path.  The true curve is the soil's class curve
from ``truth.toml`` (``soil_class``, ``a``), or, for a truth model whose μ(s) is none of the classes,
its tabulated curve ``mu_curve_s`` / ``mu_curve`` (same file), interpolated; both are compared on the
same slip grid.

Load.  The physical truth's μ(s) depends on the wheel load (Brixius' mobility number B_n ∝ 1/F_z), and
its ``mu_curve`` is the soil's curve at the static mean wheel load m g/4.  A curve identified with its
load dependence (:attr:`~tractionecu.model.mucurve.MuCurve.load_aware`) is evaluated at its reference
load, the estimator's m g/4 of ``vehicle.toml``: the same load as the truth's table (the recordings
declare the simulated mass).  A curve without one is one curve for every load and is compared with the
same table: pooled over light front and heavy rear wheels it is the soil's curve at no particular load,
and the score says so.  Never the front or rear table alone, whichever fits better.
"""

from __future__ import annotations

from collections import Counter
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

from ..model.mucurve import SOIL_CLASSES, curve_class


def true_curve(info: dict[str, Any], s_grid: NDArray[np.float64]) -> NDArray[np.float64]:
    """True μ(s) [-] of one soil of ``truth.toml`` on ``s_grid`` (tabulated curve if given, else its class)."""
    if "mu_curve_s" in info and "mu_curve" in info:
        s = np.asarray(info["mu_curve_s"], dtype=float)
        mu = np.asarray(info["mu_curve"], dtype=float)
        order = np.argsort(s)
        return np.interp(s_grid, s[order], mu[order])
    return SOIL_CLASSES[info["soil_class"]].mu(s_grid, info["a"])


def identified_curve(idx: NDArray[np.int64], a_e: NDArray[np.float64], cls_e: Sequence[str],
                     curves: Sequence[Any] | None, s_grid: NDArray[np.float64]
                     ) -> tuple[NDArray[np.float64], dict[str, Any]]:
    """Representative identified μ(s) on ``s_grid`` over the samples ``idx`` of one soil (module doc).

    ``a_e`` (n,), ``cls_e`` (n,) and ``curves`` (n,) are the estimator's per-step a, class name and
    curve (:class:`~tractionecu.model.mucurve.MuCurve` or None; None for output without curves).
    Returns (curve, info) with info keys ``a_identified``, ``class_identified``, ``curve_path``
    and, on the shape path, ``shape_params`` (mean of each parameter).
    """
    il = idx.tolist()
    paths = (Counter(curves[j].path if curves[j] is not None else f"class:{cls_e[j]}" for j in il)
             if curves is not None else Counter())
    n_shape = sum(n for p, n in paths.items() if p.startswith("shape:"))
    # the shape path when most samples report a fitted shape (of any form), else the class path
    path = (max((p for p in paths if p.startswith("shape:")), key=lambda p: paths[p])
            if n_shape > len(il) - n_shape else "")
    sel = [cls_e[j] for j in il]
    cls_name = max(set(sel), key=sel.count)
    if not path.startswith("shape:"):
        # a̅ over the class-path samples (all of them when the estimator reports no curves)
        cl = idx if curves is None else np.array([j for j in il if curves[j] is None or
                                                  not curves[j].path.startswith("shape:")], dtype=np.int64)
        a_bar = float(np.mean(a_e[cl if cl.size else idx]))
        cls = curve_class(cls_name)
        if cls is None and curves is not None:    # a shape in neither registry, carried by its curve
            cls = next((curves[j].soil_class for j in il if curves[j] is not None
                        and getattr(curves[j], "soil_class", None) is not None
                        and curves[j].soil_class.name == cls_name), None)
        if cls is None:
            raise KeyError(f"surface class {cls_name!r}: not known and no reported curve carries it")
        return cls.mu(s_grid, a_bar), {
            "a_identified": a_bar, "class_identified": cls_name, "curve_path": path or f"class:{cls_name}"}
    assert curves is not None
    use = [j for j in il if curves[j] is not None and curves[j].path.startswith("shape:")]
    count = Counter(id(curves[j]) for j in use)           # many steps share one fitted curve
    first = {id(curves[j]): curves[j] for j in use}
    tot = float(len(use))
    mean = np.zeros_like(s_grid, dtype=float)
    for key, n in count.items():
        mean += n / tot * first[key].mu(s_grid)
    same = [j for j in use if curves[j].path == path]
    names = curves[same[0]].names
    theta = np.mean([curves[j].theta for j in same], axis=0)
    return mean, {"a_identified": float(np.mean([curves[j].a for j in use])), "class_identified": cls_name,
                  "curve_path": path, "shape_params": dict(zip(names, theta.tolist())),
                  "shape_share": len(use) / len(il)}


def r_squared_over(y_hat: NDArray[np.float64], y: NDArray[np.float64], s_grid: NDArray[np.float64],
                   lo: float, hi: float) -> float:
    """R² of the identified curve ``y_hat`` against the true ``y`` (both on ``s_grid``) over the slips
    lo ≤ s ≤ hi only [-]: the soil's own slip range, where the identified curve rests on data (over the
    whole grid the rest is extrapolation).  NaN with fewer than 3 grid points in the range."""
    m = (s_grid >= lo) & (s_grid <= hi)
    if int(m.sum()) < 3:
        return float("nan")
    r = y[m] - y_hat[m]
    d = y[m] - y[m].mean()
    ss = float((d * d).sum())
    return 1.0 - float((r * r).sum()) / ss if ss > 0 else float("nan")


def pair_errors(mu_e: NDArray[np.float64], s_e: NDArray[np.float64], mu_t: NDArray[np.float64],
                s_t: NDArray[np.float64]) -> dict[str, float]:
    """Errors of estimated (μ̂, ŝ) pairs against the true (μ, s) of the same wheels and instants [-].

    The curve is fitted to (μ̂, ŝ) as if each pair were the true point plus an error that is independent
    of the true point (classical errors in variables, which binning by μ̂ and the fit's effective variance
    assume).  These figures say how far that holds: the standard deviation and mean of e_μ = μ̂ − μ and
    e_s = ŝ − s (``mu_sd``, ``mu_bias``, ``s_sd``, ``s_bias``), the correlation of the two errors
    (``corr_mu_s``), the correlation of the slip error with the true slip (``corr_s_true``: 0 for a
    classical error) and the least-squares slopes of ŝ on s and of μ̂ on μ (``s_gain``, ``mu_gain``: 1
    for a classical error; above 1 the estimate over-reacts to the true variation, below 1 it attenuates
    it).  Inputs are 1-D arrays of equal length; non-finite entries are dropped (``n`` counts the rest).
    NaN figures with fewer than 3 pairs or a constant true value."""
    arrs = [np.asarray(x, dtype=float).ravel() for x in (mu_e, s_e, mu_t, s_t)]
    if len({a.size for a in arrs}) != 1:
        raise ValueError("pair_errors: mu_e, s_e, mu_t and s_t must have the same length")
    ok = np.all([np.isfinite(a) for a in arrs], axis=0)
    me, se, mt, st = (a[ok] for a in arrs)
    nan = float("nan")
    out = {"n": float(me.size), "mu_sd": nan, "mu_bias": nan, "s_sd": nan, "s_bias": nan, "corr_mu_s": nan,
           "corr_s_true": nan, "s_gain": nan, "mu_gain": nan}
    if me.size < 3:
        return out
    em, es = me - mt, se - st

    def corr(x: NDArray[np.float64], y: NDArray[np.float64]) -> float:
        sx, sy = float(x.std()), float(y.std())
        return float(np.mean((x - x.mean()) * (y - y.mean())) / (sx * sy)) if sx > 0 and sy > 0 else nan

    def gain(est: NDArray[np.float64], true: NDArray[np.float64]) -> float:
        v = float(true.var())
        return float(np.mean((est - est.mean()) * (true - true.mean())) / v) if v > 0 else nan

    out.update(mu_sd=float(em.std()), mu_bias=float(em.mean()), s_sd=float(es.std()), s_bias=float(es.mean()),
               corr_mu_s=corr(em, es), corr_s_true=corr(es, st), s_gain=gain(se, st), mu_gain=gain(me, mt))
    return out
