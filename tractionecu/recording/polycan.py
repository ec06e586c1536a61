"""Convert PolyCAN CSV exports to candump ``-L`` frames.

PolyCAN (the tool used for the TractorHacking J1939 captures) exports one
frame per row with the columns::

    ,time,pgn,priority,source,destination,data,description

- ``time``: milliseconds since the start of the capture;
- ``pgn``: the parameter group number, with the destination byte of PDU1
  PGNs already masked out (e.g. 61184 = 0xEF00 with ``destination`` 6);
- ``priority``, ``source``, ``destination``: decimal;
- ``data``: space-separated hex bytes (0..8 of them).

The 29-bit identifier is rebuilt as ``priority<<26 | PGN<<8 | SA`` with the
destination in the PS byte for PDU1 PGNs (see :func:`tractionecu.bus.j1939.make_id`).
The capture carries no absolute time, so an epoch offset ``epoch0`` [s] is
added to ``time / 1000``.

Command line (writes a candump file, e.g. the test excerpt)::

    python -m tractionecu.recording.polycan IN.csv OUT.log --rows 320 --epoch0 1538352000
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from pathlib import Path
from typing import Iterator

from ..bus import j1939
from ..bus.candump import Frame, write_candump
from ..errors import RecordingError

DEFAULT_EPOCH0 = 1538352000.0
"""2018-10-01T00:00:00Z: an arbitrary start inside the Sept 2018 – March 2019 capture period."""


def read_polycan(
    path: str | Path, epoch0: float = DEFAULT_EPOCH0, channel: str = "can0", max_rows: int | None = None
) -> Iterator[Frame]:
    """Yield :class:`~tractionecu.bus.candump.Frame` objects from a PolyCAN CSV.

    Times are ``epoch0 + time_ms / 1000`` [s].  A malformed row raises
    :class:`~tractionecu.errors.RecordingError` naming the file and line.
    """
    p = Path(path)
    try:
        fh = open(p, newline="", encoding="utf-8", errors="replace")
    except OSError as e:
        raise RecordingError(f"{p}: cannot read: {e.strerror or e}") from e
    with fh:
        reader = csv.DictReader(fh)
        need = {"time", "pgn", "priority", "source", "destination", "data"}
        try:
            fieldnames = reader.fieldnames
        except csv.Error as e:  # e.g. a field beyond csv.field_size_limit()
            raise RecordingError(f"{p}: line 1: {e}") from None
        if fieldnames is None or not need <= set(fieldnames):
            raise RecordingError(f"{p}: line 1: not a PolyCAN export (columns {sorted(need)})")
        n = 0
        while max_rows is None or n < max_rows:
            lineno = n + 2
            try:
                row = next(reader, None)
            except csv.Error as e:
                raise RecordingError(f"{p}: line {lineno}: {e}") from None
            if row is None:
                break
            n += 1
            missing = sorted(k for k in need if row.get(k) is None)
            if missing:
                raise RecordingError(f"{p}: line {lineno}: short row, no {', '.join(missing)}")
            try:
                t = epoch0 + float(row["time"]) / 1000.0
                pgn = int(row["pgn"])
                prio = int(row["priority"])
                sa = int(row["source"])
                da = int(row["destination"])
                data = bytes.fromhex(row["data"].strip())
                can_id = j1939.make_id(prio, pgn, sa, da if j1939.is_pdu1(pgn) else None)
            except (TypeError, ValueError) as e:
                raise RecordingError(f"{p}: line {lineno}: {e}") from None
            if not (math.isfinite(t) and t >= 0.0):
                raise RecordingError(f"{p}: line {lineno}: time {row['time']!r} ms gives {t!r} s, not an epoch time")
            if len(data) > 8:
                raise RecordingError(f"{p}: line {lineno}: {len(data)} data bytes")
            yield Frame(t, channel, can_id, True, data)


def polycan_to_candump(
    src: str | Path,
    dst: str | Path,
    epoch0: float = DEFAULT_EPOCH0,
    channel: str = "can0",
    max_rows: int | None = None,
) -> int:
    """Convert a PolyCAN CSV to a candump ``-L`` file; returns the number of frames."""
    return write_candump(dst, read_polycan(src, epoch0, channel, max_rows))


def main(argv: list[str] | None = None) -> int:
    """Command-line entry: ``python -m tractionecu.recording.polycan IN OUT [--rows N] [--epoch0 S]``."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("src", type=Path, help="PolyCAN CSV export")
    ap.add_argument("dst", type=Path, help="candump -L output file")
    ap.add_argument("--rows", type=int, default=None, help="convert only the first N data rows")
    ap.add_argument("--epoch0", type=float, default=DEFAULT_EPOCH0, help="epoch time [s] of time = 0")
    ap.add_argument("--channel", default="can0", help="interface name written to each line")
    a = ap.parse_args(argv)
    try:
        n = polycan_to_candump(a.src, a.dst, a.epoch0, a.channel, a.rows)
    except RecordingError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(f"{n} frames written to {a.dst}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
