"""Replay writes the map (tiles + manifest) and, with truth, map_scorecard.json."""

import json

import numpy as np

from tractionecu.cli.main import main
from tractionecu.mapping.from_replay import field_from_truth
from tractionecu.mapping.store import MapStore
from tractionecu.sim import scenarios


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


def test_field_rebuilt_from_truth_toml(tmp_path):
    rec = tmp_path / "rec"
    assert main(["simulate", "--scenario", "paper-three-soils", "--out", str(rec), "--duration", "2"]) == 0
    fld = field_from_truth(rec / "truth.toml")
    ref = scenarios.get("paper-three-soils").field
    x = np.linspace(-10, 300, 200)
    y = np.linspace(-5, 30, 200)
    assert np.array_equal(fld.soil_index(x, y), ref.soil_index(x, y))
