"""The compiled numeric core of the μ(s) curve update (:mod:`.curve`), shared by both estimator paths.

:meth:`.curve.CurveEstimator.update` with one class (what :class:`~.estimator.Estimator`, the machine
estimator and the compiled loop of batch replay ask for) and :meth:`.curve.ShapeIdentifier.update` run
here: the forgetting of the a sums, the choice of the wheels' pairs, g(ŝ) and the weighted a sums
(eq. 18), the shape identification's change test (residual against the nearest bin, two-sided CUSUM),
the binning of the pairs, the history kept for a new segment's take-over, the move of the confirmed
pairs to the fit's bins and the weight cap.  What stays in Python is rare: the close of a soil segment
(the soils' pooling, :meth:`~.curve.ShapeIdentifier._close_soil`), the once-a-second span, soil match
and fit (:meth:`~.curve.ShapeIdentifier._maybe_fit`), and the state objects.  The step path calls
:func:`ce_update` from :meth:`~.curve.CurveEstimator.update`; the compiled loop
(:mod:`._loop_kernel`) calls the same function from compiled code, so the two paths share one
implementation, operation for operation.

The exponentials of g(ŝ) and of the change test's slope are the C library's exp (numba's ``math.exp``,
CPython's ``math.exp``); ``x ** 2`` in the change test is the C library's pow(x, 2.0), as in Python (the
exponent is read from the state so that the compiler cannot turn it into x·x); Python's ``min``/``max``
are written out with their comparison order (NaN kept as Python keeps it); sums are sequential.

State (arrays owned by the Python objects, handed in):

* ``C`` (float64, :data:`C_SIZE` + 3 n_classes): the curve estimator's last time, its constants and the
  per-class sums Σ w μ̂, Σ w g(ŝ) and the class evidence (at :data:`C_NUM`, one block of n_classes each);
* ``S`` (float64, :data:`S_SIZE`): the shape identification's constants, CUSUM sums and times;
* ``SI`` (int64, :data:`SI_SIZE`): its history ring's positions and flags;
* ``B`` (6, N_BINS): the segment's bins (W, Σws, Σws², Σwμ, Σwμ², Σwz; :class:`~.curve.PairBins`);
* ``MT`` (6, N_BINS · groups): the confirmed (mature) bins;
* ``HT`` (cap, 3): the history's instants (t, first pair's position, number of pairs), a ring;
* ``HP`` (cap_pairs, 5): the history's pairs (bin, weight, |ŝ|, |μ̂|, relative load z), a ring;
* ``PD`` (n_max, 5): the instant's pairs between the change test and the binning.
"""

from __future__ import annotations

import math

import numpy as np

from ..model.vehicle import JIT, compiled

MU_BIN_WIDTH = 0.02          # curve.MU_BIN_WIDTH (copies: numba freezes globals; test_curve_speed holds them equal)
N_BINS = 75                  # curve.PairBins.N_BINS
LOAD_EDGE_LO, LOAD_EDGE_HI = -0.12, 0.12     # curve.LOAD_EDGES
NEAR = (0, -1, 1, -2, 2, -3, 3)              # curve._NEAR

# return codes
DONE = 0
ALARM = 1          # the change test fired: the caller closes the segment (S[S_T_FROM]) and calls shape_post
CHECK = 2          # the once-a-second check is due (weight cap done): the caller runs the span / fit
GROW = 3           # the history ring is too small for this instant: nothing was changed; grow and call again

# C: the curve estimator
C_T, C_HAS_T, C_NUSED, C_TAU, C_CTAU, C_MINMU, C_MINSLIP, C_P, C_A1, C_A2, C_Q, C_REF, C_DT, C_LAM, C_LAMC = range(15)
C_NUM = 16
"""Start of the per-class sums: Σ w μ̂ (n_classes), Σ w g(ŝ) (n_classes), evidence (n_classes)."""
C_SIZE = C_NUM

