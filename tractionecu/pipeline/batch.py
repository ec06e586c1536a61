"""Batch replay: a recording's estimates as arrays, for offline work where latency does not matter.

The step path (:mod:`tractionecu.pipeline.replay`) is what the daemon runs: per step a dict of inputs
and measurements, one :meth:`Estimator.step <tractionecu.estimation.estimator.Estimator.step>`, one
:class:`~tractionecu.estimation.estimator.Estimate`, and ``estimates.csv`` written row by row.  The
batch path runs the same estimator over the same step arguments and keeps its results as arrays:

* the capture is decoded once (module doc, "Decoding"), in the blocks replay decodes it in, and the step
  arguments of a whole block are
  assembled at once: the grid and each signal group's new samples come from replay's own stream
  (:class:`~tractionecu.pipeline.replay._Run`, so the arguments are those of the step path, float for
  float), and the dicts of every step of the block are filled stream by stream;
* the estimator is stepped in a tight loop and the estimates are gathered into arrays per block of
  :data:`BLOCK` steps (the fields read with one ``attrgetter`` per estimate; the reported uncertainty
  σ_μ = √(P_μ + u_μ²), σ_ρs computed over the block's arrays, the same operations as
  :attr:`Estimate.sigma_mu <tractionecu.estimation.estimator.Estimate.sigma_mu>`);
* nothing is formatted as text: :func:`replay_batch` returns the arrays of every step (the keys of
  :class:`~tractionecu.pipeline.replay.ReplayResult`), :func:`replay_batch_rows` keeps only the steps
  a consumer asks for (the first step at or after each 1/``rate`` boundary, and the map's steps, one
  per GNSS epoch), so memory does not grow with the recording's length but for those.

Decoding: given a recording's path, the survey (``read_recording(keep=survey_keep)``, the recording's
statistics and the few signals kept whole) holds the decoded blocks of the signals a replay steps on
(:data:`~tractionecu.pipeline.survey.REPLAY_SIGNALS`, :class:`~tractionecu.recording.reader.HeldBlocks`),
and the run is fed from them (:func:`~tractionecu.recording.reader.held_signals`): the capture is read and
decoded once.  The held arrays are bounded (``hold_bytes``, default
:data:`~tractionecu.recording.reader.HOLD_MAX_BYTES`, 256 MiB, about 7 h of ``paper-three-soils``): a longer
recording drops them at the bound and is read again block by block
(:func:`~tractionecu.recording.reader.stream_signals`, as replay does), so a worker's memory stays bounded
whatever the recording's length.  Both give the same blocks, array for array, so the same estimates; the
results' ``decode`` says which ran.  A :class:`~tractionecu.recording.reader.Recording` already decoded is
fed whole.

A lost filter marks the estimates since its ``lost_since`` not valid with ``FILTER_LOST``, as the step
path does; the rows are selected only once they are older than the window a lost filter may reach
back (``lost_after_s`` + ``max_gap_s`` + 1 s).

The estimator loop: where :func:`tractionecu.estimation.compiled_loop.supported` covers the machine's
estimator (the hub estimator, numba on, none of the features a vehicle file switches on that it does not
port: a tyre carcass, a two-inertia hub), each block's step arguments go to the compiled loop
(:class:`~tractionecu.estimation.compiled_loop.CompiledLoop`) as one array and come back as the block's
estimate arrays; it returns to Python only for the μ(s) curve (and its slope for an averaged slip), the
radius calibration, the fuzzy supervisor's intensity of rule strengths not seen before, the filter's
(re)initialisation and the rare general update, calling the estimator's own objects.  Otherwise (the
machine-level estimator, those features, an ``on_estimate`` callback, ``compiled=False``, or a compiled loop
that differs from ``Estimator.step`` on a short drive of the machine,
:meth:`~tractionecu.estimation.compiled_loop.CompiledLoop.self_check`, run once per machine and process)
the loop is the step path's Python :meth:`Estimator.step`, stepped on the same dicts.  ``loop`` in the results says which ran and why.

Contract: the estimates equal the step path's to 1e-9 in every column (``tests/pipeline/test_batch.py``,
``tests/estimation/test_compiled_loop.py``).
"""

