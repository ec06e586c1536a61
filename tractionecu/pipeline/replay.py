"""The replay engine: a recording through the estimator step by step, as the daemon runs it.

:func:`replay` decodes nothing itself: it takes a
:class:`~tractionecu.recording.reader.Recording`, gates its GNSS track with
the service's rule (:class:`~.gnss.GnssGate`), builds the step grid and the
step arguments (:mod:`.steps`, the same rule the daemon applies sample by
sample) and steps one :class:`~tractionecu.estimation.estimator.Estimator`.
The result stays in memory (:class:`ReplayResult`), so diagnosis reads it
without files.

Streaming
---------
Every replay feeds one step function (:class:`_Run`) with blocks of signals: the grid
of :func:`~.steps.build_grid` is handed out as the anchor frames arrive
(:class:`_GridStream`, the same float arithmetic) and each group's latest
sample is taken by :func:`~.steps.vector_steps`' rule, block by block
(:class:`_Group`).  :func:`replay` feeds the whole recording as one block;
:func:`replay_streamed` given a path reads the capture twice: a survey
(:func:`~tractionecu.recording.reader.read_recording` keeping whole only the
speeds, :mod:`.survey`) for the signals present, the statistics and the clock
offset, then block by block
(:func:`~tractionecu.recording.reader.stream_signals`).  The sink (:class:`_Sink`)
writes ``estimates.csv`` (:data:`CSV_COLUMNS`) as the steps age past the window a
lost filter may reach back (``lost_after_s`` + ``max_gap_s`` + 1 s) and keeps the
step at or after each GNSS epoch for the map.  Batch replay (:mod:`.batch`) runs
the same function with a compiled loop, and ``tractionecu replay``'s run directory
(:mod:`.rundir`) is written by either.

A recording without the signals replay needs (:data:`~.signals.REPLAY_REQUIRED`:
the hub profile's wheel speeds and drive torques, the one profile the
estimator runs) raises :class:`MissingSignals` before anything is written;
it carries the recording, so the caller can report the profiles and the
motion (:mod:`.signals`).

Scoring against simulated truth is not here: it is the evaluation side's
(:mod:`tractionecu.evaluation`), which the on-board core never imports.
"""

from __future__ import annotations

import math
import os
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from ..columns import concat
from ..config import SensorSpec, VehicleParams, load_sensors, load_vehicle, to_toml
from ..errors import ConfigError
from ..estimation.estimator import FILTER_LOST, Estimate, EstimatorConfig
from ..estimation.smoother import FixedLagSmoother
from ..model.vehicle import N_STATE, STATE_NAMES, WHEELS
from ..recording.reader import Recording, read_recording, stream_signals
from .gnss import GnssGate
from .select import estimator_for, groups_for
from .signals import GNSS_SPEED, estimator_profile, required_missing
from .steps import GNSS_COURSE, GRID_MARGIN_S, GRID_MAX_GAP_S, build_grid
from .survey import survey_keep

_BATCH = 2048
"""Estimates kept before they are copied into the result arrays (bounded memory, bulk copies)."""

UNCERTAINTY_COLUMNS = tuple([f"sigma_mu_{w}" for w in WHEELS] + ["sigma_rho_s"]
                            + [f"radius_{k}_{a}" for k in ("scale", "hw95", "applied") for a in ("front", "rear")])
"""Last columns of ``estimates.csv``: the reported uncertainty and the rolling-radius calibration
(``Estimate.sigma_mu``, ``sigma_rho_s``, ``radius_scale``, ``radius_halfwidth``, ``radius_applied``)."""

CSV_COLUMNS = tuple(["t"] + [f"mu_{w}" for w in WHEELS] + ["rho_s", "a", "soil_class"] + [f"slip_{w}" for w in WHEELS]
                    + ["v"] + [f"omega_{w}" for w in WHEELS] + [f"var_{n}" for n in STATE_NAMES]
                    + ["nis", "nis_dof", "adapt", "status", "valid", "curve_path"]
                    + list(UNCERTAINTY_COLUMNS))
