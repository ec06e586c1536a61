"""Drive-trains of the physical truth model: the electric hub drive and a mechanical MFWD tractor.

Hub drive (the paper's machine)
-------------------------------
Each wheel has its own motor behind a planetary hub reduction.  The inverter
reports the motor's air-gap torque (estimated from the phase currents),
reflected to the wheel; the wheel receives it through

* the reduction's losses: a torque efficiency η = 0.95 when the motor
  drives, 1/η when it brakes (two planetary stages at 0.97–0.98 each and the
  hub bearings and seals; Naunheimer et al. 2011, "Automotive
  Transmissions", 2nd ed.: 0.97–0.99 per planetary stage), and a
  speed-proportional drag (oil churning);
* a torsional compliance between motor and wheel (gear meshes, planet
  carrier, hub and rim): a spring k and damper c between the motor inertia
  and the wheel.  150 kN·m/rad at the wheel with a damping ratio of ≈ 0.3
  (mesh damping and the inverter's current loop) is an assumption of this
  model; the tyre's own torsional wind-up is the relaxation length of
  :mod:`.tyre`.

The wheel-speed pickup sits on the motor shaft: it measures the motor speed,
which differs from the wheel speed while the shaft winds up.

Mechanical MFWD tractor
-----------------------
A ≈ 100 kW diesel with an all-speed governor, a powershift gearbox of 12
forward ratios, a rear axle (bevel gear, open differential, final
planetaries) and a mechanical front-wheel drive (MFWD) whose axle turns
1–5 % faster than the rear ("lead", 1–5 % on MFWD tractors; Renius 2020).  With MFWD engaged the front axle is coupled
kinematically to the rear through the lead ratio: the share of torque that
goes to the front follows from that constraint, the two axles' shaft
compliances and the tyres, never from a fixed split.  The MFWD disengages
automatically above a steering angle (tractors' 4WD management), so that the
headland turns do not wind the drive-line up.

Engine full-load curve: ≈ 100 kW rated at 2200 rpm, maximum torque ≈ 35 %
above the rated torque at 1500 rpm, which is what OECD tractor tests of
100 kW tractors report (torque rise 30–40 %, maximum at 1400–1600 rpm; e.g.
the Nebraska Tractor Test Laboratory's reports of 6R-, Maxxum- and
Vario 700-class tractors).  The governor's speed droop is ≈ 8 % from high
idle to rated speed.  Drive-line efficiency from engine to wheel is 0.90
in work (Renius 2020: mechanical stepped transmissions of tractors
0.85–0.92 at full load) with an auxiliary load (fan, charge pump,
alternator) taken off at the flywheel.

The engine torque that EEC1 reports (SPN 513) is the engine's net brake
torque as a percentage of the reference torque (EC1 SPN 544); the auxiliary
load and the drive-line losses lie between it and the wheels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

RPM = 2.0 * math.pi / 60.0
"""rad/s per rpm."""


@dataclass(frozen=True)
class HubDriveSpec:
    """Electric hub drive per wheel (module doc)."""

    efficiency: float = 0.95
    """Torque efficiency of the hub reduction (motor → wheel) [-]."""
    drag_nms: float = 4.0
    """Speed-proportional drag at the wheel [N·m per rad/s] (≈ 13 N·m at 2.5 m/s)."""
    stiffness_nmprad: float = 1.5e5
    """Torsional stiffness between motor and wheel, wheel side [N·m/rad]."""
    damping_nmsprad: float = 1000.0
    """Torsional damping between motor and wheel [N·m·s/rad]."""
    motor_inertia_kgm2: float = 37.0
    """Rotor inertia reflected to the wheel [kg·m²] (0.06 kg·m² through 1:25)."""
    wheel_inertia_kgm2: float = 37.0
    """Tyre and rim inertia [kg·m²] (160 kg, radius of gyration 0.6 r0)."""
    torque_tau_s: float = 0.02
    """Inverter torque response time constant [s] (field-oriented current control: 5–20 ms)."""
    pickup_ratio: float = 25.0
    """Speed pickup revolutions per wheel revolution (on the motor shaft, before the 1:25 reduction)."""


@dataclass(frozen=True)
class EngineSpec:
    """Diesel engine with an all-speed governor (module doc)."""

    speed_rpm: tuple[float, ...] = (800.0, 1000.0, 1200.0, 1400.0, 1500.0, 1600.0, 1800.0, 2000.0, 2200.0, 2350.0, 2400.0)
    """Speeds of the full-load curve [rpm] (2200 rated, 2350 high idle)."""
    torque_nm: tuple[float, ...] = (330.0, 470.0, 540.0, 580.0, 585.0, 580.0, 555.0, 510.0, 434.0, 0.0, 0.0)
    """Full-load brake torque [N·m]: 434 N·m = 100 kW at 2200 rpm; 585 N·m at 1500 rpm (+35 %)."""
    friction_nm: float = 45.0
    """Motoring (closed-throttle) friction torque [N·m]."""
    reference_torque_nm: float = 600.0
    """EC1 engine reference torque, SPN 544 [N·m]: the 100 % of EEC1's percent torques."""
    idle_rpm: float = 850.0
    """Low idle [rpm]."""
    inertia_kgm2: float = 2.2
    """Engine, flywheel and gearbox input inertia [kg·m²]."""
    governor_tau_s: float = 0.08
    """Fuel-injection torque response [s]."""
    aux_torque_nm: float = 20.0
    """Auxiliary load at the flywheel [N·m] (fan, charge pump, alternator ≈ 4 kW at 2000 rpm)."""

    def full_load(self, omega: float) -> float:
        """Full-load torque [N·m] at engine speed ω [rad/s]."""
        return float(np.interp(omega / RPM, self.speed_rpm, self.torque_nm))