from __future__ import annotations

import gc
import math
import time
from operator import attrgetter
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..columns import concat
from ..errors import ConfigError
from ..estimation.estimator import Estimate, EstimatorConfig
from .replay import _Sink, _rows, check_rate, stepped_seconds

BLOCK = 4096
"""Estimates gathered before they are copied into arrays."""

SCALARS = ("t", "rho_s", "a", "v", "nis", "adapt")
"""Float fields of an estimate kept per step (arrays (n,))."""
VECTORS = (("mu", 4), ("slip", 4), ("omega", 4), ("P_diag", 10))
"""Vector fields of an estimate kept per step (arrays (n, m))."""
_FIELDS = attrgetter(*SCALARS, "nis_dof", "status", "valid", "mu", "slip", "omega", "P_diag", "sys_var",
                     "radius_scale", "radius_halfwidth", "radius_applied", "soil_class", "curve_state")

__all__ = ["BLOCK", "BatchSink", "counters", "drive", "loop_choice", "max_differences", "open_recording",
           "replay_batch", "replay_batch_rows"]


class _Ready:
    """A block already made into arrays (by the compiled loop), kept as one batch of the sink."""

    __slots__ = ("arr",)

    def __init__(self, arr: dict[str, Any]) -> None:
        self.arr = arr


