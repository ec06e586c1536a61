"""NMEA 0183 from a serial port (pyserial) without blocking the event loop.

The port is opened with ``timeout=0`` (non-blocking) and its file descriptor
is watched by the event loop (``loop.add_reader``); each wake-up reads what
is there, splits lines and parses them strictly
(:func:`tractionecu.gnss.nmea.parse_line`: checksum required; GGA, RMC,
VTG, GNS, ZDA of any talker).  A read error or end of file (USB receiver
unplugged, pty closed) closes the port; it is reopened with a doubling
backoff until it is back.

Epochs
------
Sentences are grouped into receiver epochs by UTC time of day
(:class:`~tractionecu.gnss.nmea.EpochAssembler`, the same grouping
``replay`` uses).  An epoch is handed on as soon as it holds every sentence
type the previous epoch had (so a GGA+RMC+VTG receiver costs no extra
epoch of latency), otherwise when the next epoch starts.  Until one epoch
has been seen, GGA+RMC+VTG is expected.

Gating and time
---------------
A fix goes through the pipeline's GNSS gate
(:class:`~tractionecu.pipeline.gnss.GnssGate`, the rule replay applies to a
recorded track): RMC status not ``V``, fix quality at least
``gps.min_fix_quality``, HDOP at most ``gps.max_hdop``, a position, later
than the fix accepted before it, and arriving at most ``max_age_s`` after
its epoch; otherwise it is counted under ``gated_<reason>``.  Its time on
the service axis is its UTC epoch (:mod:`tractionecu.gnss.utc`: RMC/ZDA
date, else the date nearest the arrival time) when that lies within
:data:`UTC_TOLERANCE_S` of its arrival time (the host clock follows UTC, as
``replay`` assumes), else the arrival time minus ``gps.latency_s`` (counted
as ``time_from_arrival``).

The arrival time of an epoch is that of the read that brought its first
sentence, but a read that brings several epochs at once (the process was
not scheduled, or busy with estimation steps, while the port filled) says
only that the older ones waited in the port: the receiver sends its epochs
in order, so each epoch of one read is given the age of the newest epoch of
that read (arrival = read time − (newest epoch − its epoch), counted as
``arrival_from_newer``).  Otherwise the daemon's own late read would make an
epoch that came on time "stale", or stamp it from the arrival (and drop the
next ones as ``repeated``), where ``replay`` of the same recording uses it.
A receiver that itself sends old epochs is still found: the newest epoch of
its read is old too.

Counters (:attr:`GpsReader.stats`): ``lines``, ``fixes``, ``accepted``,
``rejected_<reason>`` (garbage, missing_checksum, bad_checksum, bad_field,
overlong), ``ignored`` (valid sentences of other types), ``gated_<reason>``
(invalid, fix_quality, hdop, no_position, repeated, stale), ``time_from_arrival``,
``arrival_from_newer``, ``opens``,
``open_failures``, ``link_failures``.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections import Counter
from dataclasses import dataclass
from datetime import date
from typing import Any, Callable

from ..aio import wait_event
from ..counting import WarnOnce
from ..errors import DecodeError
from ..gnss.nmea import EpochAssembler, GpsFix, parse_line, split_glued
from ..gnss.utc import nearest_date, utc_epoch
from ..pipeline.gnss import GnssGate
from .clock import ServiceClock
from .config import GpsConfig

log = logging.getLogger(__name__)

UTC_TOLERANCE_S = 0.5
"""Largest |UTC epoch − arrival time| for which the UTC epoch is taken as the fix time [service s]."""
READ_CHUNK = 4096
INITIAL_EPOCH_TYPES = frozenset({"GGA", "RMC", "VTG"})
"""Sentence types expected in an epoch until the receiver's own set has been seen once."""


