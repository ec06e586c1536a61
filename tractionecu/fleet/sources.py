"""Which recordings a fleet SOURCE holds, and each one's machine, date and field.

A SOURCE is one of

* a **directory tree**: every directory holding ``can.log`` is a recording (the layout of
  ``tractionecu simulate``), and so is every capture file with a suffix of :data:`CAPTURE_SUFFIXES`
  outside such a directory (its GNSS log beside it, as ``tractionecu replay`` reads it);
* a **manifest**: a CSV file with a ``path`` column (relative to the manifest's directory, or
  absolute) and optional ``machine``, ``date`` (ISO ``YYYY-MM-DD``) and ``field`` columns;
* a **glob** (``*``, ``?`` or ``[`` in SOURCE, ``**`` for any depth) matching recording directories or
  capture files.

Machine, date and field from the path (relative to the tree's root, or to the glob's fixed prefix):

1. Hive-style segments ``machine=M``, ``date=YYYY-MM-DD``, ``field=F`` anywhere in the path win;
2. otherwise the date is the last segment holding ``YYYY-MM-DD`` or ``YYYYMMDD``, and the machine the
   first segment of the relative path when it is not the date and not the recording itself
   (``<machine>/<date>/<recording>``, the usual logger export layout); when SOURCE lies inside such a
   tree (a machine's folder, a date's folder, one recording), SOURCE's own last two segments are read too:
   a date folder there dates the recording and the folder above it is the machine, so a recording keeps
   the machine and date (and the task key) a run over the whole tree gives it;
3. a date still unknown is the first RMC date of the recording's GNSS log; else ``unknown``.

A manifest's columns win over the path.  The field stays empty when neither names it; the tasks then
name it by the recording's first fix (:func:`field_of_fix`).
"""

from __future__ import annotations

import csv
import datetime as _dt
import glob as _glob
import logging
import re
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from ..gnss.fix import fix_rank
from ..mapping.from_replay import ORIGIN_FIXES

log = logging.getLogger(__name__)

CAPTURE_SUFFIXES = (".blf", ".asc", ".trc", ".mf4", ".mdf", ".log")
"""Capture files taken as recordings outside a recording directory (the reader knows the format by
content; the suffix only says which files to offer it)."""

UNKNOWN = "unknown"

_DATE = re.compile(r"(?<!\d)(\d{4})-?(\d{2})-?(\d{2})(?!\d)")


@dataclass(frozen=True)
class RecordingRef:
    """One recording of a fleet source: ``path`` (directory or capture file), ``machine``, ``date``
    (``YYYY-MM-DD`` or ``unknown``) and ``field`` (empty: named later from the first fix)."""

    path: str
    machine: str
    date: str
    field: str = ""

    def as_dict(self) -> dict[str, str]:
        return asdict(self)


def _parse_date(text: str) -> str | None:
    for m in reversed(list(_DATE.finditer(text))):
        try:
            return _dt.date(int(m.group(1)), int(m.group(2)), int(m.group(3))).isoformat()
        except ValueError:
            continue
    return None


def _nmea_fields(path: Path, max_lines: int) -> Iterator[list[str]]:
    """Comma-split fields of the first ``max_lines`` lines of the recording's GNSS log: ``gps.nmea`` in a
    recording directory, ``<name>.nmea`` or else ``gps.nmea`` beside a capture file (the first found)."""
    cands = [path / "gps.nmea"] if path.is_dir() else [path.with_suffix(".nmea"), path.parent / "gps.nmea"]
    for nmea in cands:
        if nmea.is_file():
            with open(nmea, encoding="utf-8-sig", errors="replace") as fh:
                for _, line in zip(range(max_lines), fh):
                    yield line.strip().split(",")
            return


def _rmc_date(path: Path, max_lines: int = 400) -> str | None:
    """Date of the first valid RMC sentence of the recording's GNSS log (ddmmyy, field 9)."""
    for f in _nmea_fields(path, max_lines):
        if len(f) > 9 and f[0].endswith("RMC") and len(f[9]) == 6 and f[9].isdigit():
            d, mo, y = int(f[9][:2]), int(f[9][2:4]), 2000 + int(f[9][4:6])
            try:
                return _dt.date(y, mo, d).isoformat()
            except ValueError:
                continue
    return None


