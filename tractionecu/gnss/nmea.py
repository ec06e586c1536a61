"""NMEA 0183 sentence formatting and strict parsing (GGA, RMC, VTG, GNS, ZDA).

The writer, the parser and the epoch assembler stay in one module (over 500
lines): they share the sentence table, the field formats and the
mode/quality maps, and together they are the whole NMEA side of the GNSS
contract, which the simulator writes and the recording reader and the
service read.

Formatting follows what a u-blox ZED-F9P writes (NMEA 4.10 output): time
``hhmmss.ss``, latitude ``ddmm.mmmmm``, longitude ``dddmm.mmmmm``, two-digit
satellite count, HDOP with 2 decimals, altitude and geoid separation with 1
decimal, speed with 3 decimals in knots (RMC, VTG) and km/h (VTG), course
with 2 decimals, and the mode / navigational-status fields of NMEA 4.10.
Every sentence ends in ``*HH``, the XOR of the characters between ``$``
and ``*``.  Lines are returned without CR/LF.

Parsing is strict: :func:`parse_line` requires a checksum and checks it
with ``pynmea2.parse(line, check=True)``, accepts any talker (GP, GN, GL,
GA, GB, ...), converts the fields to SI floats itself and raises
:class:`~tractionecu.errors.DecodeError` (with a ``reason`` attribute) for
garbage, a missing or wrong checksum, or a field out of range.  Sentences
of other types (GSA, GSV, TXT, ...) return None.

Units: time of day [s since 00:00 UTC], angles [deg] (WGS84 latitude and
longitude, course over ground clockwise from true north), altitude above
mean sea level [m], speed over ground [m/s].
"""

from __future__ import annotations

import math
import re
from collections import Counter
from dataclasses import dataclass, field, replace
from datetime import date, datetime, timedelta, timezone
from pathlib import Path
from typing import Any, Iterable, Iterator

import pynmea2

from ..counting import RejectCounter
from ..errors import DecodeError

KNOT_MPS = 1852.0 / 3600.0
"""One knot in m/s."""

SUPPORTED = ("GGA", "RMC", "VTG", "GNS", "ZDA")

MODE_FROM_QUALITY = {0: "N", 1: "A", 2: "D", 3: "A", 4: "R", 5: "F", 6: "E", 7: "M", 8: "S"}
"""GGA fix quality -> NMEA 2.3+ mode indicator (RMC, VTG, GNS)."""

QUALITY_FROM_MODE = {"N": 0, "A": 1, "D": 2, "P": 3, "R": 4, "F": 5, "E": 6, "M": 7, "S": 8}
"""Mode indicator -> GGA-style fix quality (P, precise, is reported as 3)."""

REJECT_REASONS = ("garbage", "missing_checksum", "bad_checksum", "bad_field", "time_backwards")

MAX_SENTENCES_PER_EPOCH = 16
"""Sentence names kept per epoch: a stream that repeats one time forever must not grow it without bound."""

_CHECKSUM_RE = re.compile(r"\*([0-9A-Fa-f]{2})$")


# --------------------------------------------------------------------------- formatting
def checksum(body: str) -> str:
    """Two upper-case hex digits: XOR of the characters of ``body`` (between ``$`` and ``*``)."""
    c = 0
    for ch in body.encode("ascii"):
        c ^= ch
    return f"{c:02X}"


def _sentence(body: str) -> str:
    return f"${body}*{checksum(body)}"


def _utc(t: datetime) -> datetime:
    """Naive datetimes are taken as UTC; aware ones are converted."""
    if t.tzinfo is None:
        return t
    return t.astimezone(timezone.utc).replace(tzinfo=None)


def _round_cs(t: datetime) -> datetime:
    """Round to 10 ms (the hhmmss.ss resolution), carrying into the date."""
    t = _utc(t)
    cs = round(t.microsecond / 10_000)
    return t.replace(microsecond=0) + timedelta(milliseconds=10 * cs)


def _hms(t: datetime) -> str:
    return f"{t.hour:02d}{t.minute:02d}{t.second:02d}.{t.microsecond // 10_000:02d}"


