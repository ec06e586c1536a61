"""PGN-based codec over the project DBC (``dbc/tractionecu.dbc``) and the owner's own DBCs.

J1939 decoding goes by parameter group number, not by CAN identifier: the
same PGN arrives from whatever source address the sending ECU claimed, and
PDU1 PGNs also carry a destination address.  :class:`Codec` therefore
indexes the DBC messages by PGN and ignores SA (and DA) when decoding.
The module stays whole (over 500 lines): loading, the not-available rule,
decoding, encoding and the owner's signal mapping all work on the one
table of messages and raw ranges that :class:`Codec` builds from the DBCs.

Units
-----
Physical values are SI as stated in the DBC: m/s for every speed (J1939's
km/h divided by 3.6), rad/s for angular speeds (engine speed too: J1939's
0.125 rpm/bit is π/240 rad/s per bit), m, N·m, N, and dimensionless; percentages
(percent torque, hitch position) stay in %.

Not available and error
-----------------------
A raw value outside the signal's valid raw range decodes as ``float('nan')``,
never as a number:

* **J1939 / ISO 11783 parameters** (signals with an ``SPN`` attribute) of 8,
  16, 24 or 32 unsigned bits: the valid range is the one SAE J1939-71 gives
  for the length, raw 0 to 0xFA, 0xFAFF, 0xFAFFFF, 0xFAFFFFFF; above it lie
  the parameter-specific, reserved, error (0xFE…) and not-available (0xFF…)
  codes.  This holds whatever minimum and maximum the DBC writes (DBCs often
  round the maximum, e.g. 250.996 km/h for raw 0xFAFF), and
  :attr:`SignalInfo.minimum` / :attr:`SignalInfo.maximum` are the physical
  ends of that raw range.  2- and 4-bit status fields keep their coded
  states (2 error, 3 not available).
* **Other signals**: the raw range from the DBC's ``[minimum|maximum]``
  (e.g. 0xFFFF in a 16-bit unsigned speed, 0x8000 in a signed proprietary
  signal lie outside it).  A DBC that writes ``[0|0]`` (no range, common in
  OEM files) gets the full raw range of the signal's length, less, for an
  unsigned signal of 8 bits or more, its all-ones code, which is "not
  available" as in J1939 (0xFFFF of an OEM's wheel speed decoded as 655 rpm,
  20× the real speed, and its μ was marked valid).  IEEE float
  signals are taken as they are.

Encoding a NaN or a missing signal writes the all-ones raw code (0x8000 for
signed signals) so receivers see "not available".

Multi-packet messages
---------------------
A message longer than 8 bytes (EC1, 40 bytes) travels with the J1939-21
transport protocol (:mod:`.transport`).  Its payload may be shorter than the
DBC's length (an older revision of the standard sends fewer bytes) or
longer; :meth:`Codec.decode` pads it with 0xFF ("not available") or cuts it
to the DBC's length.  Messages of up to 8 bytes must have their exact length.

The owner's own DBCs
--------------------
``Codec(extra=[...])`` loads further DBC files beside the built-in one: their
messages are decoded by PGN like the others.  Their signals are named
``Message.Signal`` (the owner's files may repeat a signal name in several
messages), so a recording holds them under those names and a ``[signals]``
table maps them onto the contract names (:meth:`Codec.resolve_mapping`).  A
PGN or a message name defined twice is a :class:`ConfigError` naming both
files.  An extra DBC's messages with an 11-bit identifier (CAN 2.0A: a
CANedge logger's GNSS/IMU frames, an implement's or a retrofit sensor's own
bus) are decoded by that identifier: they have no PGN (``pgn`` None,
``std_id`` the identifier) and no source address.  Multiplexed messages, and
a message name defined again on another identifier (the first definition is
decoded), are skipped and listed in :attr:`Codec.skipped`.

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
from contextlib import contextmanager
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Iterator, Mapping, Sequence

import cantools

from ..errors import ConfigError, DecodeError, UnknownFrame
from . import j1939

log = logging.getLogger(__name__)

_SKIP_LOGGED: set[tuple] = set()
"""(DBC file, reason, messages) already logged as skipped: a DBC loaded again (the ``--dbc`` codec of each
recording read) logs its skipped messages once."""

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
    "EstimateStatusExt",
)
"""Contract estimator output signals (dimensionless; EstimateStatus and EstimateStatusExt, its bits 16–23,
are bit fields)."""

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


UNIT_SI = {
    "m/s": 1.0, "km/h": 1.0 / 3.6, "kph": 1.0 / 3.6, "mph": 0.44704,
    "N": 1.0, "kN": 1000.0, "daN": 10.0,
    "Nm": 1.0, "N.m": 1.0, "N·m": 1.0, "kNm": 1000.0,
    "rad/s": 1.0, "rpm": math.pi / 30.0, "1/min": math.pi / 30.0, "U/min": math.pi / 30.0,
    "m": 1.0, "mm": 1e-3, "cm": 1e-2,
}
"""Units an owner's DBC may give its signals in, with their factor to SI; each group one quantity."""
_UNIT_KIND = {u: k for k, us in {"speed": ("m/s", "km/h", "kph", "mph"), "force": ("N", "kN", "daN"),
                                  "torque": ("Nm", "N.m", "N·m", "kNm"),
                                  "rotational speed": ("rad/s", "rpm", "1/min", "U/min"),
                                  "length": ("m", "mm", "cm")}.items()
              for u in us}


