"""The per-frame reference decoder of ``can.log``: candump line reader, one
:meth:`~tractionecu.bus.dbc.Codec.decode` per frame.

:func:`tractionecu.recording.reader.read_recording` decodes in bulk
(:mod:`.fastdecode`); this slow, plain form is what the bulk decoder is
tested against (identical series, statistics and counters).  Multi-packet
messages of DBC PGNs are decoded after their last transport-protocol packet
(:func:`tractionecu.bus.transport.with_reassembled`).
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

from ..bus import j1939
from ..bus.candump import REPEAT_WINDOW_S, Frame, ReadStats, read_numbered
from ..bus.dbc import NETWORK_MANAGEMENT_PGNS, Codec
from ..bus.transport import with_reassembled
from ..counting import MAX_EXAMPLES
from ..errors import DecodeError, RecordingError, UnknownFrame
from .containers import STD_SA, AddressClaim, MessageStats, RecordingStats, Series
from .reader import check_frames, message_times


class _SeriesBuilder:
    __slots__ = ("t", "v", "sa")

    def __init__(self) -> None:
        self.t: list[float] = []
        self.v: list[float] = []
        self.sa: list[int] = []

    def build(self, unit: str) -> Series:
        return Series(
            np.asarray(self.t, dtype=float),
            np.asarray(self.v, dtype=float),
            np.asarray(self.sa, dtype=np.int16),
            unit,
        )


def _counting_repeats(frames: Iterable[tuple[int, Frame]], rs: ReadStats, line: list[int]) -> Iterator[Frame]:
    """The frames of ``(line number, frame)`` pairs, each repeat of the frame before it of its identifier counted
    in ``rs`` (:class:`.chunks.Repeats`); ``line[0]`` the line number of the last frame taken."""
    last: dict[tuple[int, bool, int], tuple[float, bytes]] = {}
    for lineno, f in frames:
        line[0] = lineno
        key = (f.can_id, f.is_extended, len(f.data))
        prev = last.get(key)
        if prev is not None and prev[1] == f.data and f.t - prev[0] <= REPEAT_WINDOW_S:
            rs.repeat(lineno)
        last[key] = (f.t, f.data)
        yield f


def read_can_per_frame(path: Path, codec: Codec, stats: RecordingStats) -> dict[str, Series]:
    """Read and decode ``can.log`` frame by frame (candump line reader, :meth:`Codec.decode` per frame).

    The reference for :func:`_read_can`'s vectorised decoding; same results.
    """
    rs = ReadStats(source=path.name)
    stats.files[path.name] = rs
    builders: dict[str, _SeriesBuilder] = {}
    times: dict[str, list[float]] = {}
    claims: dict[tuple[int, int], AddressClaim] = {}
    try:
        line = [0]                              # a reassembled message's: its last packet's
        frames = _counting_repeats(read_numbered(path, rs), rs, line)
        for frame in with_reassembled(frames, lambda pgn: codec.message_for_pgn(pgn) is not None):
            lineno = line[0]
            if not math.isfinite(stats.can_t_first):
                stats.can_t_first = frame.t
            stats.can_t_last = frame.t
            if not frame.is_extended:
                if codec.message_for_std_id(frame.can_id) is None:
                    stats.non_extended_frames += 1
                    continue
                cid = None                      # an owner's message on an 11-bit identifier: no PGN, no address
            else:
                cid = j1939.parse_id(frame.can_id)
            if cid is not None and cid.pgn == j1939.PGN_ADDRESS_CLAIMED and len(frame.data) == 8:
                name = j1939.Name.from_bytes(frame.data)
                key = (cid.sa, name.to_int())
                if key in claims:
                    claims[key].count += 1
                else:
                    claims[key] = AddressClaim(cid.sa, name, frame.t, 1, lineno)
            try:
                msg, values = codec.decode(frame.can_id, frame.data, frame.is_extended)
            except UnknownFrame:
                stats.unknown_pgns[cid.pgn] += 1
                stats.add_unknown_sources(cid.pgn, (cid.sa,))
                continue
            except DecodeError:
                info = codec.message_for_pgn(cid.pgn) if cid is not None else codec.message_for_std_id(frame.can_id)
                key_name = info.name if info is not None else f"PGN {cid.pgn}"
                stats.decode_errors[key_name] += 1
                ex = stats.decode_error_lines.setdefault(key_name, [])
                if len(ex) < MAX_EXAMPLES:
                    ex.append(lineno)
                continue
            ms = stats.messages.get(msg)
            if ms is None:
                info = codec.message(msg)
                ms = stats.messages[msg] = MessageStats(msg, info.pgn, nominal_period_s=info.cycle_time_s,
                                                        std_id=info.std_id)
                times[msg] = []
            sa = STD_SA if cid is None else cid.sa
            ms.count += 1
            ms.sources[sa] += 1
            times[msg].append(frame.t)
            if cid is not None and cid.pgn in NETWORK_MANAGEMENT_PGNS:
                continue
            used = stats.source_used.setdefault(msg, sa)      # one source per message (fastdecode.one_source)
            if sa != used:
                stats.other_sources.setdefault(msg, Counter())[sa] += 1
                continue
            for sig, v in values.items():
                b = builders.get(sig)
                if b is None:
                    b = builders[sig] = _SeriesBuilder()
                b.t.append(frame.t)
                b.v.append(v)
                b.sa.append(sa)
    except OSError as e:
        raise RecordingError(f"{path}: cannot read: {e.strerror or e}") from e

    check_frames(path, rs)
    for msg, ts in times.items():
        message_times(stats.messages[msg], np.asarray(ts))
    stats.address_claims = sorted(claims.values(), key=lambda c: (c.t_first, c.sa))
    return {name: b.build(codec.signals[name].unit) for name, b in builders.items()}
