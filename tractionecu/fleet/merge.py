"""The farm map: per-recording map stores in one frame merged cell by cell.

Every fleet replay writes its recording's map in the farm frame (one origin for the whole fleet, so
cell [row, col] is the same piece of ground in every store; :mod:`.tasks`).  :func:`merge_maps`
combines stores tile by tile and cell by cell with Chan, Golub & LeVeque's pairwise formula — the one
:meth:`~tractionecu.mapping.grid.TileStats.merge_batch` applies to a batch —

    n = n_a + n_b,   δ = x̄_b − x̄_a,   x̄ = x̄_a + δ·n_b/n,   M2 = M2_a + M2_b + δ²·n_a·n_b/n,

so a merged cell holds the count-weighted mean and the pooled variance ``M2/(n − 1)`` of all its
samples.  The merge is associative up to rounding ((A+B)+C and A+(B+C) agree to ~1e-15 relative), and
merging B's store into A's gives the same floats as feeding B's samples into A's store (a map fed by
both replays in sequence): a partial tile of one replay is that replay's batch statistics exactly.

The track logs (the 10 Hz samples, for the ISO 11783-10 time log) are concatenated in the order the
stores are given; ``contributors.parquet`` (per cell, the machines and dates and their sample counts)
is summed.  The merged directory is an ordinary map store: ``tractionecu map export`` and
:mod:`tractionecu.mapping.export` read it as any other.  ``merged.json`` lists the inputs merged into
it, so a farm map is updated with a day's recordings by merging only those into it.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from ..errors import ConfigError
from ..mapping.grid import COUNT_DTYPE, TileStats
from ..mapping.store import ESTIMATE_LEVELS, MapStore
from ..mapping.tiles import TRACK_NAME, iter_tile_files, read_manifest, read_tile, read_track, write_tile
from ..mapping.track import VALUES_NAME, read_values

CONTRIBUTORS = "contributors.parquet"
MERGED = "merged.json"
_SAME = ("origin_lat", "origin_lon", "resolution_m", "tile_cells", "layers", "crs")


def chan_merge(a: TileStats, b: TileStats) -> TileStats:
    """Cell-by-cell pairwise combination of two tiles' count, mean and M2 (module doc)."""
    if a.layers != b.layers or a.cells != b.cells:
        raise ConfigError(f"tiles differ: layers {a.layers} / {b.layers}, cells {a.cells} / {b.cells}")
    na = a.count.astype(np.float64)
    nb = b.count.astype(np.float64)
    n = na + nb
    out = a.copy()
    m = nb > 0
    delta = b.mean[m] - a.mean[m]
    out.mean[m] = a.mean[m] + delta * (nb[m] / n[m])
    out.m2[m] = a.m2[m] + b.m2[m] + delta * delta * (na[m] * nb[m] / n[m])
    out.count[m] = n[m].astype(COUNT_DTYPE)
    return out


def _manifest(d: Path) -> dict[str, Any]:
    return read_manifest(d)


EXPORT_DIR = "export"
"""The sub-directory ``tractionecu map export`` writes into by default; a merge keeps it."""


def merge_maps(inputs: Sequence[str | Path], out_dir: str | Path, *, names: Sequence[str] | None = None) -> dict[str, Any]:
    """Merge the map stores ``inputs`` (directories holding ``manifest.json``; all in one frame: same
    origin, resolution, tile size and layers) into a new store ``out_dir`` (replaced if it exists).

    ``names`` label the inputs in ``merged.json`` (default: their paths); an input that is itself a
    merged map contributes its own list.  Returns ``tiles``, ``cells`` and ``inputs``.
    """
    import shutil

    dirs = [Path(d) for d in inputs]
    if not dirs:
        raise ConfigError("merge_maps: no map to merge")
    mans = [_manifest(d) for d in dirs]
    ref = mans[0]
    for d, m in zip(dirs[1:], mans[1:]):
        for k in _SAME:
            if m.get(k) != ref.get(k):
                raise ConfigError(f"{d}: {k} {m.get(k)!r} differs from {dirs[0]}'s {ref.get(k)!r}: the farm map "
                                  f"merges stores of one frame only")
    tiles: dict[tuple[int, int], TileStats] = {}
    for d in dirs:
        for key, path in sorted(iter_tile_files(d)):
            _, _, st = read_tile(path)
            tiles[key] = chan_merge(tiles[key], st) if key in tiles else st
    out = Path(out_dir)
    tmp = out.with_name(out.name + ".merging")
    if tmp.exists():
        shutil.rmtree(tmp)
    st = MapStore(tmp, float(ref["origin_lat"]), float(ref["origin_lon"]), resolution_m=float(ref["resolution_m"]),
                  tile_cells=int(ref["tile_cells"]), layers=tuple(ref["layers"]),
                  soil_classes=ref.get("soil_classes"))
    # the farm map holds every estimator level its machines' maps hold (a hub tractor's and a mechanical one's)
    st.estimate_levels = {str(lv) for m in mans for lv in m.get("estimate_levels", ()) if str(lv) in ESTIMATE_LEVELS}
    st.close()
    for (tx, ty), st in tiles.items():
        write_tile(tmp, tx, ty, st)
    n_layers = len(ref["layers"])
    with open(tmp / TRACK_NAME, "wb") as ft, open(tmp / VALUES_NAME, "wb") as fv:
        for d in dirs:
            _, good = read_track(d / TRACK_NAME)
            if good:
                with open(d / TRACK_NAME, "rb") as fh:
                    ft.write(fh.read(good))
            _, good = read_values(d / VALUES_NAME, n_layers)
            if good:
                with open(d / VALUES_NAME, "rb") as fh:
                    fv.write(fh.read(good))
    labels: list[str] = []
    for i, d in enumerate(dirs):
        prev = d / MERGED
        if prev.is_file():
            labels += json.loads(prev.read_text(encoding="utf-8"))["inputs"]
        else:
            labels.append(str(names[i]) if names is not None else str(d))
    (tmp / MERGED).write_text(json.dumps({"inputs": labels}, indent=1), encoding="utf-8")
    _merge_contributors([d / CONTRIBUTORS for d in dirs], tmp / CONTRIBUTORS)
    if (out / EXPORT_DIR).is_dir():
        # `tractionecu map export FARM` writes into FARM/export by default: the user's exports outlive a merge
        os.replace(out / EXPORT_DIR, tmp / EXPORT_DIR)
    if out.exists():
        shutil.rmtree(out)
    os.replace(tmp, out)
    cells = int(sum(int((st.count.max(axis=0) > 0).sum()) for st in tiles.values()))
    return {"tiles": len(tiles), "cells": cells, "inputs": len(labels), "map_dir": str(out)}


