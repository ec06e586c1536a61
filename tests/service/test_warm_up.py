"""The service's warm-up leaves nothing to compile inside the real-time estimation loop.

Regression: on a fresh install (no numba cache) ``tractionecu run --simulate`` logged "estimation loop
2.80 s behind; skipping 281 steps" in its first seconds.  The warm-up stepped a throwaway estimator on a
straight, short drive, which never reached the curvature's process-noise kernel (it needs a turn) nor
covariance matching's ratio (it needs a full window), so both compiled at the machine's first turn and
first adaptation, inside the loop.

Each case runs in a fresh interpreter: in this one, other tests have compiled the kernels already, and the
check would pass whatever the warm-up did.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tractionecu.model.vehicle import JIT

pytestmark = pytest.mark.skipif(not JIT, reason="numba is off: nothing is compiled")

CHECK = r"""
import json, sys
from numba.core.registry import CPUDispatcher
import tractionecu.estimation._curve_kernel as ck
import tractionecu.estimation._kernels as k
import tractionecu.model.vehicle as mv
from tractionecu.pipeline.replay import machine_of, replay
from tractionecu.recording.reader import read_recording
from tractionecu.service.loop import default_estimator_factory, warm_up

def signatures():
    return {m.__name__ + "." + n: len(d.signatures) for m in (k, ck, mv) for n, d in vars(m).items()
            if isinstance(d, CPUDispatcher)}

rec = read_recording(sys.argv[1])
warm_up(default_estimator_factory, *machine_of(rec))
before = signatures()
res = replay(rec)
after = signatures()
print(json.dumps({"compiled_in_loop": sorted(n for n in after if after[n] > before.get(n, 0)),
                  "steps": int(res.counters["steps"])}))
"""


@pytest.mark.parametrize("scenario, seconds", [
    ("s-curves-30m", 20.0),                   # hub drive in turns: the curvature's noise, covariance matching
    ("physical-declared-exact", 10.0),        # the declared carcass and two-inertia hub
    ("mechanical-three-soils", 10.0),         # the machine-level estimator
])
def test_nothing_compiles_in_the_loop_after_the_warm_up(make_recording, scenario: str, seconds: float) -> None:
    rec = make_recording(scenario, 0, seconds)
    out = subprocess.run([sys.executable, "-c", CHECK, str(rec)], capture_output=True, text=True, timeout=600,
                         cwd=Path(__file__).resolve().parents[2])
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["steps"] > 0.9 * seconds * 100.0
    assert got["compiled_in_loop"] == []
