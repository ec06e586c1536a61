"""The diagnosis suite: its cases and the figures it scores them with."""

from dataclasses import replace

import pytest

from tractionecu.evaluation.suite import Case, all_cases, cases, fast_cases, summarize
from tractionecu.model.effects import EFFECTS, SENSOR_FAULTS


def test_summarize_counts_each_kind():
    rows = [
        {"kind": "effect", "correct": True, "top1": True, "covered": {"a.x": True, "b.y": False}, "rmse_reduction": 0.9},
        {"kind": "effect", "correct": False, "top1": False, "covered": {"a.x": True}, "rmse_reduction": 0.5},
        {"kind": "effect", "correct": True, "covered": {"a.x": False}, "rmse_reduction": 0.7},
        {"kind": "characteristic", "correct": True, "covered": {"relaxation.sigma_m": True}},
        {"kind": "null", "correct": True},
        {"kind": "nominal", "correct": False, "covered": {"load_transfer.h_cg_m": True}},
        {"kind": "confounded", "correct": True},
        {"kind": "outside", "correct": True, "located": False},
    ]
    s = summarize(rows)
    assert s["named_above_absent"] == pytest.approx(3 / 4)
    assert s["top1_accuracy_single"] == pytest.approx(1 / 2)
    assert s["ci_coverage"] == pytest.approx(4 / 6)
    assert s["ci_coverage_per_effect"] == {"a": "2/3", "b": "0/1", "load_transfer": "1/1", "relaxation": "1/1"}
    assert s["median_heldout_rmse_reduction"] == pytest.approx(0.7)
    assert s["null_false_alarms"] == 1 and s["n_null_cases"] == 2
    assert s["confounded_as_ambiguous"] is True
    assert s["outside_no_library_name"] == "1/1" and s["outside_located"] == "0/1"


def test_suite_cases_conceal_valid_library_effects():
    names = [c.name for c in all_cases()]
    assert len(names) == len(set(names))
    full = cases()
    kinds = {c.kind for c in full}
    assert kinds == {"effect", "null", "confounded", "nominal", "characteristic", "outside"}
    assert sum(c.kind == "null" for c in full) >= 2
    concealed = set()
    for c in full:
        concealed |= set(c.concealed())
    assert {"grade", "gps_latency", "wheel_radius", "relaxation", "draft_speed", "mass", "drivetrain"} <= concealed
    assert {"torque_gain", "draft_offset", "axle_load_offset", "wheel_speed_hold"} <= concealed
    # Every sensor fault of the library has a recording of the independent truth model.
    phys = set()
    for c in full:
        if c.truth_model == "physical":
            phys |= set(c.concealed())
    assert set(SENSOR_FAULTS) <= phys
    assert concealed <= set(EFFECTS) | set(SENSOR_FAULTS)
    # Several effects in one recording, the independent truth model, and its healthy recordings.
    assert any(len(c.concealed()) >= 2 for c in full)
    assert sum(c.truth_model == "physical" and c.kind == "null" for c in full) >= 2
    assert any(c.kind == "outside" for c in full)
    assert fast_cases() and all(isinstance(c, Case) for c in fast_cases())
    # Seeds differ between cases.
    seeds = [c.build().seed for c in all_cases()]
    assert len(set(seeds)) == len(seeds)


def test_the_physical_plant_has_its_own_rolling_radius_and_the_paper_plant_none():
    """The independent truth model's tyre deflects by its own law; the recording's vehicle file declares the
    rear radius its owner calibrated (off the truth's inside ±0.5 %), and eq. 9 runs through it.  Against that,
    the radius the diagnosis uses, the plant's radius differs by that calibration error and the law's at the
    front, not by the +1.9 to +2.9 % of eq. 9 from the tyre's pressure and width alone, which the file does not
    use: a radius reported at +2.4 % on a healthy recording was scored as the plant's own, not a false alarm."""
    from tractionecu.evaluation.suite import inherent
    from tractionecu.sim.physwriter import DECLARED_RADIUS_TOL_REL

    by = {c.name: c for c in all_cases()}
    assert inherent(by["null_three_soils"]) == {}
    for name in ("phys_null_a", "phys_null_b", "phys_null_reverse", "mech_null_a"):
        for off in (0, 1000):
            lo, hi = inherent(by[name], off)["wheel_radius.epsilon"]
            assert -DECLARED_RADIUS_TOL_REL - 1e-3 < lo <= hi < DECLARED_RADIUS_TOL_REL + 1e-3
    # the calibration error is drawn per seed: the plant of the recording written with the offset
    assert inherent(by["phys_null_a"], 1000) != inherent(by["phys_null_a"])


def _diagnosis(reported_eps_ci, verdict="effect"):
    """A diagnosis stand-in that names a rolling-radius error with the given 95 % interval."""
    from types import SimpleNamespace

    import numpy as np

    lo, hi = reported_eps_ci
    fit = SimpleNamespace(params={"epsilon": (lo + hi) / 2}, ci95={"epsilon": (lo, hi)},
                          at_bound={"wheel_radius": {}})
    cand = SimpleNamespace(name="wheel_radius", testable=True, score=50.0, fit=fit)
    eff = [{"name": "wheel_radius", "kind": "effect", "named": True, "parameters": {}}]
    return SimpleNamespace(effects=eff, verdict=verdict, effect="wheel_radius", ambiguous_between=[],
                           candidates=[cand], joint=None, joint_heldout=None, winner=None,
                           problem=SimpleNamespace(channels={}), null_heldout=None, open_world={},
                           candidate=lambda n: cand if n == "wheel_radius" else None)


