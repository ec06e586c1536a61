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

Speed: :func:`read_gps` reads the log through the NMEA fast path.  A log
whose every line the block conversion takes (what a receiver writes, without
damage) becomes columns (:func:`tractionecu.gnss.nmea.fast_columns`) whose
epochs are assembled and aligned as arrays by the rules above
(:func:`_track_of_columns`, :func:`_align_columns`: each epoch's field from
the last sentence of the type that wins it, else the first that has it;
dates as day ordinals); any other log goes record by record
(:func:`tractionecu.gnss.nmea.iter_nmea_fast`, :func:`_assemble`,
:func:`_align_epochs`).  :func:`read_gps_reference` is the
sentence-by-sentence reader (parse_line,
:class:`~tractionecu.gnss.nmea.EpochAssembler`, :func:`align_gps`) both are
tested (``tests/recording/test_reader_fast.py``) and timed
(``benchmarks/decode.py``) against.
"""

from __future__ import annotations

import calendar
import math
from datetime import date
from pathlib import Path
from typing import Iterable

import numpy as np

from ..errors import RecordingError
from ..gnss.nmea import (EpochAssembler, GpsFix, NmeaStats, fast_columns, iter_line_blocks, iter_nmea,
                         iter_nmea_fast)
from ..gnss.utc import add_days, nearest_date, utc_epoch
from .containers import GPS_FIELDS, GpsTrack, RecordingStats


def _epoch_dates(tods: list[float], days: list[date | None], can_t0: float | None,
                 add) -> tuple[list[date | None], str]:
    """The UTC date of each epoch (module doc) from its time of day ``tods`` [s] and the date it carries
    (``days``, None without RMC/ZDA), and the method's description: a day counter from the rollovers of the
    time of day (back by more than 12 h), based on each dated epoch from the first one on, else on the date
    nearest to the first CAN time ``can_t0``.  ``add(day, k)`` is :func:`~tractionecu.gnss.utc.add_days`
    (or a memo of it); a date outside the calendar is None.  Raises :class:`RecordingError` when there is no
    date at all."""
    day_idx = []
    d = 0
    prev = None
    for tod in tods:
        if prev is not None and tod < prev - 43200.0:
            d += 1
        day_idx.append(d)
        prev = tod
    dated = [i for i, day in enumerate(days) if day is not None]
    dates: list[date | None] = []
    if dated:
        i0 = dated[0]
        base = add(days[i0], -day_idx[i0])
        method = "UTC date from RMC/ZDA, time of day from the same epoch; midnight rollover by day counter"
        for i, day in enumerate(days):
            if day is not None and i >= i0:
                base = add(day, -day_idx[i])
            dates.append(add(base, day_idx[i]))
    else:
        if can_t0 is None or not math.isfinite(can_t0):
            raise RecordingError("GPS has no date (no RMC/ZDA) and there is no CAN time to take it from")
        best = nearest_date(can_t0, tods[0])
        if best is None:
            raise RecordingError(
                f"GPS has no date (no RMC/ZDA) and the first CAN time {can_t0!r} s is not a calendar date")
        method = (
            f"no date in NMEA: UTC date {best.isoformat()} taken from the first CAN frame "
            "(nearest of the day before/of/after); midnight rollover by day counter"
        )
        dates = [add(best, k) for k in day_idx]
    return dates, method


def align_gps(
    fixes: list[GpsFix], can_t0: float | None, stats: NmeaStats | None = None
) -> tuple[GpsTrack, str]:
    """Place GPS epochs on the epoch time axis (method in the module docstring).

    Returns the track and a one-line description of the method used.
    Epochs that do not advance in time are dropped and counted in ``stats``.
    """
    if not fixes:
        return GpsTrack.empty(), "no GPS epochs"
    dates, method = _epoch_dates([f.tod_s for f in fixes], [f.date for f in fixes], can_t0, add_days)

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

    ``fast`` (default): a log whose every line the block conversion of
    :func:`~tractionecu.gnss.nmea.fast_columns` takes is assembled and aligned as arrays
    (:func:`_read_columns`); any other log is read through :func:`~tractionecu.gnss.nmea.iter_nmea_fast`
    and its epochs assembled and aligned as plain lists (:func:`_assemble`, :func:`_align_epochs`).
    ``fast=False`` is :func:`read_gps_reference`.  Both give the same track, statistics and counters
    (``tests/recording/test_reader_fast.py``)."""
    if not fast:
        return read_gps_reference(path, can_t0, stats)
    ns = NmeaStats(source=path.name)
    stats.files[path.name] = ns
    try:
        parts = _read_column_blocks(path)
        if parts is None:
            with open(path, "r", encoding="utf-8-sig", errors="replace", newline=None) as fh:
                epochs, orphans, untimed = _assemble(iter_nmea_fast(fh, ns))
    except OSError as e:
        raise RecordingError(f"{path}: cannot read: {e.strerror or e}") from e
    done = None if parts is None else _track_of_columns(parts, can_t0, ns)
    if done is not None:
        track, method = done
        stats.gps_epochs = len(track)
        stats.gps_alignment = method
        return track
    if parts is not None:                               # the arrays' shortcut declined: read by records
        try:
            with open(path, "r", encoding="utf-8-sig", errors="replace", newline=None) as fh:
                epochs, orphans, untimed = _assemble(iter_nmea_fast(fh, ns))
        except OSError as e:
            raise RecordingError(f"{path}: cannot read: {e.strerror or e}") from e
    # an empty GNSS log (a receiver that never sent, a logger stopped at once) is a recording without GNSS,
    # as one without the file or of blank lines: the CAN part is replayed, and the replay says what is missing
    if orphans:
        ns.ignored["VTG before first timed sentence"] += orphans
    if untimed:
        ns.ignored["sentence without UTC time"] += untimed
    track, method = _align_epochs(epochs, can_t0, ns)
    stats.gps_epochs = len(track)
    stats.gps_alignment = method
    return track


