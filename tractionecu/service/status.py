"""The status line: once per ``service.status_interval_s`` to systemd (``STATUS=``) and optionally a stream.

:class:`StatusReporter` turns running totals (frames, steps, fixes ...) into
rates per service second and asks the service for the line to show.
"""

from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass
from typing import IO, Callable, ClassVar

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
    name: ClassVar[str] = "status"

    def __post_init__(self) -> None:
        super().__init__()
        self.rates: dict[str, float] = {}
        self._prev: dict[str, float] = {}
        self._prev_mono = time.monotonic()

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
        if self.stream is not None:
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