UNIT_ALIASES = {"rev/min": "rpm", "r/min": "rpm", "min-1": "rpm", "min^-1": "rpm", "1/min": "rpm",
                "kmh": "km/h", "km/hr": "km/h", "kmph": "km/h", "m/sec": "m/s", "newton": "N",
                "nm": "Nm", "n m": "Nm", "n*m": "Nm", "knm": "kNm"}
"""Other spellings of the units of :data:`UNIT_SI`, matched without regard to case."""
_UNIT_FOLD = {**{u.lower(): u for u in UNIT_SI if u.lower() != "kn"}, **UNIT_ALIASES}
# "kn" is the knot as often as the kilonewton: only "kN" and "KN" (no speed is written so) are taken for it
_UNIT_FOLD_EXACT = {"KN": "kN"}


def _unit(u: str) -> str | None:
    """The :data:`UNIT_SI` name of a DBC unit string: exact, then without regard to case or through
    :data:`UNIT_ALIASES` (a DBC writes "RPM", "Km/h", "KN" as often as "rpm", "km/h", "kN"); None if unknown."""
    u = (u or "").strip()
    if u in UNIT_SI:
        return u
    return _UNIT_FOLD_EXACT.get(u) or _UNIT_FOLD.get(u.lower())


def unit_factor(src_unit: str, to_unit: str) -> float | None:
    """The factor from ``src_unit`` to ``to_unit`` when both are known units of one quantity
    (:data:`UNIT_SI`, any case, :data:`UNIT_ALIASES`), else None (unknown or blank units are not judged)."""
    a, b = _unit(src_unit), _unit(to_unit)
    if a is None or b is None or _UNIT_KIND[a] != _UNIT_KIND[b]:
        return None
    return UNIT_SI[a] / UNIT_SI[b]


def unit_kind(unit: str) -> str | None:
    """The quantity of a known unit (:data:`UNIT_SI`): speed, force, torque, rotational speed or
    length; None for an unknown or blank unit."""
    u = _unit(unit)
    return None if u is None else _UNIT_KIND[u]


@dataclass(frozen=True)
class SignalInfo:
    """Static description of one DBC signal.

    ``name`` is the key the codec decodes it under: the DBC name for the
    built-in DBC, ``Message.Signal`` for an extra DBC (``dbc_name`` is the
    name in the file).  ``raw_min``/``raw_max`` bound the valid raw range
    (module doc: the J1939 range for SPN signals, else the DBC
    minimum/maximum); ``raw_na`` is the raw code written for "not available".
    """

    name: str
    message: str
    pgn: int | None
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
    spn: int | None = None
    dbc_name: str = ""
    is_float: bool = False

    @property
    def resolution(self) -> float:
        """Quantisation step in physical units (= scale)."""
        return abs(self.scale)


