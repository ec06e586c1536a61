"""The estimation loop: the estimator stepped on a fixed grid of the service clock.

Grid ``t_k = g0 + k / rate`` on the service clock (monotonic, so it neither
drifts nor jumps).  ``g0`` is phased to the first wheel-speed frame exactly
as ``replay`` does: the step assembler records it
(:attr:`~tractionecu.pipeline.steps.StepAssembler.anchor`, that frame's time
``+ GRID_MARGIN_S``).  Step k runs ``lag_s`` after ``t_k``, when every frame
stamped up to ``t_k`` has arrived, and feeds the estimator through the step
assembler, so a capture of the bus replayed offline gives the same
estimates.  Until the first wheel-speed frame the loop idles
(``idle_ticks``) and broadcasts "no estimate".  The estimator predicts only
and sets its timeout bits when a signal stops.  A loop that falls more than
``max_catch_up_s`` behind skips ahead (``skipped_steps``).  Every
``rate / broadcast.rate_hz`` steps the estimate is broadcast; every
``rate / map.rate_hz`` steps it goes to the map; then the network serves
its queued requests (``after_step``, bounded per step), so that work comes
after the estimate, never before it.

``WATCHDOG=1`` is sent from this loop and means "estimating": it is sent
only while steps complete on schedule.  A step that runs more than one
broadcast period late, or skipped steps, put the loop *behind*; once it has
been behind for ``service.watchdog_behind_s`` the loop stops sending
``WATCHDOG=1`` (``watchdog_withheld`` counts such episodes), says why in
``STATUS=`` and the log, and systemd restarts the service after its
``WatchdogSec=``.  Steps on schedule again for :data:`RECOVER_S` resume it
(a loop that skips ahead and at once falls behind again does not).

The estimator is built in one place, :meth:`EstimationLoop.build_estimator`,
from the machine of the configuration (:func:`estimator_machine`: the
vehicle and its sensor figures).  Its compiled kernels are warmed up on a
throwaway estimator (:func:`warm_up`) before the loop starts.
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
import time
from collections import Counter
from typing import Any, Callable, Protocol

from ..counting import WarnOnce
from ..pipeline.steps import GRID_MAX_GAP_S, StepAssembler
from .clock import ServiceClock
from .config import ServiceConfig
from .fixes import FixBuffer
from .lifecycle import TaskPart
from .mapwriter import MapWriter

log = logging.getLogger(__name__)

EstimatorFactory = Callable[[Any, Any], Any]
"""``factory(vehicle, sensors) -> estimator`` with ``step(t, inputs, measurements)`` (and optionally
``reset()`` and ``counters``)."""


def default_estimator_factory(vehicle: Any, sensors: Any = None, cfg: Any = None) -> Any:
    """The estimator ``replay`` uses, with its default tuning (``sensors`` None: the documented figures;
    ``cfg`` an :class:`~tractionecu.estimation.config.EstimatorConfig`, None: the defaults): the hub
    estimator, or for an engine-driven ``[drivetrain]`` the machine-level one
    (:class:`~tractionecu.estimation.machine.MachineEstimator`, draft as ``draft_sensing`` says)."""
    dt = getattr(vehicle, "drivetrain", None)
    if dt is not None and dt.engine_driven:
        from ..estimation.machine import MachineEstimator

        return MachineEstimator(vehicle, cfg, sensors=sensors, draft=dt.draft_sensing)
    from ..estimation.estimator import Estimator

    return Estimator(vehicle, cfg, sensors=sensors)


def service_estimator_config(cfg: ServiceConfig) -> Any:
    """The :class:`~tractionecu.estimation.config.EstimatorConfig` of the service: the defaults with the
    ``[estimation]`` timeouts as the floors of the rate-derived ones (the keys were read and written to the
    resolved configuration but never reached the estimator)."""
    from ..estimation.config import EstimatorConfig

    e = cfg.estimation
    return EstimatorConfig(wheel_timeout_s=e.wheel_speed_timeout_s, gps_timeout_s=e.ground_speed_timeout_s,
                           torque_timeout_s=e.torque_timeout_s, axle_timeout_s=e.axle_load_timeout_s,
                           draft_timeout_s=e.draft_timeout_s)


def estimator_groups(cfg: ServiceConfig) -> Any:
    """The signal table the step assembler collects for the configured machine
    (:data:`~tractionecu.pipeline.signals.MACHINE_GROUPS` for an engine-driven ``[drivetrain]``, else
    None: the hub estimator's)."""
    from ..pipeline.signals import MACHINE_GROUPS, estimator_profile

    vehicle, _ = estimator_machine(cfg)
    return MACHINE_GROUPS if estimator_profile(vehicle) == "mechanical" else None


def estimator_machine(cfg: ServiceConfig) -> tuple[Any, Any]:
    """``(vehicle, sensors)`` the estimator is built for.

    The vehicle is ``estimation.vehicle``'s file, else the documented
    defaults; the sensor figures are :meth:`ServiceConfig.resolved_sensors`
    (the service's ``[sensors]`` keys over the vehicle file's over the
    defaults).
    """
    from ..config import VehicleParams, load_vehicle

    vehicle = load_vehicle(cfg.estimation.vehicle) if cfg.estimation.vehicle else VehicleParams()
    return vehicle, cfg.resolved_sensors()


def warm_up(factory: EstimatorFactory, vehicle: Any, sensors: Any = None) -> float:
    """Run a throwaway estimator through every kind of step; returns the seconds it took.

    The estimator's compiled (numba) kernels are compiled or loaded from their
    cache on first use, which takes seconds; done here, before the estimation
    loop starts, it delays neither the first steps nor the watchdog.  A short
    drive does not reach every kernel (the curvature's noise needs a turn,
    covariance matching's ratio a full window), so every filter kernel is
    compiled first (:func:`~tractionecu.estimation._kernels.warm_up`), then the
    drive compiles the machine's own model, and its estimates go through the
    fixed-lag smoother (its kernels) as the loop's do.
    """
    import numpy as np

    from ..estimation import _kernels
    from ..estimation.smoother import FixedLagSmoother

    t0 = time.perf_counter()
    _kernels.warm_up()
    est = factory(vehicle, sensors)
    smoother = FixedLagSmoother.for_estimator(est)
    push = smoother.push
    if getattr(est, "level", None) == "machine":          # the machine-level estimator's keys
        for k in range(60):
            t = 0.01 * k
            meas = {"we": 200.0 + 0.1 * k, "vwb": 2.5, **({"v": 2.4, "vr": 2.4} if k % 10 == 0 else {})}
            inputs = {"Te": 60.0, "Tref": 400.0, "gear": 4.0, "Fzf": 25000.0, "Fdx": 12000.0} if k % 7 else {}
            push(est.step(t, inputs, meas if k % 5 else {}))
        push(est.step(1.0, {"Te": math.nan}, {"v": 2.4}))
        smoother.flush()
        return time.perf_counter() - t0
    md = np.full(4, 900.0)
    om = np.full(4, 3.2)
    for k in range(60):
        t = 0.01 * k
        meas: dict[str, Any] = {"omega": om + 0.001 * k}
        if k % 10 == 0:
            meas["v"] = 2.4
        inputs = {"Md": md, "Fzf": 25000.0, "Fdx": 12000.0} if k % 7 else {}
        push(est.step(t, inputs, meas if k % 5 else {}))
    push(est.step(1.0, {"Md": md, "Fzf": math.nan}, {"v": 2.4}))
    smoother.flush()
    return time.perf_counter() - t0


RECOVER_S = 1.0
"""A loop that was behind is back on schedule once its steps have run on time this long [wall s]
(or ``service.watchdog_behind_s`` if shorter): one that skips ahead and falls behind again is not."""


class Reader(Protocol):
    """A device reader whose received input can be processed now (CAN link, GNSS reader)."""

    def drain(self) -> Any: ...


class EstimationLoop(TaskPart):
    """The estimator and the loop that steps it (module doc).

    Parameters
    ----------
    cfg:
        Resolved configuration (``[estimation]``, ``broadcast.rate_hz``, ``map.rate_hz``).
    clock:
        Service clock.
    steps:
        The step assembler the dispatcher fills.
    factory:
        Builds the estimator (:data:`EstimatorFactory`).
    broadcast:
        ``broadcast(estimate or None)`` every ``rate / broadcast.rate_hz`` steps.
    map_writer, fixes:
        The map writer (None: no map) and the fix buffer giving each mapped estimate its position.
    can, gps:
        Readers to drain before a step that runs late (``can`` also has ``drain_queued``).
    watchdog:
        Sends ``WATCHDOG=1``; ``watchdog_s`` is systemd's interval (None: no watchdog).
    status:
        ``status(text)`` sends ``STATUS=`` (when the loop stops or resumes feeding the watchdog).
    after_step:
        Called after each tick's step, broadcast and map work (the network's request serving).
    stats:
        Counter for ``steps``, ``estimator_errors``, ``idle_ticks``, ``skipped_steps`` (default: a new one).

    Attributes
    ----------
    estimator, last_estimate:
        The estimator (built by :meth:`build_estimator`) and its last estimate delivered: the fixed-lag
        smoother (:mod:`tractionecu.estimation.smoother`, ``[estimator] smoother_lag_s``) delivers each
        estimate that much later, revised by the steps in between.
    grid_t0:
        ``g0`` once the grid is phased, else None.
    max_tick_delay_s:
        Longest a step ran after it was due [wall s] (scheduling latency of the loop).
    behind_since:
        ``loop.time()`` since which the loop is behind its schedule, or None.
    """

    name = "estimation"

    def __init__(self, cfg: ServiceConfig, clock: ServiceClock, steps: StepAssembler, *,
                 factory: EstimatorFactory = default_estimator_factory,
                 broadcast: Callable[[Any], Any] | None = None,
                 map_writer: MapWriter | None = None, fixes: FixBuffer | None = None,
                 can: Any = None, gps: Reader | None = None,
                 watchdog: Callable[[], Any] | None = None, watchdog_s: float | None = None,
                 status: Callable[[str], Any] | None = None, after_step: Callable[[], Any] | None = None,
                 stats: Counter[str] | None = None) -> None:
        super().__init__()
        self.cfg = cfg
        self.clock = clock
        self.steps = steps
        self.factory = factory
        self.broadcast = broadcast
        self.map = map_writer
        self.fixes = fixes
        self.can = can
        self.gps = gps
        self.watchdog = watchdog
        self.watchdog_s = watchdog_s
        self.status = status
        self.after_step = after_step
        self.behind_since: float | None = None
        self._on_time_since: float | None = None
        self.withheld = False
        self.stats: Counter[str] = Counter() if stats is None else stats
        self.machine: tuple[Any, Any] | None = None
        self.estimator: Any = None
        self.smoother: Any = None
        self.last_estimate: Any = None
        self._t_mapped: float | None = None      # the time of the last estimate given to the map [s]
        self.grid_t0: float | None = None
        self.max_tick_delay_s = 0.0
        self._last_wd = -math.inf
        self._warn = WarnOnce(log)

    # ------------------------------------------------------------ the estimator
    def build_estimator(self) -> Any:
        """Build the estimator for the configured machine (:func:`estimator_machine`); returns it."""
        from ..estimation.smoother import FixedLagSmoother

        self.machine = estimator_machine(self.cfg)
        self.estimator = self.factory(*self.machine)
        self.smoother = (FixedLagSmoother.for_estimator(self.estimator)
                         if getattr(self.estimator, "cfg", None) is not None else None)
        return self.estimator

    async def warm_up(self) -> float:
        """:func:`warm_up` a throwaway estimator of the same machine in a worker thread; returns seconds.

        The thread is a daemon of its own, not the loop's executor: a first start compiles for 30–45 s, and a
        stop meanwhile (SIGTERM) waited for the compilation in the executor's shutdown, beyond systemd's
        ``TimeoutStopSec``.  A stop now leaves the thread behind; the process ends without it."""
        machine = self.machine or estimator_machine(self.cfg)
        loop = asyncio.get_running_loop()
        done: asyncio.Future[float] = loop.create_future()

        def settle(ok: bool, value: Any) -> None:
            if not done.done():
                done.set_result(value) if ok else done.set_exception(value)

        def work() -> None:
            try:
                res: tuple[bool, Any] = (True, warm_up(self.factory, *machine))
            except Exception as e:  # noqa: BLE001 -- handed to the awaiting start-up step
                res = (False, e)
            try:
                loop.call_soon_threadsafe(settle, *res)
            except RuntimeError:          # the loop has closed: the service stopped meanwhile
                pass

        threading.Thread(target=work, name="estimator-warm-up", daemon=True).start()
        return await done

    def step(self, t: float) -> Any:
        """Step the estimator at grid time ``t`` [s] with what the assembler holds; the latest estimate the
        smoother delivers (of a time up to ``smoother_lag_s`` and a step earlier), or None.

        An estimator that raises is counted (``estimator_errors``), logged
        once and reset; the loop goes on.
        """
        la = self.steps.last_anchor
        if la is not None and t - la > GRID_MAX_GAP_S and hasattr(self.estimator, "no_data"):
            # Replay's grid has no step in a wheel-speed gap this long, and the estimator restarts after it.
            # Stepping on would integrate the held drive torques with nothing to correct them (the speed on the
            # page grew by 0.3 m/s² for as long as the bus stayed silent).  Nothing is taken: the first step
            # after the gap gets the latest samples, as replay's does.
            self.stats["no_data_steps"] += 1
            self._warn("no_data", "no wheel speeds for %.1f s: estimation paused until they return", t - la)
            return self._deliver(t, self.estimator.no_data(t))
        self._warn.forget("no_data")
        inputs, meas = self.steps.take(t)
        try:
            est = self.estimator.step(t, inputs, meas)
        except Exception as e:  # the estimator must not take the daemon down
            self.stats["estimator_errors"] += 1
            self._warn("estimator", "estimator step failed at t=%.3f: %r; resetting it", t, e)
            if hasattr(self.estimator, "reset"):
                self.estimator.reset()
            return None
        self.stats["steps"] += 1
        return self._deliver(t, est)

    def _deliver(self, t: float, est: Any) -> Any:
        """``est`` through the smoother; the last estimate it delivers (None: none yet)."""
        return self._delivered(t, [est] if self.smoother is None else self.smoother.push(est))

    def _delivered(self, t: float, out: list[Any]) -> Any:
        """The estimates ``out`` the smoother delivered at grid time ``t`` [s]: a lost filter's period is taken
        off the map; the last of them (None: none) becomes ``last_estimate``."""
        for e in out:
            since = getattr(e, "lost_since", math.nan)
            if not math.isnan(since):      # the filter had lost the vehicle since then
                self.stats["filter_lost"] += 1
                g0 = self.grid_t0 if self.grid_t0 is not None else t      # the status line's t
                self._warn("lost", "estimator lost the vehicle at t %.1f s (since %.1f s); re-initialised",
                           e.t - g0, since - g0)
                if self.map is not None:
                    self.map.discard_since(since)
        if not out:
            return None
        self.last_estimate = out[-1]
        return out[-1]

    async def stop(self) -> None:
        """Stop the loop, then deliver what the smoother still holds (:meth:`flush_smoother`)."""
        await super().stop()
        self.flush_smoother()

    def flush_smoother(self) -> list[Any]:
        """The estimates of the run's last ``smoother_lag_s`` that the smoother still holds, smoothed with the steps
        there are: the last becomes ``last_estimate``, and the map gets those due at its rate after the last one it
        was given (a stop no longer drops them).  Returns them."""
        if self.smoother is None:
            return []
        try:
            out = self.smoother.flush()
        except Exception as e:  # noqa: BLE001 -- a stop must go on; nothing the map holds is lost
            self._warn("flush", "the smoother's last estimates were not delivered at the stop: %r", e)
            return []
        if not out:
            return out
        self._delivered(out[-1].t, out)
        if self.map is not None:
            period = 1.0 / self.cfg.map.rate_hz - 0.5 / self.cfg.estimation.rate_hz
            for e in out:
                if self._t_mapped is None or e.t - self._t_mapped >= period:
                    self.map.add(e, None if self.fixes is None else self.fixes.fix_at(e.t))
                    self._t_mapped = e.t
                    self.stats["mapped_at_stop"] += 1
        return out

    # ------------------------------------------------------------ the loop
    def behind_text(self, now_m: float) -> str:
        """Why ``WATCHDOG=1`` is withheld ("" while it is sent)."""
        if not self.withheld or self.behind_since is None:
            return ""
        return (f"estimation behind schedule for {now_m - self.behind_since:.1f} s "
                f"(budget service.watchdog_behind_s = {self.cfg.service.watchdog_behind_s:g} s): watchdog not fed")

    def _schedule(self, behind: bool, now_m: float, recover_s: float = 0.0) -> bool:
        """Track whether the loop is behind; True while ``WATCHDOG=1`` may be sent.

        A late step or a skip makes it behind; it is back on schedule once its
        steps have run on time for ``recover_s`` (a loop that skips ahead and
        falls behind again never is).
        """
        if behind:
            self._on_time_since = None
            if self.behind_since is None:
                self.behind_since = now_m
        elif self.behind_since is not None:
            if self._on_time_since is None:
                self._on_time_since = now_m
            if now_m - self._on_time_since >= recover_s:
                if self.withheld:
                    self.withheld = False
                    log.warning("estimation back on schedule after %.1f s behind: watchdog fed again",
                                now_m - self.behind_since)
                    if self.status is not None:
                        self.status("estimation back on schedule")
                self.behind_since = None
        if self.behind_since is None or now_m - self.behind_since < self.cfg.service.watchdog_behind_s:
            return not self.withheld
        if not self.withheld:
            self.withheld = True
            self.stats["watchdog_withheld"] += 1
            text = self.behind_text(now_m)
            log.error("%s", text)
            if self.status is not None:
                self.status(text)
        return False

    def _drain(self, late: bool) -> None:
        """Process input that arrived meanwhile: every reader after a late wake-up, else the CAN queue."""
        if late:
            # the process was not scheduled for a while: read what arrived meanwhile before
            # stepping (on time, the readers' callbacks have already run in this loop pass)
            for r in (self.can, self.gps):
                if r is not None:
                    r.drain()
        elif self.can is not None:
            self.can.drain_queued()

    async def run(self) -> None:
        loop = asyncio.get_running_loop()
        ec = self.cfg.estimation
        rate = ec.rate_hz
        lag = ec.lag_s
        bc_every = max(1, round(rate / self.cfg.broadcast.rate_hz))
        late_s = 1.0 / self.cfg.broadcast.rate_hz       # later than this [service s]: behind schedule
        recover_s = min(self.cfg.service.watchdog_behind_s, RECOVER_S)
        map_every = max(1, round(rate / self.cfg.map.rate_hz))
        clock = self.clock
        g0 = clock.now()
        anchored = False
        k = 0
        est = None
        while True:
            if not anchored and self.steps.anchor is not None:
                g0, k, anchored = self.steps.anchor, 0, True
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
                self._warn("behind", "estimation loop %.2f s behind; skipping %d steps",
                           -delay * clock.speed, k_new - k)
                self._schedule(True, loop.time())
                k = k_new
                continue
            self._drain(-delay > 1.0 / rate)
            if anchored:
                est = self.step(t_k)
            else:
                self.stats["idle_ticks"] += 1
            if k % bc_every == 0 and self.broadcast is not None:
                self.broadcast(est if anchored else None)
            if anchored and est is not None and self.map is not None and k % map_every == 0:
                self.map.add(est, None if self.fixes is None else self.fixes.fix_at(est.t))
                self._t_mapped = est.t
            if self.after_step is not None:
                self.after_step()
            now_m = loop.time()
            if self.map is not None:
                self.map.maybe_flush(now_m)
            on_schedule = self._schedule(-delay * clock.speed > late_s, now_m, recover_s)
            if (on_schedule and self.watchdog is not None and self.watchdog_s is not None
                    and now_m - self._last_wd >= self.watchdog_s / 4):
                self._last_wd = now_m
                self.watchdog()
            k += 1
            if k % 32 == 0:
                await asyncio.sleep(0)  # let readers in while catching up
