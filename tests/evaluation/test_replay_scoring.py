"""A replay of a simulated recording scored against its truth (estimator and map scorecards).

The "estimates" here are the truth itself, so the estimator scorecard is exact
and the map holds the true soils: what is tested is the plumbing (which files
are written, with what, and when), not the estimator.
"""

import importlib.util
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from tractionecu.evaluation.map_truth import field_from_truth
from tractionecu.evaluation.replay import score_replay
from tractionecu.evaluation.scoring import read_truth
from tractionecu.mapping.from_replay import write_replay_map
from tractionecu.model.vehicle import N_STATE
from tractionecu.recording.reader import read_recording
from tractionecu.sim import scenarios
from tractionecu.sim.simulator import simulate
from tractionecu.sim.writer import write_recording


@pytest.fixture(scope="module")
def rec_dir(tmp_path_factory):
    """45 s of the three-soil field: the first pass crosses a soil boundary."""
    scn = scenarios.get("paper-three-soils", seed=3, duration_s=45.0)
    out = tmp_path_factory.mktemp("rec")
    counts = write_recording(scn, simulate(scn), out)
    assert counts and (out / "truth.toml").is_file()
    return out


def truth_arrays(rec):
    """Replay-shaped arrays (keys as ``tractionecu replay`` builds them) holding the truth."""
    tr = read_truth(rec.truth_csv_path, rec.truth_toml_path)
    n = tr.t.size
    var = np.full((n, N_STATE), 1e-4)
    return {"t": tr.t, "mu": tr.mu, "slip": tr.slip, "omega": np.zeros((n, 4)), "P_diag": var,
            "nis_dof": np.full(n, 2, dtype=np.int64), "status": np.zeros(n, dtype=np.int64),
            "valid": np.ones(n, dtype=bool), "soil_class": [tr.soils[s]["soil_class"] for s in tr.soil_name],
            "rho_s": tr.rho_s, "a": tr.a, "v": tr.v, "nis": np.full(n, 2.0), "adapt": np.ones(n)}


def test_truth_scores_itself_perfectly_and_both_scorecards_are_written(rec_dir, tmp_path):
    rec = read_recording(rec_dir)
    arrays = truth_arrays(rec)
    summary = write_replay_map(tmp_path, rec, arrays)
    # the core writes the map and scores nothing
    assert summary["map_samples"] > 0 and "map_scorecard" not in summary
    assert not (tmp_path / "map_scorecard.json").exists()
    summary["realtime_factor"] = 123.0
    before = dict(summary)
    plot = importlib.util.find_spec("matplotlib") is not None
    add = score_replay(tmp_path, rec, arrays, plot=plot, summary=summary)
    assert summary == before
    assert set(add) == {"scorecard", "scorecard_json", "map_scorecard"} | ({"plots"} if plot else set())
    if plot:
        assert add["plots"] == [str(tmp_path / name) for name in
                                ("fig6_mu_rho.png", "fig5_mu_curves.png", "fig_efficiency.png", "report.html")]
    sc = add["scorecard"]
    assert sc["mu_mean_abs_error"] == 0.0 and sc["rho_s_mean_abs_error"] == 0.0
    assert sc["reconvergence_s"] == 0.0 and sc["n_soil_changes"] >= 1
    assert set(sc["r2_mu_curve"]) >= {"stubble-firm"}
    assert all(r2 > 0.999 for r2 in sc["r2_mu_curve"].values())
    assert json.loads((tmp_path / "scorecard.json").read_text()) == {**json.loads(json.dumps(sc)),
                                                                      "realtime_factor": 123.0}
    assert add["scorecard_json"] == str(tmp_path / "scorecard.json")
    card = add["map_scorecard"]
    assert json.loads((tmp_path / "map_scorecard.json").read_text()) == json.loads(json.dumps(card))
    assert card["map_cells_scored"] > 50
    assert card["map_soil_accuracy"] > 0.97 and card["map_a_rmse"] < 0.05


