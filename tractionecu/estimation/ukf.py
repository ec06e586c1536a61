"""Vectorised unscented Kalman filter (paper section 3.1, eqs. 11–15).

The filter stays in one module (about 500 lines): its fast and general update
paths must apply the same gating, clamping and bookkeeping to the same state,
and are kept side by side for that.

The filter follows the paper's description (Wan & van der Merwe 2000; Van der
Merwe et al. 2004) with the scaled sigma points of filterpy's
``MerweScaledSigmaPoints`` — identical points and weights:

    λ = α²(n + κ) − n
    χ⁽⁰⁾ = x̂,  χ⁽ⁱ⁾ = x̂ + [√((n+λ)P)]ᵢ,  χ⁽ⁿ⁺ⁱ⁾ = x̂ − [√((n+λ)P)]ᵢ,  i = 1..n
    W_m⁽⁰⁾ = λ/(n+λ),  W_c⁽⁰⁾ = λ/(n+λ) + 1 − α² + β,  W⁽ⁱ⁾ = 1/(2(n+λ))

with √ the Cholesky factor (row i of the upper factor, as filterpy does).

Predict (paper eqs. 12–13):
all 2n+1 sigma points go through the process model in ONE call
``fx(sigmas (2n+1, n), u, dt) -> (2n+1, n)`` (for the estimator this is
:meth:`tractionecu.model.vehicle.FilterModel.step`, RK4), then

    x̂_{k|k-1} = Σ W_m⁽ⁱ⁾ χ⁽ⁱ⁾_{k|k-1}
    P_{k|k-1} = Σ W_c⁽ⁱ⁾ (χ⁽ⁱ⁾ − x̂)(χ⁽ⁱ⁾ − x̂)ᵀ + Q.

Update (paper eqs. 14–15 and the unnumbered ŷ, S, C above them): the paper redraws the sigma points from N(x̂_{k|k-1}, P_{k|k-1})
(as filterpy does).  The output here is a selection of states,
y = h(x) = x[idx] (paper: y = (ω1..4, v), the first five states), and the
unscented transform of a linear map is exact, so the redrawn-points sums
reduce to closed forms that need no second Cholesky factorisation:

    ŷ_k = Σ W_m⁽ⁱ⁾ h(χ⁽ⁱ⁾) = x̂[idx]
    S_k = Σ W_c⁽ⁱ⁾ (h(χ⁽ⁱ⁾) − ŷ)(·)ᵀ + R = P[idx, idx] + R
    C_k = Σ W_c⁽ⁱ⁾ (χ⁽ⁱ⁾ − x̂)(h(χ⁽ⁱ⁾) − ŷ)ᵀ = P[:, idx]
    K_k = C_k S_k⁻¹,  x̂_{k|k} = x̂ + K_k(y_k − ŷ_k),  P_{k|k} = P − K_k S_k K_kᵀ.

This holds for any (W_m, W_c) with Σ W_m = 1 and symmetric points; the
cross-check against stock filterpy is in ``tests/estimation`` and in
``benchmarks/estimator.py``.

Robustness (issue 3, "never diverge or crash"):

* partial updates: any subset ``idx`` of the outputs (wheels at 100 Hz, GPS
  speed at 10 Hz);
* non-finite measurement components are dropped (counted);
* per-component Mahalanobis gating: component j is rejected when
  ν_j² / S_jj > ``gate_chi2`` (χ²₁ quantile), then the update runs with the
  rest; the NIS ν ᵀ S⁻¹ ν of the accepted components is kept with its degrees
  of freedom for consistency checks;
* P is symmetrised after every predict and update;
* a failed Cholesky factorisation is repaired by adding growing diagonal
  jitter (then, if needed, by clipping eigenvalues) and counted;
* the mean is clamped into [x_lo, x_hi] (physical bounds of μ and ρ_s).

Equation numbers follow the paper's source; see :mod:`tractionecu.estimation`.
"""

from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg.lapack import dgesv, dpotrf

from ..errors import EstimatorError
from ..model.vehicle import FilterModel
from . import _kernels
from ._kernels import JIT

ProcessFn = Callable[[NDArray[np.float64], NDArray[np.float64], float], NDArray[np.float64]]


