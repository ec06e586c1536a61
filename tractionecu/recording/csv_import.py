"""Import CSV exports of already-decoded signals into a :class:`Recording`.

Many field loggers export decoded signals as a wide CSV table: one time
column and one column per signal, cells left empty where a signal has no
new sample.  :func:`import_csv` maps such columns onto the project's
signal names and SI units through a :class:`CsvMapping`.

Column mapping
--------------
A mapping entry ``"CSV column" -> Column(target, unit)`` converts the
column from ``unit`` to SI and stores it under ``target``:

- ``target`` is a signal name (a DBC signal such as ``WheelSpeed_FL`` or an
  extra name such as ``EngineSpeed``) or ``gps.<field>`` with field one of
  ``lat, lon, alt, speed, course, fix_quality, hdop, nsat``;
- ``unit`` is a key of :data:`UNITS` (``m/s``, ``km/h``, ``mph``, ``kn``,
  ``rpm``, ``rad/s``, ``Nm``, ``kNm``, ``N``, ``kN``, ``deg``, ``m``, ``%``,
  ``""``) or ``%ref_torque``: percent of the engine reference torque, which
  the caller gives as ``reference_torque_nm`` [N·m] (J1939 SPN 544 value).

A header matches a mapping key exactly, or after replacing ``.`` by
``_`` (asammdf writes ``EEC1.EngineSpeed``).  A mapping with ``loose`` set
(:data:`J1939_AUTO_MAPPING`, ``--csv-mapping auto``) also drops a bus prefix
(``CAN1.``, ``CAN2_``, ``can0_``, ``can0.``) and ignores case, so
``CAN1.EEC1.ActualEnginePercentTorque`` and ``can0_eec1_actualenginepercenttorque``
both match ``EEC1_ActualEnginePercentTorque``.  It also reads the
"Name [unit]" headers of logger exports: spaces and hyphens count as
separators, a trailing bracketed unit is the column's unit (``Time [s]`` is
the time column, ``GNSS Speed [km/h]`` the GNSS speed in km/h), and a name
that carries a J1939 SPN number (``EEC1 SPN190 Engine Speed [rpm]``) maps by
that number (:data:`SPN_TARGETS`, else the DBC signal with that SPN
attribute) whatever else the name says.  Header columns the mapping
does not use are listed in ``CsvStats.unmapped`` and logged as a warning.

Presets
-------
:data:`CONTRACT_MAPPING` (time column ``t`` in s): every DBC data signal
under its own name in its DBC unit, plus ``gps_lat, gps_lon, gps_alt,
gps_speed, gps_course, gps_fix_quality, gps_hdop, gps_nsat`` (deg, m, m/s,
deg).

:data:`J1939_LOGGER_MAPPING` (time column ``timestamps`` in s, as asammdf
exports of CANedge logs name it):

=================================  ==========================  =============
CSV column                         target                      CSV unit
=================================  ==========================  =============
``EEC1_ActualEnginePercentTorque`` ``EngineTorque`` [N·m]      % of reference
``EEC1_EngineSpeed``               ``EngineSpeed`` [rad/s]     rpm
``CCVS1_WheelBasedVehicleSpeed``   ``WheelBasedMachineSpeed``  km/h
``WBSD_WheelBasedMachineSpeed``    ``WheelBasedMachineSpeed``  m/s
``GBSD_GroundBasedMachineSpeed``   ``GroundBasedMachineSpeed`` m/s
``gnss_speed_Speed``               ``gps.speed``               m/s
``gnss_pos_Latitude``              ``gps.lat``                 deg
``gnss_pos_Longitude``             ``gps.lon``                 deg
``gnss_altitude_Altitude``         ``gps.alt``                 m
``gnss_status_Satellites``         ``gps.nsat``                -
``GNSS_Speed``                     ``gps.speed``               km/h
``Latitude`` / ``Longitude``       ``gps.lat`` / ``gps.lon``   deg
=================================  ==========================  =============

Time
----
``time_unit`` is ``"s"`` or ``"ms"`` (numbers), ``"datetime"`` (ISO 8601
such as ``2023-10-23T06:50:50.250Z`` or ``2023-10-23 06:50:50[.fff]``,
read in ``timezone`` when it names no offset: ``UTC`` by default, an offset
``+02:00`` or an IANA name ``Europe/Berlin``) or ``"auto"``: a date-time if
the first time cell is not a number, else milliseconds if it is ≥ 10¹¹
(epoch ms), else seconds.  Date-times become Unix seconds.
``time_offset_s`` [s] is added after conversion (use it to turn a relative
logger time into epoch seconds).  Rows whose time cannot be read or goes
backwards are rejected and counted.  With ``loose`` mappings the time column
may also be any of :data:`TIME_COLUMN_NAMES` (after prefix and case
normalisation).
"""

