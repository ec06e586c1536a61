"""Compiled (numba) core of :class:`~tractionecu.estimation.ukf.UnscentedFilter`.

At 100 Hz on a 10-state model the cost of a numpy UKF step is the number of
numpy calls (≈ 0.5–1 µs each), not the arithmetic; these kernels do the
sigma points, the unscented mean and covariance and the measurement update
in one call each.  They compute the same quantities as the numpy code in
:mod:`.ukf` (which stays the fallback when numba is missing or
``TRACTIONECU_JIT=0``), up to floating-point round-off:

* :func:`sigma_points` — lower Cholesky factor L of P (column by column,
  LAPACK ``potf2`` order) and χ = x, x ± √(n+λ)·L[:, k];
* :func:`mean_cov` — x̂ = Σ W_m χ_f, P = Σ W_c (χ_f − x̂)(χ_f − x̂)ᵀ + (Q + Qᵀ)/2,
  exactly symmetric;
* :func:`predict_model` — both of the above around
  :class:`~tractionecu.model.vehicle.FilterModel`'s compiled RK4 (the
  function its ``step`` calls) in one call, used when the filter's process
  model is ``FilterModel.step``;
* :func:`update_block` — the closed-form update of a contiguous block of
  states with a diagonal R, per-component NIS gate and bounds;
* :func:`predict_model_gain` (with :func:`pair_gain`), :func:`cross_gain`,
  :func:`gain_solve`, :func:`gain_compose` — the prediction's smoother gain
  G = C P⁻¹, C the cross-covariance of the state before and after the
  prediction (Särkkä 2008, the unscented RTS smoother), for the fixed-lag
  smoother (:mod:`.smoother`).

and, for the estimator's bookkeeping around the filter (the same operations
as the numpy code they replace, which stays the fallback; bit for bit, see
``tests/estimation/test_speed_equivalence.py``):

* :func:`process_noise` — the slowly changing part of the estimator's Q
  (:meth:`~.estimator.Estimator._rebuild_Q`);
* :func:`cm_push`, :func:`cm_ratio` — covariance matching's window and its
  ratio (:class:`~.supervisor.CovarianceMatching`);
* :func:`fuzzy_strengths`, :func:`fuzzy_centroid` — the fuzzy supervisor's
  rule strengths and the centroid of its aggregated output set (:class:`~.supervisor.FuzzySupervisor`).

Results go into output arrays the caller allocates (returning arrays from
compiled code costs more than passing them in); inputs are not changed.
"""

from __future__ import annotations

import hashlib
import inspect
import math

import numpy as np

from ..model.vehicle import JIT, compiled
from ..model import vehicle as _vehicle

OK = 0
GENERAL = 1
"""update_block: a component is non-finite or outside the gate (nothing computed)."""
NOT_PD = 2
"""update_block: the innovation covariance is not positive definite (nothing computed)."""


