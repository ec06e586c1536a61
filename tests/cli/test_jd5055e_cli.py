"""The John Deere 5055E capture (stationary, mechanical drivetrain) through ``inspect`` and ``replay``.

``inspect`` lists what each estimation profile finds; without a vehicle.toml ``replay`` does not run (the hub
profile needs per-wheel speeds and torques the tractor does not send), writes nothing, reports the profiles,
the missing signals, the profile the signals fit (mechanical) and "no motion", and exits with code 4.  With
``[drivetrain] kind = "mechanical"`` it runs the machine-level estimator: tests/pipeline/test_machine_replay.py.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tractionecu.cli.main import main
from tractionecu.cli.replay import EXIT_MISSING_SIGNALS
from tractionecu.recording.polycan import DEFAULT_EPOCH0, polycan_to_candump

REPO = Path(__file__).resolve().parents[2]
EXCERPT = REPO / "tests" / "data" / "candump" / "jd5055e_excerpt.log"
SHARED_JD = REPO.parent / "shared" / "data" / "tractorhacking-jd5055e"


@pytest.fixture
def jd_dir(tmp_path) -> Path:
    d = tmp_path / "jd"
    d.mkdir()
    shutil.copy(EXCERPT, d / "can.log")
    return d


def test_inspect_lists_found_and_missing_signals_per_profile(jd_dir, capsys):
    assert main(["inspect", str(jd_dir)]) == 0
    out = capsys.readouterr().out
    assert "replay runs hub (no vehicle.toml: the default [drivetrain] kind = \"hub\")" in out
    assert "hub (replay runs this one): 0 of 11 found" in out
    assert "wheel speed FL   missing: WheelSpeed_FL" in out and "GNSS speed       missing: GNSS speed" in out
    assert ('mechanical (estimated with [drivetrain] kind = "mechanical" or "power-split" in vehicle.toml): '
            "3 of 6 found") in out
    assert 'the signals fit profile mechanical best: declare [drivetrain] kind = "mechanical"' in out
    assert "engine percent torque    ActualEnginePercentTorque from EEC1" in out
    assert "engine reference torque  EngineReferenceTorque from EC1" in out
    assert "wheel-based speed        WheelBasedVehicleSpeed from CCVS1" in out
    assert "gear ratio               missing: TransmissionActualGearRatio (ETC2 sent, every value not available)" in out
    assert "motion: no motion: WheelBasedVehicleSpeed 0.00 m/s at most (4 samples)" in out
    assert "(transport protocol: data)" in out


def test_replay_reports_profile_missing_signals_and_no_motion(jd_dir, tmp_path, capsys):
    out_dir = tmp_path / "run"
    for rec in (jd_dir, EXCERPT):                              # a recording directory, or the candump file alone
        assert main(["replay", str(rec), "--out", str(out_dir)]) == EXIT_MISSING_SIGNALS == 4
        captured = capsys.readouterr()
        err = captured.err
        assert captured.out == "" and "Traceback" not in err
        assert "not replayed: profile hub (the one the estimator runs, no vehicle.toml" in err
        assert "lacks 10 bus signal(s)" in err
        assert "missing: WheelSpeed_FL, WheelSpeed_FR, WheelSpeed_RL, WheelSpeed_RR, DriveTorque_FL" in err
        assert "profile mechanical (estimated with [drivetrain] kind" in err and "3 of 6 needs found" in err
        assert "the signals fit profile mechanical best" in err
        assert "missing gear ratio, draft, ground speed" in err
        assert "motion: no motion" in err and "idle 900 rpm" in err
        assert not out_dir.exists()


@pytest.mark.skipif(not SHARED_JD.is_dir(), reason="shared data ../shared/data/tractorhacking-jd5055e absent")
@pytest.mark.parametrize("name", ["inNeutralForStartUp.csv", "highRPM1.csv", "transmision123inGear20Seconds.csv"])
def test_full_captures_inspect_and_replay_cleanly(name, tmp_path, capsys):
    rec = tmp_path / "rec"
    rec.mkdir()
    polycan_to_candump(SHARED_JD / name, rec / "can.log", DEFAULT_EPOCH0)
    assert main(["inspect", str(rec)]) == 0
    out = capsys.readouterr().out
    assert "engine reference torque  EngineReferenceTorque from EC1" in out and "motion: no motion" in out
    assert main(["replay", str(rec), "--out", str(tmp_path / "run")]) == EXIT_MISSING_SIGNALS
    err = capsys.readouterr().err
    assert "motion: no motion" in err and "Traceback" not in err
