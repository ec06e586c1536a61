"""μ(s) curve (paper eq. 14) and the solve for a (section 3.2)."""

import math

import numpy as np
import pytest

from tractionecu.model.mucurve import SOIL_CLASSES, mu_curve, solve_a, solve_a_array


def test_curve_by_hand():
    c = SOIL_CLASSES["stubble"]
    s, a = 0.1, 0.7
    expected = a - c.p * a * math.exp(c.alpha1 * s) - a * (1 - c.p) * math.exp(c.alpha2 * s)
    assert float(c.mu(s, a)) == pytest.approx(expected, rel=1e-14)
    assert float(mu_curve(s, a, c.p, c.alpha1, c.alpha2)) == pytest.approx(expected, rel=1e-14)
    assert float(c.mu(0.0, a)) == 0.0
    assert float(c.mu(-s, a)) == pytest.approx(-expected)  # odd extension for braking


@pytest.mark.parametrize("name", sorted(SOIL_CLASSES))
def test_classes_are_monotone_and_saturate(name):
    c = SOIL_CLASSES[name]
    s = np.linspace(0, 1, 501)
    g = c.g(s)
    assert np.all(np.diff(g) > 0)
    assert 0.9 < g[-1] <= 1.0
    assert np.allclose(np.gradient(g, s)[1:-1], c.dg(s)[1:-1], rtol=2e-2)


@pytest.mark.parametrize("name", sorted(SOIL_CLASSES))
@pytest.mark.parametrize("s", [0.05, 0.1, 0.2, 0.35])
def test_solve_a_round_trip(name, s):
    c = SOIL_CLASSES[name]
    sol = solve_a(float(c.mu(s, 0.66)), s, c)
    assert sol.ok and sol.a == pytest.approx(0.66, rel=1e-12)


def test_low_slip_is_reported_ill_conditioned_not_garbage():
    c = SOIL_CLASSES["stubble"]
    sol = solve_a(0.001, 0.0005, c)
    assert not sol.ok and "ill-conditioned" in sol.reason and math.isnan(sol.a)
    # Just above min_slip the propagated slip error dominates and is flagged too.
    sol = solve_a(float(c.mu(0.012, 0.7)), 0.012, c, sigma_s=0.003)
    assert not sol.ok and sol.rel_err > 0.15


def test_solve_a_rejects_nonfinite_and_opposite_signs():
    c = SOIL_CLASSES["tilled"]
    assert not solve_a(float("nan"), 0.1, c).ok
    assert not solve_a(0.3, -0.1, c).ok


def test_vectorised_solve_matches_scalar():
    c = SOIL_CLASSES["grassland"]
    s = np.array([0.0, 0.005, 0.05, 0.1, 0.3])
    mu = c.mu(s, 0.7)
    a, rel, ok = solve_a_array(mu, s, c)
    for i in range(len(s)):
        sol = solve_a(float(mu[i]), float(s[i]), c)
        assert ok[i] == sol.ok
        if sol.ok:
            assert a[i] == pytest.approx(sol.a)
