"""SAE J1939 / ISO 11783 identifier and NAME helpers (pure functions, no I/O).

29-bit identifier layout (J1939-21)::

    bits 26..28  priority P (0 highest .. 7 lowest)
    bit  25      extended data page EDP (0 for every PGN used here)
    bit  24      data page DP
    bits 16..23  PDU format PF
    bits  8..15  PDU specific PS: destination address if PF < 240 (PDU1),
                 group extension if PF >= 240 (PDU2)
    bits  0..7   source address SA

The PGN is the 18 bits EDP|DP|PF|PS, with PS forced to 0 for PDU1 formats.

64-bit NAME layout (J1939-81 / ISO 11783-5), bit 0 least significant, sent
least significant byte first in the Address Claimed data field::

    bits  0..20  identity number (21)      bits 40..47  function (8)
    bits 21..31  manufacturer code (11)    bit  48      reserved (1)
    bits 32..34  ECU instance (3)          bits 49..55  vehicle system (7)
    bits 35..39  function instance (5)     bits 56..59  vehicle system instance (4)
    bits 60..62  industry group (3)        bit  63      arbitrary address capable (1)

The address-claim procedure itself lives in :mod:`tractionecu.service`;
this module only packs and unpacks.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

PGN_REQUEST = 59904
"""Request, 0xEA00 (PDU1)."""
PGN_ADDRESS_CLAIMED = 60928
"""Address Claimed / Cannot Claim, 0xEE00 (PDU1)."""
PGN_COMMANDED_ADDRESS = 65240
"""Commanded Address, 0xFED8 (PDU2, sent with the transport protocol)."""

ADDRESS_GLOBAL = 0xFF
"""Destination 255: broadcast to every control function."""
ADDRESS_NULL = 0xFE
"""Source 254: a control function without an address (Cannot Claim)."""

TECU_ADDRESS = 0xF0
"""ISO 11783 preferred address of the tractor ECU (industry group 2)."""
DRIVETRAIN_ECU_ADDRESS = 0x80
"""Default source address of the drive-train ECU that sends the per-wheel inputs."""
DEFAULT_SERVICE_ADDRESS = 0x90
"""Preferred source address of this service (144).

Chosen inside 128..247, the self-configurable range (SAE J1939-81, ISO
11783-5), so an arbitrary-address-capable NAME may claim it; it is
distinct from the tractor ECU (0xF0), the task controller (0xF7), the
virtual terminal (0x26), the drive-train ECU default (0x80) and from every
address claimed on the John Deere 5055E capture (0x00, 0x03, 0x06, 0x17,
0x47).
"""

INDUSTRY_GROUP_AGRICULTURE = 2
"""NAME industry group: agricultural and forestry equipment."""

INDUSTRY_GROUPS = {
    0: "global",
    1: "on-highway",
    2: "agricultural and forestry",
    3: "construction",
    4: "marine",
    5: "industrial process control",
}


class CanId(NamedTuple):
    """A parsed 29-bit J1939 identifier.  ``da`` is None for PDU2 (broadcast) PGNs."""

    priority: int
    pgn: int
    sa: int
    da: int | None


def is_pdu1(pgn: int) -> bool:
    """True if the PGN's PDU format byte is below 240 (destination-specific)."""
    return ((pgn >> 8) & 0xFF) < 240


def make_id(priority: int, pgn: int, sa: int, da: int | None = None) -> int:
    """Build a 29-bit J1939 identifier.

    For PDU1 PGNs (PF < 240) the destination address ``da`` goes into the
    PS byte (default 0xFF, global); the PGN's own PS byte must be 0.  For
    PDU2 PGNs ``da`` must be None or 0xFF.  Raises ValueError on values out
    of range.
    """
    if not 0 <= priority <= 7:
        raise ValueError(f"priority {priority} outside 0..7")
    if not 0 <= pgn <= 0x3FFFF:
        raise ValueError(f"PGN {pgn} outside 0..0x3FFFF")
    if not 0 <= sa <= 0xFF:
        raise ValueError(f"source address {sa} outside 0..255")
    if is_pdu1(pgn):
        if pgn & 0xFF:
            raise ValueError(f"PDU1 PGN {pgn:#x} must have PS = 0")
        dest = ADDRESS_GLOBAL if da is None else da
        if not 0 <= dest <= 0xFF:
            raise ValueError(f"destination address {dest} outside 0..255")
        ps_pgn = pgn | dest
    else:
        if da is not None and da != ADDRESS_GLOBAL:
            raise ValueError(f"PDU2 PGN {pgn:#x} cannot carry destination {da}")
        ps_pgn = pgn
    return (priority << 26) | (ps_pgn << 8) | sa


