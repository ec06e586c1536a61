"""NMEA formatting (u-blox F9P style) and strict parsing."""

import math
from datetime import date, datetime, timedelta, timezone
from pathlib import Path

import pynmea2
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tractionecu.errors import DecodeError
from tractionecu.gnss.nmea import (
    KNOT_MPS,
    EpochAssembler,
    NmeaStats,
    assemble_epochs,
    checksum,
    format_gga,
    format_rmc,
    format_vtg,
    format_zda,
    iter_nmea,
    parse_line,
    read_nmea,
)

DATA = Path(__file__).resolve().parents[1] / "data" / "nmea"

# latitude 47°17.11399' N, longitude 8°33.91590' E (u-blox example position)
LAT = 47 + 17.11399 / 60
LON = 8 + 33.91590 / 60


def test_gga_matches_published_ublox_example():
    line = format_gga(datetime(2002, 12, 9, 9, 27, 25), LAT, LON, 1, 8, 1.01, 499.6, 48.0, talker="GP")
    assert line == "$GPGGA,092725.00,4717.11399,N,00833.91590,E,1,08,1.01,499.6,M,48.0,M,,*5B"


def test_vtg_matches_published_ublox_example_fields():
    line = format_vtg(0.004 * KNOT_MPS, 77.52, talker="GP")
    assert line.startswith("$GPVTG,77.52,T,,M,0.004,N,0.007,K,A*")
    assert float(pynmea2.parse(line, check=True).spd_over_grnd_kts) == pytest.approx(0.004)


def test_checksum_is_xor_of_body():
    assert checksum("GPVTG,77.52,T,,M,0.004,N,0.008,K,A") == "06"


def test_default_talker_and_field_widths():
    t = datetime(2024, 5, 17, 10, 0, 1, 230000)
    gga = format_gga(t, -0.5, -179.25, 4, 12, 0.5, -3.21, -20.04, dgps_age_s=1.0, dgps_station=0)
    assert gga.startswith("$GNGGA,100001.23,0030.00000,S,17915.00000,W,4,12,0.50,-3.2,M,-20.0,M,1.0,0000*")
    rmc = format_rmc(t, 10.0, 20.0, 5.0, 359.996)
    fields = rmc.split("*")[0].split(",")
    assert fields[7] == f"{5.0 / KNOT_MPS:.3f}" and fields[8] == "0.00" and fields[9] == "170524"
    assert fields[12:] == ["A", "V"]
    assert format_rmc(t, 10.0, 20.0, 0.0, None, valid=False).split(",")[2] == "V"


def test_time_rounding_carries_into_date():
    t = datetime(2024, 12, 31, 23, 59, 59, 996000)
    rmc = parse_line(format_rmc(t, 1.0, 1.0, 0.0, 0.0))
    assert rmc.tod_s == 0.0 and rmc.date == date(2025, 1, 1)


def test_aware_datetime_converted_to_utc():
    t = datetime(2024, 5, 17, 12, 0, 0, tzinfo=timezone(timedelta(hours=2)))
    assert parse_line(format_zda(t)).tod_s == 10 * 3600.0


utc_times = st.datetimes(min_value=datetime(2000, 1, 1), max_value=datetime(2079, 12, 31))
lats = st.floats(-90.0, 90.0, allow_nan=False)
lons = st.floats(-180.0, 180.0, allow_nan=False)
speeds = st.floats(0.0, 100.0, allow_nan=False)
courses = st.floats(0.0, 359.99, allow_nan=False)


def _tod(t):
    return t.hour * 3600 + t.minute * 60 + t.second + t.microsecond / 1e6


def _tod_close(a, b):
    d = abs(a - b)
    return min(d, 86400 - d) <= 0.005 + 1e-9


@settings(max_examples=200, deadline=None)
@given(t=utc_times, lat=lats, lon=lons, q=st.integers(0, 8), n=st.integers(0, 99),
       hdop=st.floats(0.0, 99.0), alt=st.floats(-500.0, 9000.0), sep=st.floats(-100.0, 100.0))
