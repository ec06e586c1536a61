"""``tractionecu simulate``: write a simulated recording."""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from ..errors import ConfigError
from ..model.effects import parse_effect_arg
from ..sim import scenarios
from ..sim.physwriter import EXPORT_CSV
from ..sim.simulator import simulate
from ..sim.writer import write_recording


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="simulate a field run and write a recording directory")
    p.add_argument("--scenario", default="paper-three-soils", choices=sorted(scenarios.SCENARIOS),
                   help="named scenario (default: %(default)s)")
    p.add_argument("--truth", choices=("paper", "physical"), default=None,
                   help="truth model: paper (the filter's own equations) or physical (independent tyre-soil, "
                        "load-transfer, kinematics and drive-line physics); default: the scenario's")
    p.add_argument("--out", required=True, help="recording directory to write")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds [s]")
    p.add_argument("--effect", action="append", default=[], metavar="NAME[=VALUE|:P=V,...]",
                   help="switch an effect on in the truth model, e.g. grade, gps_latency=0.15, "
                        "mass:delta_kg=800,front_share=1 (repeatable)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0.0):
        raise ConfigError(f"--duration: a number of seconds > 0, got {args.duration}")
    if args.seed < 0:                     # numpy's generators take non-negative seeds only
        raise ConfigError(f"--seed: a non-negative integer, got {args.seed}")
    out = Path(args.out)
    if out.is_dir() and any((out / n).exists() for n in ("can.log", "gps.nmea", EXPORT_CSV)) and \
            not (out / "truth.toml").is_file():
        raise ConfigError(f"--out {out}: holds a recording that was not simulated (can.log, gps.nmea or {EXPORT_CSV} "
                          "without truth.toml); the simulation would overwrite it: choose another directory")
    parsed = [parse_effect_arg(e) for e in args.effect]
    twice = sorted({n for n, _ in parsed if sum(m == n for m, _ in parsed) > 1})
    if twice:                             # the last one was kept without a word
        raise ConfigError(f"--effect {', '.join(twice)}: given more than once; give each effect once, with all "
                          "its parameters (--effect NAME:P=V,Q=W)")
    effects = dict(parsed)
    scn = scenarios.get(args.scenario, seed=args.seed, effects=effects, duration_s=args.duration)
    mech = scn.truth == "physical" and scn.physical is not None and scn.physical.drivetrain.kind != "hub"
    if args.truth is not None:
        scn = scenarios.with_truth(scn, args.truth)
    if effects and scn.truth == "physical":   # simulate_physical raised them as a ValueError traceback
        raise ConfigError(f"--effect {', '.join(effects)}: effects belong to the paper truth model; {scn.name} runs "
                          "the physical one, which has its own physics (with --truth paper it runs on the paper "
                          "model, which takes them)")
    note = ""
    if mech and scn.truth == "paper":     # scenarios.with_truth: the paper model drives the hubs
        note = " (hub drive: the paper truth model has no engine, gearbox or mechanical front-wheel drive)"
    if "grade" in effects and not scn.field.terrain.source.startswith("OFPEDATA2"):
        from ..sim.terrain import Terrain
        scn.field.terrain = Terrain.henrys_field()
        scn.field.terrain_offset = (300.0, 300.0)
    if "grade" in effects:
        scn.field.relief_scale = effects["grade"]["scale"]
    t0 = time.perf_counter()
    tr = simulate(scn)
    counts = write_recording(scn, tr, args.out)
    wall = time.perf_counter() - t0
    # EC1 goes out in transport-protocol frames (TP.CM, TP.DT), which are counted; the message is not a frame
    frames = sum(v for k, v in counts.items() if k not in ("nmea_lines", "EC1"))
    print(f"{scn.name} ({scn.truth} truth): {tr.t[-1]:.1f} s simulated in {wall:.1f} s; {frames} CAN frames, "
          f"{counts['nmea_lines']} NMEA lines -> {args.out}{note}")
    return 0