from __future__ import annotations

import csv
import datetime as _dt
import logging
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np

from ..bus.dbc import NETWORK_MANAGEMENT_PGNS, default_codec
from ..counting import RejectCounter
from ..errors import ConfigError, RecordingError
from .containers import (
    GPS_FIELDS,
    GpsTrack,
    MessageStats,
    Recording,
    RecordingStats,
    Series,
)

log = logging.getLogger(__name__)

UNITS: dict[str, float] = {
    "": 1.0,
    "-": 1.0,
    "m/s": 1.0,
    "km/h": 1.0 / 3.6,
    "mph": 0.44704,
    "kn": 1852.0 / 3600.0,
    "rad/s": 1.0,
    "rpm": 2.0 * math.pi / 60.0,
    "Nm": 1.0,
    "kNm": 1000.0,
    "N": 1.0,
    "kN": 1000.0,
    "deg": 1.0,
    "m": 1.0,
    "%": 1.0,
}
"""CSV unit -> factor to the SI (or kept-percent) unit of the target."""

REF_TORQUE_UNIT = "%ref_torque"

EXTRA_UNITS = {"EngineTorque": "Nm", "EngineSpeed": "rad/s"}
"""SI units of targets that are not DBC signals."""


@dataclass(frozen=True)
class Column:
    """Where one CSV column goes (``target``) and the unit it is written in."""

    target: str
    unit: str = ""

    def __post_init__(self) -> None:
        if self.unit not in UNITS and self.unit != REF_TORQUE_UNIT:
            raise ConfigError(f"unit: {self.unit!r} for {self.target} is not one of {sorted(UNITS)} or {REF_TORQUE_UNIT}")
        if self.target.startswith("gps.") and self.target[4:] not in GPS_FIELDS:
            raise ConfigError(f"target: {self.target!r} is not gps.<{'|'.join(GPS_FIELDS)}>")


@dataclass(frozen=True)
class CsvMapping:
    """Column mapping plus the time column's name and unit (``s`` or ``ms``)."""

    columns: Mapping[str, Column]
    time_column: str = "t"
    time_unit: str = "s"
    loose: bool = False
    """Also match headers with a bus prefix and in any case (see module docstring)."""
    timezone: str | None = None
    """Zone of date-times without an offset (default UTC)."""


def _contract_mapping() -> CsvMapping:
    codec = default_codec()
    cols: dict[str, Column] = {}
    for m in codec.messages.values():
        if m.pgn in NETWORK_MANAGEMENT_PGNS:
            continue
        for s in m.signals:
            unit = codec.signals[s].unit
            cols[s] = Column(s, unit if unit in UNITS else "")
    for k, unit in zip(GPS_FIELDS, ("deg", "deg", "m", "m/s", "deg", "", "", "")):
        cols[f"gps_{k}"] = Column(f"gps.{k}", unit)
    return CsvMapping(cols, "t", "s")


CONTRACT_MAPPING = _contract_mapping()
"""Contract names, DBC units, time column ``t`` [s]."""

