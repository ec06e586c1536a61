"""Long recordings made of copies of a short one (recording/concat.py)."""

import pytest

from tractionecu.recording.concat import concatenate, nmea_shift


def _checksum_ok(line: str) -> bool:
    body, ck = line[1:].split("*")
    x = 0
    for ch in body:
        x ^= ord(ch)
    return f"{x:02X}" == ck


@pytest.fixture
def short(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    (src / "can.log").write_text("".join(f"({1000.0 + 0.01 * k:017.6f}) can0 0CFF1180#5C005B0086008200\n"
                                         for k in range(1001)))
    rmc = "$GNRMC,235955.00,A,4752.89605,N,11033.20412,W,0.645,90.00,311226,,,A,V"
    x = 0
    for ch in rmc[1:]:
        x ^= ord(ch)
    (src / "gps.nmea").write_text(f"{rmc}*{x:02X}\n")
    (src / "vehicle.toml").write_text("")
    return src


@pytest.mark.parametrize("gap_s, align_s, step", [(0.01, None, 10.01), (10.0, None, 20.0), (10.0, 8.0, 24.0)])
def test_copies_follow_after_the_gap(short, tmp_path, gap_s, align_s, step):
    """Each copy starts ``gap_s`` after the last frame of the one before (or at the next multiple of
    ``align_s``), CAN and NMEA times moved alike; the returned length is the recorded time without gaps."""
    length = concatenate(short, tmp_path / "out", 30.0, gap_s=gap_s, align_s=align_s)
    assert length == pytest.approx(3 * 10.01)
    can = (tmp_path / "out" / "can.log").read_text().splitlines()
    assert len(can) == 3 * 1001
    t = [float(ln[1:ln.index(")")]) for ln in can]
    assert t[1001] - t[0] == pytest.approx(step, abs=1e-6)
    assert t[2002] - t[0] == pytest.approx(2 * step, abs=1e-6)
    assert all(b > a for a, b in zip(t, t[1:]))
    nmea = (tmp_path / "out" / "gps.nmea").read_text().splitlines()
    assert len(nmea) == 3 and all(_checksum_ok(ln) for ln in nmea)
    assert nmea[1] == nmea_shift(nmea[0], step)


def test_nmea_time_and_date_roll_over_midnight():
    rmc = "$GNRMC,235955.00,A,4752.89605,N,11033.20412,W,0.645,90.00,311226,,,A,V*00"
    out = nmea_shift(rmc, 10.0)
    f = out.split(",")
    assert f[1] == "000005.00" and f[9] == "010127"
    assert _checksum_ok(out)


def _recording(path, t0, n, can_id, hhmmss):
    path.mkdir()
    (path / "can.log").write_text("".join(f"({t0 + 0.01 * k:017.6f}) can0 {can_id}#5C005B0086008200\n"
                                          for k in range(n)))
    rmc = f"$GNRMC,{hhmmss},A,4752.89605,N,11033.20412,W,0.645,90.00,311226,,,A,V"
    x = 0
    for ch in rmc[1:]:
        x ^= ord(ch)
    (path / "gps.nmea").write_text(f"{rmc}*{x:02X}\n")
    (path / "vehicle.toml").write_text(f"# {path.name}\n")
    return path


def test_a_list_of_two_sources_is_joined_in_order_and_cycled(tmp_path):
    """Two different recordings (different start times, lengths and frames) taken in turn: each copy
    starts ``gap_s`` after the last frame of the one before, its NMEA time moved by the same shift as
    its CAN times; copies are added while the recorded length gets closer to ``seconds``."""
    a = _recording(tmp_path / "a", 1000.0, 1001, "0CFF1180", "120000.00")   # 10.01 s
    b = _recording(tmp_path / "b", 500.0, 501, "0CFF1181", "110000.00")     # 5.01 s, earlier clock
    length = concatenate([a, b], tmp_path / "out", 30.0, gap_s=10.0)
    # a, b, a: 25.03 s; a fourth copy (b) would bring 30.04 s, closer to 30 s, a fifth (a) 40.05 s.
    assert length == pytest.approx(2 * 10.01 + 2 * 5.01)
    can = (tmp_path / "out" / "can.log").read_text().splitlines()
    assert len(can) == 2 * 1001 + 2 * 501
    t = [float(ln[1:ln.index(")")]) for ln in can]
    ids = [ln.split()[2].split("#")[0] for ln in can]
    starts = [0, 1001, 1502, 2503]
    assert [ids[i] for i in starts] == ["0CFF1180", "0CFF1181", "0CFF1180", "0CFF1181"]
    assert t[0] == pytest.approx(1000.0)
    for i in starts[1:]:
        assert t[i] - t[i - 1] == pytest.approx(10.0, abs=1e-6)
    assert all(y > x for x, y in zip(t, t[1:]))
    nmea = (tmp_path / "out" / "gps.nmea").read_text().splitlines()
    assert len(nmea) == 4 and all(_checksum_ok(ln) for ln in nmea)
    src_nmea = {"0CFF1180": (a / "gps.nmea").read_text().strip(), "0CFF1181": (b / "gps.nmea").read_text().strip()}
    src_t0 = {"0CFF1180": 1000.0, "0CFF1181": 500.0}
    for line, i in zip(nmea, starts):
        assert line == nmea_shift(src_nmea[ids[i]], t[i] - src_t0[ids[i]]) or (i == 0 and line == src_nmea[ids[i]])
    assert (tmp_path / "out" / "vehicle.toml").read_text() == "# a\n"


def test_a_list_of_sources_with_alignment_starts_on_multiples(tmp_path):
    a = _recording(tmp_path / "a", 1000.0, 1001, "0CFF1180", "120000.00")
    b = _recording(tmp_path / "b", 500.0, 501, "0CFF1181", "110000.00")
    concatenate([a, b], tmp_path / "out", 30.0, gap_s=10.0, align_s=8.0)
    t = [float(ln[1:ln.index(")")]) for ln in (tmp_path / "out" / "can.log").read_text().splitlines()]
    assert [t[i] - 1000.0 for i in (1001, 1502, 2503)] == pytest.approx([24.0, 40.0, 64.0], abs=1e-6)
