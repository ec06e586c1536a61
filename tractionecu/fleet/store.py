"""The fleet's Parquet tables: where they go and their schemas.

Under ``OUT/`` (read any of them with ``pandas.read_parquet(path)`` or ``pyarrow.dataset.dataset(path,
partitioning="hive")``; the partition columns ``machine`` and ``date`` come from the directory names):

``estimates/machine=M/date=D/<hash>.parquet`` — one row per estimator step kept at the chosen rate (the
first step at or after each 1/rate boundary, ``--estimate-rate-hz``, default 1 Hz; 0 keeps every step).
Columns: those of the replay's ``estimates.csv`` (:data:`tractionecu.pipeline.replay.CSV_COLUMNS`, same
names and units: ``t`` [s, UNIX time of the capture's clock], ``mu_*``, ``rho_s``, ``a``, ``slip_*``
[-], ``v`` [m/s], ``omega_*`` [rad/s], ``var_*`` (filter variances), ``nis``, ``nis_dof``, ``adapt``,
``status`` (EstimateStatus bits, int64), ``valid`` (bool), ``soil_class``, ``curve_path`` (string),
``sigma_*`` [-], ``radius_*`` [-]) and ``recording`` (path), ``recording_hash`` (SHA-256), ``field``.

``map_samples/machine=M/date=D/<hash>.parquet`` — the map's 10 Hz samples: every GNSS epoch that passed
the map's position checks.  ``t`` [s], ``lat``, ``lon`` [deg WGS84], ``x_m``, ``y_m`` (the farm map's
local frame [m]), ``accepted`` (bool: the sample went into the map), the layers ``a``, ``p``,
``alpha1``, ``alpha2``, ``rho_s``, ``mu`` [-] (NaN where not accepted), ``recording``,
``recording_hash``, ``field``.

``recordings.parquet`` — one row per recording and task kind (:data:`RECORDINGS_COLUMNS`).

``diagnosis.parquet`` — one row per parameter of every effect the diagnosis reports
(:data:`DIAGNOSIS_COLUMNS`): ``machine``, ``date``, ``field``, ``recording``, ``recording_hash``,
``verdict``, ``effect``, ``kind`` (``effect`` or ``nominal``), ``named``, ``rank``, ``score``,
``parameter``, ``value``, ``ci95_lo``, ``ci95_hi`` (95 % interval), ``unit``, ``at_bound``.

``failures.parquet`` — recordings whose task failed: ``kind``, ``machine``, ``date``, ``path``,
``error`` (exception type), ``message``.

``farm_map/contributors.parquet`` — per map cell (``col``, ``row``: global cell indices of the farm
frame) and machine and date: ``samples`` (the cell's largest layer count from that machine on that date).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Iterable

import numpy as np

RECORDINGS_COLUMNS = ("kind", "machine", "date", "field", "path", "recording_hash", "key", "software", "status",
                      "cached", "hours", "steps", "valid_share", "estimates_rows", "map_samples", "map_beyond_range",
                      "radius_scale_front", "radius_hw95_front", "radius_blocks_front", "radius_scale_rear",
                      "radius_hw95_rear", "radius_blocks_rear", "rho_s_mean", "rho_s_hw95", "rho_s_blocks",
                      "verdict", "wall_seconds", "cpu_seconds", "error", "message")
"""Columns of ``recordings.parquet`` (NaN / empty where a kind does not have them)."""

DIAGNOSIS_COLUMNS = ("machine", "date", "field", "recording", "recording_hash", "verdict", "effect", "kind",
                     "named", "rank", "score", "parameter", "value", "ci95_lo", "ci95_hi", "unit", "at_bound")

FAILURE_COLUMNS = ("kind", "machine", "date", "path", "error", "message")

_STRING_CSV = ("soil_class", "curve_path")
_INT_CSV = ("nis_dof", "status")


def _pa() -> Any:
    import pyarrow as pa

    return pa


def _atomic_parquet(table: Any, path: Path) -> None:
    import pyarrow.parquet as pq

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    pq.write_table(table, tmp)
    os.replace(tmp, path)


def estimates_csv_to_parquet(csv_path: Path, out_path: Path, rate_hz: float, ident: dict[str, str]) -> dict[str, int]:
    """``estimates.csv`` to Parquet at ``rate_hz`` (module doc), read in blocks (bounded memory);
    returns ``rows`` written, ``steps`` read and ``valid_steps``."""
    pa = _pa()
    import pyarrow.compute as pc
    import pyarrow.csv as pcsv
    import pyarrow.parquet as pq

    from ..pipeline.replay import CSV_COLUMNS

    types = {c: (pa.string() if c in _STRING_CSV else pa.int64() if c in _INT_CSV + ("valid",) else pa.float64())
             for c in CSV_COLUMNS}
    reader = pcsv.open_csv(csv_path, read_options=pcsv.ReadOptions(block_size=1 << 22),
                           convert_options=pcsv.ConvertOptions(column_types=types, strings_can_be_null=False,
                                                               quoted_strings_can_be_null=False))
    extra = {k: pa.string() for k in ("recording", "recording_hash", "field")}
    schema = pa.schema([pa.field(c, pa.bool_() if c == "valid" else types[c]) for c in CSV_COLUMNS]
                       + [pa.field(k, t) for k, t in extra.items()])
    out_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_path.with_name(out_path.name + ".tmp")
    prev_bucket = -math.inf
    n_rows = n_steps = n_valid = 0
    with pq.ParquetWriter(tmp, schema) as w:
        for batch in reader:
            if batch.num_rows == 0:
                continue
            t = batch.column("t").to_numpy(zero_copy_only=False)
            keep_t = np.isfinite(t)
            valid = batch.column("valid").to_numpy(zero_copy_only=False).astype(bool)
            n_steps += int(keep_t.sum())
            n_valid += int((valid & keep_t).sum())
            if rate_hz > 0:
                bucket = np.floor(t * rate_hz)
                prev = np.concatenate([[prev_bucket], bucket[:-1]])
                keep = keep_t & (bucket != prev)
                prev_bucket = float(bucket[-1])
            else:
                keep = keep_t
            idx = np.flatnonzero(keep)
            if idx.size == 0:
                continue
            sub = batch.take(pa.array(idx))
            cols = []
            for c in CSV_COLUMNS:
                col = sub.column(c)
                cols.append(pc.cast(col, pa.bool_()) if c == "valid" else col)
            cols += [pa.array([ident.get(k, "")] * idx.size, pa.string()) for k in extra]
            w.write_table(pa.Table.from_arrays(cols, schema=schema))
            n_rows += idx.size
    os.replace(tmp, out_path)
    return {"rows": n_rows, "steps": n_steps, "valid_steps": n_valid}


def map_samples_to_parquet(store: Any, out_path: Path, ident: dict[str, str]) -> int:
    """The map's track (every sample past the position checks) with the accepted samples' layer values
    (module doc); returns the rows written."""
    pa = _pa()
    tr = store.track()
    vals = store.track_values()
    n = len(tr)
    acc = tr[:, 3] > 0 if n else np.zeros(0, bool)
    layer_cols = {name: np.full(n, np.nan) for name in store.layers}
    ia = np.flatnonzero(acc)
    if ia.size and len(vals):
        if len(vals) == ia.size and np.array_equal(vals[:, 0], tr[ia, 0]):
            rows = ia
            v = vals
        else:                                    # match by time (a damaged values log keeps its prefix)
            pos = {float(t): i for i, t in zip(ia.tolist(), tr[ia, 0].tolist())}
            pick = [(pos[float(t)], k) for k, t in enumerate(vals[:, 0].tolist()) if float(t) in pos]
            rows = np.array([p for p, _ in pick], dtype=np.int64)
            v = vals[[k for _, k in pick]]
        for j, name in enumerate(store.layers):
            layer_cols[name][rows] = v[:, 1 + j]
    lat, lon = store.frame.to_latlon(tr[:, 1], tr[:, 2]) if n else (np.empty(0), np.empty(0))
    data = {"t": tr[:, 0], "lat": np.asarray(lat, float), "lon": np.asarray(lon, float), "x_m": tr[:, 1],
            "y_m": tr[:, 2], "accepted": acc, **layer_cols}
    table = pa.table({**{k: pa.array(v) for k, v in data.items()},
                      **{k: pa.array([ident.get(k, "")] * n, pa.string())
                         for k in ("recording", "recording_hash", "field")}})
    _atomic_parquet(table, out_path)
    return n


def contributors_of(store: Any, machine: str, date: str, out_path: Path) -> int:
    """Cells of ``store`` holding data, with ``machine``, ``date`` and the largest layer count
    (``farm_map/contributors.parquet``); returns the number of cells."""
    from ..mapping.tiles import iter_tile_files, read_tile

    pa = _pa()
    cols, rows, counts = [], [], []
    n = store.tile_cells
    for (tx, ty), path in sorted(iter_tile_files(Path(store.directory))):
        _, _, st = read_tile(path)
        c = st.count.max(axis=0)
        r, k = np.nonzero(c)
        rows.append(ty * n + r)
        cols.append(tx * n + k)
        counts.append(c[r, k].astype(np.int64))
    col = np.concatenate(cols) if cols else np.empty(0, np.int64)
    table = pa.table({"col": pa.array(col.astype(np.int64)),
                      "row": pa.array((np.concatenate(rows) if rows else np.empty(0)).astype(np.int64)),
                      "machine": pa.array([machine] * col.size, pa.string()),
                      "date": pa.array([date] * col.size, pa.string()),
                      "samples": pa.array((np.concatenate(counts) if counts else np.empty(0)).astype(np.int64))})
    _atomic_parquet(table, out_path)
    return int(col.size)


def write_rows(rows: Iterable[dict[str, Any]], columns: tuple[str, ...], path: Path) -> int:
    """A table of ``rows`` (missing keys empty / NaN) with ``columns`` to ``path``; returns its rows."""
    pa = _pa()
    rows = list(rows)
    data: dict[str, list[Any]] = {c: [r.get(c) for r in rows] for c in columns}
    arrays = {}
    for c, vals in data.items():
        # the column's type from all its values: one float among integers makes it float (from the first
        # value alone, a score of 40 before one of 12.7 had written 12)
        present = [v for v in vals if v is not None and not (isinstance(v, float) and math.isnan(v))]
        if present and all(isinstance(v, (bool, np.bool_)) for v in present):
            arrays[c] = pa.array([bool(v) if v is not None else None for v in vals], pa.bool_())
        elif present and all(isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))
                             for v in present) and len(present) == sum(v is not None for v in vals):
            arrays[c] = pa.array([int(v) if v is not None else None for v in vals], pa.int64())
        elif present and all(isinstance(v, (int, float, np.integer, np.floating))
                             and not isinstance(v, (bool, np.bool_)) for v in present):
            arrays[c] = pa.array([float(v) if v is not None else math.nan for v in vals], pa.float64())
        else:
            arrays[c] = pa.array(["" if v is None else str(v) for v in vals], pa.string())
    _atomic_parquet(pa.table(arrays), path)
    return len(rows)


__all__ = ["DIAGNOSIS_COLUMNS", "FAILURE_COLUMNS", "RECORDINGS_COLUMNS", "contributors_of",
           "estimates_csv_to_parquet", "map_samples_to_parquet", "write_rows"]
