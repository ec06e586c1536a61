"""The estimator's compiled bookkeeping against the numpy code it replaces: equal bit for bit.

Each fast path (compiled kernels of :mod:`tractionecu.estimation._kernels`,
memoised or cached values) keeps its numpy form as the reference (the path
taken without numba, ``TRACTIONECU_JIT=0``).  These tests run both on the
same inputs and demand identical results, down to the last bit, for the
pieces alone and for whole estimator runs.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from est_synth import synth_run

from tractionecu.config import VehicleParams
from tractionecu.estimation import estimator as est_mod
from tractionecu.estimation import supervisor as sup_mod
from tractionecu.estimation.estimator import Estimator, EstimatorConfig
from tractionecu.estimation.supervisor import CovarianceMatching, DynamicsMonitor, FuzzySupervisor
from tractionecu.model import vehicle

needs_jit = pytest.mark.skipif(not vehicle.JIT, reason="numba not installed, or TRACTIONECU_JIT=0")


def _same(a, b) -> bool:
    """Equal bit for bit (NaN where NaN)."""
    a, b = np.asarray(a), np.asarray(b)
    if not np.array_equal(a, b, equal_nan=True):
        return False
    if a.dtype.kind != "f":
        return True
    num = ~np.isnan(a)
    return bool((np.signbit(a[num]) == np.signbit(b[num])).all())


def _corrections(rng: np.random.Generator, n: int, k: int):
    """Corrections Δx and diag(K S Kᵀ) of one update, with zeros, a column of zeros, Inf and NaN now and then."""
    dx = rng.normal(0.0, 10.0 ** rng.uniform(-6, 0), n)
    ksk = np.abs(rng.normal(0.0, 10.0 ** rng.uniform(-8, -1), n))
    if k % 7 == 0:
        ksk[rng.integers(n)] = 0.0
    if k % 11 == 0:
        dx[rng.integers(n)] = 0.0
    if k % 53 == 0:
        ksk[rng.integers(n)] = math.inf
    if k % 97 == 0:
        dx[rng.integers(n)] = math.nan
    return dx, ksk


@needs_jit
@pytest.mark.parametrize("strided", [False, True])
def test_covariance_matching_kernels_equal_numpy(monkeypatch, strided):
    """push and compute (window sums, ratio, non-finite → 1, clip) give the numpy path's A bit for bit."""
    rng = np.random.default_rng(3)
    fast = CovarianceMatching(10, 20, 0.1, 10.0)
    ref = CovarianceMatching(10, 20, 0.1, 10.0)
    work = np.empty((10, 7))
    for k in range(600):
        dx, ksk = _corrections(rng, 10, k)
        if strided:                      # columns of the update's work array, as UnscentedFilter.correction()
            work[:, 5], work[:, 6] = dx, ksk
            dx, ksk = work[:, 5], work[:, 6]
        fast.push(dx, ksk)
        monkeypatch.setattr(sup_mod, "JIT", False)
        ref.push(dx, ksk)
        a_ref = ref.compute() if k % 3 == 0 else None
        monkeypatch.setattr(sup_mod, "JIT", True)
        if a_ref is not None:
            a_fast = fast.compute()
            assert _same(a_fast, a_ref), k
        assert fast.count == ref.count and fast._i == ref._i
        assert _same(fast._emp, ref._emp) and _same(fast._mod, ref._mod)


@needs_jit
def test_fuzzy_intensity_equal_numpy(monkeypatch):
    """The compiled rule strengths and the memo give the numpy path's intensity bit for bit, NaN included; the
    centroid is one function for both (the compiled loop calls it too), checked below."""
    fz = FuzzySupervisor()
    rng = np.random.default_rng(5)
    acc = np.concatenate([rng.uniform(0.0, 0.5, 300), [0.0, 0.06, 0.15, 0.3, 1.0, math.nan, math.inf]])
    tqr = np.concatenate([rng.uniform(0.0, 15000.0, 300), [0.0, 2000.0, 5000.0, 1e4, 1e5, 0.0, 0.0]])
    for rep in range(2):                 # the second pass reads the memo
        for e1, e2 in zip(acc, tqr):
            monkeypatch.setattr(sup_mod, "JIT", False)
            ref = FuzzySupervisor().intensity(e1, e2)     # a fresh supervisor: no memo, numpy
            monkeypatch.setattr(sup_mod, "JIT", True)
            got = fz.intensity(e1, e2)
            assert _same(got, ref), (rep, e1, e2)
            assert _same(fz.factor(e1, e2), FuzzySupervisor().factor(e1, e2))