J1939_LOGGER_MAPPING = CsvMapping(
    {
        "EEC1_ActualEnginePercentTorque": Column("EngineTorque", REF_TORQUE_UNIT),
        "EEC1_EngineSpeed": Column("EngineSpeed", "rpm"),
        "CCVS1_WheelBasedVehicleSpeed": Column("WheelBasedMachineSpeed", "km/h"),
        "WBSD_WheelBasedMachineSpeed": Column("WheelBasedMachineSpeed", "m/s"),
        "GBSD_GroundBasedMachineSpeed": Column("GroundBasedMachineSpeed", "m/s"),
        "gnss_speed_Speed": Column("gps.speed", "m/s"),
        "gnss_pos_Latitude": Column("gps.lat", "deg"),
        "gnss_pos_Longitude": Column("gps.lon", "deg"),
        "gnss_altitude_Altitude": Column("gps.alt", "m"),
        "gnss_status_Satellites": Column("gps.nsat", ""),
        "GNSS_Speed": Column("gps.speed", "km/h"),
        "Latitude": Column("gps.lat", "deg"),
        "Longitude": Column("gps.lon", "deg"),
    },
    time_column="timestamps",
    time_unit="s",
)
"""Typical J1939 logger export names (see module docstring)."""

J1939_AUTO_MAPPING = CsvMapping({**J1939_LOGGER_MAPPING.columns,
                                 "GNSS_Latitude": Column("gps.lat", "deg"),
                                 "GNSS_Longitude": Column("gps.lon", "deg"),
                                 "GNSS_Altitude": Column("gps.alt", "m")},
                                time_column="timestamps", time_unit="auto", loose=True)
"""The J1939 names with or without bus prefixes, either separator, any case;
time in epoch s or ms, relative s or date-time (``--csv-mapping auto``)."""

MAPPINGS = {"contract": CONTRACT_MAPPING, "j1939": J1939_LOGGER_MAPPING, "auto": J1939_AUTO_MAPPING}
"""The presets by their ``--csv-mapping`` name."""

TIME_COLUMN_NAMES = ("timestamps", "timestamp", "time", "t", "datetime", "date_time", "time_s", "time_ms",
                     "t_s", "t_ms", "utc", "time_utc", "date_time_utc", "datetime_utc", "timestamp_utc")
"""Time column names a loose mapping accepts (normalised)."""

TIME_UNITS = ("s", "ms", "datetime", "auto")


def mapping_named(name: str, *, timezone: str | None = None) -> CsvMapping:
    """The preset ``name`` (a key of :data:`MAPPINGS`), reading naive date-times in ``timezone``."""
    try:
        mp = MAPPINGS[name]
    except KeyError:
        raise ConfigError(f"csv_mapping: {name!r} is not one of {', '.join(MAPPINGS)}") from None
    if timezone is None:
        return mp
    _tzinfo(timezone)
    return CsvMapping(mp.columns, mp.time_column, mp.time_unit, mp.loose, timezone)


def _tzinfo(name: str | None) -> _dt.tzinfo:
    """``UTC``, an offset (``+02:00``, ``-0530``) or an IANA zone name."""
    if name is None or name.strip().upper() in ("UTC", "Z", "GMT"):
        return _dt.timezone.utc
    m = re.fullmatch(r"(?:UTC)?([+-])(\d{1,2}):?(\d{2})?", name.strip(), re.IGNORECASE)
    if m:
        off = _dt.timedelta(hours=int(m.group(2)), minutes=int(m.group(3) or 0))
        return _dt.timezone(off if m.group(1) == "+" else -off)
    try:
        from zoneinfo import ZoneInfo

        return ZoneInfo(name.strip())
    except Exception:
        raise ConfigError(f"timezone: {name!r} is not UTC, an offset such as +02:00 or a zone name") from None


_DECIMAL_COMMA = re.compile(r"[+-]?(\d+|\d{1,3}(\.\d{3})+),\d+([eE][+-]?\d+)?")


def _number(cell: str) -> float:
    """A number cell: as Python reads it, else with a decimal comma (``1376,1``, ``1.376,1``: what a
    spreadsheet in a European locale exports, with ``;`` between the cells); raises ValueError."""
    try:
        return float(cell)
    except ValueError:
        c = cell.strip()
        if _DECIMAL_COMMA.fullmatch(c):
            return float(c.replace(".", "").replace(",", "."))
        raise