def test_every_gga_parses_with_pynmea2_check(t, lat, lon, q, n, hdop, alt, sep):
    line = format_gga(t, lat, lon, q, n, hdop, alt, sep)
    msg = pynmea2.parse(line, check=True)
    assert msg.sentence_type == "GGA"
    r = parse_line(line)
    assert abs(r.lat_deg - lat) <= 1e-5 / 60 / 2 + 1e-12
    assert abs(r.lon_deg - lon) <= 1e-5 / 60 / 2 + 1e-12
    assert _tod_close(r.tod_s, _tod(t))
    assert (r.fix_quality, r.nsat) == (q, n)
    assert r.hdop == pytest.approx(hdop, abs=0.005 + 1e-9) and r.alt_m == pytest.approx(alt, abs=0.05 + 1e-9)


@settings(max_examples=200, deadline=None)
@given(t=utc_times, lat=lats, lon=lons, v=speeds, c=courses, valid=st.booleans())
def test_every_rmc_and_vtg_parses_with_pynmea2_check(t, lat, lon, v, c, valid):
    rmc = format_rmc(t, lat, lon, v, c, valid)
    vtg = format_vtg(v, c)
    assert pynmea2.parse(rmc, check=True).sentence_type == "RMC"
    assert pynmea2.parse(vtg, check=True).sentence_type == "VTG"
    r = parse_line(rmc)
    assert r.valid is valid
    assert abs(r.speed_mps - v) <= 0.0005 * KNOT_MPS + 1e-9
    assert abs(((r.course_deg - c + 180) % 360) - 180) <= 0.005 + 1e-9
    rounded = (t + timedelta(microseconds=5000)).replace(microsecond=0)  # upper bound of rounding
    assert r.date in (t.date(), rounded.date())
    w = parse_line(vtg)
    assert abs(w.speed_mps - v) <= 0.0005 / 3.6 + 1e-9


@settings(max_examples=50, deadline=None)
@given(t=utc_times)
def test_every_zda_parses_with_pynmea2_check(t):
    line = format_zda(t)
    assert pynmea2.parse(line, check=True).sentence_type == "ZDA"
    assert _tod_close(parse_line(line).tod_s, _tod(t))


def test_negative_speed_written_as_magnitude_nan_course_empty():
    r = parse_line(format_rmc(datetime(2024, 1, 1), 1.0, 1.0, -0.3, float("nan")))
    assert r.speed_mps == pytest.approx(0.3, abs=3e-4) and r.course_deg is None


def test_formatter_rejects_bad_position():
    with pytest.raises(ValueError):
        format_gga(datetime(2024, 1, 1), 91.0, 0.0, 1, 5, 1.0, 0.0)
    with pytest.raises(ValueError):
        format_rmc(datetime(2024, 1, 1), float("nan"), 0.0, 1.0, 0.0)


def test_mixed_fixture_counts_and_values():
    stats = NmeaStats(source="mixed.nmea")
    with open(DATA / "mixed.nmea", newline=None) as fh:
        recs = dict(iter_nmea(fh, stats))
    assert dict(stats.rejected) == {"bad_checksum": 1, "missing_checksum": 1, "garbage": 1, "bad_field": 1}
    assert stats.examples == {"bad_checksum": [6], "missing_checksum": [7], "garbage": [8], "bad_field": [12]}
    assert stats.ignored == {"GSV": 1}
    assert sorted(recs) == [1, 2, 3, 4, 9, 10, 11]
    assert {r.talker for r in recs.values()} == {"GP", "GL", "GA", "GB"}
    gga = recs[1]
    assert gga.tod_s == 9 * 3600 + 27 * 60 + 25 and gga.lat_deg == pytest.approx(LAT, abs=1e-12)
    rmc = recs[2]
    assert rmc.date == date(2002, 12, 9) and rmc.speed_mps == pytest.approx(0.004 * KNOT_MPS)
    assert recs[3].speed_mps == pytest.approx(0.008 / 3.6)  # km/h field preferred
    assert recs[4].date == date(2002, 9, 16)
    gns = recs[9]
    assert gns.sentence == "GNS" and gns.nsat == 10 and gns.lon_deg < 0 and gns.fix_quality == 1
    ga = recs[10]
    assert ga.lat_deg < 0 and ga.lon_deg < 0 and ga.fix_quality == 2 and ga.geoid_sep_m == -20.1
    gb = recs[11]
    assert gb.valid is False and gb.date == date(1999, 12, 31) and gb.speed_mps is None and gb.fix_quality == 0