_ORD_1970 = date(1970, 1, 1).toordinal()
_ORD_MAX = date.max.toordinal()


def _read_column_blocks(path: Path) -> list[dict] | None:
    """The log's blocks as :func:`~tractionecu.gnss.nmea.fast_columns`, if the block conversion takes every
    line (else None, as soon as a block has another line).  OSError propagates."""
    parts = []
    with open(path, "r", encoding="utf-8-sig", errors="replace", newline=None) as fh:
        for lines in iter_line_blocks(fh):
            cols = fast_columns(lines)
            if cols is None:
                return None
            parts.append(cols)
    return parts or None


def _read_columns(path: Path, can_t0: float | None, ns: NmeaStats) -> tuple[GpsTrack, str] | None:
    """:func:`_track_of_columns` of :func:`_read_column_blocks`, or None."""
    parts = _read_column_blocks(path)
    return None if parts is None else _track_of_columns(parts, can_t0, ns)


def _track_of_columns(parts: list[dict], can_t0: float | None, ns: NmeaStats) -> tuple[GpsTrack, str] | None:
    """The track of a log whose every line the block conversion took, assembled and aligned as arrays by
    the rules of :class:`~tractionecu.gnss.nmea.EpochAssembler` and :func:`align_gps`, counts in ``ns``;
    None (``ns`` untouched) where the arrays' shortcut does not hold (two timed sentences 0 to 1 ms apart).
    Raises :class:`RecordingError` as :func:`align_gps` does."""
    c: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for k in [k for k in parts[0] if k not in ("sentence", "date")]:     # one column at a time: the
        c[k] = (np.concatenate([p[k][0] for p in parts]), np.concatenate([p[k][1] for p in parts]))
        for p in parts:                                                  # blocks' copies go as it is made
            del p[k]
    sent = np.concatenate([p["sentence"] for p in parts])
    dates = [d for p in parts for d in p["date"]]
    parts.clear()
    n = sent.size
    # EpochAssembler: a timed sentence opens an epoch when its time differs from the open epoch's first
    # by more than 1 ms.  When consecutive timed sentences differ by 0 or by more than 1 ms, the epoch's
    # first time is its previous sentence's, and the starts are where that difference is over 1 ms.
    has_tod, tod = c["tod_s"]
    timed = np.flatnonzero(has_tod)
    d = np.abs(np.diff(tod[timed]))
    if ((d > 0) & (d <= 1e-3)).any():
        return None
    start = np.zeros(n, dtype=bool)
    if timed.size:
        start[timed[0]] = True
        start[timed[1:][d > 1e-3]] = True
    epoch_of = np.cumsum(start) - 1                 # the open epoch at each line
    vtg = sent == 3
    orphans = int((vtg & (epoch_of < 0)).sum())
    untimed = int((~has_tod & ~vtg).sum())
    members = np.flatnonzero(has_tod | (vtg & (epoch_of >= 0)))
    n_ep = int(start.sum())
    ns.lines += n
    ns.accepted += n
    if orphans:
        ns.ignored["VTG before first timed sentence"] += orphans
    if untimed:
        ns.ignored["sentence without UTC time"] += untimed
    if n_ep == 0:
        return GpsTrack.empty(), "no GPS epochs"
    ms = sent[members]
    seg = np.flatnonzero(start[members])            # each epoch's first member (its opening sentence)
    big = members.size
    pos = np.arange(big)

    def pick(name: str, priority: int) -> tuple[np.ndarray, np.ndarray]:
        """_merge's rule per epoch: the last sentence of the priority type with the field, else the first
        sentence with it; (which member, present)."""
        p = c[name][0][members]
        last = np.maximum.reduceat(np.where(p & (ms == priority), pos, -1), seg)
        first = np.minimum.reduceat(np.where(p, pos, big), seg)
        which = np.where(last >= 0, last, first)
        return np.minimum(which, big - 1), which < big

    def value(name: str, which: np.ndarray, ok: np.ndarray) -> np.ndarray:
        return np.where(ok, c[name][1][members][which], np.nan)

    w_pos, ok_pos = pick("lat_deg", 1)
    lat = value("lat_deg", w_pos, ok_pos)
    lon = np.where(ok_pos & c["lon_deg"][0][members][w_pos], c["lon_deg"][1][members][w_pos], np.nan)
    alt = value("alt_m", *pick("alt_m", 1))
    speed = value("speed_mps", *pick("speed_mps", 3))
    course = value("course_deg", *pick("course_deg", 3))
    hdop = value("hdop", *pick("hdop", 1))
    w_fq, ok_fq = pick("fix_quality", 1)
    w_ns, ok_ns = pick("nsat", 1)
    fq = np.where(ok_fq, c["fix_quality"][1][members][w_fq], -1)
    nsat = np.where(ok_ns, c["nsat"][1][members][w_ns], -1)
    pv = c["valid"][0][members]
    w_v = np.maximum.reduceat(np.where(pv, pos, -1), seg)
    valid = np.where(w_v >= 0, c["valid"][1][members][np.maximum(w_v, 0)].astype(np.int8), np.int8(-1))
    has_date = np.array([dates[i] is not None for i in members.tolist()], dtype=bool)
    w_d = np.maximum.reduceat(np.where(has_date, pos, -1), seg)
    mem_list = members.tolist()
    ep_date = [None if w < 0 else dates[mem_list[w]] for w in w_d.tolist()]
    first = members[seg]
    return _align_columns(tod[first], ep_date, first + 1, lat, lon, alt, speed, course, fq, nsat, hdop, valid,
                          can_t0, ns)


