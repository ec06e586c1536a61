import json

import numpy as np
import pytest

from tractionecu.mapping.export import (
    ISO_DDI,
    ISO_DDI_COVERAGE,
    ISO_SCALE,
    MissingExtraError,
    export_geojson,
    export_geotiff,
    export_isoxml,
    export_isoxml_grid,
    export_png,
)
from tractionecu.mapping.iso11783 import GRID_NO_DATA
from tractionecu.mapping.store import MapStore

from map_synth import ORIGIN, SOIL_A, SOIL_NAMES, SOIL_RHO, passes, soil_xy


def far_from_boundaries(x, y, margin):
    """Points whose soil does not change within ``margin`` metres (Manhattan)."""
    s = soil_xy(x, y)
    ok = np.ones(len(x), bool)
    for dx in np.linspace(-margin, margin, 9):
        for dy in np.linspace(-margin, margin, 9):
            if abs(dx) + abs(dy) <= margin + 1e-9:
                ok &= soil_xy(x + dx, y + dy) == s
    return ok


@pytest.fixture(scope="module")
def noise_free_map(tmp_path_factory):
    """Three-soil field, passes 6 m apart, exact values: any cell far enough
    from a boundary holds the soil's a and ρ_s exactly."""
    d = tmp_path_factory.mktemp("map")
    st = MapStore(d, *ORIGIN, soil_classes={SOIL_NAMES[k]: v for k, v in SOIL_A.items()})
    x, y = passes()
    lat, lon = st.to_latlon(x, y)
    sid = soil_xy(x, y)
    for i in range(len(x)):
        k = int(sid[i])
        assert st.add(float(lat[i]), float(lon[i]), {"a": SOIL_A[k], "rho_s": SOIL_RHO[k]}, 0.1 * i)
    st.close()
    return d, x, y, np.asarray(lat), np.asarray(lon)


def test_geotiff_reads_back_with_crs_and_values(noise_free_map, tmp_path):
    rasterio = pytest.importorskip("rasterio")
    pyproj = pytest.importorskip("pyproj")
    d, x, y, lat, lon = noise_free_map
    store = MapStore.open(d, read_only=True)
    raw = export_geotiff(d, tmp_path / "raw.tif", filled=False)
    filled = export_geotiff(d, tmp_path / "filled.tif")
    to_utm = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32633", always_xy=True)
    e, n = to_utm.transform(lon, lat)
    sel = far_from_boundaries(x, y, 1.0)
    with rasterio.open(raw) as ds:
        assert ds.crs.to_epsg() == 32633
        assert ds.count == 2 and ds.descriptions == ("a", "rho_s")
        assert ds.units == ("1", "1")
        assert ds.tags(1)["units"] == "1" and ds.tags(2)["long_name"] == "soil rolling resistance"
        # the synthetic map's samples carry no status: its estimator level is unknown (issue 14's flag)
        assert ds.tags()["estimate_levels"] == (",".join(sorted(store.estimate_levels)) or "unknown")
        assert ds.res == (0.5, 0.5)
        a = ds.read(1)
        rho = ds.read(2)
        rows, cols = rasterio.transform.rowcol(ds.transform, e[sel], n[sel])
        want_a = np.vectorize(SOIL_A.get)(soil_xy(x[sel], y[sel])).astype(np.float32)
        want_r = np.vectorize(SOIL_RHO.get)(soil_xy(x[sel], y[sel])).astype(np.float32)
        assert np.array_equal(a[rows, cols], want_a)
        assert np.array_equal(rho[rows, cols], want_r)
        assert np.isnan(a).sum() > 0  # unmeasured cells are no-data
        assert np.isfinite(a).sum() == (store.grid("a").count > 0).sum()
    with rasterio.open(filled) as ds:
        assert ds.crs.to_epsg() == 32633
        g = store.filled_grid("a", store.padded_extent())
        band = ds.read(1)
        assert np.array_equal(band, g.mean[::-1].astype(np.float32), equal_nan=True)
        west, north = ds.transform * (0, 0)
        assert west == pytest.approx(store.frame.easting0 + g.x0, abs=1e-6)
        assert north == pytest.approx(store.frame.northing0 + g.y0 + g.shape[0] * 0.5, abs=1e-6)


