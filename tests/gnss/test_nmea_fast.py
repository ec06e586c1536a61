"""The NMEA fast path (fast_kinds, fast_record, iter_nmea_fast) against parse_line / iter_nmea.

A line the fast path takes must give parse_line's NmeaRecord float for float (compared by repr, so -0.0 and
0.0 differ); a line it declines goes to parse_line, so a whole stream gives the same records, counts,
rejects (reasons, line numbers, texts) and ignored sentences.  Checked on simulated logs of several
scenarios, on the fixtures, and on seeded corruptions of simulated lines (with and without a repaired
checksum, so the field checks are reached too).
"""

from __future__ import annotations

import json
import random
from pathlib import Path

import pytest

from tractionecu.errors import DecodeError
from tractionecu.gnss.nmea import (
    NmeaRecord,
    NmeaStats,
    checksum,
    fast_block,
    fast_kinds,
    fast_record,
    iter_nmea,
    iter_nmea_fast,
    parse_line,
    record_values,
)

DATA = Path(__file__).resolve().parents[1] / "data"


def _simulated_lines(tmp_path_factory, name: str, seed: int, effects: dict | None = None) -> list[str]:
    from tractionecu.sim import scenarios
    from tractionecu.sim.simulator import simulate
    from tractionecu.sim.writer import write_recording

    out = tmp_path_factory.mktemp(name)
    scn = scenarios.get(name, seed=seed, effects=effects or {}, duration_s=12.0)
    write_recording(scn, simulate(scn), out)
    return (out / "gps.nmea").read_text(encoding="ascii").splitlines()


@pytest.fixture(scope="module")
def sim_lines(tmp_path_factory) -> dict[str, list[str]]:
    from tractionecu.model.effects import parse_effect_arg

    return {
        "paper-three-soils": _simulated_lines(tmp_path_factory, "paper-three-soils", 0),
        "headland-reverse": _simulated_lines(tmp_path_factory, "headland-reverse", 2),
        "paper-three-soils+latency": _simulated_lines(
            tmp_path_factory, "paper-three-soils", 1, dict([parse_effect_arg("gps_latency=0.15")])),
        "biased-sensors": _simulated_lines(tmp_path_factory, "biased-sensors", 1),   # physical, GNSS latency
        "physical-headland-reverse": _simulated_lines(tmp_path_factory, "physical-headland-reverse", 3),
    }


def _reference(line: str) -> tuple[str | None, NmeaRecord | None]:
    try:
        return None, parse_line(line)
    except DecodeError as e:
        return e.reason, None  # type: ignore[attr-defined]


def _check_lines(lines: list[str]) -> int:
    """Every line the fast path converts equals parse_line's record, and every line the block conversion
    converts equals the line's fast_record; returns how many fast_record converted."""
    taken = 0
    block, kinds = fast_block(lines)
    assert kinds.tolist() == fast_kinds(lines).tolist()
    for line, k, b in zip(lines, kinds.tolist(), block):
        got = fast_record(line, k) if k else None
        if b is not None:
            assert got is not None and repr(b) == repr(got), line
        if got is None:
            continue
        taken += 1
        reason, ref = _reference(line)
        assert reason is None and ref is not None, (line, reason)
        assert repr(NmeaRecord(*got)) == repr(ref), line
    return taken


def _streams(tmp_path: Path, data: bytes, chunk_chars: int) -> None:
    """iter_nmea and iter_nmea_fast over the same file: same (line, record) pairs and statistics."""
    p = tmp_path / "gps.nmea"
    p.write_bytes(data)
    a, b = NmeaStats(source="x"), NmeaStats(source="x")
    with open(p, "r", encoding="ascii", errors="replace", newline=None) as fh:
        ref = [(n, record_values(r)) for n, r in iter_nmea(fh, a)]
    with open(p, "r", encoding="ascii", errors="replace", newline=None) as fh:
        got = list(iter_nmea_fast(fh, b, chunk_chars=chunk_chars))
    assert repr(got) == repr(ref)
    assert repr(a) == repr(b)


def test_every_simulated_line_takes_the_fast_path_and_equals_parse_line(sim_lines):
    for name, lines in sim_lines.items():
        assert len(lines) > 100, name
        assert _check_lines(lines) == len(lines), name
        assert all(v is not None for v in fast_block(lines)[0]), name     # and the block conversion


def test_simulated_streams_equal_in_small_chunks(sim_lines, tmp_path):
    for lines in sim_lines.values():
        _streams(tmp_path, ("\r\n".join(lines) + "\r\n").encode(), chunk_chars=997)