def _latlon(value_deg: float, deg_digits: int, hemis: str) -> tuple[str, str]:
    """Degrees -> ('ddmm.mmmmm', 'N') with 5 decimals of minutes."""
    if value_deg is None or not math.isfinite(value_deg):
        raise ValueError(f"coordinate {value_deg!r} is not finite")
    limit = 90.0 if deg_digits == 2 else 180.0
    if abs(value_deg) > limit:
        raise ValueError(f"coordinate {value_deg} outside ±{limit}")
    a = abs(value_deg)
    # integer hundred-thousandths of a minute, rounded once
    total = round(a * 60.0 * 100_000)
    deg, rem = divmod(total, 60 * 100_000)
    minutes = rem / 100_000
    hemi = hemis[0] if value_deg >= 0 else hemis[1]
    return f"{deg:0{deg_digits}d}{minutes:08.5f}", hemi


def _opt(value: float | None, fmt: str) -> str:
    if value is None or not math.isfinite(value):
        return ""
    return format(value, fmt)


def _course(course_deg: float | None) -> str:
    if course_deg is None or not math.isfinite(course_deg):
        return ""
    c = round(course_deg % 360.0, 2)
    if c >= 360.0:
        c = 0.0
    return f"{c:.2f}"


def _speed(speed_mps: float | None) -> float | None:
    if speed_mps is None or not math.isfinite(speed_mps):
        return None
    return abs(speed_mps)


def format_gga(
    t_utc: datetime,
    lat_deg: float,
    lon_deg: float,
    fix_quality: int,
    nsat: int,
    hdop: float,
    alt_m: float,
    geoid_sep_m: float = 0.0,
    *,
    dgps_age_s: float | None = None,
    dgps_station: int | None = None,
    talker: str = "GN",
) -> str:
    """A GGA sentence: time, position, fix quality (0..8), satellites, HDOP,
    altitude above mean sea level [m] and geoid separation [m].

    ``dgps_age_s`` / ``dgps_station`` fill the differential fields (written
    only when given).  ``t_utc``: naive (taken as UTC) or aware datetime.
    """
    t = _round_cs(t_utc)
    lat, ns = _latlon(lat_deg, 2, "NS")
    lon, ew = _latlon(lon_deg, 3, "EW")
    if not 0 <= int(fix_quality) <= 8:
        raise ValueError(f"fix quality {fix_quality} outside 0..8")
    if not 0 <= int(nsat) <= 99:
        raise ValueError(f"satellite count {nsat} outside 0..99")
    age = _opt(dgps_age_s, ".1f")
    stn = "" if dgps_station is None else f"{int(dgps_station):04d}"
    body = (
        f"{talker}GGA,{_hms(t)},{lat},{ns},{lon},{ew},{int(fix_quality)},{int(nsat):02d},"
        f"{_opt(hdop, '.2f')},{_opt(alt_m, '.1f')},M,{_opt(geoid_sep_m, '.1f')},M,{age},{stn}"
    )
    return _sentence(body)


def format_rmc(
    t_utc: datetime,
    lat_deg: float,
    lon_deg: float,
    speed_mps: float,
    course_deg: float | None,
    valid: bool = True,
    *,
    mode: str | None = None,
    talker: str = "GN",
) -> str:
    """An RMC sentence (NMEA 4.10 layout): time, status A/V, position, speed
    over ground [m/s, written in knots], course over ground [deg], date,
    empty magnetic variation, mode indicator (default ``A`` if valid else
    ``N``) and navigational status ``V`` as a u-blox receiver writes it.

    The speed's magnitude is written; NaN/None course leaves the field empty.
    """
    t = _round_cs(t_utc)
    lat, ns = _latlon(lat_deg, 2, "NS")
    lon, ew = _latlon(lon_deg, 3, "EW")
    spd = _speed(speed_mps)
    kn = "" if spd is None else f"{spd / KNOT_MPS:.3f}"
    m = mode if mode is not None else ("A" if valid else "N")
    body = (
        f"{talker}RMC,{_hms(t)},{'A' if valid else 'V'},{lat},{ns},{lon},{ew},{kn},"
        f"{_course(course_deg)},{t.day:02d}{t.month:02d}{t.year % 100:02d},,,{m},V"
    )
    return _sentence(body)


