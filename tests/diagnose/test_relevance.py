"""Practical relevance of a detection (:data:`tractionecu.diagnose.engine.RELEVANT_F2`).

The held-out score of a candidate is S = ½ n_eff ln(SSE_null/SSE_cand) per channel: for a fixed share
of a channel's mismatch that a candidate explains (Cohen's f² = SSE_null/SSE_cand − 1), S grows with the
recording's length.  A nominal model that is slightly wrong (on ``paper-three-soils`` ρ_s is fitted per
40-m field cell while the soil changes inside two cells, and the slip coefficient k_s takes that up) then
lets some library term take up a sliver of the mismatch, consistently in every run, and on an hour of
healthy runs that sliver passed DETECT_LLR: a rear mass of +466 kg, speed equation 231 → 229 N held out.
A fault is named only when it explains a medium effect (f² ≥ 0.15) of at least one signal.

The channels are synthetic (a residual that the candidate reduces by a set share); the score and the
rule run unchanged.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from tractionecu.diagnose import engine
from tractionecu.diagnose.engine import DETECT_LLR, RELEVANT_F2
from tractionecu.diagnose.fit import HeldOut, score


def _case(n: int, f2: float, seed: int = 0):
    """A one-channel problem of n independent held-out rows whose candidate explains the share
    f2/(1 + f2) of the null residual's sum of squares."""
    rng = np.random.default_rng(seed)
    r1 = rng.standard_normal(n)
    s1 = float(np.sum(r1 * r1))
    problem = SimpleNamespace(channels={"speed": SimpleNamespace(tidx=np.arange(n, dtype=np.int64))})
    null = HeldOut("null", {"speed": s1 * (1.0 + f2)}, {"speed": n}, {"speed": r1 * math.sqrt(1.0 + f2)})
    cand = HeldOut("mass", {"speed": s1}, {"speed": n}, {"speed": r1})
    return problem, null, cand


def test_the_held_out_score_of_a_fixed_share_grows_with_the_length_of_the_recording():
    f2 = 0.013   # the share the healthy hour's rear mass explained in the speed equation (held out)
    short = score(*_case(400, f2))[0]
    long = score(*_case(40_000, f2))[0]
    assert short < DETECT_LLR <= long
    assert long / short > 50


def test_a_sliver_of_mismatch_is_not_named_however_long_the_recording():
    problem, null, cand = _case(40_000, 0.013)
    assert score(problem, null, cand)[0] >= DETECT_LLR
    why = engine._irrelevant(null, cand)
    assert "f² = 0.013" in why and "speed" in why


def test_an_effect_that_explains_a_medium_share_of_a_signal_is_relevant_on_a_short_recording():
    # gps_latency_a of the suite, the smallest true effect: held-out RMSE −13 % (f² = 0.32).
    problem, null, cand = _case(400, 1.0 / 0.87 ** 2 - 1.0)
    assert score(problem, null, cand)[0] >= DETECT_LLR
    assert engine._irrelevant(null, cand) == ""


def test_the_best_channel_decides_and_the_threshold_is_cohens_medium_effect():
    assert RELEVANT_F2 == 0.15
    null = HeldOut("null", {"speed": 100.0, "gps_speed": 100.0, "slip": 0.0}, {}, {})
    weak = HeldOut("x", {"speed": 99.0, "gps_speed": 100.0 / (1.0 + RELEVANT_F2 * 0.99), "slip": 1.0}, {}, {})
    strong = HeldOut("x", {"speed": 99.0, "gps_speed": 100.0 / (1.0 + RELEVANT_F2 * 1.01), "slip": 1.0}, {}, {})
    assert "gps_speed" in engine._irrelevant(null, weak)
    assert engine._irrelevant(null, strong) == ""
