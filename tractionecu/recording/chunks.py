"""A CAN capture read and decoded block by block, with the statistics of the whole.

:func:`iter_tables` yields the accepted frames of a capture as
:class:`~.fastdecode.FrameTable` blocks in file order: candump ``-L`` is read
:data:`~.fastdecode.CHUNK_CHARS` characters at a time, so memory is that of
one block whatever the file's length; the other formats are read whole by
their reader (:func:`.formats.read_frames`) and handed out in blocks of
:data:`BLOCK_FRAMES`.

:class:`ChunkDecoder` decodes block after block (:func:`.fastdecode.decode_table`
with one transport-protocol reassembler and one address-claim table for the
whole capture) and keeps the capture's statistics as if it had been decoded in
one piece: first and last frame, per-message counts, sources, intervals and
gaps, time jumps, unknown PGNs, decode errors, address claims, in the same
order.  ``tests/recording/test_chunks.py`` checks that a recording read in
small blocks equals one read whole.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Iterator

import numpy as np

from ..bus.candump import REPEAT_WINDOW_S, ReadStats
from ..bus.dbc import Codec
from ..bus.transport import Reassembler
from ..counting import MAX_EXAMPLES
from ..errors import RecordingError
from .containers import GAP_FACTOR, TIME_JUMP_S, AddressClaim, MessageStats, RecordingStats
from .fastdecode import FrameTable, decode_table, iter_candump_tables

BLOCK_FRAMES = 1 << 16
"""Frames per block of a capture read whole (formats other than candump ``-L``)."""


def open_tables(path: Path, rs: ReadStats, chunk_chars: int | None = None) -> tuple[str, Iterator[FrameTable]]:
    """The capture format of ``path`` (:func:`.formats.read_frames`' name, with candump's screen time mode)
    and its blocks of accepted frames (module doc).  Raises :class:`~tractionecu.errors.RecordingError` for
    an unknown format or an unreadable file."""
    from .formats import detect, read_frames

    from . import fastdecode

    chunk_chars = chunk_chars or fastdecode.CHUNK_CHARS
    fmt = detect(path)
    if fmt == "candump":
        return fmt, _candump_blocks(path, rs, chunk_chars)
    table, fmt = read_frames(path, rs, fmt)
    step = max(1, min(chunk_chars // 64, BLOCK_FRAMES))

    def blocks() -> Iterator[FrameTable]:
        for a in range(0, len(table), step):
            b = a + step
            yield FrameTable(table.lineno[a:b], table.t[a:b], table.can_id[a:b], table.ext[a:b], table.dlc[a:b],
                             table.payload[a:b])

    return fmt, blocks()


def _candump_blocks(path: Path, rs: ReadStats, chunk_chars: int) -> Iterator[FrameTable]:
    try:
        yield from iter_candump_tables(path, rs, chunk_chars)
    except OSError as e:
        raise RecordingError(f"{path}: cannot read: {e.strerror or e}") from e


class ChunkDecoder:
    """Decode frame blocks in order; ``stats`` ends as for the capture decoded in one piece (module doc).
    ``rs``: the capture's line counts, in which the repeated frames are counted (:class:`Repeats`)."""

    def __init__(self, codec: Codec, stats: RecordingStats, rs: ReadStats | None = None) -> None:
        self.codec = codec
        self.stats = stats
        self.repeats = None if rs is None else Repeats(rs)
        self.tp = Reassembler()
        self.claims: dict = {}
        self.t_prev = math.nan
        self.first = math.nan
        self.frames = 0
        self.messages: dict = {}

    def decode(self, table: FrameTable, want: set[str] | frozenset[str] | None = None
               ) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """The signals of one block: name -> (t, value, sa), in the order of their message's first frame.
        ``want``: only these signals (:func:`.fastdecode.decode_table`; the statistics are the same);
        ``messages`` holds the block's frames per message, name -> (lineno, t, sa)."""
        st = self.stats
        n = len(table)
        if self.repeats is not None:
            self.repeats.add(table)
        messages, signals, _ = decode_table(table, self.codec, st, MAX_EXAMPLES, tp=self.tp, claims=self.claims,
                                            want=want)
        self.messages = messages
        if n:
            if not math.isfinite(self.first):
                self.first = float(table.t[0])
            st.can_t_first = self.first
            st.can_t_last = float(table.t[-1])
            t = table.t if math.isnan(self.t_prev) else np.concatenate([[self.t_prev], table.t])
            if t.size >= 2:
                dt = np.diff(t)
                big = np.flatnonzero(dt > TIME_JUMP_S)
                st.n_time_jumps += int(big.size)
                room = MAX_EXAMPLES - len(st.time_jumps)
                if room > 0:
                    st.time_jumps += [(float(t[i]), float(dt[i])) for i in big[:room]]
            self.t_prev = float(table.t[-1])
            self.frames += n
        for msg, (_lines, arr, sa) in messages.items():
            ms = st.messages.get(msg)
            if ms is None:
                info = self.codec.message(msg)
                ms = st.messages[msg] = MessageStats(msg, info.pgn, nominal_period_s=info.cycle_time_s,
                                                     std_id=info.std_id)
            _add_times(ms, arr, sa)
        return {name: (t, v, sa) for name, (_lines, t, v, sa) in signals.items()}

    def finish(self) -> None:
        """Address claims into ``stats``, sorted by first time and source address."""
        self.stats.address_claims = sorted(
            (AddressClaim(sa, name, t, n, line) for (sa, _), (t, n, line, name) in self.claims.items()),
            key=lambda c: (c.t_first, c.sa))