class _TimeParser:
    """One CSV time cell -> seconds, per ``unit`` (see module docstring)."""

    def __init__(self, unit: str, tz: _dt.tzinfo) -> None:
        self.unit = unit
        self.tz = tz

    def __call__(self, cell: str) -> float:
        """Seconds; raises ValueError.  ``auto`` settles on the first cell it can read."""
        if self.unit == "auto":
            try:
                v = _number(cell)
            except ValueError:
                t = self._datetime(cell)
                self.unit = "datetime"
                return t
            self.unit = "ms" if abs(v) >= 1e11 else "s"
        if self.unit == "datetime":
            return self._datetime(cell)
        return _number(cell) * (1e-3 if self.unit == "ms" else 1.0)

    def _datetime(self, cell: str) -> float:
        text = cell.strip()
        if text.endswith(("Z", "z")):
            text = text[:-1] + "+00:00"
        d = _dt.datetime.fromisoformat(text)
        if d.tzinfo is None:
            d = d.replace(tzinfo=self.tz)
        return d.timestamp()


@dataclass
class CsvStats(RejectCounter):
    """Lines, data rows, accepted cells and rejects of one CSV file.

    ``rejected`` counts by reason (``bad_time``, ``time_backwards``,
    ``bad_value``, ``short_row``, ``bad_row``: a row the csv module cannot
    parse, such as a field beyond its 128 KiB limit) with the first line
    numbers in ``examples`` (see :class:`~tractionecu.counting.RejectCounter`);
    ``unmapped`` lists header columns the mapping does not use.
    """

    rows: int = 0
    accepted: int = 0
    unmapped: list[str] = field(default_factory=list)


def _rows(fh, delim: str):
    """CSV rows of ``fh``; None for a row the csv module refuses (e.g. a field
    beyond ``csv.field_size_limit()``), after which reading goes on."""
    rd = csv.reader(fh, delimiter=delim)
    while True:
        try:
            yield next(rd)
        except StopIteration:
            return
        except csv.Error:
            yield None


def _norm(h: str) -> str:
    return h.strip().replace(".", "_")


_BUS_PREFIX = re.compile(r"^can\d+[._]", re.IGNORECASE)


_SEPARATORS = re.compile(r"[\s.\-]+")
_BRACKET_UNIT = re.compile(r"^(.*?)\s*\[([^\]]*)\]\s*$")
_PAREN_NOTE = re.compile(r"^(.*?)\s*\(([^)]*)\)\s*$")
_SPN = re.compile(r"(?:^|[^a-z0-9])spn[\s_]*(\d+)(?:$|[^0-9])", re.IGNORECASE)


def _norm_loose(h: str) -> str:
    return _SEPARATORS.sub("_", _BUS_PREFIX.sub("", h.strip())).strip("_").lower()


SPN_TARGETS: dict[int, Column] = {
    513: Column("EngineTorque", REF_TORQUE_UNIT),
    190: Column("EngineSpeed", "rpm"),
    84: Column("WheelBasedMachineSpeed", "km/h"),
    1862: Column("WheelBasedMachineSpeed", "m/s"),
    1859: Column("GroundBasedMachineSpeed", "m/s"),
}
"""J1939 SPN -> target and default unit, where the target is not the DBC signal of that SPN (as in
:data:`J1939_LOGGER_MAPPING`: percent torque becomes ``EngineTorque`` [N·m], CCVS1's speed the
wheel-based machine speed).  Any other SPN goes to the DBC signal with that SPN attribute."""


def _spn_column(spn: int) -> Column | None:
    col = SPN_TARGETS.get(spn)
    if col is not None:
        return col
    codec = default_codec()
    for name, sig in codec.signals.items():
        if getattr(sig, "spn", None) == spn:
            unit = sig.unit if sig.unit in UNITS else ""
            return Column(name, unit)
    return None


