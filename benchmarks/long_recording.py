"""Replay, inspect and diagnose on long recordings: wall time, CPU time and peak RSS against recorded length.

A long recording is the simulated ``paper-three-soils`` run (seed 7, 415 s) repeated
(:func:`tractionecu.recording.concat.concatenate`: each copy's CAN and NMEA times moved on by the span of
the copies before it and a gap of ``--gap-s`` with nothing logged, NMEA time of day and date rewritten,
checksums recomputed), so the whole is a day's log of the chosen length on the same field, the logger
restarted between work periods.  The copies start at multiples of ``--align-s`` (80 s: twice the
diagnosis's held-out block, so that repeated noise is never scored against its own copy in the other
fold; a real day does not repeat its noise).  With ``--seeds N`` the copies are instead independently
seeded runs (seeds 0..N-1 of ``paper-three-soils``, each simulated once into ``--work``) taken in turn,
so that no noise repeats as long as N runs cover the length; no alignment is then needed (default 0).  The recorded length excludes the gaps.  Each command runs in its own
process; peak RSS is that process's ``ru_maxrss``, CPU time its user + system time.  The load average is
printed beside each line: on a shared machine wall time is not a measure of speed, CPU time is.

    python benchmarks/long_recording.py [--hours 0.1667 1 4] [--gap-s 10] [--work DIR] [--skip-diagnose]
                                        [--align-s 80] [--seeds N] [--only CMD ...]

Prints one line per command and length, then per command the ratio of time per recorded hour (CPU and
wall) between the longest and the shortest recording.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tractionecu.recording.concat import GAP_S, concatenate  # noqa: E402


def measure_fresh(cmd: list[str]) -> tuple[float, float, float, str]:
    """(wall time [s], CPU time [s], peak RSS [MB], first output line) of a command run in a fresh
    interpreter, so each command's peak RSS is its own."""
    code = ("import resource, subprocess, sys, time, json\n"
            "t = time.perf_counter()\n"
            f"p = subprocess.run({cmd!r}, capture_output=True, text=True)\n"
            "w = time.perf_counter() - t\n"
            "u = resource.getrusage(resource.RUSAGE_CHILDREN)\n"
            "print(json.dumps([w, u.ru_utime + u.ru_stime, u.ru_maxrss / 1024.0, p.returncode,"
            " (p.stdout.strip().splitlines() or [''])[0], p.stderr[-1500:]]))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    w, cpu, r, rc, first, err = json.loads(out)
    if rc not in (0, 2):
        raise SystemExit(f"{' '.join(cmd)} failed ({rc}): {err}")
    return w, cpu, r, first


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--hours", type=float, nargs="+", default=[1 / 6, 1.0, 4.0])
    ap.add_argument("--gap-s", type=float, default=GAP_S,
                    help="time between the copies with nothing logged [s] (default: %(default)s)")
    ap.add_argument("--align-s", type=float, default=None,
                    help="copies start at multiples of this [s] (default: 80 s with one seed, twice the "
                         "diagnosis's 40-s held-out block, so that no copy's held-out half repeats another's "
                         "training half; 0 with --seeds; 0: right after the gap)")
    ap.add_argument("--seeds", type=int, default=0, metavar="N",
                    help="join independently seeded runs (seeds 0..N-1), taken in turn, instead of copies of "
                         "one run (seed 7): no repeated noise while N runs cover the length")
    ap.add_argument("--work", type=Path, default=None, help="directory for the recordings (default: a temp dir)")
    ap.add_argument("--skip-diagnose", action="store_true")
    ap.add_argument("--only", nargs="+", default=None, metavar="COMMAND",
                    help="run only these of replay, replay+map, inspect, diagnose")
    args = ap.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="long_recording_"))
    exe = [sys.executable, "-m", "tractionecu"]
    if args.align_s is None:
        args.align_s = 0.0 if args.seeds else 80.0
    if args.seeds:
        sources = [work / f"seed{k}" for k in range(args.seeds)]
        seeds = list(range(args.seeds))
    else:
        sources, seeds = [work / "base"], [7]
    for src, seed in zip(sources, seeds):
        if not (src / "can.log").exists():
            subprocess.run([*exe, "simulate", "--scenario", "paper-three-soils", "--seed", str(seed),
                            "--out", str(src)], check=True, capture_output=True)
    tag = f"_seeds{args.seeds}" if args.seeds else ""
    per_hour: dict[str, list[tuple[float, float, float]]] = {}
    for h in sorted(args.hours):
        rec = work / f"rec_{h:g}h_gap{args.gap_s:g}_align{args.align_s:g}{tag}"
        if not (rec / "can.log").exists():
            length = concatenate(sources if args.seeds else sources[0], rec, h * 3600.0, gap_s=args.gap_s, align_s=args.align_s or None)
            (rec / "length_s.txt").write_text(f"{length!r}\n")
        else:
            length = float((rec / "length_s.txt").read_text())
        cmds = {"replay": [*exe, "replay", str(rec), "--out", str(work / f"run_{rec.name}"), "--no-map"],
                "replay+map": [*exe, "replay", str(rec), "--out", str(work / f"runm_{rec.name}")],
                "inspect": [*exe, "inspect", str(rec)]}
        if not args.skip_diagnose:
            cmds["diagnose"] = [*exe, "diagnose", str(rec), "--out", str(work / f"diag_{rec.name}")]
        for name, cmd in cmds.items():
            if args.only and name not in args.only:
                continue
            load0 = os.getloadavg()[0]
            wall, cpu, rss, first = measure_fresh(cmd)
            load1 = os.getloadavg()[0]
            per_hour.setdefault(name, []).append((length, wall, cpu))
            print(f"{name:<11} {length / 3600:6.2f} h recorded: {wall:8.1f} s wall, {cpu:8.1f} s CPU, "
                  f"peak RSS {rss:7.0f} MB, {length / cpu:6.0f}x real time (CPU), load {load0:.1f}/{load1:.1f} | "
                  f"{first[:80]}", flush=True)
    for name, rows in per_hour.items():
        if len(rows) >= 2:
            (l0, w0, c0), (l1, w1, c1) = rows[0], rows[-1]
            print(f"{name}: time per recorded hour, {l1 / 3600:.2f} h vs {l0 / 3600:.2f} h: "
                  f"{(c1 / l1) / (c0 / l0):.2f}x CPU, {(w1 / l1) / (w0 / l0):.2f}x wall")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
