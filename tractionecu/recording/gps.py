"""GNSS epochs of ``gps.nmea`` placed on the recording's time axis.

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

The epoch arithmetic (date + time of day, the nearest date) is
:mod:`tractionecu.gnss.utc`, the same the service uses for live epochs.

Speed: :func:`read_gps` reads the log through the NMEA fast path
(:func:`tractionecu.gnss.nmea.iter_nmea_fast`) and keeps the epochs as plain
lists, merged and aligned by the rules above (:func:`_assemble`,
:func:`_align_epochs`), several times faster than sentence by sentence;
:func:`read_gps_reference` is the sentence-by-sentence reader (parse_line,
:class:`~tractionecu.gnss.nmea.EpochAssembler`, :func:`align_gps`) it is
tested and timed against (``benchmarks/decode.py``).
"""

from __future__ import annotations

import calendar
import math
from datetime import date
from pathlib import Path
from typing import Iterable

import numpy as np

from ..errors import RecordingError
from ..gnss.nmea import EpochAssembler, GpsFix, NmeaStats, iter_nmea, iter_nmea_fast
from ..gnss.utc import add_days, nearest_date, utc_epoch
from .containers import GPS_FIELDS, GpsTrack, RecordingStats


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
        base = add_days(fixes[i0].date, -day_idx[i0])
        method = "UTC date from RMC/ZDA, time of day from the same epoch; midnight rollover by day counter"
        for i, f in enumerate(fixes):
            if f.date is not None and i >= i0:
                base = add_days(f.date, -day_idx[i])
            dates.append(add_days(base, day_idx[i]))
    else:
        if can_t0 is None or not math.isfinite(can_t0):
            raise RecordingError("GPS has no date (no RMC/ZDA) and there is no CAN time to take it from")
        best = nearest_date(can_t0, fixes[0].tod_s)
        if best is None:
            raise RecordingError(
                f"GPS has no date (no RMC/ZDA) and the first CAN time {can_t0!r} s is not a calendar date")
        method = (
            f"no date in NMEA: UTC date {best.isoformat()} taken from the first CAN frame "
            "(nearest of the day before/of/after); midnight rollover by day counter"
        )
        dates = [add_days(best, k) for k in day_idx]

    cols: dict[str, list] = {k: [] for k in ("t",) + GPS_FIELDS}
    last_t = -math.inf
    for f, dd in zip(fixes, dates):
        if dd is None:  # before 0001-01-01 or after 9999-12-31 (a ZDA year at the ends of the range)
            if stats is not None:
                stats.reject("date_out_of_range", f.lineno, "")
            continue
        t = utc_epoch(dd, f.tod_s)
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
        cols["valid"].append(f.valid)
    return GpsTrack.from_columns(cols), method


def read_gps(path: Path, can_t0: float | None, stats: RecordingStats, *, fast: bool = True) -> GpsTrack:
    """Read ``gps.nmea`` into an aligned :class:`GpsTrack`; counts go to ``stats.files[path.name]``.

    ``fast`` (default) reads through :func:`~tractionecu.gnss.nmea.iter_nmea_fast` and assembles and aligns
    the epochs as plain lists (:func:`_assemble`, :func:`_align_epochs`); ``fast=False`` is
    :func:`read_gps_reference`.  Both give the same track, statistics and counters
    (``tests/recording/test_reader_fast.py``)."""
    if not fast:
        return read_gps_reference(path, can_t0, stats)
    ns = NmeaStats(source=path.name)
    stats.files[path.name] = ns
    try:
        with open(path, "r", encoding="ascii", errors="replace", newline=None) as fh:
            epochs, orphans, untimed = _assemble(iter_nmea_fast(fh, ns))
    except OSError as e:
        raise RecordingError(f"{path}: cannot read: {e.strerror or e}") from e
    if ns.lines == 0:
        raise RecordingError(f"{path}: empty file")
    if orphans:
        ns.ignored["VTG before first timed sentence"] += orphans
    if untimed:
        ns.ignored["sentence without UTC time"] += untimed
    track, method = _align_epochs(epochs, can_t0, ns)
    stats.gps_epochs = len(track)
    stats.gps_alignment = method
    return track


# An epoch of the fast path: [tod_s, date, lat, lon, alt, speed, course, fix_quality, nsat, hdop, valid, lineno],
# GpsFix's fields but for the sentence names (which the track does not use).
def _assemble(records: Iterable[tuple[int, tuple]]) -> tuple[list[list], int, int]:
    """:class:`EpochAssembler` over record values (:func:`~tractionecu.gnss.nmea.record_values`): the epochs
    in order, the VTGs before any timed sentence and the untimed sentences.  Same rules, same merge."""
    epochs: list[list] = []
    cur: list | None = None
    orphans = untimed = 0
    for lineno, r in records:
        tod = r[2]
        if tod is None:
            if r[0] != "VTG":
                untimed += 1
                continue
            if cur is None:
                orphans += 1
                continue
        elif cur is None or abs(cur[0] - tod) > 1e-3:
            cur = [tod, None, None, None, None, None, None, None, None, None, None, lineno]
            epochs.append(cur)
        # _merge of tractionecu.gnss.nmea, field for field
        s = r[0]
        if r[3] is not None:
            cur[1] = r[3]
        if r[4] is not None and (s == "GGA" or s == "GNS" or cur[2] is None):
            cur[2], cur[3] = r[4], r[5]
        if r[6] is not None and (s == "GGA" or cur[4] is None):
            cur[4] = r[6]
        if r[8] is not None and (s == "VTG" or cur[5] is None):
            cur[5] = r[8]
        if r[9] is not None and (s == "VTG" or cur[6] is None):
            cur[6] = r[9]
        if r[10] is not None and (s == "GGA" or cur[7] is None):
            cur[7] = r[10]
        if r[11] is not None and (s == "GGA" or cur[8] is None):
            cur[8] = r[11]
        if r[12] is not None and (s == "GGA" or cur[9] is None):
            cur[9] = r[12]
        if r[13] is not None:
            cur[10] = r[13]
    return epochs, orphans, untimed