def merged_inputs(map_dir: str | Path) -> list[str]:
    """The inputs a merged map holds (``merged.json``), empty for none."""
    p = Path(map_dir) / MERGED
    return json.loads(p.read_text(encoding="utf-8"))["inputs"] if p.is_file() else []


def _merge_contributors(paths: Iterable[Path], out: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    tables = [pq.read_table(p) for p in paths if p.is_file()]
    if not tables:
        return
    t = pa.concat_tables(tables)
    if t.num_rows:
        t = t.group_by(["col", "row", "machine", "date"]).aggregate([("samples", "sum")])
        t = t.rename_columns([("samples" if c == "samples_sum" else c) for c in t.column_names])
        t = t.sort_by([("row", "ascending"), ("col", "ascending"), ("machine", "ascending"), ("date", "ascending")])
    pq.write_table(t, out)


def cell_contributors(map_dir: str | Path) -> Any:
    """Per cell (``col``, ``row``), the sorted lists of the machines and the dates that contributed and the
    samples: a pandas DataFrame from ``contributors.parquet``."""
    import pandas as pd

    t = pd.read_parquet(Path(map_dir) / CONTRIBUTORS)
    g = t.groupby(["col", "row"], sort=True)
    return pd.DataFrame({"machines": g["machine"].agg(lambda s: sorted(set(s))),
                         "dates": g["date"].agg(lambda s: sorted(set(s))),
                         "samples": g["samples"].sum()}).reset_index()


def max_difference(a_dir: str | Path, b_dir: str | Path) -> dict[str, float]:
    """Largest differences between two stores' cells: ``count`` (absolute), ``mean`` and ``var``
    (absolute, over cells with data in both); ``cells_only_in_one``.  For the merge checks."""
    a = MapStore.open(a_dir, read_only=True)
    b = MapStore.open(b_dir, read_only=True)
    out = {"count": 0.0, "mean": 0.0, "var": 0.0, "cells_only_in_one": 0.0}
    for layer in a.layers:
        ext_a, ext_b = a.extent([layer]), b.extent([layer])
        if ext_a is None and ext_b is None:
            continue
        if ext_a is None or ext_b is None:
            out["cells_only_in_one"] = math.inf
            continue
        c0 = min(ext_a[0], ext_b[0])
        r0 = min(ext_a[1], ext_b[1])
        c1 = max(ext_a[0] + ext_a[2], ext_b[0] + ext_b[2])
        r1 = max(ext_a[1] + ext_a[3], ext_b[1] + ext_b[3])
        ext = (c0, r0, c1 - c0, r1 - r0)
        ga, gb = a.grid(layer, ext), b.grid(layer, ext)
        both = (ga.count > 0) & (gb.count > 0)
        out["cells_only_in_one"] += float(((ga.count > 0) != (gb.count > 0)).sum())
        out["count"] = max(out["count"], float(np.abs(ga.count.astype(np.int64) - gb.count.astype(np.int64)).max()))
        if both.any():
            out["mean"] = max(out["mean"], float(np.abs(ga.mean[both] - gb.mean[both]).max()))
            v = both & np.isfinite(ga.var) & np.isfinite(gb.var)
            if v.any():
                out["var"] = max(out["var"], float(np.abs(ga.var[v] - gb.var[v]).max()))
    return out


__all__ = ["CONTRIBUTORS", "cell_contributors", "chan_merge", "max_difference", "merge_maps", "merged_inputs"]