# S: the shape identification
(S_SLIPCORR, S_WMIN, S_K, S_H, S_MAXW, S_HIST, S_CONFIRM, S_P, S_A1, S_A2, S_Q, S_TWO,
 S_CP, S_CN, S_TCP, S_TCN, S_TCHECK, S_TLAST, S_WFIT, S_T_FROM, S_DISCOUNT, S_T) = range(22)
S_SIZE = 22
# SI
SI_HHEAD, SI_YHEAD, SI_TAIL, SI_PTAIL, SI_LOAD, SI_NPEND = range(6)
SI_SIZE = 6


def shape_pre(S, SI, B, HT, HP, PD, t, dt, mu, s, ss, z, mb, n):        # pragma: no cover - compiled
    """ShapeIdentifier.update up to the new segment: the change test over the n pairs (|μ̂| ``mu``, |ŝ| ``s``,
    σ_s ``ss``, relative load ``z``, binning adhesion ``mb``), the pairs into PD.  GROW (nothing changed) when
    the history cannot take the instant, ALARM when the CUSUM fired (S[S_T_FROM]: the new segment's start),
    else DONE."""
    cap = HT.shape[0]
    capp = HP.shape[0]
    hh = SI[SI_HHEAD]
    used_p = SI[SI_PTAIL] - (int(HT[hh % cap, 1]) if SI[SI_TAIL] > hh else SI[SI_PTAIL])
    if SI[SI_TAIL] - hh + 1 > cap or used_p + n > capp or n > PD.shape[0]:
        return GROW
    S[S_TLAST] = t
    if dt > 0:
        v = dt / S[S_SLIPCORR]
        discount = v if v < 1.0 else 1.0                  # min(1.0, dt / slip_corr)
    else:
        discount = 1.0
    S[S_DISCOUNT] = discount
    S[S_T] = t
    W = B[0]
    S1 = B[1]
    S2 = B[2]
    M1 = B[3]
    wmin = S[S_WMIN]
    last = N_BINS - 1
    w_pair = discount / n
    z_sum = 0.0
    nz = 0
    p0 = S[S_P]
    a10 = S[S_A1]
    a20 = S[S_A2]
    q0 = S[S_Q]
    for i in range(n):
        m = abs(mu[i])
        x = abs(s[i])
        sv = ss[i]
        kv = abs(mb[i]) / MU_BIN_WIDTH
        k = last if kv >= last else int(kv)               # min(int(|μ_bin| / width), last)
        for d in NEAR:                                    # the nearest bin with enough weight
            j = k + d
            if j < 0 or j > last:
                continue
            if W[j] >= wmin:
                wj = W[j]                                 # residual against that bin's mean slip,
                sj = S1[j] / wj                           # moved to μ̂ along the class slope
                mj = M1[j] / wj
                if j != k:
                    e1 = math.exp(a10 * sj)
                    e2 = math.exp(a20 * sj)
                    dg = -p0 * a10 * e1 - q0 * a20 * e2
                    gj = 1.0 - p0 * e1 - q0 * e2
                    if dg > 0 and gj > 0:
                        sj += (m - mj) * gj / (mj * dg)   # ds/dμ = 1/(a g'(s)), a = μ̄/g(s̄)
                # max(S2/w − (S1/w)**2, σ_s² (0 for NaN), 1e-6) · (1 + 1/w), Python's max
                var = S2[j] / wj - math.pow(S1[j] / wj, S[S_TWO])
                b = sv * sv if sv == sv else 0.0
                if b > var:
                    var = b
                if 1e-6 > var:
                    var = 1e-6
                var = var * (1.0 + 1.0 / wj)
                z_sum += (x - sj) / math.sqrt(var)
                nz += 1
                break
        PD[i, 0] = k
        PD[i, 1] = w_pair
        PD[i, 2] = x
        PD[i, 3] = m
        PD[i, 4] = z[i]
    SI[SI_NPEND] = n
    if nz:
        zz = z_sum / nz                                   # the wheels of one instant: one sample
        cp = S[S_CP] + discount * (zz - S[S_K])
        cp = cp if cp > 0.0 else 0.0                      # max(0.0, ...)
        cn = S[S_CN] + discount * (-zz - S[S_K])
        cn = cn if cn > 0.0 else 0.0
        if cp > 0 and S[S_CP] == 0:
            S[S_TCP] = t
        if cn > 0 and S[S_CN] == 0:
            S[S_TCN] = t
        S[S_CP] = cp
        S[S_CN] = cn
        h = S[S_H]
        if cp > h or cn > h:
            S[S_T_FROM] = S[S_TCP] if cp > h else S[S_TCN]
            return ALARM
    return DONE