def test_gnss_dropouts_same_epochs_and_counts(sim_lines, tmp_path):
    """Outages of a few epochs, a lone VTG left at an outage's edge, a receiver without a fix (empty time
    and position fields): the same records and counts."""
    rng = random.Random(7)
    lines = list(sim_lines["physical-headland-reverse"])
    for _ in range(6):
        a = rng.randrange(len(lines) - 40)
        del lines[a:a + rng.randrange(2, 35)]
    nofix = "GNGGA,,,,,,0,00,99.99,,,,,,"
    lines.insert(50, f"${nofix}*{checksum(nofix)}")
    _streams(tmp_path, ("\n".join(lines) + "\n").encode(), chunk_chars=1 << 20)
    assert _check_lines(lines) == len(lines)


def test_mixed_fixture_same_records_and_rejects(tmp_path):
    data = (DATA / "nmea" / "mixed.nmea").read_bytes()
    lines = data.decode("ascii").splitlines()
    kinds = fast_kinds(lines).tolist()
    # the u-blox examples (GGA, RMC 2.3, VTG, ZDA) and the Galileo GGA / BeiDou RMC take the fast path;
    # GSV, the bad and missing checksums, garbage and GNS do not; 61 minutes of latitude is declined by
    # the field check and rejected by parse_line
    assert kinds == [1, 2, 3, 4, 0, 0, 0, 0, 0, 1, 2, 1]
    assert fast_record(lines[11], 1) is None and _reference(lines[11])[0] == "bad_field"
    assert _check_lines(lines) == 6
    for chunk in (7, 64, 1 << 20):
        _streams(tmp_path, data, chunk)


def test_fuzz_fixture_lines_same_as_parse_line(tmp_path):
    cases = []
    for f in sorted((DATA / "fuzz").glob("*")):
        if f.suffix == ".nmea":
            cases.append(f.read_bytes())
        elif f.suffix == ".json":
            case = json.loads(f.read_text()).get("case", {})
            if isinstance(case, dict) and "lines" in case and "terms" in case:
                cases.append("".join(a + b for a, b in zip(case["lines"], case["terms"])).encode("utf-8"))
    assert len(cases) >= 4
    for data in cases:
        _check_lines(data.decode("ascii", "replace").splitlines())
        _streams(tmp_path, data, 1 << 20)


# ------------------------------------------------------------------ seeded corruptions
_FIELD_VALUES = ["", "-", ".", "1.", ".5", "-0.0", "0000.00000", "9000.00000", "9000.00001", "4761.00000",
                 "18000.00000", "18000.00001", "1E5", "NAN", "INF", "1E999", "12345678901234567890", "N", "S",
                 "E", "W", "X", "A", "V", "9", "8", "-1", "000000", "235960.00", "240000.00", "235959.99",
                 "236000", "2359", "310299", "290223", "290224", "000000", "9999", "10000", "0", "00", "AA",
                 "ADR", "Z", "1.5", "08"]


def _corrupt(line: str, rng: random.Random) -> str:
    """One seeded corruption of a sentence: a field replaced, a character changed, dropped or doubled,
    truncated, white space, non-ASCII, lower case, another count of fields or a second '*'; the checksum
    repaired half of the time."""
    body, _, _cs = line[1:].partition("*")
    fields = body.split(",")
    how = rng.randrange(11)
    if how == 0 and len(fields) > 1:
        fields[rng.randrange(1, len(fields))] = rng.choice(_FIELD_VALUES)
        body = ",".join(fields)
    elif how == 1:
        i = rng.randrange(len(body))
        body = body[:i] + rng.choice("0123456789.,-ANSZ*$ \t") + body[i + 1:]
    elif how == 2:
        i = rng.randrange(len(body))
        body = body[:i] + body[i + 1:]
    elif how == 3:
        i = rng.randrange(len(body))
        body = body[:i] + body[i] + body[i:]
    elif how == 4:
        return line[: rng.randrange(len(line))]
    elif how == 5:
        i = rng.randrange(len(body))
        body = body[:i] + rng.choice(["é", "\u00b0", "\ufffd", "\x00"]) + body[i:]
    elif how == 6:
        body = body.lower() if rng.random() < 0.5 else body[:2].lower() + body[2:]
    elif how == 7:
        body = body + "," if rng.random() < 0.5 else body.rsplit(",", 1)[0]
    elif how == 8:
        body = "P" + body[1:] if rng.random() < 0.5 else body[:2] + "GNS" + body[5:]
    elif how == 9:
        return rng.choice([" ", "\t", ""]) + line + rng.choice([" ", "\t", "", "*"])
    else:
        return line[:-2] + f"{(int(line[-2:], 16) ^ (1 + rng.randrange(255))):02X}"
    cs = checksum(body) if body.isascii() else _cs
    if rng.random() < 0.5:
        cs = _cs                                   # the old checksum: mostly wrong now
    return f"${body}*{cs}"


