"""Curve parameter a of μ(s) from estimated (μ, s) pairs (paper section 3.2, eq. 14).

Within a surface class p, α1, α2 are fixed, so μ(s) = a·g(s) with
g(s) = 1 − p e^{α1 s} − (1−p) e^{α2 s}; each wheel's estimated pair (μ̂_i, ŝ_i)
gives a_i = μ̂_i / g(ŝ_i) (:func:`tractionecu.model.mucurve.solve_a_array`, the
vectorised :func:`~tractionecu.model.mucurve.solve_a`).  Points whose slip is
below ``min_slip`` or whose propagated relative error

    δa/a = √((σ_μ/μ)² + (g'(s) σ_s / g(s))²)

exceeds ``max_rel_err`` are skipped (low slip: g → 0 amplifies the slip
error).  The accepted values are smoothed over time with an exponentially
forgetting, inverse-variance weighted mean (time constant ``tau_s``):

    N_k = λ N_{k−1} + Σ_i w_i a_i,   D_k = λ D_{k−1} + Σ_i w_i,
    â = N_k / D_k,  λ = e^{−Δt/τ},  w_i = 1/(a_i δa_i/a_i)².

Class selection (several classes configured): every class c is also fitted
in the least-squares sense to the same forgetting window of accepted pairs,
RSS_c = Σ w (μ − a_c g_c(s))² with a_c = Σ w μ g_c / Σ w g_c², from the
sufficient statistics Σ w μ², Σ w μ g_c, Σ w g_c².  The class with the
smallest RSS fits best; a switch needs RSS_new < ``switch_ratio``·RSS_current
(hysteresis), because with a narrow slip range all shapes fit almost equally.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from ..model.mucurve import SOIL_CLASSES, SoilClass, solve_a_array


@dataclass(frozen=True)
class CurveState:
    """Current curve identification."""

    a: float
    """Smoothed a of the best class [-] (NaN until a well-conditioned point was seen)."""
    class_index: int
    """Index of the best-fitting class in the configured list."""
    class_name: str
    a_per_class: NDArray[np.float64]
    """Smoothed a for every configured class [-]."""
    rss_per_class: NDArray[np.float64]
    """Weighted residual sum of squares of every class [-²·weight]."""
    n_used: int
    """Number of (μ, s) pairs accepted on the last update."""


class CurveEstimator:
    """Online a and class identification from per-wheel (μ, s) pairs.

    Parameters
    ----------
    classes : the surface classes (shapes) to consider; the first is the
        default until the data discriminate.
    tau_s : forgetting time constant of the smoothing [s].
    min_slip : |s| below this is skipped [-].
    max_rel_err : skip points whose propagated relative error of a exceeds this [-].
    switch_ratio : hysteresis of the class decision [-] (< 1).
    """

    def __init__(self, classes: Sequence[SoilClass | str] = ("stubble",), *, tau_s: float = 5.0,
                 min_slip: float = 0.02, max_rel_err: float = 0.10, switch_ratio: float = 0.7):
        cls = [SOIL_CLASSES[c] if isinstance(c, str) else c for c in classes]
        if not cls:
            raise ValueError("at least one surface class is needed")
        self.classes = cls
        self.tau = float(tau_s)
        self.min_slip = float(min_slip)
        self.max_rel_err = float(max_rel_err)
        self.switch_ratio = float(switch_ratio)
        nc = len(cls)
        self._num = np.zeros(nc)
        self._den = np.zeros(nc)
        self._smm = np.zeros(nc)
        self._smg = np.zeros(nc)
        self._sgg = np.zeros(nc)
        self._best = 0
        self._t: float | None = None
        self.n_used = 0

    def update(self, t: float, mu: NDArray[np.float64], s: NDArray[np.float64],
               sigma_mu: NDArray[np.float64], sigma_s: NDArray[np.float64]) -> CurveState:
        """Add the pairs of one instant t [s]: μ (k,), s (k,) and their standard errors."""
        lam = 1.0 if self._t is None else math.exp(-max(t - self._t, 0.0) / self.tau)
        self._t = t
        self._num *= lam
        self._den *= lam
        self._smm *= lam
        self._smg *= lam
        self._sgg *= lam
        n_used = 0
        common = np.isfinite(mu) & np.isfinite(s) & (np.abs(s) >= self.min_slip) & (mu * s > 0)
        have_fit = bool(common.any())
        if have_fit:
            mc, sc, smc, ssc = mu[common], s[common], sigma_mu[common], sigma_s[common]
        for c, cls in enumerate(self.classes):
            a, rel, ok = solve_a_array(mu, s, cls, sigma_mu=sigma_mu, sigma_s=sigma_s,
                                       max_rel_err=self.max_rel_err, min_slip=self.min_slip)
            if ok.any():
                av, rv = a[ok], rel[ok]
                w = 1.0 / (av * rv) ** 2
                self._num[c] += float((w * av).sum())
                self._den[c] += float(w.sum())
                n_used = max(n_used, int(ok.sum()))
            if have_fit:
                # Shape fit on the same points for every class; weights 1/var(μ − a g(s)).
                g = cls.g(sc)
                wf = 1.0 / (smc ** 2 + (mc / g * cls.dg(sc) * ssc) ** 2)
                self._smm[c] += float((wf * mc * mc).sum())
                self._smg[c] += float((wf * mc * g).sum())
                self._sgg[c] += float((wf * g * g).sum())
        self.n_used = n_used
        return self.state()

    def state(self) -> CurveState:
        with np.errstate(divide="ignore", invalid="ignore"):
            a = np.where(self._den > 0, self._num / self._den, np.nan)
            rss = np.where(self._sgg > 0, self._smm - self._smg ** 2 / self._sgg, np.inf)
        if len(self.classes) > 1 and np.isfinite(rss).any():
            cand = int(np.argmin(rss))
            if cand != self._best and (not np.isfinite(rss[self._best]) or rss[cand] < self.switch_ratio * rss[self._best]):
                self._best = cand
        b = self._best
        return CurveState(float(a[b]), b, self.classes[b].name, a, rss, self.n_used)
