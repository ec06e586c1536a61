"""PGN-based codec over the project DBC (``dbc/tractionecu.dbc``).

J1939 decoding goes by parameter group number, not by CAN identifier: the
same PGN arrives from whatever source address the sending ECU claimed, and
PDU1 PGNs also carry a destination address.  :class:`Codec` therefore
indexes the DBC messages by PGN and ignores SA (and DA) when decoding.

Physical values are SI as stated in the DBC (m/s, m, rad/s, N·m, N,
dimensionless); percentages are in %.  J1939 "error / not available" raw
codes decode to NaN: a raw value outside the signal's DBC range
``[minimum, maximum]`` (e.g. 0xFFFF in a 16-bit unsigned speed, 0x8000 in
a signed proprietary signal) is reported as ``float('nan')``.  Encoding a
NaN or a missing signal writes the all-ones raw code (0x8000 for signed
signals) so receivers see "not available".

The DBC has one place, ``dbc/tractionecu.dbc`` at the top of the
repository, installed as the package ``tractionecu.contract`` (see
``pyproject.toml``); it is read from the installed package, normal or
editable, and from ``<repo>/dbc`` only when the source tree is imported
without being installed.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Mapping

import cantools

from ..errors import ConfigError, DecodeError, UnknownFrame
from . import j1939

log = logging.getLogger(__name__)

DBC_FILENAME = "tractionecu.dbc"

WHEELS = ("FL", "FR", "RL", "RR")
"""Wheel order everywhere: index 0..3, front = 0, 1."""

INPUT_SIGNALS: tuple[str, ...] = (
    *(f"WheelSpeed_{w}" for w in WHEELS),
    *(f"DriveTorque_{w}" for w in WHEELS),
    "FrontAxleLoad",
    "DraftForce",
)
"""Contract input signals: rad/s, N·m, N, N."""

OUTPUT_SIGNALS: tuple[str, ...] = (
    *(f"Adhesion_{w}" for w in WHEELS),
    "SoilRollingResistance",
    "CurveParamA",
    *(f"Slip_{w}" for w in WHEELS),
    "EstimateStatus",
)
"""Contract estimator output signals (dimensionless; EstimateStatus is a bit field)."""

CONTRACT_SIGNALS: tuple[str, ...] = INPUT_SIGNALS + OUTPUT_SIGNALS

NETWORK_MANAGEMENT_PGNS = frozenset({j1939.PGN_ADDRESS_CLAIMED, j1939.PGN_REQUEST})
"""PGNs that carry network management, not measured signals."""


def repo_dbc_path() -> Path:
    """``<repo>/dbc/tractionecu.dbc`` as seen from this source file (may not exist)."""
    return Path(__file__).resolve().parents[2] / "dbc" / DBC_FILENAME


def package_dbc_path() -> Path:
    """The DBC of the installed package ``tractionecu.contract`` (``dbc/`` of the repository)."""
    return Path(str(resources.files("tractionecu.contract").joinpath(DBC_FILENAME)))


def default_dbc_path() -> Path:
    """The installed contract DBC; ``<repo>/dbc`` when the package is not installed."""
    try:
        return package_dbc_path()
    except ModuleNotFoundError:
        return repo_dbc_path()


@dataclass(frozen=True)
class SignalInfo:
    """Static description of one DBC signal.

    ``raw_min``/``raw_max`` bound the valid raw range (from the DBC
    minimum/maximum); ``raw_na`` is the raw code written for "not available".
    """

    name: str
    message: str
    pgn: int
    scale: float
    offset: float
    minimum: float
    maximum: float
    unit: str
    length: int
    is_signed: bool
    raw_min: int
    raw_max: int
    raw_na: int
    comment: str | None

    @property
    def resolution(self) -> float:
        """Quantisation step in physical units (= scale)."""
        return abs(self.scale)


@dataclass(frozen=True)
class MessageInfo:
    """Static description of one DBC message (parameter group)."""

    name: str
    pgn: int
    priority: int
    default_sa: int
    default_da: int | None
    length: int
    cycle_time_s: float | None
    signals: tuple[str, ...]
    comment: str | None


def _raw_bounds(sig) -> tuple[int, int, int]:
    full_lo = -(1 << (sig.length - 1)) if sig.is_signed else 0
    full_hi = (1 << (sig.length - 1)) - 1 if sig.is_signed else (1 << sig.length) - 1
    scale = float(sig.scale)
    offset = float(sig.offset)
    lo_phys = sig.minimum if sig.minimum is not None else None
    hi_phys = sig.maximum if sig.maximum is not None else None
    if lo_phys is None:
        raw_min = full_lo
    else:
        raw_min = max(full_lo, math.ceil((lo_phys - offset) / scale - 1e-6))
    if hi_phys is None:
        raw_max = full_hi
    else:
        raw_max = min(full_hi, math.floor((hi_phys - offset) / scale + 1e-6))
    raw_na = -(1 << (sig.length - 1)) if sig.is_signed else (1 << sig.length) - 1
    return raw_min, raw_max, raw_na


class Codec:
    """Encode and decode J1939 frames of the project DBC by PGN.

    Parameters
    ----------
    path:
        DBC file; default :func:`default_dbc_path`.  Loaded with
        ``cantools.database.load_file(path, strict=True)``.

    Attributes
    ----------
    clip_counts:
        ``Counter`` of signal name -> number of values clipped to the
        signal's range by :meth:`encode` since construction.
    """

    def __init__(self, path: str | Path | None = None) -> None:
        self.path = Path(path) if path is not None else default_dbc_path()
        try:
            self.db = cantools.database.load_file(str(self.path), strict=True)
        except FileNotFoundError as exc:
            raise ConfigError(f"dbc: file not found: {self.path}") from exc
        except Exception as exc:  # cantools raises several unrelated types
            raise ConfigError(f"dbc: cannot load {self.path}: {exc}") from exc

        self.messages: dict[str, MessageInfo] = {}
        self.signals: dict[str, SignalInfo] = {}
        self._by_pgn: dict[int, MessageInfo] = {}
        self._cmsg: dict[str, object] = {}
        for m in self.db.messages:
            if not m.is_extended_frame:
                raise ConfigError(f"dbc: message {m.name} is not a 29-bit extended frame")
            cid = j1939.parse_id(m.frame_id)
            if cid.pgn in self._by_pgn:
                raise ConfigError(
                    f"dbc: PGN {cid.pgn} defined twice ({self._by_pgn[cid.pgn].name}, {m.name})"
                )
            info = MessageInfo(
                name=m.name,
                pgn=cid.pgn,
                priority=cid.priority,
                default_sa=cid.sa,
                default_da=cid.da,
                length=m.length,
                cycle_time_s=(m.cycle_time / 1000.0) if m.cycle_time else None,
                signals=tuple(s.name for s in m.signals),
                comment=m.comment,
            )
            self.messages[m.name] = info
            self._by_pgn[cid.pgn] = info
            self._cmsg[m.name] = m
            for s in m.signals:
                if s.name in self.signals:
                    raise ConfigError(f"dbc: signal name {s.name} used in two messages")
                raw_min, raw_max, raw_na = _raw_bounds(s)
                self.signals[s.name] = SignalInfo(
                    name=s.name,
                    message=m.name,
                    pgn=cid.pgn,
                    scale=float(s.scale),
                    offset=float(s.offset),
                    minimum=float(s.minimum) if s.minimum is not None else raw_min * s.scale + s.offset,
                    maximum=float(s.maximum) if s.maximum is not None else raw_max * s.scale + s.offset,
                    unit=s.unit or "",
                    length=s.length,
                    is_signed=s.is_signed,
                    raw_min=raw_min,
                    raw_max=raw_max,
                    raw_na=raw_na,
                    comment=s.comment,
                )
        missing = [n for n in CONTRACT_SIGNALS if n not in self.signals]
        if missing:
            raise ConfigError(f"dbc: contract signal(s) missing from {self.path}: {', '.join(missing)}")
        self.clip_counts: Counter[str] = Counter()

    # ------------------------------------------------------------------ lookup
    def message(self, name: str) -> MessageInfo:
        """Message description by name; KeyError if absent."""
        try:
            return self.messages[name]
        except KeyError:
            raise UnknownFrame(f"no message named {name!r} in {self.path.name}") from None

    def message_for_pgn(self, pgn: int) -> MessageInfo | None:
        """Message description for a PGN, or None if the DBC lacks it."""
        return self._by_pgn.get(pgn)

    def message_for_id(self, can_id: int) -> MessageInfo | None:
        """Message description for a 29-bit ID (any SA/DA), or None."""
        return self._by_pgn.get(j1939.parse_id(can_id).pgn)

    def pgns(self) -> list[int]:
        """Every PGN in the DBC, ascending."""
        return sorted(self._by_pgn)

    def signal_names(self, which: str = "contract") -> list[str]:
        """Signal names.

        ``which``: ``"contract"`` (inputs + outputs of the contract, in
        contract order), ``"inputs"``, ``"outputs"``, ``"data"`` (every
        signal except network management), ``"all"`` (every DBC signal).
        """
        if which == "contract":
            return list(CONTRACT_SIGNALS)
        if which == "inputs":
            return list(INPUT_SIGNALS)
        if which == "outputs":
            return list(OUTPUT_SIGNALS)
        if which in ("data", "all"):
            out = []
            for m in self.messages.values():
                if which == "data" and m.pgn in NETWORK_MANAGEMENT_PGNS:
                    continue
                out.extend(m.signals)
            return out
        raise ValueError(f"which={which!r}: expected contract, inputs, outputs, data or all")

    # ------------------------------------------------------------------ decode
    def decode(
        self, can_id: int, data: bytes, is_extended: bool = True
    ) -> tuple[str, dict[str, float]]:
        """Decode one frame by its PGN, whatever its source/destination address.

        Returns ``(message_name, {signal: physical value})`` with values in
        the DBC units; not-available / error codes give NaN.

        Raises :class:`UnknownFrame` for an 11-bit frame or a PGN not in the
        DBC, :class:`DecodeError` when the data length differs from the
        message's DLC.
        """
        if not is_extended:
            exc = UnknownFrame(f"11-bit frame {can_id:#05x}: J1939 uses 29-bit IDs only")
            exc.pgn = None  # type: ignore[attr-defined]
            raise exc
        try:
            pgn = j1939.parse_id(can_id).pgn
        except ValueError as e:
            raise DecodeError(str(e)) from None
        info = self._by_pgn.get(pgn)
        if info is None:
            exc = UnknownFrame(f"PGN {pgn} ({pgn:#06x}) not in {self.path.name}")
            exc.pgn = pgn  # type: ignore[attr-defined]
            raise exc
        data = bytes(data)
        if len(data) != info.length:
            raise DecodeError(
                f"{info.name} (PGN {pgn}): DLC {len(data)}, expected {info.length}"
            )
        try:
            raw = self._cmsg[info.name].decode(  # type: ignore[attr-defined]
                data, decode_choices=False, scaling=False
            )
        except Exception as e:  # cantools.DecodeError and bitstruct errors
            raise DecodeError(f"{info.name} (PGN {pgn}): {e}") from None
        out: dict[str, float] = {}
        for name, r in raw.items():
            s = self.signals[name]
            r = int(r)
            if r < s.raw_min or r > s.raw_max:
                out[name] = math.nan
            else:
                out[name] = r * s.scale + s.offset
        return info.name, out

    # ------------------------------------------------------------------ encode
    def to_raw(self, signal: str, value: float | None) -> tuple[int, bool]:
        """Physical value -> (raw integer, clipped?).  None/NaN -> not-available code."""
        s = self.signals[signal]
        if value is None or (isinstance(value, float) and math.isnan(value)):
            return s.raw_na, False
        v = float(value)
        if math.isnan(v):
            return s.raw_na, False
        if math.isinf(v):
            return (s.raw_max if v > 0 else s.raw_min), True
        r = math.floor((v - s.offset) / s.scale + 0.5)
        if r < s.raw_min:
            return s.raw_min, True
        if r > s.raw_max:
            return s.raw_max, True
        return r, False

    def encode(
        self,
        message_name: str,
        values: Mapping[str, float | None],
        sa: int | None = None,
        priority: int | None = None,
        da: int | None = None,
        clipped: list[str] | None = None,
    ) -> tuple[int, bytes]:
        """Encode a message; returns ``(29-bit can_id, data bytes)``.

        ``values`` maps signal names to physical values (DBC units).  A
        signal absent from ``values`` or given as None/NaN is sent as "not
        available".  Values outside the DBC range are clipped to it (±inf
        included); each clipped signal name is appended to ``clipped`` (if
        given), counted in :attr:`clip_counts` and logged at DEBUG level.
        Unused bits are set to 1 as J1939 requires.  ``sa``/``priority``/``da``
        default to the DBC identifier's.  Unknown signal names raise KeyError.
        """
        info = self.message(message_name)
        unknown = [k for k in values if k not in info.signals]
        if unknown:
            raise KeyError(f"{message_name} has no signal(s) {', '.join(unknown)}")
        raw: dict[str, int] = {}
        for name in info.signals:
            r, was_clipped = self.to_raw(name, values.get(name))
            raw[name] = r
            if was_clipped:
                self.clip_counts[name] += 1
                if clipped is not None:
                    clipped.append(name)
                log.debug("clipped %s=%r to DBC range", name, values.get(name))
        data = self._cmsg[message_name].encode(  # type: ignore[attr-defined]
            raw, scaling=False, padding=True, strict=False
        )
        can_id = j1939.make_id(
            info.priority if priority is None else priority,
            info.pgn,
            info.default_sa if sa is None else sa,
            (info.default_da if da is None else da) if j1939.is_pdu1(info.pgn) else None,
        )
        return can_id, bytes(data)

    def quantize(self, signal: str, value: float) -> float:
        """The physical value a receiver would decode after :meth:`encode` (clipped, quantised)."""
        r, _ = self.to_raw(signal, value)
        s = self.signals[signal]
        if r < s.raw_min or r > s.raw_max:
            return math.nan
        return r * s.scale + s.offset

    def nominal_period_s(self, message_name: str) -> float | None:
        """Nominal transmission period [s] from GenMsgCycleTime, or None."""
        return self.message(message_name).cycle_time_s


_DEFAULT: Codec | None = None


def default_codec() -> Codec:
    """A shared Codec over the default DBC (loaded once)."""
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = Codec()
    return _DEFAULT

