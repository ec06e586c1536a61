"""The one GNSS gating rule, for the daemon's live epochs and for a recording's track.

A GNSS epoch reaches the estimator (its speed over ground) and the map (its
position) only if

1. the receiver did not mark it invalid (RMC status ``V``);
2. its GGA fix quality is known, carries a measured position and is at least as accurate as
   ``min_fix_quality`` (:mod:`tractionecu.gnss.fix`: RTK float ranks below RTK fixed; dead reckoning,
   manual input and simulation are never accepted);
3. its HDOP, when given, is at most ``max_hdop``;
4. it has a position;
5. it is later than the epoch accepted before it (a repeated or earlier
   epoch is dropped);
6. it is at most ``max_age_s`` old where it is used: when it arrives (the
   daemon knows the arrival time; a recording does not, so this check
   cannot apply in replay) and when a map sample takes its position.

The first failing check names the reason; reasons are counted as
``gated_<reason>`` (``invalid``, ``fix_quality``, ``hdop``, ``no_position``,
``repeated``, ``stale``).  :meth:`GnssGate.reason` judges one epoch (the
daemon), :meth:`GnssGate.track_mask` a whole recorded track (replay) with
the same checks in the same order, so the two feed the estimator the same
epochs.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..gnss.fix import fix_accepted

REASONS = ("invalid", "fix_quality", "hdop", "no_position", "repeated", "stale")
"""Gating reasons, in the order they are checked."""


@dataclass(frozen=True)
class GnssGate:
    """Thresholds of the gating rule (module doc).

    ``min_fix_quality`` lowest GGA fix quality accepted (1 autonomous, 2
    DGNSS, 4 RTK fixed, 5 RTK float); ``max_hdop`` highest HDOP accepted
    [-]; ``max_age_s`` oldest an epoch may be where it is used [s].  The
    defaults are the service's (``[gps]`` and ``map.max_fix_age_s``).
    """

    min_fix_quality: int = 1
    max_hdop: float = 5.0
    max_age_s: float = 0.5

    def reason(self, valid: bool | None, fix_quality: int | None, hdop: float | None,
               lat_deg: float | None, lon_deg: float | None) -> str | None:
        """The first check one epoch fails (checks 1–4), or None if it passes."""
        if valid is False:
            return "invalid"
        if fix_quality is None or not fix_accepted(fix_quality, self.min_fix_quality):
            return "fix_quality"
        if hdop is not None and math.isfinite(hdop) and hdop > self.max_hdop:
            return "hdop"
        if lat_deg is None or lon_deg is None or not (math.isfinite(lat_deg) and math.isfinite(lon_deg)):
            return "no_position"
        return None

    def fresh(self, t_epoch: float, t_use: float) -> bool:
        """True if an epoch of time ``t_epoch`` may be used at ``t_use`` [s] (check 6)."""
        return t_use - t_epoch <= self.max_age_s

    def track_mask(self, track: Any, counts: Counter[str] | None = None) -> NDArray[np.bool_]:
        """Accepted epochs of a recorded :class:`~tractionecu.recording.reader.GpsTrack` (checks 1–5).

        The track's ``valid`` is 1/0/-1 (valid/invalid/unknown) and
        ``fix_quality`` -1 where unknown.  Rejections are added to ``counts``
        as ``gated_<reason>``.
        """
        n = len(track)
        reason = np.full(n, -1, dtype=np.int8)

        def mark(k: int, cond: NDArray[np.bool_]) -> None:
            reason[(reason < 0) & cond] = k

        q = np.asarray(track.fix_quality)
        hdop = np.asarray(track.hdop, dtype=float)
        mark(0, np.asarray(track.valid) == 0)
        mark(1, ~fix_accepted(q, self.min_fix_quality))
        with np.errstate(invalid="ignore"):
            mark(2, np.isfinite(hdop) & (hdop > self.max_hdop))
        mark(3, ~(np.isfinite(track.lat) & np.isfinite(track.lon)))
        # Check 5 on the epochs that passed 1–4: each must be later than the last one accepted.
        ok = np.flatnonzero(reason < 0)
        if ok.size:
            t = np.asarray(track.t, dtype=float)[ok]
            rep = t <= np.maximum.accumulate(np.concatenate([[-np.inf], t[:-1]]))
            reason[ok[rep]] = 4
        if counts is not None:
            for k, name in enumerate(REASONS[:5]):
                c = int(np.count_nonzero(reason == k))
                if c:
                    counts["gated_" + name] += c
        return reason < 0


def gate_from_config(gps: Any, max_age_s: float) -> GnssGate:
    """The gate of the service's ``[gps]`` table and ``map.max_fix_age_s``."""
    return GnssGate(int(gps.min_fix_quality), float(gps.max_hdop), float(max_age_s))
