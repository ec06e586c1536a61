"""Autocorrelation-robust statistics of residuals and scores, shared by the channels and the fits.

* :func:`andrews_bandwidth` — the Bartlett-kernel bandwidth by the AR(1) plug-in of Andrews (1991);
* :func:`hac_meat` — the Newey–West (1987) long-run covariance Σ_l w_l (Γ_l + Γ_lᵀ) of score rows;
* :func:`n_effective` — the effective sample size of autocorrelated residuals.

They depend on numpy alone, so :mod:`.channels` (per-channel nuisance intervals), :mod:`.fit`
(sandwich covariances), :mod:`.openworld` and :mod:`.reduced` import them from here.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

__all__ = ["HAC_FFT_LAGS", "andrews_bandwidth", "hac_meat", "n_effective"]


def _ar1(x: NDArray) -> float:
    x = x - x.mean()
    d = float(np.dot(x[:-1], x[:-1]))
    return float(np.clip(np.dot(x[1:], x[:-1]) / d, -0.97, 0.97)) if d > 0 else 0.0


def andrews_bandwidth(g: NDArray) -> int:
    """Bartlett-kernel bandwidth by the AR(1) plug-in of Andrews (1991)."""
    T = g.shape[0]
    num = den = 0.0
    for j in range(g.shape[1]):
        col = g[:, j]
        rho = _ar1(col)
        s2 = float(np.var(col[1:] - rho * col[:-1])) if T > 2 else 0.0
        num += 4 * rho * rho * s2 * s2 / ((1 - rho) ** 6 * (1 + rho) ** 2)
        den += s2 * s2 / (1 - rho) ** 4
    alpha = num / den if den > 0 else 0.0
    L = int(math.ceil(1.1447 * (alpha * T) ** (1.0 / 3.0)))
    return int(np.clip(L, 1, max(1, T // 3)))


HAC_FFT_LAGS = 64
"""Above this many lags the Newey–West sum is taken from FFT cross-correlations (same sum, time
O(k² T log T) instead of O(k² T L))."""


def hac_meat(g: NDArray, lag: int | None = None) -> NDArray:
    """Newey–West long-run covariance Σ_l w_l (Γ_l + Γ_lᵀ) of the score rows g (T, k)."""
    g = np.asarray(g, dtype=float)
    if g.ndim == 1:
        g = g[:, None]
    L = andrews_bandwidth(g) if lag is None else lag
    S = g.T @ g
    top = min(L, g.shape[0] - 1)
    if top > HAC_FFT_LAGS:
        # Γ_l[i, j] = Σ_t g[t+l, i] g[t, j] for every lag at once from the cross-correlations by FFT:
        # the bandwidth reaches T/3 on strongly autocorrelated scores, where the loop below is O(T²).
        T, k = g.shape
        nfft = 1 << int(math.ceil(math.log2(2 * T)))
        F = np.fft.rfft(g, nfft, axis=0)
        w = 1.0 - np.arange(1, top + 1) / (L + 1.0)
        for i in range(k):
            for j in range(i, k):
                c = np.fft.irfft(F[:, i] * np.conj(F[:, j]), nfft)   # c[l] = Γ_l[i, j], c[−l] = Γ_l[j, i]
                v = float(np.dot(w, c[1:top + 1] + c[nfft - 1:nfft - top - 1:-1]))
                S[i, j] += v
                if j != i:
                    S[j, i] += v
        return S
    for l in range(1, top + 1):
        w = 1.0 - l / (L + 1.0)
        G = g[l:].T @ g[:-l]
        S += w * (G + G.T)
    return S


def n_effective(resid: NDArray, tidx: NDArray[np.int64]) -> float:
    """Effective sample size T (1 − ρ₁)/(1 + ρ₁) of residuals aggregated per time index."""
    _, inv = np.unique(tidx, return_inverse=True)
    agg = np.bincount(inv, weights=resid)
    T = agg.size
    if T < 3:
        return float(T)
    rho = max(_ar1(agg), 0.0)
    return float(max(1.0, T * (1 - rho) / (1 + rho)))
