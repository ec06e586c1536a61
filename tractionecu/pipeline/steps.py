"""The step rule: which samples go into each estimator step, in two equal forms.

The estimator is stepped on the grid ``t_k = t_ws + GRID_MARGIN_S + k / rate``
(``t_ws`` the first wheel-speed frame, :data:`~.signals.ANCHOR_SIGNAL`), so
that every frame of one drive-train burst arrives in the step it belongs
to.  At step k each group of :data:`~.signals.GROUPS` (and the GNSS speed
``v``) whose latest sample at or before ``t_k`` is NEW — a different sample
from the one passed before — is passed, with that latest value; only the
latest of several new samples is passed.  The estimator holds inputs
itself (zero-order hold) and raises its own timeout bits.

Two forms of the same rule:

* :func:`vector_steps` — vectorised over a whole recording (replay);
* :class:`StepAssembler` — incremental, for the daemon: samples are pushed
  as frames arrive (stamped with the driver's receive time, the clock
  candump writes) and :meth:`StepAssembler.take` at ``t_k`` returns the
  same ``(inputs, measurements)``, provided every sample stamped at or
  before ``t_k`` has been pushed (the daemon waits ``estimation.lag_s``).

``tests/pipeline/test_steps.py`` proves the two equal, argument by argument.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from typing import Any, Iterator, Mapping

import numpy as np
from numpy.typing import NDArray

from .signals import ANCHOR_SIGNAL, GNSS_SPEED, GROUPS, INPUT_GROUPS, VECTOR_KEYS

GNSS_COURSE = "course"
"""Estimator measurement key of the GNSS course over ground [deg from true north], passed with the speed of
the same epoch (NaN when the epoch has none); the estimator's path curvature and direction test use it."""

GRID_MARGIN_S = 0.0015
"""Grid time after the wheel-speed frame time [s]: covers CAN arrival jitter and the spread of one burst."""

GRID_MAX_GAP_S = 2.0
"""Wheel-speed gaps longer than this [s] get no grid steps; the estimator restarts after them."""

__all__ = ["GNSS_COURSE", "GRID_MARGIN_S", "GRID_MAX_GAP_S", "StepAssembler", "arrivals", "build_grid", "vector_steps"]


# ----------------------------------------------------------------------------- grid
def build_grid(anchor_t: NDArray[np.float64], t_end: float, rate_hz: float) -> NDArray[np.float64]:
    """Fixed-rate grid [s] phased to the anchor frames ``anchor_t`` (module doc), up to ``t_end``.

    Gaps between anchor frames longer than :data:`GRID_MAX_GAP_S` (logger
    paused, a clock jump in the capture) get no grid steps: the grid covers
    the spans that hold data, so a jump of years cannot ask for an absurd
    number of steps.
    """
    if anchor_t.size == 0:
        return np.empty(0)
    t0 = float(anchor_t[0]) + GRID_MARGIN_S
    gaps = np.flatnonzero(np.diff(anchor_t) > GRID_MAX_GAP_S)
    if gaps.size == 0:
        n = int(math.floor((float(t_end) - t0) * rate_hz + 1e-9)) + 1
        return t0 + np.arange(max(n, 0)) / rate_hz
    starts = np.concatenate([[t0], anchor_t[gaps + 1] + GRID_MARGIN_S])
    ends = np.concatenate([anchor_t[gaps], [t_end]])
    parts = []
    for a, b in zip(starts, ends):
        n = int(math.floor((float(b) - float(a)) * rate_hz + 1e-9)) + 1
        if n > 0:
            parts.append(float(a) + np.arange(n) / rate_hz)
    return np.concatenate(parts) if parts else np.empty(0)