@pytest.mark.parametrize(
    "line, reason",
    [
        ("$GNGGA,092725.00,4717.11399,N,00833.91590,E,1,08,1.01,499.6,M,48.0,M,,*5C", "bad_checksum"),
        ("$GNGGA,092725.00,4717.11399,N,00833.91590,E,1,08,1.01,499.6,M,48.0,M,,", "missing_checksum"),
        ("$GNGGA,092725.00,4717.11399,N*ZZ", "bad_checksum"),
        ("GPGGA,1,2*00", "garbage"),
        ("\x00\x01\x02", "garbage"),
    ],
)
def test_bad_lines_raise_decode_error_with_reason(line, reason):
    with pytest.raises(DecodeError) as e:
        parse_line(line)
    assert e.value.reason == reason


@pytest.mark.parametrize(
    "body",
    [
        "GNGGA,256000.00,4717.11399,N,00833.91590,E,1,08,1.01,499.6,M,48.0,M,,",  # hour 25
        "GNGGA,092725.00,4717.11399,X,00833.91590,E,1,08,1.01,499.6,M,48.0,M,,",  # hemisphere
        "GNGGA,092725.00,4717.11399,N,00833.91590,E,1,08,abc,499.6,M,48.0,M,,",  # hdop
        "GNRMC,083559.00,A,4717.11437,N,00833.91522,E,0.004,77.52,311302,,,A,V",  # month 13
        "GNGGA,092725.00,9100.00000,N,00833.91590,E,1,08,1.01,499.6,M,48.0,M,,",  # lat > 90
    ],
)
def test_field_errors_are_bad_field(body):
    with pytest.raises(DecodeError) as e:
        parse_line(f"${body}*{checksum(body)}")
    assert e.value.reason == "bad_field"


def test_unsupported_and_blank_lines_return_none():
    body = "GNTXT,01,01,02,u-blox AG - www.u-blox.com"
    assert parse_line(f"${body}*{checksum(body)}") is None
    assert parse_line("   \r\n") is None


def test_epoch_assembly_groups_by_time():
    t0 = datetime(2024, 5, 17, 10, 0, 0)
    lines = []
    for k in range(3):
        t = t0 + timedelta(milliseconds=100 * k)
        lines += [
            format_gga(t, LAT, LON, 4, 12, 0.6, 400.0 + k, 47.0),
            format_rmc(t, LAT, LON, 2.0 + k, 90.0),
            format_vtg(2.0 + k, 90.0),
        ]
    fixes = list(assemble_epochs(iter_nmea(lines)))
    assert len(fixes) == 3
    for k, f in enumerate(fixes):
        assert f.sentences == ("GGA", "RMC", "VTG")
        assert f.tod_s == pytest.approx(36000 + 0.1 * k)
        assert f.date == date(2024, 5, 17)
        assert f.alt_m == pytest.approx(400.0 + k) and f.fix_quality == 4 and f.nsat == 12
        assert f.speed_mps == pytest.approx(2.0 + k, abs=1e-3) and f.valid is True
        assert f.lineno == 1 + 3 * k


def test_vtg_before_first_timed_sentence_is_an_orphan():
    asm = EpochAssembler()
    assert asm.push(1, parse_line(format_vtg(1.0, 0.0))) is None
    assert asm.orphans == 1 and asm.flush() is None