def _align_columns(tod: np.ndarray, ep_date: list, lineno: np.ndarray, lat, lon, alt, speed, course, fq, nsat, hdop,
                   valid, can_t0: float | None, stats: NmeaStats) -> tuple[GpsTrack, str]:
    """:func:`align_gps` on epoch arrays, with dates as day ordinals: the same track, method and rejects."""
    n = tod.size
    day_idx = np.zeros(n, dtype=np.int64)
    if n > 1:
        day_idx[1:] = np.cumsum(tod[1:] < tod[:-1] - 43200.0)
    dated = np.array([x is not None for x in ep_date], dtype=bool)
    if dated.any():
        method = "UTC date from RMC/ZDA, time of day from the same epoch; midnight rollover by day counter"
        i0 = int(np.argmax(dated))
        ords = np.array([0 if x is None else x.toordinal() for x in ep_date], dtype=np.int64)
        base = ords - day_idx                           # add_days(date, -day index) at each dated epoch
        base_ok = (base >= 1) & (base <= _ORD_MAX)
        anchor = np.maximum.accumulate(np.where(dated, np.arange(n), -1))
        anchor[:i0] = i0                                # before the first dated epoch: its base
        b_ok = base_ok[anchor]
        o = base[anchor] + day_idx
    else:
        if can_t0 is None or not math.isfinite(can_t0):
            raise RecordingError("GPS has no date (no RMC/ZDA) and there is no CAN time to take it from")
        best = nearest_date(can_t0, float(tod[0]))
        if best is None:
            raise RecordingError(
                f"GPS has no date (no RMC/ZDA) and the first CAN time {can_t0!r} s is not a calendar date")
        method = (
            f"no date in NMEA: UTC date {best.isoformat()} taken from the first CAN frame "
            "(nearest of the day before/of/after); midnight rollover by day counter"
        )
        b_ok = np.ones(n, dtype=bool)
        o = best.toordinal() + day_idx
    has = b_ok & (o >= 1) & (o <= _ORD_MAX)
    # utc_epoch: timegm(date) + time of day; timegm of a date is (its ordinal - 1970-01-01's) * 86400 [s]
    t = np.where(has, (o - _ORD_1970) * 86400, 0).astype(np.float64) + tod
    keep = has.copy()
    prev = np.maximum.accumulate(np.where(has, t, -np.inf))
    last = np.concatenate([[-np.inf], prev[:-1]])   # the latest epoch time kept before each epoch
    back = has & (t <= last)
    keep &= ~back
    for i in np.flatnonzero(~keep).tolist():
        stats.reject("date_out_of_range" if not has[i] else "time_backwards" if t[i] < last[i]
                     else "duplicate_epoch", int(lineno[i]), "")
    fq = np.where((fq < 0) & (valid == 0), 0, fq)
    code = lambda a: np.where((a >= 0) & (a <= 32767), a, -1).astype(np.int16)   # noqa: E731
    return GpsTrack(t=t[keep], lat=lat[keep], lon=lon[keep], alt=alt[keep], speed=speed[keep],
                    course=course[keep], fix_quality=code(fq)[keep], hdop=hdop[keep], nsat=code(nsat)[keep],
                    valid=valid[keep].astype(np.int8)), method


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
    sums: dict = {}

    def add(day: date | None, k: int) -> date | None:
        key = (day, k)
        if key not in sums:
            sums[key] = add_days(day, k)
        return sums[key]

    dates, method = _epoch_dates([ep[0] for ep in epochs], [ep[1] for ep in epochs], can_t0, add)
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
        with open(path, "r", encoding="utf-8-sig", errors="replace", newline=None) as fh:
            for lineno, rec in iter_nmea(fh, ns):
                done = asm.push(lineno, rec)
                if done is not None:
                    fixes.append(done)
    except OSError as e:
        raise RecordingError(f"{path}: cannot read: {e.strerror or e}") from e
    last = asm.flush()
    if last is not None:
        fixes.append(last)
    # an empty GNSS log (a receiver that never sent, a logger stopped at once) is a recording without GNSS,
    # as one without the file or of blank lines: the CAN part is replayed, and the replay says what is missing
    if asm.orphans:
        ns.ignored["VTG before first timed sentence"] += asm.orphans
    if asm.untimed:
        ns.ignored["sentence without UTC time"] += asm.untimed
    track, method = align_gps(fixes, can_t0, ns)
    stats.gps_epochs = len(track)
    stats.gps_alignment = method
    return track
