"""The ``tractionecu`` command: one entry point, one module per subcommand.

Each subcommand module has ``add_subparser(subparsers)`` which binds its
handler as ``func``.  A subcommand whose module cannot be imported (for
example a missing optional dependency) is reported when used; the others keep
working.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from typing import Sequence

from .. import __version__
from ..errors import TractionEcuError

SUBCOMMANDS = ("simulate", "inspect", "replay", "map", "run", "diagnose", "fleet")

log = logging.getLogger("tractionecu")

DESCRIPTION = """\
Estimate, while a tractor drives, how well the ground carries traction: the
adhesion coefficient of each wheel and the soil rolling resistance, from the
drive torques, axle load, draft force and wheel speeds on the CAN bus and the
GNSS speed, and map them."""

EPILOG = """\
examples:
  tractionecu inspect capture.blf            what a capture holds (any common CAN log format)
  tractionecu replay --out run/ REC          the estimator over a recording (directory or capture file)
  tractionecu map export --help              the ground-condition map as GeoTIFF, ISO-XML, PNG, GeoJSON
  tractionecu fleet map DIR --out OUT        a fleet's recordings on Dask: Parquet results, one farm map
  tractionecu run --simulate                 the in-cab service without hardware
  tractionecu COMMAND --help                 the options of one command

Python:  from tractionecu import Estimator, VehicleParams, read_recording, replay"""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tractionecu", description=DESCRIPTION, epilog=EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"tractionecu {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", title="commands")
    for name in SUBCOMMANDS:
        try:
            mod = importlib.import_module(f"tractionecu.cli.{name}")
        except ImportError as exc:
            p = sub.add_parser(name, help=f"(unavailable: {exc})")
            p.set_defaults(func=_unavailable(name, exc))
            p.add_argument("rest", nargs=argparse.REMAINDER)
            continue
        mod.add_subparser(sub)
    return parser


def _unavailable(name: str, exc: Exception):
    def run(args: argparse.Namespace) -> int:
        print(f"tractionecu {name}: unavailable: {exc}", file=sys.stderr)
        return 2
    return run


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI with ``argv`` (default: ``sys.argv[1:]``); returns the exit code."""
    try:
        parser = build_parser()        # imports every subcommand's modules: seconds on a cold start
    except KeyboardInterrupt:          # Ctrl-C then printed an import's traceback
        return 130
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except TractionEcuError as exc:
        print(f"tractionecu {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:              # a path the file system refuses (exists as a file, permission, disk full)
        if exc.filename is None:
            raise
        where = f"{exc.filename}" + (f" -> {exc.filename2}" if exc.filename2 else "")
        print(f"tractionecu {args.command}: error: {where}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