def _default_gears() -> tuple[float, ...]:
    # Speeds at 2200 rpm [km/h], steps of ≈ 1.28 (a 12-speed powershift range): 3.0 .. 40 km/h.
    v_kmh = 3.0 * 1.265 ** np.arange(12)
    r = 0.78
    final = 28.0
    return tuple(float(round(2200 * RPM * r / (v / 3.6) / final, 3)) for v in v_kmh)


@dataclass(frozen=True)
class MechDriveSpec:
    """Mechanical MFWD drive-line (module doc)."""

    engine: EngineSpec = field(default_factory=EngineSpec)
    gears: tuple[float, ...] = field(default_factory=_default_gears)
    """Gearbox ratios, input/output speed [-], forward gears 1..n."""
    reverse_gear: int = 3
    """The forward gear whose ratio the reverse range repeats (shuttle): its ratio, reported as gear −1."""
    final_drive: float = 28.0
    """Rear axle ratio, gearbox output / rear wheel (bevel gear × final planetaries) [-]."""
    front_lead: float = 0.03
    """Front-axle lead: front wheels turn 1 + lead times as fast as the rear at equal radii [-]."""
    efficiency: float = 0.90
    """Drive-line torque efficiency, flywheel → wheels, when driving [-]."""
    rear_stiffness_nmprad: float = 1.2e5
    """Torsional stiffness of the rear drive-line at the wheels (both sides) [N·m/rad]."""
    front_stiffness_nmprad: float = 6.0e4
    """Torsional stiffness of the front drive-line (prop shaft, front axle) at the wheels [N·m/rad]."""
    damping_ratio: float = 0.1
    """Damping ratio of the drive-line's torsional modes [-]."""
    mfwd: bool = True
    """MFWD engaged in work."""
    mfwd_off_steer_deg: float = 15.0
    """The MFWD disengages above this steering angle of the inner front wheel [deg]."""
    shift_up_rpm: float = 2150.0
    """Upshift when the engine speed the speed target needs exceeds this [rpm]."""
    shift_down_rpm: float = 1350.0
    """Downshift below this [rpm]."""
    shift_time_s: float = 0.4
    """Powershift duration: torque dip while the clutches change over [s]."""
    target_rpm: float = 1900.0
    """Engine speed the driver works at (gear chosen so the target speed needs about this) [rpm]."""

    def gear_for(self, v: float, r: float) -> int:
        """Gear (1-based) whose engine speed for v [m/s] is nearest the target speed."""
        need = [abs(v) / r * g * self.final_drive / RPM for g in self.gears]
        return 1 + int(np.argmin([abs(n - self.target_rpm) for n in need]))


@dataclass(frozen=True)
class DriveLineSpec:
    """Which drive-line the physical truth model drives (``kind``: ``hub`` or ``mechanical``)."""

    kind: str = "hub"
    hub: HubDriveSpec = field(default_factory=HubDriveSpec)
    mech: MechDriveSpec = field(default_factory=MechDriveSpec)

    def __post_init__(self) -> None:
        if self.kind not in ("hub", "mechanical"):
            raise ValueError(f"drivetrain kind {self.kind!r}: 'hub' or 'mechanical'")