@needs_jit
def test_fuzzy_centroid_compiled_equals_its_python_and_numpy():
    """The centroid compiled gives its Python source's floats bit for bit (the same sums in grid order), and
    numpy's aggregate and dot products to rounding; 0.5 for an empty set, NaN for a NaN strength."""
    from tractionecu.estimation import _kernels

    fz = FuzzySupervisor()
    tab = fz.centroid_table
    rng = np.random.default_rng(6)
    cases = [tuple(rng.uniform(0.0, 1.0, 3)) for _ in range(300)] + [(1.0, 0.0, 0.0), (0.0, 0.0, 0.0),
                                                                      (0.0, 0.0, 1.0), (math.nan, 0.5, 0.5)]
    for s0, s1, s2 in cases:
        got = _kernels.fuzzy_centroid(s0, s1, s2, tab)
        assert _same(got, _kernels.fuzzy_centroid.py_func(s0, s1, s2, tab)), (s0, s1, s2)
        agg = np.max(np.minimum(np.array([s0, s1, s2])[:, None], fz.out_mf), axis=0)
        area = float(agg @ fz._w)
        ref = 0.5 if area <= 0.0 else float(agg @ fz._xw) / area
        if math.isnan(s0):
            assert math.isnan(got)
        else:
            assert got == pytest.approx(ref, rel=1e-13, abs=0.0), (s0, s1, s2)
    assert _kernels.fuzzy_centroid(0.0, 0.0, 0.0, tab) == 0.5


def test_dynamics_monitor_gain_cache():
    """The cached low-pass gain equals exp() computed afresh on every step (irregular steps included)."""
    dm = DynamicsMonitor(0.2)
    t, v, m, acc, tr, vv, mm = 0.0, 2.0, 1000.0, 0.0, 0.0, 2.0, 1000.0
    rng = np.random.default_rng(2)
    dm.update(t, v, m)
    for k in range(500):
        t_prev = t
        t += [0.01, 0.01, 0.02, 0.0100000001][k % 4]
        dt = t - t_prev
        v += rng.normal(0, 0.01)
        m += rng.normal(0, 50.0)
        dm.update(t, v, m)
        g = 1.0 - math.exp(-dt / 0.2)
        v_new, m_new = vv + g * (v - vv), mm + g * (m - mm)
        acc += g * ((v_new - vv) / dt - acc)
        tr += g * ((m_new - mm) / dt - tr)
        vv, mm = v_new, m_new
        assert dm.accel == acc and dm.torque_rate == tr


def _run(steps, cfg=None) -> list:
    est = Estimator(VehicleParams(), cfg or EstimatorConfig())
    out = []
    for s in steps:
        e = est.step(*s)
        out.append((e.t, e.mu, e.rho_s, e.a, e.slip, e.v, e.omega, e.P_diag, e.nis, e.adapt, e.status, e.kappa,
                    e.sys_var))
    return out


def _assert_runs_equal(fast: list, ref: list) -> None:
    assert len(fast) == len(ref)
    for k, (a, b) in enumerate(zip(fast, ref)):
        for x, y in zip(a, b):
            if x is None or y is None:
                assert x is None and y is None, k
            else:
                assert _same(x, y), k


@needs_jit
def test_estimator_with_compiled_supervisor_equals_numpy_supervisor(monkeypatch):
    """A whole estimator run (adaptation, supervisor, soil change) is bit for bit the same with the compiled
    covariance matching and fuzzy aggregation as with their numpy code."""
    run = synth_run(seed=4, duration=12.0, change=(6.0, 0.5, 0.1))
    fast = _run(run.steps)
    monkeypatch.setattr(sup_mod, "JIT", False)
    ref = _run(run.steps)
    _assert_runs_equal(fast, ref)



