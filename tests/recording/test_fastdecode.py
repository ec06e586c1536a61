"""Vectorised candump decoding (recording/fastdecode.py) against the per-frame reader, line for line."""

from __future__ import annotations

import math
import random
from pathlib import Path

import numpy as np
import pytest

from tractionecu.bus import j1939
from tractionecu.bus.candump import format_line
from tractionecu.bus.dbc import Codec
from tractionecu.errors import RecordingError
from tractionecu.recording.reader import RecordingStats, _read_can, read_recording
from tractionecu.recording.reference import read_can_per_frame

REPO = Path(__file__).resolve().parents[2]
CANDUMP = REPO / "tests" / "data" / "candump"
T0 = 1_715_940_000.0
WHEELS = ("FL", "FR", "RL", "RR")


@pytest.fixture(scope="module")
def codec():
    return Codec()


def _read(fn, path: Path, codec: Codec):
    stats = RecordingStats()
    try:
        return fn(path, codec, stats), stats, None
    except RecordingError as e:
        return None, stats, str(e)


def assert_same(path: Path, codec: Codec) -> tuple[dict, RecordingStats]:
    """Vectorised and per-frame decoding of ``path`` give identical signals, statistics and dict orders."""
    sa, sta, ea = _read(_read_can, path, codec)
    sb, stb, eb = _read(read_can_per_frame, path, codec)
    assert ea == eb
    assert vars(sta.files[path.name]) == vars(stb.files[path.name])
    if ea is not None:
        return {}, sta
    assert list(sa) == list(sb)
    for name in sa:
        x, y = sa[name], sb[name]
        assert x.unit == y.unit, name
        for f in ("t", "value", "sa"):
            a, b = getattr(x, f), getattr(y, f)
            assert a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True), (name, f)
    assert list(sta.messages) == list(stb.messages)
    for m in sta.messages:
        assert vars(sta.messages[m]) == vars(stb.messages[m]), m
        assert list(sta.messages[m].sources) == list(stb.messages[m].sources), m
    for attr in ("unknown_pgns", "unknown_pgn_sources", "decode_errors", "decode_error_lines"):
        a, b = getattr(sta, attr), getattr(stb, attr)
        assert a == b and list(a) == list(b), attr
    assert sta.source_used == stb.source_used and sta.other_sources == stb.other_sources
    assert sta.non_extended_frames == stb.non_extended_frames
    assert [vars(c) for c in sta.address_claims] == [vars(c) for c in stb.address_claims]
    for attr in ("can_t_first", "can_t_last"):
        a, b = getattr(sta, attr), getattr(stb, attr)
        assert a == b or (math.isnan(a) and math.isnan(b)), attr
    return sa, sta


def _frames(codec: Codec, n: int = 300) -> list[str]:
    """Canonical lines of every contract input message, some with not-available values."""
    lines = []
    for k in range(n):
        t = T0 + 0.01 * k
        ws = {f"WheelSpeed_{w}": (math.nan if k % 37 == 0 and i == 2 else 3.0 + 0.01 * k - 2.5 * i)
              for i, w in enumerate(WHEELS)}
        cid, d = codec.encode("TECU_WheelSpeeds", ws, sa=0x80 + k % 3)
        lines.append(format_line(t, "can0", cid, True, d))
        cid, d = codec.encode("TECU_DriveTorques", {f"DriveTorque_{w}": -3000.0 + 25.0 * k for w in WHEELS})
        lines.append(format_line(t + 0.0002, "can0", cid, True, d))
        if k % 2 == 0:
            cid, d = codec.encode("TECU_AxleLoad", {"FrontAxleLoad": 24500.0 + k, "FrontAxleLoadStatus": k % 4})
            lines.append(format_line(t + 0.0004, "can0", cid, True, d))
            cid, d = codec.encode("RearHitchStatus", {"DraftForce": 12340.0 - 100 * k}, sa=0x2A)
            lines.append(format_line(t + 0.0006, "can0", cid, True, d))
        if k % 10 == 0:
            cid, d = codec.encode("GBSD", {"GroundBasedMachineSpeed": 2.5, "GroundBasedMachineDistance": k})
            lines.append(format_line(t + 0.0008, "vcan0", cid, True, d))
    return lines