class Repeats:
    """Counts in ``rs`` (:meth:`ReadStats.repeat`) the frames whose identifier (11- or 29-bit), length and data
    are those of the frame before them of that identifier and length, at most :data:`REPEAT_WINDOW_S` later,
    block by block in file order.  Between blocks it keeps the last frame of each identifier seen within the
    window of the last block's end, so memory does not grow with the identifiers a bus flood sends."""

    def __init__(self, rs: ReadStats) -> None:
        self.rs = rs
        self.key, self.t, self.payload = np.empty(0, dtype=np.int64), np.empty(0), np.empty(0, dtype=np.uint64)

    def add(self, table: FrameTable) -> None:
        """Count the repeats of one block (accepted frames, times not decreasing)."""
        n = len(table)
        if not n:
            return
        key = (table.can_id * 2 + table.ext) * 16 + table.dlc
        order = np.argsort(key, kind="stable")
        k, t = key[order], table.t[order]
        first = np.ones(n, dtype=bool)                # the first frame of its key in the block
        first[1:] = k[1:] != k[:-1]
        cand = np.zeros(n, dtype=bool)
        cand[1:] = ~first[1:] & (t[1:] - t[:-1] <= REPEAT_WINDOW_S)
        idx = np.flatnonzero(cand)
        pl = table.payload
        rep = [idx[pl[order[idx]] == pl[order[idx - 1]]]]
        if self.key.size:                             # the first of a key against the last before the block
            fi = np.flatnonzero(first)
            j = np.minimum(np.searchsorted(self.key, k[fi]), self.key.size - 1)
            hit = (self.key[j] == k[fi]) & (t[fi] - self.t[j] <= REPEAT_WINDOW_S)
            fi, j = fi[hit], j[hit]
            rep.append(fi[pl[order[fi]] == self.payload[j]])
        lines = np.sort(table.lineno[order[np.concatenate(rep)]])
        if lines.size:
            self.rs.repeated += int(lines.size)
            self.rs.repeated_lines += lines[:max(MAX_EXAMPLES - len(self.rs.repeated_lines), 0)].tolist()
        end = float(table.t[-1]) - REPEAT_WINDOW_S
        last = np.ones(n, dtype=bool)                 # the last frame of each key, if recent enough
        last[:-1] = first[1:]
        last &= t >= end
        keep = (self.t >= end) & np.isin(self.key, k, invert=True)
        key_new = np.concatenate([self.key[keep], k[last]])
        o = np.argsort(key_new, kind="stable")
        self.key = key_new[o]
        self.t = np.concatenate([self.t[keep], t[last]])[o]
        self.payload = np.concatenate([self.payload[keep], pl[order[last]]])[o]


def _add_times(ms: MessageStats, arr: np.ndarray, sa: np.ndarray) -> None:
    """Count one block's frames of a message: sources in order of first appearance, first and last time,
    longest interval and gaps (against the last frame of the blocks before)."""
    if sa.size and (sa == sa[0]).all():                 # one source (the common case): no sort
        key = int(sa[0])
        ms.sources[key] = ms.sources.get(key, 0) + int(sa.size)
    else:
        vals, first, counts = np.unique(sa, return_index=True, return_counts=True)
        for k in np.argsort(first, kind="stable").tolist():
            key = int(vals[k])
            ms.sources[key] = ms.sources.get(key, 0) + int(counts[k])
    had = ms.count
    ms.count += int(arr.size)
    if not had:
        ms.t_first = float(arr[0])
        t = arr
    else:
        t = np.concatenate([[ms.t_last], arr])
    ms.t_last = float(arr[-1])
    if t.size >= 2:
        dt = np.diff(t)
        ms.max_interval_s = max(ms.max_interval_s, float(dt.max())) if had else float(dt.max())
        if ms.nominal_period_s:
            big = np.nonzero(dt > GAP_FACTOR * ms.nominal_period_s)[0]
            ms.n_gaps += int(big.size)
            room = MAX_EXAMPLES - len(ms.gaps)
            if room > 0:
                ms.gaps += [(float(t[i]), float(dt[i])) for i in big[:room]]
