"""The paper's Manhattan-distance band fill (Kobelski et al. 2020, section 4).

Definition implemented
----------------------
For every cell c of a grid of cell means M (NaN = no data) and every band b,
take the mean of the *non-empty* cells e whose Manhattan distance
``d = res · (|Δrow| + |Δcol|)`` [m] lies in the band:

==========  =============================  ======
band        distance d [m]                 weight
==========  =============================  ======
high        ε_high ≥ d ≥ 0                 4
mid         ε_mid ≥ d > ε_high             0.5
low         ε_low ≥ d > ε_mid              0.1
==========  =============================  ======

with ε_low = 10 m, ε_mid = 5 m, ε_high = 1.5 m.  The innermost band
*includes* d = 0, i.e. a measured cell's own mean takes part in its band
mean; excluding it would let a cell's neighbours outvote the cell's own
measurement.  Comparisons of d with ε use a relative tolerance of 1e-9, so
that 5 m at 0.5 m resolution is exactly 10 cells.

Deviation from the paper (normalisation)
----------------------------------------
The paper sums the weighted band means, ``Σ_b w_b m_b``.  The weights add up
to 4.6, so that sum scales the map by up to 4.6 (and by a different factor
wherever some band is empty).  Here the sum is divided by the weights of the
bands that hold data::

    F(c) = Σ_{b: n_b(c) > 0} w_b m_b(c) / Σ_{b: n_b(c) > 0} w_b

so a constant field stays that constant, and a cell with no data within
ε_low stays NaN.  As in the paper, every cell — measured or not — is replaced
by the band estimate (``preserve_measured=True`` keeps measured means).

Vectorisation
-------------
A Manhattan ball |Δi| + |Δj| ≤ r is a square in the 45°-rotated coordinates
u = i + j, v = i − j.  Values and the non-empty mask are scattered onto the
rotated lattice, one summed-area table (float64, values centred on their mean
to keep round-off small; counts are exact integers in float64) is built, and
each ball sum is four table look-ups per cell.  Cost O(cells · bands), no
per-cell Python loop.  :func:`paper_fill_naive` is the straightforward
per-cell implementation kept as a reference for tests and the benchmark.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

EPS_LOW_M = 10.0
"""Outer band limit ε_low [m]."""
EPS_MID_M = 5.0
"""Middle band limit ε_mid [m]."""
EPS_HIGH_M = 1.5
"""Inner band limit ε_high [m]."""
W_LOW = 0.1
W_MID = 0.5
W_HIGH = 4.0

DEFAULT_EPS_M: tuple[float, float, float] = (EPS_LOW_M, EPS_MID_M, EPS_HIGH_M)
DEFAULT_WEIGHTS: tuple[float, float, float] = (W_LOW, W_MID, W_HIGH)

_REL_TOL = 1e-9


def band_radii_cells(resolution_m: float, eps_m: Sequence[float] = DEFAULT_EPS_M) -> tuple[int, ...]:
    """Largest Manhattan distance in cells inside each ε [m] (ε_low, ε_mid, ε_high order)."""
    if not (resolution_m > 0 and math.isfinite(resolution_m)):
        raise ValueError(f"resolution_m must be > 0, got {resolution_m}")
    return tuple(int(math.floor(e / resolution_m * (1.0 + _REL_TOL))) for e in eps_m)


def _check(eps_m: Sequence[float], weights: Sequence[float]) -> None:
    if len(eps_m) != 3 or len(weights) != 3:
        raise ValueError("eps_m and weights need three entries (low, mid, high)")
    lo, mid, hi = (float(e) for e in eps_m)
    if not (lo > mid > hi >= 0.0):
        raise ValueError(f"need ε_low > ε_mid > ε_high ≥ 0, got {tuple(eps_m)}")
    if any(not (w > 0 and math.isfinite(w)) for w in weights):
        raise ValueError(f"weights must be positive, got {tuple(weights)}")


def diamond_sums(values: NDArray[np.float64], valid: NDArray[np.bool_],
                 radii: Sequence[int]) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Sums of ``values`` and counts of ``valid`` over Manhattan balls.

    For each radius r (cells) returns ``(sum, count)`` arrays of the grid's
    shape: ``sum[i, j] = Σ values[e, f]`` over valid cells with
    ``|e−i| + |f−j| ≤ r``.  ``values`` must be 0 where not valid.
    """
    return [(z.real.copy(), z.imag.copy()) for z in _diamond_sums_complex(
        np.where(valid, values, 0.0) + 1j * valid, radii)]


