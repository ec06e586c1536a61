"""CAN capture formats: detected by content, read into one :class:`~.fastdecode.FrameTable`.

================  ==========================================  ===========================================
format            recognised by                               read with
================  ==========================================  ===========================================
``candump``       ``(1700000000.123456) can0 18FEE000#..``    :func:`.fastdecode.scan_candump` (bulk)
``candump-screen``  ``(...)  can0  18FEE000   [8]  0F 00 ..``  :func:`scan_screen` (``-ta``, ``-tz``,
                  (candump without ``-L``)                    ``-td``, ``-tA``, ``-x``)
``asc``           ``date ...`` / ``base hex`` / ``Begin        python-can ``ASCReader``
                  Triggerblock`` header lines
``blf``           magic ``LOGG``                              python-can ``BLFReader``
``trc``           ``;$FILEVERSION`` or ``;   Start time``     python-can ``TRCReader``
``csv``           header ``timestamp,arbitration_id,...``     python-can ``CSVReader``
``sqlite``        magic ``SQLite format 3``                   python-can ``SqliteReader``
``mf4``           magic ``MDF`` or ``UnFinMF`` (unfinalised)    asammdf (the ``mf4`` extra), imported only here
``polycan``       header ``,time,pgn,priority,source,``         :func:`_polycan_messages` (rows as
                  ``destination,data,...`` (PolyCAN CSV)       :mod:`.polycan` reads them; a bad row is
                                                              counted, not fatal)
================  ==========================================  ===========================================

The file name is never consulted.  Anything else raises
:class:`~tractionecu.errors.RecordingError` naming what the first bytes look
like and how to convert it.

Every reader counts frames and rejects in the same
:class:`~tractionecu.bus.candump.ReadStats` with the candump reasons
(``error_frame``, ``rtr``, ``canfd``, ``dlc_gt_8``, ``time_backwards``, ...);
for the binary and python-can formats the "line" of a reject is the frame's
position in the file (1-based).

Clocks
------
:data:`TRUSTED_CLOCK` says which formats carry the logger's absolute epoch time
as it was.  The others are relative (``-tz``, ``-td``: the first frame at 0),
local time of an unknown zone (``-tA``), or relative times beside a start
written to the second (can-utils' ``log2asc``) or, by python-can, to a
millisecond field it misprints (ASC): their time axis is placed against the
GNSS epochs by :mod:`.clock`.
"""

from __future__ import annotations

import binascii
import contextlib
import gc
import io
import logging
import math
import re
import sys
from calendar import timegm
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np

from ..bus.candump import ReadStats, time_order
from ..errors import RecordingError
from .fastdecode import FrameTable

FORMATS = ("candump", "candump-screen", "asc", "blf", "trc", "csv", "sqlite", "mf4", "polycan")
"""Formats :func:`read_frames` reads."""

MF4_LOCAL = "mf4 (local time)"
"""The format name of an MF4 whose start time is the logger's local time without a zone (its header's
local-time flag): its times are read as UTC.  Its clock is trusted as a UTC one is: a zone's whole hours
leave the CAN frames and the GNSS epochs apart, and the reader then places them by the GNSS speed."""

TRUSTED_CLOCK = frozenset({"candump", "blf", "trc", "csv", "sqlite", "mf4", MF4_LOCAL, "candump-screen -ta"})
"""Formats (and candump screen time modes) whose times are the logger's absolute epoch time."""

CONVERT_HINT = (
    "record with `candump -L`, or convert with python-can "
    "(`python -m can.logconvert IN OUT.log`) or can-utils (`log2asc`/`asc2log`); "
    "formats read: candump -L and screen output, Vector ASC/BLF, PEAK TRC, python-can CSV and SQLite, MF4, "
    "PolyCAN CSV")

_SCREEN = re.compile(
    r"^\s*(?:\((?P<ts>[^)]*)\)\s+)?(?P<iface>\S+)\s+(?:(?P<dir>TX|RX)\s+\S\s+\S\s+)?"
    r"(?P<id>[0-9A-Fa-f]{3}|[0-9A-Fa-f]{8})\s+\[(?P<dlc>\d{1,2})\]\s*(?P<rest>.*)$")
