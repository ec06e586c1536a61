"""Diagnosis suite: concealed-effect recordings, diagnosed blind, scored against what was concealed.

Run from the repository root::

    python benchmarks/diagnose_suite.py --json OUT.json [--fast] [--jobs 2] [--workdir DIR] [--reuse] [--seed-offset N]
    python benchmarks/diagnose_suite.py --json OUT.json --realistic --workdir DIR --simulate-only

``--seed-offset N`` adds N to every case's seed: the same cases with other noise, sensor draws and
disturbances, recordings the diagnosis has never been run on (keep them in their own ``--workdir``).

``--simulate-only`` writes the recordings into ``--workdir`` and diagnoses nothing, so that a
later ``--reuse`` run re-diagnoses the same recordings after a change of the diagnosis.

Each case of :func:`tractionecu.evaluation.suite.cases` is simulated and written as a
recording directory (``can.log``, ``gps.nmea``, ``vehicle.toml``; the truth files are
written too but diagnosis never opens them), then diagnosed by
:func:`tractionecu.diagnose.engine.diagnose` exactly as ``tractionecu diagnose`` would.

Figures (printed and written as JSON keys, see :func:`tractionecu.evaluation.suite.summarize`):

``named_above_absent``
    share of effect recordings (one or several concealed effects) whose every concealed effect is
    among the reported effects and ranked above every reported effect that is absent.
``top1_accuracy_single``
    single-effect recordings whose verdict is ``effect`` naming the concealed effect.
``ci_coverage``, ``ci_coverage_per_effect``
    share of (recording, true parameter) pairs whose 95 % interval holds the true value (the joint
    fit's interval when the effect was chosen, else its own fit's; nominal cases: the load-transfer
    heights), overall and per effect.
``outside_no_library_name``, ``outside_located``
    out-of-library recordings without a library name, and with the mismatch located.
``median_heldout_rmse_reduction``
    median over effect recordings of 1 − RMSE_after/RMSE_before on held-out data, on the
    signal the effect affects most.
``null_false_alarms``
    null (and load-transfer-only) recordings whose verdict is not ``none`` or that report an effect.
``confounded_as_ambiguous``
    whether every confounded recording is reported ``ambiguous``.

``cases`` holds one row per recording (verdict, ranking, fitted parameters, intervals).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tractionecu.diagnose.engine import diagnose  # noqa: E402
from tractionecu.evaluation.suite import all_cases, cases, fast_cases, score_case, summarize, write_case  # noqa: E402


def run_case(name: str, workdir: str, reuse: bool, simulate_only: bool = False, seed_offset: int = 0) -> dict:
    case = next(c for c in all_cases() if c.name == name)
    rec = Path(workdir) / name
    mark = Path(workdir) / f"{name}.seed_offset"       # which seeds the kept recording was made with
    t0 = time.perf_counter()
    made = (rec / "can.log").is_file() and (mark.read_text().strip() if mark.is_file() else "0") == str(seed_offset)
    if not (reuse and made):
        write_case(case, rec, seed_offset)
        mark.write_text(f"{seed_offset}\n")
    t1 = time.perf_counter()
    if simulate_only:
        return {"case": name, "simulate_s": round(t1 - t0, 2)}
    try:
        d = diagnose(rec)
    except Exception as exc:  # a crash is a result of the suite: counted as wrong, with its message
        return {"case": name, "kind": case.kind, "truth_model": case.truth_model, "truth": None,
                "verdict": "error", "effect": None, "ambiguous_between": [], "reported": [],
                "correct": False, "covered": {}, "fitted": {}, "error": f"{type(exc).__name__}: {exc}",
                # nothing fitted reduces nothing: an effect recording that crashed counts as 0 in the median
                # (as one where nothing was fitted), not as no recording
                **({"rmse_reduction": 0.0} if case.kind in ("effect", "characteristic") else {})}
    t2 = time.perf_counter()
    row = score_case(case, d, seed_offset)
    row["simulate_s"] = round(t1 - t0, 2)
    row["diagnose_s"] = round(t2 - t1, 2)
    return row


def _fmt_params(r: dict) -> str:
    out = []
    for k, f in r.get("fitted", {}).items():
        ok = "✓" if r["covered"].get(k) else "✗"
        b = f" (at {f['at_bound']} bound)" if f.get("at_bound") else ""
        if f.get("identified") is False:
            b += " (not identified)"
        out.append(f"{k} {f['value']:.4g} [{f['ci95'][0]:.3g}, {f['ci95'][1]:.3g}]{b} true {f['true']:.4g} {ok}")
    for k, ok in r.get("covered", {}).items():
        if k not in r.get("fitted", {}):
            out.append(f"{k} not fitted ✗")
    return "; ".join(out)


def table(rows: list[dict]) -> str:
    head = (f"{'case':28s} {'sim':8s} {'kind':10s} {'concealed':26s} {'reported':30s} {'ok':2s} {'RMSE red.':>9s}  "
            "parameters (95 % CI)")
    lines = [head, "-" * len(head)]
    for r in rows:
        red = r.get("rmse_reduction")
        reds = f"{red:9.2f}" if red is not None else f"{'':9s}"
        rep = "+".join(r.get("reported", [])) or (f"({r['verdict']})")
        if r["kind"] == "outside":
            ow = r.get("open_world") or {}
            rep = (rep if r.get("reported") else "") + (f" located:{ow.get('channel')}" if r.get("located") else " not located")
        lines.append(f"{r['case']:28s} {r.get('truth_model', 'paper'):8s} {r['kind']:10s} {str(r['truth'])[:26]:26s} "
                     f"{rep[:30]:30s} {'✓' if r['correct'] else '✗':2s} {reds}  {_fmt_params(r)}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", required=True, help="write the figures and rows here")
    ap.add_argument("--fast", action="store_true", help="only the quick subset run in CI")
    ap.add_argument("--realistic", action="store_true",
                    help="only the realistic-plant recordings (physical truth model, several effects, faults)")
    ap.add_argument("--cases", default=None, help="comma-separated case names (default: all)")
    ap.add_argument("--jobs", type=int, default=2, help="parallel processes (default: %(default)s)")
    ap.add_argument("--workdir", default=None, help="keep the recordings here (default: a temporary directory)")
    ap.add_argument("--reuse", action="store_true", help="diagnose recordings already in --workdir")
    ap.add_argument("--seed-offset", type=int, default=0,
                    help="add this to every case's seed: the same cases with noise, sensor draws and disturbances "
                         "the diagnosis was never run on (default: %(default)s, the suite's own recordings)")
    ap.add_argument("--simulate-only", action="store_true",
                    help="only write the recordings into --workdir (diagnose them later with --reuse)")
    args = ap.parse_args(argv)
    if args.simulate_only and args.workdir is None:
        ap.error("--simulate-only needs --workdir")
    sel = fast_cases() if args.fast else cases()
    if args.realistic:
        sel = [c for c in cases() if c.truth_model != "paper" or c.name.startswith("multi_")]
    if args.cases:
        want = {c.strip() for c in args.cases.split(",")}
        sel = [c for c in all_cases() if c.name in want]
    tmp = None
    workdir = args.workdir
    if workdir is None:
        tmp = tempfile.TemporaryDirectory()
        workdir = tmp.name
    Path(workdir).mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    names = [c.name for c in sel]
    if args.simulate_only:
        if args.jobs > 1:
            with ProcessPoolExecutor(max_workers=args.jobs) as ex:
                sims = list(ex.map(run_case, names, [workdir] * len(names), [args.reuse] * len(names),
                                   [True] * len(names), [args.seed_offset] * len(names)))
        else:
            sims = [run_case(n, workdir, args.reuse, True, args.seed_offset) for n in names]
        for r in sims:
            print(f"{r['case']:28s} simulated in {r['simulate_s']} s", flush=True)
        Path(args.json).write_text(json.dumps({"simulated": sims, "wall_s": round(time.perf_counter() - t0, 1)},
                                              indent=2), encoding="utf-8")
        return 0
    if args.jobs > 1:
        from concurrent.futures import as_completed

        with ProcessPoolExecutor(max_workers=args.jobs) as ex:
            futs = {ex.submit(run_case, n, workdir, args.reuse, False, args.seed_offset): n for n in names}
            done = {}
            for f in as_completed(futs):
                done[futs[f]] = f.result()
                print(table([done[futs[f]]]).splitlines()[-1], flush=True)   # progress, one line per case
            rows = [done[n] for n in names]
    else:
        rows = [run_case(n, workdir, args.reuse, False, args.seed_offset) for n in names]
    wall = time.perf_counter() - t0
    figs = summarize(rows)
    figs["wall_s"] = round(wall, 1)
    figs["seed_offset"] = args.seed_offset
    print(table(rows))
    print()
    for k, v in figs.items():
        print(f"{k:32s} {v}")
    out = {**figs, "cases": rows}
    Path(args.json).write_text(json.dumps(out, indent=2, ensure_ascii=False, default=_json_default), encoding="utf-8")
    if tmp is not None:
        tmp.cleanup()
    return 0


def _json_default(o):
    if isinstance(o, float) and not math.isfinite(o):
        return None
    try:
        return float(o)
    except (TypeError, ValueError):
        return str(o)


if __name__ == "__main__":
    sys.exit(main())
