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
