"""Read a recording directory into time-aligned signal series.

A recording is a directory (see ``docs/architecture.md``)::

    can.log      candump -L lines                     (required)
    gps.nmea     raw NMEA 0183 lines                  (optional)
    vehicle.toml nominal VehicleParams                (path kept, not parsed here)
    truth.csv    simulated truth                      (path kept)
    truth.toml   scenario, seed, effects              (path kept)

``read_recording`` also accepts the path of a candump file alone.

CAN decoding
------------
Frames are decoded in bulk (:mod:`.fastdecode`), with the same results as
frame by frame (:func:`read_can_per_frame`).  Every 29-bit frame is decoded by its PGN through :class:`~tractionecu.bus.dbc.Codec`,
whatever its source (and, for PDU1, destination) address.  Frames whose
PGN the DBC lacks are skipped and counted per PGN (with the source
addresses seen); frames of a known PGN with the wrong DLC are skipped and
counted per message; 11-bit frames are counted and skipped.  Address
Claimed frames (PGN 60928) are listed with source address and decoded
NAME.  Lines the candump reader rejects (garbage, truncated, bad hex,
DLC > 8, time going backwards, ...) are counted by reason with the first
line numbers.

GPS time alignment
------------------
candump time is host epoch time [s] (POSIX, UTC without leap seconds).
NMEA carries UTC time of day in GGA/RMC/GNS/ZDA and the UTC date only in
RMC and ZDA.  Sentences are grouped into receiver epochs by identical
time of day.  Each epoch gets a UTC calendar date as follows:

1. A day counter starts at 0 and increments whenever the time of day
   drops by more than 12 h from the previous epoch (midnight rollover).
2. If any epoch carries a date (RMC or ZDA), that date anchors the day
   counter; epochs before the first dated epoch get the anchor date minus
   their day difference, and each later dated epoch re-anchors.
3. Without any date in the file, the date is taken from the first CAN
   frame's epoch time: of the UTC dates one day before, on and after it,
   the one that puts the first GPS epoch nearest the first CAN frame wins
   (so a capture that starts just before or after midnight is placed on
   the right day).

The epoch time is then ``timegm(date) + time_of_day``.  An epoch not later
than its predecessor is rejected and counted (``time_backwards`` or
``duplicate_epoch``).  The result is only as good as the logging host's
clock discipline (NTP/PPS) plus the receiver's output latency; neither is
compensated here.

All series times are epoch seconds [s]; values are in the DBC's SI units.
"""

from __future__ import annotations

import calendar
import math
from collections import Counter
from dataclasses import dataclass, field
from datetime import date, datetime, timedelta, timezone
from pathlib import Path
from typing import Iterable

import numpy as np

from ..bus import j1939
from ..bus.candump import ReadStats, read_candump
from ..bus.dbc import NETWORK_MANAGEMENT_PGNS, Codec, default_codec
from ..errors import DecodeError, RecordingError, UnknownFrame
from ..gnss.nmea import EpochAssembler, GpsFix, NmeaStats, iter_nmea

CAN_FILE = "can.log"
GPS_FILE = "gps.nmea"
VEHICLE_FILE = "vehicle.toml"
TRUTH_CSV = "truth.csv"
TRUTH_TOML = "truth.toml"

GAP_FACTOR = 3.0
"""A gap is an interval between two frames of a message longer than this × its nominal period."""

MAX_EXAMPLES = 5

MAX_TABLE_ROWS = 50_000_000
"""Largest zero-order-hold table (rows) :meth:`Recording.table` builds: 5.8 days at 100 Hz."""

GPS_FIELDS = ("lat", "lon", "alt", "speed", "course", "fix_quality", "hdop", "nsat")


# --------------------------------------------------------------------------- containers
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
    (GGA code, -1 unknown); ``hdop`` [-]; ``nsat`` (-1 unknown).  Missing
    float fields are NaN.
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

    def __len__(self) -> int:
        return int(self.t.size)

    @classmethod
    def empty(cls) -> GpsTrack:
        """A track with no epochs."""
        f = np.empty(0, dtype=float)
        i = np.empty(0, dtype=np.int16)
        return cls(f, f.copy(), f.copy(), f.copy(), f.copy(), f.copy(), i, f.copy(), i.copy())

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


