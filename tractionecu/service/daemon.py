"""The in-cab daemon: CAN + GNSS in, the same Estimator as ``replay``, estimates out.

Start-up, in order (shutdown runs it backwards and gathers the errors):

1. state directory, resolved config written to ``<state>/run-config.toml``;
2. map writer: resume the tiles already on disk;
3. CAN link and GNSS reader tasks (each reopens its device on its own);
4. ``READY=1`` to systemd once the bus and the GNSS port are open;
5. J1939 address claim (again after every reopen of the bus);
6. estimator warm-up (its compiled kernels), then :func:`settle_heap` (GC
   freeze of the start-up objects, glibc's mmap threshold fixed);
7. the estimation loop and the status task.

Estimation loop
---------------
Grid ``t_k = g0 + k / rate`` on the service clock (monotonic, so it neither
drifts nor jumps).  ``g0`` is phased to the first wheel-speed frame exactly
as ``replay`` does (``+ GRID_MARGIN_S``).  Step k runs ``lag_s`` after
``t_k``, when every frame stamped up to ``t_k`` has arrived, and feeds the
estimator through :class:`~tractionecu.pipeline.steps.StepAssembler`, so a
capture of the bus replayed offline gives the same estimates.  The
estimator predicts only and sets its timeout bits when a signal stops.  A
loop that falls more than ``max_catch_up_s`` behind skips ahead (counted).
Every ``rate / broadcast.rate_hz`` steps the estimate is broadcast; every
``rate / map.rate_hz`` steps it goes to the map; ``WATCHDOG=1`` is sent
from this loop, so a stuck loop gets the service restarted.

Bad input never stops the daemon: 11-bit, remote, error and CAN FD frames,
unknown PGNs, wrong DLCs and undecodable NMEA lines are counted in
:attr:`Service.stats` (and the readers' own counters) and logged once.
"""

from __future__ import annotations

import asyncio
import collections
import logging
import math
import signal
import sys
import threading
import time
from collections import Counter
from pathlib import Path
from typing import IO, Any, Callable

import can

from ..bus import j1939
from ..bus.dbc import Codec, default_codec
from ..errors import ConfigError, DecodeError
from . import broadcast
from .address_claim import AddressClaimer, ClaimState, Tx
from .canlink import CanLink
from .heap import settle_heap
from .clock import ServiceClock
from .config import ServiceConfig, to_toml
from .gps import GpsReader, GpsSample
from .mapwriter import MapWriter
from .notify import Notifier, watchdog_interval
from ..pipeline.signals import ANCHOR_SIGNAL
from ..pipeline.steps import GRID_MARGIN_S, StepAssembler

log = logging.getLogger(__name__)

OUTPUT_PGNS = frozenset({65312, 65313, 65314})
NM_PGNS = frozenset({j1939.PGN_ADDRESS_CLAIMED, j1939.PGN_REQUEST})
INPUT_MESSAGES = ("TECU_WheelSpeeds", "TECU_DriveTorques", "TECU_AxleLoad", "RearHitchStatus")

EstimatorFactory = Callable[[Any], Any]

MAX_TRACKED_UNKNOWN_PGNS = 256
"""Unknown PGNs counted one by one (``Service.unknown_pgns``); frames of further ones are
counted together as ``unknown_pgn_untracked``.  A real bus carries a few dozen."""


def default_estimator_factory(vehicle: Any) -> Any:
    """The estimator ``replay`` uses, with its default configuration."""
    from ..estimation.estimator import Estimator

    return Estimator(vehicle)


def pgn_filters(pgns: list[int]) -> list[dict[str, Any]]:
    """python-can ``can_filters`` passing these PGNs from any source (and, PDU1, to any destination)."""
    out = []
    for pgn in pgns:
        pdu1 = ((pgn >> 8) & 0xFF) < 240
        out.append({"can_id": (pgn & (0x3FF00 if pdu1 else 0x3FFFF)) << 8,
                    "can_mask": (0x3FF00 if pdu1 else 0x3FFFF) << 8, "extended": True})
    return out


