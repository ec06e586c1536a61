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

from ..bus.candump import ReadStats
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
    """Decode frame blocks in order; ``stats`` ends as for the capture decoded in one piece (module doc)."""

    def __init__(self, codec: Codec, stats: RecordingStats) -> None:
        self.codec = codec
        self.stats = stats
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
