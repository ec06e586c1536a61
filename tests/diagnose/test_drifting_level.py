"""A level that drifts linearly in time (the CAN clock's shift δ_0 + κ t) is tested where the data hold it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tractionecu.diagnose.engine import _excludes_null, level_at_centroid
from tractionecu.diagnose.fit import FitResult


def _clock_fit(rho: float, sd0: float = 0.19, sd1: float = 900.0, x0: float = 0.27, x1: float = -211.0) -> FitResult:
    c01 = rho * sd0 * sd1
    cov = np.array([[sd0 ** 2, c01], [c01, sd1 ** 2]])
    ci = {"offset_s": (x0 - 1.959964 * sd0, x0 + 1.959964 * sd0),
          "rate_ppm": (x1 - 1.959964 * sd1, x1 + 1.959964 * sd1)}
    return FitResult(candidate="clock_skew", x=np.array([x0, x1]), cov=cov,
                     params={"offset_s": x0, "rate_ppm": x1}, ci95=ci, se={"offset_s": sd0, "rate_ppm": sd1},
                     sse={}, n={}, cost=0.0, ok=True, names=("clock_skew.offset_s", "clock_skew.rate_ppm"))


def test_a_shift_seen_only_at_few_times_is_found_where_the_data_hold_it():
    # offset and rate correlate at −0.97: each interval alone reaches zero, the shift at t* does not
    fr = _clock_fit(-0.97)
    assert fr.ci95["offset_s"][0] < 0.0 < fr.ci95["offset_s"][1]
    assert fr.ci95["rate_ppm"][0] < 0.0 < fr.ci95["rate_ppm"][1]
    lv = level_at_centroid(fr, "clock_skew")
    t_star = 0.97 * 0.19 * 900.0 / (1e-6 * 900.0 ** 2)        # −C_lr / (s C_rr)
    assert lv["t_s"] == pytest.approx(t_star)
    assert lv["value"] == pytest.approx(0.27 - 211e-6 * t_star)
    half = 1.959964 * 0.19 * math.sqrt(1.0 - 0.97 ** 2)        # the conditional standard deviation
    assert lv["ci95"] == pytest.approx((lv["value"] - half, lv["value"] + half))
    assert _excludes_null(fr)


def test_without_the_trade_off_the_level_is_the_offset_and_decides_nothing_new():
    fr = _clock_fit(0.0)
    lv = level_at_centroid(fr, "clock_skew")
    assert lv["t_s"] == pytest.approx(0.0) and lv["value"] == pytest.approx(0.27)
    assert not _excludes_null(fr)


def test_the_refined_intervals_widening_carries_over_and_other_effects_have_no_level():
    fr = _clock_fit(-0.97)
    lo, hi = fr.ci95["offset_s"]
    fr.ci95["offset_s"] = (0.27 - 2.0 * (0.27 - lo), 0.27 + 2.0 * (hi - 0.27))    # twice the sandwich's
    lv = level_at_centroid(fr, "clock_skew")
    half = 2.0 * 1.959964 * 0.19 * math.sqrt(1.0 - 0.97 ** 2)
    assert lv["ci95"][1] - lv["ci95"][0] == pytest.approx(2.0 * half)
    assert level_at_centroid(fr, "gps_latency") is None
    fr.cov = np.full((2, 2), np.nan)
    assert level_at_centroid(fr, "clock_skew") is None
