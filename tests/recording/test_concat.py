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
