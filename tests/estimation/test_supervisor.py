"""Fuzzy supervisor (memberships, rule table, defuzzification) and covariance matching."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tractionecu.errors import ConfigError
from tractionecu.estimation.supervisor import (RULES, CovarianceMatching, DynamicsMonitor, FuzzyConfig,
                                               FuzzySupervisor, trapmf, trimf)


def test_triangle_and_trapezoid_values():
    x = np.array([-1.0, 0.0, 0.5, 1.0, 1.5, 2.0, 3.0])
    np.testing.assert_allclose(trimf(x, 0.0, 1.0, 2.0), [0, 0, 0.5, 1, 0.5, 0, 0])
    np.testing.assert_allclose(trapmf(x, 0.0, 1.0, 1.5, 2.0), [0, 0, 0.5, 1, 1, 0, 0])
    # shoulders
    np.testing.assert_allclose(trapmf(x, 0.0, 0.0, 0.5, 1.0), [0, 1, 1, 0, 0, 0, 0])
    np.testing.assert_allclose(trapmf(x, 1.0, 2.0, math.inf, math.inf), [0, 0, 0, 0, 0.5, 1, 1])
    np.testing.assert_allclose(trimf(x, 0.0, 0.0, 1.0), [0, 1, 0.5, 0, 0, 0, 0])


def test_memberships_partition_the_inputs():
    sup = FuzzySupervisor()
    for e1 in np.linspace(0, 0.6, 31):
        for e2 in np.linspace(0, 15000, 31):
            m1, m2 = sup.memberships(e1, e2)
            assert m1.sum() == pytest.approx(1.0) and m2.sum() == pytest.approx(1.0)


def test_rule_table_as_documented():
    S, M, L = 0, 1, 2
    assert RULES.tolist() == [[S, M, L], [M, M, L], [L, L, L]]


def test_single_set_centroids_and_factor_range():
    c = FuzzyConfig()
    sup = FuzzySupervisor(c)
    # steady: only SMALL fires -> centroid of tri(0,0,0.5) = 1/6
    assert sup.intensity(0.0, 0.0) == pytest.approx(1 / 6, abs=2e-3)
    # intense: only LARGE fires -> centroid of tri(0.5,1,1) = 5/6
    assert sup.intensity(1.0, 0.0) == pytest.approx(5 / 6, abs=2e-3)
    assert sup.intensity(0.0, 1e6) == pytest.approx(5 / 6, abs=2e-3)
    # MEDIUM alone (both at their medium peak) -> 0.5, factor = geometric mean
    assert sup.intensity(c.accel_mid_mps2, c.torque_rate_mid_nmps) == pytest.approx(0.5, abs=1e-9)
    assert sup.factor(c.accel_mid_mps2, c.torque_rate_mid_nmps) == pytest.approx(math.sqrt(c.factor_min * c.factor_max))
    for e1 in np.linspace(0, 1, 11):
        f = sup.factor(e1, 3000.0)
        assert c.factor_min <= f <= c.factor_max


def test_factor_rises_with_dynamic_intensity():
    sup = FuzzySupervisor()
    acc = np.linspace(0, 0.5, 26)
    f = [sup.factor(a, 0.0) for a in acc]
    assert all(b >= a - 1e-12 for a, b in zip(f, f[1:]))
    assert f[-1] > 4 * f[0]
    tq = np.linspace(0, 20000, 26)
    g = [sup.factor(0.0, m) for m in tq]
    assert all(b >= a - 1e-12 for a, b in zip(g, g[1:]))
    assert g[-1] > 4 * g[0]


def test_mamdani_centroid_against_a_literal_evaluation():
    """Rule by rule, on a fine grid, with min/max written out: same centroid."""
    c = FuzzyConfig()
    sup = FuzzySupervisor(c)
    grid = np.linspace(0, 1, 2001)
    outs = [trimf(grid, 0, 0, 0.5), trimf(grid, 0.25, 0.5, 0.75), trimf(grid, 0.5, 1, 1)]
    rng = np.random.default_rng(3)
    for _ in range(20):
        e1, e2 = rng.uniform(0, 0.4), rng.uniform(0, 12000)
        m1, m2 = sup.memberships(e1, e2)
        agg = np.zeros_like(grid)
        for i in range(3):
            for j in range(3):
                agg = np.maximum(agg, np.minimum(min(m1[i], m2[j]), outs[RULES[i, j]]))
        ref = float((agg * grid).sum() / agg.sum())
        assert sup.intensity(e1, e2) == pytest.approx(ref, abs=5e-3)


def test_fuzzy_config_validation_names_the_key():
    with pytest.raises(ConfigError, match="accel"):
        FuzzyConfig(accel_low_mps2=0.5)
    with pytest.raises(ConfigError, match="factor_min"):
        FuzzyConfig(factor_min=10.0, factor_max=1.0)


def test_dynamics_monitor_follows_a_ramp():
    mon = DynamicsMonitor(tau_s=0.2)
    for k in range(400):
        t = k * 0.01
        mon.update(t, 0.3 * t, 1000.0 * t)
    assert mon.accel == pytest.approx(0.3, rel=1e-3)
    assert mon.torque_rate == pytest.approx(1000.0, rel=1e-3)


def test_covariance_matching_ratio():
    rng = np.random.default_rng(0)
    cm = CovarianceMatching(3, window=2000, a_min=0.1, a_max=10.0)
    model_var = np.array([1e-4, 4e-6, 1e-2])
    true_scale = np.array([1.0, 2.5, 0.4])
    assert np.array_equal(cm.compute(), np.ones(3))   # window not full yet
    for _ in range(2000):
        cm.push(rng.standard_normal(3) * np.sqrt(model_var * true_scale), model_var)
    np.testing.assert_allclose(cm.compute(), true_scale, rtol=0.1)


def test_covariance_matching_clips():
    cm = CovarianceMatching(2, window=10, a_min=0.5, a_max=3.0)
    for _ in range(10):
        cm.push(np.array([10.0, 0.0]), np.array([1.0, 1.0]))
    np.testing.assert_allclose(cm.compute(), [3.0, 0.5])
