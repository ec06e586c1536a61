"""NMEA 0183 sentence formatting and strict parsing (GGA, RMC, VTG, GNS, ZDA).

The writer, the parser, its fast path for recordings and the epoch
assembler stay in one module (over 1,000 lines): they share the sentence
table, the field formats and the mode/quality maps, the fast path is proven
against the parser's own helpers, and together they are the whole NMEA side
of the GNSS contract, which the simulator writes and the recording reader
and the service read.

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

Fast path (recordings)
----------------------
Why: a recording's GNSS log holds about 30 sentences a second, and
:func:`parse_line` (pynmea2's pattern and checksum, then the field helpers)
costs about 20 µs a line, more than decoding the whole CAN capture; a batch
replay meant to run 1,000x real time per core cannot spend that.
:func:`iter_nmea_fast` (what :func:`tractionecu.recording.gps.read_gps`
uses) gives the same records and counts in three tiers: :func:`fast_block`
screens a block of lines with numpy (a ``$``, a two-letter talker not
starting with ``P``, GGA/RMC/VTG/ZDA, the usual field count, only
``0-9 A-Z . , -`` in the body and a checksum that holds; such a line is one
that pynmea2 parses as a plain split at commas) and converts the sentences
of one type together; a form it leaves (an exponent, a trailing dot, more
than 15 digits, ...) goes to :func:`fast_record`, the same conversion line
by line; every other line, and every line whose value a check of
:func:`parse_line` would refuse, goes to :func:`parse_line`, so rejects keep
their reasons, line numbers and texts.  A block that the block conversion
takes whole is also given as columns (:func:`fast_columns`), which the
recording reader assembles into epochs as arrays.  pynmea2 stays the
reference: the live service parses with :func:`parse_line`.  Once numba is
loaded in the process (batch replay), the block tier's number fields are
converted by a compiled kernel (:func:`_dec`), the numpy form's checks and
arithmetic field by field, equal to it bit for bit.

How it is proven equal: each tier uses :func:`parse_line`'s arithmetic on
the same field text (``float()``; in the block tier ``N / 10**k`` for a
number of N's digits with k decimals, both exact doubles, whose correctly
rounded quotient is ``float()``'s correctly rounded value), the same sums in
the same order, and each of its checks at least as strictly.
``tests/gnss/test_nmea_fast.py`` compares the tiers with :func:`parse_line`
by ``repr`` (so -0.0 differs from 0.0) on simulated logs of several
scenarios, the fixtures and thousands of seeded corruptions, and
``tests/recording/test_reader_fast.py`` the tracks and statistics of whole
recordings with the sentence-by-sentence reader.
"""

from __future__ import annotations

import math
import re
import sys
from collections import Counter
from dataclasses import dataclass, field, replace
from datetime import date, datetime, timedelta, timezone
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np
import pynmea2

from ..counting import MAX_EXAMPLES, RejectCounter
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
_GLUED_RE = re.compile(r"(?<=\*[0-9A-Fa-f]{2})(?=[$!])")


def split_glued(line: str) -> list[str]:
    """The sentences of a line that holds several, each ended by its checksum (``$GPGGA,…*47$GPRMC,…*2A``:
    a line break lost in a receiver's or logger's buffer); ``[line]`` otherwise.  Each piece is then
    judged on its own, so a lost line break costs no epoch."""
    if line.count("$") + line.count("!") < 2:
        return [line]
    parts = _GLUED_RE.split(line.strip())
    return parts if len(parts) > 1 else [line]


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
    split_lines: list[int] = field(default_factory=list)
    """Line numbers (the first :data:`~tractionecu.counting.MAX_EXAMPLES`) of lines holding several
    sentences, each judged on its own (:func:`split_glued`); ``split_count`` counts them all."""
    split_count: int = 0
    prefixed_lines: list[int] = field(default_factory=list)
    """Line numbers (the first :data:`~tractionecu.counting.MAX_EXAMPLES`) of lines with text before their
    sentence (a logger's own time stamp), read from the sentence's ``$``; ``prefixed_count`` counts them all."""
    prefixed_count: int = 0

    def split(self, lineno: int) -> None:
        """Count one line split into its sentences."""
        self.split_count += 1
        if len(self.split_lines) < MAX_EXAMPLES:
            self.split_lines.append(lineno)

    def prefixed(self, lineno: int) -> None:
        """Count one line read from the ``$`` after a prefix."""
        self.prefixed_count += 1
        if len(self.prefixed_lines) < MAX_EXAMPLES:
            self.prefixed_lines.append(lineno)

    def notes(self) -> list[str]:
        """The lines split into several sentences, and those read past a prefix (they are not rejects:
        :meth:`RejectCounter.describe` lists those)."""
        out = []
        src = f"{self.source} " if self.source else ""
        if self.split_count:
            more = ", ..." if self.split_count > len(self.split_lines) else ""
            out.append(f"lines holding several sentences, split: {self.split_count} "
                       f"({src}line {', '.join(map(str, self.split_lines))}{more})")
        if self.prefixed_count:
            more = ", ..." if self.prefixed_count > len(self.prefixed_lines) else ""
            out.append(f"lines holding text before their sentence (a logger's time stamp), read from the "
                       f"sentence's $: {self.prefixed_count} ({src}line "
                       f"{', '.join(map(str, self.prefixed_lines))}{more})")
        return out


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
    for lineno, whole in enumerate(lines, start=first_lineno):
        st.lines += 1
        for rec in _parsed(whole, lineno, st):
            yield lineno, rec