@needs_jit
@pytest.mark.parametrize("input_noise", [True, False])
def test_process_noise_kernel_equals_numpy(monkeypatch, input_noise):
    """Estimator._rebuild_Q (tuning × adaptation, axle-load and draft terms) compiled and in numpy: the same
    Q bit for bit, along a run with a soil change (μ̂, r_d, adaptation and supervisor moving) and before
    the filter starts."""
    from dataclasses import replace

    run = synth_run(seed=6, duration=8.0, change=(4.0, 0.5, 0.1))
    est = Estimator(VehicleParams(), replace(EstimatorConfig(), input_noise=input_noise))
    checked = 0
    for k, s in enumerate(run.steps):
        if k % 7 == 0:
            for dt in (0.01, 0.02, 0.0033):
                est._rebuild_Q(dt)
                fast = est._Qbase
                monkeypatch.setattr(est_mod, "JIT", False)
                est._rebuild_Q(dt)
                monkeypatch.setattr(est_mod, "JIT", True)
                assert _same(fast, est._Qbase), (k, dt)
                checked += 1
            est._Qbase = None
        est.step(*s)
    assert checked > 100 and est.ukf is not None


@needs_jit
def test_estimate_outputs_kernel_equals_numpy_methods():
    """estimate_outputs' wheel factors, slip and slip-support test equal Estimator._wheel_factors, _slip and
    _slip_supported (straight, in turns, reversing, creeping, standstill, NaN)."""
    from tractionecu.estimation import _kernels

    est = Estimator(VehicleParams())
    est._u[:] = [3000.0, 3000.0, 4000.0, 4000.0, 24000.0, 15000.0, 0.0]
    rng = np.random.default_rng(8)
    hb, wb = est._hb, est.vehicle.wheelbase_m
    n_unsupported = 0
    for k in range(3000):
        x = rng.normal([3, 3, 3, 3, 2.3, .3, .3, .3, .3, .06], [0.5] * 4 + [1.0] + [0.1] * 5)
        if k % 5 == 0:
            x[:5] *= [1e-3, 1e-7, 1.0, 0.0, 1e-3][k % 25 // 5]
        if k % 4 == 1:
            x[:5] *= -1.0
        A = rng.normal(size=(10, 10)) * 10.0 ** rng.uniform(-5, -1)
        P = A @ A.T
        kap = [0.0, -0.0, 0.033, -0.033, 0.25, 1e-4, math.nan][k % 7]
        kv = [0.0, 1e-6, 1e-3, 0.0625, math.nan][k % 5]
        bound = [0.0125, 0.0, 0.05][k % 3]
        rdf, rdr = 0.78 * (1 + 0.01 * (k % 3)), 0.8
        est._kf = est._kr = 1.0
        est._kappa_var = kv
        est.cfg = EstimatorConfig(slip_sigma_max=bound) if bound != 0.0125 else EstimatorConfig()
        est.model._fzf_key = None
        ff, fr, rdf, rdr = est.model.load_floats(float(est._u[4]), float(est._u[5]))
        buf = np.empty(26)
        est._u[6] = kap                         # the curvature input: the lateral load transfer moves the radii
        code = _kernels.estimate_outputs(x, P, rdf, rdr, 1e-4, 1e-4, kap, hb, wb, kv, est.cfg.slip_sigma_max, buf,
                                         est.model._kc, est._u)
        kw = np.ones(4) if kap == 0.0 else est._wheel_factors(kap)
        assert _same(buf[22:26], kw), k
        assert _same(buf[4:8], np.array(est._slip(x[:4].tolist(), float(x[4]), kw.tolist()))), k
        assert _same(buf[12:22], P.diagonal()), k
        ok = est._slip_supported(float(x[4]), kap, kw, x[:4].copy(), P.diagonal().copy())
        assert (code >= 2) == ok, k
        n_unsupported += not ok
    assert 300 < n_unsupported < 2700


@needs_jit
def test_estimator_compiled_equals_numpy_estimator_paths(monkeypatch):
    """The estimator's own compiled calls (Q's parts, the outputs) against its numpy code on one run: the same
    estimates bit for bit (the filter core stays compiled in both, so only the estimator's paths differ)."""
    run = synth_run(seed=9, duration=10.0, change=(5.0, 0.5, 0.1))
    fast = _run(run.steps)
    monkeypatch.setattr(est_mod, "JIT", False)
    ref = _run(run.steps)
    _assert_runs_equal(fast, ref)