class BatchSink(_Sink):
    """Estimates of a replay, gathered into arrays block by block.

    ``keep_all``: every step's arrays are kept (:meth:`arrays`).  ``rate_hz`` (> 0): the first step at or
    after each 1/rate boundary of the time axis is kept (:meth:`rate_arrays`; 0: every step), once older
    than ``hold_s`` (the lost-filter window).  ``map_times``: the step at or after each of these times
    (GNSS epochs), and the first and last step, are kept for the map (:meth:`map_arrays`), as the step
    path's sink picks them.

    The books (batches, a lost filter, the map's steps) are the step path's sink's
    (:class:`~tractionecu.pipeline.replay._Sink`); this class changes how a block becomes arrays, keeps
    pending blocks for the rate selection instead of writing them, and selects the rate rows as they age.
    """

    def __init__(self, *, keep_all: bool = True, rate_hz: float | None = None, hold_s: float = math.inf,
                 map_times: np.ndarray | None = None, block: int = BLOCK, csv_fh: Any = None) -> None:
        if csv_fh is not None and rate_hz is not None:
            raise ValueError("a batch sink writes estimates.csv (csv_fh) or selects rate rows (rate_hz), not both")
        super().__init__(keep_all, csv_fh, hold_s, map_times)
        self.block = int(block)
        self.rate_hz = rate_hz
        self.rate_rows: list[dict[str, Any]] = []
        self.steps_finite = self.steps_valid = 0
        self._bucket = -math.inf
        self._path: dict[int, str] = {}
        self.resolve: Callable[[dict[str, Any]], dict[str, Any]] | None = None
        """Resolves the compiled loop's ``curve_key`` column into ``curve`` and ``curve_path`` when the arrays
        go out (:meth:`CompiledLoop.resolve_curves <tractionecu.estimation.compiled_loop.CompiledLoop.
        resolve_curves>`), for the rows kept only."""

    # ------------------------------------------------------------------ input
    mark_lost = _Sink._mark_lost
    flush = _Sink._flush

    def extend(self, es: list[Estimate]) -> None:
        """Many estimates in time order (as :meth:`keep` one by one)."""
        for e in es:
            self.keep(e)

    def keep_arrays(self, arr: dict[str, Any]) -> None:
        """A block of estimates as arrays (:meth:`CompiledLoop.arrays
        <tractionecu.estimation.compiled_loop.CompiledLoop.arrays>`, with ``lost_since``): the same books as
        :meth:`keep` of each estimate in turn (a batch ends on each step that declares the filter lost,
        which then marks the lost period)."""
        lost = arr.pop("lost_since")
        n = lost.size
        start = 0
        for i in np.flatnonzero(~np.isnan(lost)).tolist():
            self._keep_ready(arr, start, i + 1, n)
            self._mark_lost(float(lost[i]))
            start = i + 1
        if start < n:
            self._keep_ready(arr, start, n, n)

    def _keep_ready(self, arr: dict[str, Any], start: int, stop: int, n: int) -> None:
        self._flush()
        part = arr if start == 0 and stop == n else _rows(arr, np.arange(start, stop))
        self.batch.append(_Ready(part))      # type: ignore[arg-type]
        self._flush()

    def _pends(self) -> bool:
        return self.rate_hz is not None or self.fh is not None

    def _age(self, upto: float) -> None:
        if self.fh is not None:
            self._write(upto)
        else:
            self._release(upto)

    def _end(self) -> None:
        if self.fh is not None:
            _Sink._end(self)
        else:
            self._release(math.inf)

    def _write(self, upto: float) -> None:
        """The step path's writing of the pending blocks older than ``upto`` [s] to ``estimates.csv``, each block's
        identified curves resolved first (its ``curve_path`` column)."""
        if self.resolve is not None:
            for b in self.pending:
                if not float(b["t"][-1]) < upto:
                    break
                if "curve_key" in b:
                    self.resolve(b)
        super()._write(upto)

    # ------------------------------------------------------------------ conversion
    def _to_arrays(self, b: list[Estimate]) -> dict[str, Any]:
        if len(b) == 1 and type(b[0]) is _Ready:
            return b[0].arr                        # type: ignore[attr-defined]
        n = len(b)
        rows = [_FIELDS(e) for e in b]
        cols = list(zip(*rows))
        arr: dict[str, Any] = {}
        for j, name in enumerate(SCALARS):
            arr[name] = np.array(cols[j], dtype=float)
        j = len(SCALARS)
        arr["nis_dof"] = np.array(cols[j], dtype=np.int64)
        arr["status"] = np.array(cols[j + 1], dtype=np.int64)
        arr["valid"] = np.array(cols[j + 2], dtype=bool)
        j += 3
        for name, _m in VECTORS:
            arr[name] = np.array(cols[j], dtype=float)
            j += 1
        sys_var = cols[j]
        arr["radius_scale"] = np.array(cols[j + 1], dtype=float)
        arr["radius_halfwidth"] = np.array(cols[j + 2], dtype=float)
        arr["radius_applied"] = np.array(cols[j + 3], dtype=float)
        arr["soil_class"] = list(cols[j + 4])
        states = cols[j + 5]
        # reported uncertainty: Estimate.sigma_mu = sqrt(P_mu + u_mu^2), sigma_rho_s = sqrt(P_rho + u_rho^2)
        # (u^2 = sys_var, shared between estimates; None: the filter's own P alone), over the block
        p = arr["P_diag"][:, 5:10]
        has = np.fromiter((s is not None for s in sys_var), dtype=bool, count=n)
        sv = np.zeros((n, 5))
        if has.any():
            sv[has] = np.array([s for s in sys_var if s is not None], dtype=float)
        tot = np.where(has[:, None], p + sv, p)
        sig = np.sqrt(tot)
        arr["sigma_mu"] = sig[:, :4]
        arr["sigma_rho_s"] = sig[:, 4].copy()
        # the identified μ(s) per step and its path ("class:<name>", "shape:<form>"; "" until identified)
        paths = self._path
        curves = []
        cpath = []
        for cs in states:
            c = None if cs is None else cs.curve
            curves.append(c)
            key = id(c)
            pth = paths.get(key)
            if pth is None:
                pth = c.path if c is not None else ""
                if len(paths) > 64:
                    paths.clear()
                paths[key] = pth
            cpath.append(pth)
        arr["curve"] = curves
        arr["curve_path"] = cpath
        return arr

    def _release(self, upto: float) -> None:
        """Select the rate rows of the blocks older than ``upto`` [s] (no lost filter can reach them)."""
        while self.pending and float(self.pending[0]["t"][-1]) < upto:
            b = self.pending.pop(0)
            t = b["t"]
            fin = np.isfinite(t)
            self.steps_finite += int(fin.sum())
            self.steps_valid += int((b["valid"] & fin).sum())
            rate = float(self.rate_hz or 0.0)
            if rate > 0:
                bucket = np.floor(t * rate)
                prev = np.concatenate([[self._bucket], bucket[:-1]])
                keep = fin & (bucket != prev)
                self._bucket = float(bucket[-1])
            else:
                keep = fin
            idx = np.flatnonzero(keep)
            if idx.size:
                self.rate_rows.append(_rows(b, idx))

    # ------------------------------------------------------------------ output
    def arrays(self) -> dict[str, Any]:
        return self._out(_concat(self.done))

    def rate_arrays(self) -> dict[str, Any]:
        return self._out(_concat(self.rate_rows))

    def map_arrays(self) -> dict[str, Any]:
        return self._out(_concat(self.map_rows))

    def _out(self, arr: dict[str, Any]) -> dict[str, Any]:
        if "curve_key" in arr and self.resolve is not None:
            self.resolve(arr)
        return arr