def warm_up(factory: EstimatorFactory, vehicle: Any) -> float:
    """Run a throwaway estimator through every kind of step; returns the seconds it took.

    The estimator's compiled (numba) kernels are compiled or loaded from their
    cache on first use, which takes seconds; done here, before the estimation
    loop starts, it delays neither the first steps nor the watchdog.
    """
    import numpy as np

    t0 = time.perf_counter()
    est = factory(vehicle)
    md = np.full(4, 900.0)
    om = np.full(4, 3.2)
    for k in range(60):
        t = 0.01 * k
        meas: dict[str, Any] = {"omega": om + 0.001 * k}
        if k % 10 == 0:
            meas["v"] = 2.4
        inputs = {"Md": md, "Fzf": 25000.0, "Fdx": 12000.0} if k % 7 else {}
        est.step(t, inputs, meas if k % 5 else {})
    est.step(1.0, {"Md": md, "Fzf": math.nan}, {"v": 2.4})
    return time.perf_counter() - t0


def _pgn(can_id: int) -> int:
    raw = (can_id >> 8) & 0x3FFFF
    return raw & 0x3FF00 if ((raw >> 8) & 0xFF) < 240 else raw


class Service:
    """One run of the daemon.

    Parameters
    ----------
    cfg:
        Resolved configuration.
    clock:
        Service clock (default: real time).
    estimator_factory:
        ``factory(vehicle) -> estimator`` with ``step(t, inputs, measurements)``
        (default: :func:`default_estimator_factory`).
    bus_factory, serial_factory:
        Device constructors (defaults ``can.Bus`` and ``serial.Serial``).
    extra_bus_kwargs:
        Extra ``can.Bus`` arguments.
    notifier:
        systemd notifier (default: from ``$NOTIFY_SOCKET``).
    status_stream:
        Where to print one status line per ``service.status_interval_s``
        (None: no lines).
    env:
        Environment for ``$STATE_DIRECTORY`` and the watchdog (default os.environ).
    warm_up_estimator:
        Run :func:`warm_up` on a throwaway estimator before the loop starts.
    """

    def __init__(self, cfg: ServiceConfig, *, clock: ServiceClock | None = None,
                 estimator_factory: EstimatorFactory | None = None,
                 bus_factory: Callable[..., can.BusABC] | None = None,
                 serial_factory: Callable[..., Any] | None = None,
                 extra_bus_kwargs: dict[str, Any] | None = None,
                 notifier: Notifier | None = None,
                 status_stream: IO[str] | None = None,
                 env: dict[str, str] | None = None,
                 codec: Codec | None = None,
                 warm_up_estimator: bool = True) -> None:
        self.cfg = cfg
        self.clock = clock or ServiceClock()
        self.codec = codec or default_codec()
        self.estimator_factory = estimator_factory or default_estimator_factory
        self.notifier = notifier or Notifier(env)
        self.status_stream = status_stream
        self.env = env
        self.stats: Counter[str] = Counter()
        self.unknown_pgns: Counter[int] = Counter()
        self.bad_frames: Counter[str] = Counter()
        self.steps = StepAssembler(depth=max(256, int(cfg.estimation.lag_s * 200) + 64))
        bus_kwargs = dict(extra_bus_kwargs or {})
        if cfg.can.kernel_filters:
            bus_kwargs.setdefault("can_filters", pgn_filters(self.codec.pgns()))
        self.can = CanLink(cfg.can, self._on_frame, self.clock, bus_factory=bus_factory,
                           extra_bus_kwargs=bus_kwargs, on_open=self._on_can_open)
        self.gps: GpsReader | None = None
        if cfg.gps.source == "serial":
            self.gps = GpsReader(cfg.gps, self._on_fix, self.clock, serial_factory=serial_factory)
        self.claimer: AddressClaimer | None = None
        if cfg.broadcast.enabled:
            self.claimer = AddressClaimer(cfg.broadcast.name_value(), cfg.broadcast.preferred_address,
                                          (cfg.broadcast.address_min, cfg.broadcast.address_max))
        self.map: MapWriter | None = MapWriter(cfg.map, cfg.map_dir(env)) if cfg.map.enabled else None
        self.estimator: Any = None
        self.last_estimate: Any = None
        self.last_fix: GpsSample | None = None
        self._fixes: collections.deque[GpsSample] = collections.deque(maxlen=64)
        self.anchor: float | None = None
        self.grid_t0: float | None = None
        self.ready = asyncio.Event()
        self.started_mono = time.monotonic()
        self._stop: asyncio.Event | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._warned: set[str] = set()
        self._watchdog_s = watchdog_interval(env)
        self._last_wd = -math.inf
        self._rate_prev: dict[str, float] = {}
        self._rate_mono = time.monotonic()
        self.rates: dict[str, float] = {}
        self.exit_code = 0
        self.warm_up_estimator = warm_up_estimator
        self.max_tick_delay_s = 0.0
        """Longest a step ran after it was due [wall s] (scheduling latency of the loop)."""

    # ------------------------------------------------------------ helpers
    def _warn_once(self, kind: str, msg: str, *args: Any) -> None:
        if kind in self._warned:
            log.debug(msg, *args)
        else:
            self._warned.add(kind)
            log.warning(msg, *args)

    def request_stop(self) -> None:
        """Ask the service to shut down (SIGTERM/SIGINT do this)."""
        if self._stop is not None:
            self._stop.set()

    @property
    def address(self) -> int | None:
        """Our claimed source address, or None."""
        return None if self.claimer is None else self.claimer.address

    # ------------------------------------------------------------ CAN input
    def _on_frame(self, t: float, msg: can.Message) -> None:
        if msg.is_error_frame:
            self.stats["error_frames"] += 1
            return
        if msg.is_remote_frame:
            self.stats["remote_frames"] += 1
            return
        if not msg.is_extended_id:
            self.stats["standard_id_frames"] += 1
            return
        if msg.is_fd:
            self.stats["canfd_frames"] += 1
            return
        cid = msg.arbitration_id
        pgn = _pgn(cid)
        if pgn in NM_PGNS:
            self.stats["network_management"] += 1
            if self.claimer is not None:
                before = self.claimer.state, self.claimer.address
                self._send_txs(self.claimer.handle(self.clock.now(), cid, bytes(msg.data)))
                after = self.claimer.state, self.claimer.address
                if after != before:
                    self._log_claim(after)
            return
        info = self.codec.message_for_pgn(pgn)
        if info is None:
            if pgn in self.unknown_pgns or len(self.unknown_pgns) < MAX_TRACKED_UNKNOWN_PGNS:
                self.unknown_pgns[pgn] += 1
            else:                               # hostile traffic must not grow the table to 2^18 keys
                self.stats["unknown_pgn_untracked"] += 1
            self.stats["unknown_pgn_frames"] += 1
            return
        if pgn in OUTPUT_PGNS:
            self.stats["foreign_estimate_frames"] += 1
            return
        try:
            name, values = self.codec.decode(cid, bytes(msg.data), True)
        except (DecodeError, KeyError, ValueError) as e:
            self.bad_frames[info.name] += 1
            self.stats["bad_frames"] += 1
            self._warn_once("bad:" + info.name, "skipped frame %08X#%s: %s", cid, bytes(msg.data).hex().upper(), e)
            return
        self.stats["decoded_frames"] += 1
        self.stats["rx_" + name] += 1
        self.steps.push_signals(t, values)
        if self.anchor is None and ANCHOR_SIGNAL in values:
            self.anchor = t + GRID_MARGIN_S
            log.info("estimation grid phased to the first wheel-speed frame: t0 = %.6f", self.anchor)

    def _on_fix(self, s: GpsSample) -> None:
        self.last_fix = s
        self._fixes.append(s)
        self.stats["gps_fixes"] += 1
        if s.speed_mps is not None:
            late = self.steps.counts["late"]
            self.steps.push_speed(s.t, s.speed_mps)
            if self.steps.counts["late"] > late:
                self._warn_once("late-gps", "GNSS epoch %.3f arrived %.3f s after it (lag %.3f s): it is used one "
                                "step late; raise estimation.lag_s", s.t, s.t_arrival - s.t, self.cfg.estimation.lag_s)

    def fix_at(self, t: float) -> GpsSample | None:
        """The latest accepted fix at or before ``t`` and at most ``map.max_fix_age_s`` older, or None."""
        for s in reversed(self._fixes):
            if s.t <= t:
                return s if t - s.t <= self.cfg.map.max_fix_age_s else None
        return None

    # ------------------------------------------------------------ address claim / transmit
    def _log_claim(self, st: tuple[ClaimState, int | None]) -> None:
        state, addr = st
        if state is ClaimState.CANNOT_CLAIM:
            log.error("J1939: cannot claim an address (NAME 0x%016X); staying silent", self.claimer.name_int)  # type: ignore[union-attr]
        elif addr is not None:
            log.warning("J1939: claiming address 0x%02X (%d)", addr, addr)

    def _on_can_open(self) -> None:
        if self.claimer is not None:
            self._send_txs(self.claimer.start(self.clock.now()))
            log.info("J1939: claiming address 0x%02X with NAME 0x%016X",
                     self.claimer.address or 0, self.claimer.name_int)

    def _send_txs(self, txs: list[Tx]) -> None:
        for tx in txs:
            if tx.delay_s > 0 and self._loop is not None:
                self._loop.call_later(self.clock.wall(tx.delay_s), self.can.send, tx.can_id, tx.data)
            else:
                self.can.send(tx.can_id, tx.data)

    def _broadcast(self, est: Any) -> None:
        cl = self.claimer
        if cl is None or self.can.bus is None or not cl.can_transmit(self.clock.now()):
            self.stats["broadcast_skipped"] += 1
            return
        sa = cl.address
        assert sa is not None
        prio = self.cfg.broadcast.priority
        if est is None:
            frames = broadcast.no_estimate_frames(self.codec, sa, prio)
        else:
            frames = broadcast.estimate_frames(self.codec, est, sa, prio)
        ok = all([self.can.send(cid, data) for cid, data in frames])
        self.stats["broadcasts" if ok else "broadcast_errors"] += 1

    # ------------------------------------------------------------ estimation loop
    def _step(self, t: float) -> Any:
        inputs, meas = self.steps.take(t)
        try:
            est = self.estimator.step(t, inputs, meas)
        except Exception as e:  # the estimator must not take the daemon down
            self.stats["estimator_errors"] += 1
            self._warn_once("estimator", "estimator step failed at t=%.3f: %r; resetting it", t, e)
            if hasattr(self.estimator, "reset"):
                self.estimator.reset()
            return None
        self.stats["steps"] += 1
        self.last_estimate = est
        return est

    async def _estimation_loop(self) -> None:
        loop = asyncio.get_running_loop()
        ec = self.cfg.estimation
        rate = ec.rate_hz
        lag = ec.lag_s
        bc_every = max(1, round(rate / self.cfg.broadcast.rate_hz))
        map_every = max(1, round(rate / self.cfg.map.rate_hz))
        clock = self.clock
        g0 = clock.now()
        anchored = False
        k = 0
        est = None
        while True:
            if not anchored and self.anchor is not None:
                g0, k, anchored = self.anchor, 0, True
                self.grid_t0 = g0
            t_k = g0 + k / rate
            delay = clock.mono_at(t_k + lag) - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
                continue
            if -delay > self.max_tick_delay_s:
                self.max_tick_delay_s = -delay
            if -delay * clock.speed > ec.max_catch_up_s:
                k_new = math.ceil((clock.now() - lag - g0) * rate)
                self.stats["skipped_steps"] += k_new - k
                self._warn_once("behind", "estimation loop %.2f s behind; skipping %d steps",
                                -delay * clock.speed, k_new - k)
                k = k_new
                continue
            if -delay > 1.0 / rate:
                # the process was not scheduled for a while: read what arrived meanwhile before
                # stepping (on time, the readers' callbacks have already run in this loop pass)
                self.can.drain()
                if self.gps is not None:
                    self.gps.drain()
            else:
                self.can.drain_queued()
            if anchored:
                est = self._step(t_k)
            else:
                self.stats["idle_ticks"] += 1
            if k % bc_every == 0:
                self._broadcast(est if anchored else None)
            if anchored and est is not None and self.map is not None and k % map_every == 0:
                self.map.add(est, self.fix_at(t_k))
            now_m = loop.time()
            if self.map is not None:
                self.map.maybe_flush(now_m)
            if self._watchdog_s is not None and now_m - self._last_wd >= self._watchdog_s / 4:
                self._last_wd = now_m
                self.notifier.watchdog()
            k += 1
            if k % 32 == 0:
                await asyncio.sleep(0)  # let readers in while catching up

    # ------------------------------------------------------------ status
    def _rate_update(self) -> None:
        now = time.monotonic()
        dt = (now - self._rate_mono) * self.clock.speed  # rates per service second
        cur = {
            "can": float(self.can.stats["rx_frames"]),
            "inputs": float(sum(self.stats["rx_" + m] for m in INPUT_MESSAGES)),
            "gps": float(self.stats["gps_fixes"]),
            "est": float(self.stats["steps"]),
            "tx": float(self.can.stats["tx_frames"]),
        }
        if dt > 0 and self._rate_prev:
            self.rates = {k: (v - self._rate_prev.get(k, 0.0)) / dt for k, v in cur.items()}
        self._rate_prev = cur
        self._rate_mono = now

    def status_line(self) -> str:
        """One line: speed, μ, ρ_s, a, slip, status, rates, address."""
        e = self.last_estimate
        r = self.rates

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
        addr = self.address
        cl = self.claimer
        a = "listen-only" if cl is None else ("cannot-claim" if cl.state is ClaimState.CANNOT_CLAIM
                                               else f"0x{addr:02X}" if addr is not None else "-")
        can_s = "open" if self.can.is_open.is_set() else "DOWN"
        gps_s = "off" if self.gps is None else ("open" if self.gps.is_open.is_set() else "DOWN")
        t = "" if self.grid_t0 is None else f"t {self.clock.now() - self.grid_t0:6.1f} s  "
        return (f"{t}{est} | CAN {can_s} {r.get('can', 0):.0f} fr/s (inputs {r.get('inputs', 0):.0f}/s)"
                f"  GPS {gps_s} {r.get('gps', 0):.1f} Hz  est {r.get('est', 0):.0f} Hz"
                f"  tx {r.get('tx', 0):.0f} fr/s  addr {a}")

    def counters(self) -> dict[str, Any]:
        """Every counter, for logs and tests."""
        out: dict[str, Any] = {"service": {**self.stats, "max_tick_delay_s": self.max_tick_delay_s}, "can": dict(self.can.stats),
                               "unknown_pgns": dict(self.unknown_pgns), "bad_frames": dict(self.bad_frames),
                               "steps": {**self.steps.counts, "max_late_s": self.steps.max_late_s}}
        if self.gps is not None:
            out["gps"] = {**self.gps.stats, "max_delay_s": self.gps.stream.max_delay_s}
        if self.claimer is not None:
            out["address_claim"] = dict(self.claimer.counts)
        if self.map is not None:
            out["map"] = dict(self.map.stats)
            if self.map.store is not None:
                out["map_store"] = dict(self.map.store.stats)
        est = self.estimator
        if est is not None and hasattr(est, "counters"):
            out["estimator"] = dict(est.counters)
        return out

    async def _status_loop(self) -> None:
        period = self.cfg.service.status_interval_s
        self._rate_update()
        while True:
            await asyncio.sleep(period)
            self._rate_update()
            line = self.status_line()
            self.notifier.status(line)
            if self.status_stream is not None:
                try:
                    print(line, file=self.status_stream, flush=True)
                except (OSError, ValueError):
                    self.status_stream = None

    # ------------------------------------------------------------ lifecycle
    def _load_vehicle(self) -> Any:
        from ..config import VehicleParams, load_vehicle

        if self.cfg.estimation.vehicle:
            return load_vehicle(self.cfg.estimation.vehicle)
        return VehicleParams()

    async def run(self, stop: asyncio.Event | None = None) -> int:
        """Run until SIGTERM/SIGINT, :meth:`request_stop` or ``stop`` is set.  Returns the exit code."""
        loop = asyncio.get_running_loop()
        self._loop = loop
        self._stop = stop or asyncio.Event()
        signals_installed: list[int] = []
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGTERM, signal.SIGINT):
                try:
                    loop.add_signal_handler(sig, self.request_stop)
                    signals_installed.append(sig)
                except (NotImplementedError, RuntimeError, ValueError):
                    pass
        tasks: list[tuple[str, asyncio.Task[Any]]] = []
        errors: list[str] = []
        try:
            state = self.cfg.state_dir(self.env)
            try:
                state.mkdir(parents=True, exist_ok=True)
                (state / "run-config.toml").write_text(to_toml(self.cfg), encoding="utf-8")
            except OSError as e:
                raise ConfigError(f"service.state_dir: cannot write {state}: {e}") from e
            self.estimator = self.estimator_factory(self._load_vehicle())
            if self.map is not None:
                await self.map.open()
            tasks.append(("can", asyncio.create_task(self.can.run(), name="can")))
            if self.gps is not None:
                tasks.append(("gps", asyncio.create_task(self.gps.run(), name="gps")))
            if self.warm_up_estimator:
                self.notifier.status("preparing the estimator")
                try:
                    dt = await loop.run_in_executor(None, warm_up, self.estimator_factory, self._load_vehicle())
                    log.info("estimator compiled and ready in %.2f s", dt)
                except Exception as e:  # the real steps will show it; do not stop here
                    log.warning("estimator warm-up failed: %r", e)
            settle_heap()
            tasks.append(("estimation", asyncio.create_task(self._estimation_loop(), name="estimation")))
            tasks.append(("status", asyncio.create_task(self._status_loop(), name="status")))
            self.notifier.status("waiting for the CAN bus" + (" and GPS" if self.gps else ""))
            ready = asyncio.create_task(self._wait_ready())
            stopper = asyncio.create_task(self._stop.wait())
            watched = {t for _, t in tasks} | {ready, stopper}
            while not self._stop.is_set():
                done, _ = await asyncio.wait(watched, return_when=asyncio.FIRST_COMPLETED)
                if ready in done and ready in watched:
                    watched.discard(ready)
                    self.ready.set()
                    self.notifier.ready(self._ready_text())
                    log.info("ready: %s", self._ready_text())
                for name, t in tasks:
                    if t in done:  # a task that ends by itself is a bug: stop and let systemd restart us
                        exc = t.exception() if not t.cancelled() else None
                        log.error("task %s ended unexpectedly: %r", name, exc)
                        errors.append(f"{name}: {exc!r}")
                        self.exit_code = 1
                        self._stop.set()
            ready.cancel()
            stopper.cancel()
        except ConfigError:
            raise
        finally:
            self.notifier.stopping()
            errors += await self._shutdown(tasks)
            for sig in signals_installed:
                loop.remove_signal_handler(sig)
        if errors:
            for e in errors:
                log.error("shutdown: %s", e)
            self.exit_code = self.exit_code or 1
        log.info("stopped; counters: %s", self.counters())
        self.notifier.close()
        return self.exit_code

    def _ready_text(self) -> str:
        gps = f", GPS {self.cfg.gps.port}" if self.gps is not None else ""
        return f"CAN {self.cfg.can.interface}:{self.cfg.can.channel}{gps} open"

    async def _wait_ready(self) -> None:
        await self.can.is_open.wait()
        if self.gps is not None:
            await self.gps.is_open.wait()

    async def _shutdown(self, tasks: list[tuple[str, asyncio.Task[Any]]]) -> list[str]:
        """Stop in reverse order of start; returns the errors met."""
        errors: list[str] = []
        byname = dict(tasks)
        for name in ("status", "estimation"):
            t = byname.get(name)
            if t is not None and not t.done():
                t.cancel()
                try:
                    await t
                except asyncio.CancelledError:
                    pass
                except Exception as e:
                    errors.append(f"{name}: {e!r}")
        for name, closer in (("gps", self.gps.close if self.gps else None), ("can", self.can.close)):
            t = byname.get(name)
            if closer is None or t is None:
                continue
            try:
                await closer()
                await asyncio.wait_for(t, timeout=5.0)
            except asyncio.TimeoutError:
                t.cancel()
                errors.append(f"{name}: did not stop within 5 s")
            except asyncio.CancelledError:
                pass
            except Exception as e:
                errors.append(f"{name}: {e!r}")
        if self.map is not None:
            try:
                await self.map.close()
            except Exception as e:
                errors.append(f"map: {e!r}")
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
