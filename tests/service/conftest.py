"""Fixtures of the service tests: a short simulated recording, shared per session."""

from __future__ import annotations

from pathlib import Path

import pytest

from tractionecu.sim import scenarios
from tractionecu.sim.simulator import simulate
from tractionecu.sim.writer import write_recording

SHORT_S = 12.0
"""Length of the shared recording [s]: acceleration, then steady work on the first soil."""


@pytest.fixture(scope="session")
def short_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 12 s ``paper-straight`` recording (can.log, gps.nmea, vehicle.toml, truth)."""
    out = tmp_path_factory.mktemp("rec") / "paper-straight"
    scn = scenarios.get("paper-straight", seed=3, duration_s=SHORT_S)
    write_recording(scn, simulate(scn), out)
    return out
