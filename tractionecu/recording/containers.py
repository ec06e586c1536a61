"""The decoded recording: signal series, the GNSS track, statistics, resampled tables.

See :mod:`.reader` for the recording format.  All times are epoch seconds
[s]; values are in the DBC's SI units.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import numpy as np

from ..bus import j1939
from ..errors import RecordingError

CAN_FILE = "can.log"
GPS_FILE = "gps.nmea"
VEHICLE_FILE = "vehicle.toml"
TRUTH_CSV = "truth.csv"
TRUTH_TOML = "truth.toml"

GAP_FACTOR = 3.0
"""A gap is an interval between two frames of a message longer than this × its nominal period."""

TIME_JUMP_S = 60.0
"""A silence between two consecutive CAN frames longer than this [s] is reported as a time jump."""

MAX_TABLE_ROWS = 50_000_000
"""Largest zero-order-hold table (rows) :meth:`Recording.table` builds: 5.8 days at 100 Hz."""

GPS_FIELDS = ("lat", "lon", "alt", "speed", "course", "fix_quality", "hdop", "nsat", "valid")
"""Per-epoch fields of :class:`GpsTrack` besides ``t``."""


@dataclass
class Series:
    """Samples of one signal at its native rate.

    ``t`` epoch time [s] (non-decreasing), ``value`` in the signal's unit
    (NaN = not available), ``sa`` source address per sample (-1 if unknown,
    e.g. imported from CSV).
    """

    t: np.ndarray
    value: np.ndarray
    sa: np.ndarray
    unit: str = ""

    def __len__(self) -> int:
        return int(self.t.size)


def _code(v: object) -> int:
    """A fix-quality or satellite-count value as an int16 code: -1 (unknown) for None,
    NaN, ±inf or anything outside 0..32767."""
    if v is None:
        return -1
    try:
        f = float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError, OverflowError):
        return -1
    return int(f) if 0.0 <= f <= 32767.0 else -1


@dataclass
class GpsTrack:
    """GPS epochs as parallel arrays.

    ``t`` epoch [s]; ``lat``/``lon`` [deg WGS84]; ``alt`` [m MSL];
    ``speed`` [m/s]; ``course`` [deg from true north]; ``fix_quality``
    (GGA code, -1 unknown); ``hdop`` [-]; ``nsat`` (-1 unknown); ``valid``
    the receiver's RMC status (1 valid ``A``, 0 invalid ``V``, -1 unknown).
    Missing float fields are NaN.
    """

    t: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    alt: np.ndarray
    speed: np.ndarray
    course: np.ndarray
    fix_quality: np.ndarray
    hdop: np.ndarray
    nsat: np.ndarray
    valid: np.ndarray

    def __len__(self) -> int:
        return int(self.t.size)

    @classmethod
    def empty(cls) -> GpsTrack:
        """A track with no epochs."""
        f = np.empty(0, dtype=float)
        i = np.empty(0, dtype=np.int16)
        return cls(f, f.copy(), f.copy(), f.copy(), f.copy(), f.copy(), i, f.copy(), i.copy(), np.empty(0, np.int8))

    @classmethod
    def from_columns(cls, cols: dict[str, list]) -> GpsTrack:
        """Build from lists keyed by ``t`` and :data:`GPS_FIELDS` (None -> NaN / -1)."""

        def fa(key: str) -> np.ndarray:
            return np.array([np.nan if v is None else float(v) for v in cols.get(key, [])], dtype=float)

        def ia(key: str) -> np.ndarray:
            return np.array([_code(v) for v in cols.get(key, [])], dtype=np.int16)

        n = len(cols.get("t", []))
        out = cls(
            t=fa("t"),
            lat=fa("lat"),
            lon=fa("lon"),
            alt=fa("alt"),
            speed=fa("speed"),
            course=fa("course"),
            fix_quality=ia("fix_quality"),
            hdop=fa("hdop"),
            nsat=ia("nsat"),
            valid=np.array([-1 if v is None else int(bool(v)) for v in cols.get("valid", [])], dtype=np.int8),
        )
        for k in GPS_FIELDS:
            arr = getattr(out, k)
            if arr.size != n:
                setattr(out, k, np.full(n, -1 if arr.dtype.kind == "i" else np.nan, dtype=arr.dtype))
        return out


@dataclass
class AddressClaim:
    """An Address Claimed frame (PGN 60928): source address, NAME, first time [s], count, first line."""

    sa: int
    name: j1939.Name
    t_first: float
    count: int
    lineno: int


STD_SA = -1
"""The source address recorded for a frame on an 11-bit identifier (an owner's DBC): CAN 2.0A has none."""


@dataclass
class MessageStats:
    """Frame count, time span [s], mean rate [Hz], nominal period [s] and gaps of one message (``std_id``: its
    11-bit identifier, for an owner's message that has no PGN)."""

    name: str
    pgn: int | None
    count: int = 0
    t_first: float = math.nan
    t_last: float = math.nan
    nominal_period_s: float | None = None
    gaps: list[tuple[float, float]] = field(default_factory=list)
    """(start time [s], length [s]) of the first gaps longer than GAP_FACTOR × nominal period."""
    n_gaps: int = 0
    max_interval_s: float = 0.0
    sources: Counter = field(default_factory=Counter)
    std_id: int | None = None

    @property
    def rate_hz(self) -> float:
        """Mean frame rate over the message's own span [Hz] (NaN below 2 frames)."""
        span = self.t_last - self.t_first
        if self.count < 2 or not span > 0:
            return math.nan
        return (self.count - 1) / span


MAX_UNKNOWN_PGN_SOURCES = 1024
"""Unknown PGNs whose source addresses are kept (:meth:`RecordingStats.add_unknown_sources`); a real bus
carries a few dozen."""


@dataclass
class RecordingStats:
    """Everything counted while reading.

    ``files`` maps a file name to its line statistics (``ReadStats``,
    ``NmeaStats`` or the CSV importer's counter; each has ``rejected``,
    ``examples`` and ``describe()``).
    """

    files: dict[str, object] = field(default_factory=dict)
    messages: dict[str, MessageStats] = field(default_factory=dict)
    unknown_pgns: Counter = field(default_factory=Counter)
    unknown_pgn_sources: dict[int, set[int]] = field(default_factory=dict)
    decode_errors: Counter = field(default_factory=Counter)
    decode_error_lines: dict[str, list[int]] = field(default_factory=dict)
    non_extended_frames: int = 0
    address_claims: list[AddressClaim] = field(default_factory=list)
    gps_epochs: int = 0
    gps_alignment: str = ""
    can_t_first: float = math.nan
    """Time of the first accepted CAN frame [s] (any PGN)."""
    can_t_last: float = math.nan
    """Time of the last accepted CAN frame [s] (any PGN)."""
    can_format: str = ""
    """Capture format of the CAN file (:data:`.formats.FORMATS`, with the candump screen time mode)."""
    clock_offset_s: float = 0.0
    """Offset [s] added to every CAN time to put it on GNSS time (0 when the clocks were left alone)."""
    clock_sigma_s: float = math.nan
    """Standard deviation [s] of ``clock_offset_s`` when it was estimated."""
    clock_note: str = ""
    """How the CAN and GNSS clocks were reconciled, or why they could not be (:mod:`.clock`)."""
    time_jumps: list[tuple[float, float]] = field(default_factory=list)
    """(time [s], length [s]) of the first jumps forward between consecutive CAN frames over TIME_JUMP_S."""
    n_time_jumps: int = 0
    source_used: dict[str, int] = field(default_factory=dict)
    """The source address whose frames give a message's signals: the first one seen (J1939: one PGN sent by two
    ECUs is two measurements, and their samples interleaved are neither)."""
    other_sources: dict[str, Counter] = field(default_factory=dict)
    """Frames of a message from another source address than :attr:`source_used`, by address: decoded and
    counted (the message's ``sources``), their signals not used."""

    @property
    def unknown_frames(self) -> int:
        """Frames skipped because their PGN is not in the DBC."""
        return sum(self.unknown_pgns.values())

    def add_unknown_sources(self, pgn: int, sources: Iterable[int]) -> None:
        """The source addresses of an unknown PGN's frames, for the first :data:`MAX_UNKNOWN_PGN_SOURCES` unknown
        PGNs (a flood of random identifiers sends up to 2¹⁸ PGNs from 256 addresses each: tens of millions of
        entries); later ones are counted in :attr:`unknown_pgns` without their sources."""
        have = self.unknown_pgn_sources.get(pgn)
        if have is None:
            if len(self.unknown_pgn_sources) >= MAX_UNKNOWN_PGN_SOURCES:
                return
            have = self.unknown_pgn_sources[pgn] = set()
        have.update(sources)


@dataclass
class Table:
    """Signals resampled onto a fixed grid by zero-order hold.

    ``t`` grid [s]; ``values[name]`` the latest sample at or before each
    grid time (NaN before the first sample); ``age[name]`` the time since
    that sample [s] (+inf before the first sample).
    """

    t: np.ndarray
    values: dict[str, np.ndarray]
    age: dict[str, np.ndarray]

    def __getitem__(self, name: str) -> np.ndarray:
        return self.values[name]

    def __contains__(self, name: object) -> bool:
        return name in self.values

    def keys(self) -> list[str]:
        """Column names."""
        return list(self.values)

    def __len__(self) -> int:
        return int(self.t.size)


def _zoh(src_t: np.ndarray, src_v: np.ndarray, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    idx = np.searchsorted(src_t, grid, side="right") - 1
    ok = idx >= 0
    safe = np.where(ok, idx, 0)
    if src_v.size == 0:
        return np.full(grid.size, np.nan), np.full(grid.size, np.inf)
    val = np.where(ok, src_v[safe].astype(float), np.nan)
    age = np.where(ok, grid - src_t[safe], np.inf)
    return val, age


@dataclass
class Recording:
    """A decoded recording (see module docstring).

    ``signals`` maps each signal name (DBC signals for candump recordings)
    to its :class:`Series`; ``gps`` holds the aligned GPS epochs;
    ``signal_sources`` says where a signal came from (its DBC message, or
    ``Message.Signal × scale`` for one mapped by a ``[signals]`` table).
    """

    path: Path
    signals: dict[str, Series]
    gps: GpsTrack
    stats: RecordingStats
    vehicle_toml_path: Path | None = None
    truth_csv_path: Path | None = None
    truth_toml_path: Path | None = None
    units: dict[str, str] = field(default_factory=dict)
    signal_sources: dict[str, str] = field(default_factory=dict)

    @property
    def t_start(self) -> float:
        """Earliest time [s] over signals, GPS and accepted CAN frames of any PGN (NaN if none)."""
        firsts = [s.t[0] for s in self.signals.values() if len(s)]
        if len(self.gps):
            firsts.append(self.gps.t[0])
        if math.isfinite(self.stats.can_t_first):
            firsts.append(self.stats.can_t_first)
        return float(min(firsts)) if firsts else math.nan

    @property
    def t_end(self) -> float:
        """Latest time [s] over signals, GPS and accepted CAN frames of any PGN (NaN if none)."""
        lasts = [s.t[-1] for s in self.signals.values() if len(s)]
        if len(self.gps):
            lasts.append(self.gps.t[-1])
        if math.isfinite(self.stats.can_t_last):
            lasts.append(self.stats.can_t_last)
        return float(max(lasts)) if lasts else math.nan

    @property
    def duration(self) -> float:
        """t_end − t_start [s]."""
        return self.t_end - self.t_start

    def table(
        self,
        rate_hz: float,
        t0: float | None = None,
        t1: float | None = None,
        names: Iterable[str] | None = None,
        include_gps: bool = True,
    ) -> Table:
        """Zero-order-hold table on the grid ``t0 + k / rate_hz`` up to ``t1``.

        Defaults: ``t0``/``t1`` the recording's first/last sample, every
        signal and the GPS columns ``gps_lat, gps_lon, gps_alt, gps_speed,
        gps_course, gps_fix_quality, gps_hdop, gps_nsat``.  Each column has
        a matching age array [s].
        """
        if not rate_hz > 0:
            raise ValueError(f"rate_hz={rate_hz} must be positive")
        a = self.t_start if t0 is None else float(t0)
        b = self.t_end if t1 is None else float(t1)
        if not (math.isfinite(a) and math.isfinite(b)) or b < a:
            grid = np.empty(0)
        else:
            # 1e-3 step of tolerance: epoch times near 1.7e9 s carry ~2e-7 s of rounding
            n = int(math.floor((b - a) * rate_hz + 1e-3)) + 1
            if n > MAX_TABLE_ROWS:
                raise RecordingError(
                    f"{self.path}: a table of {b - a:.0f} s at {rate_hz} Hz needs {n} rows (limit {MAX_TABLE_ROWS}); "
                    "the recording's time jumps (see `tractionecu inspect`): pass t0/t1 or a lower rate")
            grid = a + np.arange(n) / rate_hz
        values: dict[str, np.ndarray] = {}
        ages: dict[str, np.ndarray] = {}
        for name in (self.signals if names is None else names):
            s = self.signals[name]
            values[name], ages[name] = _zoh(s.t, s.value, grid)
        if include_gps:
            for k in GPS_FIELDS:
                values[f"gps_{k}"], ages[f"gps_{k}"] = _zoh(self.gps.t, getattr(self.gps, k), grid)
        return Table(grid, values, ages)
