"""Network management: the J1939 address claim, transmission, and the estimate broadcast.

:class:`Network` holds the :class:`~.address_claim.AddressClaimer` (none when
``broadcast.enabled`` is false: listen-only) and transmits on the CAN link:

* once started (:meth:`Network.start`), it claims its address each time the
  bus is (re)opened (:meth:`Network.on_bus_open`, the link's ``on_open``);
* Address Claimed frames from the bus go to the claimer at once
  (:meth:`Network.on_nm_frame`); the frames it answers with go out at once or,
  for a Cannot Claim, after the claimer's random delay (on the event loop);
  every change of our address is reported to :attr:`Network.on_address`
  (the service moves its kernel filters with it);
* Requests wait in a bounded queue (``requests_shed`` when full; a Request
  identical to one already waiting, same ID and data, joins it and gets its
  answer: ``requests_coalesced``) and are served after the estimation step, at most ``broadcast.requests_per_tick``
  per step (:meth:`Network.serve_requests`), so a request flood never delays
  the estimate.  A Request to another destination is not ours
  (``requests_not_for_us``; the kernel filter normally drops it first).
  Answers: a Request for Address Claimed gets our claim (or Cannot Claim);
  a destination-specific Request for any other PGN gets a NACK
  (Acknowledgement, PGN 59392, J1939-21).  The same PGN is answered to the
  same requester at most once per ``broadcast.request_answer_interval_s``
  (``requests_rate_limited``); a Request for Address Claimed that falls
  inside that interval is answered once at its end instead
  (``answers_deferred``), so it is still answered within the J1939 response
  time (200 ms).  Global Requests for other PGNs are not answered
  (``requests_unsupported``).
* :meth:`Network.broadcast` sends the three estimate frames once the claim
  allows it (250 ms after an uncontested claim); otherwise it counts
  ``broadcast_skipped``.  ``broadcasts`` and ``broadcast_errors`` count the
  rest.

Stopping cancels the delayed frames not yet sent.
"""

from __future__ import annotations

import asyncio
import collections
import logging
from collections import Counter
from typing import Any, Callable, Protocol

from ..bus import j1939
from ..bus.dbc import Codec
from . import broadcast
from .address_claim import AddressClaimer, ClaimState, Tx
from .clock import ServiceClock
from .config import BroadcastConfig

log = logging.getLogger(__name__)

PGN_ACKNOWLEDGEMENT = 59392
"""Acknowledgement, 0xE800 (PDU1): byte 0 is the control byte (1 = NACK)."""
ACK_NACK = 1
REQUEST_QUEUE_FRAMES = 64
"""Requests waiting for :meth:`Network.serve_requests`; further ones are shed (``requests_shed``)."""


def nack(requester: int, pgn: int, sa: int, priority: int = 6) -> tuple[int, bytes]:
    """``(can_id, data)`` of a NACK from ``sa`` for a Request of ``pgn`` by ``requester`` (J1939-21:
    sent to the global address, the requester's address in byte 4)."""
    data = bytes([ACK_NACK, 0xFF, 0xFF, 0xFF, requester & 0xFF]) + (pgn & 0x3FFFF).to_bytes(3, "little")
    return j1939.make_id(priority, PGN_ACKNOWLEDGEMENT, sa, j1939.ADDRESS_GLOBAL), data


class Link(Protocol):
    """What the network transmits on (:class:`~.canlink.CanLink`)."""

    bus: Any

    def send(self, can_id: int, data: bytes) -> bool: ...


