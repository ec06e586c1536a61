"""The service's ``advice`` part: efficiency, s* and advice from the live estimates, on the bus and the map.

Runs as its own task beside the estimation loop, never inside its step:
woken right after each broadcast step (the daemon's broadcast callback sets
an event; the next broadcast is a whole broadcast period away) it takes the
loop's last estimate (a reference; the loop never waits for this part),
feeds the
:class:`~tractionecu.advice.engine.AdviceEngine` (s* is recomputed once a second), sends
``TECU_EstEfficiency`` (:mod:`tractionecu.advice.bus`) and adds the estimate at its GNSS
position to the live map (:class:`LiveMap`) the in-cab page shows.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections import Counter
from typing import Any, Callable

from ..advice.engine import AdviceEngine
from ..aio import wait_event
from .lifecycle import TaskPart

log = logging.getLogger(__name__)

EARTH_RADIUS_M = 6371008.8
"""Mean Earth radius [m] (IUGG) for the live map's local plane."""


class LiveMap:
    """Cell means of a, ρ_s, slip and η on a local plane around the first fix, for the page.

    Equirectangular projection about the first position (metres east and
    north; under 0.1 % error within a few km); ``cell_m`` square cells.
    :meth:`take_changed` returns the cells changed since its last call (the
    page's delta), :meth:`cells` all of them (a new viewer).  At most
    ``max_cells`` cells are kept (beyond that new cells are counted, not kept).
    """

    FIELDS = ("a", "rho_s", "slip", "eta")

    def __init__(self, cell_m: float = 3.0, max_cells: int = 40000) -> None:
        self.cell_m = cell_m
        self.max_cells = max_cells
        self.origin: tuple[float, float] | None = None
        self._sums: dict[tuple[int, int], list[float]] = {}
        self._changed: set[tuple[int, int]] = set()
        self.track: list[tuple[float, float]] = []
        self.dropped = 0

    def xy(self, lat: float, lon: float) -> tuple[float, float]:
        if self.origin is None:
            self.origin = (lat, lon)
        lat0, lon0 = self.origin
        x = math.radians(lon - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0))
        y = math.radians(lat - lat0) * EARTH_RADIUS_M
        return x, y

    def add(self, lat: float, lon: float, values: dict[str, float]) -> None:
        x, y = self.xy(lat, lon)
        key = (math.floor(x / self.cell_m), math.floor(y / self.cell_m))
        acc = self._sums.get(key)
        if acc is None:
            if len(self._sums) >= self.max_cells:
                self.dropped += 1
                return
            acc = self._sums[key] = [0.0] * (2 * len(self.FIELDS))
        for i, f in enumerate(self.FIELDS):
            v = values.get(f, math.nan)
            if math.isfinite(v):
                acc[2 * i] += v
                acc[2 * i + 1] += 1.0
        self._changed.add(key)
        if not self.track or math.hypot(x - self.track[-1][0], y - self.track[-1][1]) >= 1.0:
            self.track.append((round(x, 1), round(y, 1)))
            if len(self.track) > 20000:
                del self.track[:10000:2]          # thin the oldest half

    def _cell(self, key: tuple[int, int]) -> list[Any]:
        acc = self._sums[key]
        vals = [round(acc[2 * i] / acc[2 * i + 1], 4) if acc[2 * i + 1] > 0 else None for i in range(len(self.FIELDS))]
        return [key[0], key[1], *vals]

    def cells(self) -> list[list[Any]]:
        return [self._cell(k) for k in self._sums]

    def take_changed(self) -> list[list[Any]]:
        out = [self._cell(k) for k in self._changed]
        self._changed.clear()
        return out


class AdvicePart(TaskPart):
    """The ``advice`` part (module doc).

    ``engine`` is the :class:`~tractionecu.advice.engine.AdviceEngine` or a callable building it at start-up;
    ``estimate()`` returns the loop's last estimate; ``fix_at(t)`` the fix
    for a time (or None); ``send(report)`` puts ``TECU_EstEfficiency`` on the
    bus (None: nothing sent); ``period_s`` service seconds between samples;
    ``speed`` service seconds per wall second.
    """

    name = "advice"

    def __init__(self, engine: AdviceEngine | Callable[[], AdviceEngine], estimate: Callable[[], Any], *,
                 period_s: float = 0.1, speed: float = 1.0, fix_at: Callable[[float], Any] | None = None,
                 send: Callable[[Any], Any] | None = None, live_map: LiveMap | None = None,
                 trigger: asyncio.Event | None = None) -> None:
        super().__init__()
        self.trigger = trigger
        self._make = None if isinstance(engine, AdviceEngine) else engine
        self.engine: AdviceEngine = engine if isinstance(engine, AdviceEngine) else AdviceEngine()
        self.estimate = estimate
        self.period_s = period_s
        self.speed = speed
        self.fix_at = fix_at
        self.send = send
        self.map = live_map
        self.stats: Counter[str] = Counter()
        self.max_work_s = 0.0
        self.cpu_s = 0.0
        """CPU time of the ticks [s]."""
        self._last_t = math.nan

    def tick(self) -> None:
        """One sample: feed a new estimate, send the message, map it."""
        est = self.estimate()
        if est is not None and getattr(est, "t", math.nan) != self._last_t:
            self._last_t = est.t
            try:
                rep = self.engine.feed(est)
            except Exception as e:          # advice must never take the daemon down
                self.stats["errors"] += 1
                if self.stats["errors"] == 1:
                    log.exception("advice: feeding an estimate failed: %r", e)
                return
            self.stats["fed"] += 1
            if self.map is not None and self.fix_at is not None:
                fix = self.fix_at(est.t)
                if fix is not None and rep.slip_ok:
                    self.map.add(fix.lat_deg, fix.lon_deg, {"a": rep.a, "rho_s": rep.rho_s, "slip": rep.slip,
                                                            "eta": rep.eta})
        if self.send is not None:
            self.send(self.engine.report)
            self.stats["sent"] += 1

    async def start(self) -> None:
        """Build the engine for the configured machine (known once the estimator is built), then run."""
        if self._make is not None:
            self.engine = self._make()
        await super().start()

    async def run(self) -> None:
        wall = self.period_s / self.speed
        loop = asyncio.get_running_loop()
        nxt = loop.time()
        while True:
            if self.trigger is not None:
                # right after the loop's broadcast step: the furthest from the next broadcast
                if not await wait_event(self.trigger, max(2 * wall, 0.5)):
                    self.stats["untriggered"] += 1
                self.trigger.clear()
            else:
                nxt += wall
                delay = nxt - loop.time()
                if delay < -wall:                  # far behind: do not catch up in a burst
                    nxt = loop.time()
                    delay = 0.0
                await asyncio.sleep(max(delay, 0.0))
            t0 = time.perf_counter()
            c0 = time.thread_time()
            self.tick()
            self.cpu_s += time.thread_time() - c0
            self.max_work_s = max(self.max_work_s, time.perf_counter() - t0)

