"""Recording reader: CAN by PGN, GPS alignment by UTC, stats, errors, real JD 5055E data."""

import calendar
import math
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import pytest

from tractionecu.bus import j1939
from tractionecu.bus.candump import format_line
from tractionecu.bus.dbc import Codec
from tractionecu.errors import RecordingError
from tractionecu.gnss.nmea import format_gga, format_rmc, format_vtg
from tractionecu.recording.polycan import DEFAULT_EPOCH0, polycan_to_candump
from tractionecu.recording.reader import read_recording
from tractionecu.recording.summary import summarize

REPO = Path(__file__).resolve().parents[2]
CANDUMP = REPO / "tests" / "data" / "candump"
SHARED_JD = REPO / ".." / "shared" / "data" / "tractorhacking-jd5055e"

T0 = calendar.timegm((2024, 5, 17, 10, 0, 0))
WHEELS = ("FL", "FR", "RL", "RR")


@pytest.fixture(scope="module")
def codec():
    return Codec()


def _utc(t):
    return datetime.fromtimestamp(t, tz=timezone.utc)


def write_rec(root, codec, *, t0=T0, duration=2.0, gps=True, gps_rmc=True, drop=(), gps_t0=None):
    """Wheel speeds/torques at 100 Hz, axle load/draft at 50 Hz, GPS at 10 Hz; returns the truth functions."""
    root.mkdir(parents=True, exist_ok=True)
    omega = lambda t, i: 3.0 + 0.5 * i + 0.2 * np.sin(np.asarray(t) - t0)  # noqa: E731
    lines = []
    for k in range(int(duration * 100)):
        t = t0 + k * 0.01
        if k in drop:
            continue
        cid, d = codec.encode("TECU_WheelSpeeds", {f"WheelSpeed_{w}": omega(t, i) for i, w in enumerate(WHEELS)})
        lines.append(format_line(t, "can0", cid, True, d))
        cid, d = codec.encode("TECU_DriveTorques", {f"DriveTorque_{w}": 1000.0 + 10 * i for i, w in enumerate(WHEELS)})
        lines.append(format_line(t + 0.0002, "can0", cid, True, d))
        if k % 2 == 0:
            cid, d = codec.encode("TECU_AxleLoad", {"FrontAxleLoad": 24500.0, "FrontAxleLoadStatus": 0})
            lines.append(format_line(t + 0.0004, "can0", cid, True, d))
            cid, d = codec.encode("RearHitchStatus", {"DraftForce": 12340.0 + k}, sa=0x2A)
            lines.append(format_line(t + 0.0006, "can0", cid, True, d))
    (root / "can.log").write_text("\n".join(lines) + "\n")
    if gps:
        g = []
        start = t0 if gps_t0 is None else gps_t0
        for k in range(int(duration * 10)):
            t = start + 0.1 * k
            g.append(format_gga(_utc(t), 47.0 + 1e-6 * k, 8.0, 4, 14, 0.6, 400.0, 47.0))
            if gps_rmc:
                g.append(format_rmc(_utc(t), 47.0 + 1e-6 * k, 8.0, 2.0, 90.0))
            g.append(format_vtg(2.0, 90.0))
        (root / "gps.nmea").write_text("\r\n".join(g) + "\r\n")
    return omega


def test_signals_decoded_at_native_rate_within_quantisation(tmp_path, codec):
    omega = write_rec(tmp_path / "rec", codec)
    (tmp_path / "rec" / "vehicle.toml").write_text("")
    rec = read_recording(tmp_path / "rec")
    s = rec.signals["WheelSpeed_RL"]
    assert len(s) == 200 and s.unit == "rad/s"
    assert np.all(np.diff(s.t) > 0)
    assert np.max(np.abs(s.value - omega(s.t, 2))) <= 0.0005 + 1e-9
    assert np.all(s.sa == 0x80)
    assert len(rec.signals["FrontAxleLoad"]) == 100
    draft = rec.signals["DraftForce"]
    assert np.all(draft.sa == 0x2A)  # decoded by PGN from a non-default source
    assert np.allclose(draft.value, 12340.0 + np.arange(0, 200, 2), atol=5.0)
    assert rec.stats.messages["TECU_WheelSpeeds"].rate_hz == pytest.approx(100.0, rel=1e-6)
    assert rec.stats.messages["RearHitchStatus"].rate_hz == pytest.approx(50.0, rel=1e-6)
    assert rec.stats.messages["TECU_WheelSpeeds"].n_gaps == 0
    assert rec.vehicle_toml_path == tmp_path / "rec" / "vehicle.toml"
    assert rec.truth_csv_path is None and rec.truth_toml_path is None
    assert "IdentityNumber" not in rec.signals