@dataclass(frozen=True)
class MessageInfo:
    """Static description of one DBC message (parameter group); ``source`` is the DBC file's name.  A message
    of an owner's DBC on an 11-bit identifier has ``pgn`` None and ``std_id`` its identifier."""

    name: str
    pgn: int | None
    priority: int
    default_sa: int
    default_da: int | None
    length: int
    cycle_time_s: float | None
    signals: tuple[str, ...]
    comment: str | None
    source: str = ""
    std_id: int | None = None

    @property
    def multi_packet(self) -> bool:
        """Longer than one CAN frame: sent with the J1939-21 transport protocol, any received length accepted."""
        return self.length > 8


J1939_VALID_MAX = {8: 0xFA, 16: 0xFAFF, 24: 0xFAFFFF, 32: 0xFAFFFFFF}
"""Largest valid raw value of an unsigned J1939 parameter of this many bits (SAE J1939-71 parameter ranges);
above it: parameter-specific indicators, reserved, error (0xFE..) and not available (0xFF..)."""


def _raw_bounds(sig) -> tuple[int, int, int]:
    full_lo = -(1 << (sig.length - 1)) if sig.is_signed else 0
    full_hi = (1 << (sig.length - 1)) - 1 if sig.is_signed else (1 << sig.length) - 1
    raw_na = -(1 << (sig.length - 1)) if sig.is_signed else (1 << sig.length) - 1
    if sig.spn and not sig.is_signed and sig.length in J1939_VALID_MAX:
        return 0, J1939_VALID_MAX[sig.length], raw_na
    scale = float(sig.scale)
    offset = float(sig.offset)
    lo_phys, hi_phys = sig.minimum, sig.maximum
    no_range = lo_phys is None and hi_phys is None        # cantools reads "[0|0]" so
    if no_range or (lo_phys is not None and hi_phys is not None and lo_phys == hi_phys) or scale == 0:  # no range
        # ... but for an unsigned value of a byte or more the all-ones code is "not available" (module doc)
        return full_lo, (full_hi - 1 if not sig.is_signed and sig.length >= 8 else full_hi), raw_na
    ends = [(x - offset) / scale if x is not None else None for x in (lo_phys, hi_phys)]
    if scale < 0:
        ends.reverse()
    raw_min = full_lo if ends[0] is None else max(full_lo, math.ceil(ends[0] - 1e-6))
    raw_max = full_hi if ends[1] is None else min(full_hi, math.floor(ends[1] + 1e-6))
    return raw_min, raw_max, raw_na


@contextmanager
def _quiet_cantools() -> Iterator[None]:
    """cantools' own warnings off while a DBC loads (the codec reports what it skips, once per file)."""
    lg = logging.getLogger("cantools.database")
    level = lg.level
    lg.setLevel(logging.ERROR)
    try:
        yield
    finally:
        lg.setLevel(level)


def _where(info: MessageInfo) -> str:
    """``PGN n`` of a J1939 message, ``11-bit ID 0x..`` of an owner's message on a standard identifier."""
    return f"PGN {info.pgn}" if info.pgn is not None else f"11-bit ID {info.std_id:#05x}"


def _signal_info(key: str, message: str, pgn: int | None, s) -> SignalInfo:
    """The :class:`SignalInfo` of cantools signal ``s`` decoded under ``key``."""
    if s.is_float:
        lo = float(s.minimum) if s.minimum is not None and s.minimum != s.maximum else -math.inf
        hi = float(s.maximum) if s.maximum is not None and s.minimum != s.maximum else math.inf
        return SignalInfo(key, message, pgn, float(s.scale), float(s.offset), lo, hi, s.unit or "", s.length,
                          True, 0, 0, 0, s.comment, s.spn, s.name, True)
    raw_min, raw_max, raw_na = _raw_bounds(s)
    ends = sorted((raw_min * s.scale + s.offset, raw_max * s.scale + s.offset))
    j1939 = bool(s.spn) and not s.is_signed and s.length in J1939_VALID_MAX
    minimum = float(s.minimum) if s.minimum is not None and s.minimum != s.maximum and not j1939 else ends[0]
    maximum = float(s.maximum) if s.maximum is not None and s.minimum != s.maximum and not j1939 else ends[1]
    return SignalInfo(key, message, pgn, float(s.scale), float(s.offset), minimum, maximum, s.unit or "", s.length,
                      s.is_signed, raw_min, raw_max, raw_na, s.comment, s.spn, s.name, False)