def _diamond_sums_complex(z: NDArray[np.complex128], radii: Sequence[int],
                          window: tuple[int, int, int, int] | None = None) -> list[NDArray[np.complex128]]:
    """Manhattan-ball sums of a complex grid (real: values, imag: counts).

    ``window = (i0, j0, rows, cols)`` restricts the output to that sub-grid.

    Cell (i, j) sits at node (u, v) = (i + j, i − j + w − 1) of a rotated
    lattice, where the ball |Δi| + |Δj| ≤ r is the box |Δu| ≤ r, |Δv| ≤ r.
    A summed-area table of the lattice answers each box with four look-ups;
    the look-ups for all cells are strided views (row step size+1, column
    step size−1), so no index arrays are built.
    """
    h, w = z.shape
    rmax = max((int(r) for r in radii), default=0)
    pad = rmax + 1
    size = h + w - 1 + 2 * pad
    lattice = np.zeros((size, size), dtype=np.complex128)
    flat = lattice.reshape(-1)
    item = flat.itemsize
    base = pad * size + (w - 1 + pad)

    def cells(du: int, dv: int, i0: int, j0: int, rows: int, cols: int) -> NDArray[np.complex128]:
        start = base + du * size + dv + i0 * (size + 1) + j0 * (size - 1)
        return np.lib.stride_tricks.as_strided(flat[start:], shape=(rows, cols),
                                               strides=((size + 1) * item, (size - 1) * item))

    cells(0, 0, 0, 0, h, w)[...] = z
    win = window if window is not None else (0, 0, h, w)
    np.cumsum(lattice, axis=0, out=lattice)
    np.cumsum(lattice, axis=1, out=lattice)
    out = []
    for r in radii:
        hi, lo = int(r), -int(r) - 1
        acc = cells(hi, hi, *win) - cells(lo, hi, *win)
        acc -= cells(hi, lo, *win)
        acc += cells(lo, lo, *win)
        out.append(acc)
    return out