# ----------------------------------------------------------------------------- vectorised form
def arrivals(src_t: NDArray[np.float64], grid: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """Index of the latest sample at or before each grid time and whether it is new at that step."""
    idx = np.searchsorted(src_t, grid, side="right") - 1
    prev = np.concatenate([[-1], idx[:-1]])
    return idx, (idx >= 0) & (idx != prev)


def vector_steps(signals: Mapping[str, Any], speed_t: NDArray[np.float64], speed: NDArray[np.float64],
                 grid: NDArray[np.float64], groups: Any = None,
                 course: NDArray[np.float64] | None = None) -> Iterator[tuple[dict[str, Any], dict[str, Any]]]:
    """``(inputs, measurements)`` for every grid step of a whole recording (replay's form).

    ``signals`` maps DBC signal names to series with ``t`` and ``value``
    arrays (:class:`~tractionecu.recording.reader.Series`); ``speed_t`` and
    ``speed`` are the accepted GNSS epochs [s] and their speeds [m/s], ``course`` their
    courses over ground [deg] (passed as :data:`GNSS_COURSE` with the speed).  A
    group with a missing or empty signal is never passed.  ``groups``: another estimator's signal table
    (:class:`~.signals.SignalGroups`), default the hub estimator's.
    """
    all_groups, input_keys, vector_keys = (GROUPS, INPUT_GROUPS, VECTOR_KEYS) if groups is None else \
        (groups.groups, groups.inputs, groups.vectors)
    n = grid.size
    streams: list[tuple[str, bool, Any, list[bool]]] = []
    for key, names in all_groups.items():
        series = [signals.get(nm) for nm in names]
        if any(s is None or len(s) == 0 for s in series):
            continue
        idx, new = arrivals(series[0].t, grid)  # type: ignore[union-attr]
        safe = np.maximum(idx, 0)
        if key in vector_keys:
            vals: Any = np.column_stack([s.value[safe] for s in series])  # type: ignore[union-attr]
        else:
            vals = series[0].value[safe].tolist()  # type: ignore[union-attr]
        streams.append((key, key in input_keys, vals, new.tolist()))
    if len(speed_t):
        gi, new_v = arrivals(np.asarray(speed_t, dtype=float), grid)
        streams.append((GNSS_SPEED, False, np.asarray(speed, dtype=float)[np.maximum(gi, 0)].tolist(), new_v.tolist()))
        if course is not None:
            streams.append((GNSS_COURSE, False, np.asarray(course, dtype=float)[np.maximum(gi, 0)].tolist(),
                            new_v.tolist()))
    for k in range(n):
        inputs: dict[str, Any] = {}
        meas: dict[str, Any] = {}
        for key, is_input, vals, new in streams:
            if new[k]:
                (inputs if is_input else meas)[key] = vals[k]
        yield inputs, meas


# ----------------------------------------------------------------------------- incremental form
class _Ring:
    __slots__ = ("buf", "seq", "taken")

    def __init__(self, depth: int) -> None:
        self.buf: deque[tuple[float, int, Any]] = deque(maxlen=depth)
        self.seq = 0
        self.taken = -1


class StepAssembler:
    """Collect samples as they arrive and hand out the step arguments of :func:`vector_steps`.

    Parameters
    ----------
    depth:
        Samples kept per group; must cover ``lag × rate`` of the fastest
        message plus a margin (default 256: 2.5 s of 100 Hz frames).
    groups:
        Another estimator's signal table (:class:`~.signals.SignalGroups`, with
        its grid anchor); default the hub estimator's.

    Attributes
    ----------
    counts:
        ``late`` and ``late_<key>`` (a sample stamped at or before a step
        already taken: it is passed at the next step), ``time_backwards``
        (stamped before the previous sample of its group: dropped).
    anchor:
        Time of the first grid step [s] (first anchor frame + :data:`GRID_MARGIN_S`), or None.
    """

    def __init__(self, depth: int = 256, groups: Any = None) -> None:
        g = groups
        self._groups, self._inputs, self._vectors, self._anchor_signal = (
            (GROUPS, INPUT_GROUPS, VECTOR_KEYS, ANCHOR_SIGNAL) if g is None else
            (g.groups, g.inputs, g.vectors, g.anchor))
        self._rings = {k: _Ring(depth) for k in (*self._groups, GNSS_SPEED, GNSS_COURSE)}
        self._signal_group = {names[0]: key for key, names in self._groups.items()}
        self.t_taken = -math.inf
        self.max_late_s = 0.0
        """Largest (last step time − sample time) of a late sample [s]: how much more lag was needed."""
        self.counts: Counter[str] = Counter()
        self.anchor: float | None = None
        self.last_anchor: float | None = None
        """Time of the latest anchor frame (wheel speeds) [s], or None."""

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
                names = self._groups[key]
                if key in self._vectors:
                    self._push(key, t, np.array([values[n] for n in names], dtype=float))
                else:
                    self._push(key, t, values[first])
        if self._anchor_signal in values:
            if self.anchor is None:
                self.anchor = t + GRID_MARGIN_S
            if self.last_anchor is None or t > self.last_anchor:
                self.last_anchor = t

    def push_speed(self, t: float, speed_mps: float, course_deg: float | None = None) -> None:
        """Add a GNSS speed over ground [m/s] of the accepted epoch at ``t`` [s] and its course over ground
        [deg] (None: the epoch has none, passed as NaN as replay passes a missing course)."""
        n = self._rings[GNSS_SPEED].seq
        self._push(GNSS_SPEED, t, speed_mps)
        if self._rings[GNSS_SPEED].seq != n:          # kept (not backwards): the course goes with it, uncounted
            r = self._rings[GNSS_COURSE]
            r.seq += 1
            r.buf.append((t, r.seq, math.nan if course_deg is None else float(course_deg)))

    def take(self, t: float) -> tuple[dict[str, Any], dict[str, Any]]:
        """``(inputs, measurements)`` for the step at ``t`` [s] (the rule of the module doc)."""
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
            (inputs if key in self._inputs else meas)[key] = hit[2]
        if t > self.t_taken:
            self.t_taken = t
        return inputs, meas