def _parsed(line: str, lineno: int, st: NmeaStats) -> Iterator[NmeaRecord]:
    """The supported records of one line (each sentence of a glued line on its own, :func:`split_glued`),
    counting the line's rejects, ignored sentences and accepted records in ``st``."""
    head = line.lstrip()
    if head and head[0] not in "$!":
        # a logger that writes its own time (or a channel name) before each sentence: the sentence after it
        # is whole and is read (every line of such a log was garbage, and the replay had no GNSS)
        k = min((i for i in (head.find("$"), head.find("!")) if i > 0), default=-1)
        if k > 0:
            st.prefixed(lineno)
            line = head[k:]
    pieces = split_glued(line)
    if len(pieces) > 1:
        st.split(lineno)
    for piece in pieces:
        try:
            rec = parse_line(piece)
        except DecodeError as e:
            st.reject(getattr(e, "reason", "garbage"), lineno, piece)
            continue
        if rec is None:
            s = piece.strip()
            if s:
                st.ignored[sentence_label(s)] += 1
            continue
        st.accepted += 1
        yield rec


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
    with open(p, "r", encoding="utf-8-sig", errors="replace", newline=None) as fh:
        yield from assemble_epochs(iter_nmea(fh, st))


# --------------------------------------------------------------------------- fast path
# The fast path of the module doc ("Fast path (recordings)").  Details of the screen (_screen): '$', a
# talker of two upper-case letters not starting with P, GGA/RMC/VTG/ZDA, a comma, the usual number of
# fields for that sentence, then '*' and two hex digits that equal the XOR of the characters between '$'
# and '*', nothing but 0-9 A-Z '.' ',' '-' in between (no white space, no second '*' or '$', nothing
# non-ASCII), at most MAX_FAST_LINE characters.  For such a line pynmea2.parse(line, check=True) is
# exactly: the checksum holds, talker = line[1:3], sentence type = line[3:6], data =
# line[7:-3].split(','); of its address pattern only the proprietary ('P...') and query ('..xxQ,')
# branches could differ, and both are excluded.  The conversions (_fast_gga ... _fast_zda line by line,
# _block_gga ... _block_zda for a block) make every check of parse_line as well or more strictly; where
# one would fail or a conversion raises, the line goes one tier down.

MAX_FAST_LINE = 100
"""Longest line the fast path takes (NMEA 0183 allows 82 characters with CR LF)."""

FAST_SENTENCES = ("GGA", "RMC", "VTG", "ZDA")
"""Sentence types of the fast path; their accepted field counts are in :data:`_FAST_FIELDS`."""

_FAST_FIELDS = {1: (14,), 2: (11, 12, 13), 3: (8, 9), 4: (6,)}
"""Field counts after the address: GGA; RMC of NMEA 2.0 / 2.3 / 4.10; VTG without / with mode; ZDA."""

_SAFE = np.zeros(256, dtype=bool)
for _c in b"0123456789ABCDEFGHIJKLMNOPQRSTUVWXYZ.,-":
    _SAFE[_c] = True
_HEX = np.full(256, -1, dtype=np.int16)
for _k, _c in enumerate(b"0123456789ABCDEF"):
    _HEX[_c] = _k
for _k, _c in enumerate(b"abcdef"):
    _HEX[_c] = 10 + _k
_TYPE_CODE = {int.from_bytes(name.encode(), "big"): k + 1 for k, name in enumerate(FAST_SENTENCES)}


class _Fallback(Exception):
    """A fast-path line that parse_line must judge."""


def fast_kinds(lines: list[str]) -> np.ndarray:
    """Per line: 1..4 (GGA, RMC, VTG, ZDA) when the line is a sentence the fast path may take (block
    comment above: address, field count, character set and checksum all checked), else 0."""
    return _screen(lines)[0]