class Network:
    """Address claim, transmit and broadcast on one CAN link (module doc).

    Parameters
    ----------
    cfg:
        The ``[broadcast]`` table (NAME, addresses, priority, enabled).
    codec:
        The DBC codec (encodes the estimate frames).
    clock:
        Service clock (claim timing).
    link:
        The link to transmit on; may be set later (:attr:`link`), before the
        bus opens.
    stats:
        Counter for ``network_management``, ``broadcasts``,
        ``broadcast_errors``, ``broadcast_skipped`` and the request counts of
        the module doc (default: a new one).

    Attributes
    ----------
    on_address:
        Called with our new address (None: none) each time it changes.
    """

    name = "network"

    def __init__(self, cfg: BroadcastConfig, codec: Codec, clock: ServiceClock, link: Link | None = None,
                 stats: Counter[str] | None = None) -> None:
        self.cfg = cfg
        self.codec = codec
        self.clock = clock
        self.link = link
        self.stats: Counter[str] = Counter() if stats is None else stats
        self.claimer: AddressClaimer | None = None
        if cfg.enabled:
            self.claimer = AddressClaimer(cfg.name_value(), cfg.preferred_address,
                                          (cfg.address_min, cfg.address_max))
        self.active = False
        self.on_address: Callable[[int | None], None] | None = None
        self._pending: set[asyncio.TimerHandle] = set()
        self._requests: collections.OrderedDict[tuple[int, bytes], None] = collections.OrderedDict()
        self._answered: dict[tuple[int, int], float] = {}     # (pgn, requester) -> service time of the last answer
        self._deferred: set[int] = set()                      # requested PGNs with an answer scheduled
        self._reported: int | None = None

    @property
    def address(self) -> int | None:
        """Our claimed source address, or None."""
        return None if self.claimer is None else self.claimer.address

    def describe_address(self) -> str:
        """``listen-only``, ``cannot-claim``, ``0xNN`` or ``-`` (for the status line)."""
        cl = self.claimer
        if cl is None:
            return "listen-only"
        if cl.state is ClaimState.CANNOT_CLAIM:
            return "cannot-claim"
        return "-" if cl.address is None else f"0x{cl.address:02X}"

    # ------------------------------------------------------------ lifecycle
    async def start(self) -> None:
        """Claim at every (re)open of the bus from now on; at once if it is open already."""
        self.active = True
        if self.link is not None and self.link.bus is not None:
            self.on_bus_open()

    async def stop(self) -> None:
        """Stop claiming; cancel the delayed frames not sent yet."""
        self.active = False
        for h in self._pending:
            h.cancel()
        self._pending.clear()
        self._deferred.clear()
        self._requests.clear()

    # ------------------------------------------------------------ address claim
    def on_bus_open(self) -> None:
        """The bus was (re)opened: claim our address (once started)."""
        cl = self.claimer
        if cl is None or not self.active:
            return
        self.transmit(cl.start(self.clock.now()))
        log.info("J1939: claiming address 0x%02X with NAME 0x%016X", cl.address or 0, cl.name_int)
        self._report_address()

    def _report_address(self) -> None:
        addr = self.address
        if addr != self._reported:
            self._reported = addr
            if self.on_address is not None:
                self.on_address(addr)

    def on_nm_frame(self, can_id: int, data: bytes) -> None:
        """An Address Claimed (handled now) or Request (queued) frame from the bus."""
        self.stats["network_management"] += 1
        cl = self.claimer
        if cl is None:
            return
        if (can_id >> 16) & 0xFF == j1939.PGN_REQUEST >> 8:
            da = (can_id >> 8) & 0xFF
            if da != j1939.ADDRESS_GLOBAL and da != cl.address:
                self.stats["requests_not_for_us"] += 1
            elif (can_id, data) in self._requests:
                self.stats["requests_coalesced"] += 1
            elif len(self._requests) >= REQUEST_QUEUE_FRAMES:
                self.stats["requests_shed"] += 1
            else:
                self._requests[(can_id, data)] = None
            return
        self._handle(can_id, data)

    def _handle(self, can_id: int, data: bytes) -> None:
        cl = self.claimer
        assert cl is not None
        before = cl.state, cl.address
        self.transmit(cl.handle(self.clock.now(), can_id, data))
        after = cl.state, cl.address
        if after != before:
            state, addr = after
            if state is ClaimState.CANNOT_CLAIM:
                log.error("J1939: cannot claim an address (NAME 0x%016X); staying silent", cl.name_int)
            elif addr is not None:
                log.warning("J1939: claiming address 0x%02X (%d)", addr, addr)
            self._report_address()

    def waiting(self) -> int:
        """Requests queued, not served yet."""
        return len(self._requests)

    def serve_requests(self) -> int:
        """Serve at most ``broadcast.requests_per_tick`` queued Requests (after an estimation step);
        returns how many."""
        n = 0
        q = self._requests
        while q and n < self.cfg.requests_per_tick:
            (can_id, data), _ = q.popitem(last=False)
            n += 1
            self._request(can_id, data)
        return n

    def _request(self, can_id: int, data: bytes) -> None:
        st = self.stats
        st["requests"] += 1
        cl = self.claimer
        if cl is None or len(data) < 3:
            if cl is not None:
                cl.counts["malformed"] += 1
            return
        pgn = j1939.requested_pgn(data)
        sa, da = can_id & 0xFF, (can_id >> 8) & 0xFF
        now = self.clock.now()
        if pgn == j1939.PGN_ADDRESS_CLAIMED:
            key = (pgn, j1939.ADDRESS_GLOBAL)            # the answer goes to everyone
        elif da != j1939.ADDRESS_GLOBAL:
            key = (pgn, sa)
        else:
            st["requests_unsupported"] += 1              # a global Request for a PGN we do not send
            return
        wait = self._answered.get(key, -1e18) + self.cfg.request_answer_interval_s - now
        if wait > 0:
            if pgn != j1939.PGN_ADDRESS_CLAIMED:
                st["requests_rate_limited"] += 1
            elif pgn in self._deferred:
                st["requests_rate_limited"] += 1
            else:                                        # answer once at the end of the interval
                self._deferred.add(pgn)
                st["answers_deferred"] += 1
                self._defer(self.clock.wall(wait), key, can_id, data)
            return
        if len(self._answered) > 1024:                  # many requesters: forget the old ones
            self._answered.clear()
        self._answered[key] = now
        self._answer(key, can_id, data)

    def _defer(self, delay: float, key: tuple[int, int], can_id: int, data: bytes) -> None:
        handle: asyncio.TimerHandle

        def fire() -> None:
            self._pending.discard(handle)
            self._deferred.discard(key[0])
            self._answered[key] = self.clock.now()
            self._answer(key, can_id, data)

        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:                           # not on the event loop: answer now
            self._deferred.discard(key[0])
            self._answer(key, can_id, data)
            return
        handle = loop.call_later(delay, fire)
        self._pending.add(handle)

    def _answer(self, key: tuple[int, int], can_id: int, data: bytes) -> None:
        pgn = key[0]
        cl = self.claimer
        assert cl is not None
        if pgn == j1939.PGN_ADDRESS_CLAIMED:
            before = cl.counts["requests_answered"]
            self._handle(can_id, data)
            self.stats["requests_answered"] += cl.counts["requests_answered"] - before
            return
        if cl.address is None or not cl.can_transmit(self.clock.now()):
            self.stats["requests_unanswered"] += 1     # no address to answer from
            return
        if self._send(*nack(can_id & 0xFF, pgn, cl.address, self.cfg.priority)):
            self.stats["requests_nacked"] += 1

    # ------------------------------------------------------------ transmit
    def transmit(self, txs: list[Tx]) -> None:
        """Send the claimer's frames: now, or after their delay on the running event loop."""
        for tx in txs:
            if tx.delay_s > 0:
                try:
                    loop = asyncio.get_running_loop()
                except RuntimeError:
                    loop = None
                if loop is not None:
                    self._later(loop, self.clock.wall(tx.delay_s), tx.can_id, tx.data)
                    continue
            self._send(tx.can_id, tx.data)

    def _later(self, loop: asyncio.AbstractEventLoop, delay: float, can_id: int, data: bytes) -> None:
        handle: asyncio.TimerHandle

        def fire() -> None:
            self._pending.discard(handle)
            self._send(can_id, data)

        handle = loop.call_later(delay, fire)
        self._pending.add(handle)

    def _send(self, can_id: int, data: bytes) -> bool:
        if self.link is None:
            return False
        return self.link.send(can_id, data)

    def broadcast(self, est: Any) -> bool:
        """Send the estimate (None: the "no estimate" frames) if our claim allows; returns True if sent."""
        cl = self.claimer
        if cl is None or self.link is None or self.link.bus is None or not cl.can_transmit(self.clock.now()):
            self.stats["broadcast_skipped"] += 1
            return False
        sa = cl.address
        assert sa is not None
        prio = self.cfg.priority
        if est is None:
            frames = broadcast.no_estimate_frames(self.codec, sa, prio)
        else:
            frames = broadcast.estimate_frames(self.codec, est, sa, prio)
        ok = all([self._send(cid, data) for cid, data in frames])
        self.stats["broadcasts" if ok else "broadcast_errors"] += 1
        return ok