def merwe_weights(n: int, alpha: float, beta: float, kappa: float) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """Scaled sigma-point parameters (λ, W_m, W_c), as filterpy's ``MerweScaledSigmaPoints``."""
    lam = alpha ** 2 * (n + kappa) - n
    if n + lam <= 0:
        raise ValueError(f"sigma points: n + λ = {n + lam} must be > 0 (alpha={alpha}, kappa={kappa})")
    c = 0.5 / (n + lam)
    wm = np.full(2 * n + 1, c)
    wc = np.full(2 * n + 1, c)
    wm[0] = lam / (n + lam)
    wc[0] = lam / (n + lam) + (1.0 - alpha ** 2 + beta)
    return lam, wm, wc


def merwe_sigma_points(x: NDArray[np.float64], P: NDArray[np.float64], lam: float) -> NDArray[np.float64]:
    """Sigma points (2n+1, n) of N(x, P) with the scaled spread √(n+λ) (filterpy ordering)."""
    n = x.shape[0]
    U = np.linalg.cholesky((n + lam) * P).T   # upper factor: row k is filterpy's U[k]
    sig = np.empty((2 * n + 1, n))
    sig[0] = x
    np.add(x, U, out=sig[1:n + 1])
    np.subtract(x, U, out=sig[n + 1:])
    return sig