def test_corrupted_lines_give_parse_lines_records_and_rejects(sim_lines, tmp_path):
    rng = random.Random(20260519)
    src = sim_lines["biased-sensors"] + sim_lines["headland-reverse"]
    bad = [_corrupt(rng.choice(src), rng) for _ in range(3000)]
    taken = _check_lines(bad)
    assert 0 < taken < len(bad)                   # both paths exercised
    # the corrupted lines interleaved with good ones, in files with LF and CRLF ends
    mixed = []
    for line in src[:1500]:
        mixed.append(line)
        if rng.random() < 0.3:
            mixed.append(bad[len(mixed) % len(bad)])
    for sep in ("\n", "\r\n"):
        _streams(tmp_path, (sep.join(mixed) + sep).encode("utf-8"), chunk_chars=4093)


def test_line_endings_blank_lines_and_no_final_newline(tmp_path, sim_lines):
    lines = sim_lines["paper-three-soils"][:60]
    data = ("\r\n".join(lines[:20]) + "\r\n\r\n   \n" + "\r".join(lines[20:40]) + "\n\n" + "\n".join(lines[40:]))
    for chunk in (1, 13, 1 << 20):
        _streams(tmp_path, data.encode(), chunk)
    _streams(tmp_path, b"", 1 << 20)


def test_field_edge_values_same_as_parse_line():
    base = "GNGGA,080000.10,4752.89599,N,11033.20431,W,2,16,0.90,861.4,M,0.0,M,,"
    rmc = "GNRMC,080000.10,A,4752.89599,N,11033.20431,W,0.522,90.00,100726,,,A,V"
    vtg = "GNVTG,90.00,T,,M,0.522,N,0.966,K,A"
    zda = "GNZDA,080000.10,10,07,2026,00,00"
    lines = []
    for body in (base, rmc, vtg, zda):
        fields = body.split(",")
        for i in range(1, len(fields)):
            for v in _FIELD_VALUES:
                f = list(fields)
                f[i] = v
                b = ",".join(f)
                lines.append(f"${b}*{checksum(b)}")
    lines += ["$GNGGA,235959.999,0000.00000,S,00000.00000,W,0,00,,,M,,M,,*" + checksum(
        "GNGGA,235959.999,0000.00000,S,00000.00000,W,0,00,,,M,,M,,")]
    assert _check_lines(lines) > len(lines) // 3
    rec = NmeaRecord(*fast_record(lines[-1], 1))
    assert repr(rec.lat_deg) == "-0.0" and repr(rec.lon_deg) == "-0.0"


def test_block_numbers_are_float_of_the_text():
    """The block conversion's numbers (N / 10**k) are float() of the field, bit for bit, and it takes only
    the plain decimal form."""
    import re

    import numpy as np

    from tractionecu.gnss.nmea import _dec

    rng = np.random.default_rng(5)
    alphabet = np.frombuffer(b"0123456789.-E", dtype=np.uint8)
    plain = re.compile(r"-?\d+(\.\d+)?")
    for _ in range(40):
        lens = rng.integers(0, 19, 400)
        texts = [bytes(rng.choice(alphabet, n)).decode() for n in lens]
        texts += ["0.1", "-0.0", "999999999999999", "9999999999999999", "0.000000000000001", "52.89599"]
        buf = np.frombuffer(",".join(texts).encode(), dtype=np.uint8)
        a = np.cumsum([0] + [len(t) + 1 for t in texts[:-1]])
        b = a + np.array([len(t) for t in texts])
        ok, v, _n, _k = _dec(buf, a, b)
        for t, good, x in zip(texts, ok.tolist(), v.tolist()):
            digits = sum(ch.isdigit() for ch in t)
            assert good == (plain.fullmatch(t) is not None and digits <= 15), t
            if good:
                assert repr(x) == repr(float(t)), t


def test_a_very_long_line_across_many_chunks(sim_lines, tmp_path):
    lines = sim_lines["paper-three-soils"][:30]
    data = "\n".join(lines[:10] + ["$GNGGA," + "7" * 300_000] + lines[10:]) + "\n" + "x" * 70_000
    _streams(tmp_path, data.encode(), chunk_chars=4096)


