"""The compiled filter core (numba) against the numpy code it replaces, and the RK4 shortcut against RK4."""

from __future__ import annotations

import numpy as np
import pytest
from est_synth import synth_run

from tractionecu.config import VehicleParams
from tractionecu.estimation import _kernels
from tractionecu.estimation import estimator as est_mod
from tractionecu.estimation import ukf as ukf_mod
from tractionecu.estimation.estimator import Estimator
from tractionecu.estimation.ukf import UnscentedFilter
from tractionecu.model import vehicle
from tractionecu.model.vehicle import FilterModel, rk4

VEH = VehicleParams()
needs_jit = pytest.mark.skipif(not vehicle.JIT, reason="numba not installed, or TRACTIONECU_JIT=0")


def numpy_core(monkeypatch: pytest.MonkeyPatch) -> None:
    """Run model, filter and estimator on their numpy code paths."""
    for mod in (vehicle, ukf_mod, est_mod):
        monkeypatch.setattr(mod, "JIT", False)


def _states(rng: np.random.Generator, k: int):
    """Sigma-point-like state sets, some with a speed changing sign within the step, zeros and NaN."""
    scale = [0.001, 0.05, 1.0, 5.0][k % 4]
    x = rng.normal([3, 3, 3, 3, 2.3, .3, .3, .3, .3, .06], scale, size=(21, 10))
    if k % 5 == 0:
        x[:, :5] *= 1e-4                                   # near standstill: signs flip within 10 ms
    if k % 7 == 0:
        x[rng.integers(21), rng.integers(5)] = 0.0
    if k % 13 == 0:
        x[rng.integers(21), rng.integers(10)] = np.nan
    u = np.array([3000.0, 3000.0, 4000.0, 4000.0, 24000.0 + 5 * (k % 3), 15000.0]) * [1, -1, 0.1][k % 3]
    return x, u, [0.01, 0.02, 0.0033][k % 3]


def _reference(model: FilterModel, x, u, dt):
    fz, r_d = model.loads(u)
    return rk4(lambda y: model.rhs(y, u, fz, r_d), x, dt)


def test_numpy_step_is_bitwise_rk4(monkeypatch):
    """The shortcut (all four RK4 stages equal when no speed changes sign) gives RK4's result bit for bit."""
    numpy_core(monkeypatch)
    model = FilterModel(VEH)
    rng = np.random.default_rng(1)
    for k in range(400):
        x, u, dt = _states(rng, k)
        assert np.array_equal(model.step(x, u, dt), _reference(model, x, u, dt), equal_nan=True)
        assert np.array_equal(model.step(x[k % 21], u, dt), _reference(model, x[k % 21], u, dt), equal_nan=True)


@needs_jit
def test_compiled_step_is_bitwise_rk4():
    model = FilterModel(VEH)
    rng = np.random.default_rng(2)
    for k in range(400):
        x, u, dt = _states(rng, k)
        assert np.array_equal(model.step(x, u, dt), _reference(model, x, u, dt), equal_nan=True)
        assert np.array_equal(model.step(x[k % 21], u, dt), _reference(model, x[k % 21], u, dt), equal_nan=True)


def test_load_floats_equal_the_array_functions():
    model = FilterModel(VEH)
    for fzf in [0.0, -0.0, -5000.0, 24000.0, 1e7, VEH.weight_n + 1.0, float("nan"), float("inf")]:
        fz = vehicle.wheel_loads(fzf, VEH)
        rd = vehicle.rolling_radius(fz, VEH)
        ff, fr, rdf, rdr = model.load_floats(fzf)
        assert np.array_equal([ff, ff, fr, fr], fz, equal_nan=True)
        assert np.array_equal([rdf, rdf, rdr, rdr], rd, equal_nan=True)


