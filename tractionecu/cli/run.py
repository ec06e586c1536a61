"""``tractionecu run``: the in-cab service (daemon), or ``--simulate`` without hardware.

``tractionecu run --config /etc/tractionecu/tractionecu.toml`` runs the
daemon on the configured CAN interface and GNSS serial port until SIGTERM
(see ``systemd/tractionecu.service``).

``tractionecu run --simulate`` simulates a scenario, then plays it in real
time (``--speed`` for faster) into the real service code over python-can's
``virtual`` interface and a pseudo-terminal serial port, prints one status
line a second and writes map tiles to ``--state-dir``.

Both serve the read-only in-cab page (``[web]``, default
http://127.0.0.1:8080/; ``--simulate`` prints its address) and send the
efficiency message ``TECU_EstEfficiency`` with s*, η and η(s*) (``[advice]``).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from pathlib import Path

from ..errors import ConfigError


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run the in-cab service (or --simulate it without hardware)",
                       description="Run the in-cab service on a CAN interface and a GNSS serial port, "
                                   "or with --simulate on the built-in simulator (no hardware, no root).")
    p.add_argument("--config", metavar="TOML", default=None, help="service configuration (default: built-in defaults)")
    p.add_argument("--state-dir", metavar="DIR", default=None,
                   help="state directory for map tiles and the resolved config "
                        "(default: service.state_dir, $STATE_DIRECTORY or ./tractionecu-state)")
    p.add_argument("--interface", default=None, help="override can.interface (python-can interface name)")
    p.add_argument("--channel", default=None, help="override can.channel")
    p.add_argument("--gps-port", default=None, help="override gps.port ('none' disables GNSS)")
    p.add_argument("--quiet", action="store_true", help="no status line (nor the page's address) on stdout")
    p.add_argument("--no-web", action="store_true", help="do not serve the in-cab page (web.enabled = false)")
    g = p.add_argument_group("simulation (no hardware needed)")
    g.add_argument("--simulate", action="store_true",
                   help="drive the service with the built-in simulator over a virtual CAN bus and a pty")
    g.add_argument("--scenario", default=None, help=f"simulated scenario (default: {SIM_DEFAULTS['scenario']})")
    g.add_argument("--seed", type=int, default=None, help=f"simulation seed (default: {SIM_DEFAULTS['seed']})")
    g.add_argument("--speed", type=float, default=None,
                   help="play the simulation this many times faster than real time (default: 1)")
    g.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after S seconds of simulated driving (default: the whole scenario)")
    p.set_defaults(func=run)


SIM_DEFAULTS = {"scenario": "paper-three-soils", "seed": 0, "speed": 1.0}
"""What ``--simulate`` takes for the simulation options not given (``--duration``: the whole scenario)."""


def _config(args: argparse.Namespace):
    from ..service.config import load_config, with_overrides

    cfg = load_config(args.config)
    over: dict[str, dict] = {}
    if args.state_dir:
        over.setdefault("service", {})["state_dir"] = str(args.state_dir)
    if args.interface:
        over.setdefault("can", {})["interface"] = args.interface
    if args.channel:
        over.setdefault("can", {})["channel"] = args.channel
    if getattr(args, "no_web", False):
        over.setdefault("web", {})["enabled"] = False
    if args.gps_port:
        if args.gps_port == "none":
            over.setdefault("gps", {})["source"] = "none"
        else:
            over.setdefault("gps", {}).update(source="serial", port=args.gps_port)
    return with_overrides(cfg, **over) if over else cfg


def keep_mf4_reader_out() -> None:
    """Keep asammdf out of the daemon: python-can imports it at ``import can`` whenever it is installed
    (the ``mf4`` extra, for its MF4 reader), and with pandas, polars and lxml it doubles the daemon's
    memory after its imports (47 → 94 MB peak RSS measured); the daemon reads no MF4."""
    if "can" not in sys.modules:
        sys.modules.setdefault("asammdf", None)   # ``import asammdf`` then raises ImportError, which python-can expects


JOURNAL_STATUS_EVERY_S = 60.0
"""Wall seconds between the status lines printed when standard output is not a terminal (the journal)."""


def run(args: argparse.Namespace) -> int:
    sim_only = [f"--{k}" for k in ("scenario", "seed", "speed", "duration") if getattr(args, k) is not None]
    if sim_only and not args.simulate:
        # the daemon on real hardware runs until it is stopped: a --duration it ignored left a user waiting
        raise ConfigError(f"{', '.join(sim_only)}: simulation options, given without --simulate")
    for k, v in SIM_DEFAULTS.items():
        if getattr(args, k) is None:
            setattr(args, k, v)
    cfg = _config(args)
    if not args.simulate:
        keep_mf4_reader_out()
        from ..service.daemon import run_service

        # on a terminal a line a second; otherwise (the journal of a systemd service) one a minute, so that
        # `journalctl -u tractionecu` shows how the service is doing without a line a second all day
        tty = sys.stdout.isatty()
        return run_service(cfg, status_stream=None if args.quiet else sys.stdout,
                           status_stream_every_s=0.0 if tty else JOURNAL_STATUS_EVERY_S)
    if not args.speed > 0:
        raise ConfigError(f"--speed: must be > 0, got {args.speed}")
    if args.duration is not None and not 0 < args.duration < float("inf"):
        raise ConfigError(f"--duration: must be > 0 and finite, got {args.duration}")
    if args.seed < 0:                     # numpy's generators take non-negative seeds only
        raise ConfigError(f"--seed: a non-negative integer, got {args.seed}")
    from ..sim import scenarios

    if args.scenario not in scenarios.SCENARIOS:   # before a simulation directory is announced
        raise ConfigError(f"scenario {args.scenario!r}: unknown (known: {', '.join(sorted(scenarios.SCENARIOS))})")
    from ..service.dispatch import codec_for

    codec_for(cfg)           # can.dbc and [signals] checked before the simulation runs, not after it
    ignored = [f"--{k.replace('_', '-')}" for k in ("interface", "channel", "gps_port") if getattr(args, k)]
    if cfg.estimation.vehicle:
        ignored.append("estimation.vehicle")
    if ignored:
        print(f"tractionecu run: {', '.join(ignored)}: not used with --simulate (the simulation plays on its own "
              "virtual CAN bus and NMEA pty, with the scenario's vehicle file)", file=sys.stderr)
    from ..service.daemon import hold_state_dir
    from ..sim.player import simulate_recording

    state = cfg.state_dir()
    state.mkdir(parents=True, exist_ok=True)
    # held from before the simulation is written: a second run --simulate on the same state directory wrote its
    # simulation over the one the first was playing (which lost half its frames) and only then was refused
    release = hold_state_dir(state)
    try:
        rec_dir = state / "simulation"
        print(f"simulating {args.scenario} (seed {args.seed}) into {rec_dir} ...", file=sys.stdout, flush=True)
        # in the main thread, before the event loop: Ctrl-C stops it at once (run in the loop's executor, Ctrl-C
        # waited for the whole simulation, a first run's kernel compilation included, and then said nothing)
        simulate_recording(args.scenario, args.seed, rec_dir, args.duration)
        return asyncio.run(simulate_main(cfg, args, rec_dir))
    finally:
        release()


async def simulate_main(cfg, args: argparse.Namespace, rec_dir) -> int:
    """Run the service against the simulation in ``rec_dir``, played over a virtual bus and a pty."""
    from ..sim.player import run_simulation

    out = sys.stdout
    res = await run_simulation(cfg, rec_dir, speed=args.speed, duration_s=args.duration,
                               status_stream=None if args.quiet else out, info_stream=out)
    print("done: " + json.dumps(res.summary), file=out, flush=True)
    return res.exit_code
