"""The status line: once per ``service.status_interval_s`` to systemd (``STATUS=``) and optionally a stream.

:class:`StatusReporter` turns running totals (frames, steps, fixes ...) into
rates per service second and asks the service for the line to show.
"""

from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass
from typing import IO, Any, Callable, ClassVar

from .lifecycle import TaskPart
from .notify import Notifier


@dataclass(eq=False)
class StatusReporter(TaskPart):
    """Rates and the periodic status line.

    ``period_s`` wall seconds between lines; ``speed`` service seconds per
    wall second (rates are per service second); ``totals()`` running totals
    by name, whose rates :attr:`rates` holds; ``line()`` the line to show
    (reads :attr:`rates`); ``notifier`` gets it as ``STATUS=``; ``stream``
    prints it too (None: nowhere; dropped when it fails).
    """

    period_s: float
    speed: float
    totals: Callable[[], dict[str, float]]
    line: Callable[[], str]
    notifier: Notifier
    stream: IO[str] | None = None
    stream_every_s: float = 0.0
    """Least wall time between two lines printed on ``stream`` [s] (0: every line; the journal of a service
    under systemd takes one a minute, not one a second)."""
    name: ClassVar[str] = "status"

    def __post_init__(self) -> None:
        super().__init__()
        self.rates: dict[str, float] = {}
        self._prev: dict[str, float] = {}
        self._prev_mono = time.monotonic()
        self._printed_mono = -float("inf")

    def update_rates(self) -> dict[str, float]:
        """Rates [1/service s] of the totals since the last call (none at the first)."""
        now = time.monotonic()
        dt = (now - self._prev_mono) * self.speed
        cur = self.totals()
        if dt > 0 and self._prev:
            self.rates = {k: (v - self._prev.get(k, 0.0)) / dt for k, v in cur.items()}
        self._prev = cur
        self._prev_mono = now
        return self.rates

    def report(self) -> str:
        """Update the rates, send and print the line; returns it."""
        self.update_rates()
        text = self.line()
        self.notifier.status(text)
        now = time.monotonic()
        if self.stream is not None and now - self._printed_mono >= self.stream_every_s:
            self._printed_mono = now
            try:
                print(text, file=self.stream, flush=True)
            except (OSError, ValueError):
                self.stream = None
        return text

    async def run(self) -> None:
        self.update_rates()
        while True:
            await asyncio.sleep(self.period_s)
            self.report()


# ------------------------------------------------------------------ the in-cab page's state
CURVE_POINTS = 61
"""Points of the μ(s) and η(s) curves the page draws, slip 0 to :data:`CURVE_S_MAX`."""
CURVE_S_MAX = 0.3


def web_snapshot(svc: Any) -> dict[str, Any]:
    """The state the in-cab page shows (:mod:`tractionecu.web`), from a running
    :class:`~tractionecu.service.daemon.Service`: the last estimate, efficiency and s*, the μ(s) and η(s)
    curves with the operating point, the advice, and health (bus and GNSS state, estimator status bits,
    frame rates, dropped frames).  Reads the parts' attributes only; NaN where nothing is known."""
    import numpy as np

    from ..estimation.estimator import SLIP_AVERAGED, SLIP_UNCERTAIN, STATUS_NAMES
    from ..advice.efficiency import curve_of, eta_curve

    e = svc.estimation.last_estimate
    out: dict[str, Any] = {"wall": time.time()}
    g0 = svc.estimation.grid_t0
    out["t"] = None if g0 is None else svc.clock.now() - g0
    if e is not None:
        status = int(getattr(e, "status", 0) or 0)
        valid = bool(getattr(e, "valid", False))
        # a wheel's slip the estimate does not support (its own σ, a standstill, reversing: held) is not shown as
        # if it were this step's; μ and ρ_s are shown with the estimate's valid flag and status beside them
        slip_ok = valid and not status & (SLIP_UNCERTAIN | SLIP_AVERAGED)
        out["estimate"] = {
            "v": float(e.v), "mu": [float(x) for x in e.mu],
            "slip": [float(x) for x in e.slip] if slip_ok else [None] * 4,
            "rho_s": float(e.rho_s), "a": float(e.a), "soil_class": str(getattr(e, "soil_class", "")),
            "status": status, "status_bits": [n for b, n in STATUS_NAMES.items() if status & b],
            "valid": valid,
        }
    adv = svc.advice
    rep = adv.engine.report if adv is not None else None
    if rep is not None:
        out["efficiency"] = rep.as_dict()
        out["advice"] = [r.as_dict() for r in adv.engine.advice]
        c = curve_of(e) if e is not None else None
        if c is not None and e is not None:
            s = np.linspace(0.0, CURVE_S_MAX, CURVE_POINTS)
            out["curve"] = {"s": s.round(4).tolist(), "mu": c.mu(s).round(4).tolist(),
                            "eta": eta_curve(s, c, float(e.rho_s), adv.engine.tracker.cfg.rho_t).round(4).tolist(),
                            "class": c.class_name, "a": c.a}
    else:
        out["advice"] = []
    r = svc.status.rates
    can_stats = svc.can.stats
    health: dict[str, Any] = {
        "can": "open" if svc.can.is_open.is_set() else "down",
        "gps": "off" if svc.gps is None else ("open" if svc.gps.is_open.is_set() else "down"),
        "rates": {k: round(v, 2) for k, v in r.items()},
        "dropped_frames": int(can_stats.get("rx_kernel_dropped", 0) + can_stats.get("rx_overflow", 0)),
        "bad_frames": int(svc.stats.get("bad_frames", 0)),
        "unknown_pgn_frames": int(svc.stats.get("unknown_pgn_frames", 0)),
        "skipped_steps": int(svc.stats.get("skipped_steps", 0)),
        "late_frames": int(svc.steps.counts.get("late", 0)),
        "address": svc.network.describe_address(),
        "behind": svc.estimation.behind_text(time.monotonic()),
    }
    if svc.gps is not None:
        health["gps_fixes"] = int(svc.stats.get("gps_fixes", 0))
    health["map"] = "off" if svc.map is None else svc.map.state
    out["health"] = health
    return out