def format_vtg(
    speed_mps: float,
    course_deg: float | None,
    *,
    mode: str = "A",
    talker: str = "GN",
) -> str:
    """A VTG sentence: true course [deg], empty magnetic course, speed over
    ground [m/s] written in knots and km/h (3 decimals), mode indicator."""
    spd = _speed(speed_mps)
    kn = "" if spd is None else f"{spd / KNOT_MPS:.3f}"
    kmh = "" if spd is None else f"{spd * 3.6:.3f}"
    body = f"{talker}VTG,{_course(course_deg)},T,,M,{kn},N,{kmh},K,{mode}"
    return _sentence(body)


def format_zda(t_utc: datetime, *, talker: str = "GN") -> str:
    """A ZDA sentence: UTC time and full date, local zone 00:00."""
    t = _round_cs(t_utc)
    body = f"{talker}ZDA,{_hms(t)},{t.day:02d},{t.month:02d},{t.year:04d},00,00"
    return _sentence(body)


# --------------------------------------------------------------------------- parsing
@dataclass(frozen=True)
class NmeaRecord:
    """The content of one supported sentence, in SI units; absent fields are None.

    ``tod_s`` is the UTC time of day [s] (None for VTG); ``date`` the UTC
    date (RMC, ZDA); ``valid`` the RMC status (A = True); ``mode`` the
    mode indicator letter(s).
    """

    sentence: str
    talker: str
    tod_s: float | None = None
    date: date | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_m: float | None = None
    geoid_sep_m: float | None = None
    speed_mps: float | None = None
    course_deg: float | None = None
    fix_quality: int | None = None
    nsat: int | None = None
    hdop: float | None = None
    valid: bool | None = None
    mode: str | None = None


def _fail(reason: str, msg: str) -> DecodeError:
    e = DecodeError(f"{reason}: {msg}")
    e.reason = reason  # type: ignore[attr-defined]
    return e


def _f(s: str, name: str) -> float | None:
    if s == "":
        return None
    try:
        v = float(s)
    except ValueError:
        raise _fail("bad_field", f"{name}={s!r} is not a number") from None
    if not math.isfinite(v):
        raise _fail("bad_field", f"{name}={s!r} is not finite")
    return v


def _i(s: str, name: str) -> int | None:
    if s == "":
        return None
    try:
        return int(s, 10)
    except ValueError:
        v = _f(s, name)
        if v is None or v != int(v):
            raise _fail("bad_field", f"{name}={s!r} is not an integer") from None
        return int(v)


def _tod(s: str) -> float | None:
    if s == "":
        return None
    if len(s) < 6 or not s[:6].isdigit():
        raise _fail("bad_field", f"time {s!r} is not hhmmss[.ss]")
    h, m = int(s[0:2]), int(s[2:4])
    sec = _f(s[4:], "seconds")
    assert sec is not None
    if h > 23 or m > 59 or not 0 <= sec < 61:
        raise _fail("bad_field", f"time {s!r} out of range")
    return h * 3600.0 + m * 60.0 + sec


def _coord(value: str, hemi: str, deg_digits: int, name: str) -> float | None:
    if value == "" and hemi == "":
        return None
    if value == "" or hemi == "":
        raise _fail("bad_field", f"{name} {value!r},{hemi!r} incomplete")
    if "." in value:
        head = value.split(".", 1)[0]
    else:
        head = value
    if len(head) != deg_digits + 2 or not head.isdigit():
        raise _fail("bad_field", f"{name} {value!r} is not {'d' * deg_digits}mm.mmmm")
    deg = int(head[:deg_digits])
    minutes = _f(value[deg_digits:], name)
    assert minutes is not None
    if minutes >= 60.0:
        raise _fail("bad_field", f"{name} minutes {minutes} ≥ 60")
    v = deg + minutes / 60.0
    limit = 90.0 if deg_digits == 2 else 180.0
    if v > limit:
        raise _fail("bad_field", f"{name} {v} beyond {limit} deg")
    pos, neg = ("N", "S") if deg_digits == 2 else ("E", "W")
    if hemi == pos:
        return v
    if hemi == neg:
        return -v
    raise _fail("bad_field", f"{name} hemisphere {hemi!r}")


