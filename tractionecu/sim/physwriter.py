"""Recording of a physical-truth run: the sensors and the bus of the machine simulated.

Hub drive (the paper's machine): the proprietary per-wheel messages as in
:mod:`.writer`, but the wheel speeds come from toothed pickups on the motor
shafts (:class:`~.sensors.ToothedPickup`: coloured, once-per-revolution
errors and period-counting quantisation instead of white noise), and with
``PhysicalSpec.sensor_biases`` every torque, load pin and the GNSS carry
systematic errors drawn once per run inside the tolerances of
:class:`~tractionecu.config.SensorSpec`.

Mechanical tractor: the standard J1939 / ISO 11783-7 messages at their real
periods instead of the per-wheel ones:

==========================  =======  ====================================================
EEC1  (PGN 61444)           20 ms    engine speed, actual (indicated) percent torque
EC1   (PGN 65251)           5 s      reference torque; 40 bytes by J1939-21 BAM (TP.CM/TP.DT)
ETC2  (PGN 61445)           100 ms   selected and current gear, actual gear ratio
CCVS1 (PGN 65265)           100 ms   wheel-based vehicle speed (gearbox output pickup)
EBC2  (PGN 65215)           100 ms   front axle speed and each wheel's relative speed
WBSD  (PGN 65096)           100 ms   wheel-based machine speed, distance, direction
GBSD  (PGN 65097)           100 ms   radar ground speed (when fitted)
Rear hitch status (65093)   100 ms   position, in-work, draft (when load pins are fitted)
==========================  =======  ====================================================

plus the NMEA of the GNSS receiver and a 1 Hz CSV export of the same run
(``export_1hz.csv``, column names as a J1939 logger's export writes them:
message, SPN, name and unit).  EEC1's actual engine percent torque is the
indicated torque (J1939-71 SPN 513): the brake torque plus the engine's
friction torque, over the EC1 reference torque (SPN 544).
"""

from __future__ import annotations

import csv
import dataclasses
import datetime as _dt
import math
from pathlib import Path

import numpy as np

from ..bus import j1939
from ..bus.candump import CandumpWriter
from ..bus.dbc import Codec, default_codec
from ..config import HUB_EFFICIENCY_TOL, DrivetrainSpec as DeclaredDrivetrain, save_vehicle, to_toml, toml_value
from ..model.vehicle import WHEELS
from . import tyre as ty
from .frames import DRIVETRAIN_SA, FORWARD, HITCH_SA, NAV_SA, REVERSE, TRACTOR_SA
from .gnss_receiver import course_over_ground, gnss_sentences
from .physical import axle_loads, class_curve
from .sensors import SensorBiases, ToothedPickup, draw_biases, ou_noise, pickup_speeds, quantise
from .tyre import rolling_radius as tyre_radius

ENGINE_SA = 0x00
TRANSMISSION_SA = 0x03
BRAKE_SA = 0x0B
RADAR_SA = 0x1D
"""Source addresses: J1939 preferred addresses of engine #1, transmission #1, brakes; the radar."""
EEC1_PERIOD_S = 0.02
"""EEC1 period [s] (J1939-71: engine-speed dependent, 10–20 ms; 20 ms on the John Deere 5055E capture)."""
J1939_100MS = 0.1
EC1_PERIOD_S = 5.0
BAM_PACKET_GAP_S = 0.05
"""Time between the BAM's data packets [s] (J1939-21: 50–200 ms)."""
PGN_TP_CM, PGN_TP_DT = 60416, 60160
RADAR_SIGMA_REL = 0.015
"""Ground-speed radar noise per 100 ms sample, relative [-] (Doppler radars over a tilled surface give
1–3 % speed scatter over short averaging windows; 1.5 % here, an assumption at the middle)."""
ENGINE_SPEED_SIGMA_REL = 0.001
"""Engine-speed noise, relative [-] (crankshaft 60−2 tooth wheel averaged over a revolution)."""
WHEEL_PICKUP = ToothedPickup(teeth=90)
"""Wheel-hub pickups of the mechanical tractor (ABS-style rings of 80–100 teeth)."""
EXPORT_CSV = "export_1hz.csv"


