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
``dir``     ``WheelBasedMachineDirection`` (WBSD)        measurement  0 reverse, 1 forward (SPN 1864)
``v``       GNSS speed over ground of an accepted epoch  measurement  m/s
==========  ===========================================  ===========  ========================

The replay engine, the daemon and diagnosis all read these names from here.

Estimation profiles
-------------------
:data:`PROFILES` lists what each kind of machine must put on the bus, as
:class:`Need` items (any one of a need's signals meets it; ``gps.speed`` is
the GNSS speed over ground of the recording's track):

* ``hub``, the paper's machine (``[drivetrain] kind = "hub"``, the default): the four
  wheel speeds and drive torques, the front-axle load, the draft and the
  GNSS speed;
* ``mechanical`` (also a power-split / CVT machine), run by the machine-level
  estimator (:mod:`tractionecu.estimation.machine`) when ``vehicle.toml``
  says ``[drivetrain] kind = "mechanical"`` or ``"power-split"``: EEC1
  percent torque and engine speed with the EC1 reference torque, the ETC2
  gear ratio, one wheel-based speed (CCVS1, WBSD or EBC2's front axle), the
  draft and a ground speed (GNSS or GBSD).  Its signal table is
  :data:`MACHINE_GROUPS`; without a draft it runs and says so (ρ_s and the
  draft are not separable), without GBSD it takes the GNSS speed only,
  without ETC2 it learns the ratio, without EC1 it takes ``[drivetrain]
  engine_reference_torque_nm`` when declared (:func:`machine_missing`).

:func:`estimator_profile` names the profile a machine and a recording run;
:func:`best_profile` the one a recording's signals fit best, and
:func:`profile_role` how ``inspect`` and replay describe each.

:func:`profile_status` tells which needs a recording meets and from which
message; :func:`missing_signals` the signals it lacks, by default those
:data:`REPLAY_REQUIRED`; :func:`motion` whether its speed signals show the
machine moving (a wheel-based speed over 0.1 m/s, or with none a wheel turning
or a ground speed over it: radar and GNSS read noise at standstill).  A signal
counts as found when it has at least one sample that is not "not available".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterable

import numpy as np

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

WHEEL_BASED_DIRECTION = "WheelBasedMachineDirection"
"""The machine's own direction of travel (ISO 11783-7 WBSD, SPN 1864): 0 reverse, 1 forward, 2 error,
3 not available.  The estimator signs the unsigned GNSS speed with it."""

INPUT_GROUPS: dict[str, tuple[str, ...]] = {
    "Md": DRIVE_TORQUES,
    "Fzf": (FRONT_AXLE_LOAD,),
    "Fdx": (DRAFT,),
}
"""Estimator input key -> DBC signals (one message each)."""

MEASUREMENT_GROUPS: dict[str, tuple[str, ...]] = {
    "omega": WHEEL_SPEEDS,
    "dir": (WHEEL_BASED_DIRECTION,),
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

MACHINE_INPUT_MESSAGES = ("EEC1", "EC1", "ETC2", "CCVS1", "EBC2", "WBSD", "GBSD", "RearHitchStatus")
"""The standard messages the machine-level estimator reads (the daemon reports their rate for such a machine)."""

# ----------------------------------------------------------------------------- standard J1939 signals
ENGINE_SPEED = "EngineSpeed"
"""Engine speed [rad/s] (J1939 EEC1, SPN 190)."""

ENGINE_PERCENT_TORQUE = "ActualEnginePercentTorque"
"""Actual engine torque [%] of the reference torque (J1939 EEC1, SPN 513)."""

ENGINE_REFERENCE_TORQUE = "EngineReferenceTorque"
"""The engine's 100 % torque [N·m] (J1939 EC1, SPN 544)."""

ENGINE_IDLE_SPEED = "EngineSpeedAtIdlePoint1"
"""Engine idle speed [rad/s] (J1939 EC1, SPN 188)."""

GEAR_RATIO = "TransmissionActualGearRatio"
"""Transmission input / output shaft speed [-] (J1939 ETC2, SPN 526)."""

SELECTED_GEAR = "TransmissionSelectedGear"
"""Gear the operator selected [-], 0 neutral (J1939 ETC2, SPN 524)."""

VEHICLE_SPEED = "WheelBasedVehicleSpeed"
"""Wheel-based vehicle speed [m/s] (J1939 CCVS1, SPN 84)."""

FRONT_AXLE_SPEED = "FrontAxleSpeed"
"""Mean speed of the front wheels [m/s] (J1939 EBC2, SPN 904)."""

PARKING_BRAKE = "ParkingBrakeSwitch"
"""Parking brake: 0 not set, 1 set (J1939 CCVS1, SPN 70)."""

GNSS_TRACK_SPEED = "gps.speed"
"""In a :class:`Need`: the GNSS speed over ground of the recording's track."""


# ----------------------------------------------------------------------------- estimation profiles
@dataclass(frozen=True)
class Need:
    """One thing an estimation profile needs: any one of ``signals``."""

    what: str
    signals: tuple[str, ...]


PROFILES: dict[str, tuple[Need, ...]] = {
    "hub": (*(Need(f"wheel speed {w}", (f"WheelSpeed_{w}",)) for w in WHEELS),
            *(Need(f"drive torque {w}", (f"DriveTorque_{w}",)) for w in WHEELS),
            Need("front-axle load", (FRONT_AXLE_LOAD,)),
            Need("draft", (DRAFT,)),
            Need("GNSS speed", (GNSS_TRACK_SPEED,))),
    "mechanical": (Need("engine percent torque", (ENGINE_PERCENT_TORQUE,)),
                   Need("engine reference torque", (ENGINE_REFERENCE_TORQUE,)),
                   Need("gear ratio", (GEAR_RATIO,)),
                   Need("wheel-based speed", (VEHICLE_SPEED, WHEEL_BASED_SPEED, FRONT_AXLE_SPEED)),
                   Need("draft", (DRAFT,)),
                   Need("ground speed", (GNSS_TRACK_SPEED, GROUND_BASED_SPEED))),
}
"""Estimation profile -> its needs (module doc)."""

ESTIMATED_PROFILES = ("hub", "mechanical")
"""Both profiles are estimated: ``hub`` when ``vehicle.toml`` names no engine-driven drivetrain (the
default), ``mechanical`` with ``[drivetrain] kind = "mechanical"`` or ``"power-split"``
(:class:`~tractionecu.estimation.machine.MachineEstimator`, :func:`estimator_profile`)."""

PROFILE_KINDS = {"hub": 'kind = "hub"', "mechanical": 'kind = "mechanical" or "power-split"'}
"""The ``[drivetrain] kind`` that makes replay and the daemon run each profile (``hub`` is the default)."""

DECLARED_REFERENCE_TORQUE = "vehicle.toml [drivetrain] engine_reference_torque_nm"
"""In :func:`profile_status`: the reference torque need met by the declared value, not by EC1."""


def profile_role(name: str, run_as: str) -> str:
    """How profile ``name`` is run, beside the one (``run_as``) the recording's vehicle selects."""
    return ("replay runs this one" if name == run_as
            else f"estimated with [drivetrain] {PROFILE_KINDS[name]} in vehicle.toml")


def best_profile(status: dict[str, list[tuple[Need, str | None]]]) -> str:
    """The profile of :func:`profile_status` whose needs the recording meets best (by share; ties: the first)."""
    return max(status, key=lambda n: sum(sig is not None for _, sig in status[n]) / max(len(status[n]), 1))

ENGINE_CURRENT_GEAR = "TransmissionCurrentGear"
"""Gear engaged [-], negative in reverse, 0 neutral (J1939 ETC2, SPN 523)."""

REAR_RELATIVE_SPEEDS = ("RelativeSpeedRearAxle1LeftWheel", "RelativeSpeedRearAxle1RightWheel")
"""Rear wheel speeds relative to the front-axle speed [m/s] (J1939 EBC2, SPN 907, 908)."""

FRONT_RELATIVE_SPEEDS = ("RelativeSpeedFrontAxleLeftWheel", "RelativeSpeedFrontAxleRightWheel")
"""Front wheel speeds relative to the front-axle speed [m/s] (J1939 EBC2, SPN 905, 906)."""


@dataclass(frozen=True)
class SignalGroups:
    """One estimator's signal table: key -> DBC signals, which keys are inputs, which are per-wheel vectors,
    and the signal whose frames phase the step grid (:mod:`.steps`)."""

    groups: dict[str, tuple[str, ...]]
    inputs: frozenset[str]
    vectors: frozenset[str]
    anchor: str


HUB_GROUPS = SignalGroups(GROUPS, frozenset(INPUT_GROUPS), VECTOR_KEYS, ANCHOR_SIGNAL)
"""The hub estimator's table (:data:`GROUPS`)."""

MACHINE_GROUPS = SignalGroups(
    {"Te": (ENGINE_PERCENT_TORQUE,), "Tref": (ENGINE_REFERENCE_TORQUE,), "gear": (GEAR_RATIO,),
     "Fzf": (FRONT_AXLE_LOAD,), "Fdx": (DRAFT,),
     "we": (ENGINE_SPEED,), "vwb": (VEHICLE_SPEED,), "vwbsd": (WHEEL_BASED_SPEED,), "vfa": (FRONT_AXLE_SPEED,),
     "rel_r": REAR_RELATIVE_SPEEDS, "vr": (GROUND_BASED_SPEED,), "dir": (WHEEL_BASED_DIRECTION,),
     "cgear": (ENGINE_CURRENT_GEAR,)},
    frozenset({"Te", "Tref", "gear", "Fzf", "Fdx"}), frozenset({"rel_r"}), ENGINE_SPEED)
"""The machine-level estimator's table (:mod:`tractionecu.estimation.machine`):

==========  =========================================  ===========  ==========================
key         signal (message)                           role         unit
==========  =========================================  ===========  ==========================
``Te``      ``ActualEnginePercentTorque`` (EEC1)       input        % of the reference torque
``Tref``    ``EngineReferenceTorque`` (EC1, TP)        input        N·m
``gear``    ``TransmissionActualGearRatio`` (ETC2)     input        -
``Fzf``     ``FrontAxleLoad``                          input        N (where load pins are fitted)
``Fdx``     ``DraftForce`` (rear hitch status)         input        N (where the hitch has load pins)
``we``      ``EngineSpeed`` (EEC1)                     measurement  rad/s; the grid anchor
``vwb``     ``WheelBasedVehicleSpeed`` (CCVS1)         measurement  m/s
``vwbsd``   ``WheelBasedMachineSpeed`` (WBSD)          measurement  m/s
``vfa``     ``FrontAxleSpeed`` (EBC2)                  measurement  m/s
``rel_r``   rear relative speeds (EBC2)                measurement  m/s, left and right
``vr``      ``GroundBasedMachineSpeed`` (GBSD radar)   measurement  m/s
``dir``     ``WheelBasedMachineDirection`` (WBSD)      measurement  0 reverse, 1 forward
``cgear``   ``TransmissionCurrentGear`` (ETC2)         measurement  gear, < 0 in reverse
==========  =========================================  ===========  ==========================
"""

MACHINE_REQUIRED: tuple[str, ...] = (ENGINE_SPEED, ENGINE_PERCENT_TORQUE, ENGINE_REFERENCE_TORQUE)
"""Signals without which the machine-level estimator does not run: the grid follows the engine speed,
and the wheel torque is the engine's.  It also needs one drive speed (the gear ratio, or a wheel-based
speed to learn it from): :func:`machine_missing`."""

DRIVE_SPEEDS: tuple[str, ...] = (GEAR_RATIO, VEHICLE_SPEED, WHEEL_BASED_SPEED, FRONT_AXLE_SPEED)
"""Any one of these gives the machine-level estimator the speed of the driven wheels."""


def estimator_profile(vehicle: Any) -> str:
    """``"hub"`` or ``"mechanical"`` (engine-driven: mechanical and power-split) from ``[drivetrain] kind``."""
    dt = getattr(vehicle, "drivetrain", None)
    return "mechanical" if dt is not None and dt.engine_driven else "hub"


def machine_missing(rec: Any, vehicle: Any = None) -> list[str]:
    """The signals the machine-level estimator cannot run without that ``rec`` lacks (:data:`MACHINE_REQUIRED`,
    one of :data:`DRIVE_SPEEDS`; with ``gear_ratio = "learnt"`` a wheel-based speed).  A reference torque
    declared in ``[drivetrain] engine_reference_torque_nm`` stands in for EC1's."""
    dt = getattr(vehicle, "drivetrain", None)
    required = MACHINE_REQUIRED
    if dt is not None and dt.engine_reference_torque_nm > 0.0:
        required = tuple(n for n in required if n != ENGINE_REFERENCE_TORQUE)
    out = missing_signals(rec, required)
    speeds = DRIVE_SPEEDS
    if dt is not None and dt.gear_ratio == "learnt":
        speeds = DRIVE_SPEEDS[1:]
    if all(signal_state(rec, n) != "found" for n in speeds):
        out.append(" or ".join(speeds))
    return out


def required_missing(rec: Any, vehicle: Any) -> list[str]:
    """The signals replay of ``rec`` lacks for the estimator ``vehicle`` runs (:func:`estimator_profile`)."""
    if estimator_profile(vehicle) == "mechanical":
        return machine_missing(rec, vehicle)
    return missing_signals(rec)


REPLAY_REQUIRED: tuple[str, ...] = WHEEL_SPEEDS + DRIVE_TORQUES + (FRONT_AXLE_LOAD, DRAFT)
"""Signals without which replay of the hub profile does not run: the step grid follows the wheel speeds,
without drive torques every step would be a prediction, and the hub estimator starts only once it has the
wheel loads (the front-axle load) and the draft (a recording without either ran to exit 0 with no estimate at
all).  Without the GNSS speed it runs, and the estimator flags its steps with the time-out bits."""


def _values(rec: Any, name: str) -> np.ndarray | None:
    if name == GNSS_TRACK_SPEED:
        return np.asarray(rec.gps.speed, dtype=float) if len(rec.gps) else None
    s = rec.signals.get(name)
    return None if s is None or len(s) == 0 else np.asarray(s.value, dtype=float)


def signal_state(rec: Any, name: str) -> str:
    """``"found"`` (a sample that is a number), ``"not available"`` (sent, every sample NaN) or ``"absent"``."""
    v = _values(rec, name)
    if v is None:
        return "absent"
    return "found" if np.isfinite(v).any() else "not available"


def source_of(rec: Any, name: str) -> str:
    """Where a signal of ``rec`` came from: its message, ``Message.Signal × scale``, or ``GNSS``."""
    if name == GNSS_TRACK_SPEED:
        return "GNSS"
    if name in (DECLARED_REFERENCE_TORQUE, LEARNT_GEAR_RATIO):
        return "vehicle.toml"
    return getattr(rec, "signal_sources", {}).get(name, "")


LEARNT_GEAR_RATIO = "learnt from engine speed over wheel speed ([drivetrain] gear_ratio)"
"""What meets the gear-ratio need of a vehicle file that has the ratio learnt (no ETC2 needed)."""


def profile_status(rec: Any, vehicle: Any = None) -> dict[str, list[tuple[Need, str | None]]]:
    """For each profile of :data:`PROFILES`, each need with the first of its signals found (None if none is);
    with ``vehicle``, a declared engine reference torque meets its need (:data:`DECLARED_REFERENCE_TORQUE`)
    when the recording has no EC1, and a learnt gear ratio the ratio's (:data:`LEARNT_GEAR_RATIO`)."""
    dt = getattr(vehicle, "drivetrain", None)
    declared = dt is not None and dt.engine_reference_torque_nm > 0.0
    learnt = dt is not None and getattr(dt, "gear_ratio", "") == "learnt"
    out = {}
    for name, needs in PROFILES.items():
        rows = []
        for need in needs:
            sig = next((s for s in need.signals if signal_state(rec, s) == "found"), None)
            if sig is None and declared and need.signals == (ENGINE_REFERENCE_TORQUE,):
                sig = DECLARED_REFERENCE_TORQUE
            if sig is None and learnt and need.signals == (GEAR_RATIO,):
                sig = LEARNT_GEAR_RATIO
            rows.append((need, sig))
        out[name] = rows
    return out


def missing_signals(rec: Any, required: Iterable[str] = REPLAY_REQUIRED) -> list[str]:
    """The signals of ``required`` that ``rec`` does not carry as numbers (absent or never available)."""
    return [n for n in required if signal_state(rec, n) != "found"]


# ----------------------------------------------------------------------------- motion
MOTION_SPEED_MPS = 0.1
"""Above this speed [m/s] (0.36 km/h) the machine moves."""

MOTION_WHEEL_RAD_S = 0.2
"""Above this wheel angular speed [rad/s] the machine moves (0.1 m/s on a wheel of 0.5 m)."""

SPEED_SIGNALS: tuple[str, ...] = (VEHICLE_SPEED, WHEEL_BASED_SPEED, FRONT_AXLE_SPEED, GROUND_BASED_SPEED,
                                  GNSS_TRACK_SPEED)
"""Ground and wheel-based speeds [m/s] that tell motion."""

GROUND_SPEEDS: tuple[str, ...] = (GROUND_BASED_SPEED, GNSS_TRACK_SPEED)
"""The speeds of :data:`SPEED_SIGNALS` measured against the ground (radar, GNSS): at standstill they read their
noise, not zero (a parked CANedge logger's GNSS speed: up to 0.92 m/s at a reported accuracy of 0.1–0.3 m/s),
so where a wheel-based speed is present, it decides."""


@dataclass(frozen=True)
class Motion:
    """Whether a recording shows the machine moving: ``moving`` None when no speed signal tells; ``evidence``
    one line per signal used, engine and gear state included."""

    moving: bool | None
    evidence: tuple[str, ...]

    def describe(self) -> str:
        head = {True: "moving", False: "no motion", None: "unknown (no speed signal)"}[self.moving]
        if self.moving is None and any(e.startswith("contradiction") for e in self.evidence):
            head = "unknown (the speeds disagree)"
        return head + (": " + "; ".join(self.evidence) if self.evidence else "")


MOTION_SUSTAINED_MPS = 0.5
"""A ground speed above this [m/s] ..."""
MOTION_SUSTAINED_SHARE = 0.2
"""... on this share of its samples or more is travel, not the noise of a receiver or radar at standstill
(GNSS Doppler σ 0.05 m/s), whatever the wheel-based speeds say."""


def motion(rec: Any, engine: bool = True) -> Motion:
    """Motion from the speed signals (module doc), with the engine speed (``engine``: a streamed replay's survey
    keeps only a stub of it), gear and parking brake as context."""
    wheels: bool | None = None                     # what the wheel-based speeds say, then the ground speeds
    ground: bool | None = None
    sustained = 0.0                                # the largest share of a ground speed's samples above it
    evidence = []
    wheel_mps = tuple(n for n in SPEED_SIGNALS if n not in GROUND_SPEEDS)
    for names, limit, unit in ((wheel_mps, MOTION_SPEED_MPS, "m/s"), (WHEEL_SPEEDS, MOTION_WHEEL_RAD_S, "rad/s"),
                               (GROUND_SPEEDS, MOTION_SPEED_MPS, "m/s")):
        if names is WHEEL_SPEEDS and wheels is not None:   # wheel angular speeds only when no speed in m/s tells
            continue
        for name in names:
            v = _values(rec, name)
            if v is None or not np.isfinite(v).any():
                continue
            top = float(np.nanmax(np.abs(v)))
            label = "GNSS speed" if name == GNSS_TRACK_SPEED else name
            evidence.append(f"{label} {top:.2f} {unit} at most ({int(np.isfinite(v).sum())} samples)")
            if names is GROUND_SPEEDS:
                ground = bool(ground) or top > limit
                fin = v[np.isfinite(v)]
                sustained = max(sustained, float(np.mean(np.abs(fin) > MOTION_SUSTAINED_MPS)))
            else:
                wheels = bool(wheels) or top > limit
    moving = ground if wheels is None else wheels
    if wheels is False and sustained >= MOTION_SUSTAINED_SHARE:
        # not noise: a ground speed over 0.5 m/s on a fifth of its samples while the wheel-based speed reads
        # standing (a tractor that does not fill CCVS1's speed, a mapping onto a constant) is a contradiction
        moving = None
        evidence.append(f"contradiction: a ground speed above {MOTION_SUSTAINED_MPS:g} m/s on {100 * sustained:.0f} % "
                        "of its samples while the wheel-based speeds read standing (a wheel-based speed this "
                        "tractor does not fill, or a [signals] mapping onto a constant)")
    elif wheels is False and ground:
        evidence.append(f"the ground speeds above {MOTION_SPEED_MPS:g} m/s with the wheels standing are their "
                        "noise at standstill")
    rpm = _values(rec, ENGINE_SPEED) if engine else None
    if rpm is not None and np.isfinite(rpm).any():
        rpm = rpm[np.isfinite(rpm)] * 30.0 / math.pi
        line = f"engine {rpm.min():.0f} to {rpm.max():.0f} rpm (median {np.median(rpm):.0f})"
        idle = _values(rec, ENGINE_IDLE_SPEED)
        if idle is not None and np.isfinite(idle).any():
            idle_rpm = float(np.nanmedian(idle)) * 30.0 / math.pi
            med = float(np.median(rpm)) / idle_rpm
            line += f", idle {idle_rpm:.0f} rpm: " + ("mostly not running" if med < 0.5 else "at idle"
                                                      if 0.85 <= med <= 1.15 else f"{med:.1f} x idle")
        evidence.append(line)
    gear = _values(rec, SELECTED_GEAR)
    if gear is not None and np.isfinite(gear).any():
        g = sorted({int(x) for x in gear[np.isfinite(gear)]})
        evidence.append("gear selected: " + ", ".join("neutral" if x == 0 else f"{x:+d}" for x in g))
    brake = _values(rec, PARKING_BRAKE)
    if brake is not None and np.any(brake == 1):
        evidence.append("parking brake set")
    return Motion(moving, tuple(evidence))


__all__ = ["ANCHOR_SIGNAL", "DECLARED_REFERENCE_TORQUE", "LEARNT_GEAR_RATIO", "DRAFT", "DRIVE_TORQUES", "ENGINE_IDLE_SPEED", "ENGINE_PERCENT_TORQUE",
           "ENGINE_REFERENCE_TORQUE", "ENGINE_SPEED", "ESTIMATED_PROFILES", "FRONT_AXLE_LOAD", "FRONT_AXLE_SPEED",
           "GEAR_RATIO", "GNSS_SPEED", "GROUND_SPEEDS", "HUB_GROUPS", "MACHINE_GROUPS", "MACHINE_REQUIRED", "DRIVE_SPEEDS",
           "SignalGroups", "estimator_profile", "machine_missing", "required_missing", "ENGINE_CURRENT_GEAR",
           "REAR_RELATIVE_SPEEDS", "FRONT_RELATIVE_SPEEDS", "GNSS_TRACK_SPEED", "GROUND_BASED_SPEED", "GROUPS", "INPUT_GROUPS",
           "INPUT_MESSAGES", "IN_WORK", "MACHINE_INPUT_MESSAGES", "MEASUREMENT_GROUPS", "MOTION_SPEED_MPS", "MOTION_WHEEL_RAD_S", "Motion",
           "Need", "PARKING_BRAKE", "PROFILES", "PROFILE_KINDS", "best_profile", "profile_role", "REPLAY_REQUIRED", "SELECTED_GEAR", "SPEED_SIGNALS", "VECTOR_KEYS",
           "VEHICLE_SPEED", "WHEEL_BASED_SPEED", "WHEEL_SPEEDS", "missing_signals", "motion", "profile_status",
           "signal_state", "source_of"]