@dataclass(frozen=True)
class GpsSample:
    """One accepted GNSS epoch on the service time axis.

    ``t`` [s] service time of the epoch; ``t_arrival`` [s] when its first
    sentence arrived; ``lat_deg``/``lon_deg`` [deg WGS84]; ``alt_m`` [m];
    ``speed_mps`` [m/s] (None if no sentence gave it); ``course_deg``
    [deg]; ``fix_quality``, ``hdop`` [-], ``nsat``.
    """

    t: float
    t_arrival: float
    lat_deg: float
    lon_deg: float
    alt_m: float | None
    speed_mps: float | None
    course_deg: float | None
    fix_quality: int | None
    hdop: float | None
    nsat: int | None


class NmeaStream:
    """Bytes in, gated :class:`GpsSample` out (no I/O: the reader and tests feed it).

    Parameters
    ----------
    cfg:
        The ``[gps]`` table (line limit, latency; gating thresholds when ``gate`` is not given).
    on_sample:
        Called with each accepted sample.
    gate:
        The GNSS gate (default: from ``cfg`` and the default fix age).
    """

    def __init__(self, cfg: GpsConfig, on_sample: Callable[[GpsSample], None], gate: GnssGate | None = None) -> None:
        self.cfg = cfg
        self.gate = gate or GnssGate(cfg.min_fix_quality, cfg.max_hdop)
        self.on_sample = on_sample
        self.stats: Counter[str] = Counter()
        self._buf = bytearray()
        self._asm = EpochAssembler()
        self._lineno = 0
        self._cur_tod: float | None = None
        self._cur_types: set[str] = set()
        self._cur_arrival = math.nan
        self._prev_types: frozenset[str] = INITIAL_EPOCH_TYPES
        self._emitted_tod: float | None = None
        self._last_date: date | None = None
        self._last_t = -math.inf
        self._from_utc = False
        self.last_sample: GpsSample | None = None
        self.max_delay_s = 0.0
        """Largest arrival − UTC time of an epoch [s] (receiver output latency plus transport)."""
        self._warn = WarnOnce(log)
        self._pending: list[tuple[GpsFix, float]] = []
        self._read_tod: float | None = None

    def reset_line(self) -> None:
        """Forget a partial line (after the port was reopened)."""
        self._buf.clear()

    def feed(self, data: bytes, t_arrival: float) -> None:
        """Add received bytes; ``t_arrival`` is their arrival [service s]."""
        buf = self._buf
        buf += data
        self._read_tod = None
        try:
            self._lines(buf, t_arrival)
        finally:
            self._release(t_arrival)

    def _lines(self, buf: bytearray, t_arrival: float) -> None:
        while True:
            i = buf.find(b"\n")
            if i < 0:
                if len(buf) > self.cfg.max_line_bytes:
                    self._reject("overlong", bytes(buf[:40]).decode("ascii", "replace"))
                    buf.clear()
                return
            line = bytes(buf[:i])
            del buf[: i + 1]
            if len(line) > self.cfg.max_line_bytes:
                self._reject("overlong", line[:40].decode("ascii", "replace"))
                continue
            text = line.decode("ascii", "replace")
            pieces = split_glued(text)
            if len(pieces) > 1:              # a lost line break: each sentence on its own
                self.stats["split_lines"] += 1
            for piece in pieces:
                self._line(piece, t_arrival)

    def _reject(self, reason: str, text: str) -> None:
        self.stats["lines"] += 1
        self.stats["rejected_" + reason] += 1
        self._warn(reason, "NMEA line rejected (%s): %r", reason, text[:60])

    def _line(self, text: str, t_arrival: float) -> None:
        self._lineno += 1
        if not text.strip():
            return
        try:
            rec = parse_line(text)
        except DecodeError as e:
            self._reject(getattr(e, "reason", "garbage"), text)
            return
        self.stats["lines"] += 1
        if rec is None:
            self.stats["ignored"] += 1
            return
        if rec.tod_s is not None:
            self._read_tod = rec.tod_s       # the newest epoch time of this read (epochs come in order)
        closing_arrival = self._cur_arrival
        if rec.tod_s is not None and (self._cur_tod is None or abs(rec.tod_s - self._cur_tod) > 1e-3):
            if self._cur_types:
                self._prev_types = frozenset(self._cur_types)
            self._cur_tod = rec.tod_s
            self._cur_types = set()
            self._cur_arrival = t_arrival
        done = self._asm.push(self._lineno, rec)
        if done is not None:
            self._emit(done, closing_arrival)
        if rec.tod_s is not None or rec.sentence == "VTG":
            self._cur_types.add(rec.sentence)
        if self._prev_types and self._prev_types <= self._cur_types:
            fix = self._asm.flush()
            if fix is not None:
                self._emit(fix, self._cur_arrival)

    def _emit(self, fix: GpsFix, t_arrival: float) -> None:
        if self._emitted_tod is not None and abs(fix.tod_s - self._emitted_tod) <= 1e-3:
            return  # rest of an epoch already handed on
        self._emitted_tod = fix.tod_s
        self._pending.append((fix, t_arrival))

    def _release(self, t_read: float) -> None:
        """Judge and hand on the epochs completed by the read at ``t_read`` (module doc: an epoch is as
        old as the newest epoch of the read that brought it, and never arrived later than its first
        sentence)."""
        pending, self._pending = self._pending, []
        newest = self._read_tod
        for fix, t_arrival in pending:
            if newest is not None and math.isfinite(t_read):
                behind = (newest - fix.tod_s) % 86400.0
                if 0.0 < behind < 43200.0 and t_read - behind < t_arrival:
                    t_arrival = t_read - behind
                    self.stats["arrival_from_newer"] += 1
            self._accept(fix, t_arrival)

    def _accept(self, fix: GpsFix, t_arrival: float) -> None:
        self.stats["fixes"] += 1
        if fix.date is not None:
            self._last_date = fix.date
        q = fix.fix_quality
        reason = self.gate.reason(fix.valid, q, fix.hdop, fix.lat_deg, fix.lon_deg)
        t = self._fix_time(fix.tod_s, t_arrival) if reason is None else math.nan
        if reason is None and t <= self._last_t:
            reason = "repeated"
        if reason is None and self._from_utc and not self.gate.fresh(t, t_arrival):
            reason = "stale"  # (an arrival-stamped epoch is exactly gps.latency_s old, as configured)
        if reason is not None:
            self.stats["gated_" + reason] += 1
            return
        self._last_t = t
        self.stats["accepted"] += 1
        s = GpsSample(t, t_arrival, float(fix.lat_deg), float(fix.lon_deg), fix.alt_m,  # type: ignore[arg-type]
                      fix.speed_mps, fix.course_deg, q, fix.hdop, fix.nsat)
        self.last_sample = s
        self.on_sample(s)

    def _fix_time(self, tod_s: float, t_arrival: float) -> float:
        d = self._last_date if self._last_date is not None else nearest_date(t_arrival, tod_s)
        if d is not None and math.isfinite(t_arrival):
            best = utc_epoch(d, tod_s)
            if abs(best - t_arrival) <= UTC_TOLERANCE_S:
                self.max_delay_s = max(self.max_delay_s, t_arrival - best)
                self._from_utc = True
                return best
        self._from_utc = False
        self.stats["time_from_arrival"] += 1
        return t_arrival - self.cfg.latency_s


