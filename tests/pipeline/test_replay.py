"""``tractionecu replay`` on a short simulated recording: the pipeline's run directory, scored by the evaluation side."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from tractionecu.cli.main import main
from tractionecu.evaluation.replay import score_replay
from tractionecu.evaluation.scoring import r_squared
from tractionecu.pipeline.replay import CSV_COLUMNS, replay, replay_to_dir
from tractionecu.recording.reader import read_recording
from tractionecu.sim import scenarios
from tractionecu.sim.simulator import simulate
from tractionecu.sim.writer import write_recording


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    out = tmp_path_factory.mktemp("rec")
    scn = scenarios.get("paper-three-soils", seed=3, duration_s=40.0)
    write_recording(scn, simulate(scn), out)
    return out


def test_replay_writes_estimates_scorecard_and_config(rec, tmp_path):
    seen = []
    res, recording, result = replay_to_dir(rec, tmp_path / "run", on_estimate=seen.append)
    run = tmp_path / "run"
    assert not (run / "scorecard.json").exists()          # the core does not score
    res.update(score_replay(run, recording, result.arrays, plot=False, summary=res))
    assert len(seen) == res["steps"] > 3500
    with open(run / "estimates.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    assert tuple(rows[0]) == CSV_COLUMNS and len(rows) == res["steps"] + 1
    sc = json.loads((run / "scorecard.json").read_text())
    for key in ("mu_mean_abs_rel_error", "rho_s_mean_abs_error", "r2_mu_curve", "reconvergence_s", "nis_within_95"):
        assert key in sc
    assert sc["mu_mean_abs_rel_error"] < 0.02
    assert 0.85 < sc["nis_within_95"] <= 1.0
    assert "stubble-firm" in sc["r2_mu_curve"]
    assert (run / "config.toml").read_text().count("[estimator]") == 1
    # the last estimate is valid and the filter ran every step at 100 Hz
    assert seen[-1].valid
    assert np.allclose(np.diff([e.t for e in seen]), 0.01, rtol=0, atol=1e-6)   # epoch-second floats


def test_replay_is_deterministic(rec, tmp_path):
    replay_to_dir(rec, tmp_path / "a")
    replay_to_dir(rec, tmp_path / "b")
    assert (tmp_path / "a" / "estimates.csv").read_bytes() == (tmp_path / "b" / "estimates.csv").read_bytes()


def test_in_memory_replay_equals_the_run_directory(rec, tmp_path):
    """Diagnosis reads the replay in memory: the same estimates as the written run, no files."""
    _, _, written = replay_to_dir(rec, tmp_path / "run", write_map=False)
    before = set(tmp_path.iterdir())
    mem = replay(read_recording(rec))
    assert set(tmp_path.iterdir()) == before
    for key in ("t", "mu", "slip", "rho_s", "a", "P_diag", "status", "valid"):
        np.testing.assert_array_equal(mem.arrays[key], written.arrays[key])
    assert mem.arrays["soil_class"] == written.arrays["soil_class"]


def test_cli_replay_prints_the_scorecard(rec, tmp_path, capsys):
    assert main(["replay", str(rec), "--out", str(tmp_path / "cli"), "--rate", "50"]) == 0
    out = capsys.readouterr().out
    assert "mu_mean_abs_rel_error" in out and "r2_mu_curve[stubble-firm]" in out
    assert (tmp_path / "cli" / "estimates.csv").is_file()


def test_cli_replay_missing_recording_is_an_error(tmp_path, capsys):
    assert main(["replay", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 1
    assert "nope" in capsys.readouterr().err


def test_r_squared():
    y = np.linspace(0, 1, 11)
    assert r_squared(y, y) == 1.0
    assert r_squared(np.full(11, y.mean()), y) == pytest.approx(0.0)


def test_grid_ends_with_the_wheel_speeds_whatever_runs_on(rec):
    """A signal that runs on long after the drive-train (or a stray late time stamp) asks for no steps."""
    from tractionecu.pipeline.replay import recording_grid
    from tractionecu.pipeline.steps import GRID_MAX_GAP_S

    r = read_recording(rec)
    ws_end = float(r.signals["WheelSpeed_FL"].t[-1])
    late = r.signals["DraftForce"]
    late.t = np.append(late.t, ws_end + 3600.0 * 24 * 365)   # one draft sample a year later
    late.value = np.append(late.value, late.value[-1])
    late.sa = np.append(late.sa, late.sa[-1])
    grid = recording_grid(r, 100.0)
    assert grid[-1] <= ws_end + GRID_MAX_GAP_S
