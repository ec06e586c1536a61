"""Every capture format: detected by content, decoded to the same frames and signals as candump -L."""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from tractionecu import read_recording, replay
from tractionecu.bus.candump import ReadStats, format_line, read_candump
from tractionecu.errors import RecordingError
from tractionecu.recording.formats import detect, read_frames

DATA = Path(__file__).resolve().parents[1] / "data"
MF4 = DATA / "css-electronics-j1939" / "engine-bus-2s.mf4"

PYTHON_CAN = {"asc": "ASCWriter", "blf": "BLFWriter", "trc": "TRCWriter", "csv": "CSVWriter", "sqlite": "SqliteWriter"}
SCREEN = ("-ta", "-tz", "-td", "-tA", "-x")


def frames_of(rec_dir: Path):
    return list(read_candump(rec_dir / "can.log"))


def write_python_can(frames, path: Path, fmt: str) -> None:
    import can

    if fmt == "sqlite":       # python-can's SqliteWriter writes from a thread and may stop before the last rows
        import sqlite3

        con = sqlite3.connect(path)
        con.execute("CREATE TABLE messages (ts REAL, arbitration_id INTEGER, extended INTEGER, remote INTEGER, "
                    "error INTEGER, dlc INTEGER, data BLOB)")
        con.executemany("INSERT INTO messages VALUES (?, ?, ?, ?, ?, ?, ?)",
                        [(f.t, f.can_id, f.is_extended, False, False, len(f.data), f.data) for f in frames])
        con.commit()
        con.close()
        return
    w = getattr(can, PYTHON_CAN[fmt])(str(path))
    for f in frames:
        w.on_message_received(can.Message(timestamp=f.t, arbitration_id=f.can_id, is_extended_id=f.is_extended,
                                          data=f.data, channel=0))
    w.stop()


def screen_line(mode: str, t: float, prev: float, t0: float, f) -> str:
    ident = f"{f.can_id:08X}" if f.is_extended else f"{f.can_id:03X}".rjust(8)
    body = f"can0  {ident}   [{len(f.data)}]  " + " ".join(f"{b:02X}" for b in f.data)
    if mode == "-tA":
        lt = time.gmtime(t)
        ts = time.strftime("%Y-%m-%d %H:%M:%S", lt) + f".{round((t % 1) * 1e6) % 1000000:06d}"
    elif mode == "-ta":
        ts = f"{t:.6f}"
    elif mode == "-x":
        ts = f"{t:.6f}"
        body = f"can0  RX - -  {ident}   [{len(f.data)}]  " + " ".join(f"{b:02X}" for b in f.data)
    else:
        v = t - t0 if mode == "-tz" else (t - prev if prev is not None else 0.0)
        ts = f"{v:010.6f}"
    return f" ({ts})  {body}"


def write_screen(frames, path: Path, mode: str) -> None:
    t0 = frames[0].t
    out, prev = [], None
    for f in frames:
        # candump prints microseconds: round like it so deltas sum back exactly
        t = round(f.t * 1e6) / 1e6
        out.append(screen_line(mode, t, prev, t0, f))
        prev = t
    path.write_text("\n".join(out) + "\n")


@pytest.fixture(scope="module")
def captures(short_recording, tmp_path_factory):
    """{format: recording directory holding can.<ext> in that format, gps.nmea and vehicle.toml}."""
    frames = frames_of(short_recording)
    base = tmp_path_factory.mktemp("formats")
    out = {}
    for fmt in [*PYTHON_CAN, *(f"screen{m}" for m in SCREEN)]:
        d = base / fmt.replace("-", "_")
        d.mkdir()
        for name in ("gps.nmea", "vehicle.toml"):
            shutil.copy(short_recording / name, d / name)
        cap = d / "can.capture"                   # one name for all: detection is by content
        if fmt in PYTHON_CAN:
            write_python_can(frames, cap, fmt)
        else:
            write_screen(frames, cap, fmt[len("screen"):])
        out[fmt] = d
    return out