def test_coordinates_where_the_order_of_operations_shows():
    """Minutes for which deg + m / 60 differs from deg + m * (1 / 60) in the last bit: the fast tiers must
    compute parse_line's expression, not an equivalent one."""
    rng = random.Random(3)
    lines = []
    while len(lines) < 40:
        deg, m = rng.randrange(0, 90), round(rng.uniform(0, 59.99999), 5)
        if deg + m / 60.0 == deg + m * (1 / 60.0):
            continue
        body = f"GNGGA,080000.10,{deg:02d}{m:08.5f},S,{deg + 1:03d}{m:08.5f},E,2,16,0.90,861.4,M,0.0,M,,"
        lines.append(f"${body}*{checksum(body)}")
    assert _check_lines(lines) == len(lines)
    assert all(v is not None for v in fast_block(lines)[0])


def test_times_of_day_where_the_order_of_operations_shows():
    """Times for which h*3600 + m*60 + s summed in another order differs in the last bit (about 2 % of
    them), in GGA, RMC and ZDA: the fast tiers must compute parse_line's expression."""
    rng = random.Random(4)
    lines = []
    while len(lines) < 120:
        h, m, cs = rng.randrange(24), rng.randrange(60), rng.randrange(6000)
        sec = float(f"{cs // 100:02d}.{cs % 100:02d}")
        if h * 3600.0 + m * 60.0 + sec == h * 3600.0 + (m * 60.0 + sec):
            continue
        t = f"{h:02d}{m:02d}{cs // 100:02d}.{cs % 100:02d}"
        for body in (f"GNGGA,{t},4752.89599,N,11033.20431,W,2,16,0.90,861.4,M,0.0,M,,",
                     f"GNRMC,{t},A,4752.89599,N,11033.20431,W,0.522,90.00,100726,,,A,V", f"GNZDA,{t},10,07,2026,00,00"):
            lines.append(f"${body}*{checksum(body)}")
    assert _check_lines(lines) == len(lines)
    assert all(v is not None for v in fast_block(lines)[0])


def test_compiled_numbers_equal_the_numpy_form():
    """The compiled field conversion (nmea._compiled_dec, numba) against the numpy form (_dec_np) and the
    kernel's own Python body: ok, value, N and k bit for bit, declined fields too (their N, k = 0, the sign
    of the value), on random texts, numbers, over-long digit runs, empty fields and the buffer's last field."""
    import numba  # noqa: F401 - the compiled form is loaded once numba is

    import numpy as np

    from tractionecu.gnss import nmea

    dec = nmea._compiled_dec()
    assert dec is not None
    rng = random.Random(9)
    alphabet = "0123456789.-+eE ,*NSX"
    texts: list[str] = []
    for _ in range(6000):
        r = rng.random()
        if r < 0.4:
            texts.append(f"{rng.uniform(-1e4, 1e4):.{rng.randrange(0, 9)}f}")
        elif r < 0.7:
            texts.append("".join(rng.choice(alphabet) for _ in range(rng.randrange(0, 22))))
        else:
            texts.append("".join(rng.choice("0123456789") for _ in range(rng.randrange(0, 22)))
                         + rng.choice(["", ".", ".5", "-", "..1"]))
    texts += ["", "-", "-0", "-0.0", ".5", "5.", "1.2.3", "-.5", "00", "9" * 15, "9" * 16, "1" * 17 + ".5", "-"]
    buf = np.frombuffer(",".join(texts).encode(), dtype=np.uint8)
    a = np.cumsum([0] + [len(t) + 1 for t in texts[:-1]]).astype(np.int64)
    b = a + np.array([len(t) for t in texts], dtype=np.int64)
    declined = 0
    for sl in (slice(None), slice(0, 1), slice(1000, 1400), slice(len(texts) - 20, None)):
        ref = nmea._dec_np(buf, a[sl], b[sl])
        outs = [dec(buf, a[sl].copy(), b[sl].copy(), nmea._F10), nmea._dec(buf, a[sl], b[sl]),
                nmea._dec_fields_py(buf, a[sl][:500], b[sl][:500], nmea._F10)]
        for out in outs:
            m = out[0].size
            for x, y in zip(ref, out):
                assert x[:m].dtype == y.dtype and x[:m].tobytes() == y.tobytes()
        declined += int((~ref[0]).sum())
    assert 0 < declined < len(texts)