def test_read_nmea_file_crlf(tmp_path):
    p = tmp_path / "gps.nmea"
    t = datetime(2024, 5, 17, 10, 0, 0)
    p.write_bytes((format_gga(t, LAT, LON, 1, 9, 0.9, 10.0) + "\r\n" + format_rmc(t, LAT, LON, 1.0, 5.0) + "\r\n").encode())
    stats = NmeaStats()
    fixes = list(read_nmea(p, stats))
    assert len(fixes) == 1 and stats.total_rejected == 0 and stats.source == "gps.nmea"
    assert not math.isnan(fixes[0].lat_deg)


def test_glued_sentences_split_in_both_readers(tmp_path):
    """The log reader (reference and fast paths) reads each sentence of a line that holds several (a lost
    line break), gives the epochs of the intact log and counts the lines it split."""
    from tractionecu.gnss.nmea import NmeaStats, iter_nmea, iter_nmea_fast, split_glued
    from tractionecu.gnss.nmea import format_gga, format_rmc, format_vtg

    t0 = datetime(2026, 7, 10, 8, 0, 0, tzinfo=timezone.utc)
    lines = []
    for i in range(10):
        u = t0 + timedelta(seconds=0.1 * i)
        lines += [format_gga(u, 47.88, -110.55, 2, 12, 0.9, 850.0), format_rmc(u, 47.88, -110.55, 2.5, 90.0, True),
                  format_vtg(2.5, 90.0)]
    glued = []
    for k in range(0, len(lines), 3):
        glued += [lines[k] + lines[k + 1], lines[k + 2]]
    assert split_glued(glued[0]) == [lines[0], lines[1]] and split_glued(lines[0]) == [lines[0]]
    ref = [r for _, r in iter_nmea(lines)]
    st = NmeaStats()
    got = [r for _, r in iter_nmea(glued, st)]
    assert got == ref and st.split_count == 10 and st.total_rejected == 0
    assert "lines holding several sentences, split: 10 (line 1, 3, 5, 7, 9, ...)" in st.notes()
    p = tmp_path / "g.nmea"
    p.write_text("\n".join(glued) + "\n", encoding="ascii")
    st2 = NmeaStats()
    with open(p, encoding="ascii") as fh:
        fast = list(iter_nmea_fast(fh, st2))
    assert len(fast) == len(ref) and st2.split_count == 10 and st2.accepted == st.accepted


def test_a_loggers_prefix_before_each_sentence_is_read_past(tmp_path):
    """A logger that writes its own time before every sentence ("1783670400.001 $GNGGA,…") had all 2700
    lines rejected as garbage: no GNSS, a replay with no valid step and exit 0."""
    from tractionecu.gnss.nmea import NmeaStats, format_gga, format_rmc, iter_nmea, iter_nmea_fast

    t0 = datetime(2026, 7, 10, 8, 0, 0, tzinfo=timezone.utc)
    lines = []
    for i in range(10):
        u = t0 + timedelta(seconds=0.1 * i)
        lines += [format_gga(u, 47.88, -110.55, 2, 12, 0.9, 850.0), format_rmc(u, 47.88, -110.55, 2.5, 90.0, True)]
    prefixed = [f"{1783670400.0 + 0.05 * k:.3f} {ln}" for k, ln in enumerate(lines)]
    ref = [r for _, r in iter_nmea(lines)]
    st = NmeaStats()
    assert [r for _, r in iter_nmea(prefixed, st)] == ref
    assert st.prefixed_count == 20 and st.total_rejected == 0
    assert any(d.startswith("lines holding text before their sentence") for d in st.notes())
    p = tmp_path / "p.nmea"
    p.write_text("\n".join(prefixed) + "\n", encoding="ascii")
    st2 = NmeaStats()
    with open(p, encoding="ascii") as fh:
        assert len(list(iter_nmea_fast(fh, st2))) == len(ref) and st2.prefixed_count == 20
    bad = NmeaStats()
    assert not list(iter_nmea(["no sentence here", "GGA,080000.00,4752.8,N*00"], bad)) and bad.total_rejected == 2
