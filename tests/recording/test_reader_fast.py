"""The recording reader's fast paths against its reference paths, array for array.

``read_recording`` (NMEA fast path, epochs assembled and aligned as lists) against
``read_recording(reference=True)`` (sentence by sentence through parse_line, EpochAssembler, align_gps);
``stream_signals`` (blocks decoded without statistics, wanted signals only) against
``stream_signals(reference=True)`` (ChunkDecoder, every signal); ``held_signals`` (the blocks a survey held
for batch replay's one pass) against ``stream_signals``.  On simulated recordings of several
scenarios (GNSS latency, a physical truth, reversing), one with GNSS outages and corrupted NMEA and candump
lines, the fixtures in tests/data, and an owner-mapped capture.
"""

from __future__ import annotations

import random
import shutil
from pathlib import Path

import numpy as np
import pytest

from tractionecu.bus.candump import format_line
from tractionecu.gnss.nmea import checksum
from tractionecu.pipeline.survey import REPLAY_SIGNALS, survey_keep
from tractionecu.recording import fastdecode
from tractionecu.recording.containers import GPS_FIELDS
from tractionecu.recording.reader import HeldBlocks, held_signals, read_recording, stream_signals

REPO = Path(__file__).resolve().parents[2]
DATA = REPO / "tests" / "data"


def _bits(a: np.ndarray) -> tuple:
    return a.dtype.str, a.shape, a.tobytes()


def assert_same_recording(a, b) -> None:
    assert list(a.signals) == list(b.signals)
    for name in a.signals:
        x, y = a.signals[name], b.signals[name]
        assert x.unit == y.unit and all(_bits(getattr(x, f)) == _bits(getattr(y, f)) for f in ("t", "value", "sa")), name
    for f in ("t",) + GPS_FIELDS:
        assert _bits(getattr(a.gps, f)) == _bits(getattr(b.gps, f)), f
    assert repr(a.stats) == repr(b.stats)
    assert a.signal_sources == b.signal_sources and a.units == b.units


def assert_same_stream(rec, names) -> int:
    ref = list(stream_signals(rec, names=names, reference=True))
    new = list(stream_signals(rec, names=names))
    return assert_same_blocks(ref, new)


def assert_same_blocks(ref, new) -> int:
    """Two lists of (blocks, before) equal: as many, ``before`` alike, key order and every array's bits."""
    assert len(ref) == len(new) > 0
    for (ba, before_a), (bb, before_b) in zip(ref, new):
        assert repr(before_a) == repr(before_b)
        assert list(ba) == list(bb)
        for name in ba:
            assert all(_bits(x) == _bits(y) for x, y in zip(ba[name], bb[name])), name
    return len(ref)


def assert_held_is_stream(path: Path, names, hold_names=REPLAY_SIGNALS, **kw) -> int:
    """A survey holding ``hold_names`` equals one without; its held blocks equal ``stream_signals``' blocks of
    ``names`` (key order, ``before`` and every array's bits)."""
    hold = HeldBlocks(hold_names)
    rec = read_recording(path, keep=survey_keep, hold=hold, **kw)
    assert_same_recording(rec, read_recording(path, keep=survey_keep, **kw))
    assert hold.blocks is not None and not hold.over and hold.nbytes > 0
    new = list(held_signals(rec, hold, names))
    ref = list(stream_signals(rec, names=names, **kw))
    assert hold.blocks is None                                  # one pass: handed out and let go
    return assert_same_blocks(ref, new)


def _simulate(out: Path, name: str, seed: int, effects: dict | None = None) -> Path:
    from tractionecu.sim import scenarios
    from tractionecu.sim.simulator import simulate
    from tractionecu.sim.writer import write_recording

    scn = scenarios.get(name, seed=seed, effects=effects or {}, duration_s=15.0)
    write_recording(scn, simulate(scn), out)
    return out


