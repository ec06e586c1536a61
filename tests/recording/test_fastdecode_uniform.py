"""Candump blocks whose lines all have one width (read as one byte matrix, fastdecode._Uniform) against the
same blocks split into lines, and against the per-frame reader: same frames, rejects, statistics, signals."""

from __future__ import annotations

import dataclasses
import random
from pathlib import Path

import numpy as np
import pytest

from tractionecu.bus.candump import ReadStats, format_line
from tractionecu.bus.dbc import Codec
from tractionecu.recording import fastdecode
from tractionecu.recording.reader import RecordingStats, _read_can
from tractionecu.recording.reference import read_can_per_frame

T0 = 1_715_940_000.0


@pytest.fixture(scope="module")
def codec():
    return Codec()


def _lines(codec: Codec, n: int) -> list[str]:
    out = []
    for k in range(n):
        t = T0 + 0.01 * k
        cid, d = codec.encode("TECU_WheelSpeeds", {f"WheelSpeed_{w}": 3.0 + 0.01 * k for w in ("FL", "FR", "RL", "RR")},
                              sa=0x80 + k % 3)
        out.append(format_line(t, "can0", cid, True, d))
        cid, d = codec.encode("TECU_DriveTorques", {f"DriveTorque_{w}": -3000.0 + 25.0 * k for w in ("FL", "FR", "RL", "RR")})
        out.append(format_line(t + 0.0002, "can0", cid, True, d))
    return out


def _damage(lines: list[str], rng: random.Random) -> list[str]:
    """Lines of the same width that the per-line classifier must judge: bad hex, a bad time, a bad name,
    the error flag, time going backwards, white space; and a non-ASCII character."""
    out = list(lines)
    w = len(out[0])
    for k in rng.sample(range(10, len(out)), 40):
        line = out[k]
        how = rng.randrange(8)
        if how == 0:
            out[k] = line[:-1] + "G"
        elif how == 1:
            out[k] = line[:5] + "x" + line[6:]
        elif how == 2:
            out[k] = line[:21] + "\t" + line[22:]
        elif how == 3:
            out[k] = line[:25] + "3" + line[26:]                 # identifier 0x3....... : error flag set
        elif how == 4:
            out[k] = out[k - 5]                                  # an earlier time
        elif how == 5:
            out[k] = " " * w
        elif how == 6:
            out[k] = line[:-1] + "\u00e9"
        else:
            out[k] = line[:12] + "9" * 6 + line[18:]
    return out


def _tables(path: Path, chunk: int, uniform: bool, monkeypatch) -> tuple[list, ReadStats]:
    if not uniform:
        monkeypatch.setattr(fastdecode._Uniform, "of", staticmethod(lambda body: None))
    rs = ReadStats(source=path.name)
    tabs = [dataclasses.astuple(t) for t in fastdecode.iter_candump_tables(path, rs, chunk)]
    monkeypatch.undo()
    return tabs, rs


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_uniform_blocks_equal_split_blocks_and_per_frame(tmp_path, codec, monkeypatch, seed):
    rng = random.Random(seed)
    lines = _damage(_lines(codec, 400), rng)
    path = tmp_path / "can.log"
    path.write_bytes(("\n".join(lines) + "\n").encode("utf-8"))
    for chunk in (997, 5000, 1 << 20):
        a, ra = _tables(path, chunk, True, monkeypatch)
        b, rb = _tables(path, chunk, False, monkeypatch)
        assert len(a) == len(b)
        for x, y in zip(a, b):
            assert all(u.dtype == v.dtype and np.array_equal(u, v) for u, v in zip(x, y))
        assert vars(ra) == vars(rb) and ra.total_rejected >= 30
    sa, sb = RecordingStats(), RecordingStats()
    got, ref = _read_can(path, codec, sa), read_can_per_frame(path, codec, sb)
    assert list(got) == list(ref)
    for name in got:
        for f in ("t", "value", "sa"):
            x, y = getattr(got[name], f), getattr(ref[name], f)
            assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=True), (name, f)
    assert vars(sa.files["can.log"]) == vars(sb.files["can.log"])
    assert sa.can_t_first == sb.can_t_first and sa.can_t_last == sb.can_t_last


