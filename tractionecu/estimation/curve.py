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

Class selection (several classes configured): μ̂ comes from the torques and
is accurate, ŝ comes from the estimated speed and is noisy, so each class is
scored on how well it predicts the slip from the adhesion (regressing the
noisy variable on the accurate one avoids the errors-in-variables bias that
makes flat curves win when μ is regressed on a noisy slip):

    s_pred,i = g_c⁻¹(μ̂_i / â_c),   r_i = ŝ_i − s_pred,i,
    σ²_ci = σ_s,i² + (σ_μ,i / (â_c g_c'(s_pred,i)))²,
    L_c ← λ_c L_c + (Δt/τ_s) · mean_i ½ [r_i² / σ²_ci + ln σ²_ci],

the negative log-likelihood of one-step predictions, with â_c the class's
estimate before the new pairs and λ_c = e^{−Δt/τ_class}.  The class with the
smallest L fits best; a switch needs L_current − L_new > ``switch_min_delta``
[nats] (hysteresis).  The slip errors of the four wheels share the speed
error and are correlated over τ_s (``slip_corr_s``, ≈ 0.5 s for the speed
error of the paper-three-soils runs), so the pairs of one instant count as
one sample (the mean) and samples closer than τ_s are discounted by Δt/τ_s;
summing them as independent would make the evidence overconfident and the
class flip on noise.  With the narrow slip range of steady work the shapes
cannot be told apart and the default class stays.

Equation numbers follow the paper's source; see :mod:`tractionecu.estimation`.
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
    nll_per_class: NDArray[np.float64]
    """Forgetting negative log-likelihood of every class's predictions [nats] (lower fits better)."""
    n_used: int
    """Number of (μ, s) pairs accepted on the last update."""


class CurveEstimator:
    """Online a and class identification from per-wheel (μ, s) pairs.

    Parameters
    ----------
    classes : the surface classes (shapes) to consider; the first is the
        default until the data discriminate.
    tau_s : forgetting time constant of the a smoothing [s].
    min_mu : pairs with |μ̂| below this are skipped as ill-conditioned (low slip) [-].
    min_slip : pairs with |ŝ| below this are skipped [-] (sign changes, g ≈ 0).
    class_tau_s : forgetting time constant of the class evidence [s].
    switch_min_delta : a class switch needs the new class's negative
        log-likelihood this much below the current one's [nats].
    slip_corr_s : correlation time of the slip error [s]; evidence from
        samples closer than this is discounted.
    """

    def __init__(self, classes: Sequence[SoilClass | str] = ("stubble",), *, tau_s: float = 5.0,
                 min_mu: float = 0.15, min_slip: float = 0.005, class_tau_s: float = 30.0,
                 switch_min_delta: float = 10.0, slip_corr_s: float = 0.5):
        cls = [SOIL_CLASSES[c] if isinstance(c, str) else c for c in classes]
        if not cls:
            raise ValueError("at least one surface class is needed")
        self.classes = cls
        self.tau = float(tau_s)
        self.min_mu = float(min_mu)
        self.min_slip = float(min_slip)
        self.class_tau = float(class_tau_s)
        self.switch_min_delta = float(switch_min_delta)
        self.slip_corr = float(slip_corr_s)
        nc = len(cls)
        self._num = np.zeros(nc)
        self._den = np.zeros(nc)
        self._nll = np.zeros(nc)
        grid = np.linspace(0.0, 1.0, 4001)
        self._inv = [(c.g(grid), grid) for c in cls]     # g is increasing on [0, 1]: table for g⁻¹
        self._best = 0
        self._t: float | None = None
        self.n_used = 0

    def update(self, t: float, mu: NDArray[np.float64], s: NDArray[np.float64],
               sigma_mu: NDArray[np.float64], sigma_s: NDArray[np.float64] | None = None) -> CurveState:
        """Add the pairs of one instant t [s]: μ̂ (k,), ŝ (k,) and the standard errors of μ̂ and ŝ (k,)."""
        dt = 0.0 if self._t is None else max(t - self._t, 0.0)
        self._t = t
        lam = math.exp(-dt / self.tau)
        self._num *= lam
        self._den *= lam
        self._nll *= math.exp(-dt / self.class_tau)
        if len(self.classes) == 1:
            self._update_single(np.asarray(mu, dtype=float), np.asarray(s, dtype=float),
                                np.asarray(sigma_mu, dtype=float))
            return self.state()
        ok = np.isfinite(mu) & np.isfinite(s) & (np.abs(mu) >= self.min_mu) & (mu * s > 0)
        self.n_used = 0
        if ok.any():
            m, sv = mu[ok], s[ok]
            sm2 = np.maximum(sigma_mu[ok], 1e-6) ** 2
            ss = np.zeros_like(sv) if sigma_s is None else sigma_s[ok]
            w = 1.0 / sm2
            used = 0
            multi = len(self.classes) > 1
            discount = min(1.0, dt / self.slip_corr) if dt > 0 else 1.0
            for c, cls in enumerate(self.classes):
                a, _, good = solve_a_array(m, sv, cls, min_slip=self.min_slip, max_rel_err=math.inf)
                if not good.any():
                    continue
                g = cls.g(sv[good])
                if multi and self._den[c] > 0:
                    a_prev = self._num[c] / self._den[c]
                    gs, sg = self._inv[c]
                    s_pred = np.interp(np.abs(m[good]) / a_prev, gs, sg)
                    var = ss[good] ** 2 + sm2[good] / (a_prev * cls.dg(s_pred)) ** 2
                    r = np.abs(sv[good]) - s_pred
                    self._nll[c] += discount * 0.5 * float((r * r / var + np.log(var)).mean())
                wg = w[good] * g
                self._num[c] += float((wg * a[good]).sum())      # = Σ w μ̂
                self._den[c] += float(wg.sum())                  # = Σ w g(ŝ)
                used = max(used, int(good.sum()))
            self.n_used = used
        return self.state()

    def _update_single(self, mu: NDArray[np.float64], s: NDArray[np.float64], sigma_mu: NDArray[np.float64]) -> None:
        """The one-class update of :meth:`update` (no class evidence), with floats where the
        multi-class code uses arrays: same pairs, same operations and summation order."""
        ml, sl = mu.tolist(), s.tolist()
        sel = [i for i, (m, x) in enumerate(zip(ml, sl))
               if math.isfinite(m) and math.isfinite(x) and abs(m) >= self.min_mu and m * x > 0]
        self.n_used = 0
        if not sel:
            return
        g = self.classes[0].g(s[sel]).tolist()
        sig = np.broadcast_to(sigma_mu, s.shape)[sel].tolist()
        wa: list[float] = []
        wg: list[float] = []
        for gi, i, sm in zip(g, sel, sig):
            # solve_a_array's conditions (its error bound is not used here: max_rel_err = inf)
            if not (abs(sl[i]) >= self.min_slip and abs(gi) > 1e-9):
                continue
            a = ml[i] / gi
            if not a > 0:
                continue
            sm = sm if (sm != sm or sm >= 1e-6) else 1e-6          # np.maximum(σ_μ, 1e-6), NaN kept
            w = 1.0 / (sm * sm) * gi
            wa.append(w * a)
            wg.append(w)
        if not wg:
            return
        num, den = wa[0], wg[0]
        for k in range(1, len(wg)):
            num += wa[k]
            den += wg[k]
        self._num[0] += num       # = Σ w μ̂
        self._den[0] += den       # = Σ w g(ŝ)
        self.n_used = len(wg)

    def state(self) -> CurveState:
        """The current identification (a, best class, per-class a and evidence)."""
        a = np.array([n / d if d > 0 else math.nan for n, d in zip(self._num.tolist(), self._den.tolist())])
        if len(self.classes) > 1:
            cand = int(np.argmin(self._nll))
            if cand != self._best and self._nll[self._best] - self._nll[cand] > self.switch_min_delta:
                self._best = cand
        b = self._best
        return CurveState(float(a[b]), b, self.classes[b].name, a, self._nll.copy(), self.n_used)
