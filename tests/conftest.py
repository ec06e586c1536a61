"""Suite-wide pytest hooks.

`vcan`-marked tests need a real SocketCAN interface `vcan0`. They run inside
the User-Mode Linux guest started by `tests/vcan/run-in-vcan.sh` (which sets
TECU_IN_VCAN_GUEST=1) or on a host whose kernel has CAN and a vcan0, and are
skipped with a reason everywhere else.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import pytest

VCAN_SKIP_REASON = (
    "needs SocketCAN with vcan0; run inside the UML guest: "
    "tests/vcan/run-in-vcan.sh .venv/bin/python -m pytest -m vcan tests"
)


def socketcan_available() -> bool:
    """True inside the vcan guest, or where AF_CAN works and vcan0 exists."""
    if os.environ.get("TECU_IN_VCAN_GUEST") == "1":
        return True
    try:
        sock = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    except (AttributeError, OSError):
        return False
    sock.close()
    return os.path.exists("/sys/class/net/vcan0")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if socketcan_available():
        return
    skip = pytest.mark.skip(reason=VCAN_SKIP_REASON)
    for item in items:
        if item.get_closest_marker("vcan") is not None:
            item.add_marker(skip)


SHORT_S = 12.0
"""Length of the shared recording [s]: acceleration, then steady work on the first soil."""


@pytest.fixture(scope="session")
def make_recording(tmp_path_factory: pytest.TempPathFactory):
    """``make_recording(scenario, seed, duration_s)``: a simulated recording directory (can.log, gps.nmea,
    vehicle.toml, truth), made once per session for each argument set."""
    from tractionecu.sim import scenarios
    from tractionecu.sim.simulator import simulate
    from tractionecu.sim.writer import write_recording

    made: dict[tuple, Path] = {}

    def make(scenario: str, seed: int, duration_s: float | None = None) -> Path:
        key = (scenario, seed, duration_s)
        if key not in made:
            out = tmp_path_factory.mktemp("rec") / scenario
            scn = scenarios.get(scenario, seed=seed, duration_s=duration_s)
            write_recording(scn, simulate(scn), out)
            made[key] = out
        return made[key]

    return make


@pytest.fixture(scope="session")
def short_recording(make_recording) -> Path:
    """A 12 s ``paper-straight`` recording: acceleration, then steady work on the first soil."""
    return make_recording("paper-straight", 3, SHORT_S)


_HOLD_LOCK = """
import sys
from tractionecu.mapping.tiles import lock_directory
lock = lock_directory(sys.argv[1], "busy")
print("locked", flush=True)
sys.stdin.read()
"""


@pytest.fixture
def locked_elsewhere():
    """``with locked_elsewhere(directory):`` another process holds ``directory``'s lock
    (:func:`tractionecu.mapping.tiles.lock_directory`: a replay's output, a fleet's OUT, a TASKDATA directory,
    the service's state directory) until the block ends; the lock goes with that process."""
    @contextmanager
    def hold(directory):
        holder = subprocess.Popen([sys.executable, "-c", _HOLD_LOCK, str(directory)], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, text=True)
        try:
            assert holder.stdout.readline().strip() == "locked"
            yield
        finally:
            holder.communicate("", timeout=30)

    return hold
