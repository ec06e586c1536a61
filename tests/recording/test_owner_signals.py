"""The owner's DBC and a [signals] table through the recording reader: the form of the table, the mapped
series, the errors naming the key, and the bulk decoder equal to the per-frame one on the owner's messages."""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest

from tractionecu.bus.candump import format_line
from tractionecu.bus.dbc import Codec
from tractionecu.config import load_sensors, load_signal_map, load_vehicle, signal_map
from tractionecu.errors import ConfigError
from tractionecu.recording.reader import read_recording

REPO = Path(__file__).resolve().parents[2]
OWNER = REPO / "tests" / "data" / "dbc" / "owner_drivectrl.dbc"
T0 = 1_715_940_000.0
RPM = 2 * math.pi / 60

SIGNALS = """
[signals]
WheelSpeed_FL = { signal = "DriveCtrl_3.WhlSpdFL", scale = 0.10471975511965977 }
WheelSpeed_FR = { signal = "DriveCtrl_3.WhlSpdFR", scale = 0.10471975511965977 }
DraftForce = { signal = "DriveCtrl_4.HitchDraft", scale = 1000 }
WheelBasedMachineSpeed = "CCVS1.WheelBasedVehicleSpeed"
"""


def owner_lines(n: int = 50) -> list[str]:
    """DriveCtrl_3 (wheel speeds in rpm, little-endian), DriveCtrl_4 (big-endian draft in kN) and CCVS1."""
    out = []
    for k in range(n):
        t = T0 + 0.01 * k
        rpm = [2865 + k, 2870, 0xFFFF if k == 3 else 2800, 2810]               # 0.01 rpm/bit; 0xFFFF n/a
        out.append(format_line(t, "can0", 0x18FF5527, True, struct.pack("<4H", *rpm)))
        if k % 2 == 0:
            out.append(format_line(t + 0.001, "can0", 0x18FF5627, True,
                                   bytes([k % 16, 128]) + struct.pack(">h", -1234 + k) + b"\xff" * 4))
        if k % 10 == 0:
            out.append(format_line(t + 0.002, "can0", 0x18FEF100, True, bytes([0xFF]) + struct.pack("<H", 3200)
                                   + b"\xff" * 5))
    return out


@pytest.fixture
def rec_dir(tmp_path):
    d = tmp_path / "rec"
    d.mkdir()
    (d / "can.log").write_text("\n".join(owner_lines()) + "\n")
    (d / "vehicle.toml").write_text("[vehicle]\nmass_kg = 4000.0\n\n[sensors]\ngps_rate_hz = 5.0\n" + SIGNALS)
    return d


def test_signal_map_forms():
    m = signal_map({"WheelSpeed_FL": "DriveCtrl_3.WhlSpdFL",
                    "WheelSpeed_FR": {"signal": " DriveCtrl_3.WhlSpdFR ", "scale": 2},
                    "DraftForce": {"signal": "DriveCtrl_4.HitchDraft"}})
    assert m == {"WheelSpeed_FL": ("DriveCtrl_3.WhlSpdFL", 1.0), "WheelSpeed_FR": ("DriveCtrl_3.WhlSpdFR", 2.0),
                 "DraftForce": ("DriveCtrl_4.HitchDraft", 1.0)}
    bad = {
        "signals.WheelSpeed_FL: expected": {"WheelSpeed_FL": 3},
        "signals.WheelSpeed_FR: expected": {"WheelSpeed_FR": ""},
        "signals.WheelSpeed_RL.offset: unknown key": {"WheelSpeed_RL": {"signal": "A.B", "offset": 1}},
        "signals.WheelSpeed_RR: the table needs signal": {"WheelSpeed_RR": {"scale": 1.0}},
        "signals.DraftForce.scale: expected a finite, non-zero number": {"DraftForce": {"signal": "A.B", "scale": 0}},
        "signals.FrontAxleLoad.scale": {"FrontAxleLoad": {"signal": "A.B", "scale": "1"}},
        "signals.DriveTorque_FL.scale": {"DriveTorque_FL": {"signal": "A.B", "scale": float("nan")}},
        "signals: expected a table": [1, 2],
    }
    for text, data in bad.items():
        with pytest.raises(ConfigError) as e:
            signal_map(data)
        assert text in str(e.value), (text, str(e.value))