def test_a_block_with_lines_of_two_widths_is_not_uniform():
    assert fastdecode._Uniform.of("ab\ncd\n") is not None
    assert fastdecode._Uniform.of("ab\ncde\n") is None
    assert fastdecode._Uniform.of("ab\ncde\nf\n") is None         # the length divides, the breaks do not
    assert fastdecode._Uniform.of("a\u00e9\ncd\n") is None
    assert fastdecode._Uniform.of("") is None


def test_a_very_long_line_across_many_blocks(tmp_path, codec, monkeypatch):
    lines = _lines(codec, 50)
    path = tmp_path / "can.log"
    path.write_text("\n".join(lines[:40] + ["(" + "1" * 200_000] + lines[40:]) + "\n" + "#" * 30_000)
    a, ra = _tables(path, 4096, True, monkeypatch)
    b, rb = _tables(path, 4096, False, monkeypatch)
    assert [len(t[0]) for t in a] == [len(t[0]) for t in b] and sum(len(t[0]) for t in a) == 100
    assert vars(ra) == vars(rb) and ra.total_rejected == 2
    sa, sb = RecordingStats(), RecordingStats()
    _read_can(path, codec, sa), read_can_per_frame(path, codec, sb)
    assert vars(sa.files["can.log"]) == vars(sb.files["can.log"])


def _corrupted(rng: random.Random, n: int, iface: str) -> list[str]:
    """Canonical lines of one interface name, about half of them with one to three bytes replaced by
    characters near the layout's (digits, hex letters in both cases, brackets, dot, blank, hash, control
    and edge-of-printable characters), and edge values: the largest times, the 2^53 µs limit, the error flag."""
    chars = "0123456789abcdefABCDEFgG()#. -+:\x00\x1f\x20\x21\x7e\x7f"
    out = []
    for _ in range(n):
        line = format_line(rng.choice([0.0, 1e9, T0]) + rng.random() * 1e4, iface, rng.randrange(1 << 29), True,
                           bytes(rng.randrange(256) for _ in range(8)))
        b = list(line)
        for _ in range(rng.choice([0, 0, 0, 1, 2, 3])):
            b[rng.randrange(len(b))] = rng.choice(chars)
        out.append("".join(b))
    tail = f" {iface} "
    out += [f"(9999999999.999999){tail}1FFFFFFF#0011223344556677", f"(9007199254.740992){tail}00000001#0011223344556677",
            f"(9007199254.740991){tail}1FFFFFFF#ffffffffffffffff", f"(0000000000.000000){tail}20000000#0011223344556677",
            f"(0000000000.000001){tail}1fffffff#FFFFFFFFFFFFFFFF"]
    return out


@pytest.mark.parametrize("iface", ["can0", "v", "vcan_with_a_long_name_of_32_char"])
def test_compiled_line_check_equals_numpy(iface):
    """The compiled check and conversion of canonical lines (fastdecode._canonical_rows, numba) against the
    numpy one (_canonical_np) and the kernel's own Python body: the same lines accepted, and their time,
    identifier and data bit for bit; on split lines and on a one-width block's rows (LF kept)."""
    if not fastdecode.use_compiled():
        pytest.skip("numba is not installed")
    rng = random.Random(len(iface))
    lines = _corrupted(rng, 4000, iface)
    width = len(lines[0])
    assert 47 <= width <= 78 and all(len(x) == width for x in lines)
    uniform = fastdecode._Uniform.of("\n".join(lines) + "\n")
    assert uniform is not None
    for block in (lines, uniform):
        A = fastdecode._line_matrix(block, np.arange(len(lines)), width)
        ref = fastdecode._canonical_np(A, width)
        outs = [fastdecode._canonical_rows(A, width, fastdecode._HEXVAL),
                fastdecode._canonical_rows_py(A[:600], width, fastdecode._HEXVAL)]
        for out in outs:
            m = out[0].size
            ok = ref[0][:m]
            assert np.array_equal(out[0], ok)
            assert 0.2 * m < ok.sum() < m
            assert ref[1][:m][ok].tobytes() == out[1][ok].tobytes()
            assert np.array_equal(ref[2][:m][ok], out[2][ok]) and np.array_equal(ref[3][:m][ok], out[3][ok])
    assert ref[0][-5:].tolist() == [False, False, True, False, True]
