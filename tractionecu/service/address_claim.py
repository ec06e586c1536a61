"""J1939-81 / ISO 11783-5 address claim, as a state machine without I/O.

The daemon feeds it every Address Claimed (PGN 60928) and Request
(PGN 59904) frame it receives and sends what it returns.  Time is passed in
(seconds, any monotonic origin) so the procedure runs the same on a live bus,
on a candump file and in unit tests.

Procedure
---------
1. :meth:`AddressClaimer.start` sends Address Claimed for the preferred
   address: ``18EEFFxx`` with the 8-byte NAME (least significant byte first).
2. The control function may transmit other messages
   :data:`CLAIM_WAIT_S` (250 ms) after its claim if nobody contested it
   (:meth:`can_transmit`).
3. A Request for PGN 60928 sent to the global address or to our address is
   answered with our Address Claimed, or with Cannot Claim if we have no
   address (after a pseudo-random delay of 0–153 ms, as ISO 11783-5 asks,
   so that several silent nodes do not collide).
4. An Address Claimed from another NAME for *our* address is a contention.
   The numerically lower NAME has priority:

   - ours lower: we send our Address Claimed again and keep the address;
   - theirs lower and our NAME self-configurable (bit 63, arbitrary
     address capable): we claim the next free address in
     ``address_range`` (free = nobody claimed it in our table);
   - theirs lower and not self-configurable, or no free address left: we
     send Cannot Claim (source address 254, our NAME) and stay silent,
     apart from answering Requests for Address Claimed with Cannot Claim.

5. Every claim seen is kept in :attr:`table` (address -> NAME), so a new
   address is chosen among the free ones.  A Cannot Claim (source 254) from
   a NAME frees whatever address that NAME held.

Not implemented: Commanded Address (PGN 65240, it needs the transport
protocol) and the request-before-claim variant.
"""

from __future__ import annotations

import enum
import random
from collections import Counter
from typing import NamedTuple

from ..bus import j1939

CLAIM_WAIT_S = 0.25
"""Time after an uncontested claim before other messages may be sent [s]."""
CANNOT_CLAIM_MAX_DELAY_S = 0.153
"""Upper bound of the pseudo-random delay of a Cannot Claim answer to a Request [s]."""
PRIORITY = 6
"""Priority of network-management frames (Address Claimed, Cannot Claim)."""


class ClaimState(enum.Enum):
    """Where the procedure stands."""

    IDLE = "idle"
    CLAIMING = "claiming"          # claim sent, 250 ms not over
    CLAIMED = "claimed"            # address held, may transmit
    CANNOT_CLAIM = "cannot-claim"  # lost, silent


class Tx(NamedTuple):
    """A frame to send: 29-bit ID, data, and the delay before sending it [s]."""

    can_id: int
    data: bytes
    delay_s: float = 0.0


def address_claimed_id(sa: int) -> int:
    """ID of an Address Claimed / Cannot Claim frame from ``sa`` to the global address."""
    return j1939.make_id(PRIORITY, j1939.PGN_ADDRESS_CLAIMED, sa, j1939.ADDRESS_GLOBAL)


