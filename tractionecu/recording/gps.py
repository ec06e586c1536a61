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
"""

from __future__ import annotations

import math
from datetime import date
from pathlib import Path

from ..errors import RecordingError
from ..gnss.nmea import EpochAssembler, GpsFix, NmeaStats, iter_nmea
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


def read_gps(path: Path, can_t0: float | None, stats: RecordingStats) -> GpsTrack:
    """Read ``gps.nmea`` into an aligned :class:`GpsTrack`; counts go to ``stats.files[path.name]``."""
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