"""Columns of ``estimates.csv``."""

__all__ = ["CSV_COLUMNS", "MissingSignals", "ReplayResult", "checked", "machine_of", "recording_grid", "replay",
           "replay_streamed", "resolved_config", "write_estimates_csv"]


class MissingSignals(ConfigError):
    """The recording lacks signals replay cannot run without; ``recording`` and ``missing`` (signal names)."""

    def __init__(self, recording: Recording, missing: list[str], profile: str = "hub") -> None:
        self.recording = recording
        self.missing = missing
        self.profile = profile
        super().__init__(f"{recording.path}: the recording has no {', '.join(missing)}: the estimator's "
                         f"{profile} profile needs them (tractionecu inspect lists what the recording holds)")


RATE_HZ = (1.0, 1000.0)
"""Estimator step rates a replay takes [Hz]: 1e6 Hz on a 40 s recording asked for 40 million steps (the
process passed 21 GB before it was stopped)."""


def check_rate(rate_hz: float) -> None:
    """A :class:`ConfigError` for a step rate outside :data:`RATE_HZ` (NaN included)."""
    if not RATE_HZ[0] <= rate_hz <= RATE_HZ[1]:
        raise ConfigError(f"rate_hz: an estimator step rate in [{RATE_HZ[0]:g}, {RATE_HZ[1]:g}] Hz, got {rate_hz}")


def stepped_seconds(span_s: float, steps: int, rate_hz: float) -> float:
    """The recorded time a replay's ``steps`` at ``rate_hz`` cover [s]: their span ``span_s``, at most
    (steps − 1)/rate: a CAN clock stepped by 1.78e9 s while logging made a 90 s replay "1783670390.0 s
    simulated (2057247388x real time)"."""
    return min(float(span_s), max(steps - 1, 0) / float(rate_hz)) if rate_hz > 0 else float(span_s)


@dataclass
class ReplayResult:
    """Estimates of one replay as arrays over the step grid.

    ``arrays`` holds ``t`` [s] (n,), ``mu``, ``slip``, ``omega`` (n, 4),
    ``P_diag`` (n, 10), ``rho_s``, ``a``, ``v``, ``nis``, ``adapt`` (n,),
    ``nis_dof``, ``status`` (int), ``valid`` (bool) and ``soil_class`` (list
    of str); ``gps_mask`` marks the recording's GNSS epochs that passed the
    gate; ``counters`` are the estimator's, ``gnss`` the gate's.  When the
    estimator declares itself lost, the estimates of the lost period (from
    its ``lost_since``) are marked not valid with ``FILTER_LOST`` afterwards.
    """

    arrays: dict[str, Any]
    rate_hz: float
    gps_mask: np.ndarray
    counters: dict[str, int] = field(default_factory=dict)
    gnss: Counter[str] = field(default_factory=Counter)
    loop_seconds: float = 0.0
    n_steps: int = -1
    """Estimator steps run (-1: every one is in ``arrays``)."""
    span_s: float = math.nan
    """Span of the step grid [s] (NaN: from ``arrays``)."""

    @property
    def steps(self) -> int:
        """Number of estimator steps."""
        return int(self.arrays["t"].size) if self.n_steps < 0 else self.n_steps

    @property
    def sim_seconds(self) -> float:
        """Recorded time the steps cover [s]: the span of the step grid, at most the steps over the rate (a
        clock that jumped while logging, or a gap the grid steps over, is not time replayed)."""
        span = self.span_s
        if math.isnan(span):
            t = self.arrays["t"]
            span = float(t[-1] - t[0]) if t.size > 1 else 0.0
        return stepped_seconds(span, self.steps, self.rate_hz)