def parse_id(can_id: int) -> CanId:
    """Split a 29-bit identifier into (priority, pgn, sa, da).

    PDU1 (PF < 240): the PS byte is the destination address and is masked
    out of the PGN.  PDU2: ``da`` is None and PS is part of the PGN.
    """
    if not 0 <= can_id <= 0x1FFFFFFF:
        raise ValueError(f"CAN ID {can_id:#x} is not a 29-bit identifier")
    pgn = pgn_of(can_id)
    ps = (can_id >> 8) & 0xFF
    return CanId((can_id >> 26) & 0x7, pgn, can_id & 0xFF, ps if is_pdu1(pgn) else None)


def pgn_of(can_id):
    """The PGN of a 29-bit identifier: bits 8..25, with the PS byte (the
    destination address) cleared for PDU1 (PF < 240).

    Works alike on a Python int (gives an int) and element-wise on a numpy
    integer array (gives an array of the same dtype).  It does not check the
    range; :func:`parse_id` does.
    """
    raw = (can_id >> 8) & 0x3FFFF
    pdu1 = ((raw >> 8) & 0xFF) < 240
    return raw - (raw & 0xFF) * pdu1


# (field name, bit position, bit width), least significant first.
_NAME_LAYOUT: tuple[tuple[str, int, int], ...] = (
    ("identity_number", 0, 21),
    ("manufacturer_code", 21, 11),
    ("ecu_instance", 32, 3),
    ("function_instance", 35, 5),
    ("function", 40, 8),
    ("reserved", 48, 1),
    ("vehicle_system", 49, 7),
    ("vehicle_system_instance", 56, 4),
    ("industry_group", 60, 3),
    ("arbitrary_address_capable", 63, 1),
)


@dataclass(frozen=True, order=False)
class Name:
    """An ISO 11783-5 / J1939-81 64-bit NAME.

    Lower numeric NAME value wins address arbitration; compare with
    :meth:`to_int`.  ``arbitrary_address_capable`` is the self-configurable
    address bit.
    """

    identity_number: int = 0
    manufacturer_code: int = 0
    ecu_instance: int = 0
    function_instance: int = 0
    function: int = 0
    reserved: int = 0
    vehicle_system: int = 0
    vehicle_system_instance: int = 0
    industry_group: int = 0
    arbitrary_address_capable: bool = False

    def __post_init__(self) -> None:
        for fname, _pos, width in _NAME_LAYOUT:
            v = int(getattr(self, fname))
            if not 0 <= v < (1 << width):
                raise ValueError(f"NAME field {fname}={v} does not fit {width} bits")

    def to_int(self) -> int:
        """The NAME as an unsigned 64-bit integer."""
        value = 0
        for fname, pos, width in _NAME_LAYOUT:
            value |= (int(getattr(self, fname)) & ((1 << width) - 1)) << pos
        return value

    def to_bytes(self) -> bytes:
        """The 8 Address Claimed data bytes (least significant byte first)."""
        return self.to_int().to_bytes(8, "little")

    @classmethod
    def from_int(cls, value: int) -> Name:
        """Decode a 64-bit NAME value."""
        if not 0 <= value < (1 << 64):
            raise ValueError(f"NAME {value:#x} is not a 64-bit value")
        kw = {}
        for fname, pos, width in _NAME_LAYOUT:
            kw[fname] = (value >> pos) & ((1 << width) - 1)
        kw["arbitrary_address_capable"] = bool(kw["arbitrary_address_capable"])
        return cls(**kw)

    @classmethod
    def from_bytes(cls, data: bytes) -> Name:
        """Decode the 8 data bytes of an Address Claimed frame."""
        if len(data) != 8:
            raise ValueError(f"a NAME is 8 bytes, got {len(data)}")
        return cls.from_int(int.from_bytes(bytes(data), "little"))

    def describe(self) -> str:
        """One-line human summary, e.g. for ``tractionecu inspect``."""
        ig = INDUSTRY_GROUPS.get(self.industry_group, f"group {self.industry_group}")
        return (
            f"NAME 0x{self.to_int():016X}: function {self.function} "
            f"inst {self.function_instance}, ECU inst {self.ecu_instance}, "
            f"manufacturer {self.manufacturer_code}, identity {self.identity_number}, "
            f"vehicle system {self.vehicle_system} inst {self.vehicle_system_instance}, "
            f"industry {ig}, {'self-configurable' if self.arbitrary_address_capable else 'fixed address'}"
        )


def request_data(pgn: int) -> bytes:
    """The 3 data bytes of a Request (PGN 59904) for ``pgn``."""
    if not 0 <= pgn <= 0x3FFFF:
        raise ValueError(f"PGN {pgn} outside 0..0x3FFFF")
    return pgn.to_bytes(3, "little")


def requested_pgn(data: bytes) -> int:
    """The PGN asked for by a Request frame's data (first 3 bytes)."""
    if len(data) < 3:
        raise ValueError(f"a Request carries 3 bytes, got {len(data)}")
    return int.from_bytes(bytes(data[:3]), "little")