@pytest.fixture(scope="module")
def recordings(tmp_path_factory) -> dict[str, Path]:
    from tractionecu.model.effects import parse_effect_arg

    base = tmp_path_factory.mktemp("recs")
    out = {
        "paper-three-soils": _simulate(base / "p", "paper-three-soils", 0),
        "paper-latency": _simulate(base / "l", "paper-three-soils", 4, dict([parse_effect_arg("gps_latency=0.15")])),
        "headland-reverse": _simulate(base / "h", "headland-reverse", 1),
        "biased-sensors": _simulate(base / "b", "biased-sensors", 2),
        "physical-headland-reverse": _simulate(base / "ph", "physical-headland-reverse", 3),
    }
    # "precedence": the merge's cases, GNSS outages and a receiver without a fix, every line well formed;
    # "damaged": the same with corrupted sentences, and candump lines of the canonical width with bad hex,
    # a bad time, a time going backwards and blanks
    src = out["biased-sensors"]
    d = base / "damaged"
    shutil.copytree(src, d)
    rng = random.Random(11)
    nmea = (d / "gps.nmea").read_text().splitlines()

    def resign(line: str, i: int, value: str) -> str:           # field i replaced, checksum recomputed
        f = line[1:-3].split(",")
        f[i] = value
        body = ",".join(f)
        return f"${body}*{checksum(body)}"

    # the merge's precedence: VTG course and speed unlike RMC's, GGA without position or altitude, ZDA
    # dates, RMC without a mode, sentences in another order
    n = len(nmea)
    for k in range(60, n // 2, 7):
        typ = nmea[k][3:6]
        if typ == "VTG":
            nmea[k] = resign(resign(nmea[k], 1, f"{k % 360}.25"), 5, "")
        elif typ == "GGA":
            nmea[k] = resign(resign(resign(nmea[k], 2, ""), 3, ""), 9, "") if k % 2 else resign(nmea[k], 7, "")
        elif typ == "RMC":
            nmea[k] = resign(nmea[k], 12, "") if k % 2 else resign(nmea[k], 2, "V")
    for k in range(n // 2, n // 2 + 80, 9):
        tod = next(x.split(",")[1] for x in nmea[k:] if x[3:6] in ("GGA", "RMC") and x.split(",")[1])
        zda = f"GNZDA,{tod},10,07,2026,00,00"
        nmea.insert(k, f"${zda}*{checksum(zda)}")
    nmea[n // 2 + 100], nmea[n // 2 + 101] = nmea[n // 2 + 101], nmea[n // 2 + 100]
    for _ in range(4):
        a = rng.randrange(len(nmea) - 30)
        del nmea[a:a + rng.randrange(3, 30)]
    nofix = "GNGGA,,,,,,0,00,99.99,,,,,,"
    nmea.insert(40, f"${nofix}*{checksum(nofix)}")
    prec = base / "precedence"                       # every line well formed: the arrays' path
    shutil.copytree(src, prec)
    (prec / "gps.nmea").write_text("\n".join(nmea) + "\n")
    out["precedence"] = prec
    nmea[41:41] = [nmea[41][:-1] + "0", nmea[42].replace(",", ", ", 1), "junk", nmea[43].lower(), ""]
    (d / "gps.nmea").write_text("\r\n".join(nmea) + "\r\n")
    can = (d / "can.log").read_text().splitlines()
    w = len(can[100])
    can[100] = can[100][:-1] + "G"                    # bad hex, same width
    can[200] = can[200][:3] + "x" + can[200][4:]      # bad time, same width
    can[300] = can[290]                               # time going backwards, same width
    can[400] = " " * w                                # blank, same width
    can.insert(500, "")
    (d / "can.log").write_text("\n".join(can) + "\n")
    out["damaged"] = d
    return out


@pytest.mark.parametrize("chunk", [fastdecode.CHUNK_CHARS, 30_011])
def test_read_recording_equals_reference(recordings, monkeypatch, chunk):
    monkeypatch.setattr(fastdecode, "CHUNK_CHARS", chunk)
    for name, path in recordings.items():
        new = read_recording(path)
        assert len(new.gps) > 20, name
        assert_same_recording(new, read_recording(path, reference=True))
        assert_same_recording(read_recording(path, keep=survey_keep),
                              read_recording(path, keep=survey_keep, reference=True))
    st = read_recording(recordings["damaged"]).stats
    assert st.files["gps.nmea"].total_rejected >= 3 and st.files["can.log"].total_rejected >= 3


def test_well_formed_logs_take_the_arrays_path(recordings):
    from tractionecu.gnss.nmea import NmeaStats
    from tractionecu.recording.gps import _read_columns

    for name, path in recordings.items():
        got = _read_columns(path / "gps.nmea", 1.7e9, NmeaStats())
        assert (got is None) == (name == "damaged"), name


def _gps_both(path: Path, can_t0):
    from tractionecu.errors import RecordingError
    from tractionecu.recording.containers import RecordingStats
    from tractionecu.recording.gps import read_gps

    out = []
    for fast in (False, True):
        st = RecordingStats()
        try:
            tr = read_gps(path, can_t0, st, fast=fast)
            out.append(([_bits(getattr(tr, f)) for f in ("t",) + GPS_FIELDS], repr(st)))
        except RecordingError as e:
            out.append((str(e), repr(st)))
    assert out[0] == out[1], path.read_text()[:300]


def _sentence(body: str) -> str:
    return f"${body}*{checksum(body)}"


def test_gps_logs_edge_cases_equal_reference(tmp_path):
    """Midnight with and without a date, the last representable date, duplicate and backward epochs, times
    0.5 ms apart (the arrays' shortcut declines them), VTG before any time, sentences without a time, the
    fuzz fixtures of the GNSS reader."""
    import json

    gga = "GNGGA,{t},4752.89616,N,11033.20303,W,2,16,0.90,861.2,M,0.0,M,,"
    rmc = "GNRMC,{t},A,4752.89616,N,11033.20303,W,0.522,90.00,{d},,,A,V"
    vtg = "GNVTG,12.50,T,,M,0.522,N,0.966,K,A"
    cases = {
        "gga across midnight": [gga.format(t=t) for t in ("235959.80", "235959.90", "000000.00", "000000.10")],
        "rmc across midnight": [x for t in ("235959.90", "000000.00") for x in (gga.format(t=t), rmc.format(t=t, d="311299"))],
        "date 9999-12-31 then midnight": ["GPZDA,235959.00,31,12,9999,00,00", gga.format(t="235959.00"),
                                          gga.format(t="000000.00")],
        "year 1 back a day": ["GNGGA,000000.00,,,,,0,00,,,M,,M,,", gga.format(t="235959.00"),
                              "GPZDA,000000.00,01,01,0001,00,00"],
        "duplicate and backwards": [gga.format(t=t) for t in ("080000.10", "080000.20", "080000.20", "080000.10",
                                                                "080000.30")],
        "duplicate epoch": [gga.format(t=t) for t in ("080000.10", "080000.20", "080000.10", "080000.20",
                                                        "080000.30")],
        "date arrives later": [gga.format(t="235959.80"), gga.format(t="235959.90"), gga.format(t="000000.00"),
                               rmc.format(t="000000.10", d="010126"), gga.format(t="000000.20")],
        "no fix: rmc V without mode": ["GNRMC,080000.10,V,,,,,,,100726,,,,V", "GNRMC,080000.20,V,,,,,,,100726,,,N,V",
                                       gga.format(t="080000.30"), "GNRMC,080000.30,V,,,,,,,100726,,,,V"],
        "half a millisecond": [gga.format(t=t) for t in ("080000.1000", "080000.1005", "080000.1010", "080000.20")],
        "vtg first, untimed": [vtg, "GNGGA,,,,,,0,00,,,M,,M,,", gga.format(t="080000.10"), vtg,
                               rmc.format(t="", d="100726"), rmc.format(t="080000.10", d="100726")],
        "only vtg": [vtg, vtg],
    }
    for name, bodies in cases.items():
        for can_t0 in (1_783_670_400.0, float("nan"), 1e300):
            p = tmp_path / f"{len(name)}.nmea"
            p.write_text("\n".join(_sentence(b) for b in bodies) + "\n")
            _gps_both(p, can_t0)
    for f in sorted((DATA / "fuzz").glob("*.json")):
        case = json.loads(f.read_text()).get("case", {})
        if isinstance(case, dict) and "lines" in case and "terms" in case:
            p = tmp_path / (f.stem + ".nmea")
            p.write_bytes("".join(a + b for a, b in zip(case["lines"], case["terms"])).encode("utf-8"))
            _gps_both(p, case.get("can_t0", 1_783_670_400.0))


def test_stream_equals_reference(recordings, monkeypatch):
    monkeypatch.setattr(fastdecode, "CHUNK_CHARS", 30_011)      # several blocks
    for name, path in recordings.items():
        rec = read_recording(path, keep=survey_keep)
        names = sorted(rec.signals)
        assert assert_same_stream(rec, None) > 3, name
        assert_same_stream(rec, names[::3])
        assert_same_stream(rec, [n for n in names if n.startswith(("WheelSpeed", "DriveTorque"))])


def test_held_blocks_equal_the_stream(recordings, monkeypatch):
    monkeypatch.setattr(fastdecode, "CHUNK_CHARS", 30_011)      # several blocks
    for name, path in recordings.items():
        rec = read_recording(path, keep=survey_keep)
        names = sorted(REPLAY_SIGNALS & set(rec.signals))
        assert len(names) >= 6, name
        assert assert_held_is_stream(path, names) > 3, name
        assert_held_is_stream(path, names[::3])
        wheels = [n for n in names if n.startswith("WheelSpeed")]
        assert_held_is_stream(path, wheels, hold_names=[*wheels, "FrontAxleLoad"])


@pytest.mark.parametrize("chunk", [fastdecode.CHUNK_CHARS, 30_011])
def test_survey_stubs_are_the_full_reads_signals(recordings, monkeypatch, chunk):
    """A survey (``keep=survey_keep``, values of a stub no longer computed once its first number is known)
    against the full read: the same statistics, the kept signals bit for bit, and each stub's first and last
    time and first number those of the whole signal."""
    monkeypatch.setattr(fastdecode, "CHUNK_CHARS", chunk)
    stubs = 0
    for name, path in recordings.items():
        full = read_recording(path)
        for hold in (None, HeldBlocks(REPLAY_SIGNALS)):
            sv = read_recording(path, keep=survey_keep, hold=hold)
            assert repr(sv.stats) == repr(full.stats), name
            assert list(sv.signals) == list(full.signals) and sv.signal_sources == full.signal_sources
            for sig, s in sv.signals.items():
                f = full.signals[sig]
                if not (len(s) == 2 and (s.sa == -1).all()):        # kept whole (a stub's sources are -1)
                    assert all(_bits(getattr(s, k)) == _bits(getattr(f, k)) for k in ("t", "value", "sa")), sig
                    continue
                stubs += 1
                ok = np.flatnonzero(np.isfinite(f.value))
                first = f.value[ok[0]] if ok.size else np.nan
                assert _bits(s.t) == _bits(np.array([f.t[0], f.t[-1]])), (name, sig)
                assert _bits(s.value) == _bits(np.array([first, np.nan])), (name, sig)
                assert s.unit == f.unit and not (f.sa == -1).any()
    assert stubs > 20


def test_held_blocks_take_the_clock_offset_as_the_stream(recordings, tmp_path):
    """A CAN capture whose clock starts at 0: the survey finds the offset to the GNSS clock, and the held
    blocks carry it as the stream's do."""
    src = recordings["paper-three-soils"]
    d = tmp_path / "shifted"
    shutil.copytree(src, d)
    lines = (src / "can.log").read_text().splitlines()
    t0 = float(lines[0][1:lines[0].index(")")])
    (d / "can.log").write_text("\n".join(f"({float(ln[1:ln.index(')')]) - t0:017.6f}){ln[ln.index(')') + 1:]}"
                                         for ln in lines) + "\n")
    rec = read_recording(d, keep=survey_keep)
    assert abs(rec.stats.clock_offset_s - t0) < 1.0
    assert assert_held_is_stream(d, sorted(REPLAY_SIGNALS & set(rec.signals))) >= 1


def test_held_blocks_over_their_bound_are_dropped(recordings):
    path = recordings["paper-three-soils"]
    hold = HeldBlocks(REPLAY_SIGNALS, max_bytes=50_000)
    rec = read_recording(path, keep=survey_keep, hold=hold)
    assert hold.over and hold.blocks is None and hold.nbytes > 50_000
    assert_same_recording(rec, read_recording(path, keep=survey_keep))   # the survey is whole all the same
    with pytest.raises(ValueError, match="dropped"):
        next(held_signals(rec, hold))
    ok = HeldBlocks(["WheelSpeed_FL"])
    rec = read_recording(path, keep=survey_keep, hold=ok)
    with pytest.raises(ValueError, match="not held: DriveTorque_FL"):
        next(held_signals(rec, ok, ["WheelSpeed_FL", "DriveTorque_FL"]))


def test_fixtures_equal_reference(tmp_path):
    for log in sorted((DATA / "candump").glob("*.log")):
        assert_same_recording(read_recording(log), read_recording(log, reference=True))
    # the mixed NMEA fixture beside a capture whose clock matches its dated epoch
    d = tmp_path / "mixed"
    d.mkdir()
    shutil.copy(DATA / "nmea" / "mixed.nmea", d / "gps.nmea")
    t0 = 1_039_426_045.0                                # 2002-12-09 09:27:25 UTC, the fixture's GGA
    (d / "can.log").write_text("\n".join(format_line(t0 + 0.01 * k, "can0", 0x18FEF1FE, True, bytes(8))
                                         for k in range(50)) + "\n")
    for clock in ("keep", "report"):
        assert_same_recording(read_recording(d, clock=clock), read_recording(d, clock=clock, reference=True))


def test_owner_mapping_streams_equal_reference(tmp_path):
    import struct

    d = tmp_path / "rec"
    d.mkdir()
    t0 = 1_715_940_000.0
    lines = []
    for k in range(400):
        t = t0 + 0.01 * k
        lines.append(format_line(t, "can0", 0x18FF5527, True, struct.pack("<4H", 2865 + k, 2870, 2800, 2810)))
        if k % 2 == 0:
            lines.append(format_line(t + 0.001, "can0", 0x18FF5627, True,
                                     bytes([k % 16, 128]) + struct.pack(">h", -1234 + k) + b"\xff" * 4))
    (d / "can.log").write_text("\n".join(lines) + "\n")
    (d / "vehicle.toml").write_text(
        "[vehicle]\nmass_kg = 4000.0\n\n[signals]\n"
        'WheelSpeed_FL = { signal = "DriveCtrl_3.WhlSpdFL", scale = 0.10471975511965977 }\n'
        'DraftForce = { signal = "DriveCtrl_4.HitchDraft", scale = 1000 }\n')
    dbc = [DATA / "dbc" / "owner_drivectrl.dbc"]
    rec = read_recording(d, dbc=dbc, keep=survey_keep)
    for names in (None, ["WheelSpeed_FL", "DraftForce"], ["WheelSpeed_FL"]):
        ref = list(stream_signals(rec, dbc=dbc, names=names, reference=True))
        new = list(stream_signals(rec, dbc=dbc, names=names))
        assert [list(b) for b, _ in ref] == [list(b) for b, _ in new]
        for (ba, _), (bb, _) in zip(ref, new):
            for name in ba:
                assert all(_bits(x) == _bits(y) for x, y in zip(ba[name], bb[name])), name
    assert "WheelSpeed_FL" in new[0][0]
    # held by the survey: the mapped signals (and their owner sources) as the stream gives them
    for names in (["WheelSpeed_FL", "DraftForce"], ["DraftForce"]):
        assert assert_held_is_stream(d, names, dbc=dbc) >= 1