def _add(A, k, w, x, m, zz):                                              # pragma: no cover - compiled
    """PairBins.add, same operations."""
    A[0, k] += w
    ws = w * x
    A[1, k] += ws
    A[2, k] += ws * x
    wm = w * m
    A[3, k] += wm
    A[4, k] += wm * m
    A[5, k] += w * zz


def new_segment(S, SI, B, MT, HT, HP, t_from):                            # pragma: no cover - compiled
    """ShapeIdentifier._new_segment after the soil's close: the history's instants at or after ``t_from``
    (in order) are the new segment's, its bins rebuilt from them; the fit's bins emptied, every young;
    the CUSUM, the check time and the fit's weight reset."""
    cap = HT.shape[0]
    capp = HP.shape[0]
    hh = SI[SI_HHEAD]
    tail = SI[SI_TAIL]
    B[:, :] = 0.0
    MT[:, :] = 0.0
    wi = hh
    wp = int(HT[hh % cap, 1]) if tail > hh else SI[SI_PTAIL]
    for r in range(hh, tail):
        e = r % cap
        if not HT[e, 0] >= t_from:
            continue
        st = int(HT[e, 1])
        cnt = int(HT[e, 2])
        t_e = HT[e, 0]
        o = wi % cap
        HT[o, 0] = t_e
        HT[o, 1] = wp
        HT[o, 2] = cnt
        for q in range(cnt):
            src = (st + q) % capp
            dst = (wp + q) % capp
            if src != dst:
                for c in range(5):
                    HP[dst, c] = HP[src, c]
            _add(B, int(HP[dst, 0]), HP[dst, 1], HP[dst, 2], HP[dst, 3], HP[dst, 4])
        wp += cnt
        wi += 1
    SI[SI_TAIL] = wi
    SI[SI_PTAIL] = wp
    SI[SI_YHEAD] = hh
    S[S_TCHECK] = -math.inf
    S[S_WFIT] = 0.0
    S[S_CP] = 0.0
    S[S_CN] = 0.0
    S[S_TCP] = -math.inf
    S[S_TCN] = -math.inf


def shape_post(S, SI, B, MT, HT, HP, PD):                                 # pragma: no cover - compiled
    """ShapeIdentifier.update after the change test: the instant's pairs (PD) into the bins and the history,
    the confirmed instants into the fit's bins, and, once a second, the weight cap; CHECK then (the caller
    runs the span and fit), else DONE."""
    cap = HT.shape[0]
    capp = HP.shape[0]
    n = SI[SI_NPEND]
    t = S[S_T]
    for i in range(n):
        _add(B, int(PD[i, 0]), PD[i, 1], PD[i, 2], PD[i, 3], PD[i, 4])
    tail = SI[SI_TAIL]
    pt = SI[SI_PTAIL]
    e = tail % cap
    HT[e, 0] = t
    HT[e, 1] = pt
    HT[e, 2] = n
    for i in range(n):
        o = (pt + i) % capp
        for c in range(5):
            HP[o, c] = PD[i, c]
    SI[SI_TAIL] = tail + 1
    SI[SI_PTAIL] = pt + n
    SI[SI_NPEND] = 0
    t_h = t - S[S_HIST]
    while HT[SI[SI_HHEAD] % cap, 0] < t_h:                 # (never empty: the instant just added is not older)
        SI[SI_HHEAD] += 1
    t_old = t - S[S_CONFIRM]
    load = SI[SI_LOAD] != 0
    while SI[SI_YHEAD] < SI[SI_TAIL] and HT[SI[SI_YHEAD] % cap, 0] <= t_old:
        r = SI[SI_YHEAD] % cap
        st = int(HT[r, 1])
        for q in range(int(HT[r, 2])):
            o = (st + q) % capp
            k = int(HP[o, 0])
            zz = HP[o, 4]
            if load:
                k += (0 if zz < LOAD_EDGE_LO else (2 if zz > LOAD_EDGE_HI else 1)) * N_BINS
            _add(MT, k, HP[o, 1], HP[o, 2], HP[o, 3], zz)
        SI[SI_YHEAD] += 1
    if t - S[S_TCHECK] >= 1.0:
        S[S_TCHECK] = t
        total = 0.0                                       # sum(W), sequential
        for k in range(B.shape[1]):
            total += B[0, k]
        if total > S[S_MAXW]:                             # ShapeIdentifier._cap_weight
            f = S[S_MAXW] / total
            for r in range(6):
                for k in range(B.shape[1]):
                    B[r, k] = B[r, k] * f
                for k in range(MT.shape[1]):
                    MT[r, k] = MT[r, k] * f
            for r in range(SI[SI_HHEAD], SI[SI_TAIL]):
                ee = r % cap
                st = int(HT[ee, 1])
                for q in range(int(HT[ee, 2])):
                    o = (st + q) % capp
                    HP[o, 1] = HP[o, 1] * f
            S[S_WFIT] = S[S_WFIT] * f
        return CHECK
    return DONE


