"""What several benchmarks share: the load-average line printed beside their timings, and a simulated
recording written whole."""

from __future__ import annotations

import os
import shutil
from pathlib import Path


def load_line() -> str:
    """The machine's load averages and core count: on a shared machine a timing measures the other jobs too."""
    a, b, c = os.getloadavg()
    return f"load average {a:.2f} {b:.2f} {c:.2f} on {os.cpu_count()} cores"


def simulate_recording(out: Path, seed: int, duration: float, scenario: str = "paper-three-soils") -> None:
    """Simulate ``scenario`` (``seed``, ``duration`` [s]) into the recording directory ``out``, written beside it
    first and moved in place whole (a worker stopped half-way leaves no half recording)."""
    from tractionecu.sim import scenarios
    from tractionecu.sim.simulator import simulate
    from tractionecu.sim.writer import write_recording

    scn = scenarios.get(scenario, seed=seed, duration_s=duration)
    tmp = out.with_name(out.name + ".tmp")
    if tmp.exists():
        shutil.rmtree(tmp)
    write_recording(scn, simulate(scn), tmp)
    os.replace(tmp, out)
