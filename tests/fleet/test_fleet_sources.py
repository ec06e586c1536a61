"""Which recordings a fleet source holds, and their machine, date and field."""

from __future__ import annotations

from pathlib import Path

import pytest

from tractionecu.errors import ConfigError
from tractionecu.fleet.sources import discover, field_of_fix, first_fix

RMC = "$GNRMC,080000.10,A,4752.89606,N,11033.20423,W,0.595,90.00,100726,,,A,V*21\n"
GGA = "$GNGGA,080000.10,4752.89606,N,11033.20423,W,2,16,0.90,862.1,M,0.0,M,,*6B\n"


def _rec(d: Path, nmea: str = "") -> Path:
    d.mkdir(parents=True)
    (d / "can.log").write_text("", encoding="utf-8")
    (d / "gps.nmea").write_text(nmea, encoding="utf-8")
    return d


def test_tree_machine_date_from_path(tmp_path: Path) -> None:
    _rec(tmp_path / "m1" / "2026-07-10" / "a")
    _rec(tmp_path / "m1" / "20260711" / "b")
    _rec(tmp_path / "machine=m2" / "x" / "date=2026-08-01" / "field=north" / "c")
    _rec(tmp_path / "loose", GGA + RMC)                          # no machine, date from the RMC
    (tmp_path / "m3").mkdir()
    (tmp_path / "m3" / "2026-09-01_capture.blf").write_bytes(b"")   # a capture file
    (tmp_path / "m1" / "2026-07-10" / "a" / "notes.log").write_text("inside a recording: not one\n")
    refs = discover(tmp_path)
    got = {(Path(r.path).relative_to(tmp_path).as_posix(), r.machine, r.date, r.field) for r in refs}
    assert got == {
        ("m1/2026-07-10/a", "m1", "2026-07-10", ""),
        ("m1/20260711/b", "m1", "2026-07-11", ""),
        ("machine=m2/x/date=2026-08-01/field=north/c", "m2", "2026-08-01", "north"),
        ("loose", "unknown", "2026-07-10", ""),
        ("m3/2026-09-01_capture.blf", "m3", "2026-09-01", ""),
    }


def test_a_folder_with_a_gnss_log_but_no_can_capture_is_named(tmp_path: Path, caplog) -> None:
    """A logger that lost its CAN side left a folder with gps.nmea alone: it was no recording, without a word."""
    _rec(tmp_path / "m1" / "2026-07-10" / "a")
    lost = tmp_path / "m1" / "2026-07-11" / "b"
    lost.mkdir(parents=True)
    (lost / "gps.nmea").write_text(GGA + RMC, encoding="utf-8")
    with caplog.at_level("WARNING", logger="tractionecu.fleet.sources"):
        assert [Path(r.path).name for r in discover(tmp_path)] == ["a"]
    assert f"fleet: {lost} holds a GNSS log but no CAN capture (can.log): not a recording" in caplog.text


def test_output_inside_the_tree_is_not_searched(tmp_path: Path) -> None:
    _rec(tmp_path / "m1" / "2026-07-10" / "a")
    _rec(tmp_path / "out" / "m9" / "2026-01-01" / "z")
    assert [Path(r.path).name for r in discover(tmp_path, exclude=tmp_path / "out")] == ["a"]


