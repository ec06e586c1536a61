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


_SERVICE_MAP = """
import sys
from tractionecu.mapping.store import MapStore
st = MapStore(sys.argv[1], 47.88, 11.0)
st.add(47.8801, 11.0001, {"a": 0.7}, 1.7e9, fix_quality=4, hdop=0.8)
st.flush(force=True)
print("open", flush=True)
sys.stdin.read()
st.close()
"""


def test_a_replay_never_replaces_a_map_open_for_writing(tmp_path, short_recording, capsys):
    """``replay --out D`` while a service wrote its map in ``D/map`` (its ``map.directory`` there) deleted that
    map and made its own in its place; the service went on writing its tiles, in its own frame, into the
    replay's map (the tiles it held only on disk and its track so far lost).  A map another process has open
    for writing is now refused by name, before the replay runs, and left as it was."""
    import subprocess
    import sys

    from tractionecu.mapping.tiles import MANIFEST_NAME

    out = tmp_path / "out"
    out.mkdir()
    service = subprocess.Popen([sys.executable, "-c", _SERVICE_MAP, str(out / "map")], stdin=subprocess.PIPE,
                               stdout=subprocess.PIPE, text=True)
    try:
        assert service.stdout.readline().strip() == "open"
        before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
        assert main(["replay", str(short_recording), "--out", str(out)]) == 1
        assert "map is open for writing by another process" in capsys.readouterr().err
        assert {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
        assert not (out / "estimates.csv").exists()
    finally:
        service.communicate("", timeout=30)
    assert (out / "map" / MANIFEST_NAME).is_file()
    assert main(["replay", str(short_recording), "--out", str(out)]) == 0   # the map closed: a replay replaces it
