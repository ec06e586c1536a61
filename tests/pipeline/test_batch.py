"""The batch replay (tractionecu.pipeline.batch) against the step path: the same estimates, to 1e-9.

The contract of the batch path: every estimate column equal to the step path's
(:func:`tractionecu.pipeline.replay.replay`) within 1e-9, the integer and text columns exactly, on a
seeded `paper-three-soils` recording; the selection of rows (1 Hz, the map's steps) and the marking of a
lost filter's estimates as the step path's sink makes them.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from tractionecu.pipeline.batch import BatchSink, max_differences, replay_batch, replay_batch_rows
from tractionecu.estimation.estimator import FILTER_LOST
from tractionecu.pipeline.replay import _Sink, replay
from tractionecu.pipeline.rundir import replay_to_dir
from tractionecu.recording.reader import read_recording

TOL = 1e-9


@pytest.fixture(scope="module")
def three_soils(make_recording):
    """20 s of `paper-three-soils` (seed 0): start-up, convergence, steady work on the first soil."""
    return make_recording("paper-three-soils", 0, 20.0)


@pytest.fixture(scope="module")
def step_result(three_soils):
    return replay(read_recording(three_soils))


def _assert_equal(step: dict, batch: dict) -> dict:
    diff = max_differences(step, batch)
    assert diff, "no column compared"
    bad = {k: v for k, v in diff.items() if not v <= TOL}
    assert not bad, f"columns differing by more than {TOL}: {bad}"
    return diff


def test_batch_equals_step_path_in_every_column(three_soils, step_result):
    batch = replay_batch(read_recording(three_soils))
    a, b = step_result.arrays, batch.arrays
    assert a["t"].size > 1500 and np.array_equal(a["t"], b["t"])
    diff = _assert_equal(a, b)
    for col in ("mu", "rho_s", "slip", "v", "omega", "P_diag", "nis", "adapt", "sigma_mu", "sigma_rho_s",
                "radius_scale", "radius_applied", "status", "valid", "nis_dof", "soil_class"):
        assert col in diff
    # the run converged and estimated (not a comparison of NaN with NaN)
    assert a["valid"].sum() > 500 and np.isfinite(b["mu"][a["valid"]]).all()
    assert [c.path if c is not None else "" for c in a["curve"]] == b["curve_path"]
    assert batch.counters == step_result.counters
    assert np.array_equal(batch.gps_mask, step_result.gps_mask)


def test_batch_equals_step_path_on_an_engine_driven_tractor(make_recording):
    """The machine-level estimator (engine-driven vehicle file) through the batch path: the same estimates."""
    rec = read_recording(make_recording("mechanical-three-soils", 0, 10.0))
    a, b = replay(rec).arrays, replay_batch(rec).arrays
    assert a["t"].size > 800 and np.isfinite(b["mu"]).any()
    _assert_equal(a, b)


def test_batch_streamed_from_the_path_equals_step_path(three_soils, step_result):
    """Given the recording's path, the batch path decodes the capture once (the survey holds the decoded
    blocks of the replay's signals), or, over the bound or with none (``hold_bytes=0``), a survey and then
    block by block again (as replay_to_dir): the same estimates bit for bit, equal to the step path's."""
    once = replay_batch(three_soils)
    assert once.decode.startswith("one pass:"), once.decode
    streamed = replay_batch(three_soils, hold_bytes=0)
    assert streamed.decode.startswith("streamed:") and "bound 0" in streamed.decode
    over = replay_batch(three_soils, hold_bytes=20_000)
    assert over.decode.startswith("streamed:") and "passed the bound" in over.decode
    for res in (once, streamed, over):
        _assert_equal(step_result.arrays, res.arrays)
        assert res.counters == step_result.counters and np.array_equal(res.gps_mask, step_result.gps_mask)
    d = max_differences(once.arrays, streamed.arrays)
    assert "curve_path" in d and max(d.values()) == 0.0
    rows = [replay_batch_rows(three_soils, hold_bytes=b) for b in (None, 0)]
    assert rows[0]["decode"].startswith("one pass:") and rows[1]["decode"].startswith("streamed:")
    for key in ("rows", "map"):
        d = max_differences(rows[0][key], rows[1][key])
        assert d and max(d.values()) == 0.0, key
    for key in ("steps", "sim_seconds", "valid_steps", "steps_finite", "counters", "gnss", "loop"):
        assert rows[0][key] == rows[1][key], key
    assert repr(rows[0]["radius_calibration"]) == repr(rows[1]["radius_calibration"])
    assert np.array_equal(rows[0]["gps_mask"], rows[1]["gps_mask"])


def test_batch_rows_are_the_step_paths_rows_at_the_rate_and_the_maps(three_soils, step_result, tmp_path):
    out = replay_batch_rows(three_soils, estimate_rate_hz=1.0)
    a = step_result.arrays
    bucket = np.floor(a["t"] * 1.0)
    first = np.flatnonzero(np.concatenate([[True], bucket[1:] != bucket[:-1]]))
    rows = out["rows"]
    assert np.array_equal(rows["t"], a["t"][first]) and rows["t"].size >= 19
    _assert_equal({k: (v[first] if isinstance(v, np.ndarray) else [v[i] for i in first]) for k, v in a.items()},
                  rows)
    assert out["steps"] == a["t"].size and out["valid_steps"] == int(a["valid"].sum())
    # the map's steps: those the step path's replay_to_dir keeps for its map
    _, _, res = replay_to_dir(three_soils, tmp_path / "run", keep_arrays=False, write_map=True, compiled=False)
    m = res.arrays
    assert np.array_equal(out["map"]["t"], m["t"]) and m["t"].size > 100
    _assert_equal(m, out["map"])


def test_the_sink_marks_a_lost_filters_estimates_as_the_step_path(three_soils):
    """A lost filter (lost_since on an estimate) makes the estimates since then not valid with FILTER_LOST,
    across block boundaries: the batch sink and the step path's sink on the same estimates."""
    es = []
    replay(read_recording(three_soils), on_estimate=es.append)
    k = 1700
    es[k] = dataclasses.replace(es[k], lost_since=es[600].t)      # back across several blocks of 256
    ref = _Sink(keep_all=True)
    got = BatchSink(keep_all=True, block=256)
    for e in es:
        ref.keep(e)
        got.keep(e)
    ref.close()
    got.close()
    a, b = ref.arrays(), got.arrays()
    lost = (a["status"] & FILTER_LOST) != 0
    assert lost[600:1701].all() and not lost[:600].any() and not lost[1701:].any() and not a["valid"][lost].any()
    _assert_equal(a, b)


def test_max_differences_sees_a_difference_and_a_nan_mismatch():
    a = {"x": np.array([1.0, 2.0, math.nan]), "s": ["a", "b", "c"], "n": np.array([1, 2, 3])}
    assert max_differences(a, a) == {"x": 0.0, "s": 0.0, "n": 0.0}
    b = {"x": np.array([1.0, 2.0 + 1e-6, math.nan]), "s": ["a", "b", "c"], "n": np.array([1, 2, 3])}
    assert max_differences(a, b)["x"] == pytest.approx(1e-6)
    c = {"x": np.array([1.0, 2.0, 0.0]), "s": ["a", "x", "c"], "n": np.array([1, 2, 4])}
    d = max_differences(a, c)
    assert d["x"] == math.inf and d["s"] == math.inf and d["n"] == 1.0