def test_gps_aligned_by_rmc_date_and_time(tmp_path, codec):
    write_rec(tmp_path / "rec", codec)
    rec = read_recording(tmp_path / "rec")
    g = rec.gps
    assert len(g) == 20
    assert np.allclose(g.t, T0 + 0.1 * np.arange(20), atol=1e-6)
    assert np.allclose(g.speed, 2.0, atol=3e-4) and np.all(g.fix_quality == 4) and np.all(g.nsat == 14)
    assert np.allclose(g.alt, 400.0) and np.allclose(g.course, 90.0)
    assert "RMC" in rec.stats.gps_alignment


def test_rmc_date_wins_over_a_wrong_host_clock(tmp_path, codec):
    # host clock one day late: the CAN epoch says 18 May, the receiver 17 May
    write_rec(tmp_path / "rec", codec, t0=T0 + 86400, gps_t0=T0)
    rec = read_recording(tmp_path / "rec", clock="report")
    assert rec.gps.t[0] == pytest.approx(T0, abs=1e-6)
    # the clocks a day apart and nothing to correlate (constant speeds): reported, and refused by default
    assert "offset not found" in rec.stats.clock_note and rec.stats.clock_offset_s == 0.0
    with pytest.raises(RecordingError, match=r"CAN and GNSS clocks disagree: .* overlap over 0% .*constant"):
        read_recording(tmp_path / "rec")


@pytest.mark.parametrize("can_offset", [-0.55, +0.35])
def test_gga_only_across_midnight_takes_date_from_can(tmp_path, codec, can_offset):
    midnight = calendar.timegm((2024, 5, 18, 0, 0, 0))
    gps_t0 = midnight - 0.95  # 23:59:59.05 ... 00:00:00.95
    write_rec(tmp_path / "rec", codec, t0=midnight + can_offset, gps=True, gps_rmc=False, gps_t0=gps_t0)
    rec = read_recording(tmp_path / "rec")
    assert len(rec.gps) == 20
    assert np.allclose(rec.gps.t, gps_t0 + 0.1 * np.arange(20), atol=1e-6)
    assert "taken from the first CAN frame" in rec.stats.gps_alignment


def test_gps_time_going_backwards_is_counted(tmp_path, codec):
    write_rec(tmp_path / "rec", codec, gps=False)
    t = [T0 + 0.1 * k for k in (0, 1, 2, 1.5, 3, 3)]
    (tmp_path / "rec" / "gps.nmea").write_text(
        "\n".join(format_rmc(_utc(x), 47.0, 8.0, 1.0, 0.0) for x in t[:4])
        + "\n$GNGGA,garbage*00\n"
        + format_rmc(_utc(t[4]), 47.0, 8.0, 1.0, 0.0) + "\n"
    )
    rec = read_recording(tmp_path / "rec")
    nst = rec.stats.files["gps.nmea"]
    assert nst.rejected["time_backwards"] == 1 and nst.examples["time_backwards"] == [4]
    assert nst.rejected["bad_checksum"] == 1
    assert len(rec.gps) == 4 and np.all(np.diff(rec.gps.t) > 0)


def test_gaps_are_reported(tmp_path, codec):
    write_rec(tmp_path / "rec", codec, drop=range(50, 60))
    rec = read_recording(tmp_path / "rec")
    ms = rec.stats.messages["TECU_WheelSpeeds"]
    assert ms.n_gaps == 1
    assert ms.gaps[0][0] == pytest.approx(T0 + 0.49) and ms.gaps[0][1] == pytest.approx(0.11)
    assert rec.stats.messages["TECU_AxleLoad"].n_gaps == 1
    assert "gap 0.110 s" in summarize(rec)


def test_table_zero_order_hold_and_age(tmp_path, codec):
    omega = write_rec(tmp_path / "rec", codec)
    rec = read_recording(tmp_path / "rec")
    tab = rec.table(20.0)
    assert tab.t[0] == rec.t_start and np.allclose(np.diff(tab.t), 0.05)
    ws = tab["WheelSpeed_FL"]
    # at each grid time the latest frame is at or before it
    s = rec.signals["WheelSpeed_FL"]
    idx = np.searchsorted(s.t, tab.t, side="right") - 1
    assert np.array_equal(ws, s.value[idx])
    assert np.all(tab.age["WheelSpeed_FL"] >= 0) and np.all(tab.age["WheelSpeed_FL"] < 0.01 + 1e-9)
    # axle load's first frame is 0.4 ms after the start: NaN and infinite age at t_start
    assert math.isnan(tab["FrontAxleLoad"][0]) and math.isinf(tab.age["FrontAxleLoad"][0])
    assert tab["FrontAxleLoad"][1] == pytest.approx(24500.0)
    assert "gps_speed" in tab and np.nanmax(tab.age["gps_speed"]) <= 0.1 + 1e-6
    assert abs(omega(tab.t[5], 0) - ws[5]) < 0.01