def _align_epochs(epochs: list[list], can_t0: float | None, stats: NmeaStats | None) -> tuple[GpsTrack, str]:
    """:func:`align_gps` over the fast path's epoch lists, with the dates' day sums and midnights computed
    once per date; the same track, method text and rejects."""
    if not epochs:
        return GpsTrack.empty(), "no GPS epochs"
    day_idx = []
    d = 0
    prev = None
    for ep in epochs:
        if prev is not None and ep[0] < prev - 43200.0:
            d += 1
        day_idx.append(d)
        prev = ep[0]
    sums: dict = {}

    def add(day: date | None, k: int) -> date | None:
        key = (day, k)
        if key not in sums:
            sums[key] = add_days(day, k)
        return sums[key]

    dated = [i for i, ep in enumerate(epochs) if ep[1] is not None]
    dates: list[date | None] = []
    if dated:
        i0 = dated[0]
        base = add(epochs[i0][1], -day_idx[i0])
        method = "UTC date from RMC/ZDA, time of day from the same epoch; midnight rollover by day counter"
        for i, ep in enumerate(epochs):
            if ep[1] is not None and i >= i0:
                base = add(ep[1], -day_idx[i])
            dates.append(add(base, day_idx[i]))
    else:
        if can_t0 is None or not math.isfinite(can_t0):
            raise RecordingError("GPS has no date (no RMC/ZDA) and there is no CAN time to take it from")
        best = nearest_date(can_t0, epochs[0][0])
        if best is None:
            raise RecordingError(
                f"GPS has no date (no RMC/ZDA) and the first CAN time {can_t0!r} s is not a calendar date")
        method = (
            f"no date in NMEA: UTC date {best.isoformat()} taken from the first CAN frame "
            "(nearest of the day before/of/after); midnight rollover by day counter"
        )
        dates = [add(best, k) for k in day_idx]
    midnight: dict = {}
    kept = []
    last_t = -math.inf
    for ep, dd in zip(epochs, dates):
        if dd is None:
            if stats is not None:
                stats.reject("date_out_of_range", ep[11], "")
            continue
        m0 = midnight.get(dd)
        if m0 is None:
            m0 = midnight[dd] = _midnight(dd)
        t = m0 + ep[0]                                    # utc_epoch: timegm(date) + time of day
        if t <= last_t:
            if stats is not None:
                stats.reject("time_backwards" if t < last_t else "duplicate_epoch", ep[11], "")
            continue
        last_t = t
        ep[11] = t
        kept.append(ep)
    return _track(kept), method


def _midnight(d: date) -> int:
    """``calendar.timegm`` of the date's midnight, the integer :func:`utc_epoch` adds the time of day to."""
    return calendar.timegm((d.year, d.month, d.day, 0, 0, 0))


def _code(v: int | None) -> int:
    """GpsTrack's integer code of an int field: -1 for None or outside 0..32767 (containers._code)."""
    return v if v is not None and 0 <= v <= 32767 else -1


def _track(eps: list[list]) -> GpsTrack:
    """GpsTrack.from_columns of the kept epochs (their time in the lineno slot): None -> NaN / -1."""
    if not eps:
        return GpsTrack.from_columns({k: [] for k in ("t",) + GPS_FIELDS})
    (_tod, _date, lat, lon, alt, speed, course, fq, nsat, hdop, valid, t) = zip(*eps)
    fq = [0 if q is None and v is False else q for q, v in zip(fq, valid)]

    def fa(col: tuple) -> np.ndarray:
        return np.array(col, dtype=float)                # None -> NaN

    return GpsTrack(t=fa(t), lat=fa(lat), lon=fa(lon), alt=fa(alt), speed=fa(speed), course=fa(course),
                    fix_quality=np.array([_code(q) for q in fq], dtype=np.int16), hdop=fa(hdop),
                    nsat=np.array([_code(q) for q in nsat], dtype=np.int16),
                    valid=np.array([-1 if v is None else int(bool(v)) for v in valid], dtype=np.int8))


def read_gps_reference(path: Path, can_t0: float | None, stats: RecordingStats) -> GpsTrack:
    """:func:`read_gps` sentence by sentence (:func:`~tractionecu.gnss.nmea.iter_nmea`, :class:`EpochAssembler`,
    :func:`align_gps`): the reference the fast path is checked and timed against."""
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