def _concat(parts: list[dict[str, Any]]) -> dict[str, Any]:
    if not parts:
        out: dict[str, Any] = {name: np.empty(0) for name in SCALARS + ("sigma_rho_s",)}
        for name, m in VECTORS + (("sigma_mu", 4), ("radius_scale", 2), ("radius_halfwidth", 2),
                                  ("radius_applied", 2)):
            out[name] = np.empty((0, m))
        out.update(nis_dof=np.empty(0, dtype=np.int64), status=np.empty(0, dtype=np.int64),
                   valid=np.empty(0, dtype=bool), soil_class=[], curve=[], curve_path=[])
        return out
    return concat(parts)


# ----------------------------------------------------------------------------- the run
def _batch_run_class() -> type:
    """replay's step function (:class:`~tractionecu.pipeline.replay._Run`: grid, groups, GNSS gate, the
    estimator of the machine) with the per-step loop replaced by the block-wise one (module doc)."""
    from .replay import _Run

    class _BatchRun(_Run):
        loop: Any = None
        """The compiled loop (:class:`~tractionecu.estimation.compiled_loop.CompiledLoop`), or None."""

        def _flush(self) -> None:
            if self.loop is None:
                super()._flush()
                return
            for arr in self.smoother.flush_arrays():
                self.sink.keep_arrays(arr)

        def _step(self, grid: np.ndarray) -> None:
            n = grid.size
            if n == 0:
                return
            loop = self.loop
            lists = loop is None               # the compiled loop takes the streams as arrays
            streams = [(grp.key, grp.key in self.inputs, *grp.at(grid, lists)) for grp in self.groups]
            if self.speed.t.size:
                from .signals import GNSS_SPEED
                from .steps import GNSS_COURSE

                streams.append((GNSS_SPEED, False, *self.speed.at(grid, lists)))
                streams.append((GNSS_COURSE, False, *self.course.at(grid, lists)))
            if loop is not None:
                args = loop.block_inputs(grid, streams)
                gc_on = gc.isenabled()
                for a in range(0, n, BLOCK):          # (a recording in memory is one grid: bounded arrays)
                    # the collector off within a block, as below (its passes over the curve updates' objects
                    # and the block's arrays), on between blocks, so what cycles there are go block by block
                    if gc_on:
                        gc.disable()
                    try:
                        wall = time.perf_counter()
                        out = loop.step_block(args[a:a + BLOCK])
                        self.loop_seconds += time.perf_counter() - wall
                        for arr in self.smoother.push_arrays(loop.arrays(out)):
                            self.sink.keep_arrays(arr)
                    finally:
                        if gc_on:
                            gc.enable()
                return
            wall = time.perf_counter()
            inputs: list[dict[str, Any]] = [{} for _ in range(n)]
            meas: list[dict[str, Any]] = [{} for _ in range(n)]
            for key, is_input, vals, new in streams:      # in the step path's order of keys
                target = inputs if is_input else meas
                for k in np.flatnonzero(new).tolist():
                    target[k][key] = vals[k]
            step, keep, cb, smooth = self.est.step, self.sink.keep, self.on_estimate, self.smoother.push
            gc_on = gc.isenabled()
            if gc_on:
                # the loop makes next to no reference cycles (5 objects over a 60 s replay); the collector's
                # passes over the block's estimates and argument dicts cost ≈ 4 % of the loop's CPU time
                # (re-enabled below, whatever happens)
                gc.disable()
            try:
                if cb is None:
                    for t, i, m in zip(grid.tolist(), inputs, meas):
                        for e in smooth(step(t, i, m)):
                            keep(e)
                else:
                    for t, i, m in zip(grid.tolist(), inputs, meas):
                        for e in smooth(step(t, i, m)):
                            keep(e)
                            cb(e)
            finally:
                if gc_on:
                    gc.enable()
            self.loop_seconds += time.perf_counter() - wall

    return _BatchRun


