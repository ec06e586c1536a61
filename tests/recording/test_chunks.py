"""A capture read in small blocks decodes to the same signals and statistics as one read in one piece."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from tractionecu import read_recording
from tractionecu.recording import fastdecode


def _same(a, b) -> None:
    assert list(a.signals) == list(b.signals)
    for name, s in a.signals.items():
        o = b.signals[name]
        np.testing.assert_array_equal(o.t, s.t, err_msg=name)
        np.testing.assert_array_equal(o.value, s.value, err_msg=name)
        np.testing.assert_array_equal(o.sa, s.sa, err_msg=name)
    sa, sb = a.stats, b.stats
    assert list(sa.messages) == list(sb.messages)
    for name, ms in sa.messages.items():
        assert vars(ms) == vars(sb.messages[name]), name
    for k in ("can_t_first", "can_t_last", "n_time_jumps", "time_jumps", "unknown_pgns", "unknown_pgn_sources",
              "decode_errors", "decode_error_lines", "non_extended_frames"):
        assert getattr(sa, k) == getattr(sb, k), k
    assert list(sa.unknown_pgns) == list(sb.unknown_pgns)
    assert [vars(c) for c in sa.address_claims] == [vars(c) for c in sb.address_claims]
    ra, rb = sa.files["can.log"], sb.files["can.log"]
    assert (ra.lines, ra.frames, ra.rejected, ra.examples) == (rb.lines, rb.frames, rb.rejected, rb.examples)


@pytest.mark.parametrize("chunk_chars", [997, 20_000])
def test_blocks_decode_like_the_whole(short_recording, tmp_path, monkeypatch, chunk_chars):
    # bad lines, a gap and a time jump across block borders
    shutil.copytree(short_recording, tmp_path / "rec")
    lines = (short_recording / "can.log").read_text().splitlines()
    lines[100:100] = ["garbage line", "(1.5) can0 18FEE000#00", ""]
    n = len(lines)
    del lines[n // 3:n // 3 + 300]
    t = lambda ln: float(ln[1:ln.index(")")])  # noqa: E731
    lines[2 * n // 3:] = [f"({t(ln) + 90:017.6f}){ln[ln.index(')') + 1:]}" for ln in lines[2 * n // 3:]]
    (tmp_path / "rec" / "can.log").write_text("\n".join(lines) + "\n")
    whole = read_recording(tmp_path / "rec", clock="keep")
    assert whole.stats.n_time_jumps == 1 and whole.stats.files["can.log"].total_rejected >= 2
    monkeypatch.setattr(fastdecode, "CHUNK_CHARS", chunk_chars)
    _same(whole, read_recording(tmp_path / "rec", clock="keep"))


def test_a_stub_keeps_the_span_and_the_first_number(short_recording):
    full = read_recording(short_recording)
    part = read_recording(short_recording, keep=lambda name, seen: not name.startswith("DriveTorque_"))
    assert list(part.signals) == list(full.signals)
    for name, s in full.signals.items():
        o = part.signals[name]
        if name.startswith("DriveTorque_"):
            assert len(o) == 2 and o.t[0] == s.t[0] and o.t[-1] == s.t[-1]
            assert o.value[0] == s.value[np.isfinite(s.value)][0]
        else:
            np.testing.assert_array_equal(o.value, s.value)
    assert part.t_end == full.t_end and part.t_start == full.t_start