EXPECTED = {"asc": "asc", "blf": "blf", "trc": "trc", "csv": "csv", "sqlite": "sqlite",
            "screen-ta": "candump-screen -ta", "screen-tz": "candump-screen -tz",
            "screen-td": "candump-screen -td", "screen-tA": "candump-screen -tA", "screen-x": "candump-screen -ta"}


@pytest.mark.parametrize("fmt", list(EXPECTED))
def test_each_format_decodes_like_candump(captures, short_recording, fmt):
    ref = read_recording(short_recording)
    rec = read_recording(captures[fmt], clock="keep")
    assert rec.stats.can_format == EXPECTED[fmt]
    rs = rec.stats.files["can.capture"]
    assert rs.frames == ref.stats.files["can.log"].frames and not rs.rejected
    assert list(rec.signals) == list(ref.signals)
    assert list(rec.stats.messages) == list(ref.stats.messages)
    shift = rec.stats.can_t_first - ref.stats.can_t_first
    if fmt in ("screen-tz", "screen-td"):
        assert rec.stats.can_t_first == 0.0                # relative: the first frame at 0
    elif fmt == "asc":
        assert abs(shift) < 1.0                            # python-can writes the ASC start to the ms (or worse)
    else:
        assert abs(shift) < 1e-6
    for name, s in ref.signals.items():
        o = rec.signals[name]
        np.testing.assert_array_equal(o.value, s.value, err_msg=name)
        np.testing.assert_array_equal(o.sa, s.sa)
        np.testing.assert_allclose(o.t - shift, s.t, rtol=0, atol=2e-6, err_msg=name)


