"""The daemon's incremental step assembly gives exactly replay's estimates."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tractionecu.cli.replay import build_grid, replay
from tractionecu.config import load_vehicle
from tractionecu.estimation.estimator import Estimator
from tractionecu.recording.reader import read_recording
from tractionecu.service.steps import GROUPS, StepAssembler


def _events(rec) -> list[tuple[float, int, str, object]]:
    """Every sample of the recording as (t, order, kind, payload), in time order."""
    ev: list[tuple[float, int, str, object]] = []
    n = 0
    for names in GROUPS.values():
        s0 = rec.signals[names[0]]
        for i in range(len(s0)):
            ev.append((float(s0.t[i]), n, "sig", {nm: float(rec.signals[nm].value[i]) for nm in names}))
            n += 1
    for i in range(len(rec.gps)):
        ev.append((float(rec.gps.t[i]), n, "v", float(rec.gps.speed[i])))
        n += 1
    ev.sort(key=lambda e: (e[0], e[1]))
    return ev


def test_assembler_matches_replay_exactly(short_recording: Path, tmp_path: Path) -> None:
    got_replay = []
    replay(short_recording, tmp_path / "run", on_estimate=got_replay.append)

    rec = read_recording(short_recording)
    grid = build_grid(rec, 100.0)
    est = Estimator(load_vehicle(short_recording / "vehicle.toml"))
    asm = StepAssembler()
    ev = _events(rec)
    j = 0
    mine = []
    for t in grid.tolist():
        while j < len(ev) and ev[j][0] <= t + 0.05:  # samples arrive up to 50 ms early, as with a lag
            _, _, kind, payload = ev[j]
            if kind == "sig":
                asm.push_signals(ev[j][0], payload)  # type: ignore[arg-type]
            else:
                asm.push_speed(ev[j][0], payload)  # type: ignore[arg-type]
            j += 1
        inputs, meas = asm.take(t)
        mine.append(est.step(t, inputs, meas))

    assert len(mine) == len(got_replay)
    assert asm.counts["late"] == 0
    for a, b in zip(mine, got_replay):
        assert a.t == b.t
        assert a.status == b.status
        np.testing.assert_array_equal(a.mu, b.mu)
        np.testing.assert_array_equal(a.slip, b.slip)
        assert a.rho_s == b.rho_s or (np.isnan(a.rho_s) and np.isnan(b.rho_s))
        assert a.a == b.a or (np.isnan(a.a) and np.isnan(b.a))
    assert sum(e.valid for e in mine) > len(mine) // 3, "the estimator never converged on the fixture"
