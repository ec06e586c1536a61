"""Periods of the estimator's inputs and measurements as observed on the bus.

The estimator holds each input (zero-order hold) until the next sample and
flags a sensor whose samples stop.  Both depend on the period at which the
samples actually arrive, which need not be the machine's configured rate
(``SensorSpec``): an ECU sending its PGN every 50 ms instead of 10 ms, a
load pin at 10 Hz, an estimator stepped slower than the bus.  This module
measures that period per stream from the step times at which new samples
reach the estimator, and derives from it

* the **hold period** T of an input, used in the input noise of Q: a held
  white sample of variance σ² and period T has the spectral density σ² T
  (module doc of :mod:`.estimator`);
* the **timeout** of a stream: ``max(floor, k · T)``, the floor being the
  configured ``*_timeout_s`` of :class:`~.config.EstimatorConfig` and
  k = ``timeout_periods`` (default 3: one lost sample plus arrival jitter of
  up to one period never trips a timeout; two lost samples in a row do once
  the jitter exceeds zero, three always).

The period is the median of the last ``window`` accepted inter-arrival
intervals, recomputed once per ``window`` intervals (a block median: cheap
per sample, insensitive to single late or early frames).  An interval
longer than k periods (a dropout: it trips the timeout) or than
``max_interval_s`` (the estimator's restart gap) is a gap and is not used;
a repeated or backward time stamp is not an arrival.
When ``window`` intervals in a row were all too long, they are the stream's
new rate, not gaps, and their median becomes the period: a stream slower
than its configured rate (the configured 100 Hz, the bus 10 Hz) is learnt
after ``window`` samples.  Until the first median, the period is the
configured one.

Nothing here reads a clock: the periods are a function of the step times
alone, so replay and the daemon observe the same.
"""

from __future__ import annotations

import math
from typing import Mapping

__all__ = ["BusRates", "PeriodTracker"]

PERIOD_TOLERANCE = 1e-3
"""A median within this relative distance of the period in use leaves it unchanged [-]: the same
rate is not a new one (and the process noise is not rebuilt for it)."""


class PeriodTracker:
    """Observed period of one stream from its arrival times (module doc).

    Parameters
    ----------
    nominal_s : configured period [s], the fallback until the first median.
    window : intervals per median (and the number of samples before the
        configured period is replaced) [-].
    gap_periods : an interval longer than this many periods is a gap [-].
    max_interval_s : an interval longer than this is always a gap [s].
    """

    __slots__ = ("nominal_s", "window", "gap_periods", "max_interval_s", "period", "observed", "_last",
                 "_buf", "_long", "_gap_s")

    def __init__(self, nominal_s: float, window: int = 16, gap_periods: float = 3.0,
                 max_interval_s: float = math.inf) -> None:
        if not nominal_s > 0:
            raise ValueError(f"nominal_s must be > 0, got {nominal_s}")
        if window < 1:
            raise ValueError(f"window must be >= 1, got {window}")
        if not gap_periods > 1:
            raise ValueError(f"gap_periods must be > 1, got {gap_periods}")
        self.nominal_s = float(nominal_s)
        self.window = int(window)
        self.gap_periods = float(gap_periods)
        self.max_interval_s = float(max_interval_s)
        self.period = self.nominal_s
        """The period in use [s]: the latest median, or ``nominal_s`` before the first."""
        self.observed = False
        """True once ``period`` is a median of observed intervals."""
        self._last = -math.inf
        self._buf: list[float] = []
        self._long: list[float] = []
        self._gap_s = self.gap_periods * self.period

    def reset(self) -> None:
        """Forget every observation: back to the configured period."""
        self.period = self.nominal_s
        self.observed = False
        self._last = -math.inf
        self._buf = []
        self._long = []
        self._gap_s = self.gap_periods * self.period

    def push(self, t: float) -> bool:
        """Record a sample arriving at ``t`` [s]; True when ``period`` changed."""
        d = t - self._last
        if not d > 0.0:                 # a repeated or backward time stamp
            return False
        self._last = t
        if d <= self._gap_s and d <= self.max_interval_s:     # the usual case: one more interval
            buf = self._buf
            buf.append(d)
            if self._long:
                self._long.clear()
            if len(buf) < self.window:
                return False
            return self._median()
        if d > self.max_interval_s or d == math.inf:    # a gap, or the first sample (d = inf)
            return False
        if d > self._gap_s:
            lng = self._long
            lng.append(d)
            if len(lng) < self.window:
                return False
            self._buf = lng
            self._long = []
        return self._median()

    def _median(self) -> bool:
        b = sorted(self._buf)
        n = len(b)
        p = b[n // 2] if n % 2 else 0.5 * (b[n // 2 - 1] + b[n // 2])
        self._buf = []
        self.observed = True
        if abs(p - self.period) <= PERIOD_TOLERANCE * self.period:
            return False            # the same rate: epoch-second time stamps differ in the last bits
        self.period = p
        self._gap_s = self.gap_periods * p
        return True


class BusRates:
    """One :class:`PeriodTracker` per stream and the timeouts derived from them (module doc).

    Parameters
    ----------
    nominal_s : configured period of each stream key [s].
    floors_s : configured (shortest) timeout of each key [s].
    timeout_periods : k of ``timeout = max(floor, k · period)`` [-]; also the gap threshold.
    window, max_interval_s : see :class:`PeriodTracker`.

    Attributes
    ----------
    timeout_s : dict key -> current timeout [s], updated when a period changes.
    """

    def __init__(self, nominal_s: Mapping[str, float], floors_s: Mapping[str, float], timeout_periods: float = 3.0,
                 window: int = 16, max_interval_s: float = math.inf) -> None:
        if set(nominal_s) != set(floors_s):
            raise ValueError("nominal_s and floors_s must name the same streams")
        self.k = float(timeout_periods)
        self.floors_s = {k: float(v) for k, v in floors_s.items()}
        self.trackers = {key: PeriodTracker(p, window, self.k, max_interval_s) for key, p in nominal_s.items()}
        self.timeout_s = {key: self._timeout(key) for key in self.trackers}

    def reset(self) -> None:
        """Forget every observation (configured periods, floor-or-configured timeouts)."""
        for tr in self.trackers.values():
            tr.reset()
        self.timeout_s.update({key: self._timeout(key) for key in self.trackers})

    def _timeout(self, key: str) -> float:
        return max(self.floors_s[key], self.k * self.trackers[key].period)

    def seen(self, key: str, t: float) -> None:
        """A new sample of ``key`` reached the estimator at step time ``t`` [s]."""
        if self.trackers[key].push(t):
            self.timeout_s[key] = self._timeout(key)

    def refresh(self, key: str) -> None:
        """Recompute the timeout of ``key`` after its tracker's ``push`` returned True (the
        estimator calls the trackers' ``push`` directly on its 100 Hz path)."""
        self.timeout_s[key] = self._timeout(key)

    def period(self, key: str) -> float:
        """Period of ``key`` in use [s] (observed, else configured)."""
        return self.trackers[key].period

    def summary(self) -> dict[str, dict[str, float | bool]]:
        """Per key: ``period_s``, ``observed``, ``timeout_s`` (for status and diagnosis output)."""
        return {key: {"period_s": tr.period, "observed": tr.observed, "timeout_s": self.timeout_s[key]}
                for key, tr in self.trackers.items()}
