"""The owner's messages on 11-bit identifiers (CAN 2.0A): decoded by identifier, mapped, counted.

A CANedge logger writes its GNSS and IMU frames on identifiers 1–9 beside the J1939 traffic; an implement or a
retrofit sensor may use its own CAN 2.0A bus.  Their messages were skipped ("J1939 decodes 29-bit frames by
PGN"), so a CANedge's GNSS speed could not feed the estimator's ground speed.
"""

from __future__ import annotations

import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from tractionecu.bus.candump import format_line, read_candump
from tractionecu.cli.main import main
from tractionecu.recording.reader import read_recording

from test_reader_fast import assert_same_recording   # this directory is on sys.path (pytest prepend mode)

DATA = Path(__file__).resolve().parents[1] / "data"
MF4 = DATA / "css-electronics-j1939" / "engine-bus-gnss-3s.mf4"
OWNER = DATA / "dbc" / "owner_drivectrl.dbc"

GNSS_DBC = ('VERSION ""\nNS_ :\nBS_:\nBU_: X\n'
            'BO_ 3 gnss_pos: 8 X\n'
            ' SG_ PositionAccuracy : 58|6@1+ (1,0) [0|63] "m" X\n'
            ' SG_ Latitude : 1|28@1+ (1E-006,-90) [-90|90] "deg" X\n'
            ' SG_ Longitude : 29|29@1+ (1E-006,-180) [-180|180] "deg" X\n'
            ' SG_ PositionValid : 0|1@1+ (1,0) [0|1] "" X\n'
            'BO_ 7 gnss_speed: 5 X\n'
            ' SG_ Speed : 1|20@1+ (0.001,0) [0|1048.575] "m/s" X\n'
            ' SG_ SpeedAccuracy : 21|19@1+ (0.001,0) [0|524.287] "m/s" X\n'
            ' SG_ SpeedValid : 0|1@1+ (1,0) [0|1] "" X\n')
"""Two of the CANedge GNSS messages, with the layouts of CSS Electronics' ``gnss.dbc``
(CSS-Electronics/api-examples, MIT)."""


@pytest.fixture()
def canedge(tmp_path) -> tuple[Path, Path]:
    """The real 3-s CANedge excerpt as a recording directory with a [signals] table, and the GNSS DBC."""
    rec = tmp_path / "rec"
    rec.mkdir()
    shutil.copy(MF4, rec / "can.mf4")
    (rec / "vehicle.toml").write_text('[drivetrain]\nkind = "mechanical"\n\n'
                                      '[signals]\nGroundBasedMachineSpeed = "gnss_speed.Speed"\n')
    dbc = tmp_path / "gnss.dbc"
    dbc.write_text(GNSS_DBC)
    return rec, dbc


def test_a_canedge_gnss_speed_feeds_the_ground_speed(canedge):
    rec, dbc = canedge
    r = read_recording(rec, dbc=[dbc], clock="report")
    sp = r.signals["gnss_speed.Speed"]
    assert np.allclose(sp.value, [0.013, 0.041, 0.408]) and np.diff(sp.t) == pytest.approx([1.0, 1.0], abs=0.05)
    assert np.array_equal(r.signals["GroundBasedMachineSpeed"].value, sp.value)
    assert r.signal_sources["GroundBasedMachineSpeed"] == "gnss_speed.Speed"
    lat, lon = r.signals["gnss_pos.Latitude"].value, r.signals["gnss_pos.Longitude"].value
    assert np.allclose(lat, 41.41295, atol=2e-5) and np.allclose(lon, -92.8785, atol=1e-4)    # Iowa, USA
    assert (r.signals["gnss_pos.Latitude"].sa == -1).all()                # an 11-bit frame has no source address
    st = r.stats
    assert st.messages["gnss_speed"].std_id == 7 and st.messages["gnss_speed"].pgn is None
    assert st.messages["gnss_speed"].count == 3 and st.messages["EEC1"].count == 300
    # identifiers 1, 2, 4, 5, 6, 8 (one frame a second) and 9 (IMU, 100 Hz) are in no loaded DBC: counted, skipped
    assert st.non_extended_frames == 6 * 3 + 299


def test_inspect_tells_the_parked_machine_from_its_gnss_noise(canedge, capsys):
    """The tractor is parked (wheel-based speed 0, parking brake set), the GNSS speed reads 0.41 m/s: noise."""
    rec, dbc = canedge
    assert main(["inspect", str(rec), "--dbc", str(dbc)]) == 0
    out = capsys.readouterr().out
    assert "ground speed             GroundBasedMachineSpeed from gnss_speed.Speed" in out
    motion = next(x for x in out.splitlines() if x.strip().startswith("motion:"))
    assert "motion: no motion: WheelBasedVehicleSpeed 0.00 m/s at most" in motion
    assert "GroundBasedMachineSpeed 0.41 m/s at most (3 samples)" in motion       # kept whole, not a stub
    assert "noise at standstill" in motion and "parking brake set" in motion
    assert re.search(r"^ +gnss_speed +0x007 +3 ", out, re.M)          # the messages table: identifier, frames


def test_11_bit_owner_frames_decode_alike_in_bulk_and_frame_by_frame(short_recording, tmp_path):
    """A candump log with the owner's Dash_Lamps (11-bit 0x3A0) and an unknown 11-bit frame among the J1939 ones."""
    rec = tmp_path / "rec"
    shutil.copytree(short_recording, rec)
    lines = []
    for k, f in enumerate(read_candump(short_recording / "can.log")):
        lines.append(format_line(f.t, f.channel, f.can_id, f.is_extended, f.data))
        if k % 50 == 0:
            lines.append(format_line(f.t, f.channel, 0x3A0, False, bytes([k // 50 % 2, 0])))
        if k % 400 == 0:
            lines.append(format_line(f.t, f.channel, 0x123, False, bytes(8)))
            lines.append(format_line(f.t, f.channel, 0x3A0, False, bytes(8)))     # wrong length: a decode error
    (rec / "can.log").write_text("\n".join(lines) + "\n")
    fast = read_recording(rec, dbc=[OWNER])
    assert_same_recording(fast, read_recording(rec, dbc=[OWNER], reference=True))
    beacon = fast.signals["Dash_Lamps.Beacon"]
    assert len(beacon) == math.ceil(len(list(read_candump(short_recording / "can.log"))) / 50)
    assert set(beacon.value.tolist()) == {0.0, 1.0}
    n400 = len(beacon) // 8 + 1
    assert fast.stats.non_extended_frames == n400                         # the unknown 0x123 only
    assert fast.stats.decode_errors["Dash_Lamps"] == n400
    plain = read_recording(rec)                                           # without the owner's DBC: all skipped
    assert "Dash_Lamps.Beacon" not in plain.signals and plain.stats.non_extended_frames == len(beacon) + 2 * n400
