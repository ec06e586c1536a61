"""Estimation profiles on a recording: needs found or missing, the replay gate, and motion."""

from __future__ import annotations

import math

import pytest

from tractionecu.bus.candump import format_line
from tractionecu.bus.dbc import WHEELS, default_codec
from tractionecu.cli.replay import missing_report, profile_note
from tractionecu.pipeline.replay import MissingSignals, recording_grid
from tractionecu.pipeline.rundir import replay_to_dir
from tractionecu.pipeline.signals import (REPLAY_REQUIRED, missing_signals, motion, profile_status, signal_state,
                                          source_of)
from tractionecu.recording.reader import read_recording

T0 = 1_715_940_000.0


def write(tmp_path, messages: dict[str, dict], n: int = 200):
    """A recording of ``n`` frames of each message every 10 ms (values fixed), no GNSS."""
    codec = default_codec()
    lines = []
    for k in range(n):
        for i, (name, values) in enumerate(messages.items()):
            cid, data = codec.encode(name, values)
            lines.append(format_line(T0 + 0.01 * k + 1e-4 * i, "can0", cid, True, data))
    d = tmp_path / "rec"
    d.mkdir(exist_ok=True)
    (d / "can.log").write_text("\n".join(lines) + "\n")
    return read_recording(d)


HUB = {"TECU_WheelSpeeds": {f"WheelSpeed_{w}": 3.0 for w in WHEELS},
       "TECU_DriveTorques": {f"DriveTorque_{w}": 800.0 for w in WHEELS}}


def test_hub_without_draft_and_load_is_refused_and_without_gnss_replays_with_a_note(tmp_path):
    """Without the front-axle load and the draft the hub estimator never starts: such a replay ran to exit 0
    with no estimate at all and only the note "the estimator flags those steps"."""
    rec = write(tmp_path, HUB)
    assert missing_signals(rec) == ["FrontAxleLoad", "DraftForce"]
    hub = dict((need.what, sig) for need, sig in profile_status(rec)["hub"])
    assert hub["wheel speed FL"] == "WheelSpeed_FL" and hub["draft"] is None and hub["GNSS speed"] is None
    assert source_of(rec, "WheelSpeed_FL") == "TECU_WheelSpeeds"
    with pytest.raises(MissingSignals) as e:
        replay_to_dir(rec, tmp_path / "run", write_map=False)
    assert e.value.missing == ["FrontAxleLoad", "DraftForce"]
    m = motion(rec)
    assert m.moving is True and m.evidence[0].startswith("WheelSpeed_FL 3.00 rad/s")

    rec = write(tmp_path, {**HUB, "TECU_AxleLoad": {"FrontAxleLoad": 25000.0, "FrontAxleLoadStatus": 0},
                           "RearHitchStatus": {"DraftForce": 12000.0}})
    assert missing_signals(rec) == []
    assert profile_note(rec)[1:] == ["profile hub: missing GNSS speed: the estimator flags those steps (time-out "
                                     "bits)"]
    assert profile_note(rec)[0].startswith("no vehicle.toml beside the recording")
    summary, _, res = replay_to_dir(rec, tmp_path / "run", write_map=False)
    assert res.steps > 150 and not res.arrays["valid"].any()


def test_not_available_signals_count_as_missing_and_stop_replay(tmp_path):
    rec = write(tmp_path, {**HUB, "TECU_DriveTorques": {},          # every torque sent as "not available"
                           "TECU_AxleLoad": {"FrontAxleLoad": 25000.0, "FrontAxleLoadStatus": 0},
                           "RearHitchStatus": {"DraftForce": 12000.0}})
    assert signal_state(rec, "DriveTorque_FL") == "not available" and signal_state(rec, "DraftForce") == "found"
    assert missing_signals(rec) == [f"DriveTorque_{w}" for w in WHEELS]
    with pytest.raises(MissingSignals) as e:
        recording_grid(rec, 100.0)
    assert e.value.missing == [f"DriveTorque_{w}" for w in WHEELS] and e.value.recording is rec
    with pytest.raises(MissingSignals):
        replay_to_dir(rec, tmp_path / "run")
    assert not (tmp_path / "run").exists()
    report = "\n".join(missing_report(rec, e.value.missing))
    assert "missing: DriveTorque_FL, DriveTorque_FR, DriveTorque_RL, DriveTorque_RR" in report
    assert "profile hub: 6 of 11 needs found" in report


