"""``tractionecu replay REC --out RUN [--rate 100] [--plot] [--dbc FILE ...]``: run the estimator over a recording.

The work is the pipeline's (:func:`tractionecu.pipeline.rundir.replay_to_dir`:
the step grid phased to the wheel-speed frames, the step rule and GNSS gate
the daemon applies, ``estimates.csv``, ``config.toml``, the map).  The
estimator runs in batch replay's compiled loop where it covers the machine,
and ``--step-path`` runs the daemon's own ``Estimator.step`` instead: the same
estimates, float for float, slower (the summary's first line says which ran).  With a
simulated recording (``truth.csv``), the evaluation side
(:func:`tractionecu.evaluation.replay.score_replay`) adds ``scorecard.json``
(also printed as a table), ``map_scorecard.json`` and, with ``--plot``, the
paper's Fig. 6 (``fig6_mu_rho.png``) and Fig. 5 (``fig5_mu_curves.png``).

``--dbc FILE`` (repeatable) adds the owner's DBC files to the built-in one; a
``[signals]`` table in the recording's ``vehicle.toml`` maps their signals
onto contract names (:func:`tractionecu.config.signal_map`).

The estimator runs the ``hub`` profile (:data:`tractionecu.pipeline.signals.PROFILES`).
A recording without its wheel speeds and drive torques (a tractor with a
mechanical drivetrain, such as the John Deere 5055E capture) is not
replayed: the command writes nothing and reports on stderr the profile the
estimator runs, the signals missing, the profile the recording comes
closest to, and the motion its speed signals show ("no motion" for a
standing tractor).  A recording that has them but lacks the front-axle
load, the draft or the GNSS speed is replayed with a note: the estimator
flags those steps with its time-out bits.

Exit codes: 0 ok, 1 the recording or configuration cannot be read (the
message names the file or key), 3 ``--plot`` without matplotlib, 4 the
recording lacks the signals of the profile the estimator runs (report on
stderr).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from ..errors import ConfigError
from ..mapping.export import DEFAULT_OUT as EXPORT_DEFAULT_OUT
from ..estimation.estimator import SLIP_UNCERTAIN
from ..pipeline.replay import RATE_HZ
from .inspect import add_dbc_option

EXIT_MISSING_SIGNALS = 4
"""Exit code when the recording lacks the signals of the profile the estimator runs."""

# Bounds of --rate [Hz]: the service's estimation.rate_hz range; above it the step grid outgrows memory
# (--rate 1e9 asked for 149 GiB on a 20 s recording).  The pipeline's own check (pipeline.replay.check_rate).


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="run the estimator over a recording; score it against truth if present")
    p.add_argument("recording", metavar="REC", help="recording directory")
    p.add_argument("--out", required=True, metavar="RUN", help="output directory")
    p.add_argument("--rate", type=float, default=100.0, help="estimator rate [Hz], 1 to 1000 (default: %(default)s)")
    p.add_argument("--plot", action="store_true", help="also write the paper's Fig. 5 and Fig. 6 as PNG")
    p.add_argument("--no-map", action="store_true", help="do not write map tiles (RUN/map) and map_scorecard.json")
    p.add_argument("--config", metavar="TOML", default=None,
                   help="estimator configuration ([estimator] table, optional [estimator.fuzzy])")
    p.add_argument("--classes", default=None, metavar="A,B,...",
                   help="surface classes to fit (overrides the configuration), e.g. stubble,grassland,tilled,road")
    p.add_argument("--step-path", action="store_true",
                   help="run the daemon's Estimator.step per step instead of the compiled loop (same estimates)")
    add_dbc_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..bus.dbc import extra_dbcs
    from ..config import replace
    from ..estimation.estimator import EstimatorConfig, load_estimator_config
    from ..pipeline.replay import MissingSignals
    from ..pipeline.rundir import replay_to_dir

    cfg = load_estimator_config(args.config) if args.config else EstimatorConfig()
    if args.classes:
        cfg = replace(cfg, soil_classes=tuple(c.strip() for c in args.classes.split(",") if c.strip()))
    if not RATE_HZ[0] <= args.rate <= RATE_HZ[1]:         # NaN fails too
        raise ConfigError(f"--rate: an estimator step rate in [{RATE_HZ[0]:g}, {RATE_HZ[1]:g}] Hz, got {args.rate}")
    if args.plot:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            print("tractionecu replay: --plot needs matplotlib (pip install 'tractionecu[maps]')", file=sys.stderr)
            return 3
    earlier = _products(Path(args.out))
    try:
        with extra_dbcs(args.dbc):
            # --plot draws every step: without truth.csv the streamed replay kept only the map's steps (none
            # with --no-map), and the figures failed on an empty array
            summary, rec, res = replay_to_dir(args.recording, args.out, rate_hz=args.rate, cfg=cfg,
                                              write_map=not args.no_map, keep_arrays=True if args.plot else None,
                                              compiled=False if args.step_path else None)
    except MissingSignals as e:
        print("\n".join(missing_report(e.recording, e.missing)), file=sys.stderr)
        return EXIT_MISSING_SIGNALS
    if rec.truth_csv_path is not None or args.plot:
        from ..evaluation.replay import score_replay

        summary.update(score_replay(args.out, rec, res.arrays, plot=args.plot, summary=summary))
    removed = _remove_stale(Path(args.out), earlier, _products(Path(args.out)))
    print("\n".join([*profile_note(rec), *rejects_note(rec), *clock_gnss_note(rec, summary), *curve_note(rec, res),
                      format_summary(summary)]))
    if removed:
        print(f"removed from {args.out} what an earlier replay had written there and this one did not: "
              + ", ".join(removed))
    return 0


PRODUCTS = ("map", "scorecard.json", "map_scorecard.json", "fig6_mu_rho.png", "fig5_mu_curves.png",
            "fig_efficiency.png", "report.html", *(f"export/{name}" for name in EXPORT_DEFAULT_OUT.values()))
"""What a replay may write into its output directory beside ``estimates.csv`` and ``config.toml``, and what
``tractionecu map export`` writes there by default (an export of the map a new replay replaced is stale)."""


def _products(out: Path) -> dict[str, int]:
    """The replay products present in ``out`` and their modification times [ns] (of ``map/manifest.json``
    for the map)."""
    found = {}
    for name in PRODUCTS:
        p = out / name / "manifest.json" if name == "map" else out / name
        try:
            found[name] = p.stat().st_mtime_ns
        except OSError:
            pass                                      # a map/ without a manifest is no replay's: left alone
    return found


def _remove_stale(out: Path, before: dict[str, int], after: dict[str, int]) -> list[str]:
    """Remove the products an earlier replay left in ``out`` that this replay did not write anew: a
    scorecard, map or figure of another recording must not sit beside this replay's estimates as if it
    were theirs.  Returns the names removed.  Called only after the new replay succeeded, so a replay that
    fails loses nothing already written.
    """
    import shutil

    removed = []
    for name, mtime in before.items():
        if name not in after:                          # removed by this replay's own step (its map)
            removed.append(name)
            continue
        if after[name] != mtime:
            continue                                   # written anew
        p = out / name
        if p.is_dir():
            shutil.rmtree(p)
        else:
            p.unlink(missing_ok=True)
        removed.append(name)
    return removed


def curve_note(rec: Any, res: Any) -> list[str]:
    """Why the μ(s) curve's ``a`` was never identified, when it was not: a replay whose every estimate held
    ``a`` = NaN (1–2 Hz GNSS: the slip's σ from the ground speed's never within ``slip_sigma_max``) exited 0
    with "map: 87 of 90 GNSS epochs mapped" and a map without its ``a`` layer, and nothing said so."""
    import numpy as np

    arr = getattr(res, "arrays", None) or {}
    a = np.asarray(arr.get("a", ()), dtype=float)
    status = np.asarray(arr.get("status", ()), dtype=np.int64)
    valid = np.asarray(arr.get("valid", ()), dtype=bool)
    if not a.size or np.isfinite(a).any() or not valid.any():
        return []
    held = float(np.mean((status[valid] & SLIP_UNCERTAIN) != 0))
    gps = getattr(rec, "gps", ())
    rate = ""
    if len(gps) > 1 and gps.t[-1] > gps.t[0]:
        rate = f"; GNSS epochs at {(len(gps) - 1) / (gps.t[-1] - gps.t[0]):.1f} Hz"
    return [f"curve: a was never identified: the slip was not supported on {100 * held:.0f} % of the valid steps "
            f"(its σ from the ground speed's above [estimator] slip_sigma_max{rate}); μ and ρ_s are estimated, "
            "no a is mapped"]


def clock_gnss_note(rec: Any, summary: dict[str, Any]) -> list[str]:
    """The CAN-to-GNSS clock offset the reader applied (as ``inspect`` reports it) and the GNSS epochs the
    gate refused (``pipeline/gnss.py``): a replay whose CAN times were moved, or whose GNSS speed never
    reached the estimator, says so."""
    from .inspect import time_lines

    out = []
    note = getattr(getattr(rec, "stats", None), "clock_note", "")
    if note:
        out.append(f"clock: {note}")
    if getattr(rec, "stats", None) is not None:
        # a clock stepped while logging (set by GNSS, a logger reboot): inspect's warnings, which the
        # replay's figures (its duration, its real-time factor, the epochs without CAN) depend on
        out += [ln.strip() for ln in time_lines(rec) if ln.strip().startswith("WARNING")]
    gated = {k[len("gated_"):]: int(v) for k, v in (summary.get("gnss_gated") or {}).items()
             if k.startswith("gated_") and v}
    n = len(getattr(rec, "gps", ()))
    if gated and n:
        total = sum(gated.values())
        why = ", ".join(f"{k} {v}" for k, v in sorted(gated.items()))
        out.append(f"GNSS: {total} of {n} epochs refused by the gate ({why})"
                   + ("; no GNSS speed or position reached the estimator or the map" if total >= n else ""))
    return out


def rejects_note(rec: Any) -> list[str]:
    """The lines of the recording's files that were skipped (counted by reason, with the first line
    numbers), as ``inspect`` lists them: a replay over a damaged capture says what it left out."""
    from ..recording.summary import other_source_lines, wrong_length_line

    out = []
    stats = getattr(rec, "stats", None)
    for fname, st in getattr(stats, "files", {}).items():
        if getattr(st, "total_rejected", 0):
            out += [f"skipped {line}" for line in st.describe()]  # type: ignore[attr-defined]
        out += getattr(st, "notes", list)()
        back = getattr(st, "rejected", {}).get("time_backwards", 0)
        first = (getattr(st, "examples", {}).get("time_backwards") or [0])[0]
        if back and first and back >= 0.9 * (st.lines - first + 1) and back >= 0.01 * max(st.lines, 1):
            # every line from one on was stamped before the lines ahead of it: the clock restarted there (a
            # logger's reboot), not an order to sort (sorting interleaved the two runs and the clocks
            # could no longer be reconciled)
            out.append(f"{fname}: its clock restarted at line {first} (a logger restarted?): the {back} lines "
                       f"from there on are stamped before the lines ahead of them and were left out; split the "
                       f"capture at line {first} (head -n {first - 1} {fname} > part1.log; tail -n +{first} "
                       f"{fname} > part2.log) and replay each part")
        elif back and back >= 0.01 * max(getattr(st, "lines", 0), 1):
            # a capture merged from several interfaces, or stamped on arrival, out of time order: its frames
            # are read in file order, and each one earlier than the latest before it is left out
            out.append(f"{fname}: {back} of {st.lines} lines ({100.0 * back / max(st.lines, 1):.1f} %) are stamped "
                       "earlier than a line before them and were left out: if the capture is out of time order, "
                       f"sort it by time first (candump -L: sort -s -n -k1.2 {fname} > sorted.log)")
    if stats is not None and (line := wrong_length_line(stats)):
        out.append(line)
    if stats is not None and getattr(stats, "other_sources", None):
        out += other_source_lines(stats)
    return out


def missing_report(rec: Any, missing: list[str]) -> list[str]:
    """Why a recording is not replayed: the profile the estimator runs, what it lacks, the closest profile,
    the motion the recording shows."""
    from ..cli.inspect import vehicle_of
    from ..pipeline.signals import PROFILE_KINDS, best_profile, estimator_profile, motion, profile_role, profile_status

    veh, origin = vehicle_of(rec)
    run_as = estimator_profile(veh)
    status = profile_status(rec, veh)
    lines = [f"tractionecu replay: {rec.path}: not replayed: profile {run_as} (the one the estimator runs, "
             f"{origin}) lacks {len(missing)} bus signal(s) it cannot run without",
             f"  missing: {', '.join(missing)}"]
    absent = [need.what for need, sig in status[run_as] if sig is None]
    lines.append(f"  profile {run_as}: {len(status[run_as]) - len(absent)} of {len(status[run_as])} needs found"
                 + (f"; missing {', '.join(absent)}" if absent else ""))
    for name, needs in status.items():
        if name == run_as:
            continue
        got = [need.what for need, sig in needs if sig is not None]
        lack = [need.what for need, sig in needs if sig is None]
        lines.append(f"  profile {name} ({profile_role(name, run_as)}): {len(got)} of {len(needs)} needs found"
                     + (f"; found {', '.join(got)}" if got else "") + (f"; missing {', '.join(lack)}" if lack else ""))
    best = best_profile(status)
    if best != run_as:
        lines.append(f"  the signals fit profile {best} best: declare [drivetrain] {PROFILE_KINDS[best]} in "
                     "vehicle.toml to run it")
    lines.append(f"  motion: {motion(rec).describe()}")
    lines.append(f"  'tractionecu inspect {rec.path}' lists every signal found and missing; an owner's own "
                 "messages: --dbc FILE and a [signals] table in vehicle.toml")
    return lines


def profile_note(rec: Any) -> list[str]:
    """A line naming the hub needs the recording lacks though replay runs (the estimator flags those steps)."""
    from ..pipeline.replay import machine_of
    from ..pipeline.signals import estimator_profile, motion, profile_status

    veh = machine_of(rec)[0]
    run_as = estimator_profile(veh)                      # hub, or mechanical for an engine-driven [drivetrain]
    absent = [need.what for need, sig in profile_status(rec, veh)[run_as] if sig is None]
    out = []
    if getattr(rec, "vehicle_toml_path", None) is None:
        out.append("no vehicle.toml beside the recording: the default machine (the paper's 6300 kg hub-drive "
                   "tractor) stands in; its masses, radii and drivetrain may not be this machine's")
    if run_as == "mechanical" and "draft" in absent:      # by design: the machine-level estimator's sum
        absent.remove("draft")
        out.append("profile mechanical: no draft: rho_s and the draft are estimated as their sum, rho_s is not "
                   "reported (status rho_s_and_draft_not_separated)")
    if absent:
        out.append(f"profile {run_as}: missing {', '.join(absent)}: the estimator flags those steps (time-out bits)")
    mo = motion(rec, engine=False)                        # the survey keeps no whole engine speed
    if mo.moving is not True:                             # a stationary capture: no estimate converges
        out.append(f"motion: {mo.describe()}")
    return out


def format_summary(res: dict[str, Any]) -> str:
    """The scorecard (if any) and run figures as a plain-text table."""
    lines = [f"replay: {res['steps']} steps, {res['sim_seconds']:.1f} s simulated in {res['wall_seconds']:.2f} s "
             f"({res['realtime_factor']:.0f}x real time; loop: {res.get('loop', 'step path')})"]
    sc = res.get("scorecard")
    if sc:
        from ..evaluation.scoring import R2_TARGET_SLIP_SPAN
        if "error" in sc:
            lines.append(f"scorecard: {sc['error']}")
        else:
            mach = sc.get("level") == "machine"          # machine-level μ (estimation.machine): issue 14 targets
            rows = [("mu_mean_abs_rel_error" + ("[machine]" if mach else ""),
                     f"{sc['mu_mean_abs_rel_error'] * 100:.2f} %", "<= 4 %" if mach else "<= 2 %"),
                    ("mu_mean_abs_error", f"{sc['mu_mean_abs_error']:.4f}", ""),
                    ("rho_s_mean_abs_error", f"{sc['rho_s_mean_abs_error']:.4f}"
                     if math.isfinite(sc["rho_s_mean_abs_error"]) else "n/a: no rho_s reported",
                     "<= 0.015" if mach else ""),
                    ("reconvergence_s", f"{sc['reconvergence_s']:.2f} s", "<= 2 s"),
                    ("nis_within_95", f"{sc['nis_within_95'] * 100:.1f} %", "~95 %"),
                    ("t_first_convergence_s", f"{sc['t_first_convergence_s']:.2f} s", "")]
            for name, r2 in sc["r2_mu_curve"].items():
                c = sc["curves"].get(name, {})
                extra = f" (a {c.get('a_identified', float('nan')):.3f} vs {c.get('a_true', float('nan')):.3f})" if c else ""
                span = sc.get("slip_span", {}).get(name, math.nan)
                target = ">= 0.95" if mach else ">= 0.98"
                if not mach and not span >= R2_TARGET_SLIP_SPAN:    # issue 13's target: spans of 0.04 and more
                    target = f"n/a: true slips span {span:.3f} < {R2_TARGET_SLIP_SPAN}"
                elif math.isfinite(span):
                    target += f" (true slips span {span:.3f})"
                rows.append((f"r2_mu_curve[{name}]", f"{r2:.4f}{extra}", target))
            if mach:
                if "valid_fraction" in sc:                 # the population of the errors above
                    rows.insert(1, ("valid_fraction (mu, rho_s over valid)", f"{sc['valid_fraction'] * 100:.1f} %", ""))
                    rows.insert(2, ("mu_mean_abs_rel_error_all", f"{sc['mu_mean_abs_rel_error_all'] * 100:.2f} %",
                                    "every step after convergence"))
                rows += [(f"curve_path[{n}]", str(c.get("curve_path", "")), "") for n, c in sc["curves"].items()]
                rows.append(("rho_s_reported_fraction", f"{sc['rho_s_reported_fraction'] * 100:.1f} %",
                             "0 % without a draft sensor"))
            w = max(len(r[0]) for r in rows)
            w2 = max(len(r[1]) for r in rows)
            lines.append(f"{'metric':<{w}}  {'value':<{w2}}  target")
            lines += [f"{a:<{w}}  {b:<{w2}}  {c}" for a, b, c in rows]
    lines += res.get("truth_skipped", [])
    msc = res.get("map_scorecard")
    if msc:
        def num(x: Any, fmt: str, scale: float = 1.0) -> str:    # None: nothing to score (no ρ_s mapped)
            return "n/a" if x is None else format(x * scale, fmt)

        acc = num(msc['map_soil_accuracy'], '.1f', 100.0)
        lines.append(f"{'map_soil_accuracy':<22}  {acc}{'' if acc == 'n/a' else ' %'}  (target >= 95 %)")
        lines.append(f"{'map_a_rmse':<22}  {num(msc['map_a_rmse'], '.4f')}")
        lines.append(f"{'map_rho_s_rmse':<22}  {num(msc['map_rho_s_rmse'], '.4f')}")
    if "map_samples" in res and "map_epochs" not in res:    # no tiles written (mapping.from_replay)
        lines.append("map: none written: the recording has no GNSS epoch with a position")
    elif "map_samples" in res:
        from ..mapping.from_replay import REFUSED_WORDS

        refused = "; ".join(f"{n} {REFUSED_WORDS.get(k, k)}" for k, n in res.get("map_refused", {}).items())
        lines.append(f"map: {res['map_samples']} of {res.get('map_epochs', 0)} GNSS epochs mapped"
                     + (f" (not mapped: {refused})" if refused else "") + f" -> {res['map_dir']}")
    for axle, c in res.get("radius_calibration", {}).items():       # estimation/calibration.py
        if c.get("blocks"):
            val = "n/a" if c["scale"] is None else f"{c['scale']:.4f} ± {c['halfwidth95']:.4f} (95 %)"
            lines.append(f"radius_scale[{axle}]: {val}, {c['blocks']} low-slip blocks, "
                         f"{'applied' if c['applied'] else 'not applied'}")
    for k in ("estimates_csv", "scorecard_json", "config"):
        if k in res:
            lines.append(f"{k}: {res[k]}")
    for p in res.get("plots", []):
        lines.append(f"plot: {p}")
    return "\n".join(lines)
