"""Soil classification of a map by the asymptotic adhesion ``a``.

The paper fixes the shape parameters (p, α1, α2) per surface family and
lets ``a`` carry the ground condition, so a mapped cell is assigned the soil
whose typical ``a`` [-] is nearest to the cell's ``a``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray


def soil_a_table(soils: Mapping[Any, Any]) -> tuple[list[Any], NDArray[np.float64]]:
    """Normalise ``{key: a}`` or ``{key: obj with .a_typical}`` to (keys, typical a)."""
    keys = list(soils)
    vals = []
    for k in keys:
        v = soils[k]
        vals.append(float(getattr(v, "a_typical", v)))
    if not keys:
        raise ValueError("need at least one soil class")
    return keys, np.asarray(vals, dtype=np.float64)


def classify_by_a(a: ArrayLike, typical_a: ArrayLike) -> NDArray[np.int64]:
    """Index of the nearest typical ``a`` for every value; −1 where ``a`` is NaN.

    Ties go to the lower index.
    """
    a = np.asarray(a, dtype=np.float64)
    ta = np.asarray(typical_a, dtype=np.float64).ravel()
    if ta.size == 0:
        return np.full(a.shape, -1, dtype=np.int64)
    order = np.argsort(ta, kind="stable")
    ts = ta[order]
    # boundaries between neighbouring classes are the midpoints
    mids = 0.5 * (ts[1:] + ts[:-1])
    idx = np.searchsorted(mids, a, side="left")
    out = order[np.clip(idx, 0, len(ts) - 1)].astype(np.int64)
    out[~np.isfinite(a)] = -1
    return out


def natural_classes(a: ArrayLike, k: int = 3, iterations: int = 50, spread: float = math.nan) -> NDArray[np.float64]:
    """Up to k class centres of ``a`` by 1-D k-means (deterministic, quantile start).

    Used by the exports when a map carries no soil classes.  ``spread``: the typical standard deviation of a's
    samples within one cell; fewer classes are taken while two centres lie closer than twice it (a field of
    one soil, whose cells differ by the estimate's noise alone, was cut into three classes: 678 zones).
    """
    v = np.asarray(a, dtype=np.float64)
    v = np.sort(v[np.isfinite(v)])
    if v.size == 0:
        return np.zeros(0)
    k = max(1, min(int(k), np.unique(v).size))
    for kk in range(k, 0, -1):
        c = _kmeans(v, kk, iterations)
        if kk == 1 or not math.isfinite(spread) or np.min(np.diff(c)) >= 2.0 * spread:
            return c
    return c  # pragma: no cover - the loop returns at kk == 1


def _kmeans(v: NDArray[np.float64], k: int, iterations: int) -> NDArray[np.float64]:
    """k sorted centres of the sorted values ``v`` by 1-D k-means from the quantiles."""
    c = np.quantile(v, (np.arange(k) + 0.5) / k)
    for _ in range(iterations):
        lab = classify_by_a(v, c)
        new = np.array([v[lab == j].mean() if np.any(lab == j) else c[j] for j in range(k)])
        if np.allclose(new, c, rtol=0, atol=1e-12):
            break
        c = new
    return np.sort(c)


__all__ = ["classify_by_a", "natural_classes", "soil_a_table"]
