"""Read and write the can-utils ``candump -L`` log format.

One frame per line::

    (1700000000.123456) can0 18FF1080#0102030405060708

- ``(seconds.microseconds)`` — epoch time [s], as ``candump -L`` prints it
  (``%010lu.%06lu``);
- interface name;
- identifier: 3 hex digits for an 11-bit frame, 8 hex digits for a 29-bit
  frame (can-utils' rule), ``#``, then 0..8 data bytes as hex pairs.

The reader streams frames and never raises on bad input: a line it cannot
use is skipped and counted in :class:`ReadStats` under one of these reasons

==================  =======================================================
``garbage``         not a candump line at all
``truncated``       starts like one but stops early (no interface, no
                    ``#``, odd number of data digits), or is the last line
                    of a file, without its line break, with fewer than 8
                    data bytes (a logger cut while writing it; candump
                    writes each line whole with its line break)
``bad_timestamp``   the ``(...)`` field is not a number
``bad_hex``         non-hex digits, or an identifier that is neither 3 nor 8
                    digits (or exceeds 29 bits)
``dlc_gt_8``        more than 8 data bytes on a classic CAN frame
``canfd``           CAN FD frame (``ID##F...``): not supported
``rtr``             remote frame (``ID#R``): carries no data
``error_frame``     identifier with the CAN error flag (0x20000000)
``time_backwards``  timestamp earlier than the previous accepted frame
``time_ahead``      timestamp more than :data:`TIME_SPIKE_S` ahead of the
                    previous accepted frame, and the next frame is again
                    more than that behind it: one time stamp out of line (a
                    corrupted digit), which would otherwise have rejected
                    every frame after it as ``time_backwards``
==================  =======================================================

The writer formats exactly like can-utils: ``%08X`` for 29-bit IDs,
``%03X`` for 11-bit IDs, upper-case data hex.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Iterable, Iterator, NamedTuple

from ..counting import MAX_EXAMPLES, RejectCounter

REJECT_REASONS = (
    "garbage",
    "truncated",
    "bad_timestamp",
    "bad_hex",
    "dlc_gt_8",
    "canfd",
    "rtr",
    "error_frame",
    "time_backwards",
    "time_ahead",
)

_HEX = frozenset("0123456789abcdefABCDEF")
_CAN_ERR_FLAG = 0x20000000

TIME_SPIKE_S = 1.0
"""A frame stamped more than this [s] after the previous accepted one is held until the next frame: when that
one is again more than this before it, the held frame is ``time_ahead`` (a lone time stamp out of line), else
it is accepted (the capture's time jumped)."""

REPEAT_WINDOW_S = 1e-3
"""A frame with the identifier, length and data of the one before it of its identifier and length, at most
this later [s], is a repeat (:attr:`ReadStats.repeated`): a bus sends a message's next frame a period later, a logger echoing its
frames or two loggers' captures merged write one frame twice."""

REPEAT_SHARE = 0.1
"""Share of the frames repeated above which the capture is said to hold its frames twice."""


class Frame(NamedTuple):
    """One CAN frame: time [s, epoch], interface, identifier, 29-bit?, data."""

    t: float
    channel: str
    can_id: int
    is_extended: bool
    data: bytes


@dataclass
class ReadStats(RejectCounter):
    """Counts of lines read, frames accepted and lines rejected by reason
    (see :class:`~tractionecu.counting.RejectCounter`); ``repeated``: the accepted frames that repeat the
    one before them of their identifier (:data:`REPEAT_WINDOW_S`), with the first line numbers in
    ``repeated_lines`` (counted by the recording reader, not by :func:`iter_candump`)."""

    frames: int = 0
    repeated: int = 0
    repeated_lines: list[int] = field(default_factory=list)

    def repeat(self, lineno: int) -> None:
        """Count one repeated frame."""
        self.repeated += 1
        if len(self.repeated_lines) < MAX_EXAMPLES:
            self.repeated_lines.append(lineno)

    def notes(self) -> list[str]:
        """The repeated frames, one line (they are read as they are, and every message rate counts them)."""
        if not self.repeated:
            return []
        src = f"{self.source} " if self.source else ""
        more = ", ..." if self.repeated > len(self.repeated_lines) else ""
        share = self.repeated / max(self.frames, 1)
        why = (": the capture holds its frames twice (a logger echoing its frames, or two loggers' captures "
               "merged), and the message rates count both" if share >= REPEAT_SHARE else "")
        return [f"frames repeating the one before them of their identifier (same data, within "
                f"{REPEAT_WINDOW_S * 1e3:g} ms): {self.repeated} of {self.frames} ({100.0 * share:.1f} %; "
                f"{src}line {', '.join(map(str, self.repeated_lines))}{more}){why}"]


def _classify(line: str) -> tuple[str | None, Frame | None]:
    """Parse one line; returns (reject reason, None) or (None, frame)."""
    s = line.strip()
    if not s.startswith("("):
        return "garbage", None
    close = s.find(")")
    if close < 0:
        return "truncated", None
    ts = s[1:close]
    rest = s[close + 1 :].split()
    try:
        t = float(ts)
    except ValueError:
        return "bad_timestamp", None
    if not math.isfinite(t) or t < 0 or "." not in ts:
        return "bad_timestamp", None
    if len(rest) < 2:
        return "truncated", None  # interface or frame missing
    if len(rest) > 3:
        return "garbage", None
    # candump -L may append " T" / " R" direction flags (-x); ignore them.
    if len(rest) == 3 and rest[2] not in ("T", "R"):
        return "garbage", None
    channel, frame = rest[0], rest[1]
    if "#" not in frame:
        return "truncated", None
    ident, _, payload = frame.partition("#")
    if payload.startswith("#"):
        return "canfd", None
    if not ident or any(c not in _HEX for c in ident):
        return "bad_hex", None
    if len(ident) == 3:
        is_ext = False
    elif len(ident) == 8:
        is_ext = True
    else:
        return "bad_hex", None
    can_id = int(ident, 16)
    if is_ext and can_id & _CAN_ERR_FLAG:
        return "error_frame", None
    if can_id > (0x1FFFFFFF if is_ext else 0x7FF):
        return "bad_hex", None
    if payload[:1] in ("R", "r"):
        return "rtr", None
    # can-utils accepts '.' separators between bytes in the data field
    payload = payload.replace(".", "")
    if any(c not in _HEX for c in payload):
        return "bad_hex", None
    if len(payload) % 2:
        return "truncated", None
    if len(payload) > 16:
        return "dlc_gt_8", None
    return None, Frame(t, channel, can_id, is_ext, bytes.fromhex(payload))


def classify_unterminated(line: str) -> tuple[str | None, Frame | None]:
    """:func:`_classify` for the last line of a file that has no line break after it: the logger stopped
    while writing it, so a frame of fewer than 8 data bytes may have lost the rest of its data
    (``truncated``); 8 bytes are all a classic frame has, and such a line is read."""
    reason, frame = _classify(line)
    if frame is not None and len(frame.data) < 8:
        return "truncated", None
    return reason, frame


class TimeRule:
    """The time rule of a capture's frames in file order (module doc: ``time_backwards``, ``time_ahead``), one
    for every reader: :meth:`push` a frame's key and time [s], get the decisions made now, in file order, as
    ``(key, reason)`` with reason None for an accepted frame.  A frame stamped more than :data:`TIME_SPIKE_S`
    after the last accepted one is held: its decision comes with the next frame's (``time_ahead`` when that
    one is again more than that before it), or with :meth:`end` (accepted).  ``t_max`` is the last accepted
    time, ``held`` the ``(key, time)`` held."""

    def __init__(self) -> None:
        self.t_max = -math.inf
        self.held: tuple[Any, float] | None = None

    def push(self, key: Any, t: float) -> list[tuple[Any, str | None]]:
        out: list[tuple[Any, str | None]] = []
        if self.held is not None:
            hk, ht = self.held
            self.held = None
            if ht - t > TIME_SPIKE_S:
                out.append((hk, "time_ahead"))
            else:
                self.t_max = ht
                out.append((hk, None))
        if t < self.t_max:
            out.append((key, "time_backwards"))
        elif t - self.t_max > TIME_SPIKE_S:
            self.held = (key, t)
        else:
            self.t_max = t
            out.append((key, None))
        return out

    def end(self) -> list[tuple[Any, str | None]]:
        """The frame still held at the end (no frame came after it): accepted."""
        held, self.held = self.held, None
        return [] if held is None else [(held[0], None)]


def iter_candump(
    lines: Iterable[str], stats: ReadStats | None = None, first_lineno: int = 1, file: bool = False
) -> Iterator[Frame]:
    """Yield frames from candump ``-L`` text lines, counting rejects in ``stats`` (:func:`iter_numbered`)."""
    for _lineno, frame in iter_numbered(lines, stats, first_lineno, file):
        yield frame


def iter_numbered(
    lines: Iterable[str], stats: ReadStats | None = None, first_lineno: int = 1, file: bool = False
) -> Iterator[tuple[int, Frame]]:
    """Yield ``(line number, frame)`` from candump ``-L`` text lines, counting rejects in ``stats``.

    Blank lines are skipped without being counted as rejects.  A frame
    whose timestamp is earlier than the previous accepted frame's is
    rejected as ``time_backwards`` (equal timestamps are accepted); one
    more than :data:`TIME_SPIKE_S` ahead of it is held until the next
    frame decides whether it is ``time_ahead`` or accepted.
    ``file``: the lines are a text file's, each ended by its line break
    but the last one, which is read by :func:`classify_unterminated`
    when it has none.
    """
    st = stats if stats is not None else ReadStats()
    rule = TimeRule()
    for lineno, line in enumerate(lines, start=first_lineno):
        st.lines += 1
        if not line.strip():
            continue
        cut = file and not line.endswith("\n")
        reason, frame = classify_unterminated(line) if cut else _classify(line)
        if reason is not None:
            st.reject(reason, lineno, line)
            continue
        assert frame is not None
        for (ln, text, fr), why in rule.push((lineno, line, frame), frame.t):
            if why is None:
                st.frames += 1
                yield ln, fr
            else:
                st.reject(why, ln, text)
    for (ln, _text, fr), _why in rule.end():
        st.frames += 1
        yield ln, fr


def time_order(times: Iterable[float]) -> list[str | None]:
    """:class:`TimeRule` over the times of frames in file order: for each, None (accepted),
    ``time_backwards`` or ``time_ahead``."""
    out: list[str | None] = []
    rule = TimeRule()
    for k, t in enumerate(times):
        out.append(None)
        for j, why in rule.push(k, t):
            out[j] = why
    return out


def read_candump(path: str | Path, stats: ReadStats | None = None) -> Iterator[Frame]:
    """Stream frames from a candump ``-L`` file (see :func:`iter_candump`).

    Undecodable bytes are replaced, so binary garbage is counted, not fatal.
    ``OSError`` from opening the file propagates.
    """
    for _lineno, frame in read_numbered(path, stats):
        yield frame


def read_numbered(path: str | Path, stats: ReadStats | None = None) -> Iterator[tuple[int, Frame]]:
    """:func:`read_candump` with each frame's line number (:func:`iter_numbered`)."""
    p = Path(path)
    st = stats if stats is not None else ReadStats()
    if not st.source:
        st.source = p.name
    with open(p, "r", encoding="utf-8-sig", errors="replace", newline=None) as fh:
        yield from iter_numbered(fh, st, file=True)


def format_line(t: float, channel: str, can_id: int, is_extended: bool, data: bytes) -> str:
    """One candump ``-L`` line (without newline), formatted like can-utils.

    ``t`` is epoch time [s], rounded to the microsecond.
    """
    if not math.isfinite(t) or t < 0:
        raise ValueError(f"timestamp {t!r} is not a non-negative finite number")
    data = bytes(data)
    if len(data) > 8:
        raise ValueError(f"classic CAN carries at most 8 bytes, got {len(data)}")
    if is_extended:
        if not 0 <= can_id <= 0x1FFFFFFF:
            raise ValueError(f"29-bit ID {can_id:#x} out of range")
        ident = f"{can_id:08X}"
    else:
        if not 0 <= can_id <= 0x7FF:
            raise ValueError(f"11-bit ID {can_id:#x} out of range")
        ident = f"{can_id:03X}"
    if not channel or any(c.isspace() for c in channel):
        raise ValueError(f"interface name {channel!r} is empty or has white space")
    usec_total = round(t * 1e6)
    sec, usec = divmod(usec_total, 1_000_000)
    return f"({sec:010d}.{usec:06d}) {channel} {ident}#{data.hex().upper()}"


class CandumpWriter:
    """Write frames to a text stream in candump ``-L`` format, one per line (LF)."""

    def __init__(self, stream: IO[str], channel: str = "can0") -> None:
        self.stream = stream
        self.channel = channel
        self.count = 0

    def write(
        self,
        t: float,
        can_id: int,
        data: bytes,
        is_extended: bool = True,
        channel: str | None = None,
    ) -> None:
        """Append one frame; ``t`` epoch seconds."""
        self.stream.write(format_line(t, channel or self.channel, can_id, is_extended, data) + "\n")
        self.count += 1

    def write_frame(self, frame: Frame) -> None:
        """Append a :class:`Frame` (or any 5-tuple of the same fields)."""
        t, channel, can_id, is_ext, data = frame
        self.write(t, can_id, data, is_ext, channel)


def write_candump(path: str | Path, frames: Iterable[Frame | tuple]) -> int:
    """Write frames ``(t, channel, can_id, is_extended, data)`` to ``path``; returns the count."""
    with open(path, "w", encoding="ascii", newline="\n") as fh:
        w = CandumpWriter(fh)
        for f in frames:
            w.write_frame(f)
        return w.count
