"""Estimator step arguments from live samples, exactly as ``tractionecu replay`` builds them.

``replay`` (:mod:`tractionecu.cli.replay`) steps the estimator on the grid
``t_k = t_ws + GRID_MARGIN_S + k / rate`` (``t_ws`` the first wheel-speed
frame) and passes, at step k, each input or measurement whose latest sample
at or before ``t_k`` is NEW, i.e. a different sample from the one passed
before; only the latest of several new samples is passed.  The estimator
holds inputs itself (zero-order hold) and raises its own timeout bits.

:class:`StepAssembler` is the incremental form of that rule for the daemon:
samples are pushed as frames arrive (time-stamped with the driver's receive
time, the same clock candump writes), and :meth:`StepAssembler.take` at
``t_k`` returns the same ``(inputs, measurements)`` that replay would pass
for that step, provided every sample stamped at or before ``t_k`` has been
pushed (the daemon waits ``estimation.lag_s`` after ``t_k`` for that).
``tests/service/test_steps.py`` checks that offline, replay and an
Estimator fed through this class give identical estimates.

Groups (estimator key: DBC signals, wheel order FL, FR, RL, RR):

==========  =========================================  ===========
``Md``      ``DriveTorque_FL..RR`` (TECU_DriveTorques)  input
``Fzf``     ``FrontAxleLoad`` (TECU_AxleLoad)           input
``Fdx``     ``DraftForce`` (RearHitchStatus)            input
``omega``   ``WheelSpeed_FL..RR`` (TECU_WheelSpeeds)    measurement
``v``       GNSS speed over ground of an epoch          measurement
==========  =========================================  ===========
"""

from __future__ import annotations

import math
from collections import Counter, deque
from typing import Any, Mapping

import numpy as np

from ..bus.dbc import WHEELS
from ..cli.replay import GRID_MARGIN_S

INPUT_GROUPS: dict[str, tuple[str, ...]] = {
    "Md": tuple(f"DriveTorque_{w}" for w in WHEELS),
    "Fzf": ("FrontAxleLoad",),
    "Fdx": ("DraftForce",),
}
"""Estimator input key -> DBC signals (one message each)."""

MEASUREMENT_GROUPS: dict[str, tuple[str, ...]] = {
    "omega": tuple(f"WheelSpeed_{w}" for w in WHEELS),
}
"""Estimator measurement key -> DBC signals; ``v`` comes from the GNSS (:meth:`StepAssembler.push_speed`)."""

GROUPS: dict[str, tuple[str, ...]] = {**INPUT_GROUPS, **MEASUREMENT_GROUPS}
VECTOR_KEYS = frozenset({"Md", "omega"})
ANCHOR_SIGNAL = "WheelSpeed_FL"
"""The grid is phased to the first frame carrying this signal (as replay's ``build_grid``)."""

__all__ = ["GRID_MARGIN_S", "GROUPS", "INPUT_GROUPS", "MEASUREMENT_GROUPS", "StepAssembler"]


class _Ring:
    __slots__ = ("buf", "seq", "taken")

    def __init__(self, depth: int) -> None:
        self.buf: deque[tuple[float, int, Any]] = deque(maxlen=depth)
        self.seq = 0
        self.taken = -1


class StepAssembler:
    """Collect samples and hand out replay-identical step arguments.

    Parameters
    ----------
    depth:
        Samples kept per group; must cover ``lag × rate`` of the fastest
        message plus a margin (default 256: 2.5 s of 100 Hz frames).

    Attributes
    ----------
    counts:
        ``late`` and ``late_<key>`` (a sample stamped at or before a step
        already taken: it is passed at the next step), ``time_backwards`` (stamped before the
        previous sample of its group: dropped).
    """

    def __init__(self, depth: int = 256) -> None:
        self._rings = {k: _Ring(depth) for k in (*GROUPS, "v")}
        self._signal_group = {names[0]: key for key, names in GROUPS.items()}
        self.t_taken = -math.inf
        self.max_late_s = 0.0
        """Largest (last step time − sample time) of a late sample [s]: how much more lag was needed."""
        self.counts: Counter[str] = Counter()

    def _push(self, key: str, t: float, value: Any) -> None:
        r = self._rings[key]
        if r.buf and t < r.buf[-1][0]:
            self.counts["time_backwards"] += 1
            return
        if t <= self.t_taken:
            self.counts["late"] += 1
            self.counts["late_" + key] += 1
            self.max_late_s = max(self.max_late_s, self.t_taken - t)
        r.seq += 1
        r.buf.append((t, r.seq, value))

    def push_signals(self, t: float, values: Mapping[str, float]) -> None:
        """Add the decoded signals of one frame received at ``t`` [s]."""
        for first, key in self._signal_group.items():
            if first in values:
                names = GROUPS[key]
                if key in VECTOR_KEYS:
                    self._push(key, t, np.array([values[n] for n in names], dtype=float))
                else:
                    self._push(key, t, values[first])

    def push_speed(self, t: float, speed_mps: float) -> None:
        """Add a GNSS speed over ground [m/s] of the epoch at ``t`` [s]."""
        self._push("v", t, speed_mps)

    def take(self, t: float) -> tuple[dict[str, Any], dict[str, Any]]:
        """``(inputs, measurements)`` for the step at ``t`` [s] (replay's rule)."""
        inputs: dict[str, Any] = {}
        meas: dict[str, Any] = {}
        for key, r in self._rings.items():
            hit = None
            for item in reversed(r.buf):
                if item[0] <= t:
                    hit = item
                    break
            if hit is None or hit[1] == r.taken:
                continue
            r.taken = hit[1]
            (inputs if key in INPUT_GROUPS else meas)[key] = hit[2]
        if t > self.t_taken:
            self.t_taken = t
        return inputs, meas