def _loose_column(h: str, mp: "CsvMapping", norm_keys: dict[str, str]) -> tuple[Column | None, str]:
    """(Column, why not) for a header of a loose mapping: the name as it is, the name without its
    bracketed unit (which then replaces the mapping's unit), or its SPN number."""
    m = _BRACKET_UNIT.match(h)
    base, unit = (m.group(1), m.group(2).strip()) if m else (h, None)
    key = norm_keys.get(_norm_loose(h)) or norm_keys.get(_norm_loose(base))
    col = mp.columns[key] if key is not None else None
    if col is None:
        sm = _SPN.search(base)
        col = _spn_column(int(sm.group(1))) if sm else None
    if col is None:
        return None, ""
    if unit is None or col.unit == REF_TORQUE_UNIT and unit == "%":
        return col, ""
    if unit in ("", "-") and col.unit in ("", "-"):
        return col, ""
    if unit not in UNITS:
        return None, f"unit [{unit}] not known"
    return Column(col.target, unit), ""


def import_csv(
    path: str | Path,
    mapping: CsvMapping | None = None,
    *,
    time_column: str | None = None,
    time_unit: str | None = None,
    time_offset_s: float = 0.0,
    reference_torque_nm: float | None = None,
    vehicle_toml: str | Path | None = None,
    timezone: str | None = None,
) -> Recording:
    """Read a decoded-signal CSV into a :class:`Recording`.

    ``mapping`` defaults to :data:`CONTRACT_MAPPING`; ``time_column``,
    ``time_unit`` (one of :data:`TIME_UNITS`) and ``timezone`` override the mapping's.  ``reference_torque_nm`` [N·m] is
    required when a mapped column present in the file uses ``%ref_torque``.
    The delimiter (``,``, ``;`` or tab) is detected from the header.

    Raises :class:`RecordingError` (naming the file and line) for a missing,
    unreadable or empty file, a missing time column, or no mapped column;
    :class:`ConfigError` for a bad unit or a missing reference torque.
    """
    p = Path(path)
    mp = mapping if mapping is not None else CONTRACT_MAPPING
    tcol = time_column if time_column is not None else mp.time_column
    tunit = time_unit if time_unit is not None else mp.time_unit
    if tunit not in TIME_UNITS:
        raise ConfigError(f"time_unit: {tunit!r} is not one of {', '.join(TIME_UNITS)}")
    parse_time = _TimeParser(tunit, _tzinfo(timezone if timezone is not None else mp.timezone))
    norm = _norm_loose if mp.loose else _norm

    try:
        fh = open(p, "r", encoding="utf-8-sig", errors="replace", newline="")
    except OSError as e:
        raise RecordingError(f"{p}: cannot read: {e.strerror or e}") from e
    stats = CsvStats(source=p.name)
    with fh:
        header_line = fh.readline()
        if not header_line.strip():
            raise RecordingError(f"{p}: line 1: empty file (no header)")
        delim = max((",", ";", "\t"), key=header_line.count)
        try:
            header = next(csv.reader([header_line], delimiter=delim))
        except csv.Error as e:  # e.g. a field beyond csv.field_size_limit()
            raise RecordingError(f"{p}: line 1: {e}") from None
        stats.lines = 1
        norm_keys = {norm(k): k for k in mp.columns}
        col_idx: dict[int, Column] = {}
        t_idx = None
        time_names = {norm(tcol)} | ({norm(n) for n in TIME_COLUMN_NAMES} if mp.loose else set())
        for i, h in enumerate(header):
            hn = h.strip()
            bm = _BRACKET_UNIT.match(hn) if mp.loose else None
            pm = _PAREN_NOTE.match(hn) if mp.loose else None      # "Time (UTC)"
            if t_idx is None and (hn == tcol or norm(hn) in time_names
                                  or bm is not None and norm(bm.group(1)) in time_names
                                  or pm is not None and norm(pm.group(1)) in time_names):
                t_idx = i
                continue
            if hn in mp.columns:
                col_idx[i] = mp.columns[hn]
                continue
            if mp.loose:
                col, why = _loose_column(hn, mp, norm_keys)
            else:
                key = norm_keys.get(norm(hn))
                col, why = (mp.columns[key] if key is not None else None), ""
            if col is None:
                stats.unmapped.append(f"{hn} ({why})" if why else hn)
            else:
                col_idx[i] = col
        if t_idx is None:
            raise RecordingError(f"{p}: line 1: no time column {tcol!r} in header")
        if not col_idx:
            raise RecordingError(f"{p}: line 1: none of the mapped columns is in the header "
                                 f"(header: {', '.join(h.strip() for h in header[:12])}"
                                 f"{', ...' if len(header) > 12 else ''})")
        if stats.unmapped:
            log.warning("%s: columns the mapping ignores: %s", p.name, ", ".join(stats.unmapped))
        if any(c.unit == REF_TORQUE_UNIT for c in col_idx.values()):
            if reference_torque_nm is None or not reference_torque_nm > 0:
                raise ConfigError(
                    "reference_torque_nm: needed (> 0 N·m) to convert percent engine torque (J1939 SPN 544 "
                    "from the engine's data sheet: diagnose --reference-torque, or [drivetrain] "
                    "engine_reference_torque_nm in the vehicle file)"
                )

        sig_t: dict[str, list[float]] = {}
        sig_v: dict[str, list[float]] = {}
        gps_rows: dict[str, list] = {k: [] for k in ("t",) + GPS_FIELDS}
        msg_stats: dict[str, MessageStats] = {}
        last_t = -math.inf
        for lineno, row in enumerate(_rows(fh, delim), start=2):
            stats.lines += 1
            if row is None:
                stats.rows += 1
                stats.reject("bad_row", lineno)
                continue
            if not row or all(not c.strip() for c in row):
                continue
            stats.rows += 1
            if len(row) <= t_idx:
                stats.reject("short_row", lineno)
                continue
            try:
                t = parse_time(row[t_idx]) + time_offset_s
            except (ValueError, OverflowError):
                stats.reject("bad_time", lineno)
                continue
            if not math.isfinite(t):
                stats.reject("bad_time", lineno)
                continue
            if t < last_t:
                stats.reject("time_backwards", lineno)
                continue
            last_t = t
            gps_here: dict[str, float] = {}
            for i, col in col_idx.items():
                if i >= len(row):
                    continue
                cell = row[i].strip()
                if cell == "":
                    continue
                try:
                    raw = _number(cell)
                except ValueError:
                    stats.reject("bad_value", lineno)
                    continue
                if math.isinf(raw):     # never a measurement (NaN stays: "not available", as a J1939 NA code)
                    stats.reject("bad_value", lineno)
                    continue
                if col.unit == REF_TORQUE_UNIT:
                    v = raw / 100.0 * float(reference_torque_nm)  # type: ignore[arg-type]
                else:
                    v = raw * UNITS[col.unit]
                stats.accepted += 1
                if col.target.startswith("gps."):
                    gps_here[col.target[4:]] = v
                    continue
                sig_t.setdefault(col.target, []).append(t)
                sig_v.setdefault(col.target, []).append(v)
                ms = msg_stats.get(col.target)
                if ms is None:
                    ms = msg_stats[col.target] = MessageStats(col.target, None, t_first=t)
                ms.count += 1
                ms.t_last = t
            if gps_here:
                gps_rows["t"].append(t)
                for k in GPS_FIELDS:
                    gps_rows[k].append(gps_here.get(k))

    if stats.rows == 0:
        raise RecordingError(f"{p}: line 2: no data rows")

    codec = default_codec()
    signals: dict[str, Series] = {}
    units: dict[str, str] = {}
    for name, ts in sig_t.items():
        unit = codec.signals[name].unit if name in codec.signals else EXTRA_UNITS.get(name, "")
        t_arr = np.asarray(ts, dtype=float)
        signals[name] = Series(t_arr, np.asarray(sig_v[name], dtype=float), np.full(t_arr.size, -1, dtype=np.int16), unit)
        units[name] = unit
        ms = msg_stats[name]
        if t_arr.size >= 2:
            ms.max_interval_s = float(np.diff(t_arr).max())

    rstats = RecordingStats()
    rstats.files[p.name] = stats
    rstats.messages = msg_stats
    gps = GpsTrack.from_columns(gps_rows)
    rstats.gps_epochs = len(gps)
    rstats.gps_alignment = f"GPS columns of {p.name} on the CSV time axis" if len(gps) else ""
    return Recording(
        path=p,
        signals=signals,
        gps=gps,
        stats=rstats,
        vehicle_toml_path=Path(vehicle_toml) if vehicle_toml is not None else None,
        units=units,
    )