@dataclass
class MessageStats:
    """Frame count, time span [s], mean rate [Hz], nominal period [s] and gaps of one message."""

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

    @property
    def rate_hz(self) -> float:
        """Mean frame rate over the message's own span [Hz] (NaN below 2 frames)."""
        span = self.t_last - self.t_first
        if self.count < 2 or not span > 0:
            return math.nan
        return (self.count - 1) / span


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

    @property
    def unknown_frames(self) -> int:
        """Frames skipped because their PGN is not in the DBC."""
        return sum(self.unknown_pgns.values())

    def rejected_lines(self) -> dict[tuple[str, str], int]:
        """(file, reason) -> number of rejected lines."""
        out: dict[tuple[str, str], int] = {}
        for fname, st in self.files.items():
            for reason, n in getattr(st, "rejected", {}).items():
                out[(fname, reason)] = int(n)
        return out


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
    to its :class:`Series`; ``gps`` holds the aligned GPS epochs.
    """

    path: Path
    signals: dict[str, Series]
    gps: GpsTrack
    stats: RecordingStats
    vehicle_toml_path: Path | None = None
    truth_csv_path: Path | None = None
    truth_toml_path: Path | None = None
    units: dict[str, str] = field(default_factory=dict)

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


# --------------------------------------------------------------------------- CAN
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


def _read_can(path: Path, codec: Codec, stats: RecordingStats) -> dict[str, Series]:
    """Read and decode ``can.log`` with the vectorised decoder (:mod:`.fastdecode`).

    Same signals, statistics and counters as :func:`read_can_per_frame`.
    """
    from . import fastdecode

    rs = ReadStats(source=path.name)
    stats.files[path.name] = rs
    try:
        table = fastdecode.scan_candump(path, rs)
    except OSError as e:
        raise RecordingError(f"{path}: cannot read: {e.strerror or e}") from e
    messages, signals, claims = fastdecode.decode_table(table, codec, stats, MAX_EXAMPLES)
    _check_frames(path, rs)
    for msg, (_lines, arr, sa) in messages.items():
        info = codec.message(msg)
        ms = stats.messages[msg] = MessageStats(msg, info.pgn, nominal_period_s=info.cycle_time_s)
        ms.count = int(arr.size)
        vals, first, counts = np.unique(sa, return_index=True, return_counts=True)
        for k in np.argsort(first, kind="stable").tolist():
            ms.sources[int(vals[k])] = int(counts[k])
        _message_times(ms, arr)
    stats.address_claims = sorted((AddressClaim(sa, name, t, n, line) for (sa, _), (t, n, line, name) in claims.items()),
                                  key=lambda c: (c.t_first, c.sa))
    return {name: Series(np.asarray(t, dtype=float), np.asarray(v, dtype=float), sa.astype(np.int16),
                         codec.signals[name].unit)
            for name, (_lines, t, v, sa) in signals.items()}


def _check_frames(path: Path, rs: ReadStats) -> None:
    if rs.frames == 0 and rs.total_rejected == 0:
        raise RecordingError(f"{path}: empty file (no candump line)")
    if rs.frames == 0:
        first = min(
            ((lines[0], reason) for reason, lines in rs.examples.items() if lines),
            default=(None, None),
        )
        where = f", line {first[0]}: {first[1]}" if first[0] is not None else ""
        raise RecordingError(f"{path}: no valid candump frame in {rs.lines} lines{where}")


def _message_times(ms: MessageStats, arr: np.ndarray) -> None:
    ms.t_first, ms.t_last = float(arr[0]), float(arr[-1])
    if arr.size >= 2:
        dt = np.diff(arr)
        ms.max_interval_s = float(dt.max())
        if ms.nominal_period_s:
            big = np.nonzero(dt > GAP_FACTOR * ms.nominal_period_s)[0]
            ms.n_gaps = int(big.size)
            ms.gaps = [(float(arr[i]), float(dt[i])) for i in big[:MAX_EXAMPLES]]


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
        for frame in read_candump(path, rs):
            lineno = rs.lines
            if not math.isfinite(stats.can_t_first):
                stats.can_t_first = frame.t
            stats.can_t_last = frame.t
            if not frame.is_extended:
                stats.non_extended_frames += 1
                continue
            cid = j1939.parse_id(frame.can_id)
            if cid.pgn == j1939.PGN_ADDRESS_CLAIMED and len(frame.data) == 8:
                name = j1939.Name.from_bytes(frame.data)
                key = (cid.sa, name.to_int())
                if key in claims:
                    claims[key].count += 1
                else:
                    claims[key] = AddressClaim(cid.sa, name, frame.t, 1, lineno)
            try:
                msg, values = codec.decode(frame.can_id, frame.data, True)
            except UnknownFrame:
                stats.unknown_pgns[cid.pgn] += 1
                stats.unknown_pgn_sources.setdefault(cid.pgn, set()).add(cid.sa)
                continue
            except DecodeError:
                info = codec.message_for_pgn(cid.pgn)
                key_name = info.name if info is not None else f"PGN {cid.pgn}"
                stats.decode_errors[key_name] += 1
                ex = stats.decode_error_lines.setdefault(key_name, [])
                if len(ex) < MAX_EXAMPLES:
                    ex.append(lineno)
                continue
            ms = stats.messages.get(msg)
            if ms is None:
                info = codec.message(msg)
                ms = stats.messages[msg] = MessageStats(msg, info.pgn, nominal_period_s=info.cycle_time_s)
                times[msg] = []
            ms.count += 1
            ms.sources[cid.sa] += 1
            times[msg].append(frame.t)
            if cid.pgn in NETWORK_MANAGEMENT_PGNS:
                continue
            for sig, v in values.items():
                b = builders.get(sig)
                if b is None:
                    b = builders[sig] = _SeriesBuilder()
                b.t.append(frame.t)
                b.v.append(v)
                b.sa.append(cid.sa)
    except OSError as e:
        raise RecordingError(f"{path}: cannot read: {e.strerror or e}") from e

    _check_frames(path, rs)
    for msg, ts in times.items():
        _message_times(stats.messages[msg], np.asarray(ts))
    stats.address_claims = sorted(claims.values(), key=lambda c: (c.t_first, c.sa))
    return {name: b.build(codec.signals[name].unit) for name, b in builders.items()}


# --------------------------------------------------------------------------- GPS
def _add_days(d: date | None, days: int) -> date | None:
    """``d`` plus ``days``, or None if that leaves datetime's range (years 1..9999) or ``d`` is None."""
    if d is None:
        return None
    try:
        return d + timedelta(days=days)
    except OverflowError:
        return None


