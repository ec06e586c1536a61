"""candump -L reading and writing."""

import io
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tractionecu.bus.candump import (
    CandumpWriter,
    Frame,
    ReadStats,
    format_line,
    iter_candump,
    read_candump,
    write_candump,
)

DATA = Path(__file__).resolve().parents[1] / "data" / "candump"


def test_format_matches_can_utils():
    assert format_line(1700000000.123456, "can0", 0x18FF1080, True, bytes(range(1, 9))) == (
        "(1700000000.123456) can0 18FF1080#0102030405060708"
    )
    assert format_line(12.5, "vcan0", 0x7B, False, b"\xab\xcd") == "(0000000012.500000) vcan0 07B#ABCD"
    assert format_line(1.0, "can1", 0x0CFE4947, True, b"") == "(0000000001.000000) can1 0CFE4947#"


def test_format_rejects_invalid_frames():
    with pytest.raises(ValueError):
        format_line(1.0, "can0", 0x800, False, b"")
    with pytest.raises(ValueError):
        format_line(1.0, "can0", 0x1, True, bytes(9))
    with pytest.raises(ValueError):
        format_line(-1.0, "can0", 0x1, True, b"")


frames = st.lists(
    st.tuples(
        st.integers(0, 10_000_000),  # µs increments
        st.sampled_from(["can0", "can1", "vcan0"]),
        st.booleans(),
        st.integers(0, 0x1FFFFFFF),
        st.binary(min_size=0, max_size=8),
    ),
    max_size=40,
)


@given(frames, st.integers(1_500_000_000, 1_900_000_000))
def test_write_read_round_trip(items, t0):
    out = []
    t_us = t0 * 1_000_000
    for dt, ch, ext, ident, data in items:
        t_us += dt
        if not ext:
            ident &= 0x7FF
        out.append(Frame(t_us / 1e6, ch, ident, ext, data))
    buf = io.StringIO()
    w = CandumpWriter(buf)
    for f in out:
        w.write_frame(f)
    stats = ReadStats()
    back = list(iter_candump(io.StringIO(buf.getvalue()), stats))
    assert stats.total_rejected == 0 and stats.frames == len(out)
    for a, b in zip(out, back):
        assert (a.channel, a.can_id, a.is_extended, a.data) == (b.channel, b.can_id, b.is_extended, b.data)
        assert round(a.t * 1e6) == round(b.t * 1e6)


def test_write_candump_file(tmp_path):
    p = tmp_path / "can.log"
    n = write_candump(p, [(1.0, "can0", 0x0CFF1080, True, b"\x01"), Frame(2.0, "can0", 0x10, False, b"")])
    assert n == 2
    assert p.read_text() == "(0000000001.000000) can0 0CFF1080#01\n(0000000002.000000) can0 010#\n"


def test_bad_lines_are_counted_by_reason_with_line_numbers():
    stats = ReadStats()
    got = list(read_candump(DATA / "bad_lines.log", stats))
    assert stats.source == "bad_lines.log"
    assert stats.lines == 20
    assert stats.frames == len(got) == 9
    assert dict(stats.rejected) == {
        "garbage": 1,
        "truncated": 2,
        "bad_hex": 1,
        "dlc_gt_8": 1,
        "canfd": 1,
        "rtr": 1,
        "error_frame": 1,
        "bad_timestamp": 1,
        "time_backwards": 1,
    }
    assert stats.examples["truncated"] == [5, 18]
    assert stats.examples["time_backwards"] == [13]
    assert stats.examples["dlc_gt_8"] == [7]
    times = [f.t for f in got]
    assert times == sorted(times)
    assert any("bad_lines.log line 5, 18" in line for line in stats.describe())


def test_line_cut_in_the_middle_and_binary_garbage(tmp_path):
    p = tmp_path / "cut.log"
    good = format_line(1.0, "can0", 0x0CFF1080, True, bytes(8))
    p.write_bytes((good + "\n" + good[:20] + "\n\x00\xff\xfe\x80binary\n" + good[:-3]).encode("latin-1"))
    stats = ReadStats()
    got = list(read_candump(p, stats))
    assert len(got) == 1
    assert stats.rejected["truncated"] == 2  # cut after the timestamp; odd number of data digits
    assert stats.rejected["garbage"] == 1


def test_last_line_cut_after_whole_data_bytes_is_truncated(tmp_path):
    # a logger losing power mid-line: 4 of the 8 data bytes written, no line break
    p = tmp_path / "cut.log"
    good = format_line(1.0, "can0", 0x0CFF1080, True, bytes(8))
    p.write_text(good + "\n" + good[:-8])
    stats = ReadStats()
    got = list(read_candump(p, stats))
    assert len(got) == 1 and stats.rejected["truncated"] == 1 and stats.examples["truncated"] == [2]
    p.write_text(good + "\n" + good)               # all 8 bytes there: only the line break is missing
    stats = ReadStats()
    assert len(list(read_candump(p, stats))) == 2 and not stats.rejected
    short = format_line(2.0, "can0", 0x123, False, b"\x01\x02")
    assert len(list(iter_candump([good, short]))) == 2        # lines given without breaks: read as they are


def test_a_lone_time_stamp_ahead_is_rejected_not_every_frame_after_it():
    """One line whose seconds were 100 000 s ahead (a corrupted digit) made every later line time_backwards:
    74 % of a 60 s capture was left out, and replay advised splitting it where 'its clock restarted'."""
    lines = [format_line(1000.0 + 0.01 * k, "can0", 0x0CFF1080, True, bytes(8)) for k in range(300)]
    lines[100] = format_line(101000.0, "can0", 0x0CFF1080, True, bytes(8))
    lines[0] = format_line(5000.0, "can0", 0x0CFF1080, True, bytes(8))              # the first line too
    stats = ReadStats()
    got = list(iter_candump(lines, stats))
    assert len(got) == 298 and dict(stats.rejected) == {"time_ahead": 2}
    assert stats.examples["time_ahead"] == [1, 101]
    # a capture whose time jumps two hours and goes on from there keeps every frame
    jump = [format_line(1000.0 + 0.01 * k + (7200.0 if k >= 150 else 0.0), "can0", 0x0CFF1080, True, bytes(8))
            for k in range(300)]
    stats = ReadStats()
    assert len(list(iter_candump(jump, stats))) == 300 and not stats.rejected
    # a frame slightly ahead stays the time_backwards of the frames after it, as before
    small = [format_line(t, "can0", 0x0CFF1080, True, bytes(8)) for t in (1.0, 1.5, 1.2, 1.6)]
    stats = ReadStats()
    assert [f.t for f in iter_candump(small, stats)] == [1.0, 1.5, 1.6]
    assert dict(stats.rejected) == {"time_backwards": 1}


def test_equal_timestamps_are_accepted():
    lines = ["(1.000000) can0 123#00", "(1.000000) can0 124#00"]
    assert len(list(iter_candump(lines))) == 2


def test_direction_suffix_is_accepted():
    # candump -L -x appends T/R
    got = list(iter_candump(["(1.000000) can0 0CFF1080#00 R"]))
    assert got[0].can_id == 0x0CFF1080
