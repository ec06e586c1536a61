"""``run --simulate``: the built-in simulator plays the rest of the tractor.

A simulated recording (:mod:`tractionecu.sim`) is played in real time (or
``speed`` times faster) into the real service code (the simulator drives the
service; the service never imports the simulator):

* CAN frames go onto a python-can ``virtual`` bus channel from a second bus
  object, stamped with their recorded times (``preserve_timestamps``), as a
  kernel would stamp them on SocketCAN;
* NMEA lines are written to the master side of a pseudo-terminal at their
  epoch times; the service opens the slave side (``/dev/pts/N``) with
  pyserial, exactly as it opens a USB receiver.

The player runs in its own thread and never touches the service's objects;
the only links are the bus channel and the pty.
"""

from __future__ import annotations

import asyncio
import logging
import math
import os
import threading
import time
import tty
import uuid
from dataclasses import dataclass, field
from datetime import date
from pathlib import Path
from typing import IO, Any, Callable, Iterator

import can

from ..bus.candump import read_candump
from ..errors import DecodeError
from ..gnss.nmea import parse_line
from ..gnss.utc import utc_epoch
from ..service.clock import ServiceClock

log = logging.getLogger(__name__)

SEND_AHEAD_S = 0.0
"""Frames are sent when the service clock reaches their time stamp [s]."""
LEAD_WALL_S = 1.0
"""The service starts this many wall seconds before the first simulated frame (time to open and claim)."""
READY_MARGIN_WALL_S = 0.2
"""The service must be ready (bus and pty open) this many wall seconds before the first frame is due."""
START_ATTEMPTS = 4
"""Starts of the service tried, each with a longer lead, before the recording is played anyway."""


def nmea_schedule(path: str | Path) -> list[tuple[float, str]]:
    """``(epoch time [s], line)`` for each line of an NMEA file, from the sentences' UTC time and date.

    Lines without a time (VTG) take the time of the epoch before them.  The
    date comes from the RMC/ZDA sentences (the first one dates the lines
    before it); a time of day that drops by more than 12 h starts a new day.
    """
    lines = Path(path).read_text(encoding="ascii", errors="replace").splitlines()
    parsed: list[tuple[str, float | None, date | None]] = []
    first_date: date | None = None
    for ln in lines:
        if not ln.strip():
            continue
        try:
            rec = parse_line(ln)
        except DecodeError:
            rec = None
        tod = rec.tod_s if rec is not None else None
        d = rec.date if rec is not None else None
        if d is not None and first_date is None:
            first_date = d
        parsed.append((ln, tod, d))
    if first_date is None:
        raise ValueError(f"{path}: no RMC/ZDA date: cannot place the lines in time")
    out: list[tuple[float, str]] = []
    day = first_date
    prev_tod: float | None = None
    t_last = -math.inf
    # lines before the first dated sentence use the first date
    for ln, tod, d in parsed:
        if tod is not None:
            if prev_tod is not None and tod < prev_tod - 43200.0:
                day = date.fromordinal(day.toordinal() + 1)
            if d is not None:
                day = d
            prev_tod = tod
            t_last = utc_epoch(day, tod)
        out.append((t_last, ln))
    t_first = next((t for t, _ in out if math.isfinite(t)), 0.0)
    return [(t if math.isfinite(t) else t_first, ln) for t, ln in out]