def test_isoxml_grid_reads_back_with_the_isoxml_package(noise_free_map, tmp_path):
    isoxml_io = pytest.importorskip("isoxml.util.isoxml_io")
    from isoxml.converter.np_grid import to_numpy_array
    from isoxml.models.ddi_entities import DDEntity

    d, x, y, lat, lon = noise_free_map
    out = export_isoxml_grid(d, tmp_path / "TASKDATA")
    assert out.name == "TASKDATA.XML" and (out.parent / "GRD00001.BIN").exists()
    task_data, refs = isoxml_io.isoxml_from_path(out.parent)
    assert task_data.version_major.value == "4" and task_data.data_transfer_origin.value == "2"
    task = task_data.tasks[0]
    assert task.status.value == "1"
    grid = task.grids[0]
    assert grid.type.value == "2" and grid.treatment_zone_code == 1 and grid.filename == "GRD00001"
    tzn = [z for z in task.treatment_zones if z.code == 1][0]
    ddis = [int.from_bytes(p.process_data_ddi, "big") for p in tzn.process_data_variables]
    assert ddis == [ISO_DDI["a"], ISO_DDI["rho_s"], ISO_DDI_COVERAGE]
    vpn = {v.id: float(v.scale) for v in task_data.value_presentations}
    scales = [vpn[p.value_presentation_id_ref] for p in tzn.process_data_variables]
    assert scales == [ISO_SCALE["a"], ISO_SCALE["rho_s"], 1.0]
    assert grid.filelength == len(refs["GRD00001"]) == grid.maximum_row * grid.maximum_column * 3 * 4
    ddl = [DDEntity(ddi, f"p{ddi:X}", "", s) for ddi, s in zip(ddis, scales)]
    arr = to_numpy_array(refs["GRD00001"], grid, ddl, scale=True)
    raw = to_numpy_array(refs["GRD00001"], grid, ddl, scale=False)
    assert arr.shape == (grid.maximum_row, grid.maximum_column, 3)

    # independent parse of the bytes: little-endian int32, south row first
    ints = np.frombuffer((out.parent / "GRD00001.BIN").read_bytes(), dtype="<i4")
    assert np.array_equal(ints.reshape(raw.shape), raw)

    # sample locations far from soil boundaries carry their soil's a, ρ_s
    sel = far_from_boundaries(x, y, 11.0)
    assert sel.sum() > 100
    r = np.floor((lat[sel] - float(grid.minimum_north_position)) / grid.cell_north_size).astype(int)
    c = np.floor((lon[sel] - float(grid.minimum_east_position)) / grid.cell_east_size).astype(int)
    sid = soil_xy(x[sel], y[sel])
    assert np.allclose(raw[r, c, 0] * 1e-4, np.vectorize(SOIL_A.get)(sid), atol=0.5e-4)
    assert np.allclose(raw[r, c, 1] * 1e-5, np.vectorize(SOIL_RHO.get)(sid), atol=0.5e-5)
    assert np.allclose(arr[r, c, 0], np.vectorize(SOIL_A.get)(sid), atol=1e-4)
    assert set(np.unique(raw[r, c, 2])) <= {1, 2}
    cov = raw[:, :, 2]
    assert set(np.unique(cov)) == {0, 1, 2}
    # no-data cells are marked, never 0
    assert np.all(raw[cov == 0][:, :2] == GRID_NO_DATA)
    assert np.all(raw[cov != 0][:, 0] != GRID_NO_DATA)
    # every DDI of the grid is declared by the device description, with its scale
    dvc = task_data.devices[0]
    dvp = {v.object_id: v for v in dvc.value_presentations}
    declared = {int.from_bytes(p.ddi, "big"): dvp[p.device_value_presentation_object_id]
                for p in dvc.process_data}
    assert set(ddis) <= set(declared)
    assert [float(declared[k].scale) for k in ddis] == scales
    # cell size ≈ 0.5 m on the ground
    store = MapStore.open(d, read_only=True)
    x0, y0 = store.to_local(float(grid.minimum_north_position), float(grid.minimum_east_position))
    x1, y1 = store.to_local(float(grid.minimum_north_position) + grid.cell_north_size,
                            float(grid.minimum_east_position) + grid.cell_east_size)
    assert abs(x1 - x0 - 0.5) < 0.02 and abs(y1 - y0 - 0.5) < 0.02


