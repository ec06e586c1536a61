"""The service's time base: epoch-like seconds advanced by the monotonic clock.

All service times (frame stamps, estimator grid, GNSS epochs) are seconds on
one axis.  It starts at the wall-clock epoch when the service starts and then
advances with ``time.monotonic()`` only, so a stepped system clock cannot
make the estimation loop jump or drift.  For ``run --simulate`` it can run
faster than real time (``speed``) and start at the recording's epoch.
"""

from __future__ import annotations

import time
from typing import Callable


class ServiceClock:
    """Service time [s] = ``epoch0 + (monotonic − m0) · speed``.

    Parameters
    ----------
    speed:
        Service seconds per wall second (1 for a real machine).
    epoch0:
        Service time at construction (default: ``time.time()``).
    monotonic:
        The monotonic source, in seconds (default ``time.monotonic``, which
        is also asyncio's ``loop.time()``).
    """

    def __init__(self, speed: float = 1.0, epoch0: float | None = None,
                 monotonic: Callable[[], float] = time.monotonic) -> None:
        if not speed > 0:
            raise ValueError(f"speed must be > 0, got {speed}")
        self.speed = float(speed)
        self._mono = monotonic
        self.m0 = monotonic()
        self.epoch0 = time.time() if epoch0 is None else float(epoch0)

    def now(self) -> float:
        """Current service time [s]."""
        return self.epoch0 + (self._mono() - self.m0) * self.speed

    def mono_at(self, t: float) -> float:
        """The monotonic time [s] at which service time ``t`` is reached."""
        return self.m0 + (t - self.epoch0) / self.speed

    def wall(self, dt: float) -> float:
        """A service-time interval [s] as wall seconds."""
        return dt / self.speed