def test_a_radius_reported_at_the_plants_own_size_is_no_false_alarm_but_another_size_is():
    from tractionecu.evaluation.suite import inherent, score_case

    case = {c.name: c for c in all_cases()}["phys_null_a"]
    lo, hi = inherent(case)["wheel_radius.epsilon"]
    row = score_case(case, _diagnosis((lo - 0.005, lo + 0.002)))
    assert row["correct"] and row["plant"]["wheel_radius"]["agrees"]
    row = score_case(case, _diagnosis((-0.03, -0.01)))
    assert not row["correct"]
    row = score_case(case, _diagnosis((0.02, 0.028)))            # eq. 9's radius without the file's calibration
    assert not row["correct"] and not row["plant"]["wheel_radius"]["agrees"]


def test_a_tyre_pressure_the_file_does_not_know_is_the_cases_effect_not_the_plants():
    """``phys_tyre_pressure``: the tyres run at 1.2 bar, the vehicle file (and the calibration of its rear
    radius) says 1.6 bar; the plant's own radius range is taken at the file's pressure."""
    from tractionecu.evaluation.suite import inherent
    from tractionecu.sim import physwriter as pw

    by = {c.name: c for c in all_cases()}
    case = by["phys_tyre_pressure"]
    scn = case.scenario()
    assert scn.vehicle.tyre_pressure_pa == 1.2e5 and case.concealed() == {"tyre_pressure": {"p_ratio": 0.75}}
    veh = pw._declared_vehicle(scn)
    assert veh.tyre_pressure_pa == 1.6e5
    # the declared rear radius is the one calibrated at 1.6 bar: that of the same machine at 1.6 bar
    at_rated = replace(scn, vehicle=replace(scn.vehicle, tyre_pressure_pa=1.6e5))
    ref = pw._declared_vehicle(at_rated)
    assert veh.drivetrain.rolling_radius_m == ref.drivetrain.rolling_radius_m
    assert inherent(case) == inherent(replace(case, build=lambda: at_rated))


def test_a_seed_offset_redraws_the_recording_and_keeps_the_case(monkeypatch, tmp_path):
    """``diagnose_suite.py --seed-offset N``: the same case (field, plan, concealed effects) with the noise and
    sensor draws of seed + N, for figures on recordings the diagnosis was never run on."""
    from tractionecu.evaluation import suite as S

    seen = []
    monkeypatch.setattr(S, "simulate", lambda scn: seen.append(scn) or None)
    monkeypatch.setattr(S, "write_recording", lambda scn, tr, out: None)
    case = next(c for c in S.cases() if c.name == "phys_null_a")
    S.write_case(case, tmp_path / "a")
    S.write_case(case, tmp_path / "b", seed_offset=1000)
    assert seen[1].seed == seen[0].seed + 1000
    assert seen[1].name == seen[0].name and seen[1].vehicle == seen[0].vehicle
    assert (seen[1].plan.x == seen[0].plan.x).all() and seen[1].effects == seen[0].effects


def test_a_missed_effect_counts_as_no_rmse_reduction_not_as_no_recording():
    """An effect recording where the diagnosis fitted nothing (verdict ``none``, no winner, no joint fit) had
    ``rmse_reduction`` None, and the suite's median left the recording out: a miss raised the median instead
    of counting as the 0 the nominal model reduces."""
    from types import SimpleNamespace

    from tractionecu.evaluation.suite import score_case

    case = {c.name: c for c in all_cases()}["gps_latency_a"]
    (name,) = case.concealed()
    chans = {"gnss_speed": SimpleNamespace(name="gnss_speed", effects=(name,)),
             "front_load": SimpleNamespace(name="front_load", effects=("mass",))}
    null = SimpleNamespace(sse={"gnss_speed": 4.0, "front_load": 9.0})
    d = SimpleNamespace(effects=[], verdict="none", effect=None, ambiguous_between=[], candidates=[], joint=None,
                        joint_heldout=None, winner=None, problem=SimpleNamespace(channels=chans), null_heldout=null,
                        open_world={}, candidate=lambda n: None)
    row = score_case(case, d)
    assert not row["correct"]
    assert row["rmse_reduction"] == 0.0 and row["affected_signal"] == "gnss_speed"
    found = {"kind": "effect", "correct": True, "covered": {}, "rmse_reduction": 0.8}
    s = summarize([found, dict(found, rmse_reduction=0.6), {**row, "covered": {}}])
    assert s["median_heldout_rmse_reduction"] == pytest.approx(0.6)      # 0.7 with the miss left out


def test_a_crashed_effect_recording_counts_as_no_rmse_reduction(monkeypatch, tmp_path):
    """A crash is a result of the suite: an effect recording whose diagnosis raised had no RMSE reduction and
    dropped out of the median, which a crash could so raise."""
    import importlib.util
    from pathlib import Path

    from tractionecu.evaluation import suite as S

    path = Path(__file__).resolve().parents[2] / "benchmarks" / "diagnose_suite.py"
    spec = importlib.util.spec_from_file_location("diagnose_suite_bench", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)

    def crash(rec):
        raise FloatingPointError("diagnosis failed")

    monkeypatch.setattr(bench, "diagnose", crash)
    monkeypatch.setattr(bench, "write_case", lambda case, rec, seed_offset=0: None)
    effect = next(c for c in S.all_cases() if c.kind == "effect")
    null = next(c for c in S.all_cases() if c.kind == "null")
    rows = [bench.run_case(effect.name, str(tmp_path), reuse=False), bench.run_case(null.name, str(tmp_path), reuse=False)]
    assert rows[0]["verdict"] == "error" and rows[0]["rmse_reduction"] == 0.0 and "rmse_reduction" not in rows[1]
    assert S.summarize(rows + [{**rows[0], "case": "x", "rmse_reduction": 0.8, "correct": True}])[
        "median_heldout_rmse_reduction"] == pytest.approx(0.4)
