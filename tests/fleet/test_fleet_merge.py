"""The farm map: per-recording stores merged cell by cell (Chan), associative, equal to one map fed
by the replays in sequence."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from tractionecu.mapping.store import MapStore
from tractionecu.fleet.merge import cell_contributors, max_difference, merge_maps, merged_inputs
from tractionecu.fleet.store import contributors_of

ORIGIN = (47.88, -110.55)


def _store(d: Path, seed: int, n: int = 4000, machine: str = "m", date: str = "2026-07-10",
           status: int | None = None) -> Path:
    """A map store of ``n`` random samples over a 40 m x 40 m patch (overlapping the others)."""
    rng = np.random.default_rng(seed)
    lat = ORIGIN[0] + 0.0002 + rng.uniform(0, 3.6e-4, n)
    lon = ORIGIN[1] + 0.0002 + rng.uniform(0, 5.4e-4, n)
    vals = {"a": rng.normal(0.7, 0.05, n), "rho_s": rng.normal(0.06, 0.001, n), "mu": rng.normal(0.4, 0.1, n)}
    with MapStore(d, *ORIGIN) as st:
        st.add_many(lat, lon, vals, 1.78e9 + np.arange(n) * 0.1, status=status)
    contributors_of(MapStore.open(d, read_only=True), machine, date, d / "contributors.parquet")
    return d


def test_merge_is_associative_and_exact(tmp_path: Path) -> None:
    a, b, c = (_store(tmp_path / k, s, machine=k) for k, s in (("A", 1), ("B", 2), ("C", 3)))
    merge_maps([merge_maps([a, b], tmp_path / "AB")["map_dir"], c], tmp_path / "AB_C")
    merge_maps([a, merge_maps([b, c], tmp_path / "BC")["map_dir"]], tmp_path / "A_BC")
    d = max_difference(tmp_path / "AB_C", tmp_path / "A_BC")
    assert d["count"] == 0 and d["cells_only_in_one"] == 0
    assert d["mean"] <= 1e-12 and d["var"] <= 1e-12
    # the merged statistics are those of all the samples: check one layer against numpy
    merged = MapStore.open(tmp_path / "AB_C", read_only=True)
    tracks = [MapStore.open(x, read_only=True) for x in (a, b, c)]
    x = np.concatenate([s.track()[:, 1] for s in tracks])
    y = np.concatenate([s.track()[:, 2] for s in tracks])
    v = np.concatenate([s.track_values()[:, 1 + s.layers.index("mu")] for s in tracks])
    g = merged.grid("mu")
    col = np.floor(x / 0.5).astype(int) - int(round(g.x0 / 0.5))
    row = np.floor(y / 0.5).astype(int) - int(round(g.y0 / 0.5))
    df = pd.DataFrame({"r": row, "c": col, "v": v}).groupby(["r", "c"])["v"].agg(["count", "mean", "var"])
    r, cc = df.index.get_level_values(0).to_numpy(), df.index.get_level_values(1).to_numpy()
    assert np.array_equal(g.count[r, cc], df["count"].to_numpy())
    np.testing.assert_allclose(g.mean[r, cc], df["mean"].to_numpy(), rtol=0, atol=1e-12)
    ok = df["count"].to_numpy() >= 2
    np.testing.assert_allclose(g.var[r, cc][ok], df["var"].to_numpy()[ok], rtol=1e-9, atol=1e-15)
    # the tracks are concatenated, the contributors summed
    assert len(merged.track()) == sum(len(s.track()) for s in tracks)
    cells = cell_contributors(tmp_path / "AB_C")
    assert set(m for ms in cells["machines"] for m in ms) == {"A", "B", "C"}
    assert int(cells["samples"].sum()) == int(sum(s.grid("mu").count.sum() for s in tracks))
    assert merged_inputs(tmp_path / "AB_C") == [str(a), str(b), str(c)]


def test_merge_refuses_different_frames(tmp_path: Path) -> None:
    import pytest

    from tractionecu.errors import ConfigError

    a = _store(tmp_path / "A", 1)
    with MapStore(tmp_path / "other", ORIGIN[0] + 0.001, ORIGIN[1]) as st:
        st.add_many([ORIGIN[0] + 0.0011], [ORIGIN[1] + 0.0001], {"mu": [0.3]}, [0.0])
    with pytest.raises(ConfigError, match="origin_lat"):
        merge_maps([a, tmp_path / "other"], tmp_path / "x")


def test_merged_map_of_two_machines_equals_one_map_fed_in_sequence(tmp_path: Path,
                                                                   short_recordings: dict[str, Path]) -> None:
    """Two replays on the same field: their per-recording stores merged equal, within 1e-9, one store
    fed by both replays in sequence (counts exactly)."""
    from tractionecu.mapping.from_replay import write_replay_map
    from tractionecu.pipeline.rundir import replay_to_dir

    runs = []
    for name, rec_dir in short_recordings.items():
        _, rec, res = replay_to_dir(rec_dir, tmp_path / f"run_{name}", keep_arrays=False)
        runs.append((rec, res))
    origin = (float(runs[0][0].gps.lat[0]), float(runs[0][0].gps.lon[0]))
    parts = []
    for i, (rec, res) in enumerate(runs):
        d = tmp_path / f"part{i}"
        with MapStore(d, *origin) as st:
            write_replay_map(tmp_path, rec, res.arrays, gps_mask=res.gps_mask, store=st)
        parts.append(d)
    with MapStore(tmp_path / "sequence", *origin) as st:
        for rec, res in runs:
            write_replay_map(tmp_path, rec, res.arrays, gps_mask=res.gps_mask, store=st)
    merge_maps(parts, tmp_path / "merged")
    d = max_difference(tmp_path / "merged", tmp_path / "sequence")
    assert d["count"] == 0 and d["cells_only_in_one"] == 0
    assert d["mean"] <= 1e-9 and d["var"] <= 1e-9
    both = MapStore.open(tmp_path / "merged", read_only=True).grid("mu")
    single = [MapStore.open(p, read_only=True).grid("mu") for p in parts]
    assert int(both.count.sum()) == sum(int(g.count.sum()) for g in single) > 100
    # the two runs share cells, so the merge combines, not only places side by side
    assert int((both.count > 0).sum()) < sum(int((g.count > 0).sum()) for g in single)


def test_the_farm_map_holds_the_estimator_levels_of_its_machines(tmp_path: Path) -> None:
    """A hub tractor's map (per-wheel μ) merged with a mechanical one's (machine-level μ, status 0x4000)."""
    a = _store(tmp_path / "A", 1, n=500, machine="hub", status=0)
    b = _store(tmp_path / "B", 2, n=500, machine="mech", status=0x4000)
    assert MapStore.open(a, read_only=True).estimate_levels == {"wheel"}
    merge_maps([a, b], tmp_path / "AB")
    assert MapStore.open(tmp_path / "AB", read_only=True).estimate_levels == {"machine", "wheel"}


def test_a_merge_keeps_the_exports_written_into_the_farm_map(tmp_path: Path) -> None:
    """``tractionecu map export FARM`` writes into FARM/export by default; the next merge (a day's new
    recordings) replaced the farm map and deleted them."""
    a, b = _store(tmp_path / "a", 1), _store(tmp_path / "b", 2)
    merge_maps([a], tmp_path / "farm")
    (tmp_path / "farm" / "export").mkdir()
    (tmp_path / "farm" / "export" / "map.tif").write_bytes(b"tif")
    merge_maps([a, b], tmp_path / "farm")
    assert (tmp_path / "farm" / "export" / "map.tif").read_bytes() == b"tif"
    assert merged_inputs(tmp_path / "farm") and (tmp_path / "farm" / "manifest.json").is_file()


def test_a_recording_beyond_the_farm_maps_range_is_named(tmp_path: Path) -> None:
    """A recording 67 km from the farm map's origin was replayed "ok" with map_samples 0 and left out of the
    farm map without a word ("farm map … from 1 recordings", exit 0)."""
    import io

    from tractionecu.fleet.runner import build_farm_map

    recs = [{"kind": "replay", "status": "ok", "machine": "a", "date": "2026-07-11", "path": "far/rec", "key": "k1",
             "map_samples": 0, "map_beyond_range": 1200}]
    out = io.StringIO()
    summary = build_farm_map(tmp_path, recs, stream=out)
    assert summary["recordings"] == 0
    assert "beyond the farm map's range (50 km from its origin)" in out.getvalue()
    assert "far/rec (1200 epochs)" in out.getvalue()


def test_a_recording_that_put_nothing_in_the_farm_map_is_named(tmp_path: Path) -> None:
    """A recording without its GNSS log was replayed "ok" (valid share 0) and left out of the farm map without
    a word: "replay: 2/2 recordings", then "farm map … from 1 recordings", exit 0."""
    import io

    from tractionecu.fleet.runner import build_farm_map

    recs = [{"kind": "replay", "status": "ok", "machine": "a", "date": "2026-07-11", "path": "m/nogps", "key": "k1",
             "map_samples": 0, "map_beyond_range": 0, "valid_share": 0.0},
            {"kind": "replay", "status": "ok", "machine": "a", "date": "2026-07-11", "path": "far/rec", "key": "k2",
             "map_samples": 0, "map_beyond_range": 1200, "valid_share": 0.9}]
    out = io.StringIO()
    assert build_farm_map(tmp_path, recs, stream=out)["recordings"] == 0
    said = out.getvalue()
    assert "fleet map: 1 recording(s) replayed put no sample in the farm map (no GNSS position, or no valid " \
           "estimate at one): m/nogps (valid estimates at 0% of steps)" in said
    assert said.count("far/rec") == 1                     # named once, as beyond the range
