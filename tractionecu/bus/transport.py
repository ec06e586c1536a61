"""Passive J1939-21 transport protocol reassembly: multi-packet messages seen on the bus.

A parameter group longer than 8 bytes (EC1, 40 bytes; DM1 with several
trouble codes; many proprietary groups) is sent as a connection-management
frame, TP.CM (PGN 60416, 0xEC00), then numbered data frames, TP.DT (PGN
60160, 0xEB00).  TP.CM byte 1 is the control byte: 32 BAM (broadcast, to
0xFF), 16 RTS (to one destination, answered by CTS 17 and end-of-message
acknowledgement 19), 255 abort.  BAM and RTS carry the message size in bytes
2-3, the number of packets in byte 4 and the PGN in bytes 6-8 (all least
significant byte first).  Each TP.DT holds its sequence number (1, 2, ...)
in byte 1 and 7 data bytes.

:class:`Reassembler` follows the sessions a listener sees, one per (sender,
destination), and returns the message when its last packet arrives.  It only
listens: it never answers an RTS.  A packet out of sequence, a new
announcement or an abort drops the session's partial message; a repeated
packet (a retransmission after CTS) is ignored.  Without time stamps session
time-outs are not enforced: a recording's frames are in order, and a message
whose packets stop is simply never completed.  Given the frame times
(``feed(..., t=)``, the live service), a session idle longer than
:data:`T1_S` is dropped (J1939-21 T1, 750 ms between packets), and at most
``max_sessions`` are followed at once (the oldest is dropped first), so
traffic that opens sessions and never ends them holds bounded memory.
"""

from __future__ import annotations

import math
from typing import Iterable, Iterator

from . import j1939
from .candump import Frame

PGN_TP_CM = 60416
"""Transport protocol connection management, 0xEC00 (PDU1)."""
PGN_TP_DT = 60160
"""Transport protocol data transfer, 0xEB00 (PDU1)."""
TRANSPORT_PGNS = frozenset({PGN_TP_CM, PGN_TP_DT})

CM_RTS = 16
CM_BAM = 32
CM_ABORT = 255
MAX_SIZE = 1785
"""Largest message of the transport protocol: 255 packets of 7 bytes."""
T1_S = 0.75
"""J1939-21 T1: a receiver drops a session after this long without its next packet [s]."""


class _Session:
    __slots__ = ("pgn", "size", "packets", "data", "next_seq", "t")

    def __init__(self, pgn: int, size: int, packets: int, t: float) -> None:
        self.pgn = pgn
        self.size = size
        self.packets = packets
        self.data = bytearray()
        self.next_seq = 1
        self.t = t


class Reassembler:
    """Multi-packet messages from TP.CM / TP.DT frames (module doc)."""

    def __init__(self, max_sessions: int = 64) -> None:
        self._sessions: dict[tuple[int, int], _Session] = {}
        self.max_sessions = max_sessions
        self.dropped = 0
        """Sessions dropped incomplete: timed out (T1) or pushed out by ``max_sessions``."""

    @property
    def open_sessions(self) -> int:
        """Sessions being followed."""
        return len(self._sessions)

    def feed(self, can_id: int, data: bytes, t: float | None = None) -> tuple[int, int, bytes] | None:
        """Take one frame; returns ``(pgn, sender SA, payload)`` when it completes a message, else None.

        Frames that are not 8-byte TP.CM / TP.DT frames are ignored.  ``t`` [s]: the frame's time, which
        enables the T1 time-out (module doc).
        """
        if len(data) != 8:
            return None
        pgn = j1939.pgn_of(can_id)
        if pgn not in TRANSPORT_PGNS:
            return None
        sa = can_id & 0xFF
        da = (can_id >> 8) & 0xFF
        if t is not None and self._sessions:
            stale = [k for k, v in self._sessions.items() if t - v.t > T1_S]
            for k in stale:
                del self._sessions[k]
            self.dropped += len(stale)
        if pgn == PGN_TP_CM:
            ctrl = data[0]
            if ctrl in (CM_BAM, CM_RTS):
                size = data[1] | (data[2] << 8)
                packets = data[3]
                announced = data[5] | (data[6] << 8) | (data[7] << 16)
                if 9 <= size <= MAX_SIZE and packets == (size + 6) // 7 and announced <= 0x3FFFF:
                    if (sa, da) not in self._sessions and len(self._sessions) >= self.max_sessions:
                        del self._sessions[min(self._sessions, key=lambda k: self._sessions[k].t)]
                        self.dropped += 1
                    self._sessions[(sa, da)] = _Session(j1939.pgn_of(announced << 8), size, packets,
                                                        -math.inf if t is None else t)
                else:
                    self._sessions.pop((sa, da), None)
            elif ctrl == CM_ABORT:                      # from either end of the connection
                self._sessions.pop((sa, da), None)
                self._sessions.pop((da, sa), None)
            return None
        s = self._sessions.get((sa, da))
        if s is None:
            return None
        seq = data[0]
        if seq < s.next_seq:                            # retransmitted packet
            return None
        if seq != s.next_seq:
            del self._sessions[(sa, da)]
            return None
        s.data += data[1:]
        s.next_seq += 1
        if t is not None:
            s.t = t
        if seq < s.packets:
            return None
        del self._sessions[(sa, da)]
        return s.pgn, sa, bytes(s.data[: s.size])


def message_id(pgn: int, sa: int, priority: int = 7) -> int:
    """A 29-bit identifier for a reassembled message: its PGN from ``sa`` (PDU1: to the global address)."""
    return j1939.make_id(priority, pgn, sa, j1939.ADDRESS_GLOBAL if j1939.is_pdu1(pgn) else None)


def with_reassembled(frames: Iterable[Frame], wanted) -> Iterator[Frame]:
    """``frames`` as they are, each followed by the message it completes when ``wanted(pgn)`` is true.

    The completed message is yielded as one frame of the last packet's time
    and interface, the identifier :func:`message_id` (the sender's SA) and
    the whole payload as its data.
    """
    tp = Reassembler()
    for frame in frames:
        yield frame
        if frame.is_extended:
            done = tp.feed(frame.can_id, frame.data)
            if done is not None and wanted(done[0]):
                yield Frame(frame.t, frame.channel, message_id(done[0], done[1]), True, done[2])