def test_png_has_track_boundaries_and_legend_colours(noise_free_map, tmp_path):
    pytest.importorskip("matplotlib")
    import matplotlib.image as mpimg

    d, x, y, lat, lon = noise_free_map
    store = MapStore.open(d, read_only=True)

    def truth(la, lo):
        return soil_xy(*store.to_local(la, lo))

    out = export_png(d, tmp_path / "map.png", truth_soil_fn=truth)
    img = mpimg.imread(out)
    h, w = img.shape[:2]
    assert h > 400 and w > 600
    rgb = (img[:, :, :3] * 255).round().astype(int)
    black = np.all(rgb < 40, axis=2).sum()
    crimson = ((np.abs(rgb[:, :, 0] - 220) < 30) & (rgb[:, :, 1] < 60) & (rgb[:, :, 2] < 90)).sum()
    assert black > 2000      # vehicle track, true boundaries, text
    assert crimson > 200     # mapped soil boundary
    assert len(np.unique(rgb.reshape(-1, 3), axis=0)) > 200  # colour map, not a blank canvas


def test_geojson_zones_and_track(noise_free_map, tmp_path):
    pytest.importorskip("rasterio")
    d, x, y, lat, lon = noise_free_map
    out = export_geojson(d, tmp_path / "map.geojson", include_cells=True)
    doc = json.loads(out.read_text())
    assert doc["type"] == "FeatureCollection"
    kinds = [f["properties"]["kind"] for f in doc["features"]]
    zones = [f for f in doc["features"] if f["properties"]["kind"] == "soil_zone"]
    assert {z["properties"]["soil"] for z in zones} == set(SOIL_NAMES.values())
    store = MapStore.open(d, read_only=True)
    filled = store.filled_grid("a")
    assert sum(z["properties"]["area_m2"] for z in zones) == pytest.approx(np.isfinite(filled.mean).sum() * 0.25)
    big = max(zones, key=lambda z: z["properties"]["area_m2"])
    assert big["properties"]["a_mean"] == pytest.approx(big["properties"]["a_typical"], abs=0.02)
    for z in zones:
        ring = np.array(z["geometry"]["coordinates"][0])
        assert np.array_equal(ring[0], ring[-1])
        area2 = np.sum(ring[:-1, 0] * ring[1:, 1] - ring[1:, 0] * ring[:-1, 1])
        assert area2 > 0  # RFC 7946: exterior ring counter-clockwise
        assert np.all(np.abs(ring[:, 0] - ORIGIN[1]) < 0.01) and np.all(np.abs(ring[:, 1] - ORIGIN[0]) < 0.01)
    track = [f for f in doc["features"] if f["properties"]["kind"] == "track"]
    assert len(track) == 1
    coords = np.array(track[0]["geometry"]["coordinates"])
    assert np.allclose(coords[:, 1], lat, atol=1e-8) and np.allclose(coords[:, 0], lon, atol=1e-8)
    assert kinds.count("cell") == int((store.grid("a", store.padded_extent()).count > 0).sum())


def test_missing_extra_names_the_install_command(noise_free_map, tmp_path, monkeypatch):
    import sys

    d = noise_free_map[0]
    monkeypatch.setitem(sys.modules, "rasterio", None)
    with pytest.raises(MissingExtraError, match=r"tractionecu\[maps\]"):
        export_geotiff(d, tmp_path / "x.tif")
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(MissingExtraError, match=r"tractionecu\[maps\]"):
        export_png(d, tmp_path / "x.png")
    # the ISO-XML writer needs neither
    assert export_isoxml(d, tmp_path / "iso").exists()


def test_empty_map_is_an_error_not_a_crash(tmp_path):
    MapStore(tmp_path / "e", *ORIGIN).close()
    with pytest.raises(ValueError, match="no data"):
        export_isoxml(tmp_path / "e", tmp_path / "iso")


def test_an_isoxml_grid_across_the_180th_meridian_is_refused_not_allocated(tmp_path):
    """A field on Fiji (lon ±180) made the ISO grid span the globe: an attempt to allocate 153 GiB and a
    traceback."""
    from tractionecu.mapping.export import export

    n = 200
    lat = np.full(n, -16.8)
    lon = ((np.linspace(179.9995, 180.0005, n) + 180.0) % 360.0) - 180.0
    with MapStore(tmp_path / "m", float(lat[0]), float(lon[0])) as st:
        st.add_many(lat, lon, {"a": np.full(n, 0.7)}, 1.78e9 + 0.1 * np.arange(n))
    with pytest.raises(ValueError, match="crosses the 180th meridian"):
        export(tmp_path / "m", "isoxml-grid", tmp_path / "TASKDATA")