def _last_date(segments: list[str]) -> tuple[str | None, int | None]:
    """The date of the last segment holding one, and that segment's index; (None, None) without."""
    for i in range(len(segments) - 1, -1, -1):
        d = _parse_date(segments[i])
        if d is not None:
            return d, i
    return None, None


def from_path(path: Path, root: Path | None) -> RecordingRef:
    """Machine, date and field of the recording ``path`` by the rules of the module doc."""
    try:
        rel = path.resolve().relative_to(root.resolve()) if root is not None else Path(path.name)
    except ValueError:
        rel = Path(path.name)
    parts = list(rel.parts)
    hive = {}
    for seg in parts:
        if "=" in seg:
            k, _, v = seg.partition("=")
            if k in ("machine", "date", "field") and v:
                hive[k] = v
    date = hive.get("date")
    date = _parse_date(date) if date else None
    date_seg = None
    if date is None:
        date, date_seg = _last_date(parts)
    machine = hive.get("machine")
    if machine is None:
        machine = parts[0] if len(parts) >= 2 and date_seg != 0 and "=" not in parts[0] else UNKNOWN
    if machine == UNKNOWN and root is not None and "machine" not in hive:
        # SOURCE inside the tree (a machine's folder, a date's, one recording): its own last segments are
        # the <machine>/<date> the relative path lacks, so the recording keeps the identity (partitions,
        # task key) a run over the whole tree gives it
        ctx = [s for s in root.resolve().parts[-2:] if s != root.resolve().anchor]
        full = ctx + parts
        di = len(ctx) + date_seg if date_seg is not None else None
        if date is None:
            date, di = _last_date(ctx)
        if di is not None and 1 <= di < len(full) - 1:     # the date a folder, not the recording's own name
            m = full[di - 1]
            if "=" not in m and _parse_date(m) is None:
                machine = m
    if date is None:
        date = _rmc_date(path) or UNKNOWN
    return RecordingRef(str(path), machine, date, hive.get("field", ""))


def _is_recording_dir(p: Path) -> bool:
    return p.is_dir() and (p / "can.log").is_file()


def _walk(root: Path, exclude: Path | None) -> list[Path]:
    found: list[Path] = []
    ex = exclude.resolve() if exclude is not None else None
    stack = [root]
    while stack:
        d = stack.pop()
        if ex is not None and (d.resolve() == ex):
            continue
        if _is_recording_dir(d):
            found.append(d)
            continue
        try:
            entries = sorted(d.iterdir())
        except OSError as e:          # left out without a word before
            log.warning("fleet: %s cannot be listed (%s): its recordings are left out", d, e.strerror or e)
            continue
        captures = 0
        for e in entries:
            if e.is_dir():
                stack.append(e)
            elif e.suffix.lower() in CAPTURE_SUFFIXES and e.is_file():
                found.append(e)
                captures += 1
        if not captures and (d / "gps.nmea").is_file():
            # a logger that lost its CAN side: the folder was no recording, without a word
            log.warning("fleet: %s holds a GNSS log but no CAN capture (can.log): not a recording, left out", d)
    return sorted(found)


def _glob_root(pattern: str) -> Path:
    fixed = []
    for seg in Path(pattern).parts:
        if any(c in seg for c in "*?["):
            break
        fixed.append(seg)
    return Path(*fixed) if fixed else Path(".")