_BYTES = re.compile(r"^((?:[0-9A-Fa-f]{2}(?:\s+|$))*)(.*)$")
_DATETIME = re.compile(r"^(\d{4})-(\d{2})-(\d{2}) (\d{2}):(\d{2}):(\d{2})(?:\.(\d{1,9}))?$")


# --------------------------------------------------------------------------- detection
_COMPRESSED = ((b"\x1f\x8b", "gzip", "gunzip"), (b"\xfd7zXZ\x00", "xz", "unxz"), (b"BZh", "bzip2", "bunzip2"),
               (b"\x28\xb5\x2f\xfd", "zstd", "unzstd"), (b"\x04\x22\x4d\x18", "lz4", "unlz4"))
"""Magic numbers of compressed files a logger's capture is kept in (each file format's own specification)."""


def detect(path: str | Path) -> str:
    """The capture format of ``path`` (one of :data:`FORMATS`), judged by content.

    Raises :class:`RecordingError` for an empty file or an unknown format, naming what was seen.
    """
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            head = fh.read(4096)
    except OSError as e:
        raise RecordingError(f"{p}: cannot read: {e.strerror or e}") from e
    if not head.strip():
        return "candump"                        # blank: the candump reader names it an empty file
    if head.startswith(b"LOGG"):
        return "blf"
    if head.startswith((b"MDF ", b"UnFinMF ")):      # an MDF file, finalised or not (CANedge)
        return "mf4"
    if head.startswith(b"SQLite format 3\x00"):
        return "sqlite"
    for magic, kind, tool in _COMPRESSED:
        if head.startswith(magic):
            raise RecordingError(f"{p}: a file compressed with {kind}; decompress it first ({tool}), then read it")
    if _binary(head):
        raise RecordingError(f"{p}: binary data starting {head[:8]!r}, not a CAN capture format read here; "
                             + CONVERT_HINT)
    text = head.decode("utf-8", errors="replace")
    lines = [ln for ln in text.splitlines()[:40] if ln.strip()]
    if len(head) == 4096 and len(lines) > 1:
        lines = lines[:-1]                      # the last line may be cut
    first = lines[0].strip()
    low = first.lower()
    if low.startswith(("date ", "base hex", "base dec")) or any(
            ln.lower().startswith(("begin triggerblock", "base hex", "base dec")) for ln in lines[:6]):
        return "asc"
    if first.startswith(";$FILEVERSION") or low.startswith(";   start time") or low.startswith(";##########"):
        return "trc"
    if low.replace(" ", "").startswith("timestamp,arbitration_id,"):
        return "csv"
    if _POLYCAN_COLUMNS <= {c.strip() for c in low.split(",")}:
        return "polycan"
    frames = [ln for ln in lines if not ln.lstrip().startswith(("#", ";"))]
    if frames and all(_is_candump_l(ln) for ln in frames[:5]):
        return "candump"
    if frames and sum(bool(_SCREEN.match(ln)) for ln in frames[:10]) >= max(1, min(len(frames), 10) // 2):
        return "candump-screen"
    if any(ln.lstrip().startswith("(") for ln in frames[:10]):
        return "candump"                        # candump -L with bad lines: its reader counts them
    raise RecordingError(f"{p}: unknown CAN capture format; the first line reads {first[:80]!r}; " + CONVERT_HINT)


def _binary(head: bytes) -> bool:
    sample = head[:1024]
    return b"\x00" in sample or sum(b < 9 or 13 < b < 32 for b in sample) > len(sample) // 20


def _is_candump_l(line: str) -> bool:
    s = line.strip()
    if not s.startswith("(") or ")" not in s:
        return False
    rest = s[s.index(")") + 1:].split()
    return len(rest) >= 2 and "#" in rest[1]


# --------------------------------------------------------------------------- reading
def read_frames(path: str | Path, rs: ReadStats, fmt: str | None = None) -> tuple[FrameTable, str]:
    """All accepted frames of the capture ``path`` and its format (with the screen time mode:
    ``candump-screen -ta``, ``-tz``, ``-td``, ``-tA``).  Lines/frames and rejects are counted in ``rs``.

    Raises :class:`RecordingError` for an unknown format, an unreadable file, a screen capture without
    time stamps, or an MF4 without asammdf installed.
    """
    p = Path(path)
    fmt = fmt or detect(p)
    try:
        if fmt == "candump":
            from .fastdecode import scan_candump
            return scan_candump(p, rs), fmt
        if fmt == "candump-screen":
            return scan_screen(p, rs)
        if fmt == "mf4":
            rows, local, cut = _mf4_messages(p)
            if cut:
                rs.reject("truncated", 0, f"{cut} frame(s) at the end without their data bytes (the file ends "
                                          "inside them: a logger that lost power while writing?)")
            return _table(rows, rs), (MF4_LOCAL if local else fmt)
        if fmt == "polycan":
            return _table(_polycan_messages(p, rs), rs), fmt
        return _table(_python_can_messages(p, fmt, rs), rs), fmt
    except RecordingError:
        raise
    except OSError as e:
        raise RecordingError(f"{p}: cannot read: {e.strerror or e}") from e
    except Exception as e:  # a third-party reader failing on a damaged file
        raise RecordingError(f"{p}: cannot read as {fmt}: {type(e).__name__}: {e}") from e


class _Lines:
    """The lines of a text capture for a python-can reader, counted, with lines put back in front: a reader
    that stops at a line it cannot parse is made again on the rest (:func:`_python_can_messages`)."""

    def __init__(self, fh: Any) -> None:
        self.fh = fh
        self.n = 0                                   # lines of the file taken so far
        self.last = ""                               # the last of them
        self.front: list[str] = []

    def __iter__(self) -> "_Lines":
        return self

    def __next__(self) -> str:
        if self.front:
            return self.front.pop()
        line = next(self.fh)
        self.n += 1
        self.last = line
        return line

    def close(self) -> None:
        self.fh.close()


_RESUMED_ASC_STATE = ("base", "_converted_base", "relative_timestamp", "date", "start_time", "timestamps_format",
                      "internal_events_logged")
"""What an ASC reader learnt from the file's header, handed to the reader made again after a bad line."""


def _python_can_messages(p: Path, fmt: str, rs: ReadStats) -> Iterator[tuple]:
    """Messages of a capture python-can reads.  Text captures (ASC, python-can CSV) are read line-tolerant:
    python-can's readers end at the first line they cannot parse, so a bad line is counted (``bad_line``, with
    its line number) and the reading goes on after it, as the candump reader does; a last line without its
    line break (cut while written) that gives no message is counted ``truncated``.  TRC lines python-can
    skips itself are counted from its log; a BLF shorter than its header says is counted ``truncated``."""
    import can

    if fmt in ("asc", "csv"):
        yield from _text_messages(p, fmt, rs)
        return
    if fmt == "blf":
        reader = can.BLFReader(str(p))
        declared = int(getattr(reader, "file_size", 0) or 0)
        if 0 < (size := p.stat().st_size) < declared:
            rs.reject("truncated", 0, f"{size} of the {declared} bytes its header declares")
    elif fmt == "trc":
        reader = can.TRCReader(str(p))
    elif fmt == "sqlite":
        reader = can.SqliteReader(str(p))
    else:  # pragma: no cover - FORMATS and detect() agree
        raise RecordingError(f"{p}: no reader for format {fmt!r}")
    counted = _CountFailures(rs) if fmt == "trc" else None
    trc_log = logging.getLogger("can.io.trc")
    if counted is not None:
        trc_log.addHandler(counted)
        keep, trc_log.propagate = trc_log.propagate, False    # counted and reported, not also logged
    try:
        for m in reader:
            yield (m.timestamp, m.arbitration_id, m.is_extended_id, bytes(m.data), m.dlc,
                   m.is_error_frame, m.is_remote_frame, m.is_fd)
    finally:
        if counted is not None:
            trc_log.removeHandler(counted)
            trc_log.propagate = keep
        stop = getattr(reader, "stop", None)
        if stop is not None:
            stop()


class _CountFailures(logging.Handler):
    """Counts the lines python-can's TRC reader logs as not parsed (it skips them itself)."""

    def __init__(self, rs: ReadStats) -> None:
        super().__init__(logging.WARNING)
        self.rs = rs

    def emit(self, record: logging.LogRecord) -> None:
        self.rs.reject("bad_line", 0, record.getMessage())


def _text_messages(p: Path, fmt: str, rs: ReadStats) -> Iterator[tuple]:
    import can

    with open(p, "r", encoding="utf-8-sig", errors="replace", newline=None) as fh:
        lines = _Lines(fh)
        state: dict[str, Any] = {}
        header = None
        last_bad = -1
        read = -1                                     # the line of the last message read
        while True:
            if fmt == "asc":
                reader = can.ASCReader(lines, relative_timestamp=False)
                if state:
                    lines.front.append("\n")          # ends the new reader's header search at once
                    for k, v in state.items():
                        setattr(reader, k, v)
            else:
                reader = can.CSVReader(lines)
                if header is not None:
                    lines.front.append(header)          # the new reader skips one header line
            it = iter(reader)
            try:
                for m in it:
                    if fmt == "asc" and not state:
                        state = {k: getattr(reader, k) for k in _RESUMED_ASC_STATE if hasattr(reader, k)}
                    read = lines.n
                    yield (m.timestamp, m.arbitration_id, m.is_extended_id, bytes(m.data), m.dlc,
                           m.is_error_frame, m.is_remote_frame, m.is_fd, lines.n)
                tail = lines.last.strip()
                if (tail and not lines.last.endswith("\n") and read != lines.n and last_bad != lines.n
                        and tail.lower() != "end triggerblock"):
                    rs.reject("truncated", lines.n, lines.last)   # cut while written, and skipped by the reader
                return
            except (ValueError, TypeError, IndexError, KeyError, binascii.Error) as e:
                if lines.n == last_bad:             # no line taken since the last one: give up, as before
                    raise
                last_bad = lines.n
                rs.reject("bad_line", lines.n, f"{type(e).__name__}: {e}")
                if fmt == "asc" and not state:
                    state = {k: getattr(reader, k) for k in _RESUMED_ASC_STATE if hasattr(reader, k)}
                header = header or "timestamp,arbitration_id,extended,remote,error,dlc,data\n"


_POLYCAN_COLUMNS = frozenset({"time", "pgn", "priority", "source", "destination", "data"})


def _polycan_messages(p: Path, rs: ReadStats) -> Iterator[tuple]:
    """Frames of a PolyCAN CSV export (:mod:`.polycan`: ``time`` in ms from the capture's start, the
    29-bit identifier rebuilt from priority, PGN, source and destination).  The times are relative (the
    export has no absolute clock: not in :data:`TRUSTED_CLOCK`, placed against the GNSS epochs by
    :mod:`.clock` when there are any).  A row that cannot be read is counted in ``rs`` (``garbage``,
    ``bad_timestamp``, ``dlc_gt_8``) with its line and skipped."""
    import csv

    from ..bus import j1939

    with open(p, "r", newline="", encoding="utf-8", errors="replace") as fh:
        reader = csv.DictReader(fh)
        fields = {str(f).strip() for f in (reader.fieldnames or [])}
        if not _POLYCAN_COLUMNS <= fields:
            raise RecordingError(f"{p}: line 1: not a PolyCAN export (columns {sorted(_POLYCAN_COLUMNS)})")
        lineno = 1
        while True:
            try:
                row = next(reader, None)
            except csv.Error as e:                     # e.g. a field beyond csv.field_size_limit()
                rs.lines += 1
                rs.reject("garbage", reader.line_num, str(e))
                lineno = reader.line_num
                continue
            if row is None:
                return
            lineno = reader.line_num
            text = ",".join("" if v is None else str(v) for v in row.values() if not isinstance(v, list))
            try:
                ms = float(row["time"])
                pgn, prio = int(row["pgn"]), int(row["priority"])
                sa, da = int(row["source"]), int(row["destination"])
                data = bytes.fromhex(row["data"].strip())
                cid = j1939.make_id(prio, pgn, sa, da if j1939.is_pdu1(pgn) else None)
            except (TypeError, ValueError, AttributeError):
                rs.lines += 1
                rs.reject("garbage", lineno, text)
                continue
            t = ms / 1000.0
            yield (t, cid, True, data, len(data), False, False, False, lineno)


def _mf4_messages(p: Path) -> tuple[Iterator[tuple], bool, int]:
    """Frames of the bus-logging channel groups (``CAN_DataFrame``) of an ASAM MDF 4 file, whether its
    start time is a local time without a zone, and how many frames at the end of a group were cut off
    (a channel, e.g. the data bytes, holding fewer samples than the group's time stamps: the file ends
    inside its last records, as a logger's unfinalised file does when power is lost).  Such a start time is
    read as UTC: taken in the zone of the computer reading it, the same file started at 19:01Z, 17:01Z or
    00:01Z by that computer's setting."""
    try:
        from asammdf import MDF
    except ImportError:
        raise RecordingError(f"{p}: an MF4 (ASAM MDF 4) file; reading it needs asammdf: "
                             "pip install 'tractionecu[mf4]'") from None
    mdf = _open_mdf(MDF, p)
    cut = 0
    groups = 0
    try:
        st = mdf.header.start_time
        local = st.tzinfo is None
        start = (st.replace(tzinfo=timezone.utc) if local else st).timestamp()
        rows = []
        for gi, group in enumerate(mdf.groups):
            names = {ch.name for ch in group.channels}
            if "CAN_DataFrame.ID" not in names or "CAN_DataFrame.DataBytes" not in names:
                continue
            groups += 1

            def get(name: str, gi: int = gi):
                return mdf.get(name, group=gi, raw=True, samples_only=True)[0]

            stamps = np.asarray(mdf.get_master(gi), dtype=np.float64)
            ids = get("CAN_DataFrame.ID")
            data = get("CAN_DataFrame.DataBytes")
            ide = get("CAN_DataFrame.IDE") if "CAN_DataFrame.IDE" in names else None
            dlc = get("CAN_DataFrame.DataLength") if "CAN_DataFrame.DataLength" in names else None
            if dlc is None and "CAN_DataFrame.DLC" in names:
                dlc = get("CAN_DataFrame.DLC")
            cols = [stamps, ids, data] + [c for c in (ide, dlc) if c is not None]
            n = min(len(c) for c in cols)
            cut += max(len(c) for c in cols) - n
            t = start + stamps
            for k in range(n):
                cid = int(ids[k])
                ext = bool(ide[k]) if ide is not None else cid > 0x7FF
                row = bytes(np.asarray(data[k], dtype=np.uint8).tobytes())
                m = int(dlc[k]) if dlc is not None else len(row)
                rows.append((float(t[k]), cid & 0x1FFFFFFF, ext, row[:m], m, False, False, m > 8))
        rows.sort(key=lambda r: r[0])
    finally:
        mdf.close()
    if not groups:
        raise RecordingError(f"{p}: an MF4 file without a CAN bus-logging channel group (CAN_DataFrame)")
    if not rows:
        raise RecordingError(f"{p}: an MF4 file whose CAN bus-logging channel group holds no whole frame"
                             + (f" ({cut} cut off at the file's end)" if cut else ""))
    return iter(rows), local, cut


def _open_mdf(MDF: Any, p: Path) -> Any:
    """``MDF(p)``; a file asammdf cannot open raises :class:`RecordingError` saying why, and a file cut before
    the blocks its header points to is named as cut.  (What asammdf prints on a damaged file, to standard
    output, and the half-built reader's failing ``__del__`` are kept out of the command's output.)"""
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            return MDF(str(p))
    except Exception as e:  # asammdf on a damaged file
        why = f"{type(e).__name__}: {e}"
        past_end = isinstance(e, ValueError) and "out of range" in str(e)
        hook, sys.unraisablehook = sys.unraisablehook, (lambda _u: None)
        try:
            e.__traceback__ = None
            del e
            gc.collect()
        finally:
            sys.unraisablehook = hook
    size = p.stat().st_size
    if past_end:
        raise RecordingError(f"{p}: an MF4 file cut short: it ends at {size} bytes, before blocks its header "
                             "points to (a logger that lost power, a copy that stopped), and cannot be read "
                             f"without them ({why})")
    raise RecordingError(f"{p}: cannot read as mf4 ({size} bytes; cut short or damaged?): {why}")


def _table(messages: Iterable[tuple], rs: ReadStats) -> FrameTable:
    """A :class:`FrameTable` of decoded messages ``(t, id, ext, data, dlc, error, remote, fd[, line])``;
    rejects counted like the candump reader's (a frame with fewer data bytes than its DLC is ``truncated``),
    the frame's position standing for its line unless the message carries its line number."""
    cols: tuple[list, ...] = ([], [], [], [], [], [])
    for k, (t, cid, ext, data, dlc, err, rtr, fd, *line) in enumerate(messages, start=1):
        rs.lines += 1
        k = line[0] if line else k                     # a text format's own line number
        t = float(t)
        reason = None
        if err:
            reason = "error_frame"
        elif fd:
            reason = "canfd"
        elif rtr:
            reason = "rtr"
        elif len(data) > 8:
            reason = "dlc_gt_8"
        elif dlc is not None and len(data) < min(int(dlc), 8):
            reason = "truncated"                       # fewer data bytes than its DLC: a line cut short
        elif not math.isfinite(t) or t < 0:
            reason = "bad_timestamp"
        elif cid > (0x1FFFFFFF if ext else 0x7FF):
            reason = "bad_hex"
        if reason is not None:
            rs.reject(reason, k, f"t={t} id={cid:X} data={bytes(data).hex().upper()}")
            continue
        for col, v in zip(cols, (k, t, cid, ext, len(data), int.from_bytes(bytes(data), "little"))):
            col.append(v)
    order = time_order(cols[1])                        # time going back, a lone time stamp ahead
    if any(order):
        # (the text of a rejected frame made from its columns: one string per frame cost the memory of a
        # whole capture's text beside its table)
        for k, t, cid, n, pl, why in zip(cols[0], cols[1], cols[2], cols[4], cols[5], order):
            if why is not None:
                rs.reject(why, k, f"t={t} id={cid:X} data={int(pl).to_bytes(n, 'little').hex().upper()}")
        cols = tuple([v for v, why in zip(c, order) if why is None] for c in cols)
    rs.frames += len(cols[0])
    return FrameTable(np.asarray(cols[0], dtype=np.int64), np.asarray(cols[1], dtype=np.float64),
                      np.asarray(cols[2], dtype=np.int64), np.asarray(cols[3], dtype=bool),
                      np.asarray(cols[4], dtype=np.int64), np.asarray(cols[5], dtype=np.uint64))


# --------------------------------------------------------------------------- candump screen output
def _screen_time(ts: str) -> tuple[str, float] | None:
    """(mode, seconds) of a screen time stamp: ``-tA`` date-time (read as UTC) or a number."""
    m = _DATETIME.match(ts.strip())
    if m:
        y, mo, d, hh, mi, ss, frac = m.groups()
        try:
            whole = timegm(datetime(int(y), int(mo), int(d), int(hh), int(mi), int(ss)).timetuple())
        except ValueError:
            return None
        return "-tA", whole + (int(frac) / 10 ** len(frac) if frac else 0.0)
    try:
        v = float(ts)
    except ValueError:
        return None
    return ("num", v) if math.isfinite(v) and v >= 0 else None


def scan_screen(path: str | Path, rs: ReadStats) -> tuple[FrameTable, str]:
    """Frames of candump's screen output (no ``-L``): ``(time)  iface  ID   [n]  bytes``.

    The time mode is judged over the file: a date-time is ``-tA`` (local time of the logging host, read
    as UTC); numbers that never decrease are absolute (``-ta``) when the first is a plausible epoch
    time, else relative to the start (``-tz``); numbers that go up and down are deltas (``-td``) and
    are summed.  ``-x`` direction fields and ``-a`` ASCII columns are ignored.  A capture without
    time stamps raises :class:`RecordingError` (nothing to align it with).
    """
    p = Path(path)
    rows: list[tuple] = []
    times: list[float] = []
    modes: set[str] = set()
    with open(p, "r", encoding="utf-8-sig", errors="replace", newline=None) as fh:
        for lineno, line in enumerate(fh, start=1):
            rs.lines += 1
            if not line.strip():
                continue
            m = _SCREEN.match(line.rstrip("\n"))
            if m is None:
                rs.reject("garbage", lineno, line)
                continue
            ts = m.group("ts")
            if ts is None:
                raise RecordingError(
                    f"{p}: candump screen output without time stamps (line {lineno}: what `candump can0` "
                    "and `candump -x can0` print): the frames cannot be placed in time, nor aligned with "
                    "the GNSS log; record with `candump -L can0` (or at least `candump -ta can0`)")
            tm = _screen_time(ts)
            if tm is None:
                rs.reject("bad_timestamp", lineno, line)
                continue
            ident, rest = m.group("id"), m.group("rest")
            dlc = int(m.group("dlc"))
            if rest.lower().startswith("remote request"):
                rs.reject("rtr", lineno, line)
                continue
            hexpart = _BYTES.match(rest).group(1).split()  # type: ignore[union-attr]
            cid = int(ident, 16)
            ext = len(ident) == 8
            if ext and cid & 0x20000000:
                rs.reject("error_frame", lineno, line)
                continue
            if dlc > 8:
                rs.reject("canfd" if len(m.group("dlc")) == 2 else "dlc_gt_8", lineno, line)
                continue
            if len(hexpart) != dlc:
                rs.reject("truncated", lineno, line)
                continue
            if cid > (0x1FFFFFFF if ext else 0x7FF):
                rs.reject("bad_hex", lineno, line)
                continue
            modes.add(tm[0])
            times.append(tm[1])
            rows.append((lineno, cid, ext, dlc, int.from_bytes(bytes.fromhex("".join(hexpart)), "little"), line))
    t = np.asarray(times, dtype=np.float64)
    if "-tA" in modes:
        mode = "-tA"
    elif t.size >= 2 and np.any(np.diff(t) < 0) and t.max() < 1e6:
        mode, t = "-td", np.cumsum(t)
    elif t.size and t[0] >= 3.15e8:            # after 1980: an epoch time
        mode = "-ta"
    else:
        mode = "-tz"
    if len(modes) > 1:
        raise RecordingError(f"{p}: candump screen output mixes date-time and numeric time stamps")
    keep = np.ones(t.size, dtype=bool)
    for i, why in enumerate(time_order(t.tolist())):
        if why is not None:
            keep[i] = False
            rs.reject(why, rows[i][0], rows[i][5])
    rs.frames += int(keep.sum())
    sel = [r for r, k in zip(rows, keep) if k]
    table = FrameTable(np.asarray([r[0] for r in sel], dtype=np.int64), t[keep],
                       np.asarray([r[1] for r in sel], dtype=np.int64), np.asarray([r[2] for r in sel], dtype=bool),
                       np.asarray([r[3] for r in sel], dtype=np.int64),
                       np.asarray([r[4] for r in sel], dtype=np.uint64))
    return table, f"candump-screen {mode}"