def open_recording(recording: Any, hold_bytes: int | None = None) -> tuple[Any, bool, Any]:
    """(recording, streamed, held blocks or None): a :class:`~tractionecu.recording.reader.Recording` as it
    is; a path surveyed (:func:`~tractionecu.pipeline.survey.survey_keep`) with the blocks of the replay's
    signals held for the one pass (module doc, "Decoding"), unless they pass ``hold_bytes`` (default
    :data:`~tractionecu.recording.reader.HOLD_MAX_BYTES`; 0: never hold)."""
    from .survey import REPLAY_SIGNALS, survey_keep
    from ..recording.reader import HOLD_MAX_BYTES, HeldBlocks, Recording, read_recording

    if isinstance(recording, Recording):
        return recording, False, None
    from ..recording import fastdecode

    fastdecode.use_compiled()                  # the candump lines checked compiled (numba: the loop loads it anyway)
    bound = HOLD_MAX_BYTES if hold_bytes is None else int(hold_bytes)
    hold = HeldBlocks(REPLAY_SIGNALS, bound) if bound > 0 else None
    return read_recording(recording, keep=survey_keep, hold=hold), True, hold


def _decode_note(hold: Any, used: bool) -> str:
    """``decode`` of the results: how the capture's signals reached the loop (module doc, "Decoding")."""
    if used:
        return (f"one pass: {hold.nbytes / 2**20:.1f} MiB of decoded blocks held by the survey "
                f"(bound {hold.max_bytes / 2**20:g} MiB)")
    why = ("no blocks held (bound 0)" if hold is None else
           f"the decoded blocks passed the bound of {hold.max_bytes / 2**20:g} MiB" if hold.over else
           "a signal the replay uses was not held")
    return f"streamed: the capture decoded again block by block ({why})"


def _run(recording: Any, sink: BatchSink | None, *, rate_hz: float, cfg: EstimatorConfig | None, sensors: Any,
         gate: Any, on_estimate: Callable[[Estimate], None] | None,
         make_sink: Callable[[Any, EstimatorConfig], BatchSink] | None = None,
         compiled: bool | None = None, hold_bytes: int | None = None) -> tuple[Any, Any, BatchSink]:
    from .replay import checked

    check_rate(rate_hz)                                # before the capture is read
    rec, streamed, hold = open_recording(recording, hold_bytes)
    checked(rec, recording, streamed)
    cfg = cfg or EstimatorConfig()
    if sink is None:
        sink = make_sink(rec, cfg) if make_sink is not None else BatchSink()
    run = drive(rec, streamed, hold, sink, rate_hz=rate_hz, cfg=cfg, sensors=sensors, gate=gate,
                on_estimate=on_estimate, compiled=compiled)
    return rec, run, sink


