"""Soak: many hours of simulated operation through the daemon's own code path, as fast as it goes.

Run from the repository root::

    python benchmarks/soak.py --hours 24 --json OUT.json [--max-minutes 25]

What runs: a real :class:`tractionecu.service.daemon.Service` (default
configuration, map on, its real Estimator) without devices, driven through
its parts' public methods.  Each simulated 10 ms step feeds the step's CAN
frames of a simulated ``paper-three-soils`` recording (looped, re-stamped)
to ``FrameDispatcher.on_frame`` (J1939/DBC decoding, counters, step
assembly), a GNSS sample every 100 ms to ``FrameDispatcher.on_fix``, then
runs ``EstimationLoop.step`` (the estimator), ``Network.broadcast`` (the
encoder; no bus: counted as skipped), ``MapWriter.add`` with
``FixBuffer.fix_at`` and ``MapWriter.maybe_flush`` (tile writes in the
writer's worker thread, as in the daemon).  Positions follow a
serpentine over a 200 m x 200 m field at the vehicle's speed, so the map
stops growing after the first pass of the field (about 45 simulated minutes).

Printed once per simulated hour and at the end: resident memory (VmRSS, and
its anonymous and file-backed parts), glibc's heap in use / free / mapped
(``mallinfo2``), Python's allocated blocks, open file descriptors, asyncio
tasks, threads; with ``--census N`` also the N largest containers the
garbage collector tracks and what holds them (to find what grows).  Warm-up is the first
simulated hour (``--warmup-hours``); RSS growth is (last − at warm-up) /
at warm-up, target ≤ 5 %.  ``--max-minutes`` stops early (wall time) and
reports the hours reached.
"""

from __future__ import annotations

import argparse
import asyncio
import ctypes
import gc
import json
import math
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

import can


