"""The vectorised UKF against stock filterpy, and its robustness features."""

from __future__ import annotations

import math

import numpy as np
import pytest
from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

from tractionecu.config import VehicleParams
from tractionecu.estimation.ukf import UnscentedFilter, merwe_sigma_points, merwe_weights
from tractionecu.model.vehicle import FilterModel

VEH = VehicleParams()
MODEL = FilterModel(VEH)
X0 = np.array([3.0, 3.0, 3.1, 3.1, 2.4, 0.30, 0.30, 0.32, 0.32, 0.05])
P0 = np.diag([1e-3] * 4 + [1e-2] + [1e-2] * 4 + [1e-3])
Q = np.diag([1e-6] * 4 + [1e-6] + [1e-5] * 4 + [1e-7])
R = np.array([1.3e-4] * 4 + [2.5e-3])
U = np.array([2400.0, 2400.0, 3600.0, 3600.0, 0.4 * VEH.weight_n, 15000.0])
DT = 0.01


def _truth_and_meas(n: int, seed: int):
    rng = np.random.default_rng(seed)
    xt = np.array([3.2, 3.2, 3.3, 3.3, 2.5, 0.34, 0.34, 0.33, 0.33, 0.07])
    zs = []
    for _ in range(n):
        xt = MODEL.step(xt, U, DT)
        zs.append(xt[:5] + rng.standard_normal(5) * np.sqrt(R))
    return zs


@pytest.mark.parametrize("alpha,beta,kappa", [(1.0, 2.0, 0.0), (0.5, 2.0, 1.0)])
def test_matches_stock_filterpy_with_partial_updates(alpha, beta, kappa):
    sp = MerweScaledSigmaPoints(10, alpha, beta, kappa)
    fp = UnscentedKalmanFilter(10, 5, DT, lambda x: x[:5], lambda x, dt: MODEL.step(x, U, dt), sp)
    fp.x, fp.P, fp.Q = X0.copy(), P0.copy(), Q.copy()
    ours = UnscentedFilter(MODEL.step, X0, P0, range(5), alpha=alpha, beta=beta, kappa=kappa)
    worst = 0.0
    for k, z in enumerate(_truth_and_meas(300, 1)):
        n = 5 if k % 10 == 9 else 4          # GPS speed every 10th step only
        fp.predict()
        fp.update(z[:n], R=np.diag(R[:n]), hx=lambda x, n=n: x[:n])
        ours.predict(U, DT, Q)
        ours.update(z[:n], slice(0, n), R[:n])
        worst = max(worst, float(np.max(np.abs(ours.x - fp.x) / np.abs(fp.x))))
        np.testing.assert_allclose(ours.P, fp.P, rtol=1e-6, atol=1e-13)
    assert worst < 1e-9


def test_sigma_points_and_weights_equal_filterpy():
    sp = MerweScaledSigmaPoints(10, 0.7, 2.0, 0.5)
    lam, wm, wc = merwe_weights(10, 0.7, 2.0, 0.5)
    np.testing.assert_allclose(wm, sp.Wm)
    np.testing.assert_allclose(wc, sp.Wc)
    np.testing.assert_allclose(merwe_sigma_points(X0, P0, lam), sp.sigma_points(X0, P0), rtol=1e-12)


def test_all_sigma_points_propagate_in_one_call():
    calls = []

    def fx(sig, u, dt):
        calls.append(sig.shape)
        return MODEL.step(sig, u, dt)

    f = UnscentedFilter(fx, X0, P0, range(5))
    f.predict(U, DT, Q)
    assert calls == [(21, 10)]


def test_cholesky_failure_is_repaired_and_counted():
    P = P0.copy()
    P[5, 6] = P[6, 5] = 0.02          # |corr| > 1: indefinite
    f = UnscentedFilter(MODEL.step, X0, P, range(5))
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.cholesky(P)
    f.predict(U, DT, Q)
    assert f.chol_repairs == 1 and f.repaired_last
    np.linalg.cholesky(f.P)           # positive definite again
    assert np.allclose(f.P, f.P.T)


def test_nan_measurement_component_is_dropped():
    f = UnscentedFilter(MODEL.step, X0, P0, range(5))
    f.predict(U, DT, Q)
    x_prior = f.x.copy()
    z = X0[:5].copy()
    z[2] = np.nan
    f.update(z, slice(0, 5), R)
    assert f.nonfinite_rejected == 1
    assert f.last_dof == 4 and np.isfinite(f.x).all() and np.isfinite(f.P).all()
    assert not np.array_equal(f.x, x_prior)
    f.update(np.full(5, np.inf), slice(0, 5), R)
    assert f.last_dof == 0 and math.isnan(f.last_nis)


def test_outlier_is_gated_then_persistent_offset_is_accepted():
    gate = 15.1
    f = UnscentedFilter(MODEL.step, X0, P0, range(5), gate_chi2=gate, gate_max_consecutive=3)
    f.predict(U, DT, Q)
    z = f.x[:5].copy()
    z[1] += 20.0                         # 20 rad/s: ≫ 4 σ
    f.update(z, slice(0, 5), R)
    assert f.last_gated == 1 << 1 and f.last_dof == 4 and f.gated_total == 1
    for _ in range(2):
        f.predict(U, DT, Q)
        z = f.x[:5].copy()
        z[1] += 20.0
        f.update(z, slice(0, 5), R)
    assert f.gated_total == 3
    f.predict(U, DT, Q)
    z = f.x[:5].copy()
    z[1] += 20.0
    f.update(z, slice(0, 5), R)          # 4th in a row: accepted
    assert f.last_gated == 0 and f.last_dof == 5 and f.gate_bypassed == 1


def test_parameters_are_clamped_to_physical_bounds():
    lo = np.array([-np.inf] * 5 + [-1.2] * 4 + [0.0])
    hi = np.array([np.inf] * 5 + [1.2] * 4 + [0.5])
    x0 = X0.copy()
    x0[9] = 0.001
    P = P0.copy()
    P[9, 9] = 1.0
    P[4, 9] = P[9, 4] = 0.09            # v and ρ_s strongly correlated
    f = UnscentedFilter(MODEL.step, x0, P, range(5), x_lo=lo, x_hi=hi)
    f.predict(U, DT, Q)
    z = f.x[:5].copy()
    z[4] += 5.0                          # pushes ρ_s far negative through the correlation
    f.update(z, slice(0, 5), R)
    assert f.x[9] == 0.0 and f.clamp_events == 1


def test_symmetric_covariance_after_every_step():
    f = UnscentedFilter(MODEL.step, X0, P0, range(5))
    for k, z in enumerate(_truth_and_meas(50, 2)):
        f.predict(U, DT, Q)
        assert np.array_equal(f.P, f.P.T)
        f.update(z[:4], slice(0, 4), R[:4])
        assert np.array_equal(f.P, f.P.T)


def test_slice_cache_stays_bounded_for_new_slice_objects():
    """Regression: the update's per-slice cache was keyed by the slice object, so a caller
    writing ``update(z, slice(0, 5), R)`` every step grew it by one entry per step."""
    f = UnscentedFilter(MODEL.step, X0, P0, range(5))
    for z in _truth_and_meas(200, seed=5):
        f.predict(U, DT, Q)
        f.update(z, slice(0, 5), R)
    assert len(f._fast) <= 32
    assert np.isfinite(f.x).all()