class AddressClaimer:
    """Claim and defend one source address for one NAME.

    Parameters
    ----------
    name:
        Our NAME.  ``name.arbitrary_address_capable`` decides whether a lost
        contention moves us to another address or silences us.
    preferred:
        Address claimed first (0..253).
    address_range:
        Inclusive (low, high) range searched for a new address when
        self-configurable (default 128..247, industry group 2's
        self-configurable range).
    rng:
        Random source for the Cannot Claim delay (tests pass a seeded one).

    Attributes
    ----------
    state, address:
        Current state and our address (None unless claiming or claimed).
    table:
        Address -> NAME (int) of every other control function seen.
    counts:
        ``claims_sent``, ``contentions_won``, ``contentions_lost``,
        ``address_changes``, ``requests_answered``, ``cannot_claim_sent``,
        ``malformed`` (claims or requests with a wrong length).
    """

    def __init__(
        self,
        name: j1939.Name,
        preferred: int,
        address_range: tuple[int, int] = (128, 247),
        rng: random.Random | None = None,
    ) -> None:
        if not 0 <= preferred <= 253:
            raise ValueError(f"preferred address {preferred} outside 0..253")
        lo, hi = address_range
        if not 0 <= lo <= hi <= 253:
            raise ValueError(f"address range {address_range} outside 0..253")
        self.name = name
        self.name_int = name.to_int()
        self.name_bytes = name.to_bytes()
        self.preferred = preferred
        self.address_range = (lo, hi)
        self.self_configurable = bool(name.arbitrary_address_capable)
        self.rng = rng or random.Random()
        self.state = ClaimState.IDLE
        self.address: int | None = None
        self.claimed_at = float("-inf")
        self.table: dict[int, int] = {}
        self.counts: Counter[str] = Counter()
        self._tried: set[int] = set()

    # ------------------------------------------------------------ queries
    def can_transmit(self, now: float) -> bool:
        """True if we hold an address and its claim is at least 250 ms old and uncontested."""
        if self.state is ClaimState.CLAIMING and now - self.claimed_at >= CLAIM_WAIT_S:
            self.state = ClaimState.CLAIMED
        return self.state is ClaimState.CLAIMED

    # ------------------------------------------------------------ actions
    def start(self, now: float) -> list[Tx]:
        """Claim the preferred address (again, e.g. after the bus came back)."""
        self._tried.clear()
        if self.state is ClaimState.CANNOT_CLAIM and not self.self_configurable:
            # a fixed-address NAME that lost stays silent until restarted
            return [self._cannot_claim()]
        target = self.address if self.address is not None else self.preferred
        if self.table.get(target, self.name_int + 1) < self.name_int:
            target = self._free_address(exclude=target) if self.self_configurable else None
            if target is None:
                return self._give_up()
        return self._claim(target, now)

    def handle(self, now: float, can_id: int, data: bytes) -> list[Tx]:
        """Process one received frame; returns frames to send.

        Frames that are neither Address Claimed nor Request are ignored.
        """
        try:
            cid = j1939.parse_id(can_id)
        except ValueError:
            return []
        if cid.pgn == j1939.PGN_ADDRESS_CLAIMED:
            return self._on_claim(now, cid.sa, bytes(data))
        if cid.pgn == j1939.PGN_REQUEST:
            return self._on_request(cid.sa, cid.da, bytes(data))
        return []

    # ------------------------------------------------------------ internals
    def _claim(self, address: int, now: float) -> list[Tx]:
        if address != self.address and self.address is not None:
            self.counts["address_changes"] += 1
        self.address = address
        self._tried.add(address)
        self.state = ClaimState.CLAIMING
        self.claimed_at = now
        self.counts["claims_sent"] += 1
        return [Tx(address_claimed_id(address), self.name_bytes)]

    def _cannot_claim(self, delay_s: float = 0.0) -> Tx:
        self.counts["cannot_claim_sent"] += 1
        return Tx(address_claimed_id(j1939.ADDRESS_NULL), self.name_bytes, delay_s)

    def _give_up(self) -> list[Tx]:
        self.state = ClaimState.CANNOT_CLAIM
        self.address = None
        return [self._cannot_claim()]

    def _free_address(self, exclude: int | None = None) -> int | None:
        lo, hi = self.address_range
        n = hi - lo + 1
        start = self.preferred if lo <= self.preferred <= hi else lo
        for i in range(n):
            a = lo + (start - lo + i) % n
            if a == exclude or a in self._tried:
                continue
            if a in self.table:
                continue
            return a
        return None

    def _on_claim(self, now: float, sa: int, data: bytes) -> list[Tx]:
        if len(data) != 8:
            self.counts["malformed"] += 1
            return []
        other = int.from_bytes(data, "little")
        if other == self.name_int:
            return []  # our own frame echoed back, or a clone: nothing to decide
        if sa == j1939.ADDRESS_NULL:
            # Cannot Claim from another NAME: it holds no address any more
            for a in [a for a, n in self.table.items() if n == other]:
                del self.table[a]
            return []
        for a in [a for a, n in self.table.items() if n == other and a != sa]:
            del self.table[a]  # that NAME moved
        self.table[sa] = other
        if self.address is None or sa != self.address:
            return []
        if self.state not in (ClaimState.CLAIMING, ClaimState.CLAIMED):
            return []
        if self.name_int < other:
            self.counts["contentions_won"] += 1
            return [Tx(address_claimed_id(self.address), self.name_bytes)]
        self.counts["contentions_lost"] += 1
        if self.self_configurable:
            new = self._free_address(exclude=sa)
            if new is not None:
                return self._claim(new, now)
        return self._give_up()

    def _on_request(self, sa: int, da: int | None, data: bytes) -> list[Tx]:
        if len(data) < 3:
            self.counts["malformed"] += 1
            return []
        if j1939.requested_pgn(data) != j1939.PGN_ADDRESS_CLAIMED:
            return []
        if da is not None and da != j1939.ADDRESS_GLOBAL and da != self.address:
            return []
        if self.state in (ClaimState.CLAIMING, ClaimState.CLAIMED) and self.address is not None:
            self.counts["requests_answered"] += 1
            return [Tx(address_claimed_id(self.address), self.name_bytes)]
        if self.state is ClaimState.CANNOT_CLAIM and (da is None or da == j1939.ADDRESS_GLOBAL):
            self.counts["requests_answered"] += 1
            return [self._cannot_claim(self.rng.uniform(0.0, CANNOT_CLAIM_MAX_DELAY_S))]
        return []
