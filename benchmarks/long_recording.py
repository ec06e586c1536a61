"""Replay, inspect and diagnose on long recordings: wall time and peak RSS against recorded length.

A long recording is the simulated ``paper-three-soils`` run (seed 7, 415 s) repeated back to back: each
copy's CAN and NMEA times moved on by the span of the copies before it (NMEA time of day and date
rewritten, checksums recomputed), so the whole is one continuous drive of the chosen length on the
same field.  Each command runs in its own process; peak RSS is that process's ``ru_maxrss``.

    python benchmarks/long_recording.py [--hours 0.1667 1 4] [--work DIR] [--skip-diagnose] [--only CMD ...]

Prints one line per command and length, then the ratio of time per recorded hour between the longest
and the shortest recording.
"""

from __future__ import annotations

import argparse
import datetime as dt
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path


def _nmea_shift(line: str, shift_s: float) -> str:
    """One NMEA sentence with its UTC time (and date, when it carries one) moved by ``shift_s``."""
    if not line.startswith("$") or "*" not in line:
        return line
    body = line[1:line.rindex("*")]
    f = body.split(",")
    kind = f[0][2:]
    ti = {"GGA": 1, "RMC": 1, "GNS": 1, "ZDA": 1, "GLL": 5}.get(kind)
    if ti is None or not f[ti]:
        return line
    hh, mm, ss = int(f[ti][0:2]), int(f[ti][2:4]), float(f[ti][4:])
    base = dt.datetime(2000, 1, 1)
    if kind == "RMC" and f[9]:
        base = dt.datetime.strptime(f[9], "%d%m%y")
    elif kind == "ZDA":
        base = dt.datetime(int(f[4]), int(f[3]), int(f[2]))
    t = base + dt.timedelta(hours=hh, minutes=mm, seconds=ss + shift_s)
    dec = len(f[ti].split(".")[1]) if "." in f[ti] else 0
    sec = f"{t.second + t.microsecond / 1e6:0{3 + dec if dec else 2}.{dec}f}"
    f[ti] = f"{t.hour:02d}{t.minute:02d}{sec}"
    if kind == "RMC" and f[9]:
        f[9] = t.strftime("%d%m%y")
    elif kind == "ZDA":
        f[2], f[3], f[4] = f"{t.day:02d}", f"{t.month:02d}", f"{t.year:04d}"
    body = ",".join(f)
    ck = 0
    for ch in body:
        ck ^= ord(ch)
    return f"${body}*{ck:02X}"


def concatenate(src: Path, dst: Path, seconds: float) -> float:
    """``dst``: copies of recording ``src`` back to back until ``seconds`` are recorded; returns the length."""
    dst.mkdir(parents=True, exist_ok=True)
    shutil.copy(src / "vehicle.toml", dst / "vehicle.toml")
    can = (src / "can.log").read_text().splitlines()
    nmea = (src / "gps.nmea").read_text().splitlines()
    t0 = float(can[0][1:can[0].index(")")])
    span = float(can[-1][1:can[-1].index(")")]) - t0 + 0.01        # one frame period between copies
    copies = max(1, round(seconds / span))
    with open(dst / "can.log", "w") as fc, open(dst / "gps.nmea", "w") as fg:
        for c in range(copies):
            sh = c * span
            for ln in can:
                k = ln.index(")")
                fc.write(f"({float(ln[1:k]) + sh:017.6f}){ln[k + 1:]}\n")
            for ln in nmea:
                fg.write((_nmea_shift(ln, sh) if c else ln) + "\n")
    return copies * span


def measure_fresh(cmd: list[str]) -> tuple[float, float, str]:
    """(wall time [s], peak RSS [MB], first output line) of a command run in a fresh interpreter, so each
    command's peak RSS is its own."""
    code = ("import resource, subprocess, sys, time, json\n"
            "t = time.perf_counter()\n"
            f"p = subprocess.run({cmd!r}, capture_output=True, text=True)\n"
            "w = time.perf_counter() - t\n"
            "r = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss\n"
            "print(json.dumps([w, r / 1024.0, p.returncode, (p.stdout.strip().splitlines() or [''])[0],"
            " p.stderr[-1500:]]))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    import json

    w, r, rc, first, err = json.loads(out)
    if rc not in (0, 2):
        raise SystemExit(f"{' '.join(cmd)} failed ({rc}): {err}")
    return w, r, first


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--hours", type=float, nargs="+", default=[1 / 6, 1.0, 4.0])
    ap.add_argument("--work", type=Path, default=None, help="directory for the recordings (default: a temp dir)")
    ap.add_argument("--skip-diagnose", action="store_true")
    ap.add_argument("--only", nargs="+", default=None, metavar="COMMAND",
                    help="run only these of replay, replay+map, inspect, diagnose")
    args = ap.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="long_recording_"))
    exe = [sys.executable, "-m", "tractionecu"]
    base = work / "base"
    if not (base / "can.log").exists():
        subprocess.run([*exe, "simulate", "--scenario", "paper-three-soils", "--seed", "7", "--out", str(base)],
                       check=True, capture_output=True)
    per_hour: dict[str, list[tuple[float, float]]] = {}
    for h in sorted(args.hours):
        rec = work / f"rec_{h:g}h"
        if not (rec / "can.log").exists():
            length = concatenate(base, rec, h * 3600.0)
            (rec / "length_s.txt").write_text(f"{length!r}\n")
        else:
            length = float((rec / "length_s.txt").read_text())
        cmds = {"replay": [*exe, "replay", str(rec), "--out", str(work / f"run_{h:g}h"), "--no-map"],
                "replay+map": [*exe, "replay", str(rec), "--out", str(work / f"runm_{h:g}h")],
                "inspect": [*exe, "inspect", str(rec)]}
        if not args.skip_diagnose:
            cmds["diagnose"] = [*exe, "diagnose", str(rec), "--out", str(work / f"diag_{h:g}h")]
        for name, cmd in cmds.items():
            if args.only and name not in args.only:
                continue
            wall, rss, first = measure_fresh(cmd)
            per_hour.setdefault(name, []).append((length, wall))
            print(f"{name:<11} {length / 3600:6.2f} h recorded: {wall:8.1f} s wall, peak RSS {rss:7.0f} MB, "
                  f"{length / wall:6.0f}x real time | {first[:90]}", flush=True)
    for name, rows in per_hour.items():
        if len(rows) >= 2:
            (l0, w0), (l1, w1) = rows[0], rows[-1]
            print(f"{name}: time per recorded hour, {l1 / 3600:.2f} h vs {l0 / 3600:.2f} h: "
                  f"{(w1 / l1) / (w0 / l0):.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
