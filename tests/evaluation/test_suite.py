"""The diagnosis suite: its cases and the figures it scores them with."""

import pytest

from tractionecu.evaluation.suite import Case, all_cases, cases, fast_cases, summarize


def test_summarize_counts_each_kind():
    rows = [
        {"kind": "effect", "correct": True, "covered": {"a": True, "b": False}, "rmse_reduction": 0.9},
        {"kind": "effect", "correct": False, "covered": {"a": True}, "rmse_reduction": 0.5},
        {"kind": "effect", "correct": True, "covered": {"a": False}, "rmse_reduction": 0.7},
        {"kind": "null", "correct": True},
        {"kind": "null", "correct": False},
        {"kind": "confounded", "correct": True},
    ]
    s = summarize(rows)
    assert s["top1_accuracy"] == pytest.approx(2 / 3)
    assert s["ci_coverage"] == pytest.approx(2 / 4)
    assert s["ci_coverage_primary"] == pytest.approx(2 / 3)
    assert s["median_heldout_rmse_reduction"] == pytest.approx(0.7)
    assert s["null_false_alarms"] == 1
    assert s["confounded_as_ambiguous"] is True


def test_suite_cases_conceal_valid_library_effects():
    names = [c.name for c in all_cases()]
    assert len(names) == len(set(names))
    full = cases()
    kinds = {c.kind for c in full}
    assert kinds == {"effect", "null", "confounded"}
    assert sum(c.kind == "null" for c in full) >= 2
    concealed = {c.effect for c in full if c.kind == "effect"}
    assert {"grade", "load_transfer", "gps_latency", "wheel_radius", "relaxation", "draft_speed", "mass"} <= concealed
    assert fast_cases() and all(isinstance(c, Case) for c in fast_cases())
    # Seeds differ between cases.
    seeds = [c.build().seed for c in all_cases()]
    assert len(set(seeds)) == len(seeds)
