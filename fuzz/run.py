"""Fuzz every input path of tractionecu and print what came out.

Run from the repository root::

    python fuzz/run.py [--inputs 1000000] [--paths can,nmea,candump,csv,config] [--json OUT]

For each path it runs at least ``--inputs`` inputs (frames, lines or
documents; see ``fuzz/README.md``), split over ``--jobs`` processes, and
prints the count, the unhandled exceptions (must be 0), the contract
violations (must be 0), the rejects by reason and the rate.  A failing
input is written to ``--crash-dir`` as JSON that ``tests/fuzz`` can replay.
Exit status 1 if anything unhandled or any violation was seen.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import multiprocessing as mp
import os
import platform
import random
import resource
import signal
import sys
import tempfile
import time
import traceback
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from fuzz.targets import TARGETS, ContractViolation  # noqa: E402

PATHS = tuple(TARGETS)


class CaseTimeout(BaseException):
    """One case ran longer than the per-case limit (a hang); BaseException so no ``except Exception`` hides it."""


def _alarm(signum, frame):  # pragma: no cover - signal handler
    raise CaseTimeout()


def _where(exc: BaseException) -> str:
    """``file:line in function`` of the innermost project frame (else the innermost frame)."""
    tb = traceback.extract_tb(exc.__traceback__)
    pick = None
    for fr in tb:
        if "/tractionecu/" in fr.filename.replace("\\", "/"):
            pick = fr
    if pick is None and tb:
        pick = tb[-1]
    if pick is None:
        return "?"
    fn = pick.filename
    try:
        fn = str(Path(fn).resolve().relative_to(REPO))
    except ValueError:
        fn = Path(fn).name
    return f"{fn}:{pick.lineno} in {pick.name}"


def fuzz_worker(args: tuple) -> dict:
    """Run ``n`` inputs of one path in this process; returns counters and failures."""
    path, n, seed, worker, seeds, workroot, crash_dir, timeout_s = args
    prev_disable = logging.root.manager.disable
    logging.disable(logging.CRITICAL)  # the code under test warns about every bad input
    rng = random.Random(f"{seed}:{path}:{worker}")
    workdir = Path(workroot) / f"{path}-{worker}"
    target = TARGETS[path](seeds, rng, workdir)
    failures: dict[str, dict] = {}
    inputs = cases = 0
    max_case_s, max_case_inputs = 0.0, 0
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    old = signal.signal(signal.SIGALRM, _alarm) if timeout_s > 0 else None
    t0 = time.perf_counter()
    try:
        while inputs < n:
            case = target.generate()
            c0 = time.perf_counter()
            kind = None
            if timeout_s > 0:
                signal.setitimer(signal.ITIMER_REAL, timeout_s)
            try:
                k = target.run(case)
            except CaseTimeout as e:
                kind, exc, k = "hang", e, target.size(case)
            except ContractViolation as e:
                kind, exc, k = "violation", e, target.size(case)
            except Exception as e:  # noqa: BLE001 - the point of the exercise
                kind, exc, k = "unhandled", e, target.size(case)
            finally:
                if timeout_s > 0:
                    signal.setitimer(signal.ITIMER_REAL, 0)
            dt = time.perf_counter() - c0
            if dt > max_case_s:
                max_case_s, max_case_inputs = dt, k
            inputs += k
            cases += 1
            if kind is not None:
                where = _where(exc) if kind != "hang" else f"> {timeout_s:g} s"
                sig = f"{kind}: {type(exc).__name__} at {where}"
                f = failures.get(sig)
                size = len(json.dumps(target.dump(case)))
                if f is None:
                    f = failures[sig] = {"kind": kind, "type": type(exc).__name__, "where": where,
                                         "message": str(exc)[:500], "count": 0, "size": None, "file": None}
                f["count"] += 1
                if f["size"] is None or size < f["size"]:  # keep the smallest reproducer
                    name = f"{path}-{hashlib.sha1(sig.encode()).hexdigest()[:10]}.json"
                    out = Path(crash_dir) / name
                    out.parent.mkdir(parents=True, exist_ok=True)
                    rec = {"path": path, "signature": sig, "message": str(exc)[:2000],
                           "traceback": "".join(traceback.format_exception(exc))[-4000:],
                           "case": target.dump(case)}
                    out.write_text(json.dumps(rec, indent=1) + "\n", encoding="utf-8")
                    f["size"], f["file"], f["message"] = size, str(out), str(exc)[:500]
        if hasattr(target, "finish"):
            target.finish()
    finally:
        if old is not None:
            signal.signal(signal.SIGALRM, old)
        logging.disable(prev_disable)
    elapsed = time.perf_counter() - t0
    return {
        "inputs": inputs, "cases": cases, "elapsed_s": elapsed, "counts": dict(target.counts),
        "extra": dict(target.extra), "failures": failures, "max_case_s": max_case_s,
        "max_case_inputs": max_case_inputs,
        "rss_growth_mib": (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0) / 1024.0,
    }


def merge(results: list[dict]) -> dict:
    """Sum the worker results of one path."""
    out: dict = {"inputs": 0, "cases": 0, "counts": Counter(), "extra": Counter(), "failures": {},
                 "max_case_s": 0.0, "max_case_inputs": 0, "rss_growth_mib": 0.0, "cpu_s": 0.0}
    for r in results:
        out["inputs"] += r["inputs"]
        out["cases"] += r["cases"]
        out["counts"].update(r["counts"])
        out["extra"].update(r["extra"])
        out["cpu_s"] += r["elapsed_s"]
        if r["max_case_s"] > out["max_case_s"]:
            out["max_case_s"], out["max_case_inputs"] = r["max_case_s"], r["max_case_inputs"]
        out["rss_growth_mib"] = max(out["rss_growth_mib"], r["rss_growth_mib"])
        for sig, f in r["failures"].items():
            g = out["failures"].setdefault(sig, dict(f, count=0))
            g["count"] += f["count"]
            if f["size"] is not None and (g["size"] is None or f["size"] <= g["size"]):
                g.update(size=f["size"], file=f["file"], message=f["message"])
    return out


def fmt_path(path: str, unit: str, m: dict, wall_s: float, jobs: int) -> list[str]:
    """The printed lines of one path."""
    counts = m["counts"]
    unhandled = sum(f["count"] for f in m["failures"].values() if f["kind"] in ("unhandled", "hang"))
    violations = sum(f["count"] for f in m["failures"].values() if f["kind"] == "violation")
    rejects = {k[len("reject:"):]: v for k, v in counts.items() if k.startswith("reject:") and v}
    oks = {k[len("ok:"):]: v for k, v in counts.items() if k.startswith("ok:") and v}
    rate = m["inputs"] / wall_s if wall_s > 0 else float("nan")
    lines = [
        f"{path:<8} {m['inputs']:>9} {unit:<9} in {m['cases']} cases: unhandled {unhandled}, "
        f"contract violations {violations}, rejects counted {sum(rejects.values())}, "
        f"{rate:,.0f} inputs/s ({jobs} processes, {wall_s:.1f} s)",
        "         rejects: " + (", ".join(f"{k} {v}" for k, v in sorted(rejects.items(), key=lambda kv: -kv[1])) or "none"),
        "         accepted: " + (", ".join(f"{k} {v}" for k, v in sorted(oks.items(), key=lambda kv: -kv[1])) or "none"),
    ]
    if m["extra"]:
        lines.append("         also: " + ", ".join(f"{k} {v}" for k, v in sorted(m["extra"].items()) if v))
    lines.append(f"         slowest case {m['max_case_s'] * 1e3:.1f} ms ({m['max_case_inputs']} {unit}); "
                 f"worker peak-RSS growth {m['rss_growth_mib']:.1f} MiB")
    for sig, f in sorted(m["failures"].items(), key=lambda kv: -kv[1]["count"]):
        lines.append(f"         {f['count']:>7} x {sig}: {f['message'][:160]!r}  -> {f['file']}")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--inputs", type=int, default=1_000_000, help="inputs per path (default 1000000)")
    ap.add_argument("--paths", default=",".join(PATHS), help=f"comma-separated subset of {','.join(PATHS)}")
    ap.add_argument("--json", type=Path, default=None, help="write the figures as JSON here")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="worker processes (default: all cores)")
    ap.add_argument("--seed", type=int, default=1, help="random seed (a run is reproducible from it)")
    ap.add_argument("--crash-dir", type=Path, default=REPO / "fuzz" / "crashes", help="where failing inputs go")
    ap.add_argument("--timeout", type=float, default=30.0, help="per-case limit [s]; longer counts as a hang (0: none)")
    ap.add_argument("--bounds", action=argparse.BooleanOptionalAction, default=True,
                    help="also run the memory-bound checks (huge single lines, floods)")
    a = ap.parse_args(argv)
    paths = [p.strip() for p in a.paths.split(",") if p.strip()]
    bad = [p for p in paths if p not in TARGETS]
    if bad:
        ap.error(f"unknown path(s) {', '.join(bad)}; known: {', '.join(PATHS)}")

    from fuzz.corpus import build_seeds

    seeds = build_seeds()
    print(f"tractionecu fuzz: {a.inputs} inputs per path, seed {a.seed}, {a.jobs} processes, "
          f"Python {platform.python_version()}, {platform.machine()}", flush=True)
    report: dict = {"inputs_per_path": a.inputs, "seed": a.seed, "jobs": a.jobs,
                    "python": platform.python_version(), "paths": {}, "bounds": []}
    failed = False
    shm = Path("/dev/shm")
    with tempfile.TemporaryDirectory(prefix="tecu-fuzz-", dir=shm if shm.is_dir() and os.access(shm, os.W_OK) else None) as work:
        ctx = mp.get_context("fork")
        for path in paths:
            share = [a.inputs // a.jobs + (1 if i < a.inputs % a.jobs else 0) for i in range(a.jobs)]
            jobs = [(path, share[i], a.seed, i, seeds, work, str(a.crash_dir), a.timeout) for i in range(a.jobs) if share[i]]
            t0 = time.perf_counter()
            if len(jobs) == 1:
                results = [fuzz_worker(jobs[0])]
            else:
                with ctx.Pool(len(jobs)) as pool:
                    results = pool.map(fuzz_worker, jobs)
            wall = time.perf_counter() - t0
            m = merge(results)
            for line in fmt_path(path, TARGETS[path].unit, m, wall, len(jobs)):
                print(line, flush=True)
            if m["failures"]:
                failed = True
            report["paths"][path] = {
                "unit": TARGETS[path].unit, "inputs": m["inputs"], "cases": m["cases"], "wall_s": wall,
                "inputs_per_s": m["inputs"] / wall if wall > 0 else None,
                "unhandled": sum(f["count"] for f in m["failures"].values() if f["kind"] in ("unhandled", "hang")),
                "violations": sum(f["count"] for f in m["failures"].values() if f["kind"] == "violation"),
                "counts": dict(m["counts"]), "extra": dict(m["extra"]), "failures": m["failures"],
                "max_case_s": m["max_case_s"], "rss_growth_mib": m["rss_growth_mib"],
            }
    if a.bounds:
        from fuzz.bounds import run_bounds

        for res in run_bounds(paths):
            print(res["line"], flush=True)
            report["bounds"].append(res)
            failed = failed or not res["ok"]
    if a.json is not None:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps(report, indent=1, default=str) + "\n", encoding="utf-8")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