class SimulatedMachine:
    """Plays a recording directory onto a virtual CAN channel and a pty.

    Parameters
    ----------
    recording:
        Directory with ``can.log`` and ``gps.nmea``.
    clock:
        The service clock (recording times are service times).
    channel:
        Virtual CAN channel name (default: a fresh unique one).

    Attributes
    ----------
    port:
        Path of the pty slave for the service's ``gps.port``.
    done:
        Set when everything has been played (or :meth:`stop` was called).
    counts:
        ``frames`` and ``lines`` played.
    """

    def __init__(self, recording: str | Path, clock: ServiceClock, channel: str | None = None) -> None:
        self.recording = Path(recording)
        self.clock = clock
        self.channel = channel or f"tractionecu-sim-{uuid.uuid4().hex[:8]}"
        self.done = threading.Event()
        self.counts = {"frames": 0, "lines": 0, "lines_dropped": 0}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no CR/LF translation before pyserial opens it
        os.set_blocking(self._master, False)  # a full pty buffer drops lines instead of stalling the bus
        self.port = os.ttyname(self._slave)
        self._nmea = nmea_schedule(self.recording / "gps.nmea") if (self.recording / "gps.nmea").exists() else []
        self.bus = can.Bus(interface="virtual", channel=self.channel, preserve_timestamps=True)
        first = next(iter(read_candump(self.recording / "can.log")), None)
        self.t_first = first.t if first is not None else (self._nmea[0][0] if self._nmea else time.time())

    def _events(self) -> Iterator[tuple[float, int, object]]:
        """Frames and lines merged in time order: (t, kind 0 CAN / 1 NMEA, payload)."""
        lines = iter(self._nmea)
        nxt = next(lines, None)
        for fr in read_candump(self.recording / "can.log"):
            while nxt is not None and nxt[0] <= fr.t:
                yield nxt[0], 1, nxt[1]
                nxt = next(lines, None)
            yield fr.t, 0, fr
        while nxt is not None:
            yield nxt[0], 1, nxt[1]
            nxt = next(lines, None)

    def start(self) -> None:
        """Start playing in a background thread."""
        self._thread = threading.Thread(target=self._play, name="sim-player", daemon=True)
        self._thread.start()

    def _play(self) -> None:
        clock = self.clock
        try:
            for t, kind, payload in self._events():
                if self._stop.is_set():
                    break
                wait = clock.mono_at(t - SEND_AHEAD_S) - time.monotonic()
                if wait > 0 and self._stop.wait(wait):
                    break
                if kind == 0:
                    fr = payload
                    msg = can.Message(timestamp=fr.t, arbitration_id=fr.can_id,  # type: ignore[attr-defined]
                                      is_extended_id=fr.is_extended, data=fr.data)  # type: ignore[attr-defined]
                    try:
                        self.bus.send(msg)
                        self.counts["frames"] += 1
                    except can.CanError as e:
                        log.debug("simulated frame not sent: %s", e)
                else:
                    data = (str(payload) + "\r\n").encode("ascii", "replace")
                    try:
                        os.write(self._master, data)
                        self.counts["lines"] += 1
                    except OSError as e:
                        self.counts["lines_dropped"] += 1
                        log.debug("simulated NMEA line not written: %s", e)
        finally:
            self.done.set()

    def stop(self) -> None:
        """Stop playing and release the bus and the pty."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self.done.set()
        self.bus.shutdown()
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass


def simulate_recording(scenario: str, seed: int, out: str | Path, duration_s: float | None = None) -> Path:
    """Simulate a named scenario (optionally only its first ``duration_s`` s) into a recording directory."""
    from . import scenarios
    from .simulator import simulate
    from .writer import write_recording

    kw = {} if duration_s is None else {"duration_s": float(duration_s) + 1.0}
    scn = scenarios.get(scenario, seed=seed, **kw)
    write_recording(scn, simulate(scn), out)
    return Path(out)


@dataclass
class SimulationResult:
    """What :func:`run_simulation` returns."""

    exit_code: int
    service: Any
    machine: SimulatedMachine
    summary: dict[str, Any] = field(default_factory=dict)


def _port_of(address: str | None) -> int | None:
    """The TCP port of an ``http://host:port/`` address, or None."""
    if not address:
        return None
    from urllib.parse import urlsplit

    try:
        return urlsplit(address).port
    except ValueError:
        return None