def _run_filter(fx_wrap: bool, steps: int = 300):
    model = FilterModel(VEH)
    fx = (lambda s, u, dt: model.step(s, u, dt)) if fx_wrap else model.step
    x0 = np.array([3.0, 3.0, 3.1, 3.1, 2.4, 0.30, 0.30, 0.32, 0.32, 0.05])
    P0 = np.diag([1e-3] * 4 + [1e-2] + [1e-2] * 4 + [1e-3])
    Q = np.diag([1e-6] * 5 + [1e-5] * 4 + [1e-7])
    R = np.array([1.3e-4] * 4 + [2.5e-3])
    u = np.array([2400.0, 2400.0, 3600.0, 3600.0, 0.4 * VEH.weight_n, 15000.0])
    lo = np.array([-np.inf] * 5 + [-1.2] * 4 + [0.0])
    hi = np.array([np.inf] * 5 + [1.2] * 4 + [0.5])
    f = UnscentedFilter(fx, x0, P0, range(5), x_lo=lo, x_hi=hi, gate_chi2=15.1, gate_max_consecutive=3)
    rng = np.random.default_rng(3)
    xt = np.array([3.2, 3.2, 3.3, 3.3, 2.5, 0.34, 0.34, 0.33, 0.33, 0.07])
    out = []
    for k in range(steps):
        xt = model.step(xt, u, 0.01)
        z = xt[:5] + rng.standard_normal(5) * np.sqrt(R)
        if k % 50 == 25:
            z[1] += 5.0                                   # gated outlier: general path
        n = 5 if k % 10 == 9 else 4
        f.predict(u, 0.01, Q)
        f.update(z[:n], slice(0, n), R[:n])
        out.append((f.x.copy(), f.P.copy(), f.last_nis, f.last_gated, f.last_dx.copy(), f.ksk_diag().copy()))
    return f, out


@needs_jit
@pytest.mark.parametrize("fx_wrap", [False, True])
def test_compiled_filter_matches_the_numpy_filter(monkeypatch, fx_wrap):
    fj, a = _run_filter(fx_wrap)
    assert (fj._model is not None) == (not fx_wrap)        # FilterModel.step: predict in one compiled call
    numpy_core(monkeypatch)
    fn, b = _run_filter(fx_wrap)
    assert fn._model is None
    for (xa, Pa, na, ga, da, ka), (xb, Pb, nb, gb, db, kb) in zip(a, b):
        np.testing.assert_allclose(xa, xb, rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(Pa, Pb, rtol=1e-8, atol=1e-16)
        assert ga == gb and na == pytest.approx(nb, rel=1e-8, nan_ok=True)
        np.testing.assert_allclose(da, db, rtol=1e-7, atol=1e-15)
        np.testing.assert_allclose(ka, kb, rtol=1e-7, atol=1e-18)
    assert fj.gated_total == fn.gated_total > 0 and fj.clamp_events == fn.clamp_events
    assert np.array_equal(fj.P, fj.P.T) and np.array_equal(fn.P, fn.P.T)


@needs_jit
def test_compiled_estimator_matches_the_numpy_estimator(monkeypatch):
    run = synth_run(seed=6, duration=6.0)
    a = [Estimator(VEH)]
    ea = [a[0].step(t, i, m) for t, i, m in run.steps]
    numpy_core(monkeypatch)
    b = Estimator(VEH)
    eb = [b.step(t, i, m) for t, i, m in run.steps]
    assert a[0].counters == b.counters
    for x, y in zip(ea, eb):
        assert x.status == y.status and x.valid == y.valid and x.nis_dof == y.nis_dof
        for f in ("mu", "slip", "omega", "P_diag"):
            np.testing.assert_allclose(getattr(x, f), getattr(y, f), rtol=1e-8, atol=1e-13, err_msg=f)
        for f in ("rho_s", "v", "nis", "adapt", "a"):
            assert getattr(x, f) == pytest.approx(getattr(y, f), rel=1e-8, abs=1e-13, nan_ok=True), f


@needs_jit
def test_warm_up_compiles_every_kernel_the_estimator_uses():
    _kernels.warm_up()
    kernels = [_kernels.predict_model, _kernels.update_block, _kernels.add_torque_noise, _kernels.estimate_outputs,
               vehicle._rk4_points]
    before = [len(k.signatures) for k in kernels]
    est = Estimator(VEH)
    for t, i, m in synth_run(seed=7, duration=1.0).steps:
        est.step(t, i, m)
    assert [len(k.signatures) for k in kernels] == before    # nothing compiled on the way