J1939_CODES = (0x00, 0x7D, 0xFA, 0xFB, 0xFC, 0xFD, 0xFE, 0xFF)
"""Raw byte values through the J1939-71 ranges: valid up to 0xFA, then parameter specific, reserved, error, n/a."""


def _standard_lines(n: int = 160) -> list[str]:
    """Hand-made frames of the standard messages (EEC1, ETC2, CCVS1, EBC2) whose bytes walk through
    valid, error and not-available codes, and EC1 in transport-protocol sessions (BAM, RTS, broken)."""
    lines = []
    ec1 = bytes([0x20, 0x1C, 0xDD]) + b"\xff" * 16 + bytes([0x04, 0x01]) + b"\xff" * 13        # 34 bytes, 260 N.m
    for k in range(n):
        t = T0 + 0.02 * k
        b = J1939_CODES[k % len(J1939_CODES)]
        hi = J1939_CODES[(k // len(J1939_CODES)) % len(J1939_CODES)]
        eec1 = bytes([0xF0 | k % 16, 0xFF, b, (37 * k) & 0xFF, hi, 0xFF, 0xFF, b])
        lines.append(format_line(t, "can0", 0x0CF00400, True, eec1))
        if k % 5 == 0:
            lines.append(format_line(t + 0.001, "can0", 0x18F00503, True, bytes([b, 0x39, hi, b, 0x20, 0x20, 0x20, 0x20])))
            lines.append(format_line(t + 0.002, "can0", 0x18FEF147, True, bytes([0xF3 | (k % 4) << 2, b, hi, 0xFF,
                                                                                   0xFF, 0xFF, 0xFF, 0xFF])))
            lines.append(format_line(t + 0.003, "can0", 0x18FEBF0B, True, bytes([b, hi, b, hi, 0x7D, 0x85, 0xFE, 0xFF])))
        if k % 40 == 7:                                    # EC1 by BAM from the engine, by RTS to 0x90, one broken
            sa, da, ctrl = (0x00, 0xFF, 32) if k % 80 == 7 else (0x01, 0x90, 16)
            lines.append(format_line(t + 0.004, "can0", j1939.make_id(7, 60416, sa, da), True,
                                     bytes([ctrl, 34, 0, 5, 0xFF, 0xE3, 0xFE, 0x00])))
            for q in range(5):
                if k == 87 and q == 3:
                    continue                                # a packet lost: no message
                lines.append(format_line(t + 0.005 + 0.001 * q, "can0", j1939.make_id(7, 60160, sa, da), True,
                                         bytes([q + 1]) + ec1[7 * q:7 * q + 7].ljust(7, b"\xff")))
    return lines


def test_standard_messages_with_error_and_na_codes_decode_identically(tmp_path, codec):
    path = tmp_path / "can.log"
    path.write_text("\n".join(_standard_lines()) + "\n")
    sig, st = assert_same(path, codec)
    assert {"EEC1", "ETC2", "CCVS1", "EBC2", "EC1"} <= set(st.messages)
    torque = sig["ActualEnginePercentTorque"].value
    raw = np.array([J1939_CODES[k % len(J1939_CODES)] for k in range(160)])
    assert np.array_equal(np.isnan(torque), raw > 0xFA) and np.all(torque[raw <= 0xFA] == raw[raw <= 0xFA] - 125)
    for name in ("EngineSpeed", "WheelBasedVehicleSpeed", "FrontAxleSpeed", "RelativeSpeedFrontAxleLeftWheel",
                 "TransmissionActualGearRatio"):
        v = sig[name].value
        assert np.isnan(v).any() and np.isfinite(v).any(), name
    assert np.isnan(sig["RelativeSpeedRearAxle2LeftWheel"].value).all()      # 0xFE error
    assert dict(st.messages["EC1"].sources) == {0x00: 1, 0x01: 2}          # BAM at k = 7 (87 broken), RTS 47, 127
    # one source per message: the engine's (first seen); the other ECU's two EC1 are counted, not used
    assert st.messages["EC1"].count == 3 and sig["EngineReferenceTorque"].value.tolist() == [260.0]
    assert st.source_used["EC1"] == 0x00 and st.other_sources["EC1"] == {0x01: 2}
    from tractionecu.recording.summary import other_source_lines

    assert other_source_lines(st) == ["EC1 is sent by more than one source: its signals are those of 0x00, the "
                                      "first seen; not used: 0x01 (2 frames) (another ECU sending the same message, "
                                      "or a second bus logged through a gateway)"]


def test_fixture_with_bad_lines_decodes_identically(codec):
    sig, st = assert_same(CANDUMP / "bad_lines.log", codec)
    assert st.files["bad_lines.log"].total_rejected == 10 and st.decode_errors     # the fixture's bad lines
    assert np.allclose(sig["WheelSpeed_FL"].value, [1.0, 1.1, 1.2, 1.4])


def test_real_capture_with_unknown_pgns_and_claims_decodes_identically(codec):
    sig, st = assert_same(CANDUMP / "jd5055e_excerpt.log", codec)
    assert len(st.unknown_pgns) == 24 and st.address_claims and "Request" in st.messages
    assert {"EEC1", "ETC2", "CCVS1", "GBSD", "EC1"} <= set(st.messages)
    # EC1 arrives once, as a 34-byte BAM (TP.CM 1CECFF00#20220005FFE3FE00 and five TP.DT frames): 260 N.m
    assert st.messages["EC1"].count == 1 and st.messages["EC1"].sources == {0x00: 1}
    assert sig["EngineReferenceTorque"].value.tolist() == [260.0]
    assert sig["EngineSpeedAtIdlePoint1"].value[0] == pytest.approx(900 * math.pi / 30)
    assert sig["WheelBasedVehicleSpeed"].value.tolist() == [0.0] * 4          # CCVS1 from 0x47: standing
    assert np.isnan(sig["TransmissionActualGearRatio"].value).all()          # ETC2 all 0xFF


def test_recording_with_bad_lines_decodes_identically(tmp_path, codec):
    lines = _frames(codec)

    def ts(i: int) -> str:
        return lines[i][:19]

    bad = {
        5: "this is not a candump line",
        17: lines[17][:-3],                                      # odd number of data digits
        30: lines[30].replace("(17159", "(17x59", 1),             # not a number: bad timestamp
        44: lines[44].replace("#", "##", 1),                     # CAN FD
        61: lines[61][:-16] + "R",                               # remote frame
        77: lines[77][:-2],                                      # 7 data bytes: wrong DLC, decode error
        90: "(1715940000.000000) can0 123#0102030405060708",     # 11-bit frame, time going backwards
        91: ts(91) + " can0 123#0102030405060708",                 # 11-bit frame
        102: lines[102] + " T",                                  # direction flag: accepted
        118: "\t" + lines[118] + "  ",                           # white space around: accepted
        130: lines[130].replace("0CFF", "2CFF", 1),              # error flag
        150: "",                                                 # blank line
        171: lines[171].replace("can0", "cän0", 1),              # non-ASCII interface name: accepted
        190: lines[190][:30] + "G" + lines[190][31:],            # bad hex
        205: lines[205].replace("(17159", "(17158", 1),          # time going backwards
        222: ts(222) + " can0 18EEFF47#4D74300400340220",          # address claim
        240: ts(240) + " can0 18FEF200#0000000000000000",          # PGN not in the DBC (LFE)
        260: lines[260][:34] + "ff" + lines[260][36:],           # lower-case hex
    }
    text = [bad.get(i, line) for i, line in enumerate(lines)]
    path = tmp_path / "can.log"
    path.write_text("\n".join(text) + "\n", encoding="utf-8")
    sig, st = assert_same(path, codec)
    rs = st.files["can.log"]
    assert set(rs.rejected) >= {"garbage", "truncated", "bad_timestamp", "canfd", "rtr", "error_frame", "bad_hex",
                                "time_backwards"}
    assert st.decode_errors and st.non_extended_frames and st.unknown_pgns and st.address_claims
    assert np.isnan(sig["WheelSpeed_RL"].value).any()            # not-available code


@pytest.mark.parametrize("seed", range(8))
def test_mutated_lines_decode_identically(tmp_path, codec, seed):
    rng = random.Random(seed)
    pool = _frames(codec, 120) + (CANDUMP / "bad_lines.log").read_text().split("\n") \
        + (CANDUMP / "jd5055e_excerpt.log").read_text().split("\n")[:200] + _standard_lines(60)
    out = []
    for line in rng.sample(pool, 250):
        if line and rng.random() < 0.4:
            i = rng.randrange(len(line))
            op = rng.randrange(5)
            if op == 0:
                line = line[:i] + rng.choice("0123456789ABCDEFabcdefRr#.() g\t") + line[i + 1:]
            elif op == 1:
                line = line[:i] + line[i + 1:]
            elif op == 2:
                line = line[:i] + rng.choice("0A#. é") + line[i:]
            elif op == 3:
                line = line + "\r"
            else:
                line = line.replace("(17", "(16", 1)
        out.append(line)
    if seed % 2:
        out.sort()
    path = tmp_path / "can.log"
    path.write_bytes(("\n".join(out) + ("\n" if seed % 3 else "")).encode("utf-8") + (b"\xff(1\n" if seed == 5 else b""))
    assert_same(path, codec)


def test_last_line_cut_mid_data_is_truncated_not_a_short_frame(tmp_path, codec):
    lines = _frames(codec, 40)
    path = tmp_path / "can.log"
    path.write_text("\n".join(lines) + "\n" + lines[0][:-8])    # 4 data bytes, no line break
    sig, st = assert_same(path, codec)
    rs = st.files["can.log"]
    assert dict(rs.rejected) == {"truncated": 1} and rs.examples["truncated"] == [len(lines) + 1]
    assert not st.decode_errors


@pytest.mark.parametrize("echo_s", [0.0, 0.0004])
def test_a_capture_holding_every_frame_twice_says_so(tmp_path, codec, monkeypatch, echo_s):
    """A logger echoing its frames (the same time) or two loggers' captures merged (0.4 ms apart): every rate
    was twice the bus's and nothing said so."""
    from tractionecu.recording import fastdecode
    from tractionecu.recording.summary import summarize

    lines = _frames(codec, 200)
    doubled = []
    for ln in lines:
        t = float(ln[1:ln.index(")")])
        doubled += [ln, f"({t + echo_s:017.6f}){ln[ln.index(')') + 1:]}"]
    doubled.sort(key=lambda ln: float(ln[1:ln.index(")")]))       # time order, each pair in file order
    path = tmp_path / "can.log"
    path.write_text("\n".join(doubled) + "\n")
    monkeypatch.setattr(fastdecode, "CHUNK_CHARS", 997)               # pairs split between blocks too
    _, st = assert_same(path, codec)
    rs = st.files["can.log"]
    assert rs.repeated == len(lines) and rs.frames == 2 * len(lines) and not rs.rejected
    assert rs.repeated_lines == [2, 4, 6, 8, 10] if echo_s == 0 else len(rs.repeated_lines) == 5
    (note,) = rs.notes()
    assert f"{len(lines)} of {2 * len(lines)} (50.0 %" in note and "holds its frames twice" in note
    rec = read_recording(path, clock="keep")
    assert note in summarize(rec)
    path.write_text("\n".join(lines) + "\n")                         # each frame once: no note
    _, st = assert_same(path, codec)
    assert st.files["can.log"].repeated == 0 and st.files["can.log"].notes() == []


@pytest.mark.parametrize("seed", range(4))
def test_lone_time_stamps_ahead_decode_identically_across_blocks(tmp_path, codec, monkeypatch, seed):
    from tractionecu.recording import fastdecode

    rng = random.Random(seed)
    lines = _frames(codec, 200)
    spikes = sorted(rng.sample(range(len(lines)), 6)) + ([0] if seed % 2 else [len(lines) - 1])
    for i in spikes:
        lines[i] = f"({float(lines[i][1:18]) + rng.choice([1.5, 3600.0, 1e5]):017.6f})" + lines[i][19:]
    path = tmp_path / "can.log"
    path.write_text("\n".join(lines) + "\n")
    monkeypatch.setattr(fastdecode, "CHUNK_CHARS", rng.choice([997, 4001, 1 << 20]))
    _, st = assert_same(path, codec)
    rs = st.files["can.log"]
    assert rs.rejected["time_ahead"] >= 6 and rs.frames >= len(lines) - 7 - rs.rejected["time_backwards"]
    assert rs.rejected["time_backwards"] <= 2


@pytest.mark.parametrize("first", ["ordinary", "next_backwards", "ahead", "next_ahead"])
def test_the_first_frame_is_decided_as_the_rule_does_without_going_frame_by_frame(tmp_path, codec, monkeypatch,
                                                                                  first):
    """The rule holds a capture's first frame (ahead of no time) until the next; the vectorised reader decides
    it from the next frame at once, and only a block with a frame really ahead goes frame by frame."""
    from tractionecu.recording import fastdecode

    lines = _frames(codec, 200)

    def shift(i: int, dt: float) -> None:
        lines[i] = f"({float(lines[i][1:18]) + dt:017.6f})" + lines[i][19:]

    if first == "next_backwards":
        shift(1, -0.5)
    elif first == "ahead":
        shift(0, 3600.0)
    elif first == "next_ahead":
        shift(1, 3600.0)
    path = tmp_path / "can.log"
    path.write_text("\n".join(lines) + "\n")
    calls = []
    real = fastdecode._time_order
    monkeypatch.setattr(fastdecode, "_time_order", lambda t, state: calls.append(t.size) or real(t, state))
    _, st = assert_same(path, codec)
    rs = st.files["can.log"]
    assert rs.rejected["time_backwards"] == (1 if first == "next_backwards" else 0)
    assert rs.rejected["time_ahead"] == (1 if first in ("ahead", "next_ahead") else 0)
    assert bool(calls) == (first in ("ahead", "next_ahead"))


def test_read_in_chunks_equals_one_piece(tmp_path, codec, monkeypatch):
    from tractionecu.recording import fastdecode
    path = tmp_path / "can.log"
    lines = _frames(codec, 200)
    lines[50] = lines[50].replace("(17159", "(17158", 1)           # time going backwards across chunks
    path.write_text("\n".join(lines) + "\n")
    whole = _read(_read_can, path, codec)
    monkeypatch.setattr(fastdecode, "CHUNK_CHARS", 997)
    sig, st = assert_same(path, codec)
    assert vars(st.files["can.log"]) == vars(whole[1].files["can.log"])
    assert all(np.array_equal(sig[k].value, whole[0][k].value, equal_nan=True) for k in sig)


def test_empty_and_frameless_files_fail_the_same(tmp_path, codec):
    for text in ("", "\n\n", "hello\n(1.0) can0\n"):
        path = tmp_path / "can.log"
        path.write_text(text)
        _, _, err = _read(_read_can, path, codec)
        assert err is not None
        assert_same(path, codec)


def test_a_flood_of_unknown_pgns_keeps_the_sources_of_the_first_ones_only(tmp_path, codec, monkeypatch):
    """Every unknown PGN kept the set of its source addresses: a flood of random identifiers (2¹⁸ PGNs from 256
    addresses each) could hold tens of millions of entries.  The sources of the first PGNs are kept, the frames
    of every PGN counted; both readers agree, and the summary says which sources were not kept."""
    from tractionecu.recording import containers
    from tractionecu.recording.reader import read_recording
    from tractionecu.recording.summary import summarize

    monkeypatch.setattr(containers, "MAX_UNKNOWN_PGN_SOURCES", 3)
    rng = random.Random(7)
    pgns = [0xFF00 + k for k in range(0x40, 0x48)]            # proprietary B PGNs the contract does not use
    lines = [format_line(1.7e9 + 0.001 * k, "can0", (6 << 26) | (p << 8) | rng.randrange(256), True, bytes(8))
             for k, p in enumerate(pgns * 3)]
    path = tmp_path / "can.log"
    path.write_text("".join(ln if ln.endswith("\n") else ln + "\n" for ln in lines))
    _, st = assert_same(path, codec)
    assert sum(st.unknown_pgns.values()) == 24 and len(st.unknown_pgns) == 8
    assert list(st.unknown_pgn_sources) == pgns[:3]
    assert "(sources not kept)" in summarize(read_recording(path))
