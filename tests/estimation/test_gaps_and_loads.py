"""Regressions: a front-axle load of 0 N divided by zero; a time jump in a capture asked replay for
an absurd grid (hundreds of TiB); the estimator now restarts after a gap instead of sub-stepping it."""


import numpy as np
import pytest

from tractionecu.pipeline.replay import recording_grid
from tractionecu.pipeline.rundir import replay_to_dir
from tractionecu.config import VehicleParams
from tractionecu.errors import RecordingError
from tractionecu.estimation.estimator import INPUT_REJECTED, NOT_CONVERGED, Estimator, EstimatorConfig
from tractionecu.recording.reader import read_recording
from tractionecu.sim import scenarios
from tractionecu.sim.simulator import simulate
from tractionecu.sim.writer import write_recording

P = VehicleParams()
FZF = P.static_front_load_n()


def _steps(est, n, t0=0.0, fzf=FZF):
    e = None
    for k in range(n):
        t = t0 + 0.01 * k
        e = est.step(t, {"Md": [2000.0, 2000.0, 3000.0, 3000.0], "Fzf": fzf, "Fdx": 12000.0},
                     {"omega": [3.2, 3.2, 3.2, 3.2], "v": 2.4} if k % 10 == 0 else {"omega": [3.2, 3.2, 3.2, 3.2]})
    return e


@pytest.mark.parametrize("bad", [0.0, -5.0, P.weight_n, 2 * P.weight_n])
def test_front_load_outside_the_axles_is_rejected(bad):
    est = Estimator(P, EstimatorConfig())
    _steps(est, 50)
    with np.errstate(all="raise"):       # no division by zero anywhere
        e = est.step(0.5, {"Fzf": bad}, {"omega": [3.2] * 4})
    assert e.status & INPUT_REJECTED
    assert np.isfinite(e.mu).all()


def test_gap_restarts_the_filter_instead_of_substepping():
    est = Estimator(P, EstimatorConfig())
    _steps(est, 300)
    e = _steps(est, 1, t0=3.0 + 3600.0 * 24 * 365)   # a year later
    assert e.status & NOT_CONVERGED and est.counters["gap_resets"] == 1
    e = _steps(est, 300, t0=3.0 + 3600.0 * 24 * 365 + 0.01)
    assert np.isfinite(e.mu).all() and e.v == pytest.approx(2.4, abs=0.2)


@pytest.fixture(scope="module")
def jumped(tmp_path_factory):
    """A short recording whose second half was logged ~23 years later (a logger clock jump)."""
    root = tmp_path_factory.mktemp("jump")
    scn = scenarios.get("paper-three-soils", seed=3, duration_s=12.0)
    write_recording(scn, simulate(scn), root / "rec")
    lines = (root / "rec" / "can.log").read_text().splitlines()
    half = len(lines) // 2
    out = []
    for i, ln in enumerate(lines):
        if i >= half:
            ts, rest = ln.split(")", 1)
            ln = f"({float(ts[1:]) + 7.3e8:.6f}){rest}"
        out.append(ln)
    (root / "rec" / "can.log").write_text("\n".join(out) + "\n")
    (root / "rec" / "gps.nmea").unlink()
    (root / "rec" / "truth.csv").unlink()
    return root / "rec"


def test_replay_grid_skips_the_jump(jumped):
    rec = read_recording(jumped)
    grid = recording_grid(rec, 100.0)
    assert grid.size < 1300                      # ≈ 12 s of data at 100 Hz, not 23 years
    with pytest.raises(RecordingError, match="time jumps"):
        rec.table(100.0)


def test_replay_runs_across_the_jump(jumped, tmp_path):
    res, _, _ = replay_to_dir(jumped, tmp_path / "run", write_map=False)
    assert res["steps"] < 1300
    assert res["counters"]["gap_resets"] == 1
