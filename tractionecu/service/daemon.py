"""The in-cab daemon: CAN + GNSS in, the same Estimator as ``replay``, estimates out.

:class:`Service` composes the parts and runs their lifecycle:

==================  =========================================================
part                what it does
==================  =========================================================
dispatcher          :class:`~.dispatch.FrameDispatcher`: each CAN frame and
                    GNSS fix to the step assembler, the fix buffer or the
                    network, or counted
fixes               :class:`~.fixes.FixBuffer`: recent fixes for the map
network             :class:`~.network.Network`: J1939 address claim,
                    transmit, the estimate broadcast, Requests (served
                    after each estimation step); our address moves the
                    kernel filters (:func:`pgn_filters`)
estimation          :class:`~.loop.EstimationLoop`: the estimator on its grid
map, can, gps       :class:`~.mapwriter.MapWriter`, :class:`~.canlink.CanLink`,
                    :class:`~.gps.GpsReader`
status              :class:`~.status.StatusReporter`: the status line
advice              :class:`~.advice.AdvicePart`: traction
                    efficiency, the optimal slip s* and advice from the
                    last estimate, ``TECU_EstEfficiency`` on the bus, the
                    live map (``[advice]``)
web                 :class:`~tractionecu.web.server.WebPart`: the read-only
                    in-cab page (``[web]``)
==================  =========================================================

Start-up runs :meth:`Service.parts` in this order (the one place a part is
added); shutdown runs it backwards and gathers the errors
(:mod:`~.lifecycle`):

1. ``state``: state directory, resolved config written to ``<state>/run-config.toml``;
2. ``estimator``: the vehicle and sensor figures loaded, the estimator built
   (a bad vehicle file stops start-up here, before a device is opened);
3. ``map``: the map writer resumes the tiles already on disk;
4. ``can``, ``gps``: the CAN link and GNSS reader tasks (each reopens its
   device on its own);
5. ``network``: the J1939 address claim, now if the bus is open and again
   after every (re)open;
6. ``warm-up``: estimator warm-up (its compiled kernels), then
   :func:`~.heap.settle_heap` (GC freeze of the start-up objects, glibc's
   mmap threshold fixed);
7. ``estimation``: the estimation loop;
8. ``advice``, ``web``: efficiency and advice, and the in-cab page, each its own
   task beside the loop, woken right after a broadcast step (never inside a
   step); the page is not watched: a port that cannot be bound, or a page
   that fails, leaves the daemon estimating without it;
9. ``status``: the status task;
10. ``ready``: ``READY=1`` to systemd once the bus and the GNSS port are open.

A stop asked during start-up (SIGTERM while a first start compiles) starts no further part and does not
wait for the warm-up; the parts already started are stopped in reverse.

A task of ``can``, ``gps``, ``estimation``, ``advice`` or ``status`` that ends by itself
is a bug: the service stops with exit code 1 and systemd restarts it.

Bad input never stops the daemon: 11-bit, remote, error and CAN FD frames,
unknown PGNs, wrong DLCs and undecodable NMEA lines are counted in
:attr:`Service.stats` (and the readers' own counters) and logged once.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import math
import os
import signal
import sys
import threading
import time
from collections import Counter
from pathlib import Path
from typing import IO, Any, Callable, Iterable

import can

from ..advice.bus import efficiency_frame
from ..advice.efficiency import efficiency_config_for
from ..advice.engine import AdviceEngine
from ..aio import cancel_and_wait
from ..bus import j1939
from ..bus.dbc import Codec
from ..bus.transport import TRANSPORT_PGNS
from ..errors import ConfigError
from ..mapping.tiles import DISK_FULL_ERRNOS, atomic_write_bytes, lock_directory
from ..pipeline.gnss import gate_from_config
from ..pipeline.signals import INPUT_MESSAGES, MACHINE_INPUT_MESSAGES
from ..pipeline.steps import StepAssembler
from .advice import AdvicePart, LiveMap
from .canlink import CanLink
from .clock import ServiceClock
from .config import ServiceConfig, to_toml
from .dispatch import FrameDispatcher, codec_for
from .fixes import FixBuffer
from .gps import GpsReader
from .heap import settle_heap
from .lifecycle import DeviceTask, Hook, Lifecycle, Part
from .loop import (EstimationLoop, EstimatorFactory, default_estimator_factory, estimator_groups,
                   service_estimator_config)
from .mapwriter import MapWriter
from .network import Network
from .notify import Notifier, watchdog_interval
from .status import StatusReporter, web_snapshot

log = logging.getLogger(__name__)


PGN_ACKNOWLEDGEMENT = 59392
"""Acknowledgement, 0xE800 (PDU1)."""
PGN_TP_CM, PGN_TP_DT = 60416, 60160
"""Transport protocol connection management and data transfer, 0xEC00 / 0xEB00 (PDU1)."""
PGN_ETP_CM, PGN_ETP_DT = 51200, 50944
"""ISO 11783-3 extended transport protocol, 0xC800 / 0xC700 (PDU1)."""
ADDRESSED_PGNS = frozenset({j1939.PGN_REQUEST, PGN_ACKNOWLEDGEMENT, PGN_TP_CM, PGN_TP_DT, PGN_ETP_CM, PGN_ETP_DT})
"""PDU1 PGNs admitted only when sent to our address or to the global address: a Request, a transport
session or an acknowledgement between two other nodes is not ours to read (a flood of them would
otherwise be parsed in Python).  Address Claimed passes to any destination (every claim updates the
address table)."""


def pgn_filters(pgns: Iterable[int], address: int | None = None, std_ids: Iterable[int] = ()
                ) -> list[dict[str, Any]]:
    """python-can ``can_filters`` passing these PGNs from any source, and the 11-bit identifiers ``std_ids``
    (an owner's DBC messages on CAN 2.0A identifiers).

    A PDU2 PGN passes whole; a PDU1 PGN passes to any destination, except the
    :data:`ADDRESSED_PGNS`, which pass only to the global address (0xFF) and to
    ``address`` (our claimed address; None: global only).
    """
    out = [{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in sorted(set(std_ids))]
    for pgn in sorted(set(pgns)):
        if not j1939.is_pdu1(pgn):
            out.append({"can_id": (pgn & 0x3FFFF) << 8, "can_mask": 0x3FFFF << 8, "extended": True})
        elif pgn in ADDRESSED_PGNS:
            for da in sorted({j1939.ADDRESS_GLOBAL} | ({address} if address is not None else set())):
                out.append({"can_id": ((pgn & 0x3FF00) | da) << 8, "can_mask": 0x3FFFF << 8, "extended": True})
        else:
            out.append({"can_id": (pgn & 0x3FF00) << 8, "can_mask": 0x3FF00 << 8, "extended": True})
    return out


READY_GPS_WAIT_S = 30.0
"""Longest wait for the GNSS receiver after the CAN bus is open before ``READY=1`` [s]: well inside the unit's
``TimeoutStartSec`` (120 s), so that an unplugged receiver or a wrong ``gps.port`` is a status to show, not a
start that systemd fails and restarts every two minutes."""


STATE_BUSY = ("another tractionecu service runs on this state directory (a second instance of the unit, or a "
              "second run --simulate): stop it or give another --state-dir")
_state_locks: dict[str, list[Any]] = {}


def hold_state_dir(state: Path) -> Callable[[], None]:
    """Take the state directory's lock (:func:`~tractionecu.mapping.tiles.lock_directory`) for this process and
    return its release; a second process is refused (:class:`~tractionecu.mapping.tiles.MapStoreError`, by
    name).  Within one process it is taken again freely: ``run --simulate`` holds it while it writes the
    simulation, and its service (and the one it starts again with a longer lead) take it after."""
    key = os.path.realpath(state)
    held = _state_locks.get(key)
    if held is None:
        held = _state_locks[key] = [lock_directory(state, STATE_BUSY), 0]
    held[1] += 1
    released = False

    def release() -> None:
        nonlocal released
        if released:
            return
        released = True
        held[1] -= 1
        if held[1] == 0 and _state_locks.get(key) is held:
            del _state_locks[key]
            held[0].close()

    return release


class Readiness:
    """The ``ready`` part: ``READY=1`` once every device is open (the service's :attr:`Service.ready`), or once
    the CAN bus is and the GNSS receiver has not opened within :data:`READY_GPS_WAIT_S` (it is retried and
    shown in the status lines meanwhile)."""

    name = "ready"

    def __init__(self, svc: Service) -> None:
        self.svc = svc
        self._task: asyncio.Task[None] | None = None

    def text(self, gps_open: bool = True) -> str:
        svc = self.svc
        gps = ""
        if svc.gps is not None:
            gps = f", GPS {svc.cfg.gps.port}" if gps_open else ""
        can_part = f"CAN {svc.cfg.can.interface}:{svc.cfg.can.channel}{gps} open"
        if svc.gps is not None and not gps_open:
            can_part += f"; GPS {svc.cfg.gps.port} not open: estimating without GNSS until it opens"
        return can_part

    async def _wait(self) -> None:
        svc = self.svc
        await svc.can.is_open.wait()
        gps_open = True
        if svc.gps is not None:
            try:
                await asyncio.wait_for(svc.gps.is_open.wait(), READY_GPS_WAIT_S)
            except asyncio.TimeoutError:
                gps_open = False
        svc.ready.set()
        svc.notifier.ready(self.text(gps_open))
        (log.info if gps_open else log.warning)("ready: %s", self.text(gps_open))

    async def start(self) -> None:
        self.svc.notifier.status("waiting for the CAN bus" + (" and GPS" if self.svc.gps else ""))
        self._task = asyncio.create_task(self._wait(), name=self.name)

    async def stop(self) -> None:
        await cancel_and_wait(self._task)


class Service:
    """One run of the daemon.

    Parameters
    ----------
    cfg:
        Resolved configuration.
    clock:
        Service clock (default: real time).
    estimator_factory:
        ``factory(vehicle, sensors) -> estimator`` with ``step(t, inputs, measurements)``
        (default: :func:`~.loop.default_estimator_factory`); the machine is
        :func:`~.loop.estimator_machine` (``estimation.vehicle`` and ``[sensors]``).
    bus_factory, serial_factory:
        Device constructors (defaults ``can.Bus`` and ``serial.Serial``).
    extra_bus_kwargs:
        Extra ``can.Bus`` arguments.
    notifier:
        systemd notifier (default: from ``$NOTIFY_SOCKET``).
    status_stream:
        Where to print one status line per ``service.status_interval_s``
        (None: no lines).
    status_stream_every_s:
        At most one line printed on ``status_stream`` per this many seconds (0: every one).
    env:
        Environment for ``$STATE_DIRECTORY`` and the watchdog (default os.environ).
    warm_up_estimator:
        Run :func:`~.loop.warm_up` on a throwaway estimator before the loop starts.

    Attributes
    ----------
    stats:
        The service's counters (frames, steps, broadcasts ...), shared by its parts.
    lifecycle:
        The parts of :meth:`parts` and which of them are started.
    ready:
        Set once every device is open (``READY=1``).
    """

    def __init__(self, cfg: ServiceConfig, *, clock: ServiceClock | None = None,
                 estimator_factory: EstimatorFactory | None = None,
                 bus_factory: Callable[..., can.BusABC] | None = None,
                 serial_factory: Callable[..., Any] | None = None,
                 extra_bus_kwargs: dict[str, Any] | None = None,
                 notifier: Notifier | None = None,
                 status_stream: IO[str] | None = None,
                 status_stream_every_s: float = 0.0,
                 env: dict[str, str] | None = None,
                 codec: Codec | None = None,
                 warm_up_estimator: bool = True) -> None:
        self.cfg = cfg
        self.clock = clock or ServiceClock()
        self.codec, mapping = codec_for(cfg, codec)          # can.dbc and [signals]
        self.notifier = notifier or Notifier(env)
        self.env = env
        self.warm_up_estimator = warm_up_estimator
        self.stats: Counter[str] = Counter()
        groups = estimator_groups(cfg)
        self.steps = StepAssembler(depth=max(256, int(cfg.estimation.lag_s * 200) + 64), groups=groups)
        self._input_messages = INPUT_MESSAGES if groups is None else MACHINE_INPUT_MESSAGES
        gate = gate_from_config(cfg.gps, cfg.map.max_fix_age_s)
        self.fixes = FixBuffer(gate)
        self.network = Network(cfg.broadcast, self.codec, self.clock, stats=self.stats)
        self.dispatcher = FrameDispatcher(self.codec, self.steps, self.fixes, on_network=self.network.on_nm_frame,
                                          stats=self.stats, lag_s=cfg.estimation.lag_s, mapping=mapping)
        bus_kwargs = dict(extra_bus_kwargs or {})
        if cfg.can.kernel_filters:
            addr = cfg.broadcast.preferred_address if cfg.broadcast.enabled else None
            bus_kwargs.setdefault("can_filters", pgn_filters([*self.codec.pgns(), *TRANSPORT_PGNS], addr,
                                                             self.codec.std_ids()))
        self.can = CanLink(cfg.can, self.dispatcher.on_frame, self.clock, bus_factory=bus_factory,
                           extra_bus_kwargs=bus_kwargs, on_open=self.network.on_bus_open)
        self.network.link = self.can
        if cfg.can.kernel_filters and "can_filters" not in (extra_bus_kwargs or {}):
            self.network.on_address = self._follow_address
        self.gps: GpsReader | None = None
        if cfg.gps.source == "serial":
            self.gps = GpsReader(cfg.gps, self.dispatcher.on_fix, self.clock, serial_factory=serial_factory,
                                 gate=gate)
        self.map: MapWriter | None = MapWriter(cfg.map, cfg.map_dir(env)) if cfg.map.enabled else None
        if self.map is not None and self.gps is None:
            self.map.no_gnss = True             # said on the page, not "waiting for a GNSS fix" for ever
        self.estimation = EstimationLoop(
            cfg, self.clock, self.steps,
            factory=estimator_factory or functools.partial(default_estimator_factory,
                                                           cfg=service_estimator_config(cfg)),
            broadcast=self._broadcast, map_writer=self.map, fixes=self.fixes, can=self.can, gps=self.gps,
            watchdog=self.notifier.watchdog, watchdog_s=watchdog_interval(env), status=self.notifier.status,
            after_step=self.network.serve_requests, stats=self.stats)
        self.status = StatusReporter(cfg.service.status_interval_s, self.clock.speed, self._totals,
                                     self.status_line, self.notifier, status_stream, status_stream_every_s)
        self.live_map: LiveMap | None = LiveMap() if cfg.web.enabled else None
        self._after_broadcast: list[asyncio.Event] = []
        self.advice: AdvicePart | None = None
        if cfg.advice.enabled:
            self.advice = AdvicePart(self._advice_engine, lambda: self.estimation.last_estimate,
                                     period_s=1.0 / cfg.broadcast.rate_hz, speed=self.clock.speed,
                                     fix_at=self.fixes.fix_at, live_map=self.live_map,
                                     send=self._send_efficiency if cfg.broadcast.enabled else None,
                                     trigger=self._broadcast_event())
        self.web: Any = None
        if cfg.web.enabled:
            from ..web.server import WebPart      # aiohttp only when the page is served

            self.web = WebPart(cfg.web, self.web_state, self.live_map, on_listening=self._announce_page,
                               trigger=self._broadcast_event())
        self.ready = asyncio.Event()
        self.started_mono = time.monotonic()
        self.exit_code = 0
        self._stop: asyncio.Event | None = None
        self._state_release: Callable[[], None] | None = None
        self.lifecycle = Lifecycle(self.parts())

    def parts(self) -> list[Part]:
        """The parts in start-up order (module doc); shutdown runs them backwards."""
        parts: list[Part] = [
            Hook("state", start=self._write_state, stop=self._release_state),
            Hook("estimator", start=self.estimation.build_estimator),
        ]
        if self.map is not None:
            parts.append(Hook("map", start=self.map.open, stop=self.map.close))
        parts.append(DeviceTask("can", self.can))
        if self.gps is not None:
            parts.append(DeviceTask("gps", self.gps))
        parts += [
            self.network,
            Hook("warm-up", start=self._warm_up),
            self.estimation,
        ]
        if self.advice is not None:
            parts.append(self.advice)
        if self.web is not None:
            parts.append(self.web)
        parts += [self.status, Readiness(self)]
        return parts

    def request_stop(self) -> None:
        """Ask the service to shut down (SIGTERM/SIGINT do this)."""
        if self._stop is not None:
            self._stop.set()

    def _follow_address(self, address: int | None) -> None:
        """Our address changed: the kernel passes Requests, TP, ETP and acknowledgements to it."""
        self.can.set_filters(pgn_filters([*self.codec.pgns(), *TRANSPORT_PGNS], address, self.codec.std_ids()))
        log.info("CAN filters follow address %s", "none" if address is None else f"0x{address:02X}")

    # ------------------------------------------------------------ start-up steps
    def _write_state(self) -> None:
        state = self.cfg.state_dir(self.env)
        try:
            state.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise ConfigError(f"service.state_dir: cannot write {state}: {e}") from e
        # one service per state directory, from its start: a second one started before the map existed ran on
        # beside the first, retrying the map it could not open for as long as it ran
        self._state_release = hold_state_dir(state)
        try:
            atomic_write_bytes(state / "run-config.toml", to_toml(self.cfg).encode("utf-8"))
        except OSError as e:
            if e.errno in DISK_FULL_ERRNOS:
                # a record of the configuration, not a reason to stop: on a full disk the service estimates and
                # broadcasts, and the map keeps its tiles in memory until it can write them (the service did not
                # start at all, exit 1, restarted by systemd again and again)
                self.stats["state_write_errors"] += 1
                log.warning("service.state_dir: cannot write %s: %s; running without it", state / "run-config.toml",
                            e)
                return
            self._release_state()
            raise ConfigError(f"service.state_dir: cannot write {state}: {e}") from e

    def _release_state(self) -> None:
        release, self._state_release = self._state_release, None
        if release is not None:
            release()

    async def _warm_up(self) -> None:
        if self.warm_up_estimator:
            self.notifier.status("preparing the estimator")
            # a first start compiles for 30-45 s: a stop meanwhile does not wait for it (systemd's
            # TimeoutStopSec is 20 s); the warm-up's thread is left behind and ends with the process
            warm = asyncio.ensure_future(self.estimation.warm_up())
            waits: set[asyncio.Future[Any]] = {warm}
            if self._stop is not None:
                waits.add(asyncio.ensure_future(self._stop.wait()))
            await asyncio.wait(waits, return_when=asyncio.FIRST_COMPLETED)
            for w in waits - {warm}:
                w.cancel()
            if not warm.done():
                warm.cancel()
                log.info("stop asked during the estimator's warm-up: not waiting for it")
                return
            try:
                dt = warm.result()
                log.info("estimator compiled and ready in %.2f s", dt)
            except Exception as e:  # the real steps will show it; do not stop here
                log.warning("estimator warm-up failed: %r", e)
        settle_heap()

    # ------------------------------------------------------------ advice and the page
    def _broadcast_event(self) -> asyncio.Event:
        ev = asyncio.Event()
        self._after_broadcast.append(ev)
        return ev

    def _broadcast(self, est: Any) -> bool:
        """The estimation loop's broadcast: the estimate frames, then wake the advice and the page, whose
        work so runs after this step, a broadcast period before the next broadcast."""
        ok = self.network.broadcast(est)
        for ev in self._after_broadcast:
            ev.set()
        return ok

    def _advice_engine(self) -> AdviceEngine:
        """The advice engine for the configured machine (the estimator's vehicle) and ``[advice]``."""
        from ..config import VehicleParams

        a = self.cfg.advice
        vehicle = self.estimation.machine[0] if self.estimation.machine else VehicleParams()
        eff = efficiency_config_for(vehicle, max_sigma_s_star=a.max_sigma_s_star)
        return AdviceEngine(vehicle, a.settings(), eff=eff)

    def _send_efficiency(self, report: Any) -> bool:
        """``TECU_EstEfficiency`` from our claimed address, if the claim allows (as the estimate broadcast)."""
        cl = self.network.claimer
        if cl is None or self.can.bus is None or cl.address is None or not cl.can_transmit(self.clock.now()):
            self.stats["efficiency_skipped"] += 1
            return False
        cid, data = efficiency_frame(self.codec, report, cl.address, self.cfg.broadcast.priority)
        ok = self.can.send(cid, data)
        self.stats["efficiency_sent" if ok else "efficiency_errors"] += 1
        return ok

    def _announce_page(self, address: str) -> None:
        """The page listens: say where on the status stream (``run --simulate`` prints it)."""
        if self.status.stream is not None:
            try:
                print(f"in-cab page: {address}", file=self.status.stream, flush=True)
            except (OSError, ValueError):
                pass

    def web_state(self) -> dict[str, Any]:
        """What the in-cab page shows (:mod:`tractionecu.web`): estimate, efficiency, curve, advice, health."""
        return web_snapshot(self)

    # ------------------------------------------------------------ status
    def _totals(self) -> dict[str, float]:
        return {
            "can": float(self.can.stats["rx_frames"]),
            "inputs": float(sum(self.stats["rx_" + m] for m in self._input_messages)),
            "gps": float(self.stats["gps_fixes"]),
            "est": float(self.stats["steps"]),
            "tx": float(self.can.stats["tx_frames"]),
        }

    def status_line(self) -> str:
        """One line: speed, μ, ρ_s, a, slip, status, rates, address."""
        e = self.estimation.last_estimate
        r = self.status.rates

        def f(x: Any, fmt: str) -> str:
            try:
                v = float(x)
            except (TypeError, ValueError):
                return "-"
            return format(v, fmt) if math.isfinite(v) else "-"

        if e is None:
            est = "no estimate yet"
        else:
            est = (f"v {f(e.v, '.2f')} m/s  mu {' '.join(f(x, '.3f') for x in e.mu)}  rho_s {f(e.rho_s, '.3f')}"
                   f"  a {f(e.a, '.3f')}  slip {' '.join(f(x, '.3f') for x in e.slip)}  status 0x{int(e.status):04X}")
        can_s = "open" if self.can.is_open.is_set() else "DOWN"
        gps_s = "off" if self.gps is None else ("open" if self.gps.is_open.is_set() else "DOWN")
        g0 = self.estimation.grid_t0
        t = "" if g0 is None else f"t {self.clock.now() - g0:6.1f} s  "
        behind = self.estimation.behind_text(time.monotonic())
        if self.advice is not None and e is not None:
            est += " | " + self.advice.engine.status_text()
        if self.map is not None and self.map.last_error:
            est += " | map " + self.map.state
        return (f"{behind + ' | ' if behind else ''}{t}{est} | CAN {can_s} {r.get('can', 0):.0f} fr/s (inputs {r.get('inputs', 0):.0f}/s)"
                f"  GPS {gps_s} {r.get('gps', 0):.1f} Hz  est {r.get('est', 0):.0f} Hz"
                f"  tx {r.get('tx', 0):.0f} fr/s  addr {self.network.describe_address()}")

    def counters(self) -> dict[str, Any]:
        """Every counter, for logs and tests."""
        out: dict[str, Any] = {"service": {**self.stats, "max_tick_delay_s": self.estimation.max_tick_delay_s,
                                           "requests_waiting": self.network.waiting()},
                               "can": dict(self.can.stats), "unknown_pgns": dict(self.dispatcher.unknown_pgns),
                               "bad_frames": dict(self.dispatcher.bad_frames),
                               "steps": {**self.steps.counts, "max_late_s": self.steps.max_late_s}}
        if self.gps is not None:
            out["gps"] = {**self.gps.stats, "max_delay_s": self.gps.stream.max_delay_s}
        if self.network.claimer is not None:
            out["address_claim"] = dict(self.network.claimer.counts)
        if self.network.codec.clip_counts:     # broadcast values beyond the DBC's range, sent at its limit
            out["broadcast_clipped"] = dict(self.network.codec.clip_counts)
        if self.map is not None:
            out["map"] = dict(self.map.stats)
            if self.map.store is not None:
                out["map_store"] = dict(self.map.store.stats)
        if self.advice is not None:
            out["advice"] = {**self.advice.stats, "max_work_s": self.advice.max_work_s,
                             "active": [r.kind for r in self.advice.engine.advice]}
        if self.web is not None:
            out["web"] = {**self.web.stats, "viewers": len(self.web.viewers), "max_build_s": self.web.max_build_s,
                          "address": self.web.address}
        est = self.estimation.estimator
        if est is not None and hasattr(est, "counters"):
            out["estimator"] = dict(est.counters)
        return out

    # ------------------------------------------------------------ run
    async def run(self, stop: asyncio.Event | None = None) -> int:
        """Run until SIGTERM/SIGINT/SIGHUP, :meth:`request_stop` or ``stop`` is set.  Returns the exit code.

        SIGHUP (a closed terminal or ssh session, or a ``kill -HUP`` meant as "reload") stops the service as
        SIGTERM does, the map flushed: left to its default it killed the process and lost the last 15–20 s of
        map.  The service has nothing to reload; a changed configuration takes a restart."""
        loop = asyncio.get_running_loop()
        self._stop = stop or asyncio.Event()
        signals_installed: list[int] = []
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
                try:
                    loop.add_signal_handler(sig, self.request_stop)
                    signals_installed.append(sig)
                except (NotImplementedError, RuntimeError, ValueError):
                    pass
        errors: list[str] = []
        try:
            await self.lifecycle.start(self._stop)
            errors += await self._watch(self._stop)
        finally:
            self.notifier.stopping()
            errors += await self.lifecycle.stop()
            for sig in signals_installed:
                loop.remove_signal_handler(sig)
        if errors:
            for e in errors:
                log.error("shutdown: %s", e)
            self.exit_code = self.exit_code or 1
        log.info("stopped; counters: %s", self.counters())
        self.notifier.close()
        return self.exit_code

    async def _watch(self, stop: asyncio.Event) -> list[str]:
        """Wait for ``stop``; a part's task that ends meanwhile is an error and stops the service."""
        errors: list[str] = []
        tasks = dict((t, name) for name, t in self.lifecycle.tasks())
        stopper = asyncio.create_task(stop.wait())
        try:
            while not stop.is_set():
                done, _ = await asyncio.wait({*tasks, stopper}, return_when=asyncio.FIRST_COMPLETED)
                for t in done:
                    name = tasks.get(t)
                    if name is None:
                        continue
                    # a task that ends by itself is a bug: stop and let systemd restart us
                    exc = t.exception() if not t.cancelled() else None
                    log.error("task %s ended unexpectedly: %r", name, exc)
                    errors.append(f"{name}: {exc!r}")
                    self.exit_code = 1
                    stop.set()
        finally:
            stopper.cancel()
        return errors


def run_service(cfg: ServiceConfig, **kwargs: Any) -> int:
    """``asyncio.run`` a :class:`Service`; returns its exit code."""
    async def main() -> int:
        return await Service(cfg, **kwargs).run()

    try:
        return asyncio.run(main())
    except KeyboardInterrupt:  # pragma: no cover - SIGINT before the handler is installed
        print("interrupted", file=sys.stderr)
        return 130