def _date_ddmmyy(s: str) -> date | None:
    if s == "":
        return None
    if len(s) != 6 or not s.isdigit():
        raise _fail("bad_field", f"date {s!r} is not ddmmyy")
    d, m, y = int(s[0:2]), int(s[2:4]), int(s[4:6])
    year = 2000 + y if y < 80 else 1900 + y
    try:
        return date(year, m, d)
    except ValueError:
        raise _fail("bad_field", f"date {s!r} invalid") from None


def _field(data: list[str], i: int) -> str:
    return data[i].strip() if i < len(data) else ""


def _quality_from_modes(mode: str) -> int | None:
    best = None
    for ch in mode:
        q = QUALITY_FROM_MODE.get(ch)
        if q is None:
            continue
        # rank: RTK fixed > float > DGNSS/precise > autonomous > DR/manual/sim > none
        rank = {4: 6, 5: 5, 2: 4, 3: 4, 1: 3, 6: 2, 7: 1, 8: 1, 0: 0}[q]
        if best is None or rank > best[0]:
            best = (rank, q)
    return None if best is None else best[1]


def _fix_fields(d: list[str], geoid_index: int) -> dict[str, Any]:
    """Time, position, satellites, HDOP, altitude and geoid separation: the fields
    GGA and GNS share (at the same places but for the geoid separation)."""
    return {
        "tod_s": _tod(_field(d, 0)),
        "lat_deg": _coord(_field(d, 1), _field(d, 2), 2, "latitude"),
        "lon_deg": _coord(_field(d, 3), _field(d, 4), 3, "longitude"),
        "nsat": _i(_field(d, 6), "satellites"),
        "hdop": _f(_field(d, 7), "hdop"),
        "alt_m": _f(_field(d, 8), "altitude"),
        "geoid_sep_m": _f(_field(d, geoid_index), "geoid separation"),
    }


def _exc_text(e: Exception) -> str:
    a = e.args[0] if e.args else e
    if isinstance(a, tuple) and a:
        a = a[0]
    return str(a)


def parse_line(line: str) -> NmeaRecord | None:
    """Parse one NMEA line strictly.

    Returns an :class:`NmeaRecord` for GGA, RMC, VTG, GNS and ZDA from any
    talker, None for a blank line or a valid sentence of another type.
    Raises :class:`DecodeError` (``.reason`` one of ``garbage``,
    ``missing_checksum``, ``bad_checksum``, ``bad_field``).
    """
    s = line.strip()
    if not s:
        return None
    if not s.startswith(("$", "!")) or not s.isascii():
        raise _fail("garbage", f"not an NMEA sentence: {s[:40]!r}")
    if not _CHECKSUM_RE.search(s):
        if "*" in s:
            raise _fail("bad_checksum", f"malformed checksum field: {s[-6:]!r}")
        raise _fail("missing_checksum", s[:40])
    try:
        msg = pynmea2.parse(s, check=True)
    except pynmea2.ChecksumError as e:
        if "missing" in _exc_text(e):
            raise _fail("missing_checksum", s[:40]) from None
        raise _fail("bad_checksum", _exc_text(e)) from None
    except pynmea2.SentenceTypeError:
        return None  # checksum verified by regex + unknown type: not ours
    except pynmea2.ParseError as e:
        raise _fail("garbage", _exc_text(e)) from None
    except Exception as e:  # pynmea2 may raise ValueError/TypeError on odd input
        raise _fail("garbage", f"{type(e).__name__}: {e}") from None

    stype = getattr(msg, "sentence_type", None)
    talker = getattr(msg, "talker", "") or ""
    if stype not in SUPPORTED:
        return None
    d = [str(x) for x in msg.data]
    if stype == "GGA":
        q = _i(_field(d, 5), "fix quality")
        if q is not None and not 0 <= q <= 8:
            raise _fail("bad_field", f"fix quality {q}")
        return NmeaRecord("GGA", talker, fix_quality=q, **_fix_fields(d, geoid_index=10))
    if stype == "RMC":
        status = _field(d, 1)
        if status not in ("A", "V"):
            raise _fail("bad_field", f"RMC status {status!r}")
        kn = _f(_field(d, 6), "speed (knots)")
        mode = _field(d, 11) or None
        return NmeaRecord(
            "RMC",
            talker,
            tod_s=_tod(_field(d, 0)),
            valid=(status == "A"),
            lat_deg=_coord(_field(d, 2), _field(d, 3), 2, "latitude"),
            lon_deg=_coord(_field(d, 4), _field(d, 5), 3, "longitude"),
            speed_mps=None if kn is None else kn * KNOT_MPS,
            course_deg=_f(_field(d, 7), "course"),
            date=_date_ddmmyy(_field(d, 8)),
            mode=mode,
            fix_quality=None if mode is None else _quality_from_modes(mode),
        )
    if stype == "VTG":
        kmh = _f(_field(d, 6), "speed (km/h)")
        kn = _f(_field(d, 4), "speed (knots)")
        if kmh is not None:
            spd: float | None = kmh / 3.6
        elif kn is not None:
            spd = kn * KNOT_MPS
        else:
            spd = None
        mode = _field(d, 8) or None
        return NmeaRecord(
            "VTG", talker, course_deg=_f(_field(d, 0), "course"), speed_mps=spd, mode=mode
        )
    if stype == "GNS":
        mode = _field(d, 5) or None
        fq = None if mode is None else _quality_from_modes(mode)
        return NmeaRecord("GNS", talker, mode=mode, fix_quality=fq, **_fix_fields(d, geoid_index=9))
    # ZDA
    day, month, year = _i(_field(d, 1), "day"), _i(_field(d, 2), "month"), _i(_field(d, 3), "year")
    zdate = None
    if day is not None and month is not None and year is not None:
        try:
            zdate = date(year, month, day)
        except (ValueError, OverflowError):  # OverflowError: beyond a C int
            raise _fail("bad_field", f"ZDA date {day}/{month}/{year}") from None
    return NmeaRecord("ZDA", talker, tod_s=_tod(_field(d, 0)), date=zdate)