def write_physical_recording(scn, tr, out: str | Path, codec: Codec | None = None) -> dict[str, int]:
    """Write a physical-truth run: ``can.log``, ``gps.nmea``, ``vehicle.toml``, ``truth.csv``, ``truth.toml``
    (and ``export_1hz.csv`` for a mechanical tractor; one an earlier run left in ``out`` is removed otherwise).
    Returns counts of frames per message and NMEA lines."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    codec = codec or default_codec()
    ps = scn.physical
    spec = scn.sensors
    rng = np.random.default_rng(scn.seed + 1_000_003)
    if ps.sensor_biases:
        biases = draw_biases(spec, np.random.default_rng(scn.seed + 7_000_001), latency_s=ps.gnss_latency_s)
    else:
        biases = SensorBiases(gnss_latency_s=ps.gnss_latency_s)
    counts: dict[str, int] = {}
    frames: list[tuple[float, int, bytes]] = []
    t0 = scn.start_epoch

    def emit(name: str, t: float, values: dict, sa: int) -> None:
        cid, data = codec.encode(name, values, sa=sa)
        frames.append((t0 + t + float(rng.uniform(0.0, spec.can_jitter_s)), cid, data))
        counts[name] = counts.get(name, 0) + 1

    mech = ps.drivetrain.kind == "mechanical"
    if mech:
        export = _mechanical_frames(scn, tr, biases, rng, emit, frames, counts, codec)
    else:
        _hub_frames(scn, tr, biases, rng, emit)
        export = None
    lines, gps = _gnss(scn, tr, biases, rng, emit, radar=mech and ps.gbsd, gbsd_from_gnss=not mech)
    (out / "gps.nmea").write_text("\n".join(lines) + "\n", encoding="ascii")
    counts["nmea_lines"] = len(lines)

    frames.sort(key=lambda f: f[0])
    with open(out / "can.log", "w", encoding="ascii", newline="\n") as fh:
        w = CandumpWriter(fh, "can0")
        for t, cid, data in frames:
            w.write(t, cid, data, True)
    save_vehicle(_declared_vehicle(scn), out / "vehicle.toml", scn.sensors)
    if export is not None:
        _write_export(out / EXPORT_CSV, scn, export, gps)
    else:                                 # an earlier mechanical run's export is not this run's
        (out / EXPORT_CSV).unlink(missing_ok=True)
    _write_truth(scn, tr, out, biases)
    return counts


def _declared_vehicle(scn):
    """The vehicle as its owner declares it; a mechanical tractor's [drivetrain] from its spec sheet; the roll
    moment's front share from the chassis's construction (:func:`_declared_roll_share`)."""
    veh = scn.vehicle
    if not any(f.name == "drivetrain" for f in dataclasses.fields(veh)):
        return veh
    veh = _declared_drivetrain(scn)
    return dataclasses.replace(veh, front_roll_share=_declared_roll_share(scn), tyre_pressure_pa=_declared_pressure(scn))


def _declared_pressure(scn) -> float:
    """The tyre pressure the owner's file states [Pa] (``PhysicalSpec.declared_tyre_pressure_pa``, else the
    simulated machine's own): the rear rolling radius is calibrated at it."""
    p = scn.physical.declared_tyre_pressure_pa
    return float(scn.vehicle.tyre_pressure_pa if p is None else p)


def _declared_roll_share(scn) -> float:
    """The share of a turn's roll moment that the simulated machine's front axle carries, as its owner states
    it from the chassis's construction.  This machine's chassis shares the moment between its axles in
    proportion to their loads (:mod:`tractionecu.sim.physical`: the lateral load transfer is "shared by the
    axles as their loads", as springs sized for equal ride frequencies front and rear make the axles' roll
    stiffness proportional to their loads), so the owner declares the front axle's share of the static load, at
    rest with the implement raised as in a headland turn (one figure: in work the draft moves a few per cent
    of the load rearwards)."""
    veh = scn.vehicle
    fzf, fzr = axle_loads(veh, scn.physical.hitch, veh.mass_kg, 0.0, 0.0, 0.0)
    return round(fzf / (fzf + fzr), 4)


def _declared_drivetrain(scn):
    """The vehicle with its [drivetrain] (and the figures that go with it) as its owner declares them."""
    veh = scn.vehicle
    ps = scn.physical
    if ps.drivetrain.kind != "mechanical":
        return _declared_hub(scn)
    md = ps.drivetrain.mech
    eng = md.engine
    # What the owner knows, each with an error drawn once per seed inside its tolerance (own stream: nothing
    # else of the recording moves): SPN 514 nominal friction percent torque, which J1939-71 defines as the
    # basic engine's friction plus the accessories' loss torque (1 %/bit); the line of pull from the
    # implement's hitch geometry; the rear wheels' rolling radius from a 100 m calibration run at static load.
    rng = np.random.default_rng(scn.seed + 7_000_003)
    err = rng.uniform(-1.0, 1.0, 3) * np.array([DECLARED_FRICTION_TOL_PCT, DECLARED_PULL_ANGLE_TOL_DEG,
                                                 DECLARED_RADIUS_TOL_REL])
    friction_pct = 100.0 * (eng.friction_nm + eng.aux_torque_nm) / eng.reference_torque_nm + float(err[0])
    fzr = axle_loads(veh, ps.hitch, veh.mass_kg, 0.0, 0.0, 0.0)[1]
    r_cal = float(tyre_radius(0.5 * fzr, veh.r0_m, ps.tyre, _declared_pressure(scn))) * (1.0 + float(err[2]))
    dd = DeclaredDrivetrain(kind="mechanical", final_drive_ratio=md.final_drive, gear_ratio="bus",
                            front_drive="engaged" if md.mfwd else "disengaged", front_lead=md.front_lead,
                            engine_friction_percent=round(friction_pct, 2),
                            engine_inertia_kgm2=eng.inertia_kgm2, wheel_speeds="per-axle",
                            load_sensing="none", draft_sensing=bool(ps.draft_sensor),
                            rolling_radius_m=round(r_cal, 4))
    return dataclasses.replace(veh, drivetrain=dd,
                               pull_angle_deg=round(ps.hitch.pull_angle_deg + float(err[1]), 2))


