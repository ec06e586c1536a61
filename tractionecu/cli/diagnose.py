"""``tractionecu diagnose``: find why a recording and the model disagree, name the effect, fit it.

``--dbc FILE`` (repeatable) adds the owner's DBC files to the built-in one
for every read of the recording; a ``[signals]`` table in its
``vehicle.toml`` maps their signals onto contract names.

Exit status: 0 with a verdict, 4 (as ``replay`` with missing signals) when nothing could be tested
(verdict ``untestable``: the recording is too short, or has none of the signals an effect acts on); the
report is written either way.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from .inspect import add_dbc_option
from .replay import EXIT_MISSING_SIGNALS

EPILOG = """\
writes OUT/report.json, OUT/report.md and three figures; the verdict is one of
effect, ambiguous, none, unexplained (a located mismatch no library effect
explains) or untestable (nothing could be tested: too short, standing, or
without the signals any effect acts on).

exit status: 0 with a verdict, 4 with the verdict untestable (the report is
written either way), 1 on an error (nothing written), 130 when interrupted
(the folder's earlier report left whole)."""

REFERENCE_TORQUE_MAX_NM = 64255.0
"""Largest engine reference torque J1939 SPN 544 can carry [N·m] (the vehicle file's bound too)."""


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("diagnose", help="locate and name the physics a recording shows and the model lacks",
                       formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EPILOG)
    p.add_argument("recording", help="recording directory (can.log, gps.nmea, vehicle.toml) or a decoded CSV export")
    p.add_argument("--out", required=True, help="directory for report.json, report.md and the figures")
    p.add_argument("--vehicle", default=None, help="vehicle.toml (default: the recording's own)")
    p.add_argument("--csv-mapping", choices=("contract", "j1939", "auto"), default=None,
                   help="the recording is a decoded CSV export with these column names; auto: J1939 "
                        "message.signal names with or without a bus prefix (CAN1., can0_), time in epoch "
                        "s or ms or as a date-time")
    p.add_argument("--csv-timezone", default=None,
                   help="zone of CSV date-times that name none: UTC (default), +02:00 or Europe/Berlin")
    p.add_argument("--reference-torque", type=float, default=None,
                   help="engine reference torque [N·m] (J1939 SPN 544) for percent-torque CSV columns, and for "
                        "a bus recording whose capture holds no EC1")
    p.add_argument("--time-offset", type=float, default=0.0, help="added to the CSV time column [s]")
    p.add_argument("--no-estimator", action="store_true", help="skip the estimator-innovation view")
    add_dbc_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..bus.dbc import extra_dbcs
    from ..diagnose import diagnose_path
    from ..errors import ConfigError

    # a value that is no finite number reached the export's times or torques and was reported as its data
    # ("no signal with more than two samples", "missing signals: engine_torque")
    if not math.isfinite(args.time_offset):
        raise ConfigError(f"--time-offset: must be a finite number of seconds, got {args.time_offset}")
    if args.reference_torque is not None and not 0.0 < args.reference_torque <= REFERENCE_TORQUE_MAX_NM:
        raise ConfigError(f"--reference-torque: must be > 0 and at most {REFERENCE_TORQUE_MAX_NM:.0f} N·m "
                          f"(J1939 SPN 544's range), got {args.reference_torque}")
    if (args.csv_mapping or args.csv_timezone) and Path(args.recording).is_dir():
        # (it was read as one: "REC: cannot read: Is a directory")
        raise ConfigError(f"--csv-mapping, --csv-timezone: for a decoded CSV export; {args.recording} is a "
                          "recording directory (give the export's file, or leave these options out)")
    csv_mapping = args.csv_mapping
    if args.csv_timezone is not None:
        from ..recording.csv_import import mapping_named

        csv_mapping = mapping_named(csv_mapping or "auto", timezone=args.csv_timezone)
    t0 = time.perf_counter()
    with extra_dbcs(args.dbc):
        rep = diagnose_path(args.recording, args.out, vehicle=args.vehicle, csv_mapping=csv_mapping,
                            reference_torque_nm=args.reference_torque, time_offset_s=args.time_offset,
                            estimator=not args.no_estimator)
    dt = time.perf_counter() - t0
    head = rep["verdict"] + (f": {rep['effect']}" if rep.get("effect") else "")
    if rep.get("ambiguous_between"):
        head += " (" + " / ".join(rep["ambiguous_between"]) + ")"
    lines = [head, rep["statement"]]
    for e in rep.get("effects") or []:
        ps = ", ".join((f"{k} = {p['value']:.4g}" if isinstance(p.get("value"), (int, float)) else f"{k} = {p.get('value')}")
                       + (f" (at its {p['at_bound']} bound)" if p.get("at_bound") else "")
                       + (" (not identified)" if p.get("identified") is False else "")
                       for k, p in (e.get("parameters") or {}).items())
        lines.append(f"  {e['kind']:15s} {e['name']}" + (f": {ps}" if ps else "")
                     + (" (ambiguous)" if e.get("ambiguous") else "")
                     + (" (not named)" if e.get("named") is False and e["kind"] not in ("nominal",) else "")
                     + (f" (explains as well: {', '.join(e['consistent_with'])})" if e.get("consistent_with") else ""))
    lines.append(f"-> {Path(args.out) / 'report.md'} ({dt:.1f} s)")
    print("\n".join(lines))
    return EXIT_MISSING_SIGNALS if rep["verdict"] == "untestable" else 0