def test_bad_lines_fixture_through_reader():
    rec = read_recording(CANDUMP / "bad_lines.log")
    st = rec.stats
    assert st.files["bad_lines.log"].total_rejected == 10
    assert st.decode_errors == {"TECU_WheelSpeeds": 1, "TECU_AxleLoad": 1}
    assert st.decode_error_lines == {"TECU_WheelSpeeds": [4], "TECU_AxleLoad": [17]}
    assert st.unknown_pgns == {65266: 1}
    assert st.non_extended_frames == 1
    assert np.allclose(rec.signals["WheelSpeed_FL"].value, [1.0, 1.1, 1.2, 1.4])
    assert rec.signals["FrontAxleLoad"].sa.tolist() == [0x21]
    text = summarize(rec)
    for needle in ("time_backwards: 1 (bad_lines.log line 13)", "TECU_AxleLoad: 1 (line 17)", "PGN  65266"):
        assert needle in text


# ------------------------------------------------------------------ errors
def test_missing_recording(tmp_path):
    with pytest.raises(RecordingError, match="no such recording"):
        read_recording(tmp_path / "nope")


def test_directory_without_can_log(tmp_path):
    with pytest.raises(RecordingError, match=r"can\.log: missing"):
        read_recording(tmp_path)


def test_empty_can_log(tmp_path):
    (tmp_path / "can.log").write_text("\n\n")
    with pytest.raises(RecordingError, match=r"can\.log: empty"):
        read_recording(tmp_path)


def test_can_log_without_a_valid_frame_names_file_and_line(tmp_path):
    (tmp_path / "can.log").write_text("\nhello\n(1.0) can0\n")
    with pytest.raises(RecordingError, match=r"can\.log: no valid candump frame in 3 lines, line 2: garbage"):
        read_recording(tmp_path)


def test_empty_gps_file(tmp_path, codec):
    """An empty GNSS log is a recording without GNSS (as without the file): the CAN part is read; refusing
    the whole recording lost a capture whose receiver had never sent."""
    write_rec(tmp_path, codec, gps=False)
    (tmp_path / "gps.nmea").write_text("")
    rec = read_recording(tmp_path)
    assert len(rec.gps) == 0 and rec.signals
    assert rec.stats.files["gps.nmea"].lines == 0


def test_unreadable_can_log(tmp_path):
    (tmp_path / "can.log").mkdir()
    with pytest.raises(RecordingError, match=r"can\.log"):
        read_recording(tmp_path)


# ------------------------------------------------------------------ real data
JD_CLAIMS = {0x00, 0x03, 0x06, 0x17, 0x47}


def test_jd5055e_excerpt_unknown_pgns_counted_and_claims_listed():
    rec = read_recording(CANDUMP / "jd5055e_excerpt.log")
    st = rec.stats
    assert st.files["jd5055e_excerpt.log"].frames == 320
    assert st.files["jd5055e_excerpt.log"].total_rejected == 0
    assert st.decode_errors == {}
    # skipped and counted per PGN: EEC2, TSC1, proprietary A, A2 (data page 1), B, the transport frames ...
    assert 61444 not in st.unknown_pgns and st.messages["EEC1"].count == 54 and st.unknown_pgns[61443] == 53
    assert st.unknown_pgns[61184] == 95 and st.unknown_pgn_sources[61184] == {0x00, 0x06}
    assert st.unknown_pgns[126720] == 31 and st.unknown_pgns[0] == 1
    assert st.unknown_pgns[60416] == 1 and st.unknown_pgns[60160] == 5      # TP.CM (BAM) and TP.DT of EC1
    assert len(st.unknown_pgns) == 24
    # every frame once, as a known message or an unknown PGN; EC1 is the message its TP frames carried
    assert st.messages["EC1"].count == 1
    assert st.unknown_frames + sum(m.count for n, m in st.messages.items() if n != "EC1") == 320
    # the address claims present, with their source addresses and NAMEs
    assert {c.sa for c in st.address_claims} == JD_CLAIMS
    by_sa = {c.sa: c for c in st.address_claims}
    assert by_sa[0x47].name.to_int() == 0x200234000430744D and by_sa[0x47].count == 3
    assert all(c.name.industry_group == 2 for c in st.address_claims)
    assert by_sa[0x00].name.function == 0  # engine
    assert st.messages["AddressClaimed"].count == 16
    assert st.messages["Request"].count == 8
    # GBSD comes from SA 0x47 (not the DBC's 0xF0) and says "not available"
    g = rec.signals["GroundBasedMachineSpeed"]
    assert len(g) == 4 and np.all(g.sa == 0x47) and np.all(np.isnan(g.value))
    assert np.all(rec.signals["GroundBasedMachineDirection"].value == 3)
    assert j1939.DEFAULT_SERVICE_ADDRESS not in JD_CLAIMS
    text = summarize(rec)
    assert "SA 0x47 ( 71)" in text and "unknown PGNs skipped: 230 frames, 24 PGNs" in text
    assert rec.duration == pytest.approx(1.088)