def _epoch_of(d: date, tod_s: float) -> float:
    return calendar.timegm((d.year, d.month, d.day, 0, 0, 0)) + tod_s


def align_gps(
    fixes: list[GpsFix], can_t0: float | None, stats: NmeaStats | None = None
) -> tuple[GpsTrack, str]:
    """Place GPS epochs on the epoch time axis (method in the module docstring).

    Returns the track and a one-line description of the method used.
    Epochs that do not advance in time are dropped and counted in ``stats``.
    """
    if not fixes:
        return GpsTrack.empty(), "no GPS epochs"
    day_idx = []
    d = 0
    prev = None
    for f in fixes:
        if prev is not None and f.tod_s < prev - 43200.0:
            d += 1
        day_idx.append(d)
        prev = f.tod_s
    dated = [i for i, f in enumerate(fixes) if f.date is not None]
    dates: list[date | None] = []
    if dated:
        i0 = dated[0]
        base = _add_days(fixes[i0].date, -day_idx[i0])
        method = "UTC date from RMC/ZDA, time of day from the same epoch; midnight rollover by day counter"
        for i, f in enumerate(fixes):
            if f.date is not None and i >= i0:
                base = _add_days(f.date, -day_idx[i])
            dates.append(_add_days(base, day_idx[i]))
    else:
        if can_t0 is None or not math.isfinite(can_t0):
            raise RecordingError("GPS has no date (no RMC/ZDA) and there is no CAN time to take it from")
        try:
            d0 = datetime.fromtimestamp(can_t0, tz=timezone.utc).date()
        except (OverflowError, ValueError, OSError):
            raise RecordingError(
                f"GPS has no date (no RMC/ZDA) and the first CAN time {can_t0!r} s is not a calendar date"
            ) from None
        cands = [c for c in (_add_days(d0, k) for k in (-1, 0, 1)) if c is not None]
        best = min(cands, key=lambda c: abs(_epoch_of(c, fixes[0].tod_s) - can_t0))
        method = (
            f"no date in NMEA: UTC date {best.isoformat()} taken from the first CAN frame "
            "(nearest of the day before/of/after); midnight rollover by day counter"
        )
        dates = [_add_days(best, k) for k in day_idx]

    cols: dict[str, list] = {k: [] for k in ("t",) + GPS_FIELDS}
    last_t = -math.inf
    for f, dd in zip(fixes, dates):
        if dd is None:  # before 0001-01-01 or after 9999-12-31 (a ZDA year at the ends of the range)
            if stats is not None:
                stats.reject("date_out_of_range", f.lineno, "")
            continue
        t = _epoch_of(dd, f.tod_s)
        if t <= last_t:
            if stats is not None:
                stats.reject("time_backwards" if t < last_t else "duplicate_epoch", f.lineno, "")
            continue
        last_t = t
        cols["t"].append(t)
        cols["lat"].append(f.lat_deg)
        cols["lon"].append(f.lon_deg)
        cols["alt"].append(f.alt_m)
        cols["speed"].append(f.speed_mps)
        cols["course"].append(f.course_deg)
        q = f.fix_quality
        if f.valid is False and q is None:
            q = 0
        cols["fix_quality"].append(q)
        cols["hdop"].append(f.hdop)
        cols["nsat"].append(f.nsat)
    return GpsTrack.from_columns(cols), method


