"""Which GGA fix qualities carry a measured position, and how they rank.

NMEA 0183 (4.11) GGA quality: 0 no fix, 1 autonomous GNSS, 2 differential, 3 PPS (precise), 4 RTK fixed,
5 RTK float, 6 estimated (dead reckoning), 7 manual input, 8 simulation.  The codes are not an accuracy
order: RTK float (5) is worse than RTK fixed (4), and 6–8 are no measurement at all.  :data:`FIX_RANK`
orders them by accuracy; a quality ranked 0 is never accepted, whatever the configured minimum.
"""

from __future__ import annotations

from typing import Any

import numpy as np

FIX_RANK = np.array([0, 1, 2, 2, 4, 3, 0, 0, 0], dtype=np.int8)
"""Accuracy rank of GGA quality 0–8 (module doc): autonomous 1, differential and PPS 2, RTK float 3, RTK
fixed 4; no fix, dead reckoning, manual input and simulation 0."""


def fix_rank(q: Any) -> Any:
    """:data:`FIX_RANK` of a quality or an array of them (unknown, negative or above 8: 0)."""
    a = np.asarray(q, dtype=float)
    ok = np.isfinite(a) & (a >= 0) & (a <= 8)
    r = np.where(ok, FIX_RANK[np.where(ok, a, 0).astype(np.int64)], 0)
    return int(r) if r.ndim == 0 else r


def fix_accepted(q: Any, min_quality: int) -> Any:
    """True where quality ``q`` carries a measured position at least as accurate as ``min_quality``
    (both GGA codes).  ``min_quality`` ≤ 0 accepts every known quality (≥ 0): an ungated replay."""
    a = np.asarray(q, dtype=float)
    if min_quality <= 0:
        out = np.isfinite(a) & (a >= 0)
    else:
        r = np.asarray(fix_rank(a))
        out = (r > 0) & (r >= max(int(fix_rank(min_quality)), 1))
    return bool(out) if np.ndim(out) == 0 else out
