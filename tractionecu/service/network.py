"""Network management: the J1939 address claim, transmission, and the estimate broadcast.

:class:`Network` holds the :class:`~.address_claim.AddressClaimer` (none when
``broadcast.enabled`` is false: listen-only) and transmits on the CAN link:

* once started (:meth:`Network.start`), it claims its address each time the
  bus is (re)opened (:meth:`Network.on_bus_open`, the link's ``on_open``);
* Address Claimed and Request frames from the bus go to the claimer
  (:meth:`Network.on_nm_frame`); the frames it answers with go out at once or,
  for a Cannot Claim, after the claimer's random delay (on the event loop);
* :meth:`Network.broadcast` sends the three estimate frames once the claim
  allows it (250 ms after an uncontested claim); otherwise it counts
  ``broadcast_skipped``.  ``broadcasts`` and ``broadcast_errors`` count the
  rest.

Stopping cancels the delayed frames not yet sent.
"""

from __future__ import annotations

import asyncio
import logging
from collections import Counter
from typing import Any, Protocol

from ..bus.dbc import Codec
from . import broadcast
from .address_claim import AddressClaimer, ClaimState, Tx
from .clock import ServiceClock
from .config import BroadcastConfig

log = logging.getLogger(__name__)


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
        ``broadcast_errors``, ``broadcast_skipped`` (default: a new one).
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
        self._pending: set[asyncio.TimerHandle] = set()

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

    # ------------------------------------------------------------ address claim
    def on_bus_open(self) -> None:
        """The bus was (re)opened: claim our address (once started)."""
        cl = self.claimer
        if cl is None or not self.active:
            return
        self.transmit(cl.start(self.clock.now()))
        log.info("J1939: claiming address 0x%02X with NAME 0x%016X", cl.address or 0, cl.name_int)

    def on_nm_frame(self, can_id: int, data: bytes) -> None:
        """An Address Claimed or Request frame from the bus."""
        self.stats["network_management"] += 1
        cl = self.claimer
        if cl is None:
            return
        before = cl.state, cl.address
        self.transmit(cl.handle(self.clock.now(), can_id, data))
        after = cl.state, cl.address
        if after != before:
            state, addr = after
            if state is ClaimState.CANNOT_CLAIM:
                log.error("J1939: cannot claim an address (NAME 0x%016X); staying silent", cl.name_int)
            elif addr is not None:
                log.warning("J1939: claiming address 0x%02X (%d)", addr, addr)

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