def test_the_geojson_track_is_broken_between_stretches_driven(tmp_path):
    """A farm map of two machines 1.1 km apart: the GeoJSON track was one LineString with a straight 1124 m
    segment between the two fields."""
    from tractionecu.mapping.export import export_geojson

    n = 200
    with MapStore(tmp_path / "m", *ORIGIN) as st:
        for x0, t0 in ((0.0, 1.78e9), (1100.0, 1.78e9)):            # the second machine at the same times
            x = x0 + np.linspace(0.0, 100.0, n)
            lat, lon = st.to_latlon(x, np.zeros(n))
            st.add_many(lat, lon, {"a": np.full(n, 0.7)}, t0 + 0.1 * np.arange(n))
    doc = json.loads(export_geojson(tmp_path / "m", tmp_path / "map.geojson").read_text())
    (track,) = [f for f in doc["features"] if f["properties"]["kind"] == "track"]
    assert track["geometry"]["type"] == "MultiLineString" and len(track["geometry"]["coordinates"]) == 2
    assert all(len(line) == n for line in track["geometry"]["coordinates"])


_FULL_DISK = """
import resource, sys
from tractionecu.mapping.export import export_geotiff
resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv[3]), resource.RLIM_INFINITY))
try:
    export_geotiff(sys.argv[1], sys.argv[2])
except OSError as e:
    print("OSError", e.errno)
else:
    print("written")
"""


def test_a_geotiff_the_disk_cannot_hold_is_an_error_and_the_earlier_one_stays(noise_free_map, tmp_path):
    """GDAL only prints a write that fails (a full disk: ``_tiffWriteProc: No space left on device``): the
    export moved the file it closed, empty, over the earlier map.tif and said it was written.  The GeoTIFF is
    now made in memory and written with the atomic write: the write raises and the earlier file is left as it
    was.  The disk is a file size limit here (RLIMIT_FSIZE in a child process: EFBIG, as ENOSPC)."""
    import subprocess
    import sys

    pytest.importorskip("rasterio")
    d = noise_free_map[0]
    out = export_geotiff(d, tmp_path / "map.tif")
    before = out.read_bytes()
    assert len(before) > 4096
    p = subprocess.run([sys.executable, "-c", _FULL_DISK, str(d), str(out), "4096"], capture_output=True,
                       text=True, timeout=120)
    assert p.stdout.split() == ["OSError", "27"], p.stdout + p.stderr      # EFBIG
    assert out.read_bytes() == before
    assert [f.name for f in tmp_path.iterdir()] == ["map.tif"]            # no temporary left beside it


def _noisy_map(d, soils: bool, seed: int = 3):
    """The passes above with a noisy `a` (σ 0.03 per sample, as a converged estimate's) and no soil classes
    declared: one soil (a 0.7 everywhere), or the three soils."""
    rng = np.random.default_rng(seed)
    st = MapStore(d, *ORIGIN)
    x, y = passes()
    lat, lon = st.to_latlon(x, y)
    sid = soil_xy(x, y)
    for i in range(len(x)):
        a = (SOIL_A[int(sid[i])] if soils else 0.7) + rng.normal(0.0, 0.03)
        assert st.add(float(lat[i]), float(lon[i]), {"a": a, "rho_s": 0.08}, 0.1 * i)
    st.close()
    return d


def test_a_map_of_one_soil_without_classes_is_one_zone(tmp_path):
    """A map carries no soil classes (replay's and the service's do not): the exports cut a field of one soil
    into three "natural" classes of its noise, 678 GeoJSON zones on a noisy line.  Classes closer than twice
    the spread of a's samples in a cell are one; the three soils of the field above stay three."""
    from tractionecu.mapping.soil import natural_classes

    rng = np.random.default_rng(0)
    one = rng.normal(0.7, 0.01, 500)
    assert len(natural_classes(one, 3)) == 3 and len(natural_classes(one, 3, spread=0.03)) == 1
    three = np.concatenate([rng.normal(m, 0.01, 200) for m in (0.42, 0.60, 0.75)])
    assert natural_classes(three, 3, spread=0.03) == pytest.approx([0.42, 0.60, 0.75], abs=0.01)
    for soils, n in ((False, 1), (True, 3)):
        d = _noisy_map(tmp_path / f"map{n}", soils)
        doc = json.loads(export_geojson(d, tmp_path / f"z{n}.geojson").read_text())
        zones = {f["properties"]["soil"] for f in doc["features"] if f["properties"]["kind"] == "soil_zone"}
        assert len(zones) == n, zones