def drive(rec: Any, streamed: bool, hold: Any, sink: BatchSink, *, rate_hz: float, cfg: EstimatorConfig,
          sensors: Any, gate: Any, on_estimate: Callable[[Estimate], None] | None, compiled: bool | None) -> Any:
    """The estimator over a recording opened by :func:`open_recording` (``rec``, ``streamed``, ``hold``) into
    ``sink``: the loop of :func:`loop_choice`, the capture's blocks as :func:`open_recording` holds them or
    streamed again.  Returns the run (``est``, ``loop``, ``loop_used``, ``decode``, ``gps_mask``, ``gnss``,
    ``loop_seconds``)."""
    from .gnss import GnssGate
    from .replay import machine_of
    from ..recording.reader import held_signals

    vehicle, s0 = machine_of(rec)
    run = _batch_run_class()(rec, rate_hz, vehicle, sensors or s0, cfg, gate or GnssGate(), sink, on_estimate)
    run.loop_used = loop_choice(run.est, compiled, on_estimate)
    if run.loop_used == "compiled":
        from ..estimation.compiled_loop import CompiledLoop

        run.loop = CompiledLoop(run.est)
        sink.resolve = run.loop.resolve_curves
    run.decode = "in memory: the recording given decoded"
    blocks = None
    if streamed:
        names = run.signal_names()
        one = hold is not None and hold.blocks is not None and set(names) <= hold.names
        run.decode = _decode_note(hold, one)
        blocks = held_signals(rec, hold, names) if one else None      # (None: decoded again, streamed)
        hold = None                            # the held blocks go as they are fed
    run.feed_recording(rec, streamed, blocks)
    return run


def loop_choice(est: Any, compiled: bool | None, on_estimate: Any = None) -> str:
    """Which estimator loop batch replay runs: ``"compiled"``, or ``"python: <why>"`` (module doc).
    ``compiled``: None the compiled loop where supported, False never, True where supported (the same)."""
    if compiled is False:
        return "python: compiled=False"
    if on_estimate is not None:
        return "python: an on_estimate callback needs the Estimate objects"
    from ..estimation.compiled_loop import CompiledLoop, supported

    ok, why = supported(est)
    if not ok:
        return f"python: {why}"
    try:
        equal, diff = CompiledLoop.self_check(est)
    except Exception as exc:               # noqa: BLE001 - any failure of the check means: do not trust the loop
        return f"python: the compiled loop's self-check failed ({type(exc).__name__}: {exc})"
    if not equal:
        return f"python: the compiled loop's self-check against Estimator.step differs by {diff:.3g} on this machine"
    return "compiled"


def counters(run: Any) -> dict[str, int]:
    """The estimator's counters of a run of :func:`drive` (the compiled loop's, or the estimator's own)."""
    return run.loop.counters if run.loop is not None else dict(run.est.counters)


def replay_batch(recording: Any, *, rate_hz: float = 100.0, cfg: EstimatorConfig | None = None,
                 sensors: Any = None, gate: Any = None,
                 on_estimate: Callable[[Estimate], None] | None = None, compiled: bool | None = None,
                 hold_bytes: int | None = None) -> Any:
    """The estimates of every step of ``recording`` (a path, decoded once or streamed, or a
    :class:`~tractionecu.recording.reader.Recording`) as a :class:`~tractionecu.pipeline.replay.ReplayResult`
    (the step path's :func:`~tractionecu.pipeline.replay.replay` keys, plus ``curve_path``).  ``compiled``:
    see :func:`loop_choice`; the result's ``loop`` attribute says which loop ran.  ``hold_bytes``: the bound
    of the decoded blocks held for one pass (module doc, "Decoding"); the result's ``decode`` says how the
    capture was decoded."""
    from .replay import ReplayResult

    rec, run, sink = _run(recording, BatchSink(keep_all=True), rate_hz=rate_hz, cfg=cfg, sensors=sensors,
                          gate=gate, on_estimate=on_estimate, compiled=compiled, hold_bytes=hold_bytes)
    res = ReplayResult(sink.arrays(), float(rate_hz), run.gps_mask, counters(run), run.gnss, run.loop_seconds)
    res.loop = run.loop_used                  # type: ignore[attr-defined]
    res.decode = run.decode                   # type: ignore[attr-defined]
    return res


