"""The efficiency report on the bus: ``TECU_EstEfficiency``, Proprietary B PGN 65315 (0xFF23), 10 Hz.

==============================  ==============================================
signal                          value
==============================  ==============================================
``OptimalSlip``                 s* [-]
``TractionEfficiency``          η of the machine now [-]
``TractionEfficiencyAtOptimum`` η(s*) [-]
``EfficiencyValidity``          :data:`~.efficiency.FLAGS` (0: all valid)
``OptimalSlipHalfWidth``        half width of the 95 % interval of s* [-]
==============================  ==============================================

A value its flags declare invalid goes out as "not available"; η below 0
(pulling less than the rolling resistance) is sent as 0.  Before the first
report every value is "not available" with bits 0x01 and 0x08 set.
"""

from __future__ import annotations

import math

from ..bus.dbc import Codec
from .efficiency import CURVE_NOT_IDENTIFIED, ESTIMATE_INVALID, NOT_PULLING, EfficiencyReport

MESSAGE = "TECU_EstEfficiency"
NO_REPORT_FLAGS = CURVE_NOT_IDENTIFIED | ESTIMATE_INVALID | NOT_PULLING


def efficiency_values(rep: EfficiencyReport | None) -> dict[str, float]:
    """Signal values of :data:`MESSAGE` for a report (None: nothing known yet)."""
    if rep is None:
        return {"EfficiencyValidity": float(NO_REPORT_FLAGS)}

    def clip01(x: float) -> float:
        return min(max(x, 0.0), 1.0) if math.isfinite(x) else math.nan

    half = (rep.s_star_hi - rep.s_star_lo) / 2 if rep.s_star_valid else math.nan
    return {
        "OptimalSlip": rep.s_star if rep.s_star_valid else math.nan,
        "TractionEfficiency": clip01(rep.eta) if rep.eta_valid else math.nan,
        "TractionEfficiencyAtOptimum": clip01(rep.eta_star) if rep.s_star_valid else math.nan,
        "EfficiencyValidity": float(rep.flags & 0xFF),
        "OptimalSlipHalfWidth": min(half, 0.25) if math.isfinite(half) else math.nan,
    }


def efficiency_frame(codec: Codec, rep: EfficiencyReport | None, sa: int, priority: int) -> tuple[int, bytes]:
    """``(can_id, data)`` of :data:`MESSAGE` from source address ``sa``."""
    return codec.encode(MESSAGE, efficiency_values(rep), sa=sa, priority=priority)