class Codec:
    """Encode and decode J1939 frames of the project DBC (and the owner's DBCs) by PGN.

    Parameters
    ----------
    path:
        The contract DBC; default :func:`default_dbc_path`.  Loaded with
        ``cantools.database.load_file(path, strict=True)``; it must hold
        every contract signal.
    extra:
        The owner's DBC files, loaded after it (module doc): their messages
        are added, their signals named ``Message.Signal``.

    Attributes
    ----------
    clip_counts:
        ``Counter`` of signal name -> number of values clipped to the
        signal's range by :meth:`encode` since construction.
    skipped:
        ``(file, message, reason)`` of the extra DBCs' messages not decoded.
    """

    def __init__(self, path: str | Path | None = None, extra: Sequence[str | Path] = ()) -> None:
        self.path = Path(path) if path is not None else default_dbc_path()
        self.extra_paths: tuple[Path, ...] = tuple(Path(x) for x in extra)
        self.messages: dict[str, MessageInfo] = {}
        self.signals: dict[str, SignalInfo] = {}
        self.skipped: list[tuple[str, str, str]] = []
        self._by_pgn: dict[int, MessageInfo] = {}
        self._by_std_id: dict[int, MessageInfo] = {}      # owner messages on 11-bit identifiers
        self._cmsg: dict[str, object] = {}
        self._keys: dict[str, dict[str, str]] = {}       # message -> {DBC signal name: decoded key}
        self.db = self._load(self.path, extra=False)
        missing = [n for n in CONTRACT_SIGNALS if n not in self.signals]
        if missing:
            raise ConfigError(f"dbc: contract signal(s) missing from {self.path}: {', '.join(missing)}")
        ours = {n for m in self.db.messages if any(s.name in OUTPUT_SIGNALS for s in m.signals) for n in m.senders}
        self.contract_inputs: tuple[str, ...] = tuple(
            n for m in self.messages.values() if m.pgn not in NETWORK_MANAGEMENT_PGNS
            and not ours & set(self.db.get_message_by_name(m.name).senders) for n in m.signals)
        """Signals of the contract DBC a ``[signals]`` table may map onto: every data signal but those of the
        messages the service sends (the estimate and the efficiency report)."""
        for x in self.extra_paths:
            self._load(x, extra=True)
        self.clip_counts: Counter[str] = Counter()

    def _load(self, path: Path, extra: bool):
        try:
            with _quiet_cantools():        # "Overwriting message ..." for a name on several identifiers: ours says it
                db = cantools.database.load_file(str(path), strict=not extra)
        except FileNotFoundError as exc:
            raise ConfigError(f"dbc: file not found: {path}") from exc
        except Exception as exc:  # cantools raises several unrelated types
            raise ConfigError(f"dbc: cannot load {path}: {exc}") from exc
        skipped: dict[str, list[str]] = {}
        for m in db.messages:
            std = not m.is_extended_frame
            again = std and extra and m.name in self.messages and self.messages[m.name].source == path.name
            if extra and (m.is_multiplexed() or again):
                why = "multiplexed (not decoded by PGN)" if m.is_multiplexed() else \
                    "defined again on another 11-bit identifier (the first is decoded)"
                self.skipped.append((path.name, m.name, why))
                names = skipped.setdefault(why, [])
                if m.name not in names:             # a DBC may define one name on several identifiers
                    names.append(m.name)
                continue
            if std and not extra:
                raise ConfigError(f"dbc: message {m.name} is not a 29-bit extended frame")
            cid = None if std else j1939.parse_id(m.frame_id)
            pgn = None if cid is None else cid.pgn
            twice = self._by_std_id.get(m.frame_id) if std else self._by_pgn.get(pgn)
            what = f"11-bit identifier {m.frame_id:#05x}" if std else f"PGN {pgn} ({pgn:#06x})"
            if twice is None and m.name in self.messages:
                twice, what = self.messages[m.name], f"message name {m.name}"
            if twice is not None:
                raise ConfigError(f"dbc: {what} defined twice: {twice.name} in {twice.source}, "
                                  f"{m.name} in {path.name}")
            keys = {s.name: (f"{m.name}.{s.name}" if extra else s.name) for s in m.signals}
            info = MessageInfo(
                name=m.name,
                pgn=pgn,
                priority=cid.priority if cid is not None else 0,
                default_sa=cid.sa if cid is not None else 0,
                default_da=cid.da if cid is not None else None,
                length=m.length,
                cycle_time_s=(m.cycle_time / 1000.0) if m.cycle_time else None,
                signals=tuple(keys.values()),
                comment=m.comment,
                source=path.name,
                std_id=m.frame_id if std else None,
            )
            for s in m.signals:
                if keys[s.name] in self.signals:
                    raise ConfigError(f"dbc: signal name {s.name} used in two messages")
            self.messages[m.name] = info
            if std:
                self._by_std_id[m.frame_id] = info
            else:
                self._by_pgn[pgn] = info
            self._cmsg[m.name] = m
            self._keys[m.name] = keys
            for s in m.signals:
                self.signals[keys[s.name]] = _signal_info(keys[s.name], m.name, pgn, s)
        for why, names in skipped.items():                    # one line per file and reason, once per process
            key = (str(path.resolve()), why, tuple(names))
            if key not in _SKIP_LOGGED:
                _SKIP_LOGGED.add(key)
                log.warning("dbc: %s: %d message(s) skipped, %s: %s", path.name, len(names), why, ", ".join(names))
        return db

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

    def message_for_std_id(self, can_id: int) -> MessageInfo | None:
        """Message description for an 11-bit identifier (an owner's DBC), or None."""
        return self._by_std_id.get(can_id)

    @property
    def has_std_ids(self) -> bool:
        """Whether any message is on an 11-bit identifier (an owner's DBC)."""
        return bool(self._by_std_id)

    def std_ids(self) -> list[int]:
        """Every 11-bit identifier of the owner's DBCs, ascending."""
        return sorted(self._by_std_id)

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

        An 11-bit frame is decoded by its identifier when an owner's DBC
        defines it.  Raises :class:`UnknownFrame` for an 11-bit frame or a
        PGN not in the DBCs, :class:`DecodeError` when the data length
        differs from the message's DLC.
        """
        if not is_extended:
            info = self._by_std_id.get(can_id)
            if info is None:
                exc = UnknownFrame(f"11-bit frame {can_id:#05x}: not in an owner's DBC (J1939 uses 29-bit IDs)")
                exc.pgn = None  # type: ignore[attr-defined]
                raise exc
            pgn = None
        else:
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
            if not info.multi_packet:
                raise DecodeError(
                    f"{info.name} ({_where(info)}): DLC {len(data)}, expected {info.length}"
                )
            data = data[: info.length].ljust(info.length, b"\xff")
        try:
            raw = self._cmsg[info.name].decode(  # type: ignore[attr-defined]
                data, decode_choices=False, scaling=False
            )
        except Exception as e:  # cantools.DecodeError and bitstruct errors
            raise DecodeError(f"{info.name} ({_where(info)}): {e}") from None
        keys = self._keys[info.name]
        out: dict[str, float] = {}
        for name, r in raw.items():
            key = keys[name]
            s = self.signals[key]
            if s.is_float:
                out[key] = float(r) * s.scale + s.offset
                continue
            r = int(r)
            if r < s.raw_min or r > s.raw_max:
                out[key] = math.nan
            else:
                out[key] = r * s.scale + s.offset
        return info.name, out

    def resolve(self, ref: str) -> str:
        """The decoded key of a signal reference ``Message.Signal`` (the DBC names) or a contract signal name.

        Raises :class:`KeyError` with a message naming what is missing.
        """
        msg, dot, sig = ref.partition(".")
        if not dot:
            if ref in self.signals and "." not in ref:
                return ref
            raise KeyError(f"{ref!r} is not a signal of {self.path.name}; write Message.Signal")
        info = self.messages.get(msg)
        if info is None:
            files = ", ".join(p.name for p in (self.path, *self.extra_paths))
            hint = ("" if self.extra_paths else "; add the owner's DBC (--dbc FILE for replay, inspect and "
                    "diagnose; dbc = [\"FILE\"] in the service's [can] table)")
            raise KeyError(f"no message {msg!r} in the loaded DBCs ({files}){hint}")
        key = self._keys[msg].get(sig)
        if key is None:
            raise KeyError(f"message {msg} ({info.source}) has no signal {sig!r} "
                           f"(it has {', '.join(self._keys[msg])})")
        return key

    def resolve_mapping(self, mapping: Mapping[str, tuple[str, float]], section: str = "signals"
                        ) -> list[tuple[str, str, float]]:
        """Check a ``[signals]`` table against the loaded DBCs.

        ``mapping`` maps a contract name (a data signal of the contract DBC,
        :attr:`contract_inputs`) to ``(Message.Signal, scale)``.  Returns
        ``[(contract name, decoded key of the source, scale)]`` in the table's
        order.  A :class:`ConfigError` names the key ``section.<name>`` of an
        unknown contract name, message or signal.
        """
        out = []
        used: dict[str, str] = {}
        for target, (ref, scale) in mapping.items():
            key = f"{section}.{target}"
            if target not in self.contract_inputs:
                raise ConfigError(f"{key}: not a contract signal (known: {', '.join(self.contract_inputs)})")
            try:
                src = self.resolve(ref)
            except KeyError as e:
                raise ConfigError(f"{key}: {e.args[0]}") from None
            if src in used:
                # a radar speed mapped onto the wheel-based speed's source made the slip read half its size
                raise ConfigError(f"{key}: {ref} is already {section}.{used[src]}; one measurement cannot be two "
                                  "contract signals")
            used[src] = target
            factor = unit_factor(self.signals[src].unit, self.signals[target].unit)
            kinds = unit_kind(self.signals[src].unit), unit_kind(self.signals[target].unit)
            if None not in kinds and kinds[0] != kinds[1] and float(scale) == 1.0:
                # a wheel speed in rpm mapped onto a drive torque was taken as N·m, without a word
                raise ConfigError(f"{key}: {ref} is a {kinds[0]} in {self.signals[src].unit}, {target} a "
                                  f"{kinds[1]} in {self.signals[target].unit}: map a {kinds[1]} signal, or give "
                                  f"the scale that converts one into the other ({target} = {{signal = \"{ref}\", "
                                  "scale = ...}})")
            if factor is not None and abs(factor - 1.0) > 1e-9 and float(scale) == 1.0:
                raise ConfigError(f"{key}: {ref} is in {self.signals[src].unit}, {target} in "
                                  f"{self.signals[target].unit}: give scale = {factor:.6g} "
                                  f"({target} = {{signal = \"{ref}\", scale = {factor:.6g}}})")
            if factor is not None and abs(factor - 1.0) > 1e-9 and abs(float(scale) * factor - 1.0) < 1e-3:
                # a scale from the target's unit to the source's: 9.549 for rpm → rad/s made ω 91× too large
                raise ConfigError(f"{key}: scale {float(scale):.6g} converts {self.signals[target].unit} to "
                                  f"{self.signals[src].unit}, the wrong way: {ref} in {self.signals[src].unit} "
                                  f"becomes {target} in {self.signals[target].unit} with scale = {factor:.6g}")
            out.append((target, src, float(scale)))
        return out

    # ------------------------------------------------------------------ encode
    def to_raw(self, signal: str, value: float | None) -> tuple[int, bool]:
        """Physical value -> (raw integer, clipped?).  None/NaN -> not-available code."""
        s = self.signals[signal]
        if s.is_float:
            raise ValueError(f"{signal}: encoding IEEE float signals is not supported")
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
        names = {v: k for k, v in self._keys[message_name].items()}
        data = self._cmsg[message_name].encode(  # type: ignore[attr-defined]
            {names[k]: r for k, r in raw.items()}, scaling=False, padding=True, strict=False
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
    """A shared Codec over the default DBC (loaded once), with the owner's DBCs inside :func:`extra_dbcs`."""
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = Codec()
    return _DEFAULT


@contextmanager
def extra_dbcs(paths: Sequence[str | Path] | None) -> Iterator[Codec]:
    """Within the block, :func:`default_codec` also decodes the owner's DBC files ``paths`` (none: unchanged).

    What the ``--dbc FILE`` options of ``tractionecu replay``, ``inspect`` and
    ``diagnose`` do: every recording read in the block gets the owner's messages.
    """
    global _DEFAULT
    before = default_codec()
    if paths:
        _DEFAULT = Codec(before.path, extra=[*before.extra_paths, *paths])
    try:
        yield default_codec()
    finally:
        _DEFAULT = before