def ce_update(C, S, SI, B, MT, HT, HP, PD, SC, t, mu, s, sm, ss, fz, has_shape, has_ss, has_fz):  # pragma: no cover
    """CurveEstimator.update with one class (:meth:`.curve.CurveEstimator._update_one`): the forgetting, the a
    sums of the wheels' pairs (μ̂ ``mu``, ŝ ``s``, σ_μ ``sm``; σ_s ``ss`` when ``has_ss``; wheel loads ``fz``
    when ``has_fz`` and the reference load is positive) and, with ``has_shape``, the shape identification's
    pairs (:func:`shape_pre`; then :func:`shape_post` unless the change test fired).  ``SC`` (4, n): scratch
    for the shape's pairs.  Returns GROW (nothing changed), ALARM, CHECK or DONE."""
    n = mu.shape[0]
    if has_shape:                                         # (room in the history first: GROW changes nothing)
        cap = HT.shape[0]
        hh = SI[SI_HHEAD]
        used_p = SI[SI_PTAIL] - (int(HT[hh % cap, 1]) if SI[SI_TAIL] > hh else SI[SI_PTAIL])
        if SI[SI_TAIL] - hh + 1 > cap or used_p + n > HP.shape[0] or n > PD.shape[0] or n > SC.shape[1]:
            return GROW
    if C[C_HAS_T] != 0.0:
        x = t - C[C_T]
        dt = 0.0 if 0.0 > x else x                        # max(t − t_last, 0.0)
    else:
        dt = 0.0
    C[C_T] = t
    C[C_HAS_T] = 1.0
    C[C_DT] = dt
    lam = math.exp(-dt / C[C_TAU])
    lam_c = math.exp(-dt / C[C_CTAU])
    C[C_NUM] *= lam
    C[C_NUM + 1] *= lam
    C[C_NUM + 2] *= lam_c
    min_mu = C[C_MINMU]
    min_slip = C[C_MINSLIP]
    ref = C[C_REF]
    use_fz = has_fz and ref > 0
    n_ok = 0
    p = C[C_P]
    a1 = C[C_A1]
    a2 = C[C_A2]
    q = C[C_Q]
    num = 0.0
    den = 0.0
    nw = 0
    for i in range(n):
        m = mu[i]
        x = s[i]
        # |μ̂| ≥ min_mu, same sign, both finite (math.isfinite ⇔ |v| < inf once m x > 0 holds)
        if m * x > 0 and abs(m) >= min_mu and abs(m) < math.inf and abs(x) < math.inf:
            if has_shape and abs(x) >= min_slip:
                SC[0, n_ok] = m
                SC[1, n_ok] = x
                SC[2, n_ok] = ss[i] if has_ss else 0.0
                if use_fz:
                    f = fz[i]
                    SC[3, n_ok] = f / ref - 1.0 if f == f else 0.0
                else:
                    SC[3, n_ok] = 0.0
                n_ok += 1
            # g(ŝ) of the class (SoilClass.g: 1 − p e^{α1|ŝ|} − (1−p) e^{α2|ŝ|}, with the sign of ŝ)
            sa = abs(x)
            e1 = math.exp(a1 * sa)
            e2 = math.exp(a2 * sa)
            g = (1.0 - p * e1 - q * e2) if x > 0 else -(1.0 - p * e1 - q * e2)
            # solve_a_array's conditions (its error bound is not used: max_rel_err = inf)
            if not (abs(x) >= min_slip and abs(g) > 1e-9):
                continue
            a = m / g
            if not a > 0:
                continue
            sg = sm[i]
            sg = sg if (sg != sg or sg >= 1e-6) else 1e-6   # np.maximum(σ_μ, 1e-6), NaN kept
            w = 1.0 / (sg * sg) * g
            if nw == 0:
                num = w * a
                den = w
            else:
                num += w * a
                den += w
            nw += 1
    if nw:
        C[C_NUM] += num       # = Σ w μ̂
        C[C_NUM + 1] += den   # = Σ w g(ŝ)
    C[C_NUSED] = nw
    if not (has_shape and n_ok):
        return DONE
    r = shape_pre(S, SI, B, HT, HP, PD, t, dt, SC[0], SC[1], SC[2], SC[3], SC[0], n_ok)
    if r != DONE:
        return r
    return shape_post(S, SI, B, MT, HT, HP, PD)


