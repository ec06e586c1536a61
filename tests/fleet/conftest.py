"""Simulated recordings for the fleet tests, written once per session (seeded)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

pytest.importorskip("pyarrow")
pytest.importorskip("distributed")


def simulate(out: Path, *, scenario: str = "paper-three-soils", seed: int = 0, duration_s: float | None = 20.0,
             radius_eps: float | None = None) -> Path:
    """Write one simulated recording to ``out``: a named scenario cut to ``duration_s``, or with
    ``radius_eps`` the transport-then-work run whose tyres roll (1 + eps) x the nominal radius."""
    from tractionecu.sim import scenarios
    from tractionecu.sim.simulator import simulate as run
    from tractionecu.sim.writer import write_recording

    if radius_eps is not None:
        from tractionecu.evaluation.coverage import radius_scenario

        scn = radius_scenario(radius_eps, seed=seed)
    else:
        scn = scenarios.get(scenario, seed=seed, duration_s=duration_s)
    write_recording(scn, run(scn), out)
    return out


@pytest.fixture(scope="session")
def short_recordings(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Two 20 s `paper-three-soils` recordings (seeds 1 and 2) on the same field."""
    d = tmp_path_factory.mktemp("fleet_short")
    return {name: simulate(d / name, seed=seed) for name, seed in (("s1", 1), ("s2", 2))}


@pytest.fixture()
def fleet_tree(tmp_path: Path, short_recordings: dict[str, Path]) -> Path:
    """A directory tree ``<machine>/<date>/<recording>``: two machines, one recording each, and one
    recording that cannot be read."""
    root = tmp_path / "season"
    shutil.copytree(short_recordings["s1"], root / "tractor-a" / "2026-07-10" / "run1")
    shutil.copytree(short_recordings["s2"], root / "tractor-b" / "2026-07-11" / "run1")
    bad = root / "tractor-b" / "2026-07-12" / "broken"
    bad.mkdir(parents=True)
    (bad / "can.log").write_text("this is not a CAN capture\n", encoding="utf-8")
    return root


@pytest.fixture(scope="session")
def radius_season(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two machines on two dates (transport-then-work runs, seeded): tractor-a's tyres roll 3 % larger on
    the second date (a changed tyre or pressure), tractor-b's stay nominal."""
    root = tmp_path_factory.mktemp("fleet_radius") / "season"
    plan = (("tractor-a", "2026-07-10", 0.0, 10), ("tractor-a", "2026-08-10", 0.03, 11),
            ("tractor-b", "2026-07-10", 0.0, 12), ("tractor-b", "2026-08-10", 0.0, 13))
    for machine, date, eps, seed in plan:
        simulate(root / machine / date / "run", seed=seed, radius_eps=eps)
    return root
