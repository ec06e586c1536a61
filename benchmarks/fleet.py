"""Fleet replay on Dask: scaling from 1 to 2 workers, peak memory per worker, the farm map's merge.

Simulated season: ``--recordings`` (default 64) ``paper-three-soils`` runs of ``--duration`` seconds
(default 300), seeds 0.., spread over ``--machines`` (default 4) machines and one date per recording
pair, in a tree ``<machine>/<date>/run<seed>`` (kept in ``--work`` and reused).  Then, in one run:

1. ``fleet replay`` of the whole season on a local cluster of 1 worker, then of 2 workers (each
   into a fresh output directory, so nothing is cached; each cluster warmed first by a 5 s replay on
   every worker, so the numba compilation is not timed); wall time per run, CPU time of the tasks;
   scaling efficiency = wall(1) / (2 · wall(2));
2. peak resident memory per worker: the largest ``ru_maxrss`` any worker process reported after a task;
3. the farm map: the merged map of two machines' recordings (their per-recording maps from the
   2-worker run, merged cell by cell) against one map store fed by both replays in sequence
   (:func:`tractionecu.mapping.from_replay.write_replay_map` into one store): the largest differences
   of count, mean and variance per cell;
4. batch replay against the step path (``benchmarks/batch_replay.py``'s figures on the season's first
   recording: CPU time of each path, real time per core, their ratio, the largest difference of the
   estimates); ``--batch`` runs the fleet replays above on the batch path.

Prints the load average beside every wall time: on a shared machine the scaling figure measures the
other jobs as much as the fleet code.

    python benchmarks/fleet.py [--recordings 64] [--machines 4] [--duration 300] [--work DIR] [--json OUT]
                               [--batch] [--batch-repeat 3]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

from _common import load_line as _load, simulate_recording as _simulate   # benchmarks/_common.py


def make_season(work: Path, n: int, machines: int, duration: float, client) -> Path:
    """The simulated season (module doc), simulated on the cluster's workers; existing runs are kept."""
    root = work / f"season_{n}x{int(duration)}s_{machines}m"
    todo = []
    for seed in range(n):
        d = root / f"machine{seed % machines}" / f"2026-07-{1 + (seed // machines) % 28:02d}" / f"run{seed}"
        if not (d / "can.log").is_file():
            d.parent.mkdir(parents=True, exist_ok=True)
            todo.append((d, seed))
    if todo:
        print(f"simulating {len(todo)} recordings of {duration:.0f} s ...", flush=True)
        futs = [client.submit(_simulate, d, seed, duration, pure=False) for d, seed in todo]
        client.gather(futs)
    return root


def _warm(path: str, out: str, batch: bool = False) -> int:
    from tractionecu.pipeline.rundir import replay_to_dir

    replay_to_dir(path, out, keep_arrays=False)
    if batch:
        # the batch path's compiled estimator loop: loaded from numba's cache (or compiled) before the timing
        from tractionecu.pipeline.batch import replay_batch_rows

        replay_batch_rows(path)
    return os.getpid()


def run_fleet(season: Path, out: Path, workers: int, memory_limit: str, warm_rec: Path, batch: bool = False) -> dict:
    from tractionecu.fleet import runner

    client = runner.make_client(workers, memory_limit)
    try:
        client.run(lambda: _warm(str(warm_rec), tempfile.mkdtemp(prefix="fleet_warm_"), batch))
        load0 = _load()
        t0 = time.perf_counter()
        recs = runner.run_kind("replay", season, out, client=client, stream=sys.stderr, batch=batch)
        wall = time.perf_counter() - t0
        load1 = _load()
    finally:
        runner.close_client(client)
    ok = [r for r in recs if r.get("status") == "ok"]
    hours = sum(float(r["hours"]) for r in ok)
    return {"workers": workers, "recordings": len(recs), "ok": len(ok), "hours": hours, "wall_s": wall,
            "task_cpu_s": sum(float(r.get("cpu_seconds") or 0.0) for r in ok),
            "realtime_factor": hours * 3600.0 / wall if wall > 0 else float("nan"),
            "peak_rss_mb_per_worker": max(float(r.get("worker_peak_rss_mb") or 0.0) for r in ok) if ok else float("nan"),
            "worker_pids": sorted({int(r.get("worker_pid") or 0) for r in ok}), "load_before": load0,
            "load_after": load1, "records": recs}


