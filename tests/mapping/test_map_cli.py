import argparse
import json
import os
import stat

import numpy as np
import pytest

from tractionecu.cli import map as map_cmd
from tractionecu.mapping.store import MapStore

from map_synth import ORIGIN, fill_store, passes


def parse(argv):
    """Build the parser the way the main CLI does and dispatch via args.func."""
    parser = argparse.ArgumentParser(prog="tractionecu")
    sub = parser.add_subparsers(dest="command")
    map_cmd.add_subparser(sub)
    return parser.parse_args(argv)


@pytest.fixture(scope="module")
def replay_dir(tmp_path_factory):
    """A replay output directory with the map under ``map/``."""
    out = tmp_path_factory.mktemp("run")
    st = MapStore(out / "map", *ORIGIN)
    x, y = passes(width_m=30.0, length_m=20.0)
    fill_store(st, x, y, np.random.default_rng(2))
    st.close()
    return out


@pytest.mark.parametrize("fmt,name", [("geotiff", "map.tif"), ("isoxml", "TASKDATA/TASKDATA.XML"),
                                      ("isoxml-grid", "TASKDATA_GRID/TASKDATA.XML"),
                                      ("png", "map.png"), ("geojson", "map.geojson")])
def test_export_each_format(replay_dir, fmt, name, capsys):
    if fmt in ("geotiff", "geojson"):
        pytest.importorskip("rasterio")
    if fmt == "png":
        pytest.importorskip("matplotlib")
    args = parse(["map", "export", str(replay_dir), "--format", fmt])
    assert args.func(args) == 0
    path = replay_dir / "export" / name
    assert path.exists() and path.stat().st_size > 0
    assert capsys.readouterr().out.strip() == str(path)


def test_export_options(replay_dir, tmp_path):
    rasterio = pytest.importorskip("rasterio")
    args = parse(["map", "export", str(replay_dir / "map"), "--format", "geotiff", "--out",
                  str(tmp_path / "a.tif"), "--layers", "a", "--raw"])
    assert args.func(args) == 0
    with rasterio.open(tmp_path / "a.tif") as ds:
        assert ds.count == 1 and ds.descriptions == ("a",)
    args = parse(["map", "export", str(replay_dir), "--format", "geojson", "--out", str(tmp_path / "z.geojson"),
                  "--soil-classes", "firm=0.75,soft=0.42"])
    assert args.func(args) == 0
    doc = json.loads((tmp_path / "z.geojson").read_text())
    soils = {f["properties"].get("soil") for f in doc["features"] if f["properties"]["kind"] == "soil_zone"}
    assert soils <= {"firm", "soft"} and soils


def test_errors_give_exit_codes(tmp_path, replay_dir, capsys, monkeypatch):
    args = parse(["map", "export", str(tmp_path / "nothing"), "--format", "png"])
    assert args.func(args) == 1
    assert "nothing: no such directory" in capsys.readouterr().err
    args = parse(["map", "export", str(replay_dir), "--format", "isoxml", "--layers", "nope"])
    assert args.func(args) == 2
    args = parse(["map", "export", str(replay_dir), "--format", "png", "--soil-classes", "junk"])
    assert args.func(args) == 2
    import sys

    monkeypatch.setitem(sys.modules, "rasterio", None)
    args = parse(["map", "export", str(replay_dir), "--format", "geotiff", "--out", str(tmp_path / "x.tif")])
    assert args.func(args) == 3
    assert "pip install 'tractionecu[maps]'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        parse(["map", "export", str(replay_dir), "--format", "shapefile"])


def test_info(replay_dir, capsys):
    args = parse(["map", "info", str(replay_dir)])
    assert args.func(args) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["crs"] == "EPSG:32633" and info["tiles"] >= 1 and info["track_points"] > 0
    assert info["corrupt_tiles"] == []


@pytest.mark.parametrize("classes,why", [("firm=abc", "class 'firm': its a is not a number: 'abc'"),
                                          ("firm=nan,soft=0.4", "class 'firm': its a must be finite, got 'nan'")])
def test_soil_classes_that_are_not_numbers_are_named(replay_dir, classes, why, capsys):
    """``--soil-classes firm=abc`` printed only Python's "could not convert string to float: 'abc'", and a NaN
    a was taken and classified every cell against it."""
    args = parse(["map", "export", str(replay_dir), "--format", "geojson", "--soil-classes", classes])
    assert args.func(args) == 2
    assert f"--soil-classes: {why}" in capsys.readouterr().err


@pytest.mark.parametrize("fmt,name", [("geotiff", "map.tif"), ("geojson", "map.geojson")])
def test_out_an_existing_directory_gets_the_default_file_name(replay_dir, tmp_path, fmt, name, capsys):
    """``--out DIR`` of a file format ended in "[Errno 21] Is a directory: '.DIR.tmp.1234' -> 'DIR'"."""
    pytest.importorskip("rasterio")
    args = parse(["map", "export", str(replay_dir), "--format", fmt, "--out", str(tmp_path)])
    assert args.func(args) == 0
    assert (tmp_path / name).stat().st_size > 0
    assert capsys.readouterr().out.strip() == str(tmp_path / name)


@pytest.mark.parametrize("fmt", ["geotiff", "isoxml", "isoxml-grid", "png"])
@pytest.mark.parametrize("layers", [",,", "a,a"])
def test_an_empty_or_repeated_layer_list_is_a_usage_error(tmp_path, replay_dir, capsys, fmt, layers):
    """--layers ",," gave an IndexError traceback (isoxml-grid), a rasterio error (geotiff) or a log without
    layers (isoxml); "a,a" wrote two bands named a and two process-data entries of one DDI."""
    args = parse(["map", "export", str(replay_dir), "--format", fmt, "--layers", layers, "--out", str(tmp_path / "x")])
    code = args.func(args)
    err = capsys.readouterr().err
    if fmt == "png" and layers == "a,a":
        assert code == 0                                  # png draws the first layer named
    else:
        assert code == 2 and ("no layer named" in err or "named twice" in err), err


def test_an_out_that_is_no_regular_file_is_refused_and_left_alone(replay_dir, tmp_path, capsys):
    """``--out`` naming a device node or pipe replaced it with the export (/dev/full became a PNG file)."""
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    args = parse(["map", "export", str(replay_dir), "--format", "geojson", "--out", str(fifo)])
    assert args.func(args) == 1
    assert "exists and is not a regular file or a directory" in capsys.readouterr().err
    assert stat.S_ISFIFO(fifo.stat().st_mode)


def test_an_export_that_outgrows_memory_says_why(replay_dir, capsys, monkeypatch):
    """Fields kilometres apart: one raster over the whole extent raised MemoryError with a traceback."""
    from tractionecu.mapping import export as exp

    def too_big(*a, **k):
        raise MemoryError

    monkeypatch.setitem(exp.EXPORTERS, "geotiff", too_big)
    args = parse(["map", "export", str(replay_dir), "--format", "geotiff", "--out", str(replay_dir / "x.tif")])
    assert args.func(args) == 1
    err = capsys.readouterr().err
    assert "not enough memory for one geotiff grid over the map's whole extent" in err and "Traceback" not in err
