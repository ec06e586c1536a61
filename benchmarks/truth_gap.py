"""Where the estimator's error on the physical truth comes from: one physical difference at a time.

Runs ``physical-three-soils`` (or ``--scenario``) on the physical truth model, then again with its
differences from the filter's model taken away one after another, replays each recording with
``tractionecu replay`` and prints the estimator's μ error and ρ_s error:

    A  as simulated
    B  A without the hub reduction's losses (η = 1, no drag)
    C  B with a level line of pull (the draft's vertical part no longer loads the rear axle)
    D  C with the truth's rolling radius equal to the filter's (vertical stiffness chosen so that
       r0 − δ/3 is Guskov's r0 − Δr at every load)

What is left in D is what the tyre–soil law (load-dependent μ(s), μ(0) ≠ 0, ρ_s growing with
slip), the relaxation length, the drive-line compliance, the toothed pickups and the turns cost.
Each variant's ``vehicle.toml`` is what the recording writer declares for that variant (the
owner's knowledge of it), so the rows measure what is left after those declarations.

    python benchmarks/truth_gap.py [--scenario NAME] [--duration S] [--seed N] [--work DIR]
"""

from __future__ import annotations

import argparse
import dataclasses as dc
import math
import subprocess
import sys
import tempfile
from pathlib import Path

from tractionecu.evaluation.replay import read_scorecard
from tractionecu.sim import scenarios
from tractionecu.sim.simulator import simulate
from tractionecu.sim.writer import write_recording


def variants(scn):
    ps = scn.physical
    veh = scn.vehicle
    hub = ps.drivetrain.hub
    b = dc.replace(ps, drivetrain=dc.replace(ps.drivetrain, hub=dc.replace(hub, efficiency=1.0, drag_nms=0.0)))
    c = dc.replace(b, hitch=dc.replace(ps.hitch, pull_angle_deg=0.0))
    k_per_pa = 2.0 * math.pi * math.sqrt(veh.tyre_width_m * veh.r0_m / 2.0) / 3.0
    d = dc.replace(c, tyre=dc.replace(ps.tyre, k_z_carcass_npm=0.0, k_z_per_pa=k_per_pa))
    return [("A as simulated", ps), ("B no hub losses", b), ("C B + level pull", c), ("D C + filter's radius", d)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="physical-three-soils")
    ap.add_argument("--duration", type=float, default=240.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--work", default=None, help="directory for the recordings (default: a temporary one)")
    args = ap.parse_args(argv)
    base = scenarios.get(args.scenario, seed=args.seed, duration_s=args.duration)
    if base.truth != "physical" or base.physical.drivetrain.kind != "hub":
        ap.error("a hub-drive scenario on the physical truth model")
    work = Path(args.work or tempfile.mkdtemp(prefix="truth_gap_"))
    print(f"{args.scenario}, seed {args.seed}, {args.duration:.0f} s; recordings in {work}")
    print(f"{'variant':26s} {'mu rel err':>10s} {'rho_s MAE':>10s}")
    for i, (name, spec) in enumerate(variants(base)):
        scn = dc.replace(base, physical=spec)
        rec, run = work / f"rec{i}", work / f"run{i}"
        write_recording(scn, simulate(scn), rec)
        subprocess.run([sys.executable, "-m", "tractionecu", "replay", str(rec), "--out", str(run), "--no-map"],
                       check=True, capture_output=True)
        sc = read_scorecard(run / "scorecard.json")
        print(f"{name:26s} {100 * sc['mu_mean_abs_rel_error']:9.2f} % {sc['rho_s_mean_abs_error']:10.4f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
