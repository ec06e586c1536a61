"""The fleet's tasks on Dask, the tables they fill, the farm map and the drift report.

Where the tasks run:

* ``workers`` ≥ 1 (default 2): a local Dask cluster (``distributed.LocalCluster``) of that many worker
  processes, one thread each, each with ``memory_limit`` (default ``"2GiB"``; the nanny restarts a
  worker past 95 % of it and the task runs again);
* ``scheduler="tcp://host:8786"``: an existing Dask cluster (its workers need tractionecu installed with
  the ``fleet`` extra and must see SOURCE and OUT at the same paths);
* ``workers=0``: in this process, one task after the other (debugging, tests of the logic).

A task that raises (a worker that died, :class:`MemoryError`) is retried ``retries`` times; a task that
still fails, and every recording its task reports as failed (:mod:`.tasks`), lands in
``failures.parquet``: the run goes on.  The progress line (stderr) shows recordings done of the total
(cached, failed), the hours of recording processed and the throughput as a multiple of real time.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
import resource
import sys
import time
from pathlib import Path
from typing import Any, Sequence, TextIO

from ..errors import ConfigError
from ..mapping.store import DEFAULT_MAX_RANGE_M
from . import store as fstore
from .sources import RecordingRef, discover, first_fix
from .tasks import copies, partition_file, run_task

log = logging.getLogger(__name__)

DEFAULT_WORKERS = 2
DEFAULT_MEMORY_LIMIT = "2GiB"
DEFAULT_RETRIES = 2


def _task_with_rss(spec: dict[str, Any]) -> dict[str, Any]:
    """:func:`~.tasks.run_task` and the worker process's peak resident memory so far [MB]."""
    rec = run_task(spec)
    rec["worker_peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    rec["worker_pid"] = os.getpid()
    return rec


class Progress:
    """The progress line: recordings done, hours processed, throughput."""

    def __init__(self, kind: str, total: int, stream: TextIO | None) -> None:
        self.kind, self.total, self.stream = kind, total, stream
        self.done = self.cached = self.failed = 0
        self.hours = 0.0
        self.t0 = time.perf_counter()

    def update(self, rec: dict[str, Any]) -> None:
        self.done += 1
        if rec.get("cached"):
            self.cached += 1
        elif rec.get("status") == "ok":
            self.hours += float(rec.get("hours") or 0.0)
        if rec.get("status") != "ok":
            self.failed += 1
        if self.stream is not None:
            tty = getattr(self.stream, "isatty", lambda: False)()
            end = "\n" if self.done == self.total or not tty else ""
            self.stream.write("\r" + self.line() + end)
            self.stream.flush()

    def line(self) -> str:
        wall = time.perf_counter() - self.t0
        x = self.hours * 3600.0 / wall if wall > 0 else 0.0
        return (f"fleet {self.kind}: {self.done}/{self.total} recordings ({self.cached} cached, {self.failed} failed), "
                f"{self.hours:.2f} h processed in {wall:.0f} s, {x:.0f}x real time")


def make_client(workers: int = DEFAULT_WORKERS, memory_limit: str | int = DEFAULT_MEMORY_LIMIT,
                scheduler: str | None = None) -> Any:
    """A ``distributed.Client``: to ``scheduler``, or on a new local cluster (module doc); None for
    ``workers=0`` without a scheduler."""
    if scheduler is None and workers == 0:
        return None
    try:
        from distributed import Client, LocalCluster
    except ImportError as e:  # pragma: no cover - the extra is installed in CI
        raise ConfigError(f"fleet needs Dask: pip install 'tractionecu[fleet]' ({e})") from None
    for name in ("distributed", "dask"):               # the cluster's own start/stop chatter
        logging.getLogger(name).setLevel(logging.ERROR)
    if scheduler is not None:
        return Client(scheduler)
    if workers < 0:
        raise ConfigError(f"--workers: must be >= 0, got {workers}")
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, memory_limit=memory_limit,
                           dashboard_address=None, silence_logs=logging.ERROR)
    return Client(cluster)


def close_client(client: Any) -> None:
    """Close a client from :func:`make_client` and the local cluster it started."""
    if client is None:
        return
    cluster = client.cluster
    client.close()
    if cluster is not None:
        cluster.close()