def recording_grid(rec: Recording, rate_hz: float, vehicle: VehicleParams | None = None) -> np.ndarray:
    """The step grid of a recording (:func:`~.steps.build_grid` on its wheel-speed frames; on the engine
    speed frames for an engine-driven ``vehicle``, :func:`~.select.groups_for`).

    Raises :class:`MissingSignals` when the recording lacks a signal of :data:`~.signals.REPLAY_REQUIRED`
    (:func:`~.signals.required_missing` for ``vehicle``).
    """
    check_rate(rate_hz)
    missing = required_missing(rec, vehicle)
    if missing:
        raise MissingSignals(rec, missing, estimator_profile(vehicle))
    ws = rec.signals[groups_for(vehicle).anchor].t
    # The grid ends with the data that drives the estimator: never more than a wheel-speed gap past the
    # last wheel-speed frame, whatever other signal runs on (or whatever time an odd clock put there).
    return build_grid(ws, min(float(rec.t_end), float(ws[-1]) + GRID_MAX_GAP_S), rate_hz)


_MACHINES: dict[tuple[str, int, int], tuple[VehicleParams, SensorSpec]] = {}
"""The vehicle files read, by path, modification time and size (both results are frozen dataclasses)."""
_MACHINES_MAX = 16


def machine_of(rec: Recording) -> tuple[VehicleParams, SensorSpec]:
    """The recording's ``vehicle.toml`` (vehicle and ``[sensors]``), else the documented defaults.  A replay asks
    three times (the check, the run directory's writer, the loop): the file is read once while it is unchanged."""
    path = rec.vehicle_toml_path
    if path is None:
        return VehicleParams(), SensorSpec()
    try:
        st = os.stat(path)
    except OSError:
        return load_vehicle(path), load_sensors(path)       # its own clear error
    key = (os.path.abspath(path), st.st_mtime_ns, st.st_size)
    got = _MACHINES.get(key)
    if got is None:
        got = (load_vehicle(path), load_sensors(path))
        if len(_MACHINES) >= _MACHINES_MAX:
            _MACHINES.clear()
        _MACHINES[key] = got
    return got


def checked(rec: Recording, recording: Any, streamed: bool) -> Recording:
    """``rec``, the recording ``recording`` as read (its survey when ``streamed``), if it has the signals its
    machine's estimator needs (:func:`~.signals.required_missing`); else :class:`MissingSignals`, before
    anything is written, with the recording read whole for the caller's report."""
    vehicle = machine_of(rec)[0]
    missing = required_missing(rec, vehicle)
    if missing:
        raise MissingSignals(read_recording(recording) if streamed else rec, missing, estimator_profile(vehicle))
    return rec


def replay(rec: Recording | str | Path, *, rate_hz: float = 100.0, vehicle: VehicleParams | None = None,
           sensors: SensorSpec | None = None, cfg: EstimatorConfig | None = None, gate: GnssGate | None = None,
           on_estimate: Callable[[Estimate], None] | None = None) -> ReplayResult:
    """Step the estimator over ``rec`` (a :class:`Recording`, or its path: :func:`read_recording`) and keep
    every estimate (module doc).

    ``vehicle`` and ``sensors`` default to the recording's ``vehicle.toml``
    (:func:`machine_of`); ``on_estimate`` is called with every
    :class:`~tractionecu.estimation.estimator.Estimate` in time order.
    The recording is fed to the same step function as a streamed one, as one block.
    """
    check_rate(rate_hz)
    if not isinstance(rec, Recording):                 # a path, as replay_streamed and replay_to_dir take
        rec = read_recording(rec)
    if vehicle is None or sensors is None:
        v0, s0 = machine_of(rec)
        vehicle = vehicle or v0
        sensors = sensors or s0
    recording_grid(rec, rate_hz, vehicle)             # the checks (rate, required signals)
    sink = _Sink(keep_all=True)
    run = _Run(rec, rate_hz, vehicle, sensors, cfg or EstimatorConfig(), gate or GnssGate(), sink, on_estimate)
    run.feed_recording(rec, streamed=False)
    return ReplayResult(sink.arrays(), float(rate_hz), run.gps_mask, dict(run.est.counters), run.gnss,
                        run.loop_seconds)