@pytest.mark.parametrize("fmt", ["blf", "asc", "screen-tz", "screen-td"])
def test_replay_gives_the_same_estimates_from_each_format(captures, short_recording, fmt):
    a = replay(read_recording(short_recording)).arrays
    rec = read_recording(captures[fmt])
    b = replay(rec).arrays
    if fmt != "blf":
        assert "CAN clock offset" in rec.stats.clock_note and "applied" in rec.stats.clock_note
    assert a["t"].size == b["t"].size
    half = slice(a["t"].size // 2, None)
    tol = 1e-9 if fmt == "blf" else 0.002                 # a placed clock moves GNSS timing by tens of ms
    assert np.max(np.abs(a["mu"][half] - b["mu"][half])) <= tol
    assert b["valid"][half].all()


def test_can_utils_log2asc_output_replays_like_candump(short_recording, tmp_path):
    import os
    import subprocess

    if shutil.which("log2asc") is None:
        if os.environ.get("CI"):
            pytest.fail("can-utils' log2asc is missing on CI (.ci/run installs can-utils)")
        pytest.skip("can-utils' log2asc is not installed")

    shutil.copytree(short_recording, tmp_path / "rec")
    subprocess.run(["log2asc", "-I", str(short_recording / "can.log"), "-O", str(tmp_path / "rec" / "can.asc"),
                    "can0"], check=True)
    (tmp_path / "rec" / "can.log").unlink()
    ref = read_recording(short_recording)
    rec = read_recording(tmp_path / "rec")
    assert rec.stats.can_format == "asc"
    st = rec.stats
    # log2asc keeps the start to the second only; the clock offset puts it back within 50 ms
    assert "applied" in st.clock_note and abs(st.can_t_first - ref.stats.can_t_first) < 0.05
    for name, s in ref.signals.items():
        np.testing.assert_array_equal(rec.signals[name].value, s.value, err_msg=name)
    a, b = replay(ref).arrays, replay(rec).arrays
    half = slice(a["t"].size // 2, None)
    assert a["t"].size == b["t"].size and np.max(np.abs(a["mu"][half] - b["mu"][half])) <= 0.002


def test_a_lone_capture_file_reads_the_nmea_beside_it(captures):
    d = captures["blf"]
    rec = read_recording(d / "can.capture")
    assert len(rec.gps) > 100 and rec.stats.can_format == "blf"
    assert rec.vehicle_toml_path is None


def test_a_directory_may_hold_one_can_capture_of_any_extension(captures, tmp_path):
    shutil.copytree(captures["trc"], tmp_path / "rec")
    (tmp_path / "rec" / "can.capture").rename(tmp_path / "rec" / "can.trc")
    rec = read_recording(tmp_path / "rec")
    assert rec.stats.can_format == "trc" and rec.vehicle_toml_path is not None


def test_mf4_excerpt_decodes_like_the_same_frames_as_candump(tmp_path):
    pytest.importorskip("asammdf")
    from asammdf import MDF

    # the reference: the frames taken out of the MF4 with asammdf directly, written as candump -L
    mdf = MDF(str(MF4))
    start = mdf.header.start_time.timestamp()
    ids = mdf.get("CAN_DataFrame.ID", raw=True)
    ide = mdf.get("CAN_DataFrame.IDE", raw=True).samples
    dlc = mdf.get("CAN_DataFrame.DataLength", raw=True).samples
    data = mdf.get("CAN_DataFrame.DataBytes", raw=True).samples
    lines = [format_line(start + float(t), "can0", int(i), bool(e), bytes(d[:n]))
             for t, i, e, n, d in zip(ids.timestamps, ids.samples, ide, dlc, data)]
    mdf.close()
    (tmp_path / "can.log").write_text("\n".join(lines) + "\n")
    ref = read_recording(tmp_path / "can.log")
    rec = read_recording(MF4)
    assert rec.stats.can_format == "mf4" and detect(MF4) == "mf4"
    assert rec.stats.files[MF4.name].frames == len(lines) == 352
    assert list(rec.signals) == list(ref.signals) and "EngineSpeed" in rec.signals
    assert rec.stats.unknown_pgns == ref.stats.unknown_pgns
    assert rec.stats.non_extended_frames == ref.stats.non_extended_frames
    for name, s in ref.signals.items():
        np.testing.assert_array_equal(rec.signals[name].value, s.value)
        np.testing.assert_allclose(rec.signals[name].t, s.t, rtol=0, atol=1e-6)
    rpm = np.nanmean(rec.signals["EngineSpeed"].value) * 60 / (2 * np.pi)
    assert 600 < rpm < 700                                # the engine idles at about 650 rpm


CAN_DATA_FRAME = [("BusChannel", "u1"), ("ID", "<u4"), ("IDE", "u1"), ("DLC", "u1"), ("DataLength", "u1"),
                  ("DataBytes", "u1", (8,)), ("Dir", "u1"), ("EDL", "u1"), ("ESI", "u1"), ("BRS", "u1")]


def write_mf4(frames, path: Path) -> None:
    """The frames as ASAM MDF 4 bus logging, laid out like a CANedge file: one ``CAN_DataFrame`` channel group
    (a bus event of a CAN source) whose structure channel holds ``CAN_DataFrame.ID``, ``.IDE``, ``.DataBytes``…,
    the time in float64 seconds after the header's start time."""
    import datetime as dt

    from asammdf import MDF, Signal, Source
    from asammdf.blocks import v4_constants as v4c

    start = float(np.floor(frames[0].t))     # whole seconds: t - start and start + (t - start) are then exact
    rec = np.zeros(len(frames), dtype=[(f"CAN_DataFrame.{f[0]}", *f[1:]) for f in CAN_DATA_FRAME])
    rec["CAN_DataFrame.BusChannel"] = 1
    rec["CAN_DataFrame.ID"] = [f.can_id for f in frames]
    rec["CAN_DataFrame.IDE"] = [f.is_extended for f in frames]
    rec["CAN_DataFrame.DLC"] = rec["CAN_DataFrame.DataLength"] = [len(f.data) for f in frames]
    for k, f in enumerate(frames):
        rec["CAN_DataFrame.DataBytes"][k, :len(f.data)] = np.frombuffer(f.data, np.uint8)
    src = Source("CAN", "CAN", "", v4c.SOURCE_BUS, v4c.BUS_TYPE_CAN)
    mdf = MDF(version="4.11")
    mdf.header.start_time = dt.datetime.fromtimestamp(start, tz=dt.timezone.utc)
    mdf.append(Signal(rec, np.array([f.t for f in frames]) - start, name="CAN_DataFrame", source=src),
               acq_name="CAN_DataFrame", acq_source=src)
    cg = mdf.groups[0]
    cg.channel_group.path_separator = ord(".")
    cg.channels[0].name = "Timestamp"
    mdf.save(str(path), overwrite=True)
    mdf.close()


@pytest.fixture(scope="module")
def mf4_capture(short_recording, tmp_path_factory):
    """The simulated recording with its CAN frames in ``can.mf4`` instead of ``can.log``."""
    pytest.importorskip("asammdf")
    d = tmp_path_factory.mktemp("mf4") / "rec"
    d.mkdir()
    for name in ("gps.nmea", "vehicle.toml"):
        shutil.copy(short_recording / name, d / name)
    write_mf4(frames_of(short_recording), d / "can.mf4")
    return d


def test_a_simulated_mf4_has_the_canedge_layout(mf4_capture):
    from asammdf import MDF

    def layout(path):
        mdf = MDF(str(path))
        try:
            g = next(g for g in mdf.groups if g.channel_group.acq_name == "CAN_DataFrame")
            cg = g.channel_group
            return (cg.flags, cg.path_separator, cg.acq_source.bus_type,
                    [(c.name, c.channel_type, c.data_type, c.bit_count, c.byte_offset) for c in g.channels])
        finally:
            mdf.close()

    assert layout(mf4_capture / "can.mf4") == layout(MF4)


def test_a_simulated_mf4_decodes_like_candump(mf4_capture, short_recording):
    ref = read_recording(short_recording)
    rec = read_recording(mf4_capture)
    assert detect(mf4_capture / "can.mf4") == "mf4" and rec.stats.can_format == "mf4"
    rs = rec.stats.files["can.mf4"]
    assert rs.frames == ref.stats.files["can.log"].frames and not rs.rejected
    assert list(rec.signals) == list(ref.signals) and list(rec.stats.messages) == list(ref.stats.messages)
    # float64 seconds after a start time in whole seconds: the candump time stamps come back bit for bit
    assert rec.stats.can_t_first == ref.stats.can_t_first and rec.stats.clock_note == ref.stats.clock_note
    for name, s in ref.signals.items():
        o = rec.signals[name]
        np.testing.assert_array_equal(o.value, s.value, err_msg=name)
        np.testing.assert_array_equal(o.sa, s.sa)
        np.testing.assert_array_equal(o.t, s.t, err_msg=name)


def test_inspect_and_replay_of_a_simulated_mf4_match_candump(mf4_capture, short_recording, capsys):
    from tractionecu.cli.main import main

    assert main(["inspect", str(short_recording)]) == 0
    ref = capsys.readouterr().out
    assert main(["inspect", str(mf4_capture)]) == 0
    out = capsys.readouterr().out
    assert "CAN capture format: mf4" in out and "can.mf4: " in out
    same = (out.replace(str(mf4_capture), str(short_recording)).replace("can.mf4: ", "can.log: ")
            .replace("CAN capture format: mf4", "CAN capture format: candump"))
    assert same.splitlines()[:-1] == ref.splitlines()[:-1]           # all but the reading's throughput
    assert same.splitlines()[-1].startswith("  read in ")
    a = replay(read_recording(short_recording)).arrays
    b = replay(read_recording(mf4_capture)).arrays
    assert list(a) == list(b) and a["t"].size > 1000 and b["valid"][a["t"].size // 2:].all()
    for k in a:
        if isinstance(a[k], np.ndarray):
            np.testing.assert_array_equal(b[k], a[k], err_msg=k)
        else:                                   # per-step objects (class names, curves): equal as written
            assert [repr(x) for x in b[k]] == [repr(x) for x in a[k]], k


def _as_mf4(short_recording, tmp_path):
    """The recording with its capture written as an MF4 by python-can's writer (skips without one)."""
    pytest.importorskip("asammdf")
    import can

    if not hasattr(can, "MF4Writer"):
        pytest.skip("this python-can has no MF4 writer")
    shutil.copytree(short_recording, tmp_path / "rec")
    (tmp_path / "rec" / "can.log").unlink()
    w = can.MF4Writer(str(tmp_path / "rec" / "can.mf4"))
    for f in frames_of(short_recording):
        w.on_message_received(can.Message(timestamp=f.t, arbitration_id=f.can_id, is_extended_id=f.is_extended,
                                          data=f.data, channel=0))
    w.stop()
    return tmp_path / "rec"


def test_python_can_mf4_writer_output_decodes_like_candump(short_recording, tmp_path):
    _as_mf4(short_recording, tmp_path)
    ref = read_recording(short_recording)
    rec = read_recording(tmp_path / "rec")
    # python-can writes its start time as a local time without a zone (the header's local-time flag)
    assert rec.stats.can_format == "mf4 (local time)" and rec.stats.can_t_first == ref.stats.can_t_first
    assert list(rec.signals) == list(ref.signals)
    for name, s in ref.signals.items():
        np.testing.assert_array_equal(rec.signals[name].value, s.value, err_msg=name)
        np.testing.assert_array_equal(rec.signals[name].t, s.t, err_msg=name)


def test_an_mf4_cut_before_its_channel_descriptions_is_refused_saying_so(mf4_capture, tmp_path, capsys):
    """A finalised MF4 cut at half its length: refused with asammdf's 'ValueError: seek out of range' alone,
    asammdf's own traceback on standard output and a failing ``MDF4.__del__``'s on standard error."""
    raw = (mf4_capture / "can.mf4").read_bytes()
    (tmp_path / "can.mf4").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(RecordingError, match=rf"an MF4 file cut short: it ends at {len(raw) // 2} bytes"):
        read_frames(tmp_path / "can.mf4", ReadStats())
    import gc

    gc.collect()
    out, err = capsys.readouterr()
    assert out == "" and "Traceback" not in err


def test_an_mf4_whose_last_frame_lost_its_data_bytes_is_read_up_to_it(mf4_capture, monkeypatch):
    """A logger's unfinalised MF4 cut inside its last record: the data bytes channel holds one sample fewer
    than the time stamps, and asammdf's 'samples and timestamps length mismatch' refused the whole file."""
    from asammdf import MDF

    whole = read_frames(mf4_capture / "can.mf4", ReadStats())[0]
    get = MDF.get

    def short(self, name, *a, **kw):
        got = get(self, name, *a, **kw)
        return (got[0][:-1], *got[1:]) if name == "CAN_DataFrame.DataBytes" else got

    monkeypatch.setattr(MDF, "get", short)
    rs = ReadStats()
    table, _ = read_frames(mf4_capture / "can.mf4", rs)
    assert len(table.t) == len(whole.t) - 1 and np.array_equal(table.t, whole.t[:-1])
    assert dict(rs.rejected) == {"truncated": 1} and "without their data bytes" in rs.texts["truncated"]


def test_the_real_unfinalised_mf4_cut_inside_a_record_reads_every_whole_frame(tmp_path):
    real = DATA.parents[2] / "shared" / "data" / "css-electronics-j1939" / "engine-bus-with-gnss.MF4"
    if not real.is_file():
        pytest.skip("the shared data set is not beside the checkout")
    pytest.importorskip("asammdf")
    (tmp_path / "cut.mf4").write_bytes(real.read_bytes()[:2_000_001])
    rs = ReadStats()
    table, _ = read_frames(tmp_path / "cut.mf4", rs)
    assert len(table.t) == 55215 and dict(rs.rejected) == {"truncated": 1}


def test_the_real_unfinalised_mf4_is_recognised():
    real = DATA.parents[2] / "shared" / "data" / "css-electronics-j1939" / "engine-bus-with-gnss.MF4"
    if not real.is_file():
        pytest.skip("the shared data set is not beside the checkout")
    assert real.read_bytes()[:8] == b"UnFinMF " and detect(real) == "mf4"


@pytest.mark.parametrize("content, seen", [
    (b"\x89PNG\r\n\x1a\n" + bytes(200), r"binary data starting b'\\x89PNG"),
    (b"time,speed\n1,2\n3,4\n", r"first line reads 'time,speed'"),
    (b"\x1f\x8b\x08\x00" + bytes(50), r"gzip"),
    (b"\xfd7zXZ\x00\x00\x04" + bytes(50), r"a file compressed with xz; decompress it first \(unxz\)"),
    (b"BZh91AY&SY" + bytes(50), r"compressed with bzip2"),
    (b"\x28\xb5\x2f\xfd" + bytes(50), r"compressed with zstd"),
])
def test_unknown_formats_name_what_was_seen_and_how_to_convert(tmp_path, content, seen):
    p = tmp_path / "capture.log"
    p.write_bytes(content)
    with pytest.raises(RecordingError, match=seen) as e:
        read_recording(p)
    if "compressed" not in seen and "gzip" not in seen:
        assert "candump -L" in str(e.value) and "logconvert" in str(e.value)


@pytest.mark.parametrize("direction", ["", "RX - -  "], ids=["candump", "candump-x"])
def test_screen_output_without_time_stamps_is_refused_with_advice(tmp_path, short_recording, direction):
    f = frames_of(short_recording)[:5]
    p = tmp_path / "can.log"
    p.write_text("".join(f"  can0  {direction}{x.can_id:08X}   [8]  " + " ".join(f"{b:02X}" for b in x.data) + "\n"
                         for x in f))
    assert detect(p) == "candump-screen"
    with pytest.raises(RecordingError, match=r"without time stamps .*cannot be placed in time.*candump -L can0"):
        read_frames(p, ReadStats())


def test_mf4_without_asammdf_names_the_extra(monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_asammdf(name, *a, **k):
        if name == "asammdf" or name.startswith("asammdf."):
            raise ImportError("no asammdf")
        return real_import(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_asammdf)
    with pytest.raises(RecordingError, match=r"tractionecu\[mf4\]"):
        read_frames(MF4, ReadStats())


def _damage_line(path: Path, lineno: int, edit) -> str:
    lines = path.read_text().splitlines(keepends=True)
    lines[lineno - 1] = edit(lines[lineno - 1])
    path.write_text("".join(lines))
    return lines[lineno - 1]


@pytest.mark.parametrize("fmt, edit", [
    ("asc", lambda ln: ln.replace(" d 8 ", " d 8 ZZ ", 1)),            # a data byte that is no hex
    ("csv", lambda ln: "notatime" + ln[ln.index(","):]),                 # a time stamp that is no number
    ("csv", lambda ln: ln.split(",", 1)[0] + ",0xZZ,1,0,0,8,AAAA\n"),    # an identifier that is no hex
])
def test_one_bad_line_of_a_text_capture_is_counted_and_the_rest_read(captures, tmp_path, fmt, edit):
    """One bad line stopped python-can's ASC and CSV readers, and the whole file was refused
    ("cannot read as asc: ValueError: invalid literal for int() with base 16: 'ZZ'", no line number)."""
    d = tmp_path / fmt
    shutil.copytree(captures[fmt], d)
    good = read_frames(captures[fmt] / "can.capture", ReadStats())[0]
    _damage_line(d / "can.capture", 300, edit)
    rs = ReadStats()
    table, got = read_frames(d / "can.capture", rs)
    assert got == fmt and rs.rejected["bad_line"] == 1 and rs.examples["bad_line"] == [300]
    assert len(table.t) == len(good.t) - 1                                # every other frame kept
    rec = read_recording(d)
    assert "bad_line: 1 (can.capture line 300)" in rec.stats.files["can.capture"].describe()


@pytest.mark.parametrize("cut", [3, 12, 24, 35, 44, 57])
def test_an_asc_whose_last_line_is_cut_counts_it(captures, tmp_path, cut):
    """A logger losing power: no ``End TriggerBlock`` and the last frame's line cut ``cut`` characters early.
    Cut in its data it was read as a frame with fewer bytes than its DLC (a decode error of its message);
    cut before them python-can skipped it, and neither was counted."""
    d = tmp_path / "asc"
    shutil.copytree(captures["asc"], d)
    good = read_frames(captures["asc"] / "can.capture", ReadStats())[0]
    text = (d / "can.capture").read_text()
    text = text[:text.rindex("End TriggerBlock")].rstrip("\n")
    n_lines = text.count("\n") + 1
    (d / "can.capture").write_text(text[:-cut])
    rs = ReadStats()
    table, _ = read_frames(d / "can.capture", rs)
    assert dict(rs.rejected) == {"truncated": 1} and rs.examples["truncated"] == [n_lines]
    assert len(table.t) == len(good.t) - 1 and (table.dlc == 8).all()
    (d / "can.capture").write_text(text)             # whole, only the last line break is missing: all read
    rs = ReadStats()
    assert len(read_frames(d / "can.capture", rs)[0].t) == len(good.t) and not rs.rejected


@pytest.mark.parametrize("fmt", ["csv", "screen-ta"])
def test_a_lone_time_stamp_ahead_costs_one_frame_not_the_rest(captures, tmp_path, fmt):
    d = tmp_path / fmt
    shutil.copytree(captures[fmt], d)
    good = read_frames(captures[fmt] / "can.capture", ReadStats())[0]

    def ahead(ln: str) -> str:                        # the time stamp a day ahead
        if fmt == "csv":
            t, rest = ln.split(",", 1)
            return f"{float(t) + 86400.0:.6f},{rest}"
        a, b = ln.index("(") + 1, ln.index(")")
        return f"{ln[:a]}{float(ln[a:b]) + 86400.0:.6f}{ln[b:]}"

    _damage_line(d / "can.capture", 300, ahead)
    rs = ReadStats()
    table, _ = read_frames(d / "can.capture", rs)
    assert dict(rs.rejected) == {"time_ahead": 1} and rs.examples["time_ahead"] == [300]
    assert len(table.t) == len(good.t) - 1


def test_trc_lines_python_can_skips_and_a_truncated_blf_are_counted(captures, tmp_path):
    d = tmp_path / "trc"
    shutil.copytree(captures["trc"], d)
    lines = (d / "can.capture").read_text().splitlines(keepends=True)
    lines.insert(len(lines) // 2, "garbage\r\n")
    (d / "can.capture").write_text("".join(lines))
    rs = ReadStats()
    read_frames(d / "can.capture", rs)
    assert rs.rejected["bad_line"] == 1
    b = tmp_path / "blf"
    shutil.copytree(captures["blf"], b)
    raw = (b / "can.capture").read_bytes()
    (b / "can.capture").write_bytes(raw[: 2 * len(raw) // 3])
    rs = ReadStats()
    read_frames(b / "can.capture", rs)
    assert rs.rejected["truncated"] == 1 and "truncated: 1" in rs.describe()[0]


def test_an_mf4_in_local_time_reads_the_same_in_every_time_zone(short_recording, tmp_path, monkeypatch):
    """An MF4 whose header holds a local time without a zone started at 19:01Z, 17:01Z or 00:01Z by the TZ
    of the computer reading it."""
    import time

    _as_mf4(short_recording, tmp_path)
    firsts = []
    try:
        for zone in ("UTC", "Europe/Berlin", "America/Chicago"):
            monkeypatch.setenv("TZ", zone)
            time.tzset()
            firsts.append(read_recording(tmp_path / "rec", clock="keep").stats.can_t_first)
    finally:
        monkeypatch.undo()
        time.tzset()
    assert firsts[0] == firsts[1] == firsts[2]
