"""The GNSS fix buffer: the accepted fixes of the last seconds, looked up by time for the map.

An estimate of step ``t`` is mapped at the position of the latest fix at or
before ``t``, if that fix is still fresh by the pipeline's GNSS gate
(:meth:`~tractionecu.pipeline.gnss.GnssGate.fresh`: at most
``map.max_fix_age_s`` old), the same age rule the GNSS reader applies when a
fix arrives.
"""

from __future__ import annotations

import collections

from ..pipeline.gnss import GnssGate
from .gps import GpsSample

DEPTH = 64
"""Fixes kept: 6.4 s at 10 Hz, far more than any ``estimation.lag_s`` plus ``map.max_fix_age_s``."""


class FixBuffer:
    """The latest accepted fixes (oldest dropped first).

    Parameters
    ----------
    gate:
        The GNSS gate; its ``max_age_s`` limits how old a fix :meth:`fix_at` returns.
    depth:
        Fixes kept.

    Attributes
    ----------
    last:
        The latest fix added, or None.
    """

    def __init__(self, gate: GnssGate, depth: int = DEPTH) -> None:
        self.gate = gate
        self.last: GpsSample | None = None
        self._fixes: collections.deque[GpsSample] = collections.deque(maxlen=depth)

    def add(self, fix: GpsSample) -> None:
        """Keep an accepted fix (fixes come in time order: the reader drops repeated epochs)."""
        self.last = fix
        self._fixes.append(fix)

    def fix_at(self, t: float) -> GpsSample | None:
        """The latest fix at or before ``t`` [s] if it is fresh at ``t``, else None."""
        for s in reversed(self._fixes):
            if s.t <= t:
                return s if self.gate.fresh(s.t, t) else None
        return None

    def __len__(self) -> int:
        return len(self._fixes)