class GpsReader:
    """Supervised serial port feeding an :class:`NmeaStream`.

    Parameters
    ----------
    cfg:
        The ``[gps]`` table.
    on_sample:
        Called on the event-loop thread with each accepted :class:`GpsSample`.
    clock:
        Service clock (arrival times).
    serial_factory:
        Opens the port (default ``serial.Serial``); called as
        ``serial_factory(port=..., baudrate=..., timeout=0)``.
    gate:
        The GNSS gate (default: from ``cfg``).
    """

    def __init__(self, cfg: GpsConfig, on_sample: Callable[[GpsSample], None], clock: ServiceClock, *,
                 serial_factory: Callable[..., Any] | None = None, gate: GnssGate | None = None) -> None:
        self.cfg = cfg
        self.clock = clock
        self.stream = NmeaStream(cfg, on_sample, gate)
        self.stats = self.stream.stats
        self.serial_factory = serial_factory
        self.is_open = asyncio.Event()
        self.last_error = ""
        self._port: Any = None
        self._fd: int | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._failed: asyncio.Future[str] | None = None
        self._closing = False
        self._closed = asyncio.Event()     # wakes a backoff at close
        self._warn = WarnOnce(log)

    def _factory(self) -> Callable[..., Any]:
        if self.serial_factory is None:
            import serial

            self.serial_factory = serial.Serial
        return self.serial_factory

    def _open(self) -> Any:
        port = self._factory()(port=self.cfg.port, baudrate=self.cfg.baudrate, timeout=0)
        try:
            port.reset_input_buffer()
        except Exception:  # not every port supports it (pty, loop://)
            pass
        return port

    async def run(self) -> None:
        """Open, read, and reopen after failures until :meth:`close`."""
        self._loop = loop = asyncio.get_running_loop()
        backoff = self.cfg.reopen_min_s
        while not self._closing:
            try:
                port = await loop.run_in_executor(None, self._open)
            except asyncio.CancelledError:
                raise
            except Exception as e:  # SerialException, OSError, ValueError
                self.stats["open_failures"] += 1
                self.last_error = f"open: {e}"
                self._warn("open", "GPS %s: cannot open (%s); retrying", self.cfg.port, e)
                await wait_event(self._closed, backoff)
                backoff = min(2 * backoff, self.cfg.reopen_max_s)
                continue
            if self._closing:
                port.close()
                break
            backoff = self.cfg.reopen_min_s
            self.stats["opens"] += 1
            self._warn.forget("open")
            (log.warning if self.stats["opens"] > 1 else log.info)("GPS %s: open", self.cfg.port)
            reason = await self._serve(port)
            if self._closing:
                break
            self.stats["link_failures"] += 1
            self.last_error = reason
            self._warn("link", "GPS %s: lost (%s); reopening", self.cfg.port, reason)
            await wait_event(self._closed, backoff)
            backoff = min(2 * backoff, self.cfg.reopen_max_s)

    async def _serve(self, port: Any) -> str:
        loop = self._loop
        assert loop is not None
        self._failed = loop.create_future()
        self._port = port
        self.stream.reset_line()
        self._fd = port.fileno()
        loop.add_reader(self._fd, self._on_readable)
        self.is_open.set()
        try:
            return await self._failed
        finally:
            self.is_open.clear()
            if self._fd is not None:
                loop.remove_reader(self._fd)
                self._fd = None
            self._port = None
            try:
                port.close()
            except Exception as e:
                log.debug("GPS close: %s", e)

    def _fail(self, reason: str) -> None:
        if self._failed is not None and not self._failed.done():
            self._failed.set_result(reason)

    def _on_readable(self) -> None:
        port = self._port
        if port is None:
            return
        try:
            data = port.read(READ_CHUNK)
        except Exception as e:  # SerialException: device gone / EIO on a closed pty
            if self._fd is not None and self._loop is not None:
                self._loop.remove_reader(self._fd)
                self._fd = None
            self._fail(f"read: {e}")
            return
        if data:
            self.stream.feed(data, self.clock.now())

    def drain(self) -> None:
        """Read whatever the port holds now (called before each estimator step, so an epoch
        that arrived while the process was not scheduled is not used a step late)."""
        if self._port is not None and self._fd is not None:
            self._on_readable()

    async def close(self) -> None:
        """Stop reading and close the port (also ends a wait before the next open)."""
        self._closing = True
        self._closed.set()
        self._fail("closed")