DECLARED_FRICTION_TOL_PCT = 1.0
"""Tolerance of a declared (or EEC3-read) nominal friction percent torque [% of the reference]: its 1 %/bit."""
DECLARED_PULL_ANGLE_TOL_DEG = 2.0
"""Tolerance of a line of pull taken from the hitch and implement geometry [deg]."""
DECLARED_RADIUS_TOL_REL = 0.005
"""Tolerance of a rolling radius from a 100 m calibration run [-] (course and wheel-pulse count, ±0.5 %)."""


def _declared_hub(scn):
    """The hub-drive machine as its owner declares it: the hub reduction's efficiency with its tolerance
    (:data:`tractionecu.config.HUB_EFFICIENCY_TOL`), the line of pull and the rear wheels' calibrated rolling
    radius, each with an error drawn once per seed inside its tolerance (own stream: nothing else of the
    recording moves), never the truth's exact figure.  With ``PhysicalSpec.declared_exact`` it declares the
    truth's figures without errors, and also the hub's drag, the motor-plus-wheel inertia, the tyre
    carcass's longitudinal stiffness and the hub's torsional stiffness, damping and motor-side inertia (the
    two-inertia hub).  With ``PhysicalSpec.declared_hub`` (and not ``declared_exact``) it declares the two-inertia
    hub and the carcass off the truth by errors drawn inside their tolerances (:func:`_declared_two_inertia`)."""
    veh = scn.vehicle
    ps = scn.physical
    rng = np.random.default_rng(scn.seed + 7_000_005)
    err = rng.uniform(-1.0, 1.0, 3) * np.array([HUB_EFFICIENCY_TOL, DECLARED_PULL_ANGLE_TOL_DEG,
                                                 DECLARED_RADIUS_TOL_REL])
    if ps.declared_hub and not ps.declared_exact:
        veh = _declared_two_inertia(scn)
    if ps.declared_exact:
        hub = ps.drivetrain.hub
        err = np.zeros(3)
        veh = dataclasses.replace(veh, wheel_inertia_kgm2=hub.motor_inertia_kgm2 + hub.wheel_inertia_kgm2,
                                  tyre_carcass_stiffness_npm=ps.tyre.carcass_stiffness_npm,
                                  drivetrain=dataclasses.replace(veh.drivetrain, hub_drag_nms=hub.drag_nms,
                                                                 hub_stiffness_nmprad=hub.stiffness_nmprad,
                                                                 hub_damping_nmsprad=hub.damping_nmsprad,
                                                                 hub_motor_inertia_kgm2=hub.motor_inertia_kgm2))
    eta = min(1.0, ps.drivetrain.hub.efficiency * (1.0 + float(err[0])))
    fzr = axle_loads(veh, ps.hitch, veh.mass_kg, 0.0, 0.0, 0.0)[1]
    r_cal = float(tyre_radius(0.5 * fzr, veh.r0_m, ps.tyre, _declared_pressure(scn))) * (1.0 + float(err[2]))
    dd = dataclasses.replace(veh.drivetrain, kind="hub", efficiency=round(eta, 4),
                             efficiency_tolerance=HUB_EFFICIENCY_TOL, rolling_radius_m=round(r_cal, 4))
    return dataclasses.replace(veh, drivetrain=dd, pull_angle_deg=round(ps.hitch.pull_angle_deg + float(err[1]), 2),
                               pull_angle_tol_deg=DECLARED_PULL_ANGLE_TOL_DEG)


DECLARED_HUB_STIFFNESS_TOL_REL = 0.20
"""Tolerance of the hub reduction's declared torsional stiffness [-].  Planetary-gear catalogues give the
torsional stiffness as one typical figure over the upper load range; at part load the mesh is softer (backlash
and Hertzian contact make the stiffness rise with torque), and the wheel bearing and hub flange add compliance
the gear's figure leaves out: ±20 %."""
DECLARED_HUB_DAMPING_TOL_REL = 0.50
"""Tolerance of the hub's declared torsional damping [-].  No data sheet states it; it follows from a modal
damping ratio of a few per cent estimated for a gear train with oil churning and bearing losses, a figure known
to no better than about a factor of 1.5 either way: ±50 %."""
DECLARED_MOTOR_INERTIA_TOL_REL = 0.10
"""Tolerance of the declared motor-side inertia, reflected to the wheel [-]: the rotor's inertia from the motor's
data sheet (a few per cent) times the reduction ratio squared (exact), plus the first stage's carrier and sun,
which are estimated: ±10 %."""
DECLARED_WHEEL_INERTIA_TOL_REL = 0.20
"""Tolerance of the declared wheel-side inertia (tyre, rim, hub output) [-]: tyre and rim masses from the makers'
tables, the radius of gyration estimated (0.55–0.65 of r0 changes m k² by ±17 %), tread wear: ±20 %."""
DECLARED_CARCASS_TOL_REL = 0.20
"""Tolerance of the declared longitudinal carcass stiffness [-]: no maker publishes it for field tyres; it is taken
from a test-rig figure or a similar tyre, and it changes with inflation pressure (field tyres run at 0.8–1.6 bar),
wheel load and tread wear.  An engineering estimate for one declared figure: ±20 %."""


