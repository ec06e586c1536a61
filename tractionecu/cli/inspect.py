"""``tractionecu inspect REC [--dbc FILE ...]``: what a recording holds, and what was wrong with it.

The report (:func:`tractionecu.recording.summary.summarize`): duration,
frames, rates and gaps per message, unknown PGNs, decode errors, address
claims, GNSS epochs, rejected lines, then for each estimation profile the
contract signals found (with the message they came from) and missing, and
whether the speed signals show motion.

``--dbc FILE`` (repeatable) adds the owner's DBC files to the built-in one;
a ``[signals]`` table in the recording's ``vehicle.toml`` maps their
signals onto contract names (:func:`tractionecu.config.signal_map`).
"""

from __future__ import annotations

import argparse

from ..bus.dbc import Codec, extra_dbcs
from ..recording.reader import read_recording
from ..recording.summary import summarize


def add_dbc_option(p: argparse.ArgumentParser) -> None:
    """``--dbc FILE``, repeatable: the owner's DBC files, loaded beside the built-in one."""
    p.add_argument("--dbc", action="append", default=[], metavar="FILE",
                   help="the owner's DBC file, added to the built-in one (repeatable); map its signals onto the "
                        "contract names with a [signals] table in the recording's vehicle.toml")


def dbc_lines(codec: Codec) -> list[str]:
    """The owner's DBC files of ``codec``: messages added, messages skipped and why."""
    out = []
    for path in codec.extra_paths:
        names = [m.name for m in codec.messages.values() if m.source == path.name]
        out.append(f"  owner DBC {path.name}: {len(names)} messages ({', '.join(names)})")
        out += [f"    skipped {msg}: {why}" for f, msg, why in codec.skipped if f == path.name]
    return out


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("inspect", help="print duration, frame counts, rates, gaps, rejected lines and the signals "
                                       "each estimation profile finds or misses")
    p.add_argument("recording", help="recording directory (or a candump file)")
    add_dbc_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    with extra_dbcs(args.dbc) as codec:
        rec = read_recording(args.recording)
    print("\n".join([summarize(rec), *dbc_lines(codec)]))
    return 0