def test_vehicle_file_with_signals_still_loads_vehicle_and_sensors(rec_dir, tmp_path):
    path = rec_dir / "vehicle.toml"
    assert load_vehicle(path).mass_kg == 4000.0 and load_sensors(path).gps_rate_hz == 5.0
    assert load_signal_map(path)["DraftForce"] == ("DriveCtrl_4.HitchDraft", 1000.0)
    flat = tmp_path / "flat.toml"                                   # vehicle keys at the top level
    flat.write_text("mass_kg = 5000.0\n" + SIGNALS)
    assert load_vehicle(flat).mass_kg == 5000.0 and len(load_signal_map(flat)) == 4
    (tmp_path / "none.toml").write_text("mass_kg = 5000.0\n")
    assert load_signal_map(tmp_path / "none.toml") == {}


def test_mapped_signals_are_the_source_times_the_scale(rec_dir):
    rec = read_recording(rec_dir, dbc=[OWNER])
    fl, src = rec.signals["WheelSpeed_FL"], rec.signals["DriveCtrl_3.WhlSpdFL"]
    assert np.array_equal(fl.t, src.t) and np.array_equal(fl.sa, src.sa)
    assert fl.value == pytest.approx((28.65 + 0.01 * np.arange(50)) * RPM) and fl.unit == "rad/s"
    assert src.unit == "rpm" and rec.units["WheelSpeed_FL"] == "rad/s"
    assert rec.signals["DraftForce"].value[:2] == pytest.approx([-1234e1, -1232e1]) and rec.units["DraftForce"] == "N"
    assert rec.signals["WheelBasedMachineSpeed"].value == pytest.approx([12.5 / 3.6] * 5)
    assert "WheelSpeed_RL" not in rec.signals                        # not mapped
    assert math.isnan(rec.signals["DriveCtrl_3.WhlSpdRL"].value[3])
    assert rec.signal_sources["WheelSpeed_FL"] == "DriveCtrl_3.WhlSpdFL x 0.10472"
    assert rec.signal_sources["WheelBasedMachineSpeed"] == "WheelBasedVehicleSpeed"
    assert rec.signal_sources["DriveCtrl_4.HitchDraft"] == "DriveCtrl_4"


def test_an_explicit_mapping_replaces_the_vehicle_files(rec_dir):
    rpm = math.pi / 30.0                                   # the owner's wheel speeds are in rpm
    rec = read_recording(rec_dir, dbc=[OWNER], signals={"WheelSpeed_RR": ("DriveCtrl_3.WhlSpdRR", rpm)})
    assert "WheelSpeed_FL" not in rec.signals and rec.signals["WheelSpeed_RR"].value[0] == pytest.approx(28.10 * rpm)
    rec = read_recording(rec_dir, dbc=[OWNER], signals={})
    assert not any(k.startswith("WheelSpeed") for k in rec.signals)
    rec = read_recording(rec_dir, dbc=[OWNER], signals={"FrontAxleLoad": ("DriveCtrl_4.Counter", 5.0)})
    assert "FrontAxleLoad" in rec.signals                                       # mapped onto any contract input
    (rec_dir / "can.log").write_text("\n".join(x for x in owner_lines() if "18FF5627" not in x) + "\n")
    rec = read_recording(rec_dir, dbc=[OWNER])                                 # DriveCtrl_4 never sent
    assert "DraftForce" not in rec.signals
    assert rec.signal_sources["DraftForce"] == "DriveCtrl_4.HitchDraft x 1000, not in the recording"
    from tractionecu.cli.inspect import profile_lines
    assert any("missing: DraftForce (mapped: DriveCtrl_4.HitchDraft x 1000, not in the recording)" in x
               for x in profile_lines(rec))


def test_a_mapping_without_the_owner_dbc_is_a_config_error_naming_file_and_key(rec_dir):
    with pytest.raises(ConfigError) as e:
        read_recording(rec_dir)
    assert str(rec_dir / "vehicle.toml") in str(e.value) and "signals.WheelSpeed_FL" in str(e.value)
    assert "--dbc" in str(e.value)
    (rec_dir / "vehicle.toml").write_text('[signals]\nWheelSpeed_XX = "DriveCtrl_3.WhlSpdFL"\n')
    with pytest.raises(ConfigError, match="signals.WheelSpeed_XX: not a contract signal"):
        read_recording(rec_dir, dbc=[OWNER])