def _declared_two_inertia(scn):
    """The vehicle with the two-inertia hub and the tyre carcass declared, each figure off the truth's by an error
    drawn once per seed, uniform inside its tolerance (own stream: nothing else of the recording moves; never the
    truth's exact figure): the hub's torsional stiffness (:data:`DECLARED_HUB_STIFFNESS_TOL_REL`), its damping
    (:data:`DECLARED_HUB_DAMPING_TOL_REL`), the motor-side inertia (:data:`DECLARED_MOTOR_INERTIA_TOL_REL`), the
    wheel-side inertia (:data:`DECLARED_WHEEL_INERTIA_TOL_REL`; ``wheel_inertia_kgm2`` declares motor and wheel
    side together) and the carcass's longitudinal stiffness (:data:`DECLARED_CARCASS_TOL_REL`).  The hub's drag is
    left undeclared, as without the option."""
    veh = scn.vehicle
    ps = scn.physical
    hub = ps.drivetrain.hub
    rng = np.random.default_rng(scn.seed + 7_000_007)
    e = 1.0 + rng.uniform(-1.0, 1.0, 5) * np.array([DECLARED_HUB_STIFFNESS_TOL_REL, DECLARED_HUB_DAMPING_TOL_REL,
                                                     DECLARED_MOTOR_INERTIA_TOL_REL, DECLARED_WHEEL_INERTIA_TOL_REL,
                                                     DECLARED_CARCASS_TOL_REL])
    jm = round(hub.motor_inertia_kgm2 * float(e[2]), 3)
    jw = round(hub.wheel_inertia_kgm2 * float(e[3]), 3)
    dd = dataclasses.replace(veh.drivetrain, hub_stiffness_nmprad=round(hub.stiffness_nmprad * float(e[0]), 1),
                             hub_damping_nmsprad=round(hub.damping_nmsprad * float(e[1]), 2),
                             hub_motor_inertia_kgm2=jm)
    return dataclasses.replace(veh, wheel_inertia_kgm2=round(jm + jw, 3), drivetrain=dd,
                               tyre_carcass_stiffness_npm=round(ps.tyre.carcass_stiffness_npm * float(e[4]), 1))


# ----------------------------------------------------------------------------- hub drive
def _hub_frames(scn, tr, b: SensorBiases, rng, emit) -> None:
    spec = scn.sensors
    ps = scn.physical
    dt = scn.control_dt
    n = len(tr.t)
    wheel_every = max(1, round(1.0 / (spec.wheel_rate_hz * dt)))
    pin_every = max(1, round(1.0 / (spec.loadpin_rate_hz * dt)))
    kw = np.arange(0, n, wheel_every)
    tw = tr.t[kw]
    prng = np.random.default_rng(scn.seed + 3_000_017)
    om = np.column_stack([pickup_speeds(tr.t, tr.omega_sensor[:, i], tw, wheel_every * dt, ToothedPickup(),
                                        ps.drivetrain.hub.pickup_ratio, prng) for i in range(4)])
    om = quantise(om, spec.wheel_speed_quant)
    gain = 1.0 + np.asarray(b.torque_gain)
    md = tr.md[kw] * gain + np.asarray(b.torque_offset_nm)
    md = quantise(md + (spec.torque_sigma_abs + spec.torque_sigma_rel * np.abs(md)) * rng.standard_normal(md.shape),
                  spec.torque_quant)
    fzf = quantise(tr.fzf * (1.0 + b.axle_gain) + b.axle_offset_n + spec.axle_sigma_n * rng.standard_normal(n),
                   spec.axle_quant_n)
    fdx = quantise(tr.fdx * (1.0 + b.draft_gain) + b.draft_offset_n + spec.draft_sigma_n * rng.standard_normal(n),
                   spec.draft_quant_n)
    r_ecu = scn.vehicle.r0_m
    v_wheel = r_ecu * 0.5 * (om[:, 2] + om[:, 3])
    dist_w = np.cumsum(np.abs(v_wheel)) * wheel_every * dt
    dir_code = np.where(tr.direction > 0, FORWARD, REVERSE)
    wbsd_every = max(1, round(J1939_100MS / dt))
    for j, k in enumerate(kw):
        t = float(tr.t[k])
        emit("TECU_WheelSpeeds", t, {f"WheelSpeed_{w}": float(om[j, i]) for i, w in enumerate(WHEELS)}, DRIVETRAIN_SA)
        emit("TECU_DriveTorques", t + 0.0002, {f"DriveTorque_{w}": float(md[j, i]) for i, w in enumerate(WHEELS)},
             DRIVETRAIN_SA)
        if k % wbsd_every == 0:
            emit("WBSD", t + 0.0008, {"WheelBasedMachineSpeed": float(abs(v_wheel[j])),
                                      "WheelBasedMachineDistance": float(dist_w[j]),
                                      "WheelBasedMachineDirection": int(dir_code[k])}, TRACTOR_SA)
    for k in range(0, n, pin_every):
        t = float(tr.t[k])
        if ps.axle_load_sensor:
            emit("TECU_AxleLoad", t + 0.0004, {"FrontAxleLoad": float(fzf[k]), "FrontAxleLoadStatus": 0}, DRIVETRAIN_SA)
        emit("RearHitchStatus", t + 0.0006, _hitch(tr, k, fdx[k] if ps.draft_sensor else math.nan), HITCH_SA)