def run_specs(specs: Sequence[dict[str, Any]], client: Any = None, *, retries: int = DEFAULT_RETRIES,
              progress: Progress | None = None) -> list[dict[str, Any]]:
    """Run the task ``specs`` (on ``client``, else in this process); one record per spec, in spec order."""
    out: list[dict[str, Any] | None] = [None] * len(specs)

    def failed(i: int, e: BaseException) -> dict[str, Any]:
        s = specs[i]
        return {"kind": s["kind"], **s["ref"], "status": "failed", "error": type(e).__name__,
                "message": (str(e).splitlines() or [type(e).__name__])[0][:500], "cached": False, "hours": 0.0,
                "key": "", "recording_hash": ""}

    if client is None:
        for i, s in enumerate(specs):
            for attempt in range(retries + 1):
                try:
                    out[i] = _task_with_rss(s)
                    break
                except Exception as e:  # noqa: BLE001 - as a worker's death: retried, then reported
                    if attempt == retries:
                        out[i] = failed(i, e)
            if progress is not None:
                progress.update(out[i])  # type: ignore[arg-type]
        return out  # type: ignore[return-value]
    from distributed import as_completed

    futs = [client.submit(_task_with_rss, s, pure=False, retries=retries, key=f"fleet-{s['kind']}-{i}-{time.time_ns()}")
            for i, s in enumerate(specs)]
    index = {f.key: i for i, f in enumerate(futs)}
    for fut in as_completed(futs):
        i = index[fut.key]
        try:
            out[i] = fut.result()
        except Exception as e:  # noqa: BLE001 - KilledWorker and the like: reported, not fatal
            out[i] = failed(i, e)
        fut.release()
        if progress is not None:
            progress.update(out[i])  # type: ignore[arg-type]
    return out  # type: ignore[return-value]


def farm_origin(out: Path, refs: Sequence[RecordingRef], origin: tuple[float, float] | None) -> tuple[float, float] | None:
    """The farm frame's origin: ``origin``; else the existing farm map's; else the first fix of the first
    recording (sorted by machine, date, path) that has one."""
    if origin is not None:
        return (float(origin[0]), float(origin[1]))
    man = out / "farm_map" / "manifest.json"
    if man.is_file():
        m = json.loads(man.read_text(encoding="utf-8"))
        return (float(m["origin_lat"]), float(m["origin_lon"]))
    for r in refs:
        fix = first_fix(r.path)
        if fix is not None:
            return fix
    return None


def _table_rows(path: Path) -> list[dict[str, Any]]:
    """The rows of the Parquet table at ``path`` (NaN as None), none when it does not exist."""
    if not path.is_file():
        return []
    import pandas as pd

    return [{k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in r.items()}
            for r in pd.read_parquet(path).to_dict("records")]


def _update_table(path: Path, rows: list[dict[str, Any]], columns: tuple[str, ...], kind: str | None,
                  keep: Any = None, path_col: str = "path") -> list[dict[str, Any]]:
    """Write the table at ``path``: its rows of other kinds, its rows of ``kind`` for which ``keep(path)``
    is true (recordings this run does not cover, module doc of :func:`run_kind`), then ``rows``; returns the
    rows of ``kind`` it kept.  ``kind`` None: the rows of every kind are candidates for ``keep``."""
    kept_other: list[dict[str, Any]] = []
    kept: list[dict[str, Any]] = []
    for r in _table_rows(path):
        if kind is not None and r.get("kind", kind) != kind:
            kept_other.append(r)
        elif keep is not None and keep(str(r.get(path_col) or "")):
            kept.append(r)
    fstore.write_rows(kept_other + kept + rows, columns, path)
    return kept


_PART = re.compile(r"^machine=[^/]+/date=[^/]+/[0-9a-f]{24}\.parquet$")
"""A Parquet file a replay task writes under ``estimates/`` and ``map_samples/`` (:mod:`.tasks`)."""