def _screen(lines: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(:func:`fast_kinds`, the block's bytes, each line's first and end offset in them)."""
    n = len(lines)
    kind = np.zeros(n, dtype=np.int8)
    if n == 0:
        e = np.zeros(0, dtype=np.int64)
        return kind, np.zeros(0, dtype=np.uint8), e, e
    lens = np.fromiter(map(len, lines), dtype=np.int64, count=n)
    buf = np.frombuffer("\n".join(lines).encode("ascii", "replace"), dtype=np.uint8)  # one byte a character
    starts = np.zeros(n, dtype=np.int64)
    np.cumsum(lens[:-1] + 1, out=starts[1:])
    ends = starts + lens
    cand = np.flatnonzero((lens >= 10) & (lens <= MAX_FAST_LINE))
    if cand.size == 0:
        return kind, buf, starts, ends
    s = starts[cand]
    e = ends[cand]
    ok = (buf[s] == 0x24) & (buf[e - 3] == 0x2A) & (buf[s + 6] == 0x2C)
    t1, t2 = buf[s + 1], buf[s + 2]
    ok &= (t1 >= 0x41) & (t1 <= 0x5A) & (t1 != 0x50) & (t2 >= 0x41) & (t2 <= 0x5A)
    code = (buf[s + 3].astype(np.int64) << 16) | (buf[s + 4].astype(np.int64) << 8) | buf[s + 5]
    k = np.zeros(cand.size, dtype=np.int8)
    for c, v in _TYPE_CODE.items():
        k[code == c] = v
    ok &= k > 0
    h1, h2 = _HEX[buf[e - 2]], _HEX[buf[e - 1]]
    ok &= (h1 >= 0) & (h2 >= 0)
    # per body (the characters between '$' and '*', at least 6 of them): unsafe characters, commas, XOR
    bounds = np.empty(2 * cand.size, dtype=np.int64)
    bounds[0::2] = s + 1
    bounds[1::2] = e - 3
    ok &= np.add.reduceat((~_SAFE[buf]).view(np.uint8), bounds, dtype=np.int64)[0::2] == 0
    nfields = np.add.reduceat((buf == 0x2C).view(np.uint8), bounds, dtype=np.int64)[0::2]   # after the address
    good_count = np.zeros(cand.size, dtype=bool)
    for kk, counts in _FAST_FIELDS.items():
        for c in counts:
            good_count |= (k == kk) & (nfields == c)
    ok &= good_count
    ok &= np.bitwise_xor.reduceat(buf, bounds)[0::2] == ((h1 << 4) | h2)
    kind[cand[ok]] = k[ok]
    return kind, buf, starts, ends


def _ff(s: str) -> float | None:
    """_f's value for a field that parse_line would accept; _Fallback where it would not."""
    if not s:
        return None
    v = float(s)
    if v != v or v == math.inf or v == -math.inf:
        raise _Fallback
    return v


def _fi(s: str) -> int | None:
    """_i's value where int() takes the text (else parse_line judges it)."""
    return int(s, 10) if s else None


def _ftod(s: str) -> float | None:
    if not s:
        return None
    if len(s) < 6 or not s[:6].isdigit():
        raise _Fallback
    h, m = int(s[0:2]), int(s[2:4])
    sec = float(s[4:])
    if h > 23 or m > 59 or not 0 <= sec < 61:      # also NaN and inf
        raise _Fallback
    return h * 3600.0 + m * 60.0 + sec


def _fcoord(value: str, hemi: str, deg_digits: int, pos: str, neg: str, limit: float) -> float | None:
    if not value and not hemi:
        return None
    if not value or not hemi:
        raise _Fallback
    head = value.split(".", 1)[0] if "." in value else value
    if len(head) != deg_digits + 2 or not head.isdigit():
        raise _Fallback
    deg = int(head[:deg_digits])
    minutes = float(value[deg_digits:])
    if not minutes < 60.0:                          # also NaN and inf
        raise _Fallback
    v = deg + minutes / 60.0
    if v > limit:
        raise _Fallback
    if hemi == pos:
        return v
    if hemi == neg:
        return -v
    raise _Fallback


_DATES: dict[str, date] = {}
_MODE_QUALITY: dict[str, int | None] = {}


def _fdate(s: str) -> date | None:
    if not s:
        return None
    d = _DATES.get(s)
    if d is None:
        if len(s) != 6 or not s.isdigit():
            raise _Fallback
        dd, m, y = int(s[0:2]), int(s[2:4]), int(s[4:6])
        try:
            d = date(2000 + y if y < 80 else 1900 + y, m, dd)
        except ValueError:
            raise _Fallback from None
        if len(_DATES) < 4096:
            _DATES[s] = d
    return d


def _fmode_quality(mode: str) -> int | None:
    q = _MODE_QUALITY.get(mode, -1)
    if q == -1:
        q = _quality_from_modes(mode)
        if len(_MODE_QUALITY) < 256:
            _MODE_QUALITY[mode] = q
    return q


def _fast_gga(line: str) -> tuple:
    d = line[7:-3].split(",")
    q = _fi(d[5])
    if q is not None and not 0 <= q <= 8:
        raise _Fallback
    return ("GGA", line[1:3], _ftod(d[0]), None, _fcoord(d[1], d[2], 2, "N", "S", 90.0),
            _fcoord(d[3], d[4], 3, "E", "W", 180.0), _ff(d[8]), _ff(d[10]), None, None, q, _fi(d[6]),
            _ff(d[7]), None, None)


def _fast_rmc(line: str) -> tuple:
    d = line[7:-3].split(",")
    status = d[1]
    if status != "A" and status != "V":
        raise _Fallback
    kn = _ff(d[6])
    mode = (d[11] if len(d) > 11 else "") or None
    return ("RMC", line[1:3], _ftod(d[0]), _fdate(d[8]), _fcoord(d[2], d[3], 2, "N", "S", 90.0),
            _fcoord(d[4], d[5], 3, "E", "W", 180.0), None, None, None if kn is None else kn * KNOT_MPS,
            _ff(d[7]), None if mode is None else _fmode_quality(mode), None, None, status == "A", mode)


def _fast_vtg(line: str) -> tuple:
    d = line[7:-3].split(",")
    kmh = _ff(d[6])
    kn = _ff(d[4])
    if kmh is not None:
        spd = kmh / 3.6
    elif kn is not None:
        spd = kn * KNOT_MPS
    else:
        spd = None
    mode = (d[8] if len(d) > 8 else "") or None
    return ("VTG", line[1:3], None, None, None, None, None, None, spd, _ff(d[0]), None, None, None, None, mode)


def _fast_zda(line: str) -> tuple:
    d = line[7:-3].split(",")
    day, month, year = _fi(d[1]), _fi(d[2]), _fi(d[3])
    zdate = None
    if day is not None and month is not None and year is not None:
        try:
            zdate = date(year, month, day)
        except (ValueError, OverflowError):
            raise _Fallback from None
    return ("ZDA", line[1:3], _ftod(d[0]), zdate, None, None, None, None, None, None, None, None, None, None,
            None)


_FAST = (None, _fast_gga, _fast_rmc, _fast_vtg, _fast_zda)


def fast_record(line: str, kind: int) -> tuple | None:
    """The field values of parse_line's :class:`NmeaRecord` for ``line`` (``NmeaRecord(*values)``), for a
    line of :func:`fast_kinds` ``kind`` 1..4; None where parse_line must judge the line."""
    try:
        return _FAST[kind](line)
    except (_Fallback, ValueError):
        return None


def record_values(rec: NmeaRecord) -> tuple:
    """An :class:`NmeaRecord`'s field values in field order (what :func:`fast_record` returns)."""
    return (rec.sentence, rec.talker, rec.tod_s, rec.date, rec.lat_deg, rec.lon_deg, rec.alt_m, rec.geoid_sep_m,
            rec.speed_mps, rec.course_deg, rec.fix_quality, rec.nsat, rec.hdop, rec.valid, rec.mode)


# ---- the fast path over a block of lines at once (numpy): the same values as fast_record, or None
_F10 = np.array([10.0 ** k for k in range(19)])        # exact: 10**k < 2**53 for k <= 15
MAX_FAST_DIGITS = 15
"""Digits of a number the block path converts: below 2**53, so ``N / 10**k`` is ``float()`` of the text."""


def _dec(buf: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The fields ``buf[a:b]`` as numbers written ``-?d+(.d+)?`` with at most :data:`MAX_FAST_DIGITS` digits:
    (ok, float value, integer digits N, decimals k).  The value is ``N / 10**k`` (negated after a '-'):
    both exact doubles, so the division's correctly rounded quotient is the correctly rounded value of
    the decimal, which is what ``float(text)`` returns.  ok is False for an empty field or another form.
    Compiled (:func:`_dec_fields_py` with numba) once numba is loaded in the process, else
    :func:`_dec_np`: the same four arrays, bit for bit, whatever the fields (``tests/gnss/test_nmea_fast.py``)."""
    fn = _compiled_dec()
    if fn is not None and a.size:
        return fn(buf, np.ascontiguousarray(a, dtype=np.int64), np.ascontiguousarray(b, dtype=np.int64), _F10)
    return _dec_np(buf, a, b)


def _dec_fields_py(buf: np.ndarray, a: np.ndarray, b: np.ndarray, f10: np.ndarray):
    """:func:`_dec_np` field by field (compiled with numba by :func:`_compiled_dec`): the same checks and the
    same arithmetic, also for the fields it declines (N of the digits read, k = 0, the sign)."""
    m = a.size
    top = buf.size - 1
    cap = MAX_FAST_DIGITS + 2
    W = 0
    for i in range(m):
        W = max(W, b[i] - a[i])
    W = min(W, cap)
    ok = np.zeros(m, dtype=np.bool_)
    val = np.zeros(m, dtype=np.float64)
    Ns = np.zeros(m, dtype=np.int64)
    ks = np.zeros(m, dtype=np.int64)
    for i in range(m):
        L = b[i] - a[i]
        N = 0
        ndig = 0
        k = 0
        ndot = 0
        bad = L > W
        neg = buf[min(a[i], top)] == 0x2D
        for j in range(min(L, W)):
            c = np.int64(buf[min(a[i] + j, top)]) - 0x30
            isd = 0 <= c <= 9
            isdot = c == 0x2E - 0x30
            if isd:
                N = N * 10 + c
                ndig += 1
                if ndot > 0:
                    k += 1
            elif not isdot and not (j == 0 and neg):
                bad = True
            if isdot:
                if ndig == 0:                           # a digit before the dot
                    bad = True
                ndot += 1
        good = not bad and ndot <= 1 and 1 <= ndig <= MAX_FAST_DIGITS and (ndot == 0 or k >= 1)
        if not good:
            k = 0
        v = N / f10[k]
        ok[i] = good
        val[i] = -v if neg else v
        Ns[i] = N
        ks[i] = k
    return ok, val, Ns, ks


_dec_fields = None
""":func:`_dec_fields_py` compiled, once :func:`_compiled_dec` has loaded it."""


def _compiled_dec():
    """The compiled field conversion, loaded on first use once numba is imported in this process (by the
    estimator's kernels, or batch replay); None before, so reading a log alone does not pay numba's start-up."""
    global _dec_fields
    if _dec_fields is None and "numba" in sys.modules:
        import numba

        _dec_fields = numba.njit(cache=True, nogil=True)(_dec_fields_py)
    return _dec_fields


def _dec_np(buf: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_dec` in numpy, one character position at a time over all fields (few positions, many
    fields): the reference of the compiled form and the path until numba is loaded."""
    m = a.size
    L = b - a
    W = int(min(L.max(initial=0), MAX_FAST_DIGITS + 2))
    top = buf.size - 1
    N = np.zeros(m, dtype=np.int64)
    ndig = np.zeros(m, dtype=np.int64)
    k = np.zeros(m, dtype=np.int64)                     # digits after the dot
    ndot = np.zeros(m, dtype=np.int64)
    bad = L > W
    neg = buf[np.minimum(a, top)] == 0x2D
    for j in range(W):
        inside = L > j
        c = buf[np.minimum(a + j, top)].astype(np.int64) - 0x30
        isd = (c >= 0) & (c <= 9) & inside
        isdot = (c == 0x2E - 0x30) & inside
        N = np.where(isd, N * 10 + c, N)
        ndig += isd
        k += isd & (ndot > 0)
        bad |= inside & ~isd & ~isdot & (~neg if j == 0 else True)
        bad |= isdot & (ndig == 0)                      # a digit before the dot
        ndot += isdot
    ok = ~bad & (ndot <= 1) & (ndig >= 1) & (ndig <= MAX_FAST_DIGITS) & ((ndot == 0) | (k >= 1))
    k = np.where(ok, k, 0)
    v = N / _F10[k]
    return ok, np.where(neg, -v, v), N, k


def _digits(buf: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(is a digit, its value) of the characters at ``pos``."""
    c = buf[pos].astype(np.int64) - 0x30
    return (c >= 0) & (c <= 9), c


class _Block:
    """The fields of the lines of one sentence type and field count: their spans in the block's bytes."""

    def __init__(self, buf: np.ndarray, commas: np.ndarray, s: np.ndarray, e: np.ndarray, nf: int) -> None:
        self.buf = buf
        first = np.searchsorted(commas, s + 6)          # the comma after the address
        P = commas[first[:, None] + np.arange(nf)]      # the body's commas, one per field
        self.a = P + 1
        self.b = np.empty_like(P)
        self.b[:, :-1] = P[:, 1:]
        self.b[:, -1] = e - 3
        self.m = s.size
        self.ok = np.ones(self.m, dtype=bool)

    def present(self, f: int) -> np.ndarray:
        return self.b[:, f] > self.a[:, f]

    def num(self, f: int) -> tuple[np.ndarray, np.ndarray]:
        """(present, value) of a number field (_ff); an unusual form declines the line."""
        pres = self.present(f)
        ok, v, _N, _k = _dec(self.buf, self.a[:, f], self.b[:, f])
        self.ok &= ok | ~pres
        return pres, v

    def int(self, f: int, max_digits: int = 4) -> tuple[np.ndarray, np.ndarray]:
        """(present, value) of an unsigned integer field (_fi) of at most ``max_digits`` digits."""
        pres = self.present(f)
        ok, _v, N, k = _dec(self.buf, self.a[:, f], self.b[:, f])
        neg = self.buf[np.minimum(self.a[:, f], self.buf.size - 1)] == 0x2D
        self.ok &= (ok & (k == 0) & ~neg & (self.b[:, f] - self.a[:, f] <= max_digits)) | ~pres
        return pres, N

    def tod(self, f: int) -> tuple[np.ndarray, np.ndarray]:
        """(present, time of day [s]) of a hhmmss[.s] field (_ftod)."""
        a, b = self.a[:, f], self.b[:, f]
        pres = b > a
        top = self.buf.size - 1
        ok = b - a >= 6
        d = [_digits(self.buf, np.minimum(a + i, top)) for i in range(6)]
        for isd, _ in d:
            ok &= isd
        h = d[0][1] * 10 + d[1][1]
        mi = d[2][1] * 10 + d[3][1]
        oks, sec, _N, _k = _dec(self.buf, np.minimum(a + 4, b), b)
        ok &= oks & (h <= 23) & (mi <= 59) & (sec >= 0) & (sec < 61)
        self.ok &= ok | ~pres
        return pres, h * 3600.0 + mi * 60.0 + sec

    def char(self, f: int) -> np.ndarray:
        """The field's character code when it is one character long, else 0."""
        one = self.b[:, f] - self.a[:, f] == 1
        return np.where(one, self.buf[np.minimum(self.a[:, f], self.buf.size - 1)], 0)

    def coord(self, f: int, deg_digits: int, pos: str, neg: str, limit: float) -> tuple[np.ndarray, np.ndarray]:
        """(present, degrees) of a value and hemisphere field pair (_fcoord)."""
        a, b = self.a[:, f], self.b[:, f]
        pv = b > a
        ph = self.present(f + 1)
        hemi = self.char(f + 1)
        top = self.buf.size - 1
        ok = b - a >= deg_digits + 2
        deg = np.zeros(self.m, dtype=np.int64)
        for i in range(deg_digits + 2):
            isd, c = _digits(self.buf, np.minimum(a + i, top))
            ok &= isd
            if i < deg_digits:
                deg = deg * 10 + c
        after = self.buf[np.minimum(a + deg_digits + 2, top)]
        ok &= (b - a == deg_digits + 2) | (after == 0x2E)
        okm, minutes, _N, _k = _dec(self.buf, np.minimum(a + deg_digits, b), b)
        v = deg + minutes / 60.0
        sgn_neg = hemi == ord(neg)
        ok &= okm & (minutes >= 0) & (minutes < 60.0) & (v <= limit) & ((hemi == ord(pos)) | sgn_neg)
        self.ok &= (ok & pv & ph) | (~pv & ~ph)
        return pv, np.where(sgn_neg, -v, v)

    def text(self, f: int, max_len: int = 2) -> list[str | None]:
        """The field's text (None when empty), for fields of at most ``max_len`` letters A-Z."""
        a, b = self.a[:, f], self.b[:, f]
        L = b - a
        top = self.buf.size - 1
        code = L.copy()
        for i in range(max_len):
            c = np.where(i < L, self.buf[np.minimum(a + i, top)], 0).astype(np.int64)
            self.ok &= (i >= L) | ((c >= 0x41) & (c <= 0x5A))
            code = (code << 8) | c
        self.ok &= L <= max_len
        names = {}
        for u in np.unique(code).tolist():
            n = u >> (8 * max_len)
            names[u] = None if n == 0 or n > max_len else bytes(
                (u >> (8 * (max_len - 1 - i))) & 0xFF for i in range(n)).decode("ascii")
        return [names[u] for u in code.tolist()]


def _col(present: np.ndarray, values: np.ndarray) -> list:
    """Python values, None where the field is empty."""
    o = values.astype(object)
    o[~present] = None
    return o.tolist()


def _talkers(buf: np.ndarray, s: np.ndarray) -> list[str]:
    code = (buf[s + 1].astype(np.int64) << 8) | buf[s + 2]
    names = {u: chr(u >> 8) + chr(u & 0xFF) for u in np.unique(code).tolist()}
    return [names[u] for u in code.tolist()]


# A block's fields: {NmeaRecord field name: (present, values)} for numbers (and the RMC status as bools),
# lists of Python values for the talker, dates and mode letters; fields not listed are None.
def _block_gga(blk: _Block) -> dict:
    pq, q = blk.int(5, 1)
    blk.ok &= ~pq | (q <= 8)
    return {"tod_s": blk.tod(0), "lat_deg": blk.coord(1, 2, "N", "S", 90.0),
            "lon_deg": blk.coord(3, 3, "E", "W", 180.0), "alt_m": blk.num(8), "geoid_sep_m": blk.num(10),
            "fix_quality": (pq, q), "nsat": blk.int(6), "hdop": blk.num(7)}


def _block_rmc(blk: _Block, nf: int) -> dict:
    status = blk.char(1)
    blk.ok &= (status == 0x41) | (status == 0x56)
    pk, kn = blk.num(6)
    m = blk.m
    modes = blk.text(11) if nf > 11 else [None] * m
    a, b = blk.a[:, 8], blk.b[:, 8]                       # date ddmmyy: 6 digits or empty
    pd = b > a
    dcode = np.zeros(m, dtype=np.int64)
    okd = b - a == 6
    for i in range(6):
        isd, c = _digits(blk.buf, np.minimum(a + i, blk.buf.size - 1))
        okd &= isd
        dcode = dcode * 10 + c
    blk.ok &= okd | ~pd
    dates: dict[int, date | None] = {}
    for u in np.unique(dcode[okd & blk.ok]).tolist():
        try:
            dates[u] = _fdate(f"{u:06d}")
        except _Fallback:
            dates[u] = None
    good = np.array([u for u, d in dates.items() if d is not None], dtype=np.int64)
    blk.ok &= ~pd | np.isin(dcode, good)
    return {"tod_s": blk.tod(0), "date": [dates.get(u) if p else None for u, p in zip(dcode.tolist(), pd.tolist())],
            "lat_deg": blk.coord(2, 2, "N", "S", 90.0), "lon_deg": blk.coord(4, 3, "E", "W", 180.0),
            "speed_mps": (pk, kn * KNOT_MPS), "course_deg": blk.num(7),
            "fix_quality": [None if md is None else _fmode_quality(md) for md in modes],
            "valid": (np.ones(m, dtype=bool), status == 0x41), "mode": modes}


def _block_vtg(blk: _Block, nf: int) -> dict:
    pkmh, kmh = blk.num(6)
    pkn, kn = blk.num(4)
    return {"speed_mps": (pkmh | pkn, np.where(pkmh, kmh / 3.6, kn * KNOT_MPS)), "course_deg": blk.num(0),
            "mode": blk.text(8) if nf > 8 else [None] * blk.m}


def _block_zda(blk: _Block) -> dict:
    pday, day = blk.int(1, 2)
    pmon, mon = blk.int(2, 2)
    pyr, yr = blk.int(3, 4)
    dates: list[date | None] = [None] * blk.m
    for i in np.flatnonzero(pday & pmon & pyr & blk.ok).tolist():
        try:
            dates[i] = date(int(yr[i]), int(mon[i]), int(day[i]))
        except ValueError:
            blk.ok[i] = False
    return {"tod_s": blk.tod(0), "date": dates}


_RECORD_FIELDS = ("sentence", "talker", "tod_s", "date", "lat_deg", "lon_deg", "alt_m", "geoid_sep_m", "speed_mps",
                  "course_deg", "fix_quality", "nsat", "hdop", "valid", "mode")
""":class:`NmeaRecord`'s fields in order."""


def _block_groups(lines: list[str]) -> tuple[np.ndarray, list[tuple[int, np.ndarray, list[str], _Block, dict]]]:
    """(kinds, groups): per sentence type and field count of the fast-path lines, (kind, the lines' rows,
    talkers, the block with its ok mask, the fields)."""
    kind, buf, starts, ends = _screen(lines)
    groups: list = []
    if not kind.any():
        return kind, groups
    commas = np.flatnonzero(buf == 0x2C)
    fast = kind > 0
    nf_all = np.zeros(len(lines), dtype=np.int64)
    nf_all[fast] = np.searchsorted(commas, ends[fast] - 3) - np.searchsorted(commas, starts[fast] + 1)
    for k in range(1, 5):
        rows = np.flatnonzero(kind == k)
        if rows.size == 0:
            continue
        nfs = nf_all[rows]
        for nf in np.unique(nfs).tolist():
            r = rows[nfs == nf]
            blk = _Block(buf, commas, starts[r], ends[r], nf)
            if k == 1:
                fields = _block_gga(blk)
            elif k == 2:
                fields = _block_rmc(blk, nf)
            elif k == 3:
                fields = _block_vtg(blk, nf)
            else:
                fields = _block_zda(blk)
            groups.append((k, r, _talkers(buf, starts[r]), blk, fields))
    return kind, groups


def fast_block(lines: list[str]) -> tuple[list, np.ndarray]:
    """(values, kinds) of a block of lines: ``values[i]`` what :func:`fast_record` gives for line i,
    converted for all lines of one sentence type and field count at once, or None where the line is not a
    fast-path line or is of a form the block conversion leaves to :func:`fast_record` (numbers with an
    exponent, a trailing dot or more than :data:`MAX_FAST_DIGITS` digits, longer mode fields, ...)."""
    kind, groups = _block_groups(lines)
    out: list = [None] * len(lines)
    for k, r, talkers, blk, fields in groups:
        m = blk.m
        cols = []
        for name in _RECORD_FIELDS:
            f = fields.get(name)
            if name == "sentence":
                cols.append([FAST_SENTENCES[k - 1]] * m)
            elif name == "talker":
                cols.append(talkers)
            elif f is None:
                cols.append([None] * m)
            elif isinstance(f, tuple):
                cols.append(_col(*f))
            else:
                cols.append(f)
        for i, v, good in zip(r.tolist(), zip(*cols), blk.ok.tolist()):
            if good:
                out[i] = v
    return out, kind


def fast_columns(lines: list[str]) -> dict[str, Any] | None:
    """The records of a block of lines as columns in line order, when every line is converted by the block
    conversion (:func:`fast_block`'s values, field by field); else None.

    ``sentence``: 1..4 (GGA, RMC, VTG, ZDA); each number field ``(present, values)`` (``fix_quality`` and
    ``nsat`` as int64, the others float64, ``valid`` bool); ``date`` a list of dates or None.  The talker,
    the geoid separation and the mode letters, which no epoch keeps, are left out."""
    n = len(lines)
    kind, groups = _block_groups(lines)
    if n == 0 or not kind.all() or not all(blk.ok.all() for _k, _r, _t, blk, _f in groups):
        return None
    out: dict[str, Any] = {"sentence": kind}
    for name, dtype in (("tod_s", float), ("lat_deg", float), ("lon_deg", float), ("alt_m", float),
                        ("speed_mps", float), ("course_deg", float), ("fix_quality", np.int64),
                        ("nsat", np.int64), ("hdop", float), ("valid", bool)):
        present = np.zeros(n, dtype=bool)
        values = np.zeros(n, dtype=dtype)
        for _k, r, _t, _blk, fields in groups:
            f = fields.get(name)
            if f is None:
                continue
            if isinstance(f, list):                        # the RMC's fix quality from its mode letters
                p = np.array([q is not None for q in f], dtype=bool)
                f = (p, np.array([0 if q is None else q for q in f], dtype=dtype))
            present[r] = f[0]
            values[r] = f[1]
        out[name] = (present, values)
    dates: list = [None] * n
    for _k, r, _t, _blk, fields in groups:
        if "date" in fields:
            for i, d in zip(r.tolist(), fields["date"]):
                dates[i] = d
    out["date"] = dates
    return out


def iter_line_blocks(fh: Any, chunk_chars: int = 1 << 20) -> Iterator[list[str]]:
    """The lines of the text file ``fh`` (without their line breaks) in blocks of about ``chunk_chars``
    characters, whole lines, as iterating over the file gives them.  The text after the last line break is
    kept in pieces and joined once, so a line longer than a block costs its length."""
    carry: list[str] = []
    while True:
        block = fh.read(chunk_chars)
        if not block:
            if carry:
                yield ["".join(carry)]
            return
        cut = block.rfind("\n") + 1
        if not cut:
            carry.append(block)
            continue
        lines = ("".join(carry) + block[:cut - 1]).split("\n")
        carry = [block[cut:]] if cut < len(block) else []
        yield lines


def iter_nmea_fast(fh: Any, stats: NmeaStats, chunk_chars: int = 1 << 20) -> Iterator[tuple[int, tuple]]:
    """:func:`iter_nmea` over the text file ``fh`` (opened as :func:`read_nmea` opens it), yielding
    ``(line number, record values)`` (:func:`record_values`), with the same counts in ``stats``: lines
    the fast path takes are converted by it, every other line by :func:`parse_line`.  Reads
    ``chunk_chars`` characters at a time."""
    st = stats
    lineno0 = 0
    fast = _FAST
    for lines in iter_line_blocks(fh, chunk_chars):
        st.lines += len(lines)
        block_vals, kind = fast_block(lines)
        kinds = kind.tolist()
        for i, line in enumerate(lines):
            vals = block_vals[i]
            if vals is None and kinds[i]:
                try:
                    vals = fast[kinds[i]](line)
                except (_Fallback, ValueError):
                    pass
            if vals is not None:
                st.accepted += 1
                yield lineno0 + i + 1, vals
                continue
            for rec in _parsed(line, lineno0 + i + 1, st):
                yield lineno0 + i + 1, record_values(rec)
        lineno0 += len(lines)