def _hitch(tr, k: int, draft: float) -> dict:
    return {"RearHitchPosition": 20.0 if tr.work[k] else 80.0,
            "RearHitchInWorkIndication": 1 if tr.work[k] else 0,
            "RearNominalLowerLinkForce": float(np.clip(draft / 500.0, -100, 100)) if math.isfinite(draft) else math.nan,
            "DraftForce": float(draft)}


# ----------------------------------------------------------------------------- mechanical
def _mechanical_frames(scn, tr, b: SensorBiases, rng, emit, frames, counts, codec) -> dict:
    ps = scn.physical
    md = ps.drivetrain.mech
    eng = md.engine
    spec = scn.sensors
    dt = scn.control_dt
    n = len(tr.t)
    t_ref = eng.reference_torque_nm
    prng = np.random.default_rng(scn.seed + 3_000_017)
    r_ecu = scn.vehicle.r0_m
    dir_code = np.where(tr.direction > 0, FORWARD, REVERSE)
    exp: dict[str, list] = {k: [] for k in ("t", "rpm", "pct", "gear", "ratio", "v_wheel", "v_front", "draft")}

    # EEC1 at 20 ms: indicated percent torque with the run's gain error and noise, engine speed.
    ke = np.arange(0, n, max(1, round(EEC1_PERIOD_S / dt)))
    indicated = (tr.engine_torque[ke] + eng.friction_nm) * (1.0 + b.torque_gain[0]) + b.torque_offset_nm[0]
    indicated = indicated + (spec.torque_sigma_abs + spec.torque_sigma_rel * np.abs(indicated)) * rng.standard_normal(len(ke))
    pct = 100.0 * indicated / t_ref
    rpm_e = tr.engine_speed[ke] * (1.0 + ENGINE_SPEED_SIGMA_REL * rng.standard_normal(len(ke)))
    for j, k in enumerate(ke):
        emit("EEC1", float(tr.t[k]), {"EngineTorqueMode": 1, "DriversDemandEnginePercentTorque": float(round(pct[j])),
                                      "ActualEnginePercentTorque": float(pct[j]), "EngineSpeed": float(rpm_e[j]),
                                      "EngineDemandPercentTorque": float(round(pct[j]))}, ENGINE_SA)

    # EC1 every 5 s as a BAM.
    ec1 = {"EngineSpeedAtIdlePoint1": eng.idle_rpm * 2 * math.pi / 60, "EnginePercentTorqueAtIdlePoint1": 0.0,
           "EngineSpeedAtHighIdlePoint6": 2350.0 * 2 * math.pi / 60, "EngineReferenceTorque": float(t_ref)}
    _, payload = codec.encode("EC1", ec1, sa=ENGINE_SA)
    size = len(payload)
    packets = (size + 6) // 7
    pgn = codec.message("EC1").pgn
    t_ec1 = 0.5
    while t_ec1 < float(tr.t[-1]):
        cm = bytes([32, size & 0xFF, size >> 8, packets, 0xFF, pgn & 0xFF, (pgn >> 8) & 0xFF, pgn >> 16])
        frames.append((scn.start_epoch + t_ec1, j1939.make_id(7, PGN_TP_CM, ENGINE_SA, 0xFF), cm))
        for q in range(packets):
            chunk = payload[7 * q: 7 * q + 7]
            data = bytes([q + 1]) + chunk + b"\xff" * (7 - len(chunk))
            frames.append((scn.start_epoch + t_ec1 + BAM_PACKET_GAP_S * (q + 1),
                           j1939.make_id(7, PGN_TP_DT, ENGINE_SA, 0xFF), data))
        counts["EC1"] = counts.get("EC1", 0) + 1
        counts["TP.CM"] = counts.get("TP.CM", 0) + 1
        counts["TP.DT"] = counts.get("TP.DT", 0) + packets
        t_ec1 += EC1_PERIOD_S

    # 100 ms messages.
    every = max(1, round(J1939_100MS / dt))
    k1 = np.arange(0, n, every)
    t1 = tr.t[k1]
    wheel_m = np.column_stack([pickup_speeds(tr.t, tr.omega[:, i], t1, J1939_100MS, WHEEL_PICKUP, 1.0, prng)
                               for i in range(4)])
    # Gearbox output pickup (60 teeth) turning at the rear axle's mean speed × final drive.
    out_m = pickup_speeds(tr.t, 0.5 * (tr.omega[:, 2] + tr.omega[:, 3]), t1, J1939_100MS, ToothedPickup(),
                          md.final_drive, prng)
    v_wb = r_ecu * out_m
    dist_w = np.cumsum(np.abs(v_wb)) * J1939_100MS
    v_front = r_ecu * 0.5 * (wheel_m[:, 0] + wheel_m[:, 1])
    rel = r_ecu * wheel_m - v_front[:, None]
    draft = tr.fdx[k1] * (1.0 + b.draft_gain) + b.draft_offset_n + spec.draft_sigma_n * rng.standard_normal(len(k1))
    draft = quantise(draft, spec.draft_quant_n)
    for j, k in enumerate(k1):
        t = float(tr.t[k])
        gear = int(tr.gear[k])
        emit("ETC2", t + 0.001, {"TransmissionSelectedGear": gear, "TransmissionActualGearRatio": float(tr.gear_ratio[k]),
                                 "TransmissionCurrentGear": gear}, TRANSMISSION_SA)
        emit("CCVS1", t + 0.002, {"ParkingBrakeSwitch": 0, "WheelBasedVehicleSpeed": float(abs(v_wb[j]))}, ENGINE_SA)
        emit("EBC2", t + 0.003, {"FrontAxleSpeed": float(abs(v_front[j])),
                                 "RelativeSpeedFrontAxleLeftWheel": float(rel[j, 0]),
                                 "RelativeSpeedFrontAxleRightWheel": float(rel[j, 1]),
                                 "RelativeSpeedRearAxle1LeftWheel": float(rel[j, 2]),
                                 "RelativeSpeedRearAxle1RightWheel": float(rel[j, 3])}, BRAKE_SA)
        emit("WBSD", t + 0.004, {"WheelBasedMachineSpeed": float(abs(v_wb[j])), "WheelBasedMachineDistance": float(dist_w[j]),
                                 "WheelBasedMachineDirection": int(dir_code[k])}, TRACTOR_SA)
        emit("RearHitchStatus", t + 0.005, _hitch(tr, k, float(draft[j]) if ps.draft_sensor else math.nan), HITCH_SA)
    # 1 Hz export: the last value sent in each second.
    per_s = max(1, round(1.0 / dt))
    for k in range(per_s - 1, n, per_s):
        je = min(int(np.searchsorted(ke, k, side="right")) - 1, len(ke) - 1)
        j1 = min(int(np.searchsorted(k1, k, side="right")) - 1, len(k1) - 1)
        exp["t"].append(float(tr.t[k]))
        exp["rpm"].append(float(rpm_e[je]) * 60.0 / (2 * math.pi))
        exp["pct"].append(float(np.clip(np.round(pct[je]), -125, 125)))
        exp["gear"].append(int(tr.gear[k1[j1]]))
        exp["ratio"].append(float(tr.gear_ratio[k1[j1]]))
        exp["v_wheel"].append(float(abs(v_wb[j1])) * 3.6)
        exp["v_front"].append(float(abs(v_front[j1])) * 3.6)
        exp["draft"].append(float(draft[j1]) if ps.draft_sensor else math.nan)
    return exp