def test_mechanical_needs_take_any_wheel_based_or_ground_speed(tmp_path):
    rec = write(tmp_path, {"EEC1": {"ActualEnginePercentTorque": 40.0, "EngineSpeed": 1800 * math.pi / 30},
                           "ETC2": {"TransmissionActualGearRatio": 42.5, "TransmissionSelectedGear": 4},
                           "EBC2": {"FrontAxleSpeed": 2.0}, "GBSD": {"GroundBasedMachineSpeed": 1.9},
                           "RearHitchStatus": {"DraftForce": 15000.0}})
    mech = dict((need.what, sig) for need, sig in profile_status(rec)["mechanical"])
    assert mech == {"engine percent torque": "ActualEnginePercentTorque", "engine reference torque": None,
                    "gear ratio": "TransmissionActualGearRatio", "wheel-based speed": "FrontAxleSpeed",
                    "draft": "DraftForce", "ground speed": "GroundBasedMachineSpeed"}
    assert set(missing_signals(rec)) == set(REPLAY_REQUIRED) - {"DraftForce"}    # the hub's needs: the draft is there
    m = motion(rec)
    assert m.moving is True and "engine 1800 to 1800 rpm (median 1800)" in m.describe()
    assert "gear selected: +4" in m.describe()


def test_motion_unknown_without_speeds_and_standing_with_zero_speed(tmp_path):
    rec = write(tmp_path, {"EEC1": {"EngineSpeed": 900 * math.pi / 30}}, n=20)
    assert motion(rec).moving is None and motion(rec).describe().startswith("unknown (no speed signal)")
    rec = write(tmp_path, {"CCVS1": {"WheelBasedVehicleSpeed": 0.05, "ParkingBrakeSwitch": 1},
                           "ETC2": {"TransmissionSelectedGear": 0}}, n=20)
    m = motion(rec)
    assert m.moving is False
    assert m.describe() == ("no motion: WheelBasedVehicleSpeed 0.05 m/s at most (20 samples); gear selected: neutral; "
                            "parking brake set")


def test_the_rear_hitch_status_at_its_standard_rate_has_no_gaps(make_recording):
    """ISO 11783-7 sends the rear hitch status every 100 ms, as the mechanical simulator does; the DBC's
    nominal period was 20 ms, so inspect listed every frame of a mechanical recording as a gap."""
    rec = read_recording(make_recording("mechanical-three-soils", 3, 4.0))
    ms = rec.stats.messages["RearHitchStatus"]
    assert ms.rate_hz == pytest.approx(10.0, rel=0.05) and ms.nominal_period_s == pytest.approx(0.1)
    assert ms.n_gaps == 0
    hub = read_recording(make_recording("paper-straight", 3, 4.0)).stats.messages["RearHitchStatus"]
    assert hub.rate_hz == pytest.approx(50.0, rel=0.05) and hub.n_gaps == 0     # faster than the standard: fine


def test_a_ground_speed_in_travel_against_standing_wheels_is_a_contradiction_not_no_motion(tmp_path):
    """CCVS1's speed left at 0 by the tractor while GBSD read 2.8 m/s: inspect and replay said "no motion",
    calling the ground speed its noise at standstill, while the replay made 4981 valid estimates."""
    rec = write(tmp_path, {"CCVS1": {"WheelBasedVehicleSpeed": 0.0, "ParkingBrakeSwitch": 0},
                           "GBSD": {"GroundBasedMachineSpeed": 2.8}}, n=50)
    m = motion(rec)
    assert m.moving is None and m.describe().startswith("unknown (the speeds disagree): ")
    assert "contradiction: a ground speed above 0.5 m/s on 100 % of its samples" in m.describe()
    rec = write(tmp_path, {"CCVS1": {"WheelBasedVehicleSpeed": 0.0, "ParkingBrakeSwitch": 1},
                           "GBSD": {"GroundBasedMachineSpeed": 0.15}}, n=50)     # radar noise at standstill
    assert motion(rec).moving is False and "noise at standstill" in motion(rec).describe()