def test_a_step_without_estimate_does_not_blank_the_scorecard(rec_dir, tmp_path):
    """Three NaN steps of 3701 (a filter restarting after a CAN gap) made mu_mean_abs_error,
    rho_s_mean_abs_error and mu_mean_bias NaN ("n/a: no rho_s reported"), and scorecard.json held bare NaN,
    which strict JSON parsers refuse."""
    rec = read_recording(rec_dir)
    arrays = truth_arrays(rec)
    arrays["mu"] = arrays["mu"].copy()
    arrays["rho_s"] = arrays["rho_s"].copy()
    arrays["mu"][1000:1003] = np.nan
    arrays["rho_s"][1000:1003] = np.nan
    add = score_replay(tmp_path, rec, arrays, plot=False, summary={})
    sc = add["scorecard"]
    assert sc["mu_mean_abs_error"] == 0.0 and sc["rho_s_mean_abs_error"] == 0.0
    assert sc["mu_mean_bias"] == [0.0] * 4 and sc["steps_without_estimate"] == 3
    text = (tmp_path / "scorecard.json").read_text()
    assert "NaN" not in text and json.loads(text)["mu_mean_abs_error"] == 0.0


def test_no_map_scorecard_without_a_written_map(rec_dir, tmp_path):
    rec = read_recording(rec_dir)
    add = score_replay(tmp_path, rec, truth_arrays(rec), plot=False, summary={})
    assert set(add) == {"scorecard", "scorecard_json"}
    assert "realtime_factor" not in json.loads((tmp_path / "scorecard.json").read_text())
    assert not (tmp_path / "map_scorecard.json").exists()


def test_recording_without_truth_adds_nothing_but_plots(rec_dir, tmp_path):
    bare = tmp_path / "rec"
    shutil.copytree(rec_dir, bare)
    arrays = truth_arrays(read_recording(rec_dir))
    (bare / "truth.csv").unlink()
    (bare / "truth.toml").unlink()
    rec = read_recording(bare)
    run = tmp_path / "run"
    summary = write_replay_map(run, rec, arrays)
    assert score_replay(run, rec, arrays, plot=False, summary=summary) == {}
    assert not (run / "scorecard.json").exists() and not (run / "map_scorecard.json").exists()
    pytest.importorskip("matplotlib")
    add = score_replay(run, rec, arrays, plot=True, summary=summary)
    # no truth: no Fig. 5; the efficiency figure and the HTML report need no truth
    assert add == {"plots": [str(run / name) for name in ("fig6_mu_rho.png", "fig_efficiency.png", "report.html")]}
    assert all(Path(f).stat().st_size > 0 for f in add["plots"])


def test_field_rebuilt_from_truth_toml(rec_dir):
    fld = field_from_truth(rec_dir / "truth.toml")
    ref = scenarios.get("paper-three-soils").field
    x = np.linspace(-10, 300, 200)
    y = np.linspace(-5, 30, 200)
    assert np.array_equal(fld.soil_index(x, y), ref.soil_index(x, y))


def test_replay_map_keeps_only_the_gnss_epochs_the_gate_accepted(rec_dir, tmp_path):
    rec = read_recording(rec_dir)
    arrays = truth_arrays(rec)
    n = len(rec.gps)
    full = write_replay_map(tmp_path / "all", rec, arrays)["map_samples"]
    assert write_replay_map(tmp_path / "ones", rec, arrays, gps_mask=np.ones(n, bool))["map_samples"] == full
    assert write_replay_map(tmp_path / "none", rec, arrays, gps_mask=np.zeros(n, bool))["map_samples"] == 0
    half = write_replay_map(tmp_path / "half", rec, arrays, gps_mask=np.arange(n) % 2 == 0)["map_samples"]
    assert 0.4 * full < half < 0.6 * full


def test_a_truth_file_of_another_tool_is_left_unscored_not_fatal(rec_dir, tmp_path):
    """A recording holding another simulator's truth.csv (no column 'a') and a truth.toml that is not TOML:
    replay raised KeyError after writing its estimates; the scoring is now said to be left out."""
    other = tmp_path / "rec"
    shutil.copytree(rec_dir, other)
    arrays = truth_arrays(read_recording(rec_dir))
    (other / "truth.csv").write_text("t,speed,mu\n0.0,1.0,0.5\n", encoding="utf-8")
    (other / "truth.toml").write_text("x = [\n", encoding="utf-8")
    rec = read_recording(other)
    run = tmp_path / "run"
    summary = write_replay_map(run, rec, arrays)
    add = score_replay(run, rec, arrays, plot=False, summary=summary)
    assert set(add) == {"truth_skipped"} and not (run / "scorecard.json").exists()
    said = "\n".join(add["truth_skipped"])
    assert "truth.csv: not scored: truth.csv is not the truth file of tractionecu simulate (no column" in said
    assert "a, soil_id" in said and "truth.toml: not scored" in said
