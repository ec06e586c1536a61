"""The draft sensor's reading with the implement lifted (:mod:`tractionecu.diagnose.lifted`)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from tractionecu.diagnose import engine
from tractionecu.diagnose.lifted import SHAPE_MIN_N, TRIM_S, lifted_draft_channel, shape_check


def _feat(offset, seed: int = 3, rate: float = 10.0, pull: float = 17000.0):
    """A 420-s recording at ``rate``: four passes in work (pull ``pull`` N) with lifted headlands of 20 s
    between them (and 6 s before the first pass); the draft pin reads the pull plus ``offset(t)`` plus
    300 N of noise, and pulls of 2 kN while the implement is being lowered or raised."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 420.0, 1.0 / rate)
    work = np.zeros(t.size, dtype=bool)
    for start in (6.0, 112.0, 218.0, 324.0):
        work |= (t >= start) & (t < start + 86.0)
    moving = np.zeros(t.size, dtype=bool)
    for e in np.nonzero(np.diff(work.astype(int)))[0]:
        moving |= np.abs(t - t[e]) < 1.5
    fdx = np.where(work, pull, 0.0) + np.where(moving, 2000.0, 0.0) + offset(t) + rng.normal(0.0, 300.0, t.size)
    frame = SimpleNamespace(t=t, fdx=fdx, work=work, n=t.size)
    fold = (np.floor(t / 30.0).astype(np.int64) % 2)
    return SimpleNamespace(frame=frame, fold=fold, valid=np.ones(t.size, dtype=bool))


def test_lifted_rows_leave_out_the_lowering_and_raising():
    feat = _feat(lambda t: 0.0 * t)
    ch = lifted_draft_channel(feat)
    assert ch is not None and ch.effects == frozenset({"draft_offset"})
    fr = feat.frame
    assert not fr.work[ch.tidx].any()
    edges = fr.t[np.nonzero(np.diff(fr.work.astype(int)))[0]]
    assert np.min(np.abs(ch.t[:, None] - edges[None, :])) >= TRIM_S - 0.1
    # Nominal: the lifted implement pulls nothing, so the residual is the reading (noise only here).
    r = ch.residual({}, np.ones(ch.m, dtype=bool))
    assert abs(float(np.mean(r))) < 100.0 and 250.0 < float(np.std(r)) < 350.0
    # A draft offset is predicted on these rows as b_0 + b_1 t.
    r2 = ch.residual({"draft_offset": {"b0_n": 500.0, "b1_npm": 60.0}}, np.ones(ch.m, dtype=bool))
    assert np.allclose(r - r2, 500.0 + ch.t)


def test_no_channel_without_draft_or_in_work_indication():
    feat = _feat(lambda t: 0.0 * t)
    feat.frame.work = None
    assert lifted_draft_channel(feat) is None
    assert shape_check(None) == {}


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_linear_drift_and_a_healthy_pin_follow_a_line(seed):
    drift = shape_check(lifted_draft_channel(_feat(lambda t: 300.0 * t / 60.0, seed=seed)))
    assert drift["linear"] and abs(drift["line_b1_npm"] - 300.0) < 30.0 and abs(drift["line_b0_n"]) < 150.0
    healthy = shape_check(lifted_draft_channel(_feat(lambda t: 0.0 * t, seed=seed)))
    assert healthy["linear"] and abs(healthy["line_b1_npm"]) < 30.0


def test_a_stepping_offset_is_not_a_line_and_is_located():
    sh = shape_check(lifted_draft_channel(_feat(lambda t: np.where(t >= 200.0, 1500.0, 0.0))))
    assert not sh["linear"] and sh["p"] < 1e-3 and sh["max_departure_n"] >= SHAPE_MIN_N
    a, b = sh["jump_between_s"]
    assert a < 200.0 < b
    assert sh["level_after_n"] - sh["level_before_n"] == pytest.approx(1500.0, abs=150.0)
    assert "No library effect is named" in sh["statement"]
    # The engine's rule: a draft-sensor offset is then not the library's b_0 + b_1 t.
    problem = SimpleNamespace(lifted_shape=sh)
    assert "does not follow b_0 + b_1 t" in engine._other_shape(problem, "draft_offset")
    assert engine._other_shape(problem, "axle_load_offset") == ""
    assert engine._other_shape(SimpleNamespace(lifted_shape={"linear": True}), "draft_offset") == ""


def test_a_small_step_below_the_sensor_tolerance_is_not_called_another_shape():
    sh = shape_check(lifted_draft_channel(_feat(lambda t: np.where(t >= 200.0, 150.0, 0.0))))
    assert sh["linear"]