# --------------------------------------------------------------------------- streams
@dataclass
class NmeaStats(RejectCounter):
    """Counts for an NMEA stream: lines, accepted records, ignored sentence
    types and rejected lines by reason (see :class:`~tractionecu.counting.RejectCounter`)."""

    accepted: int = 0
    ignored: Counter = field(default_factory=Counter)


def sentence_label(line: str) -> str:
    """How an ignored sentence is counted: the formatter (``GSV`` of ``$GPGSV``), or the whole
    address of a proprietary sentence (``PUBX`` of ``$PUBX,00``, ``PGRME``); ``?`` for a non-sentence."""
    if not line.startswith("$") or len(line) <= 6:
        return "?"
    addr = line[1:].split(",", 1)[0].split("*", 1)[0]
    if addr.startswith("P"):
        return addr or "?"
    return addr[2:] if len(addr) > 2 else "?"


def iter_nmea(
    lines: Iterable[str], stats: NmeaStats | None = None, first_lineno: int = 1
) -> Iterator[tuple[int, NmeaRecord]]:
    """Yield ``(line number, record)`` for each supported sentence; count the rest."""
    st = stats if stats is not None else NmeaStats()
    for lineno, line in enumerate(lines, start=first_lineno):
        st.lines += 1
        try:
            rec = parse_line(line)
        except DecodeError as e:
            st.reject(getattr(e, "reason", "garbage"), lineno, line)
            continue
        if rec is None:
            s = line.strip()
            if s:
                st.ignored[sentence_label(s)] += 1
            continue
        st.accepted += 1
        yield lineno, rec


@dataclass(frozen=True)
class GpsFix:
    """One receiver epoch, merged from the sentences sharing a UTC time.

    Units: ``tod_s`` [s of UTC day], ``lat_deg``/``lon_deg`` [deg WGS84],
    ``alt_m`` [m above MSL], ``speed_mps`` [m/s], ``course_deg`` [deg from
    true north].  ``date`` is set when an RMC or ZDA of the epoch carried
    one.  ``lineno`` is the first line of the epoch; ``sentences`` lists the
    sentence types merged (the first :data:`MAX_SENTENCES_PER_EPOCH`).
    """

    tod_s: float
    date: date | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_m: float | None = None
    speed_mps: float | None = None
    course_deg: float | None = None
    fix_quality: int | None = None
    nsat: int | None = None
    hdop: float | None = None
    valid: bool | None = None
    lineno: int = 0
    sentences: tuple[str, ...] = ()