def cholesky(P, L):                                      # pragma: no cover - compiled
    """The lower Cholesky factor of P into L (zero above the diagonal; column by column, LAPACK ``potf2``
    order); False if P is not positive definite."""
    n = P.shape[0]
    for j in range(n):
        for i in range(j):
            L[i, j] = 0.0
        s = P[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:              # also NaN
            return False
        d = math.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            t = P[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / d
    return True


def lower_inverse(L, Li):                                # pragma: no cover - compiled
    """The inverse of the lower triangular L into Li (zero above its diagonal on entry), column by column."""
    n = L.shape[0]
    for j in range(n):
        Li[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, n):
            t = 0.0
            for k in range(j, i):
                t -= L[i, k] * Li[k, j]
            Li[i, j] = t / L[i, i]


def sigma_points(x, P, sqrt_c, sig):                     # pragma: no cover - compiled
    """Fill sig (2n+1, n) with the scaled sigma points of N(x, P); False if P is not positive definite."""
    n = x.shape[0]
    return sigma_factor(x, P, sqrt_c, sig, np.empty((n, n)))


def sigma_factor(x, P, sqrt_c, sig, L):                  # pragma: no cover - compiled
    """:func:`sigma_points`, P's lower Cholesky factor into L (n, n) as well."""
    n = x.shape[0]
    if not cholesky(P, L):
        return False
    for j in range(n):
        sig[0, j] = x[j]
    for k in range(n):
        for j in range(n):
            o = sqrt_c * L[j, k]
            sig[1 + k, j] = x[j] + o
            sig[1 + n + k, j] = x[j] - o
    return True


def mean_cov(sf, Wm, Wc, Q, x, P):                     # pragma: no cover - compiled
    """x̂ into x (n,) and P into P (n, n) from the propagated sigma points sf (2n+1, n); False if not finite."""
    npt, n = sf.shape
    for j in range(n):
        x[j] = 0.0
    for i in range(npt):
        w = Wm[i]
        for j in range(n):
            x[j] += w * sf[i, j]
    d = np.empty((npt, n))
    for i in range(npt):
        for j in range(n):
            d[i, j] = sf[i, j] - x[j]
    finite = True
    for j in range(n):
        for k in range(j, n):
            s = 0.0
            for i in range(npt):
                s += Wc[i] * d[i, j] * d[i, k]
            s += 0.5 * (Q[j, k] + Q[k, j])
            P[j, k] = s
            P[k, j] = s
        if not math.isfinite(P[j, j]) or not math.isfinite(x[j]):
            finite = False
    return finite


def cross_gain(sig, sf, Wc, x0, x1, P1, G):              # pragma: no cover - compiled
    """The unscented RTS smoother's gain of one prediction into G (n, n); False if P1 is not positive definite.

    sig (2n+1, n): the sigma points of the state before the prediction (mean x0); sf: the same points
    propagated (mean x1, covariance P1 with the process noise).  C = Σ W_c (χ − x0)(χ_f − x1)ᵀ (the
    cross-covariance), G = C P1⁻¹ from P1's Cholesky factor (Särkkä 2008, "Unscented Rauch–Tung–Striebel
    smoother", IEEE TAC 53(3), eq. 13)."""
    npt, n = sf.shape
    C = np.zeros((n, n))
    df = np.empty(n)
    for i in range(1, npt):          # the centre point is the mean: χ₀ − x0 = 0
        w = Wc[i]
        for b in range(n):
            df[b] = sf[i, b] - x1[b]
        for a in range(n):
            da = w * (sig[i, a] - x0[a])
            if da == 0.0:            # (χ − x0 is a column of P's lower Cholesky factor: zero above its row)
                continue
            for b in range(n):
                C[a, b] += da * df[b]
    return gain_solve(C, P1, G)


def gain_solve(C, P1, G):                                   # pragma: no cover - compiled
    """G = C P1⁻¹ into G; False if P1 is not positive definite or G is not finite.

    P1⁻¹ = L⁻ᵀ L⁻¹ from P1's Cholesky factor L, then one product: the row-by-row triangular solves it replaces
    chain every operation on the one before (1.8 µs at n = 10); these products are independent along a row."""
    n = C.shape[0]
    L = np.empty((n, n))
    if not cholesky(P1, L):
        return False
    Li = np.zeros((n, n))                 # L⁻¹, lower triangular
    lower_inverse(L, Li)
    Pi = np.zeros((n, n))                 # P1⁻¹ = Σ_k Li[k]ᵀ Li[k] (row k of L⁻¹ is zero beyond k)
    for k in range(n):
        for a in range(k + 1):
            lka = Li[k, a]
            for b in range(k + 1):
                Pi[a, b] += lka * Li[k, b]
    for a in range(n):
        for b in range(n):
            G[a, b] = 0.0
        for k in range(n):
            cak = C[a, k]
            for b in range(n):
                G[a, b] += cak * Pi[k, b]
    for a in range(n):
        for b in range(n):
            if not math.isfinite(G[a, b]):
                return False
    return True


def pair_gain(Lp, sf, wc_sqrt_c, P1, G):                 # pragma: no cover - compiled
    """:func:`cross_gain` of a prediction whose sigma points are x ± √c L[:, k] with one weight W_c for all of
    them but the centre (Van der Merwe's), from P's Cholesky factor Lp itself: then
    C = W_c √c Σ_k L[:, k] (χ_f,k − χ_f,n+k)ᵀ, half the products of the general sum (``wc_sqrt_c`` = W_c √c)."""
    n = Lp.shape[0]
    C = np.zeros((n, n))
    d = np.empty(n)
    for k in range(n):
        for b in range(n):
            d[b] = wc_sqrt_c * (sf[1 + k, b] - sf[1 + n + k, b])
        for a in range(k, n):            # L is lower triangular
            la = Lp[a, k]
            for b in range(n):
                C[a, b] += la * d[b]
    return gain_solve(C, P1, G)


def gain_compose(G, Gs, first):                             # pragma: no cover - compiled
    """G ← Gs when ``first``, else G ← G Gs: the gain over the sub-steps of one step (no update between them,
    so the smoother passes each in turn: x̂ₖ = xₖ + G₁(x̂ₘ − x⁻ₘ), x̂ₘ = x⁻ₘ + G₂(x̂ₖ₊₁ − x⁻ₖ₊₁))."""
    n = G.shape[0]
    if first:
        for a in range(n):
            for b in range(n):
                G[a, b] = Gs[a, b]
        return
    T = np.empty((n, n))
    for a in range(n):
        for b in range(n):
            s = 0.0
            for k in range(n):
                s += G[a, k] * Gs[k, b]
            T[a, b] = s
    for a in range(n):
        for b in range(n):
            G[a, b] = T[a, b]


def _model_tag() -> int:
    """A number that changes with the source of FilterModel's compiled RK4 (and its helpers).

    :func:`predict_model` compiles that code in; numba's on-disk cache keys a
    function by its own file and bytecode and by the values it closes over,
    not by the functions it calls from other files.  Closing over this number
    makes an edit of the model kernels recompile predict_model instead of
    reusing a stale cached copy.
    """
    src = "".join(inspect.getsource(getattr(f, "py_func", f))
                  for f in (_vehicle._sign, _vehicle._rhs5, _vehicle._radius, _vehicle._rk4_points,
                            _vehicle._mudot, _vehicle._rk4_carcass, _vehicle._lat_shift, _vehicle._lateral_on,
                            _vehicle._wheel_terms))
    return int(hashlib.sha256(src.encode("utf-8")).hexdigest()[:15], 16)


def _make_predict_points(tag: int):
    def predict_points(x, P, u, dt, Q, w, kc, sig, xo, Po, L):  # pragma: no cover - compiled
        """The sigma points into sig (P's Cholesky factor into L), propagated through FilterModel's compiled RK4,
        x̂ into xo and P into Po: (code, the propagated points), code 0, 1 if P is not positive definite (nothing
        computed: the caller repairs it) or 2 if the prediction is not finite."""
        if tag < 0:                  # never: ties this function (and its cache entry) to the model's source
            return 3, sig
        npt = sig.shape[0]
        if not sigma_factor(x, P, w[0], sig, L):
            return 1, sig
        sf = _rk4_points(sig, u, kc, dt)
        if not mean_cov(sf, w[1:1 + npt], w[1 + npt:1 + 2 * npt], Q, xo, Po):
            return 2, sf
        return 0, sf

    return predict_points


def _make_predict_model(tag: int, gain: bool):
    """predict_model (``gain`` False) or predict_model_gain, closed over the model's tag (:func:`_model_tag`:
    they carry the model's compiled RK4 in their machine code)."""
    if not gain:
        def predict_model(x, P, u, dt, Q, w, kc, sig, xo, Po):      # pragma: no cover - compiled
            """Predict through FilterModel's compiled RK4 in one call: sigma points into sig, x̂ into xo, P into Po.

            w = [√(n+λ), W_m (2n+1), W_c (2n+1)]; kc: FilterModel's constants.
            Returns 0, 1 if P is not positive definite (nothing computed: the caller
            repairs it) or 2 if the prediction is not finite.
            """
            if tag < 0:              # never: ties this function (and its cache entry) to the model's source
                return 3
            n = x.shape[0]
            code, _ = _predict_points(x, P, u, dt, Q, w, kc, sig, xo, Po, np.empty((n, n)))
            return code

        return predict_model

    def predict_model_gain(x, P, u, dt, Q, w, kc, sig, xo, Po, G):  # pragma: no cover - compiled
        """predict_model, and the prediction's smoother gain into G (:func:`cross_gain`).

        Returns predict_model's code, or 3 when the prediction is done but its gain is not (P⁻ not positive
        definite or the gain not finite: the smoother's chain breaks there)."""
        if tag < 0:                  # never: ties this function (and its cache entry) to the model's source
            return 4
        n = x.shape[0]
        L = np.empty((n, n))
        code, sf = _predict_points(x, P, u, dt, Q, w, kc, sig, xo, Po, L)
        if code != 0:
            return code
        # the Merwe sigma points: one W_c beyond the centre, the gain from P's factor (pair_gain)
        if not pair_gain(L, sf, w[2 + 2 * n + 1] * w[0], Po, G):
            return 3
        return 0

    return predict_model_gain


def update_block(x, P, z, R, i0, gate, lo, hi, xn, Pn, work, small):  # pragma: no cover - compiled
    """Update with z (m,) measuring states i0..i0+m−1, R (m,) their noise variances.

    Outputs (preallocated by the caller): x⁺ into xn (n,), P⁺ into Pn (n, n),
    work (n, m+2) = [K | Δx = Kν | diag(K S Kᵀ)], small (2m+1, m) = [S; S⁻¹; ν].
    Returns (code, NIS, clamped); code is OK, or GENERAL / NOT_PD with no
    output written (the caller's general path then handles gating,
    non-finite values or the singular S).
    """
    n = x.shape[0]
    m = z.shape[0]
    for a in range(m):
        q = z[a] - x[i0 + a]
        s = P[i0 + a, i0 + a] + R[a]
        q *= q
        if not (q <= gate * s and q < math.inf):
            return GENERAL, math.nan, False
    S = small[:m]
    Si = small[m:2 * m]
    nu = small[2 * m]
    for a in range(m):
        nu[a] = z[a] - x[i0 + a]
        for b in range(m):
            S[a, b] = P[i0 + a, i0 + b]
        S[a, a] += R[a]
    # S⁻¹ from the Cholesky factor: S = L Lᵀ, S⁻¹ = L⁻ᵀ L⁻¹
    L = np.empty((m, m))
    if not cholesky(S, L):
        return NOT_PD, math.nan, False
    Li = np.zeros((m, m))            # L⁻¹ (lower)
    lower_inverse(L, Li)
    for a in range(m):
        for b in range(a, m):
            t = 0.0
            for k in range(b, m):
                t += Li[k, a] * Li[k, b]
            Si[a, b] = t
            Si[b, a] = t
    clamped = False
    for i in range(n):
        dx = 0.0
        kc = 0.0
        for b in range(m):
            t = 0.0
            for a in range(m):
                t += P[i, i0 + a] * Si[a, b]
            work[i, b] = t
            dx += t * nu[b]
            kc += t * P[i, i0 + b]
        work[i, m] = dx
        work[i, m + 1] = kc
        v = x[i] + dx
        if v < lo[i]:
            v = lo[i]
            clamped = True
        elif v > hi[i]:
            v = hi[i]
            clamped = True
        xn[i] = v
    for i in range(n):
        for j in range(i, n):
            a1 = 0.0
            a2 = 0.0
            for b in range(m):
                a1 += work[i, b] * P[j, i0 + b]
                a2 += work[j, b] * P[i, i0 + b]
            s = 0.5 * ((P[i, j] - a1) + (P[j, i] - a2))
            Pn[i, j] = s
            Pn[j, i] = s
    nis = 0.0
    for a in range(m):
        t = 0.0
        for b in range(m):
            t += Si[a, b] * nu[b]
        nis += nu[a] * t
    return OK, nis, clamped


def add_torque_noise(Qb, u, a, r, q2, gain, Q):             # pragma: no cover - compiled
    """Q = Qb + diag((σ_i² + q2)·gain, i < 4) with σ_i = a + r|M_d,i| (Estimator._Q)."""
    n = Qb.shape[0]
    for i in range(n):
        for j in range(n):
            Q[i, j] = Qb[i, j]
    for i in range(4):
        sm = a + r * abs(u[i])
        Q[i, i] += (sm * sm + q2) * gain


def add_kappa_noise(Q, x, u, kc, J, iw, c):                 # pragma: no cover - compiled
    """Q += g gᵀ·c, the process noise of the curvature input's uncertainty (Estimator._Q; c = σ_κ² τ Δt):
    g_v = ∂v̇/∂κ (row 4) and g_i = ∂ω̇_i/∂κ of the wheel speeds (rows iw..iw+3, J their inertia) of the state x
    under u, kc = FilterModel._kc.

    In eq. 8 κ moves the front forces' direction, F_h cos δ (∂cos δ/∂κ, model doc "Kinematics in turns"), and
    through the lateral load transfer each wheel's load, ∂F_z,i/∂κ = ∓λ m v² h_cg/b (zero where the transfer is
    at its limit; model doc "Lateral load transfer"); in eq. 2 the load moves the wheel's ground and rolling-
    resistance torque r_d (μ_i + ρ_t sign ω_i) F_z,i, whose radius follows the load (eq. 9:
    ∂(r_d F_z)/∂F_z = 2 r_d − r0)."""
    kap = u[6]
    hb, L, m, rho_t = kc[7], kc[8], kc[6], kc[4]
    fzf = u[4]
    ff = 0.5 * fzf
    fr = 0.5 * (kc[0] - fzf)
    if kc[9] != 0.0:
        fr = 0.5 * ((kc[0] - fzf) + u[5] * kc[9])
    rdf = _vehicle._radius(ff, kc[3], kc[1], kc[2])
    rdr = _vehicle._radius(fr, kc[3], kc[1], kc[2])
    lat = _vehicle._lateral_on(kc, kap)
    lw = np.empty(12)
    _vehicle._wheel_terms(kc, lat, x[4], kap, ff, fr, rdf, rdr, lw)
    v2 = x[4] * x[4]
    df = np.zeros(4)
    if lat:
        for j in (0, 2):
            ca = kc[16] if j == 0 else kc[17]
            half = ff if j == 0 else fr
            d = ca * (v2 * kap)
            if d < 0.9 * half and d > -0.9 * half:
                df[j] = -ca * v2
                df[j + 1] = ca * v2
    d = L * kap
    a0 = 1.0 - hb * kap
    a1 = 1.0 + hb * kap
    n0 = a0 * a0 + d * d
    n1 = a1 * a1 + d * d
    dc0 = d * (-hb * d - a0 * L) / (n0 * math.sqrt(n0))
    dc1 = d * (hb * d - a1 * L) / (n1 * math.sqrt(n1))
    gv = x[5] * lw[0] * dc0 + x[6] * lw[1] * dc1
    if lat:
        gv += x[5] * (a0 / math.sqrt(n0)) * df[0] + x[6] * (a1 / math.sqrt(n1)) * df[1] + x[7] * df[2] + x[8] * df[3]
    g = np.zeros(5)
    for i in range(4):
        w = x[iw + i]
        sg = 1.0 if w > 0.0 else (-1.0 if w < 0.0 else 0.0)
        g[i] = -((2.0 * lw[4 + i] - kc[3]) * (x[5 + i] + rho_t * sg) * df[i]) / J
    g[4] = gv / m
    for a in range(5):
        ia = iw + a if a < 4 else 4
        for b in range(5):
            ib = iw + b if b < 4 else 4
            Q[ia, ib] += (g[a] * g[b]) * c


def estimate_outputs(x, P, rdf, rdr, c_mu, c_rho, kap, hb, wb, kv, bound, out, kc, u):  # pragma: no cover - compiled
    """out (26,) = [μ (4), slip (4, eq. 6 as model.vehicle.slip), ω (4), diag P (10), k (4)] of the state x,
    k the wheels' ground speeds over v at path curvature ``kap`` (Estimator._wheel_factors: half track ``hb``,
    wheelbase ``wb``), slip i that of ω_i against k_i·v, each wheel rolling on its own radius (rdf, rdr of the
    axle loads, and the lateral load transfer: :func:`~tractionecu.model.vehicle.wheel_radii` with kc, u).  Returns bit 0: every P_μμ < c_mu and P_ρρ < c_rho
    (not for NaN); bit 1: every wheel's slip σ within ``bound`` (Estimator._slip_supported, with the
    curvature variance ``kv``).  The same operations as those two methods and the numpy path."""
    h = hb * kap
    lk = wb * kap
    left = 1.0 - h
    right = 1.0 + h
    out[22] = math.sqrt(left * left + lk * lk)
    out[23] = math.sqrt(right * right + lk * lk)
    out[24] = left
    out[25] = right
    rw = np.empty(4)
    _vehicle.wheel_radii(kc, u, x[4], kap, rdf, rdr, rw)
    for i in range(4):
        va = abs(x[4] * out[22 + i])
        w = x[i]
        vw = abs(rw[i] * w)
        if vw < 1e-6 and va < 1e-6:
            s = 0.0
        elif va <= vw:
            s = 1.0 - va / vw
        elif va != 0.0:
            s = -1.0 + vw / va
        else:
            s = math.nan
        out[i] = x[5 + i]
        out[4 + i] = s
        out[8 + i] = w
    conv = True
    n = x.shape[0]
    for j in range(n):
        p = P[j, j]
        out[12 + j] = p
        if 5 <= j <= 8 and not p < c_mu:
            conv = False
    if not P[9, 9] < c_rho:
        conv = False
    ok = True
    if bound > 0.0:
        # wheel_speed_factor_slopes(kap, 2 hb, wb) when the curvature's variance is positive, else 0
        d0 = d1 = d2 = d3 = 0.0
        if kv > 0.0:
            th = 0.5 * (2.0 * hb)
            lft = 1.0 - th * kap
            rgt = 1.0 + th * kap
            lk2 = wb * kap
            d0 = (-th * lft + wb * lk2) / math.sqrt(lft * lft + lk2 * lk2)
            d1 = (th * rgt + wb * lk2) / math.sqrt(rgt * rgt + lk2 * lk2)
            d2 = -th
            d3 = th
        pv = P[4, 4]
        v = x[4]
        lim = bound * bound
        for i in range(4):
            dk = d0 if i == 0 else (d1 if i == 1 else (d2 if i == 2 else d3))
            ki = out[22 + i]
            vw = rw[i] * x[i]
            vi = v * dk
            if not pv * ki * ki + vi * vi * kv <= lim * vw * vw:        # (NaN: not supported either)
                ok = False
                break
    return (1 if conv else 0) + (2 if ok else 0)


def process_noise(q_tune, fdt, A, inputs, rd, x, rho_t, J, g_v, c_fz, c_fd, Q):  # pragma: no cover - compiled
    """Estimator._rebuild_Q's Q (n, n), same operations: diag(q_tune·(f Δt)·A); with the input noise
    (``inputs``) plus g gᵀ·c_fz, g_i = ∓½ r_d,i (μ_i + ρ_t)/J for the wheels (μ_i = x[5 + i]), g_4 = g_v,
    and c_fd added to the v diagonal."""
    n = q_tune.shape[0]
    g = np.zeros(n)
    if inputs:
        for i in range(4):
            s = -0.5 if i < 2 else 0.5
            g[i] = ((s * rd[i]) * (x[5 + i] + rho_t)) / J
        g[4] = g_v
    for i in range(n):
        for j in range(n):
            q = (q_tune[i] * fdt) * A[i] if i == j else 0.0
            if inputs:
                q = q + (g[i] * g[j]) * c_fz
            Q[i, j] = q
    if inputs:
        Q[4, 4] += c_fd


def cm_push(emp, mod, i, dx, ksk):                          # pragma: no cover - compiled
    """Row i of the covariance-matching window: emp[i] = Δx², mod[i] = diag(K S Kᵀ) (CovarianceMatching.push)."""
    for j in range(dx.shape[0]):
        emp[i, j] = dx[j] * dx[j]
        mod[i, j] = ksk[j]


def cm_ratio(emp, mod, a_min, a_max, out):                  # pragma: no cover - compiled
    """A (n,) into out from the window (CovarianceMatching.compute, same operations): the column sums of emp
    and mod in row order (numpy's sum over axis 0 of a C-ordered array), their ratio, 1 where it is not
    finite (a zero sum included), clipped to [a_min, a_max]."""
    npt, n = emp.shape
    for j in range(n):
        se = emp[0, j]
        sm = mod[0, j]
        for i in range(1, npt):
            se += emp[i, j]
            sm += mod[i, j]
        r = 1.0
        if sm != 0.0:
            r = se / sm
            if not math.isfinite(r):
                r = 1.0
        if r < a_min:
            r = a_min
        elif r > a_max:
            r = a_max
        out[j] = r


def _fmin(a, b):                                            # pragma: no cover - compiled
    """supervisor._min: NaN if either is NaN."""
    if a != a or b != b:
        return math.nan
    return a if a <= b else b


def _fmax(a, b):                                            # pragma: no cover - compiled
    """supervisor._max: NaN if either is NaN."""
    if a != a or b != b:
        return math.nan
    return a if a >= b else b


def _tri(x, a, b, c):                                       # pragma: no cover - compiled
    """supervisor._tri1 (triangle membership of one float), same operations."""
    left = 1.0 if b == a else (x - a) / (b - a)
    right = 1.0 if c == b else (c - x) / (c - b)
    y = 0.0 if (x < a or x > c) else _fmin(left, right)
    return _fmin(_fmax(y, 0.0), 1.0)


def _trap(x, a, b, c, d):                                   # pragma: no cover - compiled
    """supervisor._trap1 (trapezoid membership of one float), same operations."""
    rise = 1.0 if b == a else (x - a) / (b - a)
    fall = 1.0 if (d == c or math.isinf(d)) else (d - x) / (d - c)
    y = _fmin(_fmin(rise, 1.0), fall)
    if x < a or (not math.isinf(d) and x > d):
        y = 0.0
    return _fmin(_fmax(y, 0.0), 1.0)


def fuzzy_strengths(e1, e2, a1, a2, a3, m1, m2, m3, rules, out):  # pragma: no cover - compiled
    """The three rule strengths of FuzzySupervisor.intensity into out (3,): memberships of e₁ = |dv/dt| and
    e₂ = |dM/dt| (LOW, MEDIUM, HIGH; breakpoints a, m), AND = min, one strength per output set = max over
    the rule table ``rules`` (3, 3); supervisor._degrees and its loop, same operations."""
    p0 = _trap(e1, 0.0, 0.0, a1, a2)
    p1 = _tri(e1, a1, a2, a3)
    p2 = _trap(e1, a2, a3, math.inf, math.inf)
    q0 = _trap(e2, 0.0, 0.0, m1, m2)
    q1 = _tri(e2, m1, m2, m3)
    q2 = _trap(e2, m2, m3, math.inf, math.inf)
    out[0] = 0.0
    out[1] = 0.0
    out[2] = 0.0
    for i in range(3):
        pi = p0 if i == 0 else (p1 if i == 1 else p2)
        for j in range(3):
            qj = q0 if j == 0 else (q1 if j == 1 else q2)
            k = rules[i, j]
            out[k] = _fmax(out[k], _fmin(pi, qj))


def fuzzy_centroid(s0, s1, s2, fz):                            # pragma: no cover - compiled
    """The defuzzified intensity c of the rule strengths s_k (FuzzySupervisor.intensity): the centroid of the
    aggregated output set agg (G,) = max_k min(s_k, out_mf[k]) (clip, then aggregate) by the trapezoid rule,
    Σ agg·x·w / Σ agg·w, summed in grid order; 0.5 where the set is empty, NaN for a NaN strength.
    ``fz`` (5, G): the three output sets, the trapezoid weights w and x·w over the universe's grid x."""
    if s0 != s0 or s1 != s1 or s2 != s2:
        return math.nan
    g = fz.shape[1]
    area = 0.0
    num = 0.0
    for j in range(g):
        a = fz[0, j]
        if s0 < a:
            a = s0
        b = fz[1, j]
        if s1 < b:
            b = s1
        c = fz[2, j]
        if s2 < c:
            c = s2
        if b > a:
            a = b
        if c > a:
            a = c
        area += a * fz[3, j]
        num += a * fz[4, j]
    if area <= 0.0:
        return 0.5
    return num / area


_rk4_points = _vehicle._rk4_points

cholesky = compiled(cholesky, inline=True)
lower_inverse = compiled(lower_inverse, inline=True)
sigma_factor = compiled(sigma_factor, inline=True)
sigma_points = compiled(sigma_points)
mean_cov = compiled(mean_cov)
_predict_points = compiled(_make_predict_points(_model_tag()), inline=True)
predict_model = compiled(_make_predict_model(_model_tag(), False))
gain_solve = compiled(gain_solve)
cross_gain = compiled(cross_gain)
pair_gain = compiled(pair_gain)
gain_compose = compiled(gain_compose)
predict_model_gain = compiled(_make_predict_model(_model_tag(), True))
update_block = compiled(update_block)
add_torque_noise = compiled(add_torque_noise)
add_kappa_noise = compiled(add_kappa_noise)
estimate_outputs = compiled(estimate_outputs)
process_noise = compiled(process_noise)
cm_push = compiled(cm_push)
cm_ratio = compiled(cm_ratio)
_fmin = compiled(_fmin, inline=True)
_fmax = compiled(_fmax, inline=True)
_tri = compiled(_tri, inline=True)
_trap = compiled(_trap, inline=True)
fuzzy_strengths = compiled(fuzzy_strengths)
fuzzy_centroid = compiled(fuzzy_centroid)

_warm = False


def warm_up() -> None:
    """Compile every kernel now (or load it from numba's on-disk cache) instead of on the first step.

    With a cache this takes ≈ 0.1–0.3 s, without one a few seconds; afterwards
    it returns at once.  Without numba it does nothing.  Kernels not warmed up
    compile on first use, so calling this is optional (a service can call it,
    or step a throwaway estimator, before its real-time loop starts).
    """
    global _warm
    if _warm or not JIT:
        return
    from ..config import VehicleParams
    from ..model.vehicle import FilterModel

    n = 10
    x = np.array([3.0, 3.0, 3.0, 3.0, 2.4, 0.3, 0.3, 0.3, 0.3, 0.06])
    P = np.eye(n) * 1e-3
    u = np.array([2000.0, 2000.0, 3000.0, 3000.0, 25000.0, 10000.0])
    kc = FilterModel(VehicleParams())._kc
    w = np.full(1 + 2 * (2 * n + 1), 0.05)
    sig = np.empty((2 * n + 1, n))
    predict_model(x, P, u, 0.01, P, w, kc, sig, np.empty(n), np.empty((n, n)))
    G = np.empty((n, n))
    predict_model_gain(x, P, u, 0.01, P, w, kc, sig, np.empty(n), np.empty((n, n)), G)
    cross_gain(sig, sig, w[22:], x, x, P, G)
    gain_compose(G, P, True)
    gain_compose(G, P, False)
    _rk4_points(sig, u, kc, 0.01)
    _rk4_points(sig[:1].copy(), u, kc, 0.01)
    sigma_points(x, P, 1.0, sig)
    mean_cov(sig, w[1:22], w[22:], P, np.empty(n), np.empty((n, n)))
    lo, hi = np.full(n, -np.inf), np.full(n, np.inf)
    for m in (1, 4, 5):
        update_block(x, P, x[:m].copy(), np.full(m, 1e-4), 0, math.inf, lo, hi, np.empty(n), np.empty((n, n)),
                     np.empty((n, m + 2)), np.empty((2 * m + 1, m)))
    add_torque_noise(P, u, 1.0, 0.01, 0.1, 1e-6, np.empty((n, n)))
    estimate_outputs(x, P, 0.78, 0.78, 1e-4, 1e-4, 0.01, 0.9, 2.5, 1e-6, 0.0125, np.empty(26), kc, u)
    add_kappa_noise(np.zeros((n, n)), x, u, kc, 2.0, 0, 1e-6)
    process_noise(x, 0.01, x, True, x[:4], x, 0.01, 2.0, 0.1, 1e-6, 1e-6, np.empty((n, n)))
    process_noise(x, 0.01, x, False, x[:4], x, 0.01, 2.0, 0.0, 0.0, 0.0, np.empty((n, n)))
    emp = np.zeros((4, n))
    cm_push(emp, emp.copy(), 0, x, x)
    cm_push(emp, emp.copy(), 0, sig[:, 0], sig[:, 1])
    cm_ratio(emp, emp + 1.0, 0.1, 10.0, np.empty(n))
    fuzzy_centroid(1.0, 0.0, 0.0, np.ones((5, 11)))
    fuzzy_strengths(0.1, 3000.0, 0.06, 0.15, 0.3, 2000.0, 5000.0, 1e4, np.zeros((3, 3), dtype=np.int64), np.empty(3))
    _warm = True
