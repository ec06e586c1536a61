"""Per-cell running statistics (count, mean, variance) for the map layers.

Each tile holds, for every layer and cell, a sample count ``n`` (uint32), the
running mean and the running sum of squared deviations ``M2`` (float64),
updated with Welford's algorithm, which stays accurate where sum/sum-of-
squares would cancel (e.g. ρ_s ≈ 0.06 ± 0.001 over 10⁵ samples).  Batches
and tiles merge with Chan et al.'s pairwise formula.  The (unbiased) sample
variance is ``M2 / (n − 1)``; it is NaN for n < 2.

Layers (all dimensionless, as in the paper): ``a, p, alpha1, alpha2`` — the
μ(s) curve parameters of eq. 14; ``rho_s`` — soil rolling resistance; ``mu``
— adhesion coefficient (the caller decides which scalar, e.g. the mean over
driven wheels).  Array index order is ``[layer, row, col]`` with ``row``
growing northwards (+y) and ``col`` eastwards (+x).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

LAYERS: tuple[str, ...] = ("a", "p", "alpha1", "alpha2", "rho_s", "mu")
"""Default map layers, in storage order."""

COUNT_DTYPE = np.dtype("<u4")
VALUE_DTYPE = np.dtype("<f8")


class TileStats:
    """Count/mean/M2 arrays of one square tile for a fixed list of layers."""

    __slots__ = ("layers", "cells", "count", "mean", "m2")

    def __init__(self, layers: Sequence[str], cells: int,
                 count: NDArray[np.uint32] | None = None,
                 mean: NDArray[np.float64] | None = None,
                 m2: NDArray[np.float64] | None = None) -> None:
        self.layers = tuple(layers)
        self.cells = int(cells)
        shape = (len(self.layers), self.cells, self.cells)
        self.count = np.zeros(shape, COUNT_DTYPE) if count is None else count
        self.mean = np.zeros(shape, VALUE_DTYPE) if mean is None else mean
        self.m2 = np.zeros(shape, VALUE_DTYPE) if m2 is None else m2
        for name, arr in (("count", self.count), ("mean", self.mean), ("m2", self.m2)):
            if arr.shape != shape:
                raise ValueError(f"{name} has shape {arr.shape}, expected {shape}")

    def add(self, row: int, col: int, layer_values: Sequence[tuple[int, float]]) -> None:
        """Welford update of one cell with ``(layer_index, value)`` pairs."""
        cnt, mean, m2 = self.count, self.mean, self.m2
        for li, v in layer_values:
            n = int(cnt[li, row, col]) + 1
            cnt[li, row, col] = n
            mu = mean[li, row, col]
            d = v - mu
            mu = mu + d / n
            mean[li, row, col] = mu
            m2[li, row, col] += d * (v - mu)

    def merge_batch(self, li: int, rows: ArrayLike, cols: ArrayLike, values: ArrayLike) -> None:
        """Add many samples of layer ``li`` at once (any order, repeated cells allowed)."""
        rows = np.asarray(rows, dtype=np.intp)
        cols = np.asarray(cols, dtype=np.intp)
        values = np.asarray(values, dtype=np.float64)
        if values.size == 0:
            return
        flat = rows * self.cells + cols
        size = self.cells * self.cells
        nb = np.bincount(flat, minlength=size).astype(np.float64)
        sb = np.bincount(flat, weights=values, minlength=size)
        touched = nb > 0
        mb = np.zeros(size)
        mb[touched] = sb[touched] / nb[touched]
        dev = values - mb[flat]
        m2b = np.bincount(flat, weights=dev * dev, minlength=size)
        cnt = self.count[li].reshape(-1)
        mean = self.mean[li].reshape(-1)
        m2 = self.m2[li].reshape(-1)
        idx = np.flatnonzero(touched)
        na = cnt[idx].astype(np.float64)
        nbt = nb[idx]
        n = na + nbt
        delta = mb[idx] - mean[idx]
        mean[idx] = mean[idx] + delta * (nbt / n)
        m2[idx] = m2[idx] + m2b[idx] + delta * delta * (na * nbt / n)
        cnt[idx] = (na + nbt).astype(COUNT_DTYPE)

    def variance(self) -> NDArray[np.float64]:
        """Unbiased sample variance per layer and cell; NaN where n < 2."""
        out = np.full(self.m2.shape, np.nan)
        ok = self.count >= 2
        out[ok] = self.m2[ok] / (self.count[ok].astype(np.float64) - 1.0)
        return out

    def copy(self) -> TileStats:
        return TileStats(self.layers, self.cells, self.count.copy(), self.mean.copy(), self.m2.copy())


__all__ = ["LAYERS", "TileStats"]
