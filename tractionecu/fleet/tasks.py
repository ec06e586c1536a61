"""One task per recording: replay or diagnose it, keyed by the input's content and the software.

A task's output lives in ``OUT/tasks/<kind>/<key>/``, ``key`` a digest of the kind, the recording's
content hash (:func:`content_hash`: every file of the recording directory, or the capture file and
its GNSS log), the software version (:func:`software_version`: the package version and a digest of
its Python sources, so a changed estimator re-runs everything) and the task's options.  ``done.json``
is written last (atomically): a re-run finds it and returns its record without replaying
(``cached`` true) when the Parquet files it lists (``outputs``) are all there.  A recording that fails
(unreadable, missing signals, any error of the pipeline) gives a record with ``status`` ``"failed"``, the
error's type and message; it is not cached, so a re-run tries it again.  Only a worker that dies (out of memory, killed) raises: the scheduler retries
those (:mod:`.runner`).

Replay (:func:`replay_task`) writes

* the replay's own output (:func:`~tractionecu.pipeline.rundir.replay_to_dir`, streamed, bounded
  memory) in ``replay/`` (``estimates.csv`` removed once converted, unless ``keep_csv``);
* the estimates at ``estimate_rate_hz`` (the first step at or after each 1/rate boundary; 0: every
  step) to ``OUT/estimates/machine=M/date=D/<hash>.parquet`` and the map's 10 Hz samples to
  ``OUT/map_samples/machine=M/date=D/<hash>.parquet`` (``hash``: the recording's content hash, so a
  re-run under a new software version replaces the file) (schemas in :mod:`.store`);
* the recording's map in the farm frame (origin ``origin``) in ``farm_map/``, with the cells it
  touched (``contributors.parquet``), for :mod:`.merge`.

Diagnosis (:func:`diagnose_task`) runs :func:`tractionecu.diagnose.diagnose_path` into ``diagnose/``
and returns its effects and parameters with their 95 % intervals as rows of the diagnosis table.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import shutil
import time
import traceback
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .. import __version__

KINDS = ("replay", "diagnose")


# ----------------------------------------------------------------------------- keys
def recording_files(path: str | Path) -> list[Path]:
    """The files of a recording: for a directory every regular file in it, sorted by name; for a capture
    file the file and the GNSS log ``tractionecu replay`` reads beside it."""
    p = Path(path)
    if p.is_dir():
        return sorted(f for f in p.iterdir() if f.is_file())
    return [p] + [f for f in (p.with_suffix(".nmea"), p.parent / "gps.nmea") if f.is_file()]


def content_hash(path: str | Path) -> str:
    """SHA-256 over the recording's files (:func:`recording_files`), names and contents."""
    h = hashlib.sha256()
    for f in recording_files(path):
        h.update(f.name.encode() + b"\0")
        with open(f, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        h.update(b"\0")
    return h.hexdigest()


@functools.lru_cache(maxsize=1)
def software_version() -> str:
    """``<package version>+<first 12 hex of a SHA-256 over the package's Python sources>``."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for f in sorted(root.rglob("*.py")):
        h.update(str(f.relative_to(root)).encode() + b"\0" + f.read_bytes())
    return f"{__version__}+{h.hexdigest()[:12]}"


def copies(refs: Sequence[Any]) -> list[tuple[Any, Any]]:
    """(copy, original) of every recording of ``refs`` with an earlier one's machine, date and field whose
    files are byte for byte that one's (same names and :func:`content_hash`): one drive filed twice, with
    one task key (:func:`task_key`), so one output for both.  Only recordings whose file names and sizes
    agree are hashed here; one that cannot be read is left to its task."""
    alike: dict[tuple[Any, ...], list[Any]] = {}
    for r in refs:
        try:
            sig = (r.machine, r.date, r.field, *((f.name, f.stat().st_size) for f in recording_files(r.path)))
        except OSError:
            continue
        alike.setdefault(sig, []).append(r)
    out = []
    for group in alike.values():
        if len(group) < 2:
            continue
        first: dict[str, Any] = {}
        for r in group:
            try:
                h = content_hash(r.path)
            except OSError:
                continue
            if h in first:
                out.append((r, first[h]))
            else:
                first[h] = r
    return out


def task_key(kind: str, chash: str, options: dict[str, Any]) -> str:
    """The task's output key (module doc)."""
    blob = json.dumps({"kind": kind, "content": chash, "software": software_version(), "options": options},
                      sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:24]


def _safe(s: str) -> str:
    """A partition value that is one path segment."""
    return "".join(c if c.isalnum() or c in "-_.@" else "_" for c in str(s)) or "_"


def partition_file(machine: str, date: str, chash: str) -> str:
    """A recording's Parquet file under ``estimates/`` and ``map_samples/``: ``machine=M/date=D/<hash>.parquet``,
    named by the content hash (module doc)."""
    return f"machine={_safe(machine)}/date={_safe(date)}/{str(chash)[:24]}.parquet"


def _atomic_json(path: Path, obj: Any) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, indent=1, default=_json_default), encoding="utf-8")
    os.replace(tmp, path)