def test_manifest_columns_win(tmp_path: Path) -> None:
    _rec(tmp_path / "data" / "m1" / "2026-07-10" / "a")
    _rec(tmp_path / "data" / "b")
    man = tmp_path / "manifest.csv"
    man.write_text("path,machine,date,field\ndata/m1/2026-07-10/a,,,\ndata/b,tractor-7,2026-05-04,west\n",
                   encoding="utf-8")
    with open(man, "a", encoding="utf-8") as fh:
        fh.write("data/b,tractor-8,2026-05-05,east\n")               # listed twice: the first row counts
    listed = discover(man)
    assert len(listed) == 2
    refs = {Path(r.path).name: r for r in listed}
    assert (refs["a"].machine, refs["a"].date) == ("data", "2026-07-10")     # path rule, relative to the manifest
    assert (refs["b"].machine, refs["b"].date, refs["b"].field) == ("tractor-7", "2026-05-04", "west")
    bad = tmp_path / "bad.csv"
    bad.write_text("path,date\ndata/b,10.07.2026\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="not YYYY-MM-DD"):
        discover(bad)
    with pytest.raises(ConfigError, match="'path' column"):
        (tmp_path / "nopath.csv").write_text("file\nx\n", encoding="utf-8")
        discover(tmp_path / "nopath.csv")


def test_glob(tmp_path: Path) -> None:
    _rec(tmp_path / "m1" / "2026-07-10" / "a")
    _rec(tmp_path / "m2" / "2026-07-11" / "b")
    refs = discover(str(tmp_path / "*" / "2026-07-1*" / "*"))
    assert [(r.machine, r.date) for r in refs] == [("m1", "2026-07-10"), ("m2", "2026-07-11")]


def test_missing_source_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such directory"):
        discover(tmp_path / "nothing")


def test_first_fix_and_field_name(tmp_path: Path) -> None:
    d = _rec(tmp_path / "r", "$GNGGA,080000.00,,,,,0,00,99.9,,M,,M,,*00\n" + GGA)
    lat, lon = first_fix(d)
    assert lat == pytest.approx(47 + 52.89606 / 60, abs=1e-12)
    assert lon == pytest.approx(-(110 + 33.20423 / 60), abs=1e-12)
    assert field_of_fix(lat, lon) == "lat47.88_lon-110.56"


def test_first_fix_is_not_a_dead_reckoned_or_single_glitched_one(tmp_path: Path) -> None:
    """A dead-reckoned (quality 6) first fix 60 km away became the farm map's origin, and every recording of
    the season then lay beyond the map's 50 km range: "farm map: None from 0 recordings", exit 0."""
    dr = "$GNGGA,080000.00,4720.00000,N,11033.20383,W,6,16,0.90,862.1,M,0.0,M,,*00\n"
    glitch = "$GNGGA,080000.05,4600.00000,N,11033.20383,W,1,16,0.90,862.1,M,0.0,M,,*00\n"
    d = _rec(tmp_path / "r", dr + glitch + GGA * 5)
    lat, lon = first_fix(d)
    assert lat == pytest.approx(47 + 52.89606 / 60, abs=1e-12)
    assert lon == pytest.approx(-(110 + 33.20423 / 60), abs=1e-12)


@pytest.mark.parametrize("origin", ["95,10", "48,200", "nan,10"])
def test_an_origin_off_the_globe_is_refused_before_any_replay(tmp_path, capsys, origin):
    """--origin 95,10 replayed every recording in full, then failed each one with a ConfigError."""
    from tractionecu.cli.main import main

    assert main(["fleet", "map", str(tmp_path / "nothing"), "--out", str(tmp_path / "out"), "--origin", origin]) == 1
    assert "--origin: latitude in [-90, 90]" in capsys.readouterr().err


def test_source_inside_the_tree_keeps_machine_and_date(tmp_path: Path) -> None:
    """A machine's folder, a date's folder or one recording as SOURCE: the same machine and date as a run
    over the whole tree (they were 'unknown' and the RMC date, so the recording became another task)."""
    _rec(tmp_path / "season" / "m1" / "2026-07-10" / "a")
    _rec(tmp_path / "season" / "m1" / "20260711" / "b")
    whole = {Path(r.path).name: (r.machine, r.date) for r in discover(tmp_path / "season")}
    assert whole == {"a": ("m1", "2026-07-10"), "b": ("m1", "2026-07-11")}
    for src in ("season/m1", "season/m1/2026-07-10", "season/m1/2026-07-10/a", "season/m1/20260711/b"):
        for r in discover(tmp_path / src):
            assert (r.machine, r.date) == whole[Path(r.path).name], src
    # a folder without a date above the recording names no machine (as in the tree)
    _rec(tmp_path / "loose" / "c", GGA + RMC)
    assert [(r.machine, r.date) for r in discover(tmp_path / "loose" / "c")] == [("unknown", "2026-07-10")]