def _prune_outputs(out: Path, rows: Sequence[dict[str, Any]]) -> int:
    """Remove the replay tasks' Parquet files under ``estimates/`` and ``map_samples/`` that belong to no
    recording of ``rows`` with status ok (a recording since changed, dropped, or now failing): the datasets
    hold the recordings table's recordings, once each.  Returns the files removed."""
    want = {partition_file(r["machine"], r["date"], r["recording_hash"]) for r in rows
            if r.get("status") == "ok" and r.get("recording_hash")}
    removed = 0
    for sub in ("estimates", "map_samples"):
        base = out / sub
        if not base.is_dir():
            continue
        for f in base.glob("machine=*/date=*/*.parquet"):
            rel = f.relative_to(base).as_posix()
            if _PART.match(rel) and rel not in want:
                f.unlink()
                removed += 1
    return removed


def run_kind(kind: str, source: str | Path, out: str | Path, *, client: Any = None, retries: int = DEFAULT_RETRIES,
             rate_hz: float = 100.0, estimate_rate_hz: float = 1.0, origin: tuple[float, float] | None = None,
             keep_csv: bool = False, stream: TextIO | None = sys.stderr,
             refs: Sequence[RecordingRef] | None = None, batch: bool = False,
             prune: bool = False, notes: TextIO | None = None, estimator: Any = None) -> list[dict[str, Any]]:
    """Run ``kind`` (``replay`` or ``diagnose``) over every recording of ``source`` into ``out``; update
    ``recordings.parquet``, ``failures.parquet`` and, for diagnosis, ``diagnosis.parquet``.  Returns the
    task records.  ``batch``: replay on the batch path (:mod:`tractionecu.pipeline.batch`: the same
    estimates, kept as arrays, Parquet written from them at full precision, no ``estimates.csv``;
    ``keep_csv`` writes each replay's ``estimates.csv`` as ``tractionecu replay`` does, Parquet from its text).
    ``estimator``: the replays' :class:`~tractionecu.estimation.config.EstimatorConfig` (default: the documented
    one); given, its TOML text is one of the tasks' options, so a changed configuration re-runs them.

    OUT accumulates a season: a run updates the recordings of its SOURCE and keeps, in every table, dataset
    and the farm map, the recordings of earlier runs that this SOURCE does not cover (a day's folder run
    after the season's tree adds that day).  ``prune``: those of them no longer at their path are dropped.
    A recording whose content changed is one recording with new results: the Parquet files of its old
    content are removed (:func:`_prune_outputs`), never left beside the new ones.  A recording whose files
    are byte for byte another's of the same machine and date (:func:`~.tasks.copies`) is left out.  What was
    kept, dropped, removed or left out is said on ``notes`` (else on ``stream``, the progress line's)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    refs = list(refs) if refs is not None else discover(source, exclude=out)
    if not refs:
        raise ConfigError(f"{source}: no recording found (a directory with can.log, a capture file, a manifest)")
    if kind == "replay":
        if not rate_hz > 0:
            raise ConfigError(f"--rate: must be > 0, got {rate_hz}")
        if not estimate_rate_hz >= 0:
            raise ConfigError(f"--estimate-rate-hz: must be >= 0, got {estimate_rate_hz}")
        org = farm_origin(out, refs, origin)
        options: dict[str, Any] = {"rate_hz": float(rate_hz), "estimate_rate_hz": float(estimate_rate_hz),
                                   "origin": list(org) if org is not None else None, "keep_csv": bool(keep_csv),
                                   "batch": bool(batch)}
        if estimator is not None:
            options["estimator"] = estimator.to_toml()
    elif kind == "diagnose":
        options = {}
    else:
        raise ConfigError(f"unknown fleet task {kind!r}")
    here = {str(r.path) for r in refs}              # a copy's path too: this run covers it
    notes = notes if notes is not None else stream
    dup = copies(refs)
    if dup:
        # one drive filed twice for one machine and day (one task key, one output): run once, so that the
        # farm map counts its samples once and the recordings table lists each path once
        refs = [r for r in refs if r.path not in {c.path for c, _ in dup}]
        if notes is not None:
            which = ", ".join(f"{c.path} (= {o.path})" for c, o in dup[:5]) + (" …" if len(dup) > 5 else "")
            print(f"fleet {kind}: {len(dup)} recording(s) hold the same files as another of their machine and "
                  f"date and are left out, so that their data count once: {which}", file=notes)
    specs = [{"kind": kind, "ref": r.as_dict(), "out": str(out), "options": options} for r in refs]
    recs = run_specs(specs, client, retries=retries, progress=Progress(kind, len(specs), stream))
    resolved = {_resolved(p) for p in here}

    def earlier(path: str) -> bool:
        """A recording of an earlier run that this run does not cover: kept, unless ``prune`` and it is gone."""
        if not path or path in here or _resolved(path) in resolved:
            return False
        return not (prune and not Path(path).exists())

    before = {str(r.get("path")) for r in _table_rows(out / "recordings.parquet") if r.get("kind") == kind}
    kept = _update_table(out / "recordings.parquet", [{**r, "path": r.get("path")} for r in recs],
                         fstore.RECORDINGS_COLUMNS, kind, earlier)
    kept_paths = {str(k.get("path")) for k in kept}
    _update_table(out / "failures.parquet", [r for r in recs if r.get("status") != "ok"], fstore.FAILURE_COLUMNS,
                  kind, kept_paths.__contains__)
    dropped = len(before - here - kept_paths)
    gone = sum(1 for k in kept if not Path(str(k.get("path"))).exists())
    removed = 0
    if kind == "replay":
        removed = _prune_outputs(out, kept + list(recs))
    elif kind == "diagnose":
        rows = [row for r in recs if r.get("status") == "ok" for row in r.get("rows", [])]
        _update_table(out / "diagnosis.parquet", rows, fstore.DIAGNOSIS_COLUMNS, None, kept_paths.__contains__,
                      path_col="recording")
    if notes is not None and (kept or dropped or removed):
        said = [f"{len(kept)} recording(s) of earlier runs that this SOURCE does not cover kept"
                + (f" ({gone} no longer at their path: --prune drops them)" if gone else "")] if kept else []
        if dropped:
            said.append(f"{dropped} no longer at their path dropped")
        if removed:
            said.append(f"{removed} Parquet file(s) of changed or dropped recordings removed")
        print(f"fleet {kind}: " + "; ".join(said), file=notes)
    return recs


def _resolved(path: str) -> str:
    try:
        return str(Path(path).resolve())
    except OSError:
        return path


def build_farm_map(out: str | Path, recs: Sequence[dict[str, Any]], formats: Sequence[str] = (),
                   stream: TextIO | None = None) -> dict[str, Any]:
    """Merge the farm-frame maps of the replay records ``recs`` and of the earlier recordings
    ``recordings.parquet`` keeps (:func:`run_kind`) into ``OUT/farm_map`` (:mod:`.merge`): only the new ones
    into an existing farm map that holds nothing else, else all anew (``left_out``: the earlier farm map's
    recordings no longer among them, said on ``stream``); export ``formats``
    (:data:`tractionecu.mapping.export.FORMATS`) into ``OUT/farm_export/``."""
    from .merge import merge_maps, merged_inputs

    out = Path(out)
    paths = {str(r.get("path")) for r in recs}
    # the recordings of earlier runs the table keeps (:func:`run_kind`) are the farm map's too
    earlier = [r for r in _table_rows(out / "recordings.parquet")
               if r.get("kind") == "replay" and str(r.get("path")) not in paths
               and (out / "tasks" / "replay" / str(r.get("key")) / "farm_map").is_dir()]
    ok = sorted((r for r in list(recs) + earlier if r.get("status") == "ok" and r.get("map_samples")),
                key=lambda r: (r["machine"], r["date"], r["path"]))
    far = [r for r in recs if r.get("status") == "ok" and (r.get("map_beyond_range") or 0) > 0]
    if far and stream is not None:
        # a recording of another farm (or a farm map whose origin is elsewhere): its epochs there are refused
        which = ", ".join(f"{r['path']} ({r['map_beyond_range']} epochs)" for r in far[:5])
        print(f"fleet map: {len(far)} recording(s) have GNSS epochs beyond the farm map's range "
              f"({DEFAULT_MAX_RANGE_M / 1000.0:.0f} km from its origin), which are not mapped: {which}"
              + (" …" if len(far) > 5 else "") + "; map that farm into another OUT, or give --origin", file=stream)
    empty = [r for r in recs if r.get("status") == "ok" and not r.get("map_samples") and r not in far]
    if empty and stream is not None:
        # replayed, yet nothing of them in the farm map: the count of recordings it is made from says only that
        def valid(r: dict[str, Any]) -> str:
            v = r.get("valid_share")
            return "" if v is None or not math.isfinite(float(v)) else f" (valid estimates at {float(v):.0%} of steps)"

        which = ", ".join(f"{r['path']}{valid(r)}" for r in empty[:5]) + (" …" if len(empty) > 5 else "")
        print(f"fleet map: {len(empty)} recording(s) replayed put no sample in the farm map (no GNSS position, or "
              f"no valid estimate at one): {which}", file=stream)
    keys = [r["key"] for r in ok]
    dirs = {r["key"]: out / "tasks" / "replay" / r["key"] / "farm_map" for r in ok}
    farm = out / "farm_map"
    have = merged_inputs(farm) if farm.is_dir() else []
    summary: dict[str, Any] = {"recordings": len(ok)}
    if not ok:
        summary["map_dir"] = None
        return summary
    if have and set(have) <= set(keys):
        new = [k for k in keys if k not in set(have)]
        if new:
            merge_maps([farm] + [dirs[k] for k in new], farm, names=[""] + new)
        summary.update(merged_now=len(new), reused=len(have))
    else:
        taken = set(keys)
        left_out = [k for k in have if k not in taken]
        merge_maps([dirs[k] for k in keys], farm, names=keys)
        summary.update(merged_now=len(keys), reused=0, left_out=len(left_out))
        if left_out and stream is not None:
            # a recording that changed, was dropped (--prune) or whose replay failed leaves the farm map
            print(f"fleet map: the farm map was rebuilt from {len(keys)} recording(s); {len(left_out)} "
                  "recording(s) of the earlier farm map are not among them (changed, replayed by another software "
                  "version, which makes every task new, dropped, or their replay failed) and are no longer in it", file=stream)
    summary["map_dir"] = str(farm)
    exports = {}
    if formats:
        from ..mapping.export import DEFAULT_OUT, MissingExtraError, export

        for fmt in formats:
            try:
                exports[fmt] = str(export(farm, fmt, out / "farm_export" / DEFAULT_OUT[fmt]))
            except MissingExtraError as e:
                exports[fmt] = f"not written: {e}"
                if stream is not None:
                    print(f"fleet map: {fmt}: {e}", file=stream)
    summary["exports"] = exports
    return summary


def write_drift(out: str | Path) -> dict[str, Any]:
    """``OUT/drift.parquet`` and ``OUT/drift.md`` from ``recordings.parquet`` and ``diagnosis.parquet``
    (:mod:`.drift`); returns the machines that moved and the paths."""
    import pandas as pd

    from .drift import drift_table, report_markdown, series_rows

    out = Path(out)
    recs = pd.read_parquet(out / "recordings.parquet") if (out / "recordings.parquet").is_file() else None
    diag = pd.read_parquet(out / "diagnosis.parquet") if (out / "diagnosis.parquet").is_file() else None
    table = drift_table(series_rows(recs, diag))
    cols = ("machine", "series", "recordings", "dates", "first_date", "first_value", "first_hw95", "last_date",
            "last_value", "last_hw95", "change", "slope_per_day", "moved")
    fstore.write_rows(table, cols, out / "drift.parquet")
    (out / "drift.md").write_text(report_markdown(table), encoding="utf-8")
    moved = sorted({r["machine"] for r in table if r["moved"] and not r["series"].startswith("rho_s@")})
    return {"moved": moved, "series": len(table), "report": str(out / "drift.md"), "table": str(out / "drift.parquet")}


__all__ = ["DEFAULT_MEMORY_LIMIT", "DEFAULT_RETRIES", "DEFAULT_WORKERS", "Progress", "build_farm_map",
           "close_client", "farm_origin", "make_client", "run_kind", "run_specs", "write_drift"]