def _read_gps(path: Path, can_t0: float | None, stats: RecordingStats) -> GpsTrack:
    ns = NmeaStats(source=path.name)
    stats.files[path.name] = ns
    asm = EpochAssembler()
    fixes: list[GpsFix] = []
    try:
        with open(path, "r", encoding="ascii", errors="replace", newline=None) as fh:
            for lineno, rec in iter_nmea(fh, ns):
                done = asm.push(lineno, rec)
                if done is not None:
                    fixes.append(done)
    except OSError as e:
        raise RecordingError(f"{path}: cannot read: {e.strerror or e}") from e
    last = asm.flush()
    if last is not None:
        fixes.append(last)
    if ns.lines == 0:
        raise RecordingError(f"{path}: empty file")
    if asm.orphans:
        ns.ignored["VTG before first timed sentence"] += asm.orphans
    if asm.untimed:
        ns.ignored["sentence without UTC time"] += asm.untimed
    track, method = align_gps(fixes, can_t0, ns)
    stats.gps_epochs = len(track)
    stats.gps_alignment = method
    return track


# --------------------------------------------------------------------------- entry
def read_recording(path: str | Path, codec: Codec | None = None) -> Recording:
    """Read a recording directory (or a lone candump file) into a :class:`Recording`.

    Raises :class:`~tractionecu.errors.RecordingError` naming the file (and
    line) when the path is missing, ``can.log`` is missing, unreadable,
    empty or holds no valid frame, or ``gps.nmea`` is present but empty or
    unreadable.  Bad lines and frames are counted in ``Recording.stats``.
    """
    p = Path(path)
    if not p.exists():
        raise RecordingError(f"{p}: no such recording")
    if p.is_dir():
        root = p
        can_path = p / CAN_FILE
        if not can_path.is_file():
            raise RecordingError(f"{can_path}: missing (a recording needs {CAN_FILE})")
    else:
        root = p.parent
        can_path = p
    codec = codec if codec is not None else default_codec()
    stats = RecordingStats()
    signals = _read_can(can_path, codec, stats)
    can_t0 = stats.can_t_first

    gps = GpsTrack.empty()
    gps_path = root / GPS_FILE if p.is_dir() else None
    if gps_path is not None and gps_path.exists():
        gps = _read_gps(gps_path, can_t0, stats)
    elif p.is_dir():
        stats.gps_alignment = f"no {GPS_FILE}"

    def opt(name: str) -> Path | None:
        q = root / name
        return q if p.is_dir() and q.is_file() else None

    units = {name: codec.signals[name].unit for name in signals}
    return Recording(
        path=p,
        signals=signals,
        gps=gps,
        stats=stats,
        vehicle_toml_path=opt(VEHICLE_FILE),
        truth_csv_path=opt(TRUTH_CSV),
        truth_toml_path=opt(TRUTH_TOML),
        units=units,
    )


# --------------------------------------------------------------------------- summary
def _fmt_t(t: float) -> str:
    if not math.isfinite(t):
        return "-"
    try:
        return datetime.fromtimestamp(t, tz=timezone.utc).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3] + "Z"
    except (OverflowError, ValueError, OSError):  # beyond years 1..9999 or the platform's time_t
        return f"{t:.6f} s"


