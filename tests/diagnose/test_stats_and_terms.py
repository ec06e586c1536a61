"""Building blocks of diagnosis against closed-form results: filters, curve inverse, HAC, scoring."""

import math

import numpy as np
import pytest

from tractionecu.diagnose.candidates import CANDIDATES, DETECTORS
from tractionecu.diagnose.channels import _CurveInverse, _onehot_scaled_fit, relaxed, relaxed_by_distance
from tractionecu.diagnose.hac import andrews_bandwidth, hac_meat, n_effective
from tractionecu.model.effects import EFFECTS, LIBRARY, SENSOR_FAULTS
from tractionecu.model.mucurve import SOIL_CLASSES


def test_every_library_effect_is_a_candidate_with_library_bounds():
    # Physical effects and sensor faults: each a fitted candidate or a data check.
    assert set(EFFECTS) <= set(CANDIDATES)
    assert set(CANDIDATES) | DETECTORS == set(LIBRARY) == set(EFFECTS) | set(SENSOR_FAULTS)
    for name, cand in CANDIDATES.items():
        specs = {p.name: p for p in LIBRARY[name].params}
        for fp in cand.fitted:
            assert (fp.lo, fp.hi, fp.unit) == (specs[fp.name].lo, specs[fp.name].hi, specs[fp.name].unit)
            assert fp.lo <= fp.null <= fp.hi
        # Fitted and held parameters together are exactly the library's parameters.
        assert {fp.name for fp in cand.fitted} | set(cand.fixed) == set(specs)


@pytest.mark.parametrize("sigma", [0.3, 0.8, 2.0])
def test_relaxation_by_distance_matches_first_order_step_response(sigma):
    """A slip step at constant speed relaxes as 1 − exp(−x/σ), x the distance after the step."""
    dt, v = 0.01, 2.0
    t = np.arange(0.0, 6.0, dt)
    s = np.where(t >= 1.0, 0.1, 0.0)[:, None]
    out = relaxed_by_distance(t, s, np.full(t.size, v), sigma, dx=0.005)[:, 0]
    x_after = np.clip((t - 1.0) * v, 0.0, None)
    expect = np.where(t >= 1.0, 0.1 * (1.0 - np.exp(-x_after / sigma)), 0.0)
    # The step is known only to within one sample of travel (v·dt): the response may be off by
    # what the filter does over that distance.
    assert np.max(np.abs(out - expect)) <= 0.1 * (1.0 - math.exp(-v * dt / sigma))


def test_relaxation_time_and_distance_forms_agree_at_varying_speed():
    """The exact-step time-domain filter and the distance-domain filter solve the same equation."""
    dt = 0.002
    t = np.arange(0.0, 8.0, dt)
    v = 1.0 + 0.8 * np.sin(0.7 * t)
    s = (0.05 + 0.03 * np.sin(3.0 * t) + 0.02 * (t > 4))[:, None]
    a = relaxed(s, v, 0.6, dt)[:, 0]
    b = relaxed_by_distance(t, s, v, 0.6, dx=0.002)[:, 0]
    assert np.max(np.abs(a[500:] - b[500:])) < 2e-3


@pytest.mark.parametrize("cls", list(SOIL_CLASSES))
def test_curve_inverse_inverts_g(cls):
    c = SOIL_CLASSES[cls]
    inv = _CurveInverse(c)
    s = np.linspace(-0.5, 0.5, 101)
    assert np.max(np.abs(inv(c.g(s)) - s)) < 1e-3


def test_onehot_scaled_fit_is_least_squares_per_group():
    rng = np.random.default_rng(0)
    g = np.repeat(np.arange(3), 50)
    x = rng.uniform(0.5, 1.5, g.size)
    beta = np.array([0.5, 1.0, 2.0])
    y = beta[g] * x
    assert np.allclose(_onehot_scaled_fit(y, x, g, 3), y)


def test_effective_sample_size_of_white_and_ar1_noise():
    rng = np.random.default_rng(1)
    n = 20000
    e = rng.standard_normal(n)
    assert n_effective(e, np.arange(n)) == pytest.approx(n, rel=0.05)
    rho = 0.9
    x = np.empty(n)
    x[0] = e[0]
    for k in range(1, n):
        x[k] = rho * x[k - 1] + e[k]
    assert n_effective(x, np.arange(n)) == pytest.approx(n * (1 - rho) / (1 + rho), rel=0.15)


def test_hac_long_run_variance_of_ar1_mean():
    """Newey–West on an AR(1) recovers the long-run variance σ²/(1 − ρ)² of its mean."""
    rng = np.random.default_rng(2)
    rho, n, reps = 0.8, 4000, 40
    ratios = []
    for _ in range(reps):
        e = rng.standard_normal(n)
        x = np.empty(n)
        x[0] = e[0] / math.sqrt(1 - rho * rho)
        for k in range(1, n):
            x[k] = rho * x[k - 1] + e[k]
        lrv = hac_meat((x - x.mean())[:, None])[0, 0] / n
        ratios.append(lrv / (1.0 / (1 - rho) ** 2))
    # Bartlett HAC is biased low by a few per cent at this bandwidth; the mean ratio must be near 1.
    assert 0.8 < float(np.mean(ratios)) < 1.1
    assert andrews_bandwidth(x[:, None]) > 5