def _merge(fix: GpsFix, rec: NmeaRecord) -> GpsFix:
    names = fix.sentences if len(fix.sentences) >= MAX_SENTENCES_PER_EPOCH else fix.sentences + (rec.sentence,)
    upd: dict = {"sentences": names}
    s = rec.sentence
    if rec.date is not None:
        upd["date"] = rec.date
    if rec.lat_deg is not None and (s in ("GGA", "GNS") or fix.lat_deg is None):
        upd["lat_deg"], upd["lon_deg"] = rec.lat_deg, rec.lon_deg
    if rec.alt_m is not None and (s == "GGA" or fix.alt_m is None):
        upd["alt_m"] = rec.alt_m
    if rec.speed_mps is not None and (s == "VTG" or fix.speed_mps is None):
        upd["speed_mps"] = rec.speed_mps
    if rec.course_deg is not None and (s == "VTG" or fix.course_deg is None):
        upd["course_deg"] = rec.course_deg
    if rec.fix_quality is not None and (s == "GGA" or fix.fix_quality is None):
        upd["fix_quality"] = rec.fix_quality
    if rec.nsat is not None and (s == "GGA" or fix.nsat is None):
        upd["nsat"] = rec.nsat
    if rec.hdop is not None and (s == "GGA" or fix.hdop is None):
        upd["hdop"] = rec.hdop
    if rec.valid is not None:
        upd["valid"] = rec.valid
    return replace(fix, **upd)


class EpochAssembler:
    """Group records into :class:`GpsFix` epochs by their UTC time of day.

    A record with a time (GGA, RMC, GNS, ZDA) whose time differs from the
    open epoch's by more than 1 ms closes it.  VTG has no time and joins the
    open epoch; a VTG before any timed sentence is counted in ``orphans``;
    another sentence with an empty time field (a receiver without any fix)
    cannot be placed in time and is counted in ``untimed``.
    Feed records with :meth:`push` (returns a finished fix or None), then
    call :meth:`flush`.
    """

    def __init__(self) -> None:
        self._cur: GpsFix | None = None
        self.orphans = 0
        self.untimed = 0

    def push(self, lineno: int, rec: NmeaRecord) -> GpsFix | None:
        """Add one record; returns the previous epoch if this one closed it."""
        done = None
        if rec.tod_s is None:
            if rec.sentence != "VTG":
                self.untimed += 1
            elif self._cur is None:
                self.orphans += 1
            else:
                self._cur = _merge(self._cur, rec)
            return None
        if self._cur is not None and abs(self._cur.tod_s - rec.tod_s) > 1e-3:
            done = self._cur
            self._cur = None
        if self._cur is None:
            self._cur = GpsFix(tod_s=rec.tod_s, lineno=lineno)
        self._cur = _merge(self._cur, rec)
        return done

    def flush(self) -> GpsFix | None:
        """Close and return the open epoch, if any."""
        done, self._cur = self._cur, None
        return done


def assemble_epochs(records: Iterable[tuple[int, NmeaRecord]]) -> Iterator[GpsFix]:
    """Group ``(line number, record)`` pairs into epochs (see :class:`EpochAssembler`)."""
    asm = EpochAssembler()
    for lineno, rec in records:
        done = asm.push(lineno, rec)
        if done is not None:
            yield done
    last = asm.flush()
    if last is not None:
        yield last


def read_nmea(path: str | Path, stats: NmeaStats | None = None) -> Iterator[GpsFix]:
    """Stream epochs from an NMEA file (LF or CRLF), counting rejects in ``stats``."""
    p = Path(path)
    st = stats if stats is not None else NmeaStats()
    if not st.source:
        st.source = p.name
    with open(p, "r", encoding="ascii", errors="replace", newline=None) as fh:
        yield from assemble_epochs(iter_nmea(fh, st))