def replay_streamed(recording: str | Path, *, rate_hz: float = 100.0, cfg: EstimatorConfig | None = None,
                    gate: GnssGate | None = None, on_estimate: Callable[[Estimate], None] | None = None,
                    ) -> tuple[Recording, dict[str, int]]:
    """Step the estimator over the recording at ``recording`` and keep nothing: every estimate goes to
    ``on_estimate`` (in time order), as :func:`replay` does, but the capture is streamed as
    :func:`replay_to_dir` streams it, so memory does not grow with the recording's length.  Returns the
    survey (:func:`replay_to_dir`'s) and the estimator's counters."""
    check_rate(rate_hz)                                # before the capture is read
    rec = checked(read_recording(recording, keep=survey_keep), recording, streamed=True)
    vehicle, sensors = machine_of(rec)
    run = _Run(rec, rate_hz, vehicle, sensors, cfg or EstimatorConfig(), gate or GnssGate(), _Sink(keep_all=False),
               on_estimate)
    run.feed_recording(rec, streamed=True)
    return rec, dict(run.est.counters)


# ----------------------------------------------------------------------------- streaming
class _GridStream:
    """:func:`~.steps.build_grid`'s grid, handed out as the anchor (wheel-speed) frames arrive.

    A segment starts at an anchor frame + :data:`GRID_MARGIN_S` and ends at the last anchor frame before a
    gap over :data:`GRID_MAX_GAP_S` (the last segment at the recording's end); step k of a segment that
    starts at a and ends at b exists when ``k <= floor((b - a)·rate + 1e-9)``, the same arithmetic as
    ``build_grid``, so the times are the same floats.
    """

    def __init__(self, rate_hz: float) -> None:
        self.rate = float(rate_hz)
        self.a = math.nan                 # start of the open segment [s]
        self.k = 0                        # next step index in it
        self.last = math.nan              # latest anchor time [s]
        self.closed: list[tuple[float, int, int]] = []   # (start, next k, steps) of segments ended by a gap

    def _n(self, b: float) -> int:
        return int(math.floor((float(b) - self.a) * self.rate + 1e-9)) + 1

    def anchors(self, t: np.ndarray) -> None:
        """Take the next anchor frame times [s] (in order)."""
        if t.size == 0:
            return
        if math.isnan(self.a):
            self.a, self.k, self.last = float(t[0]) + GRID_MARGIN_S, 0, float(t[0])
        prev = np.concatenate([[self.last], t[:-1]])
        for i in np.flatnonzero(t - prev > GRID_MAX_GAP_S).tolist():
            self.closed.append((self.a, self.k, self._n(prev[i])))
            self.a, self.k = float(t[i]) + GRID_MARGIN_S, 0
        self.last = float(t[-1])

    def take(self, before: float, t_end: float | None = None) -> np.ndarray:
        """The next steps earlier than ``before`` [s] that are certain; with ``t_end`` (the recording's end,
        no anchor to come) all the rest."""
        out = []
        for a, k, n in self.closed:
            out.append(a + np.arange(k, n) / self.rate)
        self.closed.clear()
        if math.isnan(self.a):
            return np.concatenate(out) if out else np.empty(0)
        n = self._n(t_end if t_end is not None else self.last)
        if n > self.k:
            g = self.a + np.arange(self.k, n) / self.rate
            if t_end is None:
                g = g[g < before]
            self.k += g.size
            out.append(g)
        return np.concatenate(out) if out else np.empty(0)


