"""Curve parameter a from (μ, s) pairs and the surface-class decision (paper section 3.2)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tractionecu.estimation.curve import CurveEstimator
from tractionecu.model.mucurve import SOIL_CLASSES

STUBBLE = SOIL_CLASSES["stubble"]
SIG = np.full(4, 0.005)


@pytest.mark.parametrize("a", [0.5, 0.7, 0.9])
def test_exact_pairs_give_exact_a(a):
    ce = CurveEstimator(["stubble"], tau_s=2.0)
    s = np.array([0.04, 0.05, 0.08, 0.12])
    st = ce.update(0.0, STUBBLE.mu(s, a), s, SIG)
    assert st.a == pytest.approx(a, rel=1e-12)
    assert st.n_used == 4 and st.class_name == "stubble"


def test_low_adhesion_and_low_slip_pairs_are_skipped():
    ce = CurveEstimator(["stubble"], min_mu=0.15, min_slip=0.005)
    s = np.array([0.002, 0.004, 0.01, 0.1])
    mu = STUBBLE.mu(s, 0.7)           # the first three have μ < 0.15
    st = ce.update(0.0, mu, s, SIG)
    assert st.n_used == 1 and st.a == pytest.approx(0.7)
    ce2 = CurveEstimator(["stubble"])
    st2 = ce2.update(0.0, np.array([0.3, np.nan, -0.3, 0.3]), np.array([0.0, 0.05, 0.05, np.inf]), SIG)
    assert st2.n_used == 0 and math.isnan(st2.a)


def test_smoothing_follows_a_step_with_its_time_constant():
    ce = CurveEstimator(["stubble"], tau_s=1.0)
    s = np.full(4, 0.06)
    for k in range(200):                      # 20 s on a = 0.8
        ce.update(k * 0.1, STUBBLE.mu(s, 0.8), s, SIG)
    for k in range(200, 210):                 # 1 s on a = 0.6
        st = ce.update(k * 0.1, STUBBLE.mu(s, 0.6), s, SIG)
    # after one time constant about 63 % of the way (discrete forgetting, equal weights)
    frac = (0.8 - st.a) / 0.2
    assert 0.55 < frac < 0.7
    for k in range(210, 300):
        st = ce.update(k * 0.1, STUBBLE.mu(s, 0.6), s, SIG)
    assert st.a == pytest.approx(0.6, rel=1e-3)


def test_ratio_estimate_is_not_biased_by_slip_noise():
    """At firm-soil slip (≈ 0.03) a slip error of 0.005 must not bias a by more than 2 %."""
    rng = np.random.default_rng(7)
    a_true = 0.82
    ce = CurveEstimator(["stubble"], tau_s=1e6)
    for k in range(4000):
        s = rng.uniform(0.025, 0.045, 4)
        mu = STUBBLE.mu(s, a_true) + 0.003 * rng.standard_normal(4)
        s_hat = s + 0.005 * rng.standard_normal(4)
        st = ce.update(k * 0.1, mu, s_hat, SIG)
    assert st.a == pytest.approx(a_true, rel=0.02)


def test_best_class_is_found_from_a_slip_range():
    tilled = SOIL_CLASSES["tilled"]
    ce = CurveEstimator(["stubble", "grassland", "tilled", "road"], tau_s=20.0)
    rng = np.random.default_rng(1)
    for k in range(300):
        s = rng.uniform(0.03, 0.3, 4)
        mu = tilled.mu(s, 0.6) + 0.002 * rng.standard_normal(4)
        st = ce.update(k * 0.1, mu, s, SIG, np.full(4, 0.002))
    assert st.class_name == "tilled" and st.class_index == 2
    assert st.a == pytest.approx(0.6, rel=0.02)
    assert np.argmin(st.nll_per_class) == 2


def test_class_switch_needs_a_clear_margin():
    ce = CurveEstimator(["stubble", "grassland"])
    s = np.full(4, 0.06)                     # one slip value: shapes cannot be told apart
    for k in range(50):
        st = ce.update(k * 0.1, STUBBLE.mu(s, 0.7), s, SIG, np.full(4, 0.005))
    assert st.class_name == "stubble"


def test_flat_class_does_not_win_on_slip_noise():
    """Stubble data at low slip with a noisy slip: the default class must stay (road's g is flat there)."""
    rng = np.random.default_rng(11)
    ce = CurveEstimator(["stubble", "grassland", "tilled", "road"], tau_s=3.0)
    for k in range(3000):
        s = rng.uniform(0.03, 0.08, 4)
        mu = STUBBLE.mu(s, 0.8) + 0.003 * rng.standard_normal(4)
        st = ce.update(k * 0.1, mu, s + 0.009 * rng.standard_normal(4), SIG, np.full(4, 0.009))
    assert st.class_name == "stubble"