def test_bulk_and_per_frame_decoders_agree_on_the_owner_messages(tmp_path):
    from test_fastdecode import assert_same    # this directory is on sys.path (pytest's prepend import mode)

    path = tmp_path / "can.log"
    lines = owner_lines(120)
    lines[7] = lines[7][:-4]                                          # a DriveCtrl frame of 6 bytes: decode error
    path.write_text("\n".join(lines) + "\n")
    sig, st = assert_same(path, Codec(extra=[OWNER]))
    assert {"DriveCtrl_3", "DriveCtrl_4", "CCVS1"} <= set(st.messages) and st.decode_errors
    assert sig["DriveCtrl_4.HitchDraft"].value[0] == pytest.approx(-12.34)


def test_a_mapping_in_other_units_without_a_scale_or_one_source_twice_is_refused():
    """A km/h speed mapped without its scale ran replay with a ρ_s error of 0.29 and no word; a radar mapped
    onto the wheel-based speed's source halved the slip."""
    from tractionecu.bus.dbc import Codec
    from tractionecu.errors import ConfigError

    codec = Codec(extra=[OWNER])
    with pytest.raises(ConfigError, match=r"signals.WheelSpeed_FL: DriveCtrl_3.WhlSpdFL is in rpm, WheelSpeed_FL in "
                                          r"rad/s: give scale = 0.10472"):
        codec.resolve_mapping({"WheelSpeed_FL": ("DriveCtrl_3.WhlSpdFL", 1.0)})
    assert codec.resolve_mapping({"WheelSpeed_FL": ("DriveCtrl_3.WhlSpdFL", math.pi / 30.0)})
    with pytest.raises(ConfigError, match=r"signals.WheelSpeed_FR: DriveCtrl_3.WhlSpdFL is already "
                                          r"signals.WheelSpeed_FL; one measurement cannot be two"):
        codec.resolve_mapping({"WheelSpeed_FL": ("DriveCtrl_3.WhlSpdFL", math.pi / 30.0),
                               "WheelSpeed_FR": ("DriveCtrl_3.WhlSpdFL", math.pi / 30.0)})


def test_units_in_capitals_are_judged_and_an_inverted_scale_is_refused(tmp_path):
    """An owner DBC giving its wheel speed in "RPM" (capitals) was mapped without a scale and taken as rad/s:
    ω 33 rad/s for 3.4, slip 0.90, a 0.35 for 0.73, exit 0. Its inverse (9.549) ran with no valid step."""
    from tractionecu.bus.dbc import Codec, unit_factor
    from tractionecu.errors import ConfigError

    for unit, to, f in (("RPM", "rad/s", math.pi / 30.0), ("Km/h", "m/s", 1 / 3.6), ("KPH", "m/s", 1 / 3.6),
                        ("KN", "N", 1000.0), ("MPH", "m/s", 0.44704), ("rev/min", "rad/s", math.pi / 30.0),
                        ("NM", "Nm", 1.0)):
        assert unit_factor(unit, to) == pytest.approx(f), unit
    assert unit_factor("kn", "N") is None           # the knot as often as the kilonewton: not judged
    text = OWNER.read_text().replace('"rpm"', '"RPM"')
    assert '"RPM"' in text
    (tmp_path / "owner.dbc").write_text(text)
    codec = Codec(extra=[tmp_path / "owner.dbc"])
    with pytest.raises(ConfigError, match=r"is in RPM, WheelSpeed_FL in rad/s: give scale = 0.10472"):
        codec.resolve_mapping({"WheelSpeed_FL": ("DriveCtrl_3.WhlSpdFL", 1.0)})
    with pytest.raises(ConfigError, match=r"scale 9.5493 converts rad/s to RPM, the wrong way"):
        codec.resolve_mapping({"WheelSpeed_FL": ("DriveCtrl_3.WhlSpdFL", 30.0 / math.pi)})
    assert codec.resolve_mapping({"WheelSpeed_FL": ("DriveCtrl_3.WhlSpdFL", math.pi / 30.0 / 20.0)})  # a reduction
