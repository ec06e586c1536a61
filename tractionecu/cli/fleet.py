"""``tractionecu fleet replay|diagnose|map|drift SOURCE --out DIR``: a season of recordings on Dask.

SOURCE is a directory tree, a manifest CSV or a glob of recordings (:mod:`tractionecu.fleet.sources`:
machine and date from the path or the manifest's columns).  Tasks run one per recording on a local Dask
cluster (``--workers N``, ``--memory-limit`` per worker) or an existing one (``--scheduler ADDRESS``),
are retried when a worker dies (``--retries``), and skip recordings whose output matches the input's
content hash and the software version.  A failing recording goes to ``DIR/failures.parquet`` and the
run goes on.  ``--config TOML`` sets the replays' estimator configuration (``tractionecu replay --config``'s
``[estimator]`` table; part of the task key).

* ``replay`` — estimates at ``--estimate-rate-hz`` (default 1 Hz) and the map's 10 Hz samples to
  Parquet partitioned by machine and date, ``recordings.parquet`` (hours, radius calibration, ρ_s);
* ``diagnose`` — ``diagnosis.parquet``: machine, recording, effects, parameters with 95 % intervals;
* ``map`` — ``replay``, then the farm map ``DIR/farm_map`` (every recording merged cell by cell) and its
  exports (``--format``, default all that the installed extras allow) in ``DIR/farm_export``;
* ``drift`` — ``replay`` and (unless ``--no-diagnose``) ``diagnose``, then ``DIR/drift.md`` and
  ``DIR/drift.parquet``: machines whose parameters moved beyond their interval.

Exit codes: 0 every recording done, 1 bad arguments or SOURCE, 5 some recordings failed (listed).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ..errors import ConfigError
from ..mapping.tiles import lock_directory

EXIT_SOME_FAILED = 5
DESCRIPTION = """\
One task per recording of SOURCE (a directory tree <machine>/<date>/<recording>, a manifest CSV with
columns path[,machine,date,field], or a glob), on a local Dask cluster (--workers, --memory-limit) or an
existing one (--scheduler).  Done recordings (same content hash, same software) are skipped; a failing
one is listed in DIR/failures.parquet and the run goes on (exit code 5).

  replay    estimates (1 Hz) and map samples (10 Hz) to Parquet by machine and date; recordings.parquet
  diagnose  diagnosis.parquet: machine, recording, effects, parameters with 95 % intervals
  map       replay, then the farm map DIR/farm_map merged cell by cell, exported to DIR/farm_export
  drift     replay and diagnose, then DIR/drift.md: machines whose parameters moved beyond their interval"""
FORMATS_ALL = ("geotiff", "isoxml", "geojson", "png")


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fleet", help="replay, diagnose, map and watch a fleet's recordings on Dask",
                       description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("action", choices=("replay", "diagnose", "map", "drift"))
    p.add_argument("source", metavar="SOURCE", help="directory tree, manifest CSV (column path) or glob")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--workers", type=int, default=2,
                   help="local Dask worker processes (default: %(default)s; 0: in this process)")
    p.add_argument("--memory-limit", default="2GiB", help="memory per local worker (default: %(default)s)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="an existing Dask scheduler, e.g. tcp://10.0.0.5:8786 (instead of a local cluster)")
    p.add_argument("--retries", type=int, default=2, help="retries of a task whose worker died (default: %(default)s)")
    p.add_argument("--rate", type=float, default=100.0, help="estimator rate [Hz] (default: %(default)s)")
    p.add_argument("--estimate-rate-hz", type=float, default=1.0,
                   help="rate of the estimates written to Parquet [Hz] (default: %(default)s; 0: every step)")
    p.add_argument("--origin", default=None, metavar="LAT,LON",
                   help="farm map origin [deg] (default: the existing farm map's, else the first recording's first fix)")
    p.add_argument("--keep-csv", action="store_true",
                   help="keep each replay's estimates.csv (as tractionecu replay writes it)")
    p.add_argument("--batch", action="store_true",
                   help="replay on the batch path: the same estimates kept as arrays, Parquet at full precision, "
                        "no estimates.csv (otherwise estimates.csv as tractionecu replay writes it)")
    p.add_argument("--config", metavar="TOML", default=None,
                   help="estimator configuration of the replays ([estimator] table, as tractionecu replay --config)")
    p.add_argument("--format", action="append", default=None, choices=FORMATS_ALL,
                   help="farm map export format (repeatable; default: all)")
    p.add_argument("--no-diagnose", action="store_true", help="drift: only the replay's series")
    p.add_argument("--prune", action="store_true",
                   help="drop the recordings of earlier runs that are no longer at their path (kept otherwise)")
    p.add_argument("--no-progress", action="store_true", help="no progress line")
    p.set_defaults(func=run)


def _origin(text: str | None) -> tuple[float, float] | None:
    if text is None:
        return None
    try:
        lat, lon = (float(x) for x in text.split(","))
    except ValueError:
        raise ConfigError(f"--origin: expected LAT,LON in degrees, got {text!r}") from None
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):    # NaN fails too; checked before any replay
        raise ConfigError(f"--origin: latitude in [-90, 90] and longitude in [-180, 180] degrees, got {text!r}")
    return lat, lon


def run(args: argparse.Namespace) -> int:
    try:
        from ..fleet import runner
    except ImportError as e:
        print(f"tractionecu fleet: needs Dask and pyarrow: pip install 'tractionecu[fleet]' ({e})", file=sys.stderr)
        return 3
    from ..fleet.sources import discover

    origin = _origin(args.origin)
    estimator = None
    if args.config is not None:          # read and checked before any recording is looked at
        from ..estimation.config import load_estimator_config

        estimator = load_estimator_config(args.config)
    refs = discover(args.source, exclude=args.out)
    if not refs:
        raise ConfigError(f"{args.source}: no recording found (a directory with can.log, a capture file, a manifest)")
    stream = None if args.no_progress else sys.stderr
    # one run at a time in OUT: two removed each other's task directories, Parquet files and farm map as they
    # went (both exit 5, the estimates and map samples tables left empty, the farm map with one recording)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    lock = lock_directory(args.out, "another fleet run is writing into this directory: wait for it to end or "
                                    "choose another --out")
    try:
        return _run_locked(args, runner, refs, origin, stream, estimator)
    finally:
        lock.close()


def _run_locked(args: argparse.Namespace, runner: Any, refs: list, origin: Any, stream: Any, estimator: Any) -> int:
    client = runner.make_client(args.workers, args.memory_limit, args.scheduler)
    failed: list[dict] = []
    try:
        kw = dict(client=client, retries=args.retries, stream=stream, notes=sys.stderr, refs=refs, prune=args.prune)
        if args.action in ("replay", "map", "drift"):
            recs = runner.run_kind("replay", args.source, args.out, rate_hz=args.rate,
                                   estimate_rate_hz=args.estimate_rate_hz, origin=origin, keep_csv=args.keep_csv,
                                   batch=args.batch, estimator=estimator, **kw)
            failed += [r for r in recs if r.get("status") != "ok"]
            hours = sum(float(r.get("hours") or 0.0) for r in recs if r.get("status") == "ok")
            print(f"replay: {len(recs) - len(failed)}/{len(recs)} recordings, {hours:.2f} h; "
                  f"estimates in {args.out}/estimates, map samples in {args.out}/map_samples")
            if args.action == "map":
                s = runner.build_farm_map(args.out, recs, tuple(args.format or FORMATS_ALL), stream=sys.stderr)
                print(f"farm map: {s.get('map_dir')} from {s['recordings']} recordings "
                      f"({s.get('merged_now', 0)} merged now, {s.get('reused', 0)} already in it)")
                for fmt, path in (s.get("exports") or {}).items():
                    print(f"  {fmt}: {path}")
        if args.action == "diagnose" or (args.action == "drift" and not args.no_diagnose):
            recs = runner.run_kind("diagnose", args.source, args.out, **kw)
            bad = [r for r in recs if r.get("status") != "ok"]
            failed += bad
            print(f"diagnose: {len(recs) - len(bad)}/{len(recs)} recordings; table {args.out}/diagnosis.parquet")
        if args.action == "drift":
            d = runner.write_drift(args.out)
            print(f"drift: {d['series']} series; moved beyond their interval: {', '.join(d['moved']) or 'none'}; "
                  f"report {d['report']}")
    finally:
        runner.close_client(client)
    if failed:
        print(f"{len(failed)} recordings failed (table {args.out}/failures.parquet):", file=sys.stderr)
        for r in failed[:20]:
            print(f"  {r.get('kind')} {r.get('path')}: {r.get('error')}: {r.get('message')}", file=sys.stderr)
        return EXIT_SOME_FAILED
    return 0