# ----------------------------------------------------------------------------- GNSS and radar
def _gnss(scn, tr, b: SensorBiases, rng, emit, *, radar: bool, gbsd_from_gnss: bool):
    spec = scn.sensors
    dt = scn.control_dt
    n = len(tr.t)
    t0 = scn.start_epoch
    gps_every = max(1, round(1.0 / (spec.gps_rate_hz * dt)))
    gi = np.arange(gps_every - 1, n, gps_every)
    tg = tr.t[gi]
    lag = b.gnss_latency_s
    # The fix stamped t describes the machine at t − latency.
    x = np.interp(tg - lag, tr.t, tr.x)
    y = np.interp(tg - lag, tr.t, tr.y)
    vt = np.interp(tg - lag, tr.t, tr.v)
    hd = np.interp(tg - lag, tr.t, np.unwrap(tr.heading))
    alt_t = np.interp(tg - lag, tr.t, tr.alt)
    v_gps = np.abs(vt) + spec.gps_speed_sigma * rng.standard_normal(len(gi))
    g_dt = gps_every * dt
    ex = ou_noise(len(gi), g_dt, spec.gps_pos_sigma / math.sqrt(2), spec.gps_pos_tau_s, rng)
    ey = ou_noise(len(gi), g_dt, spec.gps_pos_sigma / math.sqrt(2), spec.gps_pos_tau_s, rng)
    ez = ou_noise(len(gi), g_dt, spec.gps_alt_sigma, spec.gps_pos_tau_s, rng)
    lat, lon = scn.field.to_latlon(x + ex, y + ey)
    alt = scn.field.origin_alt + alt_t + ez
    course = course_over_ground(hd, vt, spec.gps_speed_sigma, rng.spawn(1)[0])
    dir_code = np.where(tr.direction > 0, FORWARD, REVERSE)
    gbsd_dist = np.cumsum(np.abs(v_gps)) * g_dt
    lines: list[str] = []
    for j, k in enumerate(gi):
        lines += gnss_sentences(spec, t0, float(tg[j]), float(lat[j]), float(lon[j]), float(alt[j]),
                                float(v_gps[j]), float(course[j]))
        if gbsd_from_gnss:
            emit("GBSD", float(tg[j]) + 0.03, {"GroundBasedMachineSpeed": max(float(v_gps[j]), 0.0),
                                               "GroundBasedMachineDistance": float(gbsd_dist[j]),
                                               "GroundBasedMachineDirection": int(dir_code[k])}, NAV_SA)
    if radar:
        every = max(1, round(J1939_100MS / dt))
        kr = np.arange(0, n, every)
        va = np.abs(tr.v[kr])
        v_r = np.maximum(va * (1.0 + b.radar_gain) * (1.0 + RADAR_SIGMA_REL * rng.standard_normal(len(kr))), 0.0)
        v_r = np.where(va < 0.05, 0.0, v_r)          # Doppler radars read zero below their least speed
        dist = np.cumsum(v_r) * J1939_100MS
        for j, k in enumerate(kr):
            emit("GBSD", float(tr.t[k]) + 0.006, {"GroundBasedMachineSpeed": float(v_r[j]),
                                                  "GroundBasedMachineDistance": float(dist[j]),
                                                  "GroundBasedMachineDirection": int(dir_code[k])}, RADAR_SA)
    return lines, {"t": tg, "lat": lat, "lon": lon, "v": v_gps}


