"""Replay writes the map (tiles + manifest) and, with truth, map_scorecard.json."""

import json

import numpy as np

from tractionecu.cli.main import main
from tractionecu.mapping.store import MapStore


def test_replay_writes_tiles_and_map_scorecard(tmp_path):
    rec, run = tmp_path / "rec", tmp_path / "run"
    assert main(["simulate", "--scenario", "paper-three-soils", "--out", str(rec), "--duration", "45"]) == 0
    assert main(["replay", str(rec), "--out", str(run)]) == 0
    card = json.loads((run / "map_scorecard.json").read_text())
    for k in ("map_soil_accuracy", "map_a_rmse", "map_rho_s_rmse"):
        assert np.isfinite(card[k])
    store = MapStore.open(run / "map", read_only=True)
    mean, *_ = store.mean_grid("a")
    assert np.isfinite(mean).sum() > 50           # the first pass is mapped
    assert 0.5 < np.nanmedian(mean) < 0.95        # a of stubble soils
    # A second replay into the same directory replaces the map instead of averaging into it.
    n1 = int(np.isfinite(mean).sum())
    assert main(["replay", str(rec), "--out", str(run)]) == 0
    mean2, *_ = MapStore.open(run / "map", read_only=True).mean_grid("a")
    assert int(np.isfinite(mean2).sum()) == n1
    assert np.allclose(mean, mean2, equal_nan=True)


def test_a_machine_without_a_draft_sensor_is_mapped_and_flagged(tmp_path, make_recording):
    """A mechanical tractor without a draft sensor reports no ρ_s (issue 14), and its NaN rejected every sample
    of the replay's map: "0 of 450 GNSS epochs mapped" on 45 s of mechanical-no-draft (the service, which drops
    a layer's NaN, mapped it). The map now holds its μ and a, no ρ_s, and says they are machine-level."""
    from tractionecu.mapping.export import export_geojson

    rec, run = make_recording("mechanical-no-draft", 11, 45.0), tmp_path / "run"
    assert main(["replay", str(rec), "--out", str(run)]) == 0
    store = MapStore.open(run / "map", read_only=True)
    assert store.estimate_levels == {"machine"}
    mu, *_ = store.mean_grid("mu")
    rho, *_ = store.mean_grid("rho_s")
    assert np.isfinite(mu).sum() > 50 and not np.isfinite(rho).any()
    doc = json.loads(export_geojson(store, tmp_path / "map.geojson").read_text())
    assert list(doc["estimate_levels"]) == ["machine"] and "no per-wheel precision" in doc["estimate_levels"]["machine"]