class _Group:
    """One group of :data:`~.signals.GROUPS` (or the GNSS speed): the samples not yet passed, and which
    was passed last (by its index in the whole recording): :func:`~.steps.vector_steps`' rule, block by
    block."""

    def __init__(self, key: str, names: tuple[str, ...], vector: bool) -> None:
        self.key, self.names, self.vector = key, names, vector
        self.t = np.empty(0)
        self.v: list[np.ndarray] = [np.empty(0) for _ in names]
        self.base = 0                     # index in the recording of self.t[0]
        self.prev = -1                    # index passed at the last step

    def push(self, t: np.ndarray, values: list[np.ndarray]) -> None:
        self.t = np.concatenate([self.t, t]) if self.t.size else t
        self.v = [np.concatenate([a, b]) if a.size else b for a, b in zip(self.v, values)]

    def at(self, grid: np.ndarray, lists: bool = True) -> tuple[Any, Any]:
        """(values, new) at the steps ``grid`` [s]; keeps only the samples still needed.  ``lists=False``:
        a scalar group's values and ``new`` as arrays (the batch path), else as lists."""
        idx = np.searchsorted(self.t, grid, side="right") - 1
        g = idx + self.base
        g[idx < 0] = np.where(self.base > 0, self.base - 1, -1)
        prev = np.concatenate([[self.prev], g[:-1]])
        new = (g >= 0) & (g != prev)
        safe = np.maximum(idx, 0)
        if self.vector:
            vals: Any = np.column_stack([v[safe] for v in self.v]) if self.t.size else None
        else:
            vals = (self.v[0][safe].tolist() if lists else self.v[0][safe]) if self.t.size else None
        if grid.size:
            self.prev = int(g[-1])
            cut = max(int(idx[-1]), 0)
            if cut:
                self.t = self.t[cut:]
                self.v = [v[cut:] for v in self.v]
                self.base += cut
        return vals, (new.tolist() if lists else new)


class _Run:
    """The estimator fed block by block: signals in, steps out (the step function every replay uses)."""

    def __init__(self, rec: Recording, rate_hz: float, vehicle: VehicleParams, sensors: SensorSpec,
                 cfg: EstimatorConfig, gate: GnssGate, sink: "_Sink",
                 on_estimate: Callable[[Estimate], None] | None) -> None:
        self.est, g = estimator_for(rec, vehicle, cfg, sensors)      # hub or machine level (.select)
        self.smoother = FixedLagSmoother.for_estimator(self.est)   # the estimates, smoothed and delivered later
        self.anchor, self.inputs = g.anchor, g.inputs
        self.gnss: Counter[str] = Counter()
        self.gps_mask = gate.track_mask(rec.gps, self.gnss)
        self.sink = sink
        self.on_estimate = on_estimate
        self.grid = _GridStream(rate_hz)
        # groups the recording carries (as vector_steps: every signal present with samples)
        self.groups = [_Group(key, names, key in g.vectors) for key, names in g.groups.items()
                       if all(nm in rec.signals and len(rec.signals[nm]) for nm in names)]
        self.speed = _Group(GNSS_SPEED, (GNSS_SPEED,), False)
        self.course = _Group(GNSS_COURSE, (GNSS_COURSE,), False)       # passed with the speed (.steps)
        if self.gps_mask.any():
            self.speed.push(np.asarray(rec.gps.t[self.gps_mask], dtype=float),
                            [np.asarray(rec.gps.speed[self.gps_mask], dtype=float)])
            self.course.push(np.asarray(rec.gps.t[self.gps_mask], dtype=float),
                             [np.asarray(rec.gps.course[self.gps_mask], dtype=float)])
        ws = rec.signals.get(self.anchor)
        self.ws_last = float(ws.t[-1]) if ws is not None and len(ws) else math.nan
        self.t_end = float(rec.t_end)
        self.loop_seconds = 0.0

    def feed(self, signals: Mapping[str, tuple[np.ndarray, np.ndarray]], before: float) -> None:
        """One block of signals (name -> (t, value), in time order); step every grid time before ``before``
        [s] (the last frame time of the block: a later block may still hold a sample at that time)."""
        for grp in self.groups:
            cols = [signals.get(nm) for nm in grp.names]
            if cols[0] is not None and cols[0][0].size:
                grp.push(cols[0][0], [c[1] if c is not None else np.empty(0) for c in cols])
        ws = signals.get(self.anchor)
        if ws is not None:
            self.grid.anchors(np.asarray(ws[0], dtype=float))
        if math.isinf(before):
            return
        self._step(self.grid.take(before))

    def feed_recording(self, rec: Recording, streamed: bool, blocks: Any = None) -> None:
        """Every signal of ``rec``, then :meth:`close`: the blocks ``blocks`` gives ((signals, before) pairs) when
        given, else the capture decoded again block by block when ``streamed`` (``rec`` is its survey), else
        ``rec`` whole as one block."""
        if blocks is None and streamed:
            blocks = stream_signals(rec, names=self.signal_names())
        if blocks is None:
            self.feed({name: (s.t, s.value) for name, s in rec.signals.items()}, math.inf)
        else:
            for block, before in blocks:
                self.feed(block, before)
        self.close()

    def signal_names(self) -> list[str]:
        """The signals the run steps on (its groups'), sorted."""
        return sorted({nm for grp in self.groups for nm in grp.names})

    def close(self) -> None:
        """No block to come: the steps up to the grid's end (:func:`recording_grid`)."""
        if not math.isnan(self.ws_last):
            self._step(self.grid.take(math.inf, min(self.t_end, self.ws_last + GRID_MAX_GAP_S)))
        self._flush()
        self.sink.close()

    def _flush(self) -> None:
        """The estimates the smoother still holds, to the sink."""
        keep, cb = self.sink.keep, self.on_estimate
        for e in self.smoother.flush():
            keep(e)
            if cb is not None:
                cb(e)

    def _step(self, grid: np.ndarray) -> None:
        if grid.size == 0:
            return
        streams = [(grp.key, grp.key in self.inputs, *grp.at(grid)) for grp in self.groups]
        if self.speed.t.size:
            streams.append((GNSS_SPEED, False, *self.speed.at(grid)))
            streams.append((GNSS_COURSE, False, *self.course.at(grid)))
        step, keep, cb, smooth = self.est.step, self.sink.keep, self.on_estimate, self.smoother.push
        wall = time.perf_counter()
        for k, t in enumerate(grid.tolist()):
            inputs: dict[str, Any] = {}
            meas: dict[str, Any] = {}
            for key, is_input, vals, new in streams:
                if new[k]:
                    (inputs if is_input else meas)[key] = vals[k]
            for e in smooth(step(t, inputs, meas)):
                keep(e)
                if cb is not None:
                    cb(e)
        self.loop_seconds += time.perf_counter() - wall


