"""Curve parameter a of μ(s) from estimated (μ, s) pairs (paper section 3.2, eq. 18).

Within a surface class p, α1, α2 are fixed, so μ(s) = a·g(s) with
g(s) = 1 − p e^{α1 s} − (1−p) e^{α2 s}; each wheel's estimated pair (μ̂_i, ŝ_i)
gives a_i = μ̂_i / g(ŝ_i) (:func:`tractionecu.model.mucurve.solve_a_array`, the
vectorised :func:`~tractionecu.model.mucurve.solve_a`).  Near s = 0, g → 0 and
the division amplifies the slip error, δa/a = (g'(s)/g(s))·δs; such
ill-conditioned low-slip pairs are skipped and the rest are smoothed over time
as described below.

Why no per-point error threshold: the slip ŝ comes from the estimated speed,
whose error (≈ 0.01–0.02 m/s, correlated over seconds) is a slip error of
≈ 0.005; at the low slip of firm soil (s ≈ 0.03) a threshold on the
propagated error of each point, evaluated at the noisy ŝ, keeps the points
whose slip error happens to be positive and so biases a low (measured: −24 %
on a firm stubble).  Points are therefore judged by quantities that do not
contain the slip error: |μ̂| ≥ ``min_mu`` (low adhesion means low slip, where
g → 0), speed (done by the caller) and a small ``min_slip`` that only removes
sign changes and g ≈ 0.  The accepted pairs are combined as a ratio of sums,

    â = Σ w μ̂_i / Σ w g(ŝ_i) = Σ (w g_i) a_i / Σ (w g_i),  a_i = μ̂_i / g(ŝ_i) (solve_a),

the g-weighted mean of the per-pair solutions, with forgetting λ = e^{−Δt/τ}
and w = 1/σ_μ².  Being linear in g(ŝ) it is first-order unbiased under slip
noise; the remaining bias is −½ g''(s) σ_s² / g(s) (curvature of g), about
+1–2 % of a at the lowest slips of paper-three-soils (s ≈ 0.03, σ_s ≈ 0.009)
and less elsewhere.  Ill-conditioned pairs (small g) carry small weight.

Class selection (several classes configured): every class c is scored on
the same pairs by RSS_c = Σ w (μ̂ − â_c g_c(ŝ))², from the sufficient
statistics Σ w μ̂², Σ w μ̂ g_c, Σ w g_c² under the same forgetting.  The
class with the smallest RSS fits best; a switch needs RSS_new <
``switch_ratio``·RSS_current and RSS_current − RSS_new > ``switch_min_delta``
(hysteresis), because with a narrow slip range all shapes fit almost equally.

Equation numbers are those of the paper's source (Kobelski et al. 2020), in
order: (11) discrete model x_k = f(x_{k−1}, u_{k−1}) + q, y_k = h(x_k) + r;
(12) predicted distribution; (13) a-priori covariance; (14) mean update;
(15) covariance update; (16) adaptation argmin over A_k; (17) windowed
innovation covariance S̄_k; (18) μ(s).  Issue 3 calls (16)–(17) "eqs. 12–13"
and ``model/mucurve.py`` calls (18) "eq. 14".
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
    min_mu : pairs with |μ̂| below this are skipped as ill-conditioned (low slip) [-].
    min_slip : pairs with |ŝ| below this are skipped [-] (sign changes, g ≈ 0).
    switch_ratio : hysteresis of the class decision [-] (< 1).
    switch_min_delta : a switch also needs RSS_current − RSS_new above this
        [χ² units, the weights are 1/σ_μ²], so that equally good fits (one slip
        value, exact data) never switch.
    """

    def __init__(self, classes: Sequence[SoilClass | str] = ("stubble",), *, tau_s: float = 5.0,
                 min_mu: float = 0.15, min_slip: float = 0.005, switch_ratio: float = 0.7,
                 switch_min_delta: float = 10.0):
        cls = [SOIL_CLASSES[c] if isinstance(c, str) else c for c in classes]
        if not cls:
            raise ValueError("at least one surface class is needed")
        self.classes = cls
        self.tau = float(tau_s)
        self.min_mu = float(min_mu)
        self.min_slip = float(min_slip)
        self.switch_ratio = float(switch_ratio)
        self.switch_min_delta = float(switch_min_delta)
        nc = len(cls)
        self._num = np.zeros(nc)
        self._den = np.zeros(nc)
        self._smm = 0.0
        self._smg = np.zeros(nc)
        self._sgg = np.zeros(nc)
        self._best = 0
        self._t: float | None = None
        self.n_used = 0

    def update(self, t: float, mu: NDArray[np.float64], s: NDArray[np.float64],
               sigma_mu: NDArray[np.float64]) -> CurveState:
        """Add the pairs of one instant t [s]: μ̂ (k,), ŝ (k,) and the standard errors of μ̂ (k,)."""
        lam = 1.0 if self._t is None else math.exp(-max(t - self._t, 0.0) / self.tau)
        self._t = t
        self._num *= lam
        self._den *= lam
        self._smm *= lam
        self._smg *= lam
        self._sgg *= lam
        ok = np.isfinite(mu) & np.isfinite(s) & (np.abs(mu) >= self.min_mu) & (mu * s > 0)
        self.n_used = 0
        if ok.any():
            m, sv = mu[ok], s[ok]
            w = 1.0 / np.maximum(sigma_mu[ok], 1e-6) ** 2
            self._smm += float((w * m * m).sum())
            used = 0
            for c, cls in enumerate(self.classes):
                a, _, good = solve_a_array(m, sv, cls, min_slip=self.min_slip, max_rel_err=math.inf)
                if not good.any():
                    continue
                g = cls.g(sv[good])
                wg = w[good] * g
                self._num[c] += float((wg * a[good]).sum())      # = Σ w μ̂
                self._den[c] += float(wg.sum())                  # = Σ w g(ŝ)
                self._smg[c] += float((w[good] * m[good] * g).sum())
                self._sgg[c] += float((wg * g).sum())
                used = max(used, int(good.sum()))
            self.n_used = used
        return self.state()

    def state(self) -> CurveState:
        """The current identification (a, best class, per-class a and RSS)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            a = np.where(self._den > 0, self._num / self._den, np.nan)
            rss = np.where(self._sgg > 0, self._smm - 2.0 * a * self._smg + a * a * self._sgg, np.inf)
        if len(self.classes) > 1 and np.isfinite(rss).any():
            cand = int(np.nanargmin(np.where(np.isfinite(rss), rss, np.inf)))
            cur = rss[self._best]
            if cand != self._best and (not np.isfinite(cur) or (rss[cand] < self.switch_ratio * cur
                                                               and cur - rss[cand] > self.switch_min_delta)):
                self._best = cand
        b = self._best
        return CurveState(float(a[b]), b, self.classes[b].name, a, rss, self.n_used)
