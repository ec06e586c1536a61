"""NMEA UTC time of day to epoch seconds: the one timing rule of recordings and the service.

NMEA carries the UTC time of day in GGA/RMC/GNS/ZDA and the UTC date only
in RMC and ZDA.  An epoch's time is ``timegm(date) + time_of_day`` [s,
POSIX].  Where no sentence gave the date, it is the one of the UTC dates a
day before, on and after a reference time (the first CAN frame of a
recording, the arrival time of a live epoch) that puts the epoch nearest
that reference: a capture that starts just before or after midnight is
placed on the right day.
"""

from __future__ import annotations

import calendar
import math
from datetime import date, datetime, timedelta, timezone


def utc_epoch(d: date, tod_s: float) -> float:
    """Epoch seconds [s] of UTC date ``d`` plus ``tod_s`` seconds of that day."""
    return calendar.timegm((d.year, d.month, d.day, 0, 0, 0)) + tod_s


def add_days(d: date | None, days: int) -> date | None:
    """``d`` plus ``days``, or None if that leaves datetime's range (years 1..9999) or ``d`` is None."""
    if d is None:
        return None
    try:
        return d + timedelta(days=days)
    except OverflowError:
        return None


def nearest_date(t_ref: float, tod_s: float) -> date | None:
    """The UTC date (of the day before, of and after ``t_ref`` [s]) that puts ``tod_s`` nearest ``t_ref``.

    None if ``t_ref`` is not finite or not a calendar date.
    """
    if not math.isfinite(t_ref):
        return None
    try:
        d0 = datetime.fromtimestamp(t_ref, tz=timezone.utc).date()
    except (OverflowError, ValueError, OSError):
        return None
    cands = [c for c in (add_days(d0, k) for k in (-1, 0, 1)) if c is not None]
    return min(cands, key=lambda c: abs(utc_epoch(c, tod_s) - t_ref)) if cands else None