shape_pre = compiled(shape_pre)
_add = compiled(_add)
new_segment = compiled(new_segment)
shape_post = compiled(shape_post)
ce_update = compiled(ce_update)


_warm = False


def warm_up() -> None:
    """Compile the update now (or load it from numba's on-disk cache) instead of at the first curve update, which
    on the step path comes seconds into a real-time loop (the service steps a throwaway estimator before its loop,
    and a CurveEstimator calls this when it is made).  Afterwards it returns at once; without numba it does nothing."""
    global _warm
    if _warm or not JIT:
        return
    _warm = True
    C = np.zeros(C_SIZE + 3)
    C[C_TAU], C[C_CTAU], C[C_MINMU], C[C_MINSLIP], C[C_REF] = 5.0, 30.0, 0.15, 0.005, 20000.0
    C[C_P], C[C_A1], C[C_A2], C[C_Q] = 0.5, -10.0, -20.0, 0.5
    S = np.zeros(S_SIZE)
    S[S_SLIPCORR], S[S_WMIN], S[S_K], S[S_H], S[S_MAXW], S[S_HIST], S[S_CONFIRM] = 0.5, 2.0, 0.5, 4.0, 2000.0, 10.0, 5.0
    S[S_P], S[S_A1], S[S_A2], S[S_Q], S[S_TWO] = 0.5, -10.0, -20.0, 0.5, 2.0
    SI = np.zeros(SI_SIZE, dtype=np.int64)
    B, MT = np.zeros((6, N_BINS)), np.zeros((6, N_BINS))
    HT, HP, PD, SC = np.zeros((8, 3)), np.zeros((32, 5)), np.zeros((4, 5)), np.zeros((4, 4))
    mu, s, sg = np.full(4, 0.4), np.full(4, 0.05), np.full(4, 0.02)
    for k in range(3):
        ce_update(C, S, SI, B, MT, HT, HP, PD, SC, 0.1 * k, mu, s, sg, sg, mu, True, True, True)
    ce_update(C, S, SI, B, MT, HT, HP, PD, SC, 1.0, mu, s, sg, sg, mu, False, False, False)
    shape_pre(S, SI, B, HT, HP, PD, 2.0, 0.1, mu, s, sg, sg, mu, 4)
    shape_post(S, SI, B, MT, HT, HP, PD)
    new_segment(S, SI, B, MT, HT, HP, 0.0)
