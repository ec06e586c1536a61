"""Mapping benchmark: fill speed on 100 ha, speed-up over a per-cell fill, 10 Hz accumulation cost.

Run from the repository root::

    python benchmarks/mapping.py --json OUT.json

Prints and writes:

* ``map_fill_seconds_100ha`` — the paper's fill (one layer) of a 1000 m × 1000 m
  field at 0.5 m (4·10⁶ cells) whose cell means come from back-and-forth
  passes 6 m apart, sampled every 0.25 m (2.5 m/s at 10 Hz) with ±0.3 m
  lateral wander, over three soils; median of 3 runs.  Target ≤ 2 s.
* ``map_fill_speedup_vs_naive`` — per-cell Python implementation
  (:func:`paper_fill_naive`) time / vectorised time on a 60 m × 60 m field with
  the same pattern, in the same run; the two results are checked to agree to
  1e-9.
* ``map_accumulate_us_per_sample`` — mean cost of one ``MapStore.add`` with
  all six layers (projection, gating and Welford update), flushes excluded.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

try:
    import tractionecu  # noqa: F401
except ImportError:  # run as a script from the repository root
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tractionecu.mapping.fill import paper_fill, paper_fill_naive  # noqa: E402
from tractionecu.mapping.store import MapStore  # noqa: E402

RES_M = 0.5
SOIL_A = np.array([0.75, 0.60, 0.42])


def soil(x: np.ndarray, y: np.ndarray, size_m: float) -> np.ndarray:
    """Three soils: west third, then north / south of a slanted line."""
    return np.where(x < size_m / 3, 0, np.where(y > 0.5 * (x - size_m / 3) + size_m / 3, 1, 2))


def pass_pattern(size_m: float, spacing_m: float = 6.0, step_m: float = 0.25,
                 rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Back-and-forth passes with headland turns; (x, y) samples [m]."""
    rng = rng or np.random.default_rng(0)
    xs, ys = [], []
    lanes = np.arange(spacing_m / 2, size_m, spacing_m)
    for k, x in enumerate(lanes):
        y = np.arange(step_m, size_m - step_m, step_m)
        if k % 2:
            y = y[::-1]
        wander = 0.3 * np.sin(2 * np.pi * y / 37.0 + k) + rng.normal(0.0, 0.05, len(y))
        xs.append(x + wander)
        ys.append(y)
        if k + 1 < len(lanes):  # headland turn: half circle to the next lane
            th = np.linspace(0, np.pi, max(int(np.pi * spacing_m / 2 / step_m), 2))
            yc = y[-1]
            sign = 1.0 if k % 2 == 0 else -1.0
            xs.append(x + spacing_m / 2 * (1 - np.cos(th)))
            ys.append(yc + sign * spacing_m / 2 * np.sin(th) * 0.5)
    return np.concatenate(xs), np.concatenate(ys)


def mean_grid(size_m: float, rng: np.random.Generator) -> np.ndarray:
    """Cell means of noisy a-samples along the pass pattern (NaN = no sample)."""
    x, y = pass_pattern(size_m, rng=rng)
    n = int(round(size_m / RES_M))
    a = SOIL_A[soil(x, y, size_m)] + rng.normal(0.0, 0.03, len(x))
    col = np.floor(x / RES_M).astype(np.int64)
    row = np.floor(y / RES_M).astype(np.int64)
    ok = (col >= 0) & (col < n) & (row >= 0) & (row < n)
    flat = row[ok] * n + col[ok]
    cnt = np.bincount(flat, minlength=n * n)
    tot = np.bincount(flat, weights=a[ok], minlength=n * n)
    m = np.full(n * n, np.nan)
    m[cnt > 0] = tot[cnt > 0] / cnt[cnt > 0]
    return m.reshape(n, n)


def bench_fill_100ha(rng: np.random.Generator) -> tuple[float, dict]:
    m = mean_grid(1000.0, rng)
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        f = paper_fill(m, RES_M)
        times.append(time.perf_counter() - t0)
    info = {"cells": int(m.size), "cells_measured": int(np.isfinite(m).sum()),
            "cells_filled": int(np.isfinite(f).sum()), "runs_s": [round(t, 4) for t in times]}
    return float(np.median(times)), info


def bench_speedup(rng: np.random.Generator) -> tuple[float, dict]:
    m = mean_grid(60.0, rng)
    t0 = time.perf_counter()
    slow = paper_fill_naive(m, RES_M)
    t_naive = time.perf_counter() - t0
    fast_times = []
    for _ in range(5):
        t0 = time.perf_counter()
        fast = paper_fill(m, RES_M)
        fast_times.append(time.perf_counter() - t0)
    t_fast = float(np.median(fast_times))
    same_nan = bool(np.array_equal(np.isnan(slow), np.isnan(fast)))
    diff = float(np.nanmax(np.abs(slow - fast)))
    if not same_nan or diff > 1e-9:
        raise SystemExit(f"vectorised fill disagrees with the per-cell fill (max diff {diff}, same NaN {same_nan})")
    return t_naive / t_fast, {"cells": int(m.size), "naive_s": round(t_naive, 4), "vectorised_s": round(t_fast, 6),
                              "max_abs_diff": diff}


def bench_accumulate(rng: np.random.Generator, n: int = 30000) -> tuple[float, dict]:
    with tempfile.TemporaryDirectory() as d:
        store = MapStore(Path(d) / "map", 50.91, 13.34)
        x, y = pass_pattern(200.0, rng=rng)
        x, y = x[:n], y[:n]
        lat, lon = store.to_latlon(x, y)
        lat = lat.tolist()
        lon = lon.tolist()
        a = (SOIL_A[soil(x, y, 200.0)] + rng.normal(0.0, 0.03, len(x))).tolist()
        t0 = time.perf_counter()
        for i in range(len(lat)):
            store.add(lat[i], lon[i], {"a": a[i], "p": 0.55, "alpha1": -25.0, "alpha2": -5.0,
                                       "rho_s": 0.06, "mu": 0.45}, 0.1 * i)
        dt = time.perf_counter() - t0
        t1 = time.perf_counter()
        tiles = store.flush(force=True)
        t_flush = time.perf_counter() - t1
        store.close()
    return dt / len(lat) * 1e6, {"samples": len(lat), "tiles_flushed": tiles,
                                 "flush_ms_per_tile": round(t_flush / max(tiles, 1) * 1e3, 3)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, required=True, help="write the figures to this JSON file")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)

    fill_s, fill_info = bench_fill_100ha(rng)
    speedup, sp_info = bench_speedup(rng)
    acc_us, acc_info = bench_accumulate(rng)
    result = {
        "map_fill_seconds_100ha": round(fill_s, 4),
        "map_fill_speedup_vs_naive": round(speedup, 1),
        "map_accumulate_us_per_sample": round(acc_us, 2),
    }
    for k, v in result.items():
        print(f"{k}: {v}")
    print(f"  fill 100 ha: {fill_info}")
    print(f"  speed-up field: {sp_info}")
    print(f"  accumulate: {acc_info}")
    doc = dict(result)
    doc["details"] = {"fill_100ha": fill_info, "speedup": sp_info, "accumulate": acc_info,
                      "resolution_m": RES_M, "python": platform.python_version(), "machine": platform.machine(),
                      "cpus": os.cpu_count(), "numpy": np.__version__}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(doc, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