def merge_check(season_out: Path, recs: list[dict], work: Path) -> dict:
    """Merged map of the first recordings of two machines against one store fed by both in sequence."""
    from tractionecu.fleet.merge import max_difference, merge_maps
    from tractionecu.mapping.from_replay import write_replay_map
    from tractionecu.mapping.store import MapStore
    from tractionecu.pipeline.rundir import replay_to_dir

    ok = sorted((r for r in recs if r.get("status") == "ok" and r.get("map_samples")),
                key=lambda r: (r["machine"], r["date"], r["path"]))
    firsts: dict[str, dict] = {}
    for r in ok:
        firsts.setdefault(r["machine"], r)
    pair = list(firsts.values())[:2]
    if len(pair) < 2:
        return {"error": "fewer than two machines with map samples"}
    d = work / "merge_check"
    if d.exists():
        shutil.rmtree(d)
    d.mkdir(parents=True)
    merged = merge_maps([season_out / "tasks" / "replay" / r["key"] / "farm_map" for r in pair], d / "merged")
    origin = json.loads((season_out / "tasks" / "replay" / pair[0]["key"] / "farm_map" / "manifest.json").read_text())
    with MapStore(d / "sequence", float(origin["origin_lat"]), float(origin["origin_lon"])) as st:
        for r in pair:
            _, rec, res = replay_to_dir(r["path"], d / f"replay_{r['machine']}", keep_arrays=False)
            write_replay_map(d, rec, res.arrays, gps_mask=res.gps_mask, store=st)
    diff = max_difference(d / "merged", d / "sequence")
    return {"machines": [r["machine"] for r in pair], "recordings": [r["path"] for r in pair],
            "cells": merged["cells"], **diff}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--recordings", type=int, default=64)
    ap.add_argument("--machines", type=int, default=4)
    ap.add_argument("--duration", type=float, default=300.0, help="seconds per recording")
    ap.add_argument("--memory-limit", default="1GiB", help="memory limit per worker")
    ap.add_argument("--work", type=Path, default=None, help="directory for the season and outputs (kept)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--batch", action="store_true", help="run the fleet replays on the batch path")
    ap.add_argument("--batch-repeat", type=int, default=3, help="rounds of the batch-vs-step comparison")
    a = ap.parse_args(argv)
    from tractionecu.fleet import runner
    from tractionecu.fleet.tasks import software_version

    work = a.work or Path(tempfile.mkdtemp(prefix="fleet_bench_"))
    work.mkdir(parents=True, exist_ok=True)
    print(f"fleet benchmark: {a.recordings} recordings x {a.duration:.0f} s from {a.machines} machines; "
          f"software {software_version()}; {_load()}", flush=True)
    client = runner.make_client(2, a.memory_limit)
    try:
        season = make_season(work, a.recordings, a.machines, a.duration, client)
        warm = work / "warm_5s"
        if not (warm / "can.log").is_file():
            client.submit(_simulate, warm, 999, 5.0, pure=False).result()
    finally:
        runner.close_client(client)
    runs = {}
    for w in (1, 2):
        out = work / f"out_{w}w"
        if out.exists():
            shutil.rmtree(out)
        r = run_fleet(season, out, w, a.memory_limit, warm, a.batch)
        runs[w] = r
        print(f"{w} worker(s): {r['ok']}/{r['recordings']} recordings, {r['hours']:.3f} h in {r['wall_s']:.1f} s wall "
              f"({r['realtime_factor']:.0f}x real time), task CPU {r['task_cpu_s']:.1f} s, peak RSS per worker "
              f"{r['peak_rss_mb_per_worker']:.0f} MB, worker processes {len(r['worker_pids'])}; "
              f"{r['load_before']} before, {r['load_after']} after", flush=True)
    eff = runs[1]["wall_s"] / (2.0 * runs[2]["wall_s"])
    peak = max(runs[1]["peak_rss_mb_per_worker"], runs[2]["peak_rss_mb_per_worker"])
    print(f"scaling efficiency 2 workers vs 1: {100 * eff:.0f} % (target >= 80 %; wall(1) / (2 wall(2)) = "
          f"{runs[1]['wall_s']:.1f} / (2 x {runs[2]['wall_s']:.1f}))")
    print(f"peak memory per worker: {peak:.0f} MB = {peak / 1024:.2f} GiB (target <= 1 GiB)")
    try:
        mc = merge_check(work / "out_2w", runs[2]["records"], work)
    except Exception as e:  # noqa: BLE001 - report it beside the other figures
        mc = {"error": f"{type(e).__name__}: {e}"}
    if "error" in mc:
        print(f"merged map check: {mc['error']}")
    else:
        print(f"merged map of {mc['machines'][0]} and {mc['machines'][1]} ({mc['cells']} cells) vs one map fed by "
              f"both replays in sequence: max |count diff| {mc['count']:.0f}, max |mean diff| {mc['mean']:.3g}, "
              f"max |var diff| {mc['var']:.3g}, cells in one only {mc['cells_only_in_one']:.0f} (target <= 1e-9)")
    print(f"the fleet runs above: {'batch' if a.batch else 'step'} path, "
          f"{runs[1]['hours'] * 3600 / max(runs[1]['task_cpu_s'], 1e-9):.0f}x real time per CPU second of the "
          f"1-worker run's tasks")
    # batch replay against the step path in this run, on the season's first recording (benchmarks/batch_replay.py)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import batch_replay

    first = sorted(season.glob("*/*/run*"))[0]
    bm = batch_replay.measure(first, repeat=a.batch_repeat)
    print(f"batch replay vs step path on {first.relative_to(season)} ({bm['span_s']:.0f} s; best CPU time of "
          f"{a.batch_repeat}):")
    for line in batch_replay.report(bm):
        print("  " + line)
    print(_load())
    if a.json:
        for r in runs.values():
            r.pop("records")
        a.json.write_text(json.dumps({"runs": {str(k): v for k, v in runs.items()}, "scaling_efficiency": eff,
                                      "peak_rss_mb_per_worker": peak, "merge_check": mc, "batch_vs_step": bm},
                                     indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
