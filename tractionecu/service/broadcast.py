"""The estimate on the bus: three Proprietary B frames of the project DBC.

==================  =======  ================================================
message             PGN      signals
==================  =======  ================================================
TECU_EstAdhesion    65312    ``Adhesion_FL..RR`` = μ per wheel [-]
TECU_EstSlip        65313    ``Slip_FL..RR`` = slip per wheel [-]
TECU_EstSoil        65314    ``SoilRollingResistance`` = ρ_s [-],
                             ``CurveParamA`` = a [-], ``EstimateStatus``,
                             ``SoilClassIndex``
==================  =======  ================================================

``SoilClassIndex`` is the class's index in the configured ``estimator.soil_classes`` (below 200), or,
for a class that is not one of them, its fixed code 200 + k of
:data:`~tractionecu.model.mucurve.CLASS_CODES` (the machine-level estimator's ``machine_curve_prior``:
``d497`` is 204, a surface class outside the configured list 200-203), so that a receiver mapping the
index through the configured classes never reads another class (:func:`soil_class_index`).

A NaN (not yet estimated) goes out as the DBC's "not available" code;
values beyond the DBC range are clipped (and counted by the codec).  Before
the first estimate, :func:`no_estimate_frames` sends every value as not
available with the timeout and not-converged bits set.
"""

from __future__ import annotations

import math
from typing import Any

from ..bus.dbc import WHEELS, Codec
from ..model.mucurve import CLASS_CODES, CURVE_SHAPES

MESSAGES = ("TECU_EstAdhesion", "TECU_EstSlip", "TECU_EstSoil")


EFFICIENCY_MESSAGE = "TECU_EstEfficiency"
"""The efficiency and optimal-slip message (:mod:`tractionecu.advice.bus`), sent beside the three."""


def output_pgns(codec: Codec) -> frozenset[int]:
    """The PGNs of the estimate messages (a frame of these from the bus is another ECU's estimate)."""
    return frozenset(codec.message(name).pgn for name in (*MESSAGES, EFFICIENCY_MESSAGE))

NO_DATA_STATUS = 0x01 | 0x02 | 0x04 | 0x08 | 0x10 | 0x20
"""Status sent before the first estimate: every input timed out, not converged."""


def _f(x: Any) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return math.nan
    return v


def soil_class_index(est: Any) -> float:
    """``SoilClassIndex`` of an ``Estimate`` (module doc; NaN: not available).

    The estimate's ``soil_class_index`` is its class's index in the configured ``soil_classes``; a class
    that is a curve shape and no surface class (:data:`~tractionecu.model.mucurve.CURVE_SHAPES`) is never one
    of them, so it goes out as its code in :data:`~tractionecu.model.mucurve.CLASS_CODES` whatever index
    the estimate carries."""
    name = str(getattr(est, "soil_class", ""))
    if name in CURVE_SHAPES:
        return float(CLASS_CODES[name])
    idx = _f(getattr(est, "soil_class_index", None))
    return idx if 0 <= idx < 255 else math.nan        # NaN, or an index of no class (-1): not available


def estimate_values(est: Any) -> dict[str, dict[str, float]]:
    """Signal values of the three messages for an ``Estimate``."""
    mu = [_f(x) for x in est.mu]
    slip = [_f(x) for x in est.slip]
    return {
        "TECU_EstAdhesion": {f"Adhesion_{w}": mu[i] for i, w in enumerate(WHEELS)},
        "TECU_EstSlip": {f"Slip_{w}": slip[i] for i, w in enumerate(WHEELS)},
        "TECU_EstSoil": {
            "SoilRollingResistance": _f(est.rho_s),
            "CurveParamA": _f(est.a),
            "EstimateStatus": float(int(est.status) & 0xFFFF),
            "EstimateStatusExt": float((int(est.status) >> 16) & 0xFF),
            "SoilClassIndex": soil_class_index(est),
        },
    }


def estimate_frames(codec: Codec, est: Any, sa: int, priority: int) -> list[tuple[int, bytes]]:
    """``(can_id, data)`` of the three estimate frames from source address ``sa``."""
    vals = estimate_values(est)
    return [codec.encode(name, vals[name], sa=sa, priority=priority) for name in MESSAGES]


def no_estimate_frames(codec: Codec, sa: int, priority: int, status: int = NO_DATA_STATUS) -> list[tuple[int, bytes]]:
    """The three frames with every value "not available" and ``status``."""
    out = []
    for name in MESSAGES:
        vals: dict[str, float] = {}
        if name == "TECU_EstSoil":
            vals["EstimateStatus"] = float(status & 0xFFFF)
            vals["EstimateStatusExt"] = float((status >> 16) & 0xFF)
        out.append(codec.encode(name, vals, sa=sa, priority=priority))
    return out