def summarize(recording: Recording) -> str:
    """Human-readable report for ``tractionecu inspect``: duration, frames and
    rates per message, gaps, unknown PGNs, decode errors, address claims,
    GPS epochs and rejected lines."""
    r = recording
    st = r.stats
    out: list[str] = [f"Recording {r.path}"]
    out.append(
        f"  duration {r.duration:.3f} s  ({_fmt_t(r.t_start)} .. {_fmt_t(r.t_end)})"
        if math.isfinite(r.duration)
        else "  duration: no samples"
    )
    for fname, fst in st.files.items():
        lines = getattr(fst, "lines", 0)
        acc = getattr(fst, "frames", getattr(fst, "accepted", 0))
        rej = getattr(fst, "total_rejected", 0)
        out.append(f"  {fname}: {lines} lines, {acc} accepted, {rej} rejected")
    if st.messages:
        out.append("  messages:")
        out.append(f"    {'name':<22}{'PGN':>7}{'frames':>8}{'rate Hz':>9}{'nominal':>9}{'gaps':>6}{'max dt s':>10}  sources")
        for ms in sorted(st.messages.values(), key=lambda m: (m.pgn is None, m.pgn or 0, m.name)):
            nom = f"{1.0 / ms.nominal_period_s:.1f}" if ms.nominal_period_s else "-"
            rate = f"{ms.rate_hz:.2f}" if math.isfinite(ms.rate_hz) else "-"
            srcs = ",".join(f"0x{sa:02X}" for sa in sorted(ms.sources) if sa >= 0) or "-"
            pgn = str(ms.pgn) if ms.pgn is not None else "-"
            out.append(
                f"    {ms.name:<22}{pgn:>7}{ms.count:>8}{rate:>9}{nom:>9}{ms.n_gaps:>6}{ms.max_interval_s:>10.3f}  {srcs}"
            )
            for t0, dt in ms.gaps:
                out.append(f"      gap {dt:.3f} s at {_fmt_t(t0)}")
    if st.unknown_pgns:
        out.append(
            f"  unknown PGNs skipped: {st.unknown_frames} frames, {len(st.unknown_pgns)} PGNs"
        )
        for pgn, n in sorted(st.unknown_pgns.items()):
            srcs = ",".join(f"0x{sa:02X}" for sa in sorted(st.unknown_pgn_sources.get(pgn, ())))
            out.append(f"    PGN {pgn:>6} (0x{pgn:05X}) {n:>7} frames  from {srcs}")
    if st.non_extended_frames:
        out.append(f"  11-bit frames skipped: {st.non_extended_frames}")
    if st.decode_errors:
        out.append("  decode errors (wrong DLC):")
        for name, n in sorted(st.decode_errors.items()):
            lines = ", ".join(map(str, st.decode_error_lines.get(name, [])))
            out.append(f"    {name}: {n} (line {lines})")
    if st.address_claims:
        out.append("  address claims (PGN 60928):")
        for c in st.address_claims:
            out.append(f"    SA 0x{c.sa:02X} ({c.sa:3d}) x{c.count}: {c.name.describe()}")
    if len(r.gps):
        q = Counter(int(v) for v in r.gps.fix_quality)
        span = r.gps.t[-1] - r.gps.t[0]
        rate = (len(r.gps) - 1) / span if span > 0 else math.nan
        out.append(
            f"  GPS: {len(r.gps)} epochs, {rate:.2f} Hz, fix quality "
            + ", ".join(f"{k}:{v}" for k, v in sorted(q.items()))
        )
    if st.gps_alignment:
        out.append(f"  GPS alignment: {st.gps_alignment}")
    rej = [(f, s) for f, s in st.files.items() if getattr(s, "total_rejected", 0)]
    if rej:
        out.append("  rejected lines:")
        for _fname, s in rej:
            for line in s.describe():  # type: ignore[attr-defined]
                out.append(f"    {line}")
    ign = [(f, s) for f, s in st.files.items() if getattr(s, "ignored", None)]
    for fname, s in ign:
        out.append(
            f"  {fname} ignored: " + ", ".join(f"{k} x{v}" for k, v in sorted(s.ignored.items()))  # type: ignore[attr-defined]
        )
    return "\n".join(out)