# ----------------------------------------------------------------------------- export and truth
EXPORT_COLUMNS = (
    "Time [s]", "Date Time UTC",
    "EEC1 SPN190 Engine Speed [rpm]", "EEC1 SPN513 Actual Engine - Percent Torque [%]",
    "ETC2 SPN523 Transmission Current Gear", "ETC2 SPN526 Transmission Actual Gear Ratio",
    "CCVS1 SPN84 Wheel-Based Vehicle Speed [km/h]", "EBC2 SPN904 Front Axle Speed [km/h]",
    "RHS SPN1879 Rear Draft [N]", "GNSS Latitude [deg]", "GNSS Longitude [deg]", "GNSS Speed [km/h]",
)


def _write_export(path: Path, scn, exp: dict, gps: dict) -> None:
    """The 1 Hz CSV export a J1939 logger writes (last value of each signal in each second)."""
    with open(path, "w", newline="", encoding="utf-8") as fh:
        wr = csv.writer(fh)
        wr.writerow(EXPORT_COLUMNS)
        for i, t in enumerate(exp["t"]):
            g = min(int(np.searchsorted(gps["t"], t, side="right")) - 1, len(gps["t"]) - 1)
            utc = _dt.datetime.fromtimestamp(scn.start_epoch + t, tz=_dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S")
            wr.writerow([f"{t:.0f}", utc, f"{exp['rpm'][i]:.1f}", f"{exp['pct'][i]:.0f}", exp["gear"][i],
                         f"{exp['ratio'][i]:.3f}", f"{exp['v_wheel'][i]:.2f}", f"{exp['v_front'][i]:.2f}",
                         "" if not math.isfinite(exp["draft"][i]) else f"{exp['draft'][i]:.0f}",
                         f"{gps['lat'][g]:.8f}", f"{gps['lon'][g]:.8f}", f"{gps['v'][g] * 3.6:.2f}"])


def _toml_table(name: str, obj) -> list[str]:
    """A flat ``[name]`` table of a dataclass (nested dataclasses as ``[name.field]``)."""
    lines = [f"[{name}]"]
    subs = []
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if dataclasses.is_dataclass(v):
            subs.append((f.name, v))
        elif isinstance(v, (tuple, list)) and v and dataclasses.is_dataclass(v[0]):
            continue
        elif v is not None:
            lines.append(f"{f.name} = {toml_value(v)}")
    lines.append("")
    for k, v in subs:
        lines += _toml_table(f"{name}.{k}", v)
    return lines


def _write_truth(scn, tr, out: Path, b: SensorBiases) -> None:
    lat, lon = scn.field.to_latlon(tr.x, tr.y)
    names = [r.name for r in scn.field.regions]
    ps = scn.physical
    mech = ps.drivetrain.kind == "mechanical"
    with_dir = bool(np.any(scn.plan.direction < 0))
    cols = (["t"] + [f"mu_{w}" for w in WHEELS] + ["rho_s", "a", "soil_id", "soil_name"]
            + [f"slip_{w}" for w in WHEELS] + ["v", "x", "y", "lat", "lon", "alt", "fdx", "fzf", "work"]
            + (["direction"] if with_dir else [])
            + [f"v_{w}" for w in WHEELS] + ["curvature"] + [f"fz_{w}" for w in WHEELS]
            + (["engine_torque_nm", "engine_speed_rpm", "gear", "gear_ratio", "front_lead", "mfwd"] if mech else []))
    rpm = 60.0 / (2 * math.pi)
    with open(out / "truth.csv", "w", newline="", encoding="utf-8") as fh:
        wr = csv.writer(fh)
        wr.writerow(cols)
        t_abs = scn.start_epoch + tr.t
        for k in range(len(tr.t)):
            row = ([f"{t_abs[k]:.3f}"] + [f"{x:.5f}" for x in tr.mu[k]]
                   + [f"{tr.rho_s[k]:.5f}", f"{tr.a[k]:.4f}", int(tr.soil[k]), names[tr.soil[k]]]
                   + [f"{x:.5f}" for x in tr.slip[k]]
                   + [f"{tr.v[k]:.4f}", f"{tr.x[k]:.3f}", f"{tr.y[k]:.3f}", f"{lat[k]:.8f}", f"{lon[k]:.8f}",
                      f"{tr.alt[k] + scn.field.origin_alt:.3f}", f"{tr.fdx[k]:.1f}", f"{tr.fzf[k]:.1f}", int(tr.work[k])]
                   + ([int(tr.direction[k])] if with_dir else [])
                   + [f"{x:.4f}" for x in tr.v_wheel[k]] + [f"{tr.curvature[k]:.5f}"] + [f"{x:.1f}" for x in tr.fz[k]])
            if mech:
                row += [f"{tr.engine_torque[k]:.1f}", f"{tr.engine_speed[k] * rpm:.1f}", int(tr.gear[k]),
                        f"{tr.gear_ratio[k]:.3f}", f"{tr.front_lead[k]:.3f}", int(tr.mfwd[k])]
            wr.writerow(row)
    lines = ["# Simulation truth: never read by diagnosis.",
             f'scenario = "{scn.name}"', f"seed = {scn.seed}", f"start_epoch = {scn.start_epoch}",
             f"duration_s = {float(tr.t[-1]):.2f}", 'truth_model = "physical"',
             f'drivetrain = "{ps.drivetrain.kind}"',
             "# truth.csv: slip_* is eq. 6 of each wheel against its own ground speed v_* (not v);",
             "# mu_* = F_h/F_z in the paper's split with the declared rho_t (see tractionecu.sim.physical).", ""]
    lines += ["[field]", f"origin_lat = {scn.field.origin_lat}", f"origin_lon = {scn.field.origin_lon}", ""]
    veh = scn.vehicle
    fz_static = (veh.static_front_fraction * veh.mass_kg * 9.81 / 2, (1 - veh.static_front_fraction) * veh.mass_kg * 9.81 / 2)

    def axle_curve(soil, s_grid, axle):
        return ty.paper_mu(s_grid, soil, fz_static[axle], veh.tyre_width_m, veh.r0_m, ps.tyre, veh.tyre_pressure_pa,
                           veh.rho_t)

    for r, s in zip(scn.field.regions, ps.soils):
        s_grid, mu_grid = class_curve(s, scn.vehicle, ps.tyre)
        lines += ["[[soils]]", f'name = "{r.name}"', f'soil_class = "{r.soil_class}"', f"a = {r.a}", f"rho_s = {r.rho_s}",
                  "polygon = [" + ", ".join(f"[{x}, {y}]" for x, y in r.polygon) + "]",
                  "# a, soil_class: the filter's class that fits this soil's mu(s) best (s 0..0.3, static mean wheel load)",
                  *(s.toml_lines() if hasattr(s, "toml_lines") else
                    [f"cone_index_pa = {s.cone_index_pa!r}", f'law = "{s.law}"', f"s_shape = {s.s_shape!r}"]),
                  "mu_curve_s = " + toml_value([round(float(x), 4) for x in s_grid]),
                  "mu_curve = " + toml_value([round(float(x), 5) for x in mu_grid]),
                  "# the same under the static front and rear wheel loads (mu(s) depends on the load)",
                  "mu_curve_front = " + toml_value([round(float(x), 5) for x in axle_curve(s, s_grid, 0)]),
                  "mu_curve_rear = " + toml_value([round(float(x), 5) for x in axle_curve(s, s_grid, 1)]), ""]
    lines.append("[effects]")
    lines.append("")
    lines.append(to_toml(scn.implement, "implement"))
    lines.append(to_toml(scn.sensors, "sensors"))
    lines += ["# Systematic sensor errors of this run (drawn once from the seed; zero = none).", "[biases]"]
    lines += [f"{f.name} = {toml_value(getattr(b, f.name))}" for f in dataclasses.fields(b)]
    lines.append("")
    dl = ps.drivetrain
    phys = dataclasses.replace(ps, soils=(), drivetrain=None)
    lines += _toml_table("physical", phys)
    lines += ["[physical.drivetrain]", f'kind = "{dl.kind}"', ""]
    lines += _toml_table("physical.drivetrain." + ("mech" if dl.kind == "mechanical" else "hub"),
                         dl.mech if dl.kind == "mechanical" else dl.hub)
    (out / "truth.toml").write_text("\n".join(lines), encoding="utf-8")
