"""``tractionecu replay``'s job: a recording replayed into a run directory.

:func:`replay_to_dir` reads the recording, replays it and writes

* ``estimates.csv`` — one row per step (columns :data:`~.replay.CSV_COLUMNS`);
* ``config.toml`` — the resolved vehicle, sensor and estimator configuration;
* ``map/`` — tiles of the estimates at the accepted GNSS epochs
  (:func:`tractionecu.mapping.from_replay.write_replay_map`).

Two loops give the same estimates, float for float (:mod:`.batch`'s contract):

* ``compiled`` (the default where it covers the machine, :func:`~.batch.loop_choice`): batch replay's
  loop;
* ``step``: the step path the daemon runs (:class:`~.replay._Run`), one
  :meth:`Estimator.step <tractionecu.estimation.estimator.Estimator.step>` per grid time.  It is what runs
  with an ``on_estimate`` callback (it needs the :class:`~tractionecu.estimation.estimator.Estimate`
  objects), with ``compiled=False`` or where the compiled loop does not cover the machine.

The summary's ``loop`` says which ran and why.  Either way the capture is read twice: a survey (the signals
present, the statistics, the clock offset), then block by block into the loop (:data:`HOLD_BYTES`).

Either way ``estimates.csv`` is written as the steps age past the window a lost filter may reach back
(``lost_after_s`` + ``max_gap_s`` + 1 s), beside the file it replaces and renamed over it when the run is
through; the map keeps the step at or after each GNSS epoch.  A recording without the signals replay needs
raises :class:`~.replay.MissingSignals` before anything is written.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any, Callable

from ..estimation.estimator import Estimate, EstimatorConfig
from ..config import SensorSpec
from ..mapping.tiles import lock_directory
from ..recording.reader import Recording, read_recording
from . import batch
from .gnss import GnssGate
from .replay import CSV_COLUMNS, ReplayResult, _Run, _Sink, check_rate, checked, machine_of, resolved_config
from .survey import survey_keep

__all__ = ["HOLD_BYTES", "replay_to_dir"]

HOLD_BYTES = 0
"""The bound of the decoded blocks :func:`replay_to_dir`'s pass holds [B]: none by default, the capture is decoded
again block by block after the survey.  Holding them saved no time here (a 1.04 h replay took 8.2 s of CPU
either way, the decoding being compiled) and cost memory: a 4-hour replay, which must stay within 600 MB, peaked
at 623 MB with its 140 MiB of blocks held, and at 485–505 MB streamed (427 MB once the compiled loop's curve
cache was bounded, :data:`~tractionecu.estimation.compiled_loop.CURVE_CACHE_MAX`)."""


def replay_to_dir(recording: str | Path | Recording, out_dir: str | Path, *, rate_hz: float = 100.0,
                  cfg: EstimatorConfig | None = None, sensors: SensorSpec | None = None,
                  gate: GnssGate | None = None, write_map: bool = True,
                  on_estimate: Callable[[Estimate], None] | None = None, keep_arrays: bool | None = None,
                  compiled: bool | None = None, hold_bytes: int | None = None,
                  ) -> tuple[dict[str, Any], Recording, ReplayResult]:
    """Read, replay and write ``estimates.csv``, ``config.toml`` and the map (module doc).

    ``compiled``: None or True the compiled loop where it covers the machine, False the step path
    (:func:`~.batch.loop_choice`); ``hold_bytes``: the bound of the decoded blocks the compiled loop's single
    pass holds (:func:`~.batch.open_recording`; default :data:`HOLD_BYTES`).  Memory does not grow with the
    recording's length but for the held blocks (bounded), the GNSS track and the map's samples (one step per
    GNSS epoch).  The result's
    ``arrays`` hold every step only with ``keep_arrays`` (default: when the recording has ``truth.csv`` to
    score, or was given in memory); otherwise the map's steps.

    Returns the run summary (``steps``, ``sim_seconds``, ``read_seconds``, ``loop_seconds``,
    ``write_seconds``, ``wall_seconds``, ``realtime_factor``, ``counters``, ``gnss_gated``, ``loop``,
    ``decode``, output paths and map counts), the recording (for one given by its path, its survey: signals
    not kept whole are stubs of two samples) and the result.
    """
    wall0 = time.perf_counter()
    check_rate(rate_hz)                                # before the capture is read
    out = Path(out_dir)
    streamed = not isinstance(recording, Recording)
    step_path = compiled is False or on_estimate is not None
    hold = None
    if step_path:
        rec = read_recording(recording, keep=survey_keep) if streamed else recording
    else:
        rec, streamed, hold = batch.open_recording(recording, HOLD_BYTES if hold_bytes is None else hold_bytes)
    checked(rec, recording, streamed)
    if write_map:
        from ..mapping.from_replay import check_map_dir

        check_map_dir(out / "map")                        # before the run: an owner's folder is never replaced
    out.mkdir(parents=True, exist_ok=True)
    # One replay at a time in a directory: two wrote one estimates.csv.partial (the second truncated the
    # first's, whose later rows left a hole of NUL bytes in the estimates.csv it moved into place)
    lockf = lock_directory(out, "another replay is writing into this directory, or a service runs on it as its "
                                "state directory: choose another --out")
    try:
        return _replay_locked(rec, out, streamed, hold, wall0, rate_hz, cfg, sensors, gate, write_map, on_estimate,
                              keep_arrays, step_path)
    finally:
        lockf.close()


def _replay_locked(rec: Recording, out: Path, streamed: bool, hold: Any, wall0: float, rate_hz: float,
                   cfg: EstimatorConfig | None, sensors: SensorSpec | None, gate: GnssGate | None, write_map: bool,
                   on_estimate: Callable[[Estimate], None] | None, keep_arrays: bool | None, step_path: bool,
                   ) -> tuple[dict[str, Any], Recording, ReplayResult]:
    """:func:`replay_to_dir` once the recording is read (by :func:`~.batch.open_recording`, its blocks in ``hold``,
    unless ``step_path``) and ``out`` is locked."""
    read_s = time.perf_counter() - wall0
    vehicle, s0 = machine_of(rec)
    sensors = sensors or s0
    cfg = cfg or EstimatorConfig()
    gate = gate or GnssGate()
    if keep_arrays is None:
        keep_arrays = not streamed or rec.truth_csv_path is not None
    csv_path = out / "estimates.csv"
    # Written beside and renamed over estimates.csv when the run is through: a replay interrupted (Ctrl-C,
    # a read error) leaves the previous run's estimates.csv whole, with the products that belong to it.
    part_path = out / "estimates.csv.partial"
    hold_s = cfg.lost_after_s + cfg.max_gap_s + 1.0
    map_times = rec.gps.t if write_map and len(rec.gps) else None
    sink: Any
    try:
        with open(part_path, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(",".join(CSV_COLUMNS) + "\n")
            if step_path:
                sink = _Sink(keep_all=keep_arrays, csv_fh=fh, hold_s=hold_s, map_times=map_times)
                run = _Run(rec, rate_hz, vehicle, sensors, cfg, gate, sink, on_estimate)
                run.loop_used = ("python: an on_estimate callback needs the Estimate objects" if on_estimate
                                 else "python: compiled=False")
                run.decode = ("streamed: a survey, then the capture decoded again block by block" if streamed
                              else "in memory: the recording given decoded")
                run.feed_recording(rec, streamed)
                counters = dict(run.est.counters)
            else:
                sink = batch.BatchSink(keep_all=keep_arrays, csv_fh=fh, hold_s=hold_s, map_times=map_times)
                run = batch.drive(rec, streamed, hold, sink, rate_hz=rate_hz, cfg=cfg, sensors=sensors, gate=gate,
                                  on_estimate=None, compiled=None)
                counters = batch.counters(run)
        os.replace(part_path, csv_path)
    except BaseException:
        part_path.unlink(missing_ok=True)
        raise
    if sink.late_lost:                                    # pragma: no cover - hold_s covers the lost window
        raise RuntimeError(f"{sink.late_lost} lost periods reached estimates already written")
    arrays = sink.arrays() if keep_arrays else sink.map_arrays()
    res = ReplayResult(arrays, float(rate_hz), run.gps_mask, counters, run.gnss, run.loop_seconds,
                       sink.rows, sink.t_last - sink.t_first if sink.rows > 1 else 0.0)
    t_w = time.perf_counter()
    cfg_path = out / "config.toml"
    cfg_path.write_text(resolved_config(vehicle, sensors, cfg, rate_hz, gate), encoding="utf-8")
    summary_map: dict[str, Any] = {}
    if write_map:
        from ..mapping.from_replay import write_replay_map

        summary_map = write_replay_map(out, rec, sink.map_arrays() if keep_arrays else arrays,
                                       gps_mask=res.gps_mask)
    wall = time.perf_counter() - wall0
    sim_s = res.sim_seconds
    summary: dict[str, Any] = {
        "recording": str(rec.path), "steps": res.steps, "rate_hz": float(rate_hz), "sim_seconds": sim_s,
        "read_seconds": read_s, "loop_seconds": res.loop_seconds, "write_seconds": time.perf_counter() - t_w,
        "counters": res.counters, "gnss_gated": dict(res.gnss), "estimates_csv": str(csv_path),
        "config": str(cfg_path), **summary_map, "wall_seconds": wall,
        "radius_calibration": run.est.calibration_summary() if hasattr(run.est, "calibration_summary") else {},
        "loop": run.loop_used, "decode": run.decode,
        "realtime_factor": sim_s / wall if wall > 0 else float("inf"),
    }
    return summary, rec, res