def test_nis_coverage_is_95_percent_for_white_noise_and_falls_with_a_systematic_error():
    from types import SimpleNamespace

    from tractionecu.diagnose.locate import nis_coverage, noise_sigma

    rng = np.random.default_rng(5)
    n = 4000
    ch = SimpleNamespace(tidx=np.arange(n))
    white = rng.normal(0.0, 2.0, n)
    sigma = noise_sigma(ch, white)
    assert abs(sigma - 2.0) < 0.1
    assert abs(nis_coverage(ch, white, sigma) - 0.95) < 0.015
    # a slow systematic error (a grade-like sine) leaves the noise level alone but drops the coverage
    slow = white + 6.0 * np.sin(np.arange(n) / 200.0)
    assert abs(noise_sigma(ch, slow) - 2.0) < 0.1
    assert nis_coverage(ch, slow, noise_sigma(ch, slow)) < 0.6


def test_the_direction_of_travel_comes_from_the_wheels_and_is_held_through_a_stop():
    from tractionecu.diagnose.data import DIRECTION_MIN_RAD_S, travel_direction

    w = np.array([0.0, 0.05, 3.0, 3.0, 0.1, 0.0, -0.1, -1.2, -1.3, 0.0, np.nan, 2.0])
    om = np.tile(w[:, None], (1, 4))
    d = travel_direction(om)
    assert d.tolist() == [1, 1, 1, 1, 1, 1, 1, -1, -1, -1, -1, 1]
    assert travel_direction(None) is None
    assert 0.1 < DIRECTION_MIN_RAD_S < 0.5


def test_the_speed_equations_resistance_turns_with_the_travel():
    """ρ_g m g d + k x per field cell: with d ≡ 1 the per-cell means (forward driving, as before); with a
    reverse leg the resistance changes sign there, and a fit without the direction leaves 2 ρ m g."""
    from tractionecu.diagnose.channels import _rho_and_slip_fit

    rng = np.random.default_rng(0)
    n = 400
    group = np.repeat([0, 1], n // 2)
    xs = rng.uniform(0.0, 3000.0, n)
    d = np.ones(n)
    mg = 6300.0 * 9.81
    y = np.array([0.05, 0.08])[group] * mg + 0.1 * xs
    fit1 = _rho_and_slip_fit(y, mg, xs, group, 2)
    np.testing.assert_allclose(_rho_and_slip_fit(y, mg, xs, group, 2, d), fit1, rtol=1e-12)
    np.testing.assert_allclose(fit1, y, rtol=1e-9)
    d[150:190] = -1.0                              # a reverse leg in the first cell
    y = np.array([0.05, 0.08])[group] * mg * d + 0.1 * xs * d
    np.testing.assert_allclose(_rho_and_slip_fit(y, mg, xs * d, group, 2, d), y, rtol=1e-9, atol=1e-6)
    assert np.abs(_rho_and_slip_fit(y, mg, xs * d, group, 2) - y).max() > mg * 0.05


@pytest.mark.parametrize("step", [1, 20])
def test_open_world_location_on_sparse_rows(step):
    """The largest 20-s running mean is found on a channel with one row per frame row and on the speed
    equation's, one row per 2-s window (20 frame rows at 10 Hz).  Regression: on the sparse rows no window
    counted, and every statement on the speed equation located its mismatch "around t = 0 s" with a mean of 0."""
    from tractionecu.diagnose.openworld import largest_running_mean

    n, rate = 3000, 10.0
    idx = np.arange(0, n, step)
    t = idx / rate
    rt = np.where((t >= 150.0) & (t < 170.0), 500.0, 0.0) + np.random.default_rng(3).normal(0.0, 20.0, idx.size)
    j, mean = largest_running_mean(n, rate, idx, rt)
    assert 150.0 <= j / rate <= 170.0
    assert 400.0 < mean < 600.0


def test_a_generic_term_is_named_only_when_significant():
    """The held-out selection's terms are named only with |coefficient| ≥ 2 HAC standard errors (a drifting
    draft was named on a healthy recording at z = 1.2)."""
    from tractionecu.diagnose.openworld import significant_terms

    coefs = {"time_draft": {"coefficient": -0.0758, "se": 0.061, "words": "draft × time"},
             "v2": {"coefficient": 126.0, "se": 20.0, "words": "speed squared v²"},
             "acc": {"coefficient": 3.0, "se": float("nan"), "words": "acceleration dv/dt"}}
    assert significant_terms(coefs, ["time_draft", "v2", "acc"]) == ["v2"]
    assert coefs["time_draft"]["z"] == pytest.approx(1.243, abs=1e-3) and coefs["time_draft"]["significant"] is False
    assert coefs["v2"]["significant"] is True and coefs["acc"]["significant"] is False
