"""Decoding a recording: the reference paths against the fast paths, in one run, per 10 ms step.

On one simulated recording (``--scenario``, ``--seed``, ``--duration``; kept in ``--work``, or an existing
recording directory with ``--recording``), best of ``--repeat`` rounds, the two paths alternating within
each round, timed by ``time.process_time`` (CPU seconds of this process; the load average is printed
beside):

* ``full read``: :func:`tractionecu.recording.reader.read_recording` with ``reference=True`` (the GNSS log
  sentence by sentence: parse_line with pynmea2, EpochAssembler, align_gps) against the default (the NMEA
  fast path, epochs as lists);
* ``survey + stream``: what the replay and the batch path do for bounded memory: the survey
  (``read_recording(keep=survey_keep)``) and the capture read again block by block
  (:func:`~tractionecu.recording.reader.stream_signals` for the estimator's input signals), reference paths
  (the GNSS log sentence by sentence, every block decoded by ChunkDecoder with its statistics and every
  signal) against the fast paths;
* ``NMEA``: :func:`tractionecu.recording.gps.read_gps` with ``fast=False`` against ``fast=True``;
* ``batch decoding``: the batch path's decoding of a recording's path, survey + stream (fast paths, what it
  did before) against one pass (the survey holding the decoded blocks of the replay's signals,
  :class:`~tractionecu.recording.reader.HeldBlocks`, then :func:`~tractionecu.recording.reader.held_signals`;
  what :mod:`tractionecu.pipeline.batch` does for a recording under the bound).

The candump scan (:mod:`tractionecu.recording.fastdecode`) is shared by both paths, so its own speed-up is
in both columns; the figures of the code before it are in the notes of the change.  A step is one of the
step path's 100 Hz grid (:func:`~tractionecu.pipeline.replay.recording_grid`).  Each case also checks that
the two paths give the same arrays and statistics (``equal``).

    python benchmarks/decode.py [--scenario paper-three-soils] [--seed 0] [--duration 415] [--repeat 5]
                                [--work DIR | --recording DIR]
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

from _common import load_line as _load, simulate_recording   # benchmarks/_common.py


def _best(fns: list[Callable[[], Any]], repeat: int) -> list[float]:
    """Best CPU time of each function over ``repeat`` rounds, the functions alternating in each round."""
    best = [float("inf")] * len(fns)
    for _ in range(repeat):
        for k, fn in enumerate(fns):
            c0 = time.process_time()
            fn()
            best[k] = min(best[k], time.process_time() - c0)
    return best


def _same_arrays(a: Any, b: Any) -> bool:
    import numpy as np

    if isinstance(a, np.ndarray):
        return isinstance(b, np.ndarray) and a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    if isinstance(a, dict):
        return isinstance(b, dict) and list(a) == list(b) and all(_same_arrays(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return type(a) is type(b) and len(a) == len(b) and all(_same_arrays(x, y) for x, y in zip(a, b))
    return repr(a) == repr(b)


def _recording_arrays(rec: Any) -> Any:
    from tractionecu.recording.containers import GPS_FIELDS

    return ({n: (s.t, s.value, s.sa, s.unit) for n, s in rec.signals.items()},
            [getattr(rec.gps, f) for f in ("t",) + GPS_FIELDS], repr(rec.stats), rec.signal_sources)


def measure(path: Path, repeat: int = 5) -> list[dict[str, Any]]:
    """The cases of the module doc on the recording directory ``path``."""
    from tractionecu.pipeline.replay import machine_of, recording_grid
    from tractionecu.pipeline.select import groups_for
    from tractionecu.pipeline.survey import REPLAY_SIGNALS, survey_keep
    from tractionecu.recording.containers import RecordingStats
    from tractionecu.recording.gps import read_gps
    from tractionecu.recording.reader import HeldBlocks, held_signals, read_recording, stream_signals

    rec = read_recording(path)
    vehicle, _sensors = machine_of(rec)
    steps = int(recording_grid(rec, 100.0, vehicle).size)
    inputs = sorted({n for names in groups_for(vehicle).groups.values() for n in names if n in rec.signals})

    def full(reference: bool) -> Callable[[], Any]:
        return lambda: read_recording(path, reference=reference)

    def survey_stream(reference: bool) -> Callable[[], Any]:
        def run() -> Any:
            survey = read_recording(path, keep=survey_keep, reference=reference)
            return survey, list(stream_signals(survey, names=inputs, reference=reference))
        return run

    def one_pass() -> Any:
        hold = HeldBlocks(REPLAY_SIGNALS)
        survey = read_recording(path, keep=survey_keep, hold=hold)
        return survey, list(held_signals(survey, hold, inputs))

    def nmea(fast: bool) -> Callable[[], Any]:
        return lambda: read_gps(path / "gps.nmea", rec.stats.can_t_first, RecordingStats(), fast=fast)

    cases = [
        ("full read", full(True), full(False), _recording_arrays),
        ("survey + stream", survey_stream(True), survey_stream(False),
         lambda r: (_recording_arrays(r[0]), r[1])),
        ("NMEA", nmea(False), nmea(True), lambda tr: [getattr(tr, f) for f in vars(tr)]),
        ("batch decoding: survey + stream against one pass", survey_stream(False), one_pass,
         lambda r: (_recording_arrays(r[0]), r[1])),
    ]
    out = []
    for name, old, new, arrays in cases:
        equal = _same_arrays(arrays(old()), arrays(new()))         # also the first-use costs of both
        load0 = _load()
        t_old, t_new = _best([old, new], repeat)
        out.append({"case": name, "steps": steps, "old_s": t_old, "new_s": t_new, "equal": equal,
                    "load_before": load0, "load_after": _load()})
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="paper-three-soils")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=415.0, help="simulated seconds (default 415)")
    ap.add_argument("--repeat", type=int, default=5, help="rounds; the best CPU time of each path is kept")
    ap.add_argument("--work", type=Path, help="keep the simulated recording here (default: a temporary dir)")
    ap.add_argument("--recording", type=Path, help="an existing recording directory instead of simulating")
    args = ap.parse_args(argv)
    tmp = None
    if args.recording is not None:
        path = args.recording
        what = str(path)
    else:
        work = args.work or Path(tempfile.mkdtemp(prefix="decode_bench_"))
        tmp = None if args.work else work
        path = work / f"{args.scenario}_s{args.seed}_{args.duration:g}s"
        if not (path / "can.log").is_file():
            simulate_recording(path, args.seed, args.duration, args.scenario)
        what = f"{args.scenario} seed {args.seed}, {args.duration:g} s"
    try:
        print(f"decode benchmark: {what}; best CPU time of {args.repeat}, old and new alternating; {_load()}")
        ok = True
        for r in measure(path, args.repeat):
            us_old, us_new = 1e6 * r["old_s"] / r["steps"], 1e6 * r["new_s"] / r["steps"]
            ok &= r["equal"]
            print(f"{r['case']}: old {r['old_s']:.4f} s CPU = {us_old:.2f} us/step, new {r['new_s']:.4f} s CPU = "
                  f"{us_new:.2f} us/step over {r['steps']} steps: {r['old_s'] / r['new_s']:.2f}x faster; "
                  f"{'equal' if r['equal'] else 'NOT EQUAL'}; {r['load_before']} before, {r['load_after']} after")
        print(_load())
        return 0 if ok else 1
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    raise SystemExit(main())