def read_manifest(path: Path) -> list[RecordingRef]:
    """The recordings of a manifest CSV (module doc); a row without a path is refused with its line."""
    out = []
    with open(path, newline="", encoding="utf-8") as fh:
        rows = csv.DictReader(fh)
        if rows.fieldnames is None or "path" not in [c.strip() for c in rows.fieldnames]:
            raise ConfigError(f"{path}: a fleet manifest needs a 'path' column, found {rows.fieldnames}")
        for i, row in enumerate(rows, start=2):
            row = {(k or "").strip(): (v or "").strip() for k, v in row.items()}
            if not row.get("path"):
                raise ConfigError(f"{path}:{i}: empty path")
            p = Path(row["path"])
            if not p.is_absolute():
                p = path.parent / p
            guess = from_path(p, path.parent)
            date = _parse_date(row["date"]) if row.get("date") else guess.date
            if row.get("date") and date is None:
                raise ConfigError(f"{path}:{i}: date {row['date']!r} is not YYYY-MM-DD")
            out.append(RecordingRef(str(p), row.get("machine") or guess.machine, date or UNKNOWN,
                                    row.get("field") or guess.field))
    return out


def discover(source: str | Path, *, exclude: str | Path | None = None) -> list[RecordingRef]:
    """The recordings of ``source`` (module doc), sorted by machine, date and path.

    ``exclude`` (the output directory, when it lies inside the tree) is not searched; a recording listed
    twice (a manifest, overlapping globs) is kept once, with its first row.
    """
    s = str(source)
    ex = Path(exclude) if exclude is not None else None
    if any(c in s for c in "*?["):
        root = _glob_root(s)
        paths = sorted(Path(p) for p in _glob.glob(s, recursive=True))
        refs = [from_path(p, root) for p in paths if _is_recording_dir(p) or p.is_file()]
    else:
        p = Path(s)
        if not p.exists():
            raise ConfigError(f"{p}: no such directory, manifest or capture file")
        if p.is_file() and p.suffix.lower() == ".csv":
            refs = read_manifest(p)
        elif _is_recording_dir(p) or p.is_file():
            refs = [from_path(p, p.parent)]
        else:
            refs = [from_path(r, p) for r in _walk(p, ex)]
    seen: set[str] = set()
    unique = []
    for r in refs:                       # a recording listed twice is one task (its outputs share a key)
        k = str(Path(r.path).resolve())
        if k not in seen:
            seen.add(k)
            unique.append(r)
    return sorted(unique, key=lambda r: (r.machine, r.date, r.path))


def first_fix(path: str | Path, max_lines: int = 2000) -> tuple[float, float] | None:
    """(lat, lon) [deg] where the recording starts: the median of the first :data:`~tractionecu.mapping.from_replay.ORIGIN_FIXES` GGA
    positions of a measured fix (:data:`~tractionecu.gnss.fix.FIX_RANK` > 0: not dead reckoning, manual
    or simulated) in the recording's GNSS log, so that one glitched first fix does not move a farm map's
    origin tens of kilometres away; None without such a fix."""
    lats: list[float] = []
    lons: list[float] = []
    for f in _nmea_fields(Path(path), max_lines):
        if len(f) > 6 and f[0].endswith("GGA") and f[2] and f[4]:
            try:
                if fix_rank(int(f[6])) <= 0:
                    continue
                lat = int(f[2][:2]) + float(f[2][2:]) / 60.0
                lon = int(f[4][:3]) + float(f[4][3:]) / 60.0
            except ValueError:
                continue
            lats.append(-lat if f[3] == "S" else lat)
            lons.append(-lon if f[5] == "W" else lon)
            if len(lats) == ORIGIN_FIXES:
                break
    if not lats:
        return None
    return (float(np.median(lats)), float(np.median(lons)))


def field_of_fix(lat_deg: float, lon_deg: float, cell_deg: float = 0.01) -> str:
    """A field name from a recording's first fix when none is given: the 0.01° cell (about 1.1 km
    north–south) the fix lies in, ``"lat47.88_lon-110.56"``."""
    import math

    la = math.floor(lat_deg / cell_deg) * cell_deg
    lo = math.floor(lon_deg / cell_deg) * cell_deg
    return f"lat{la:.2f}_lon{lo:.2f}"


__all__ = ["CAPTURE_SUFFIXES", "RecordingRef", "UNKNOWN", "discover", "field_of_fix", "first_fix", "from_path",
           "read_manifest"]