def _gain_numpy(sig: NDArray[np.float64], sf: NDArray[np.float64], Wc: NDArray[np.float64],
               x0: NDArray[np.float64], x1: NDArray[np.float64], P1: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """:func:`._kernels.cross_gain` in numpy (the path without numba): G = C P1⁻¹, or None."""
    C = ((sig - x0).T * Wc) @ (sf - x1)
    L, info = dpotrf(P1, lower=1, clean=1)
    if info != 0:
        return None
    G = np.linalg.solve(L.T, np.linalg.solve(L, C.T)).T
    return G if bool(np.isfinite(G).all()) else None


class UnscentedFilter:
    """UKF with vectorised sigma-point propagation and partial, gated measurement updates.

    Parameters
    ----------
    fx : process model ``fx(sigmas (2n+1, n), u, dt [s]) -> (2n+1, n)``, one call for all points.
    x0, P0 : initial mean (n,) and covariance (n, n), in the units of the state.
    meas_index : state index of each output component: y_j = x[meas_index[j]].
    alpha, beta, kappa : sigma-point scaling (Van der Merwe 2004); defaults α = 1,
        β = 2, κ = 0 make every covariance weight W_c ≥ 0, so the predicted P is
        positive semi-definite by construction.
    x_lo, x_hi : bounds the mean is clamped into after each step (±inf = free).
    gate_chi2 : per-component gate on ν_j²/S_jj (∞ disables gating).
    gate_max_consecutive : a component gated on this many updates in a row is
        accepted on the next one (and its count restarts): a persistent
        discrepancy is the model's, not the sensor's, and rejecting it for ever
        would lock the filter out (gating-induced divergence).

    Implementation notes (the filter runs at 100 Hz on a 10-state model, so
    the cost is the number of numpy calls, not arithmetic):

    * with numba (``_kernels``), sigma points, unscented transform and update
      are compiled; when ``fx`` is :meth:`FilterModel.step
      <tractionecu.model.vehicle.FilterModel.step>` the whole predict,
      including the model's compiled RK4 over all sigma points, is one call;
    * without numba, the sigma points are x + E·Lᵀ with L the lower Cholesky factor of P
      (LAPACK ``potrf``) and E the constant (2n+1, n) matrix [0; √(n+λ)·I;
      −√(n+λ)·I], one matrix product;
    * with all W_c ≥ 0 the predicted covariance is Dᵀ D + Q with the weighted
      deviations D = √W_c (χ − x̂), one product (numpy's ``syrk``);
    * an update whose measurements are finite, contiguous in the state and
      within the gate runs without fancy indexing; anything else (NaN/Inf
      components, gating, index arrays) takes the general path, with the
      same results.
    """

    def __init__(self, fx: ProcessFn, x0: ArrayLike, P0: ArrayLike, meas_index: Sequence[int], *,
                 alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0,
                 x_lo: ArrayLike | None = None, x_hi: ArrayLike | None = None, gate_chi2: float = math.inf,
                 gate_max_consecutive: int = 5):
        self.fx = fx
        self.x = np.array(x0, dtype=float)
        self.n = n = self.x.shape[0]
        self.P = np.array(P0, dtype=float).reshape(n, n)
        self.meas_index = np.asarray(meas_index, dtype=np.intp)
        self.alpha, self.beta, self.kappa = float(alpha), float(beta), float(kappa)
        self.lam, self.Wm, self.Wc = merwe_weights(n, self.alpha, self.beta, self.kappa)
        self._c = n + self.lam
        self.x_lo = np.full(n, -np.inf) if x_lo is None else np.array(x_lo, dtype=float).reshape(n)
        self.x_hi = np.full(n, np.inf) if x_hi is None else np.array(x_hi, dtype=float).reshape(n)
        self._clamped_dims = np.flatnonzero(np.isfinite(self.x_lo) | np.isfinite(self.x_hi))
        self._bounds = [(int(j), float(self.x_lo[j]), float(self.x_hi[j])) for j in self._clamped_dims]
        self.gate_chi2 = float(gate_chi2)
        self.gate_max_consecutive = int(gate_max_consecutive)
        self._gate_run = np.zeros(self.meas_index.size, dtype=np.int64)
        self._gate_run_any = False
        self.gate_bypassed = 0
        """Number of components accepted after ``gate_max_consecutive`` gated updates in a row."""
        self._sig = np.empty((2 * n + 1, n))
        self._eye = np.eye(n)
        # Sigma-point offsets: rows 1..n and n+1..2n of E·Lᵀ are ±√(n+λ)·(row k of Lᵀ).
        self._E1 = np.concatenate([np.zeros((1, n)), np.eye(n), -np.eye(n)])
        self._Ec = self._E1 * math.sqrt(self._c)
        self._sqrt_wc = np.sqrt(self.Wc)[:, None] if bool((self.Wc >= 0.0).all()) else None
        self._sqrt_c = math.sqrt(self._c)
        self._w = np.concatenate([[self._sqrt_c], self.Wm, self.Wc])
        # The project's own process model: predict runs in one compiled call (same RK4 code as fx).
        owner = getattr(fx, "__self__", None)
        self.gain_n: int | None = None
        """The smoother's gain over the first ``gain_n`` states only (their marginal); None: all."""
        self._model = owner if (JIT and isinstance(owner, FilterModel) and n == 10
                                and getattr(fx, "__func__", None) is FilterModel.step) else None
        self._fast: dict[int, tuple] = {}
        # Counters (cumulative) and last-step diagnostics.
        self.chol_repairs = 0
        """Number of Cholesky failures repaired with jitter / eigenvalue clipping."""
        self.nonfinite_rejected = 0
        """Number of measurement components dropped as NaN/Inf."""
        self.gated_total = 0
        """Number of measurement components rejected by the NIS gate."""
        self.clamp_events = 0
        """Number of steps on which the mean was clamped into its bounds."""
        self.repaired_last = False
        self.track_gain = False
        """Compute each prediction's smoother gain (``last_gain``; the fixed-lag smoother, :mod:`.smoother`)."""
        self.last_gain: NDArray[np.float64] | None = None
        """G = C P⁻¹ of the last prediction (C the cross-covariance of the state before and after it, P⁻ its
        predicted covariance; :func:`._kernels.cross_gain`), with ``track_gain``; None when not tracked, when
        the prediction repaired its covariance or when P⁻ was not positive definite."""
        self.last_nis = math.nan
        self.last_dof = 0
        self.last_gated = 0
        """Bit j set when output component j was gated on the last update."""
        self.last_outside = 0
        """Bit j set when output component j fell outside the gate on the last update, whether it was
        gated or then accepted as persistent (the divergence monitor counts both)."""
        self.last_idx: NDArray[np.intp] = np.empty(0, dtype=np.intp)
        """Output components used on the last update."""
        self._lazy: tuple | None = None
        self._set_last(np.zeros(n), np.empty((n, 0)), np.empty((n, 0)))

    # ------------------------------------------------------------------ diagnostics of the last update
    def _set_last(self, dx, K, C, ksk=None) -> None:
        self._lazy = None
        self._last = (dx, K, C)
        self._ksk = ksk

    def _last_parts(self) -> tuple:
        lz = self._lazy
        if lz is not None:                 # compiled update: views into its output arrays
            work, m, P, sl = lz
            self._set_last(work[:, m], work[:, :m], P[:, sl], work[:, m + 1])
        return self._last

    @property
    def last_dx(self) -> NDArray[np.float64]:
        """Correction K ν of the last update (before clamping)."""
        return self._last_parts()[0]

    def ksk_diag(self) -> NDArray[np.float64]:
        """diag(K S Kᵀ) = Σ_j K_ij C_ij of the last update (the covariance it removed), (n,)."""
        _, K, C = self._last_parts()
        if self._ksk is None:
            self._ksk = (K * C).sum(axis=1)
        return self._ksk

    def correction(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(last_dx, ksk_diag()) of the last update, for covariance matching."""
        lz = self._lazy
        if lz is not None:
            work, m = lz[0], lz[1]
            return work[:, m], work[:, m + 1]
        return self.last_dx, self.ksk_diag()

    # ------------------------------------------------------------------ helpers
    def _chol(self, A: NDArray[np.float64]) -> NDArray[np.float64]:
        """Lower Cholesky factor of A; repairs (and counts) a failure."""
        try:
            return np.linalg.cholesky(A)
        except np.linalg.LinAlgError:
            pass
        self.chol_repairs += 1
        self.repaired_last = True
        A = 0.5 * (A + A.T)
        scale = float(np.max(np.abs(np.diag(A))))
        if not math.isfinite(scale):
            raise EstimatorError("covariance is not finite; cannot repair")
        scale = max(scale, 1e-300)
        jitter = 1e-12 * scale
        for _ in range(8):
            try:
                L = np.linalg.cholesky(A + jitter * self._eye)
                self.P = (A + jitter * self._eye) / self._c
                return L
            except np.linalg.LinAlgError:
                jitter *= 100.0
        w, V = np.linalg.eigh(A)
        w = np.clip(w, 1e-12 * scale, None)
        A = (V * w) @ V.T
        A = 0.5 * (A + A.T)
        self.P = A / self._c
        return np.linalg.cholesky(A + 1e-12 * scale * self._eye)

    # ------------------------------------------------------------------ predict
    def sigma_points(self) -> NDArray[np.float64]:
        """Sigma points of N(x, P), (2n+1, n); a failed factorisation is repaired."""
        sig = self._sig
        if JIT:
            if _kernels.sigma_points(self.x, self.P, self._sqrt_c, sig):
                return sig
        else:
            L, info = dpotrf(self.P, lower=1, clean=1)
            if info == 0:
                np.matmul(self._Ec, L.T, out=sig)
                sig += self.x
                return sig
        np.matmul(self._E1, self._chol(self._c * self.P).T, out=sig)
        sig += self.x
        return sig

    def predict(self, u: NDArray[np.float64], dt: float, Q: NDArray[np.float64]) -> None:
        """Propagate mean and covariance over dt [s] with input u and process noise covariance Q (n, n).

        The mean of μ and ρ_s cannot leave its bounds here (their dynamics are
        zero), so clamping is done after the update only.
        """
        self.repaired_last = False
        track = self.track_gain
        self.last_gain = None
        model = self._model
        if model is not None and u.dtype == np.float64 and u.shape in ((6,), (7,)):
            n = self.n
            x = np.empty(n)
            P = np.empty((n, n))
            if track:
                G = np.empty((n, n))
                code = _kernels.predict_model_gain(self.x, self.P, np.ascontiguousarray(u), float(dt),
                                                   np.ascontiguousarray(Q, dtype=np.float64), self._w, model._kc,
                                                   self._sig, x, P, G)
                if code == 0 or code == 3:
                    if code == 0:
                        self.last_gain = G
                    self.x = x
                    self.P = P
                    return
            else:
                code = _kernels.predict_model(self.x, self.P, np.ascontiguousarray(u), float(dt),
                                              np.ascontiguousarray(Q, dtype=np.float64), self._w, model._kc,
                                              self._sig, x, P)
                if code == 0:
                    self.x = x
                    self.P = P
                    return
            if code == 2:
                raise EstimatorError("non-finite prediction (process model returned NaN/Inf)")
        x0 = self.x
        sig0 = self.sigma_points()
        if track:
            sig0 = sig0.copy()           # the process model may reuse the array
        sf = self.fx(sig0, u, dt)
        if JIT and sf.dtype == np.float64 and sf.shape == self._sig.shape:
            n = self.n
            x = np.empty(n)
            P = np.empty((n, n))
            if not _kernels.mean_cov(np.ascontiguousarray(sf), self.Wm, self.Wc,
                                     np.ascontiguousarray(Q, dtype=np.float64), x, P):
                raise EstimatorError("non-finite prediction (process model returned NaN/Inf)")
            self.x = x
            self.P = P
            if track and not self.repaired_last:
                g = self.gain_n or n
                G = np.empty((g, g))
                if g == n:
                    ok = _kernels.cross_gain(sig0, np.ascontiguousarray(sf), self.Wc, x0, x, P, G)
                else:
                    ok = _kernels.cross_gain(np.ascontiguousarray(sig0[:, :g]), np.ascontiguousarray(sf[:, :g]),
                                             self.Wc, np.ascontiguousarray(x0[:g]), x[:g].copy(),
                                             np.ascontiguousarray(P[:g, :g]), G)
                if ok:
                    self.last_gain = G
            return
        x = self.Wm @ sf
        d = sf - x
        sw = self._sqrt_wc
        if sw is not None:
            d *= sw
            P = d.T @ d
        else:
            P = (d.T * self.Wc) @ d
        P += Q
        P += P.T
        P *= 0.5
        # A non-finite sigma point makes x̂ or a deviation non-finite, and so a diagonal entry of P.
        if not math.isfinite(P.trace()):
            raise EstimatorError("non-finite prediction (process model returned NaN/Inf)")
        self.x = x
        self.P = P
        if track and not self.repaired_last:
            g = self.gain_n or self.n
            self.last_gain = _gain_numpy(sig0[:, :g], sf[:, :g], self.Wc, x0[:g], x[:g], P[:g, :g])

    def predict_steps(self, u: NDArray[np.float64], h: float, n_sub: int,
                      q_of: Callable[[float], NDArray[np.float64]]) -> NDArray[np.float64] | None:
        """``n_sub`` predictions of ``h`` [s] each, the process noise of each ``q_of(h)`` taken just before it;
        returns their smoother gain (the sub-steps' gains multiplied, :func:`._kernels.gain_compose`: no update
        between them), or None when gains are not tracked or one of them has none (``last_gain``)."""
        G = None
        ok = self.track_gain
        for _ in range(n_sub):
            self.predict(u, h, q_of(h))
            if ok:
                gs = self.last_gain
                if gs is None:
                    ok = False
                    G = None
                elif G is None:
                    G = gs
                else:
                    _kernels.gain_compose(G, gs, False)
        return G

    # ------------------------------------------------------------------ update
    def _fast_entry(self, idx: slice) -> tuple:
        """(the slice, fast spec or None, index array) of an output slice; the spec is
        (index array, state slice, m, I_m, (m,), scratch (2m+1, m)) when its states are contiguous."""
        comp = np.arange(self.meas_index.size)[idx]
        st = self.meas_index[comp]
        m = int(st.size)
        if m == 0 or (m > 1 and (np.diff(st) != 1).any()):
            spec = None
        else:
            spec = (comp, slice(int(st[0]), int(st[0]) + m), m, np.eye(m), (m,), np.empty((2 * m + 1, m)))
        ent = (idx, spec, comp)
        if len(self._fast) >= 32:            # a caller making a new slice per step must not grow it
            self._fast.clear()
        self._fast[id(idx)] = ent            # the entry holds the slice, so its id stays unique
        return ent

    def update(self, z: ArrayLike, idx: ArrayLike | slice, R: ArrayLike) -> None:
        """Measurement update with output components ``idx``, values z and noise R.

        ``idx`` selects output components (positions in ``meas_index``), either
        as an index array or as a ``slice`` (fast path).  R is the (m,)
        diagonal of the measurement noise variances or an (m, m) matrix.
        Results of the step are left in the ``last_*`` attributes.
        """
        z = np.asarray(z, dtype=float)
        R = np.asarray(R, dtype=float)
        self.last_gated = 0
        self.last_outside = 0
        if idx.__class__ is slice:
            ent = self._fast.get(id(idx))
            if ent is None or ent[0] is not idx:
                ent = self._fast_entry(idx)
            spec = ent[1]
            if spec is not None and R.ndim == 1 and z.shape == spec[4] and self._update_fast(z, R, spec):
                return
            idx = ent[2]
        else:
            idx = np.asarray(idx, dtype=np.intp)
        self._update_general(z, idx, R)

    def _update_fast(self, z: NDArray[np.float64], R: NDArray[np.float64], spec: tuple) -> bool:
        """Update of contiguous states with a diagonal R; False (nothing changed) if a component
        is non-finite or outside the gate, which the general path then handles."""
        comp, sl, m, eye, _, small = spec
        P = self.P
        if JIT:
            n = self.n
            x = np.empty(n)
            Pn = np.empty((n, n))
            work = np.empty((n, m + 2))         # kept for correction() (small is scratch only)
            code, nis, clamped = _kernels.update_block(self.x, P, np.ascontiguousarray(z), np.ascontiguousarray(R),
                                                       sl.start, self.gate_chi2, self.x_lo, self.x_hi,
                                                       x, Pn, work, small)
            if code:                            # not _kernels.OK
                return False
            if self._gate_run_any:
                run = self._gate_run
                run[comp] = 0
                self._gate_run_any = bool(run.any())
            self.x = x
            self.P = Pn
            if clamped:
                self.clamp_events += 1
            self.last_nis = nis
            self.last_dof = m
            self.last_idx = comp
            self._lazy = (work, m, P, sl)
            return True
        S = P[sl, sl].copy()
        S.ravel()[::m + 1] += R
        nu = z - self.x[sl]
        g = self.gate_chi2
        for q, s in zip(nu.tolist(), S.diagonal().tolist()):
            q *= q
            if not (q <= g * s and q < math.inf):     # NaN/Inf or gated: general path
                return False
        if self._gate_run_any:
            run = self._gate_run
            run[comp] = 0
            self._gate_run_any = bool(run.any())
        Si, info = dgesv(S, eye)[2:]
        if info != 0:
            Si = np.linalg.inv(S)                     # singular S: raises LinAlgError as before
        C = P[:, sl]
        K = C @ Si
        dx = K @ nu
        x = self.x + dx
        P = P - K @ C.T
        P += P.T
        P *= 0.5
        self.P = P
        xl = x.tolist()
        for j, lo, hi in self._bounds:
            if not lo <= xl[j] <= hi:
                np.minimum(np.maximum(x, self.x_lo), self.x_hi, out=self.x)
                self.clamp_events += 1
                break
        else:
            self.x = x
        self.last_nis = float(nu @ (Si @ nu))
        self.last_dof = m
        self.last_idx = comp
        self._set_last(dx, K, C)
        return True

    def _update_general(self, z: NDArray[np.float64], idx: NDArray[np.intp], R: NDArray[np.float64]) -> None:
        """Any subset of outputs, non-finite components dropped, per-component gating."""
        if not math.isfinite(float(z.sum())):
            ok = np.isfinite(z)
            self.nonfinite_rejected += int((~ok).sum())
            z, idx = z[ok], idx[ok]
            R = R[ok] if R.ndim == 1 else R[np.ix_(ok, ok)]
        st = self.meas_index[idx]
        m = st.size
        if m == 0:
            self._no_update()
            return
        P = self.P
        # Contiguous state block (the usual ω1..4[, v]): plain slicing.
        contiguous = st[-1] - st[0] == m - 1
        if contiguous:
            sl = slice(int(st[0]), int(st[0]) + m)
            S = P[sl, sl].copy()
            C = P[:, sl]
            nu = z - self.x[sl]
        else:
            S = P[np.ix_(st, st)]
            C = P[:, st]
            nu = z - self.x[st]
        if R.ndim == 1:
            S.flat[::m + 1] += R
        else:
            S += R
        if self.gate_chi2 < math.inf:
            keep = nu * nu <= self.gate_chi2 * S.diagonal()
            run = self._gate_run
            if keep.all():
                run[idx] = 0
            else:
                for pos in np.flatnonzero(~keep):
                    j = int(idx[pos])
                    self.last_outside |= 1 << j
                    if run[j] >= self.gate_max_consecutive:
                        keep[pos] = True          # persistent: accept (see class doc)
                        self.gate_bypassed += 1
                    else:
                        self.last_gated |= 1 << j
                run[idx[keep]] = 0
                run[idx[~keep]] += 1
                if not keep.all():
                    self.gated_total += int((~keep).sum())
                    idx, st, nu = idx[keep], st[keep], nu[keep]
                    if st.size == 0:
                        self._gate_run_any = bool(run.any())
                        self._no_update()
                        return
                    S = S[np.ix_(keep, keep)]
                    C = P[:, st]
            self._gate_run_any = bool(run.any())
        Si = np.linalg.inv(S)
        K = C @ Si
        dx = K @ nu
        x = self.x + dx
        P = P - K @ C.T
        P += P.T
        P *= 0.5
        self.P = P
        np.minimum(np.maximum(x, self.x_lo), self.x_hi, out=self.x)
        if (self.x != x).any():
            self.clamp_events += 1
        self.last_nis = float(nu @ (Si @ nu))
        self.last_dof = int(st.size)
        self.last_idx = idx
        self._set_last(dx, K, C)

    def _no_update(self) -> None:
        self.last_nis = math.nan
        self.last_dof = 0
        self.last_idx = np.empty(0, dtype=np.intp)
        self._set_last(np.zeros(self.n), np.empty((self.n, 0)), np.empty((self.n, 0)))
