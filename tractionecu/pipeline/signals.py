"""The signal table: which bus signal feeds which estimator input or measurement.

This is the one place that names the DBC signals the estimator reads
(wheel order FL, FR, RL, RR, as :data:`tractionecu.bus.dbc.WHEELS`):

==========  ===========================================  ===========  ========================
key         signals (message)                            role         unit
==========  ===========================================  ===========  ========================
``Md``      ``DriveTorque_FL..RR`` (TECU_DriveTorques)   input        N·m, one per wheel
``Fzf``     ``FrontAxleLoad`` (TECU_AxleLoad)            input        N
``Fdx``     ``DraftForce`` (RearHitchStatus)             input        N
``omega``   ``WheelSpeed_FL..RR`` (TECU_WheelSpeeds)     measurement  rad/s, one per wheel
``v``       GNSS speed over ground of an accepted epoch  measurement  m/s
==========  ===========================================  ===========  ========================

The replay engine, the daemon and diagnosis all read these names from here.
"""

from __future__ import annotations

from ..bus.dbc import WHEELS

WHEEL_SPEEDS: tuple[str, ...] = tuple(f"WheelSpeed_{w}" for w in WHEELS)
"""Wheel angular speeds [rad/s] (TECU_WheelSpeeds)."""

DRIVE_TORQUES: tuple[str, ...] = tuple(f"DriveTorque_{w}" for w in WHEELS)
"""Drive torques at the wheels [N·m] (TECU_DriveTorques)."""

FRONT_AXLE_LOAD = "FrontAxleLoad"
"""Front-axle ground reaction from the load pins [N] (TECU_AxleLoad)."""

DRAFT = "DraftForce"
"""Horizontal draft at the hitch [N] (ISO 11783-7 rear hitch status)."""

IN_WORK = "RearHitchInWorkIndication"
"""Implement in work (ISO 11783-7 rear hitch status), used by diagnosis."""

WHEEL_BASED_SPEED = "WheelBasedMachineSpeed"
"""The tractor's own wheel-based speed [m/s] (ISO 11783-7 WBSD), used by diagnosis."""

GROUND_BASED_SPEED = "GroundBasedMachineSpeed"
"""Radar / ground-based speed [m/s] (ISO 11783-7 GBSD), used by diagnosis when there is no GNSS."""

INPUT_GROUPS: dict[str, tuple[str, ...]] = {
    "Md": DRIVE_TORQUES,
    "Fzf": (FRONT_AXLE_LOAD,),
    "Fdx": (DRAFT,),
}
"""Estimator input key -> DBC signals (one message each)."""

MEASUREMENT_GROUPS: dict[str, tuple[str, ...]] = {
    "omega": WHEEL_SPEEDS,
}
"""Estimator measurement key -> DBC signals; ``v`` comes from the GNSS (:data:`GNSS_SPEED`)."""

GROUPS: dict[str, tuple[str, ...]] = {**INPUT_GROUPS, **MEASUREMENT_GROUPS}
"""Every bus group of the estimator, inputs first."""

GNSS_SPEED = "v"
"""Estimator measurement key of the GNSS speed over ground [m/s]."""

VECTOR_KEYS = frozenset({"Md", "omega"})
"""Keys whose value is a per-wheel vector (the others are scalars)."""

ANCHOR_SIGNAL = WHEEL_SPEEDS[0]
"""The step grid is phased to the frames carrying this signal."""

INPUT_MESSAGES = ("TECU_WheelSpeeds", "TECU_DriveTorques", "TECU_AxleLoad", "RearHitchStatus")
"""DBC messages that carry the estimator's bus signals (the daemon reports their rate)."""

__all__ = ["ANCHOR_SIGNAL", "DRAFT", "DRIVE_TORQUES", "FRONT_AXLE_LOAD", "GNSS_SPEED", "GROUND_BASED_SPEED",
           "GROUPS", "INPUT_GROUPS", "INPUT_MESSAGES", "IN_WORK", "MEASUREMENT_GROUPS", "VECTOR_KEYS",
           "WHEEL_BASED_SPEED", "WHEEL_SPEEDS"]