def _json_default(o: Any) -> Any:
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


# ----------------------------------------------------------------------------- the task
def run_task(spec: dict[str, Any]) -> dict[str, Any]:
    """Run one task ``spec`` (``kind``, ``ref``: a :class:`~.sources.RecordingRef` as a dict, ``out``,
    ``options``) unless its ``done.json`` exists; returns its record (module doc)."""
    t0 = time.perf_counter()
    c0 = time.process_time()
    ref = spec["ref"]
    kind = spec["kind"]
    base = {"kind": kind, **ref, "software": software_version()}
    try:
        chash = content_hash(ref["path"])
    except OSError as e:
        return {**base, "status": "failed", "error": type(e).__name__, "message": str(e), "key": "",
                "recording_hash": "", "cached": False, "hours": 0.0}
    # the machine, date and field place the outputs (Parquet partitions, the farm map's contributors)
    key = task_key(kind, chash, {**spec.get("options", {}), "machine": ref["machine"], "date": ref["date"],
                                 "field": ref.get("field", "")})
    tdir = Path(spec["out"]) / "tasks" / kind / key
    done = tdir / "done.json"
    if done.is_file():
        try:
            rec = json.loads(done.read_text(encoding="utf-8"))
            # its Parquet files too (removed with OUT/estimates, or as a changed recording's): else run again
            if all((Path(spec["out"]) / o).is_file() for o in rec.get("outputs", ())):
                rec["cached"] = True
                return rec
        except ValueError:
            pass                                     # a damaged record: run again
    base.update(key=key, recording_hash=chash, cached=False)
    if tdir.exists():
        shutil.rmtree(tdir)                          # a half-done earlier attempt
    tdir.mkdir(parents=True)
    try:
        fn = replay_task if kind == "replay" else diagnose_task
        out = fn(ref, key, chash, tdir, Path(spec["out"]), spec.get("options", {}))
    except MemoryError:
        raise
    except Exception as e:  # noqa: BLE001 - any failure of one recording is reported, never fatal
        return {**base, "status": "failed", "error": type(e).__name__, "message": str(e).splitlines()[0][:500]
                if str(e) else type(e).__name__, "traceback": traceback.format_exc(limit=6), "hours": 0.0,
                "wall_seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0}
    rec = {**base, "status": "ok", **out, "wall_seconds": time.perf_counter() - t0,
           "cpu_seconds": time.process_time() - c0, "pid": os.getpid()}
    _atomic_json(done, rec)
    return rec


# ----------------------------------------------------------------------------- replay
def replay_task(ref: dict[str, str], key: str, chash: str, tdir: Path, out: Path,
                options: dict[str, Any]) -> dict[str, Any]:
    """Replay one recording (module doc); returns the recording's row of the recordings table."""
    from ..mapping.from_replay import write_replay_map
    from ..mapping.store import MapStore
    from ..pipeline.rundir import replay_to_dir
    from . import store as fstore
    from .sources import field_of_fix

    rate = float(options.get("rate_hz", 100.0))
    est_rate = float(options.get("estimate_rate_hz", 1.0))
    cfg = estimator_config(options)
    if options.get("batch", False) and not options.get("keep_csv", False):
        summary, rec, map_arrays, gps_mask, rows = _replay_batch(ref["path"], tdir / "replay", rate, est_rate, cfg)
    else:
        summary, rec, res = replay_to_dir(ref["path"], tdir / "replay", rate_hz=rate, write_map=True,
                                          keep_arrays=False, cfg=cfg)
        map_arrays, gps_mask, rows = res.arrays, res.gps_mask, None
    gps = rec.gps
    ok = np.isfinite(gps.lat) & np.isfinite(gps.lon) if len(gps) else np.zeros(0, bool)
    field = ref.get("field") or (field_of_fix(float(gps.lat[ok][0]), float(gps.lon[ok][0])) if ok.any() else "")
    # named by the content, not the key: a re-run under a new software version replaces the file
    part = partition_file(ref["machine"], ref["date"], chash)
    ident = {"recording": ref["path"], "recording_hash": chash, "field": field}
    if rows is not None:
        est = estimates_arrays_to_parquet(rows, out / "estimates" / part, ident)
        est.update(steps=summary["steps_finite"], valid_steps=summary["valid_steps"])
    else:
        csv_path = Path(summary["estimates_csv"])
        est = fstore.estimates_csv_to_parquet(csv_path, out / "estimates" / part, est_rate, ident)
        if not options.get("keep_csv", False):
            csv_path.unlink()
    origin = options.get("origin")
    n_map = 0
    n_far = 0
    outputs = [f"estimates/{part}"]                  # the Parquet files of the task, relative to OUT
    rho = {"rho_s_mean": math.nan, "rho_s_hw95": math.nan, "rho_s_blocks": 0}
    if origin is not None and ok.any() and len(map_arrays["t"]):
        fdir = tdir / "farm_map"
        with MapStore(fdir, float(origin[0]), float(origin[1])) as st:
            msum = write_replay_map(tdir, rec, map_arrays, gps_mask=gps_mask, store=st)
        n_far = int(msum.get("map_refused", {}).get("range", 0))
        st = MapStore.open(fdir, read_only=True)
        n_map = fstore.map_samples_to_parquet(st, out / "map_samples" / part, ident)
        outputs.append(f"map_samples/{part}")
        fstore.contributors_of(st, ref["machine"], ref["date"], fdir / "contributors.parquet")
        rho = rho_s_of_field(st.track_values(), st.layers)
    cal = summary.get("radius_calibration") or {}
    row: dict[str, Any] = {
        "outputs": outputs,
        "field": field, "hours": float(summary["sim_seconds"]) / 3600.0, "steps": int(summary["steps"]),
        "loop_seconds": float(summary["loop_seconds"]), "estimates_rows": est["rows"], "map_samples": n_map,
        "map_beyond_range": n_far,
        "map_samples_own_frame": int(summary.get("map_samples", 0)),
        "valid_share": est["valid_steps"] / est["steps"] if est["steps"] else math.nan, **rho,
    }
    for axle in ("front", "rear"):
        a = cal.get(axle) or {}
        row[f"radius_scale_{axle}"] = _f(a.get("scale"))
        row[f"radius_hw95_{axle}"] = _f(a.get("halfwidth95"))
        row[f"radius_blocks_{axle}"] = int(a.get("blocks") or 0)
    return row


def estimator_config(options: dict[str, Any]) -> Any:
    """The replays' estimator configuration: the TOML text of the task's ``estimator`` option, else the default."""
    import tomllib

    from ..estimation.config import EstimatorConfig

    text = options.get("estimator")
    if text is None:
        return EstimatorConfig()
    return EstimatorConfig.from_mapping(tomllib.loads(text)["estimator"])


def _replay_batch(path: str, run_dir: Path, rate: float, est_rate: float, cfg: Any
                  ) -> tuple[dict[str, Any], Any, dict[str, Any], np.ndarray, dict[str, Any]]:
    """The batch path (:func:`tractionecu.pipeline.batch.replay_batch_rows`): the estimates at ``est_rate``
    and the map's steps as arrays, no ``estimates.csv``; ``config.toml`` and the recording's own map in
    ``run_dir`` as :func:`~tractionecu.pipeline.rundir.replay_to_dir` writes them.  Returns (summary, recording,
    map arrays, GNSS mask, rows)."""
    from ..pipeline.batch import replay_batch_rows
    from ..mapping.from_replay import write_replay_map
    from ..pipeline.gnss import GnssGate
    from ..pipeline.replay import machine_of, resolved_config

    b = replay_batch_rows(path, rate_hz=rate, estimate_rate_hz=est_rate, cfg=cfg)
    rec = b["recording"]
    run_dir.mkdir(parents=True, exist_ok=True)
    vehicle, sensors = machine_of(rec)
    (run_dir / "config.toml").write_text(resolved_config(vehicle, sensors, cfg, rate, GnssGate()),
                                         encoding="utf-8")
    summary = {"steps": b["steps"], "sim_seconds": b["sim_seconds"], "loop_seconds": b["loop_seconds"],
               "steps_finite": b["steps_finite"], "valid_steps": b["valid_steps"],
               "radius_calibration": b["radius_calibration"],
               **write_replay_map(run_dir, rec, b["map"], gps_mask=b["gps_mask"])}
    return summary, rec, b["map"], b["gps_mask"], b["rows"]


def estimates_arrays_to_parquet(rows: dict[str, Any], out_path: Path, ident: dict[str, str]) -> dict[str, int]:
    """Estimates as arrays (:func:`tractionecu.pipeline.batch.replay_batch_rows`' ``rows``) to Parquet with
    the schema of :func:`.store.estimates_csv_to_parquet` (the columns of ``estimates.csv`` and ``ident``),
    at full precision (the step path's went through the text of ``estimates.csv``); returns ``rows``."""
    import pyarrow as pa

    from ..model.vehicle import STATE_NAMES, WHEELS
    from ..pipeline.replay import CSV_COLUMNS

    n = int(rows["t"].size)
    cols: dict[str, Any] = {"t": rows["t"], "rho_s": rows["rho_s"], "a": rows["a"], "v": rows["v"],
                            "nis": rows["nis"], "adapt": rows["adapt"], "sigma_rho_s": rows["sigma_rho_s"]}
    for name, pre in (("mu", "mu"), ("slip", "slip"), ("omega", "omega"), ("sigma_mu", "sigma_mu")):
        for j, w in enumerate(WHEELS):
            cols[f"{pre}_{w}"] = rows[name][:, j]
    for j, sn in enumerate(STATE_NAMES):
        cols[f"var_{sn}"] = rows["P_diag"][:, j]
    for name, pre in (("radius_scale", "scale"), ("radius_halfwidth", "hw95"), ("radius_applied", "applied")):
        for j, ax in enumerate(("front", "rear")):
            cols[f"radius_{pre}_{ax}"] = rows[name][:, j]
    arrays = []
    for c in CSV_COLUMNS:
        if c in ("soil_class", "curve_path"):
            arrays.append(pa.array([str(x) for x in rows[c]], pa.string()))
        elif c in ("nis_dof", "status"):
            arrays.append(pa.array(np.asarray(rows[c], dtype=np.int64), pa.int64()))
        elif c == "valid":
            arrays.append(pa.array(np.asarray(rows[c], dtype=bool), pa.bool_()))
        else:
            arrays.append(pa.array(np.ascontiguousarray(cols[c], dtype=np.float64), pa.float64()))
    names = list(CSV_COLUMNS)
    for k in ("recording", "recording_hash", "field"):
        arrays.append(pa.array([ident.get(k, "")] * n, pa.string()))
        names.append(k)
    from . import store as fstore

    fstore._atomic_parquet(pa.Table.from_arrays(arrays, names=names), out_path)
    return {"rows": n}


def _f(x: Any) -> float:
    return math.nan if x is None else float(x)


def rho_s_of_field(values: np.ndarray, layers: tuple[str, ...], block_s: float = 10.0) -> dict[str, Any]:
    """Mean ρ_s of the samples the map accepted and its 95 % half-width from the spread of ``block_s``
    block means (the 10 Hz samples are correlated within a block; blocks are taken as independent)."""
    from scipy import stats

    if "rho_s" not in layers or not len(values):
        return {"rho_s_mean": math.nan, "rho_s_hw95": math.nan, "rho_s_blocks": 0}
    t = values[:, 0]
    r = values[:, 1 + layers.index("rho_s")]
    good = np.isfinite(r)
    t, r = t[good], r[good]
    if r.size == 0:
        return {"rho_s_mean": math.nan, "rho_s_hw95": math.nan, "rho_s_blocks": 0}
    blk = np.floor((t - t[0]) / block_s).astype(np.int64)
    _, inv = np.unique(blk, return_inverse=True)
    means = np.bincount(inv, weights=r) / np.bincount(inv)
    n = means.size
    hw = float(stats.t.ppf(0.975, n - 1) * means.std(ddof=1) / math.sqrt(n)) if n >= 2 else math.nan
    return {"rho_s_mean": float(means.mean()), "rho_s_hw95": hw, "rho_s_blocks": int(n)}


# ----------------------------------------------------------------------------- diagnosis
def diagnose_task(ref: dict[str, str], key: str, chash: str, tdir: Path, out: Path,
                  options: dict[str, Any]) -> dict[str, Any]:
    """Diagnose one recording; returns ``rows`` of the diagnosis table (:data:`.store.DIAGNOSIS_SCHEMA`)
    and the verdict."""
    from ..diagnose import diagnose_path
    from ..pipeline.survey import survey_keep
    from ..recording.reader import read_recording

    rep = diagnose_path(ref["path"], tdir / "diagnose")
    span = read_recording(ref["path"], keep=survey_keep).duration      # the recording's span [s]
    return {"verdict": str(rep.get("verdict", "")), "rows": diagnosis_rows(rep, ref, chash),
            "hours": float(span) / 3600.0 if math.isfinite(span) else 0.0}


def diagnosis_rows(rep: dict[str, Any], ref: dict[str, str], chash: str) -> list[dict[str, Any]]:
    """One row per parameter of every effect in a ``report.json`` (one row with an empty effect when
    the report names none)."""
    head = {"machine": ref["machine"], "date": ref["date"], "field": ref.get("field", ""),
            "recording": ref["path"], "recording_hash": chash, "verdict": str(rep.get("verdict", ""))}
    rows = []
    for eff in rep.get("effects") or []:
        params = eff.get("parameters") or {}
        for pname, p in params.items():
            ci = p.get("ci95") or [None, None]
            rows.append({**head, "effect": str(eff.get("name", "")), "kind": str(eff.get("kind", "")),
                         "named": bool(eff.get("named", False)), "rank": int(eff.get("rank") or 0),
                         "score": _f(eff.get("score")), "parameter": pname, "value": _f(p.get("value")),
                         "ci95_lo": _f(ci[0]), "ci95_hi": _f(ci[1]), "unit": str(p.get("unit", "")),
                         "at_bound": str(p.get("at_bound", ""))})
    if not rows:
        rows.append({**head, "effect": "", "kind": "", "named": False, "rank": 0, "score": math.nan,
                     "parameter": "", "value": math.nan, "ci95_lo": math.nan, "ci95_hi": math.nan, "unit": "",
                     "at_bound": ""})
    return rows


__all__ = ["KINDS", "content_hash", "copies", "diagnose_task", "diagnosis_rows", "replay_task", "rho_s_of_field",
           "run_task", "software_version", "task_key"]