async def run_simulation(cfg: Any, recording: str | Path, *, speed: float = 1.0, duration_s: float | None = None,
                         status_stream: IO[str] | None = None, info_stream: IO[str] | None = None,
                         before_play: Callable[[SimulatedMachine], None] | None = None,
                         estimator_factory: Callable[[Any, Any], Any] | None = None) -> SimulationResult:
    """Run the real service against a recording played onto a virtual bus and a pty.

    ``cfg`` is the base :class:`~tractionecu.service.config.ServiceConfig`;
    its CAN and GPS sections are replaced by the virtual channel and the pty,
    the vehicle by the recording's ``vehicle.toml``.  ``before_play`` is
    called with the machine before anything is played (tests attach a
    listener bus to ``machine.channel`` there).  Stops after ``duration_s``
    simulated seconds, at the end of the recording, or on SIGINT/SIGTERM.
    """
    from ..service.config import with_overrides
    from ..service.daemon import Service
    from ..service.loop import default_estimator_factory, estimator_machine, warm_up

    rec = Path(recording)
    first = next(iter(read_candump(rec / "can.log")), None)
    if first is None:
        raise ValueError(f"{rec / 'can.log'}: no frame to play")
    # Compile (or load) the estimator's kernels before the simulated clock starts: on a fresh
    # install that takes seconds, and a machine already playing would leave the loop behind.
    factory = estimator_factory or default_estimator_factory
    cfg = with_overrides(cfg, estimation={"vehicle": str(rec / "vehicle.toml")})
    await asyncio.get_running_loop().run_in_executor(None, warm_up, factory, *estimator_machine(cfg))
    machine = SimulatedMachine(rec, ServiceClock(speed=speed, epoch0=first.t - LEAD_WALL_S * speed))
    lag = max(cfg.estimation.lag_s, min(1.0, 0.02 * speed))
    cfg = with_overrides(
        cfg,
        can={"interface": "virtual", "channel": machine.channel, "timestamps": "kernel", "options": {}},
        gps={"source": "serial", "port": machine.port},
        estimation={"lag_s": lag},
        service={"state_dir": str(cfg.state_dir())},
    )
    if before_play is not None:
        before_play(machine)
    # The service anchors its grid to the first wheel-speed frame it receives, replay to the first one
    # recorded: a frame sent before the service has opened the bus (a virtual bus delivers only to the
    # buses open when it is sent) or a line written before it opened the pty would be lost, and the
    # service would estimate from a later start.  On a loaded machine start-up can take longer than the
    # lead: then that service is stopped and a new one started with a longer lead (``start_attempts``).
    lead = LEAD_WALL_S
    for attempt in range(1, START_ATTEMPTS + 1):
        clock = ServiceClock(speed=speed, epoch0=first.t - lead * speed)
        machine.clock = clock
        try:
            svc = Service(cfg, clock=clock, status_stream=status_stream, estimator_factory=estimator_factory,
                          warm_up_estimator=False)      # warmed up above
        except BaseException:
            machine.stop()                              # its virtual bus and pty, also on a config error
            raise
        stop = asyncio.Event()
        task = asyncio.create_task(svc.run(stop))
        t0 = time.monotonic()
        ready = asyncio.create_task(svc.ready.wait())
        await asyncio.wait({ready, task}, timeout=max(0.0, clock.mono_at(first.t) - READY_MARGIN_WALL_S
                                                      - time.monotonic()))
        ready.cancel()
        if svc.ready.is_set() or task.done() or attempt == START_ATTEMPTS:
            break
        log.info("simulated service not ready %.1f s after its start; starting it again with a longer lead",
                 time.monotonic() - t0)
        stop.set()
        await asyncio.wait({task})
        port = _port_of(getattr(getattr(svc, "web", None), "address", None))
        if port is not None:
            # the in-cab page's address was printed and may be open in a browser: the next service serves
            # it on the same port (it was bound to port 0: any free port)
            cfg = with_overrides(cfg, web={"port": port})
        lead *= 2
    if info_stream is not None:
        print(f"playing on virtual CAN channel {machine.channel} and NMEA pty {machine.port} at {speed:g}x "
              f"real time; Ctrl-C stops", file=info_stream, flush=True)
    machine.start()
    t_end = first.t + (duration_s if duration_s is not None else math.inf)
    try:
        while not task.done():
            if machine.done.is_set() or clock.now() >= t_end:
                await asyncio.sleep(clock.wall(lag + 0.2))
                stop.set()
                break
            await asyncio.sleep(0.05)
        rc = await task
    finally:
        stop.set()
        if not task.done():
            await asyncio.wait({task})
        machine.stop()
    c = svc.counters()
    summary = {
        "start_attempts": attempt,
        "ready_before_play": svc.ready.is_set(),
        "played_frames": machine.counts["frames"],
        "played_nmea_lines": machine.counts["lines"],
        "estimator_steps": c["service"].get("steps", 0),
        "broadcasts": c["service"].get("broadcasts", 0),
        "address": None if svc.network.address is None else f"0x{svc.network.address:02X}",
        "map_dir": str(cfg.map_dir()),
        "map_samples": c.get("map", {}).get("added", 0),
        "map_tiles_written": c.get("map_store", {}).get("tiles_written", 0),
    }
    return SimulationResult(rc, svc, machine, summary)