def replay_batch_rows(recording: str | Path | Any, *, rate_hz: float = 100.0, estimate_rate_hz: float = 1.0,
                      cfg: EstimatorConfig | None = None, sensors: Any = None, gate: Any = None,
                      map_rows: bool = True, compiled: bool | None = None,
                      hold_bytes: int | None = None) -> dict[str, Any]:
    """Replay ``recording`` keeping only the estimates at ``estimate_rate_hz`` (the first step at or after
    each 1/rate boundary; 0: every step) and, with ``map_rows``, the map's steps (one per GNSS epoch, the
    ones :func:`~tractionecu.mapping.from_replay.write_replay_map` samples).

    Returns ``recording`` (the :class:`~tractionecu.recording.reader.Recording`, a survey when streamed),
    ``rows`` (arrays at the rate), ``map`` (arrays of the map's steps), ``steps``, ``sim_seconds``,
    ``valid_steps`` and ``steps_finite`` (steps with a finite time), ``gps_mask``, ``counters``, ``gnss``,
    ``loop_seconds``, ``radius_calibration`` (:meth:`Estimator.calibration_summary`), ``loop`` (which
    estimator loop ran, :func:`loop_choice`; ``compiled`` chooses as there) and ``decode`` (how the capture was
    decoded: once, its blocks held by the survey up to ``hold_bytes``, or streamed; module doc, "Decoding").
    """
    if not estimate_rate_hz >= 0:
        raise ConfigError(f"estimate_rate_hz: must be >= 0, got {estimate_rate_hz}")

    def make(rec: Any, c: EstimatorConfig) -> BatchSink:
        return BatchSink(keep_all=False, rate_hz=float(estimate_rate_hz), hold_s=c.lost_after_s + c.max_gap_s + 1.0,
                         map_times=rec.gps.t if map_rows and len(rec.gps) else None)

    rec, run, sink = _run(recording, None, rate_hz=rate_hz, cfg=cfg, sensors=sensors, gate=gate,
                          on_estimate=None, make_sink=make, compiled=compiled, hold_bytes=hold_bytes)
    est = run.est
    return {"recording": rec, "rows": sink.rate_arrays(), "map": sink.map_arrays(), "steps": sink.rows,
            "sim_seconds": stepped_seconds(sink.t_last - sink.t_first if sink.rows > 1 else 0.0, sink.rows,
                                           float(rate_hz)),
            "valid_steps": sink.steps_valid, "steps_finite": sink.steps_finite, "gps_mask": run.gps_mask,
            "counters": counters(run), "gnss": dict(run.gnss), "loop_seconds": run.loop_seconds,
            "radius_calibration": est.calibration_summary() if hasattr(est, "calibration_summary") else {},
            "loop": run.loop_used, "decode": run.decode}


# ----------------------------------------------------------------------------- the contract
def max_differences(a: dict[str, Any], b: dict[str, Any]) -> dict[str, float]:
    """Largest absolute difference per column of two replays' arrays (the keys both hold, but ``curve``):
    0 for equal columns, inf where the shapes differ, where one is NaN and the other not, or where a text
    column differs anywhere; integer and bool columns as numbers."""
    out: dict[str, float] = {}
    for name in a:
        if name == "curve" or name not in b:
            continue
        x, y = a[name], b[name]
        if not isinstance(x, np.ndarray):
            out[name] = 0.0 if list(x) == list(y) else math.inf
            continue
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        if x.shape != y.shape:
            out[name] = math.inf
            continue
        nx, ny = np.isnan(x), np.isnan(y)
        if (nx != ny).any():
            out[name] = math.inf
            continue
        both = ~nx
        xs, ys = x[both], y[both]
        same = xs == ys                      # equal infinities too
        d = np.abs(xs[~same] - ys[~same])
        out[name] = float(d.max()) if d.size else 0.0
    return out