_MAP_FIELDS = ("t", "mu", "slip", "P_diag", "v", "rho_s", "soil_class", "valid", "status")


class _Sink:
    """Estimates in batches of :data:`_BATCH`: kept whole (``keep_all``), written to ``estimates.csv`` as
    they age past ``hold_s`` (a lost filter marks the estimates since ``lost_since`` not valid, at most
    ``lost_after_s`` + ``max_gap_s`` back), and those the map needs (the step at or just after each GNSS
    epoch ``map_times``, and the first and last step) kept for the map.

    The batch path's :class:`~tractionecu.pipeline.batch.BatchSink` keeps the same books: it replaces how
    a batch becomes arrays (:meth:`_to_arrays`), whether batches wait in ``pending`` (:meth:`_pends`) and
    what happens to them as they age (:meth:`_age`, :meth:`_end`)."""

    _SCALARS = ("rho_s", "a", "v", "nis", "adapt", "sigma_rho_s")
    _VECTORS = (("mu", 4), ("slip", 4), ("omega", 4), ("P_diag", N_STATE), ("sigma_mu", 4), ("radius_scale", 2),
                ("radius_halfwidth", 2), ("radius_applied", 2))

    def __init__(self, keep_all: bool, csv_fh: Any = None, hold_s: float = math.inf,
                 map_times: np.ndarray | None = None) -> None:
        self.keep_all = keep_all
        self.block = _BATCH
        self.fh = csv_fh
        self.hold_s = hold_s
        self.map_times = None if map_times is None else np.asarray(map_times, dtype=float) - 1e-9
        self.map_k = 0                        # next GNSS epoch to find a step for
        self.batch: list[Estimate] = []
        self.pending: list[dict[str, Any]] = []     # batches not yet written
        self.done: list[dict[str, Any]] = []        # batches kept whole
        self.map_rows: list[dict[str, Any]] = []    # the steps the map needs
        self.t_prev = -math.inf
        self.last: dict[str, Any] | None = None
        self.rows = 0
        self.t_first = self.t_last = math.nan
        self.written = 0
        self.late_lost = 0

    def keep(self, e: Estimate) -> None:
        self.batch.append(e)
        if len(self.batch) == self.block:
            self._flush()
        if not math.isnan(e.lost_since):
            self._mark_lost(e.lost_since)

    def _mark_lost(self, since: float) -> None:
        """The estimates since ``since`` [s] came from a lost filter: not valid, FILTER_LOST set."""
        self._flush()
        if self.written and (not self.pending or float(self.pending[0]["t"][0]) > since):
            self.late_lost += 1                  # rows already written: cannot happen with replay_to_dir's hold_s
        for group in (self.done, self.pending, self.map_rows):   # done and pending share their batches
            for b in reversed(group):
                k = int(np.searchsorted(b["t"], since, side="left"))
                b["valid"][k:] = False
                b["status"][k:] |= FILTER_LOST
                if k > 0:
                    break

    def _flush(self) -> None:
        b = self.batch
        if not b:
            return
        arr = self._to_arrays(b)
        b.clear()
        if self.keep_all:
            self.done.append(arr)
        if self._pends():
            self.pending.append(arr)
        if self.map_times is not None:
            self._map_pick(arr)
        self.last = arr
        if not self.rows:
            self.t_first = float(arr["t"][0])
        self.t_last = float(arr["t"][-1])
        self.rows += arr["t"].size
        self._age(float(arr["t"][-1]) - self.hold_s)

    def _pends(self) -> bool:
        """Whether batches wait in ``pending`` until they are older than ``hold_s`` (to be written)."""
        return self.fh is not None

    def _age(self, upto: float) -> None:
        """The pending batches older than ``upto`` [s] (no lost filter can reach them) go out."""
        self._write(upto)

    def _to_arrays(self, b: list[Estimate]) -> dict[str, Any]:
        """One batch of estimates as arrays (keys of :class:`ReplayResult`)."""
        arr: dict[str, Any] = {"t": np.array([e.t for e in b], dtype=float)}
        for name in self._SCALARS:
            arr[name] = np.array([getattr(e, name) for e in b], dtype=float)
        for name, _m in self._VECTORS:
            arr[name] = np.array([getattr(e, name) for e in b], dtype=float)
        arr["nis_dof"] = np.array([e.nis_dof for e in b], dtype=np.int64)
        arr["status"] = np.array([e.status for e in b], dtype=np.int64)
        arr["valid"] = np.array([e.valid for e in b], dtype=bool)
        arr["soil_class"] = [e.soil_class for e in b]
        arr["curve"] = [e.curve for e in b]                  # identified μ(s) per step (estimation.curve)
        return arr

    def _map_pick(self, arr: dict[str, Any]) -> None:
        t = arr["t"]
        mt = self.map_times
        hi = int(np.searchsorted(mt, t[-1], side="right"))        # epochs whose step is in this batch
        pick = np.searchsorted(t, mt[self.map_k:hi], side="left")
        self.map_k = hi
        if self.rows == 0:
            pick = np.concatenate([[0], pick])
        pick = np.unique(pick)
        if pick.size:
            self.map_rows.append(_rows(arr, pick))

    def _write(self, upto: float) -> None:
        while self.pending and (float(self.pending[0]["t"][-1]) < upto):
            b = self.pending.pop(0)
            _write_rows(self.fh, b)
            self.written += b["t"].size

    def close(self) -> None:
        self._flush()
        if self.map_times is not None and self.last is not None:
            last = _rows(self.last, np.array([self.last["t"].size - 1]))
            if not self.map_rows or self.map_rows[-1]["t"][-1] != last["t"][0]:
                self.map_rows.append(last)
        self._end()

    def _end(self) -> None:
        """After the last batch: the pending ones go out whatever their age."""
        if self.fh is not None:
            self._write(math.inf)
            if self.rows == 0:
                self.fh.write("\n")

    def arrays(self) -> dict[str, Any]:
        return _concat(self.done)

    def map_arrays(self) -> dict[str, Any]:
        return _concat(self.map_rows)