needs_shared = pytest.mark.skipif(not SHARED_JD.is_dir(), reason="shared data ../shared/data/tractorhacking-jd5055e absent")


@needs_shared
def test_committed_excerpt_matches_its_source(tmp_path):
    out = tmp_path / "x.log"
    polycan_to_candump(SHARED_JD / "inNeutralForStartUp.csv", out, DEFAULT_EPOCH0, max_rows=320)
    assert out.read_bytes() == (CANDUMP / "jd5055e_excerpt.log").read_bytes()


@needs_shared
@pytest.mark.parametrize("name", ["inNeutralForStartUp.csv", "highRPM1.csv", "transmision123inGear20Seconds.csv"])
def test_full_jd_captures_through_reader(tmp_path, name):
    with open(SHARED_JD / name) as fh:
        rows = sum(1 for _ in fh) - 1
    polycan_to_candump(SHARED_JD / name, tmp_path / "can.log")
    rec = read_recording(tmp_path)
    st = rec.stats
    assert st.files["can.log"].frames == rows and st.files["can.log"].total_rejected == 0
    assert st.unknown_frames + sum(m.count for n, m in st.messages.items() if n != "EC1") == rows
    # EC1 (BAM from the engine, 34 bytes): reference torque 260 N.m, idle 900 rpm
    assert set(rec.signals["EngineReferenceTorque"].value.tolist()) == {260.0}
    assert rec.signals["EngineSpeedAtIdlePoint1"].value[0] == pytest.approx(900 * math.pi / 30)
    assert np.all(rec.signals["WheelBasedVehicleSpeed"].value == 0.0)              # stationary
    assert JD_CLAIMS <= {c.sa for c in st.address_claims}
    assert j1939.DEFAULT_SERVICE_ADDRESS not in {c.sa for c in st.address_claims}
    assert rec.gps.t.size == 0 and st.gps_alignment == "no gps.nmea"


def test_a_byte_order_mark_costs_no_line(tmp_path, codec):
    """A capture and a GNSS log saved by a Windows tool begin with a UTF-8 byte-order mark: the first line of
    each was rejected as garbage (or read as a prefixed sentence)."""
    write_rec(tmp_path, codec)
    ref = read_recording(tmp_path)
    for name in ("can.log", "gps.nmea"):
        p = tmp_path / name
        p.write_bytes(b"\xef\xbb\xbf" + p.read_bytes())
    rec = read_recording(tmp_path)
    st, gst = rec.stats.files["can.log"], rec.stats.files["gps.nmea"]
    assert st.total_rejected == 0 and gst.total_rejected == 0 and gst.prefixed_count == 0
    assert len(rec.gps) == len(ref.gps) and st.frames == ref.stats.files["can.log"].frames


def test_inspect_lists_the_most_frequent_unknown_pgns_of_a_flood(tmp_path):
    """A flood of random identifiers printed one line per unknown PGN: 8056 lines for 60 s at 5 kHz."""
    import random

    from tractionecu.recording.summary import MAX_UNKNOWN_PGNS, summarize

    rng = random.Random(3)
    lines = [format_line(1000.0 + 0.001 * k, "can0", 0x0CFE0000 | (0x100 * k) % 0x10000 | 0x42, True, bytes(8))
             for k in range(200)]
    lines += [format_line(1000.3 + 0.001 * k, "can0", 0x18F00000 | rng.getrandbits(16), True, bytes(8))
              for k in range(2000)]
    lines.sort(key=lambda ln: float(ln[1:18]))
    (tmp_path / "can.log").write_text("\n".join(lines) + "\n")
    rec = read_recording(tmp_path / "can.log", clock="keep")
    text = summarize(rec)
    pgn_lines = [ln for ln in text.splitlines() if ln.startswith("    PGN ")]
    more = [ln for ln in text.splitlines() if ln.startswith("    ... ")]
    assert len(pgn_lines) == MAX_UNKNOWN_PGNS and len(more) == 1
    n = len(rec.stats.unknown_pgns)
    assert f"{n - MAX_UNKNOWN_PGNS} more PGNs" in more[0]
    listed = sum(int(ln.split()[3]) for ln in pgn_lines) + int(more[0].split()[4])
    assert listed == rec.stats.unknown_frames