def paper_fill(mean: ArrayLike, resolution_m: float, *,
               eps_m: Sequence[float] = DEFAULT_EPS_M,
               weights: Sequence[float] = DEFAULT_WEIGHTS,
               preserve_measured: bool = False,
               block_cells: int = 256) -> NDArray[np.float64]:
    """Fill a grid of cell means with the normalised three-band Manhattan fill.

    Parameters
    ----------
    mean:
        2-D array of cell means (any unit); NaN/±Inf marks an empty cell.
    resolution_m:
        Cell size [m] (square cells).
    eps_m:
        (ε_low, ε_mid, ε_high) [m], default (10, 5, 1.5).
    weights:
        (w_low, w_mid, w_high) [-], default (0.1, 0.5, 4).
    preserve_measured:
        Keep the cell's own mean where it has data instead of the band
        estimate.
    block_cells:
        The grid is processed in blocks of this many cells per side (plus an
        ε_low halo) to bound the working memory to ~(2·(block+2·halo))² ·
        16 bytes (≈ 6 MB at the default); the result does not depend on it.

    Returns
    -------
    float64 array of the input's shape; NaN where no data lies within ε_low.
    """
    _check(eps_m, weights)
    m = np.asarray(mean, dtype=np.float64)
    if m.ndim != 2:
        raise ValueError(f"mean must be 2-D, got shape {m.shape}")
    out = np.full(m.shape, np.nan)
    valid = np.isfinite(m)
    if m.size == 0 or not valid.any():
        return out
    r_low, r_mid, r_high = band_radii_cells(resolution_m, eps_m)
    ref = float(np.mean(m[valid]))
    w_low, w_mid, w_high = (float(x) for x in weights)
    h, w = m.shape
    step = max(int(block_cells), 1)
    halo = r_low
    for i0 in range(0, h, step):
        i1 = min(i0 + step, h)
        e0, e1 = max(i0 - halo, 0), min(i1 + halo, h)
        for j0 in range(0, w, step):
            j1 = min(j0 + step, w)
            f0, f1 = max(j0 - halo, 0), min(j1 + halo, w)
            sub = m[e0:e1, f0:f1]
            vsub = valid[e0:e1, f0:f1]
            if not vsub.any():
                continue
            z = np.where(vsub, sub - ref, 0.0) + 1j * vsub
            hi_s, mid_s, low_s = _diamond_sums_complex(z, (r_high, r_mid, r_low),
                                                       window=(i0 - e0, j0 - f0, i1 - i0, j1 - j0))
            num = np.zeros((i1 - i0, j1 - j0))
            den = np.zeros((i1 - i0, j1 - j0))
            for band, wb in ((hi_s, w_high), (mid_s - hi_s, w_mid), (low_s - mid_s, w_low)):
                cnt = np.rint(band.imag)
                has = cnt > 0
                num[has] += wb * (band.real[has] / cnt[has])
                den[has] += wb
            ok = den > 0
            blk = out[i0:i1, j0:j1]
            blk[ok] = ref + num[ok] / den[ok]
    if preserve_measured:
        out[valid] = m[valid]
    return out


def paper_fill_naive(mean: ArrayLike, resolution_m: float, *,
                     eps_m: Sequence[float] = DEFAULT_EPS_M,
                     weights: Sequence[float] = DEFAULT_WEIGHTS,
                     preserve_measured: bool = False) -> NDArray[np.float64]:
    """Straightforward per-cell implementation of :func:`paper_fill`.

    Loops over every cell in Python and averages each band inside a window
    with a precomputed Manhattan-distance mask.  Same result as
    :func:`paper_fill`; O(cells · r²), for tests and the benchmark only.
    """
    _check(eps_m, weights)
    m = np.asarray(mean, dtype=np.float64)
    h, w = m.shape
    out = np.full(m.shape, np.nan)
    valid = np.isfinite(m)
    r_low, r_mid, r_high = band_radii_cells(resolution_m, eps_m)
    w_low, w_mid, w_high = (float(x) for x in weights)
    di, dj = np.mgrid[-r_low:r_low + 1, -r_low:r_low + 1]
    d = np.abs(di) + np.abs(dj)
    bands = ((d <= r_high, w_high), ((d > r_high) & (d <= r_mid), w_mid), ((d > r_mid) & (d <= r_low), w_low))
    mp = np.pad(np.where(valid, m, 0.0), r_low)
    vp = np.pad(valid, r_low)
    for i in range(h):
        for j in range(w):
            win = mp[i:i + 2 * r_low + 1, j:j + 2 * r_low + 1]
            wv = vp[i:i + 2 * r_low + 1, j:j + 2 * r_low + 1]
            num = 0.0
            den = 0.0
            for mask, wb in bands:
                sel = mask & wv
                n = int(sel.sum())
                if n:
                    num += wb * float(win[sel].sum()) / n
                    den += wb
            if den > 0:
                out[i, j] = num / den
    if preserve_measured:
        out[valid] = m[valid]
    return out


__all__ = [
    "DEFAULT_EPS_M",
    "DEFAULT_WEIGHTS",
    "EPS_HIGH_M",
    "EPS_LOW_M",
    "EPS_MID_M",
    "band_radii_cells",
    "diamond_sums",
    "paper_fill",
    "paper_fill_naive",
]