def _rows(arr: dict[str, Any], k: np.ndarray) -> dict[str, Any]:
    out = {name: (v[k] if isinstance(v, np.ndarray) else [v[i] for i in k.tolist()]) for name, v in arr.items()}
    return out


def _concat(parts: list[dict[str, Any]]) -> dict[str, Any]:
    if not parts:
        out: dict[str, Any] = {"t": np.empty(0)}
        for name in _Sink._SCALARS:
            out[name] = np.empty(0)
        for name, m in _Sink._VECTORS:
            out[name] = np.empty((0, m))
        out.update(nis_dof=np.empty(0, dtype=np.int64), status=np.empty(0, dtype=np.int64),
                   valid=np.empty(0, dtype=bool), soil_class=[])
        return out
    return concat(parts)


# ----------------------------------------------------------------------------- run directory
def write_estimates_csv(path: Path, arrays: dict[str, Any]) -> None:
    """Write ``estimates.csv`` (columns :data:`CSV_COLUMNS`)."""
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(",".join(CSV_COLUMNS) + "\n")
        if len(arrays["t"]):
            _write_rows(fh, arrays)
        else:
            fh.write("\n")


def _write_rows(fh: Any, arrays: dict[str, Any]) -> None:
    """Rows of ``estimates.csv`` for the steps of ``arrays``, each ending in a newline."""
    left = np.column_stack([arrays["t"], arrays["mu"], arrays["rho_s"], arrays["a"]]).tolist()
    right = np.column_stack([arrays["slip"], arrays["v"], arrays["omega"], arrays["P_diag"], arrays["nis"],
                             arrays["nis_dof"], arrays["adapt"], arrays["status"], arrays["valid"]]).tolist()
    fl = "%.3f" + ",%.6g" * 6 + ",%s,"
    fr = ",".join(["%.6g"] * 20) + ",%d,%.4g,%d,%d"
    cls = arrays["soil_class"]
    paths = arrays.get("curve_path")
    if paths is None:
        paths = [c.path if c is not None else "" for c in arrays.get("curve", [None] * len(cls))]
    rows = [fl % (*a, c) + fr % tuple(b) + "," + p for a, c, b, p in zip(left, cls, right, paths)]
    fh.write("\n".join([r + x for r, x in zip(rows, _uncertainty_cells(arrays))]))
    fh.write("\n")


def _uncertainty_cells(arrays: dict[str, Any]) -> list[str]:
    """The :data:`UNCERTAINTY_COLUMNS` cells of each row, each starting with a comma."""
    cells = np.column_stack([arrays["sigma_mu"], arrays["sigma_rho_s"], arrays["radius_scale"],
                             arrays["radius_halfwidth"], arrays["radius_applied"]]).tolist()
    f = ",%.4g" * 5 + ",%.6g" * 6
    return [f % tuple(c) for c in cells]


def resolved_config(vehicle: VehicleParams, sensors: SensorSpec, cfg: EstimatorConfig, rate_hz: float,
                    gate: GnssGate) -> str:
    """``config.toml`` of a replay: everything needed to run it again (SI units)."""
    return ("# Resolved configuration of this replay (SI units)\n" + to_toml(vehicle, "vehicle") + "\n"
            + to_toml(sensors, "sensors") + "\n" + cfg.to_toml()
            + f"\n[replay]\nrate_hz = {float(rate_hz)!r}\ngrid_margin_s = {GRID_MARGIN_S!r}\n"
            + f"gnss_min_fix_quality = {gate.min_fix_quality}\ngnss_max_hdop = {float(gate.max_hdop)!r}\n")