def status_kb(field: str = "VmRSS") -> int:
    """A memory figure of /proc/self/status [KiB]: VmRSS, RssAnon (heap, stacks: what a leak grows)
    or RssFile (pages of mapped files, e.g. shared libraries touched for the first time); -1 if absent."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    return -1


class _Mallinfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                                 "fsmblks", "uordblks", "fordblks", "keepcost")]


def heap_kb() -> dict[str, int]:
    """glibc's heap figures [KiB]: in use, free but kept (fragmentation), mmapped; {} off glibc."""
    try:
        libc = ctypes.CDLL(None)
        f = libc.mallinfo2
    except (OSError, AttributeError):
        return {}
    f.restype = _Mallinfo2
    mi = f()
    return {"heap_used_kb": mi.uordblks // 1024, "heap_free_kb": mi.fordblks // 1024, "mmap_kb": mi.hblkhd // 1024}


def print_census(n: int) -> None:
    """The n largest containers the cyclic collector tracks (objects made since start-up), by length,
    each with the type of what holds it."""
    top: list = []
    for o in gc.get_objects():
        try:
            ln = len(o)
        except TypeError:
            continue
        if len(top) < n or ln > top[-1][0]:
            top.append((ln, o))
            top.sort(key=lambda r: -r[0])
            del top[n:]
    objs = [o for _, o in top]
    lens = [ln for ln, _ in top]
    del top
    for ln, o in zip(lens, objs):
        holders = [r for r in gc.get_referrers(o) if r is not objs and not isinstance(r, type(sys._getframe()))]
        ref = ", ".join(type(r).__name__ + (f"({', '.join(list(r)[:4])})" if isinstance(r, dict) else "")
                        for r in holders[:2]) or "?"
        print(f"  census: {type(o).__name__:<12} len {ln:>8}  held by {ref}", flush=True)


def fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def serpentine(dist_m: float, side: float = 200.0, swath: float = 6.0) -> tuple[float, float]:
    """(x, y) [m] after ``dist_m`` along a back-and-forth path over a side x side field (then repeats)."""
    passes = int(side // swath)
    period = passes * side
    d = dist_m % period
    i = int(d // side)
    along = d - i * side
    x = along if i % 2 == 0 else side - along
    return x - side / 2, i * swath - side / 2


async def soak(hours: float, max_minutes: float, warmup_h: float, work: Path, census: int = 0) -> dict:
    from tractionecu.bus.candump import read_candump
    from tractionecu.service.config import ServiceConfig, with_overrides
    from tractionecu.service.daemon import Service
    from tractionecu.service.gps import GpsSample
    from tractionecu.service.heap import settle_heap
    from tractionecu.service.loop import warm_up
    from tractionecu.sim.player import simulate_recording

    rec = simulate_recording("paper-three-soils", 0, work / "rec", 60.0)
    frames = [(f.t, f.can_id, bytes(f.data)) for f in read_candump(rec / "can.log")]
    t_first = frames[0][0]
    loop_s = math.ceil(frames[-1][0] - t_first) + 1.0
    cfg = with_overrides(ServiceConfig(), gps={"source": "none"}, service={"state_dir": str(work / "state")},
                         map={"origin_lat": 47.88, "origin_lon": -110.55})
    svc = Service(cfg, env={}, warm_up_estimator=False)
    estimation, dispatcher, mapw = svc.estimation, svc.dispatcher, svc.map
    estimation.build_estimator()
    warm_up(estimation.factory, *estimation.machine)
    settle_heap()                          # as Service.run does before its loop
    await mapw.open()
    # Simulated time runs ~70x faster than the wall clock, so the writer's 5 s flushes come ~70 ms apart;
    # the store's 10-per-second write limit (wall clock) would skip most of them, which the daemon never does.
    mapw.store.min_flush_interval_s = 0.0
    lat0, lon0 = 47.88, -110.55
    m_per_deg_lat = 111_320.0
    m_per_deg_lon = m_per_deg_lat * math.cos(math.radians(lat0))
    rate = cfg.estimation.rate_hz
    steps_total = int(round(hours * 3600 * rate))
    t0 = 1.7e9
    fi = 0
    n_frames = len(frames)
    loop_k = 0
    dist = 0.0
    rows = []
    v = 2.5
    wall0 = time.monotonic()
    base = None
    stopped_early = False
    tasks0 = len(asyncio.all_tasks())

    def sample(h: float) -> dict:
        gc.collect()
        return {"sim_hours": round(h, 3), "rss_kb": status_kb("VmRSS"), "rss_anon_kb": status_kb("RssAnon"),
                "rss_file_kb": status_kb("RssFile"), "fds": fds(), "tasks": len(asyncio.all_tasks()),
                "threads": threading.active_count(), "wall_s": round(time.monotonic() - wall0, 1),
                "steps": svc.stats["steps"], "tiles": len(mapw.store.tile_keys()) if mapw.store else 0,
                "flush_errors": mapw.stats["flush_errors"], "py_blocks": sys.getallocatedblocks(),
                **heap_kb()}

    for k in range(steps_total):
        t = t0 + k / rate
        # frames of this step (recording looped and re-stamped)
        while True:
            ft, cid, data = frames[fi]
            ts = t0 + loop_k * loop_s + (ft - t_first)
            if ts > t:
                break
            dispatcher.on_frame(ts, can.Message(timestamp=ts, arbitration_id=cid, is_extended_id=True, data=data,
                                                check=False))
            fi += 1
            if fi == n_frames:
                fi, loop_k = 0, loop_k + 1
        if k % 10 == 0:
            x, y = serpentine(dist)
            fix = GpsSample(t, t, lat0 + y / m_per_deg_lat, lon0 + x / m_per_deg_lon, 850.0, v, 90.0, 4, 0.8, 14)
            dispatcher.on_fix(fix)
        est = estimation.step(t)
        v = float(est.v) if est is not None and math.isfinite(float(est.v)) else 2.5
        dist += max(0.0, v) / rate
        if k % 10 == 0:
            svc.network.broadcast(est)
            if est is not None:
                mapw.add(est, svc.fixes.fix_at(t))
            mapw.maybe_flush(k / rate)             # flush interval on the simulated clock
            await asyncio.sleep(0)
        if k % int(3600 * rate) == 0 or k == steps_total - 1:
            h = k / rate / 3600
            await mapw.wait_flushed()
            row = sample(h)
            rows.append(row)
            if census:
                print_census(census)
            if base is None and h >= warmup_h:
                base = row
            print(f"soak: {row['sim_hours']:6.2f} h simulated  RSS {row['rss_kb'] / 1024:7.1f} MiB"
                  f" (anon {row['rss_anon_kb'] / 1024:.1f}, file {row['rss_file_kb'] / 1024:.1f})  fds {row['fds']}"
                  f"  tasks {row['tasks']}  threads {row['threads']}  tiles {row['tiles']}  wall {row['wall_s']} s"
                  + (f"  heap used {row['heap_used_kb'] / 1024:.1f} free {row['heap_free_kb'] / 1024:.1f}"
                     f" mmap {row['mmap_kb'] / 1024:.1f} MiB" if "heap_used_kb" in row else "")
                  + f"  py blocks {row['py_blocks']}",
                  flush=True)
        if max_minutes and k % 1000 == 0 and time.monotonic() - wall0 > 60 * max_minutes:
            stopped_early = True
            h = k / rate / 3600
            row = sample(h)
            rows.append(row)
            print(f"soak: stopped at the wall-time limit, {h:.2f} h simulated", flush=True)
            break
    await mapw.close()
    last = rows[-1]
    base = base or rows[0]
    growth = 100.0 * (last["rss_kb"] - base["rss_kb"]) / base["rss_kb"]
    res = {
        "hours_requested": hours, "hours_simulated": last["sim_hours"], "stopped_early": stopped_early,
        "wall_s": last["wall_s"], "speed_x_real_time": round(last["sim_hours"] * 3600 / max(last["wall_s"], 1e-9), 1),
        "warmup_hours": base["sim_hours"], "rss_kb_after_warmup": base["rss_kb"], "rss_kb_last": last["rss_kb"],
        "rss_growth_pct_after_warmup": round(growth, 2),
        "rss_anon_kb_after_warmup": base["rss_anon_kb"], "rss_anon_kb_last": last["rss_anon_kb"],
        "rss_file_kb_after_warmup": base["rss_file_kb"], "rss_file_kb_last": last["rss_file_kb"],
        "fds_min_max": [min(r["fds"] for r in rows), max(r["fds"] for r in rows)],
        "tasks_min_max": [min(r["tasks"] for r in rows), max(r["tasks"] for r in rows)],
        "tasks_at_start": tasks0,
        "threads_min_max": [min(r["threads"] for r in rows), max(r["threads"] for r in rows)],
        "steps": svc.stats["steps"], "estimator_errors": svc.stats["estimator_errors"],
        "map": dict(mapw.stats), "rows": rows,
    }
    print(f"soak: {res['hours_simulated']:.2f} h simulated in {res['wall_s']:.0f} s ({res['speed_x_real_time']}x); "
          f"RSS after warm-up {base['rss_kb'] / 1024:.1f} MiB -> {last['rss_kb'] / 1024:.1f} MiB ({growth:+.2f} %, "
          f"target <= 5 %; anon {base['rss_anon_kb'] / 1024:.1f} -> {last['rss_anon_kb'] / 1024:.1f}, "
          f"file {base['rss_file_kb'] / 1024:.1f} -> {last['rss_file_kb'] / 1024:.1f}); fds {res['fds_min_max']}; asyncio tasks {res['tasks_min_max']}; "
          f"threads {res['threads_min_max']}; estimator errors {res['estimator_errors']}", flush=True)
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=24.0, help="simulated hours (default 24)")
    ap.add_argument("--json", metavar="OUT", default=None, help="write the figures here")
    ap.add_argument("--max-minutes", type=float, default=0.0, help="stop after this much wall time (0 = no limit)")
    ap.add_argument("--warmup-hours", type=float, default=1.0, help="RSS growth is measured from here (default 1)")
    ap.add_argument("--census", type=int, default=0, metavar="N",
                    help="each simulated hour, print the N largest containers the collector tracks")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="tecu-soak-") as work:
        res = asyncio.run(soak(args.hours, args.max_minutes, args.warmup_hours, Path(work),
                               args.census))
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n", encoding="utf-8")
    ok = res["rss_growth_pct_after_warmup"] <= 5.0 and res["fds_min_max"][0] == res["fds_min_max"][1] \
        and res["tasks_min_max"][0] == res["tasks_min_max"][1]
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
