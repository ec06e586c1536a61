"""Physical truth model: a simulator whose equations are not the filter's.

``Scenario.truth = "physical"`` runs this model instead of the paper's
(:mod:`.simulator`).  It is built from its own sources, never from
:mod:`tractionecu.model.effects` or the filter's curve family, and differs
from the filter where real machines do:

1. **Tyre–soil force** (:mod:`.tyre`): Brixius' mobility-number equations
   from the soil's cone index and the tyre's size and deflection, so μ(s)
   depends on the wheel load and ρ_s on slip; soils with a peaked or
   sigmoid μ(s); the force builds up over a relaxation length.  Or, for soils given by their
   bevameter parameters (:class:`.terramech.BekkerSoil`), Bekker's pressure–sinkage and
   Janosi–Hanamoto's shear over the contact patch (:mod:`.terramech`): a μ(s) not of Brixius' family.
2. **Load transfer from geometry**, every step: the drawbar pull along a
   line of pull (hitch height, hitch behind the rear axle, pull angle),
   acceleration at the centre of gravity, and grade; in turns the
   centripetal acceleration moves load to the outer wheels.
3. **Turning kinematics** (Ackermann, no lateral tyre slip): the reference
   point is the rear-axle midpoint (also the GNSS antenna), whose path has
   curvature κ; with yaw rate Ω = v κ each wheel's ground speed along its
   own heading is

       v_RL,RR = v (1 ∓ κ w/2),   v_FL,FR = v √((1 ∓ κ w/2)² + (κ L)²)

   (w track width, L wheelbase, left wheels first, κ > 0 turning left):
   outer wheels run faster, the front wheels on the larger radius.  Each
   wheel's slip is taken against its own ground speed.  The body moves with
   one degree of freedom v; the wheels' forces enter its equation weighted
   by g_i = v_i / v (their power over v).
4. **Drive-line** (:mod:`.drivetrain`): the hub drive with compliance and
   losses, or a mechanical MFWD tractor with engine, governor, powershift
   gearbox, front-axle lead and losses.

Equations (per wheel i, state in :mod:`._physical_kernel`):

    J_w ω̇_i = M_shaft,i − r_i F_z,i (T_i(σ_f,i) + ρ_t,tyre sgn ω_i)
    σ̇_f,i  = max(|v_i|, V_RELAX_MIN)/L_r (σ_i − σ_f,i),   σ_i = (r_i ω_i − v_i)/max(r_i|ω_i|, |v_i|, V_SLIP_MIN)
    m v̇    = Σ g_i F_z,i (T_i(σ_f,i) − (1/B_n,i + 0.5|σ_f,i|/√B_n,i) sgn v_i) − F_dx − m g sin θ − F_air

integrated with RK4 in compiled code (2 ms steps).

Truth in the paper's terms (what ``truth.csv`` holds)
------------------------------------------------------
The filter writes the wheel torque as r F_z (μ + ρ_t) with the machine's
declared ρ_t (``vehicle.toml``).  The truth's μ is defined so that the same
relation holds with the truth's torque, i.e. it is observable from the
wheel torque:

    μ_i    = T_i(σ_f,i) + (ρ_t,tyre − ρ_t,declared) sgn ω_i
    ρ_s    = Σ (1/B_n,i + 0.5|σ_f,i|/√B_n,i + ρ_t,tyre − ρ_t,declared) F_z,i / Σ F_z,i
    slip_i = paper eq. 6 of ω_i against the wheel's own ground speed v_i (not v)

So μ(0) is not zero (Brixius' internal loss 0.04 is more than the declared
ρ_t), ρ_s grows with slip, and in a turn each wheel's slip is against its
own speed.  ``a`` and the soil class in ``truth.toml`` are the least-squares
fit of the filter's classes to the soil's μ(s) at the static mean wheel
load (s from 0 to 0.3); the sampled true curve is written beside them.
The wheel torque in the truth trace (``md``) is what the drive-line reports:
the inverter's motor torque for the hub drive (before the hub's losses),
the axle shaft torque for the mechanical tractor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..config import G, VehicleParams
from ..model.mucurve import SOIL_CLASSES
from . import _physical_kernel as K
from . import terramech as tm
from . import tyre as ty
from .control import Shuttle
from .drivetrain import RPM, DriveLineSpec
from .field import Field, SoilRegion
from .plan import DS, DURATION_CAP
from .trace import TruthTrace

AIR_DENSITY = 1.2
"""Air density [kg/m³] at 20 °C."""
H_INT = 0.002
"""Integration step [s]."""


@dataclass(frozen=True)
class HitchSpec:
    """Where and how the implement pulls (ASABE D497.7: line of pull)."""

    behind_rear_axle_m: float = 1.0
    """Drawbar pin behind the rear axle [m] (an assumption: the drawbar hitch point of a 100 kW tractor
    lies some 0.4–0.5 m behind the PTO shaft end, itself ≈ 0.5 m behind the axle)."""
    pull_angle_deg: float = 8.0
    """Line of pull below the horizontal, towards the implement [deg] (drawn tillage tools 5–15°)."""
    draft_a: float = 46.0
    """ASABE D497.7 Table 1 draft coefficient A of a field cultivator [N per tool per cm depth]."""
    draft_b: float = 2.8
    """ASABE D497.7 Table 1 coefficient B [N·h/km per tool per cm] (draft grows with speed)."""


@dataclass(frozen=True)
class PhysicalSpec:
    """Everything the physical truth model needs beyond the scenario's vehicle, implement and plan."""

    soils: tuple[ty.PhysSoil, ...]
    """Soils by region index (the scenario's ``Field`` regions carry their class-equivalents)."""
    tyre: ty.TyreSpec = field(default_factory=ty.TyreSpec)
    drivetrain: DriveLineSpec = field(default_factory=DriveLineSpec)
    hitch: HitchSpec = field(default_factory=HitchSpec)
    kp: float = 1.2
    """Speed controller proportional gain [1/s]."""
    ki: float = 0.4
    """Speed controller integral gain [1/s²]."""
    gbsd: bool = True
    """A ground-speed radar (GBSD) is fitted (mechanical runs)."""
    draft_sensor: bool = True
    """Draft load pins are fitted (rear hitch status carries the draft)."""
    axle_load_sensor: bool = True
    """Front-axle load pins are fitted (hub runs; mechanical tractors have none)."""
    sensor_biases: bool = False
    """Draw sensor gain/offset errors inside the datasheet tolerances (fixed per run from the seed)."""
    gnss_latency_s: float = 0.0
    """GNSS latency [s]: the fix stamped t describes the machine at t − latency (with ``sensor_biases``
    it is drawn in 50–100 ms when left at 0)."""
    lateral_load_transfer: bool = True
    """Shift load to the outer wheels in turns (m v² κ h_cg / track, shared by the axles as their loads)."""
    draft_cycle: tuple[float, float, float] | None = None
    """(low, high, period [m]): the working depth, and with it the draft, varies between low and high times
    nominal with the distance travelled (an implement on uneven ground or a depth-control programme)."""
    declared_exact: bool = False
    """The recording's ``vehicle.toml`` declares the truth's own hub drive-line and hitch figures (the hub's
    efficiency and no-load drag, the motor-plus-wheel inertia, the tyre carcass's stiffness, the line of pull, the
    rear wheels' rolling radius at their static load) instead of figures off by errors drawn inside their
    tolerances: only the truth's physics and the sensors' noise separate the declared machine from the simulated
    one (recording writer only; the simulated machine is the same)."""
    declared_hub: bool = False
    """The recording's ``vehicle.toml`` also declares the two-inertia hub (torsional stiffness, damping, motor-side
    and wheel-side inertia) and the tyre carcass's longitudinal stiffness, each off the truth's figure by an error
    drawn once per seed inside its stated tolerance (:func:`tractionecu.sim.physwriter._declared_hub`); recording
    writer only, the simulated machine is the same."""
    declared_tyre_pressure_pa: float | None = None
    """The tyre inflation pressure the recording's ``vehicle.toml`` declares, and at which its rear rolling
    radius was calibrated [Pa]; None: the simulated machine's own.  Set apart from the vehicle's pressure, the
    tyres run at another pressure than the file says (let down for the field and the file not updated, a slow
    leak): recording writer only, the simulated machine runs at ``vehicle.tyre_pressure_pa``."""


def class_equivalent(soil: ty.PhysSoil, veh: VehicleParams, tyre: ty.TyreSpec,
                     s_max: float = 0.3) -> tuple[str, float, float]:
    """(class, a, ρ_s) of the filter's classes that fit the soil's μ(s) best at the static mean wheel load."""
    fz = veh.mass_kg * G / 4.0
    s = np.linspace(0.0, s_max, 61)
    mu = ty.paper_mu(s, soil, fz, veh.tyre_width_m, veh.r0_m, tyre, veh.tyre_pressure_pa, veh.rho_t)
    best = ("stubble", math.nan, math.inf)
    for name, cls in SOIL_CLASSES.items():
        g = cls.g(s)
        a = float(np.dot(g, mu) / np.dot(g, g))
        res = float(np.sum((mu - a * g) ** 2))
        if res < best[2]:
            best = (name, a, res)
    rho = float(ty.paper_rho_s(0.1, soil, fz, veh.tyre_width_m, veh.r0_m, tyre, veh.tyre_pressure_pa, veh.rho_t))
    return best[0], round(best[1], 4), round(rho, 4)


def class_curve(soil: ty.PhysSoil, veh: VehicleParams, tyre: ty.TyreSpec, s_max: float = 0.5,
                n: int = 26) -> tuple[np.ndarray, np.ndarray]:
    """The soil's true μ(s) (paper split) at the static mean wheel load, sampled on s in [0, s_max]."""
    s = np.linspace(0.0, s_max, n)
    return s, ty.paper_mu(s, soil, veh.mass_kg * G / 4.0, veh.tyre_width_m, veh.r0_m, tyre, veh.tyre_pressure_pa,
                          veh.rho_t)


def physical_field(soils: tuple[ty.PhysSoil, ...], veh: VehicleParams, tyre: ty.TyreSpec | None = None,
                   **kw) -> Field:
    """A :class:`Field` whose regions are the soils' class-equivalents (for maps and scoring)."""
    tyre = tyre or ty.TyreSpec()
    regions = []
    for s in soils:
        cls, a, rho = class_equivalent(s, veh, tyre)
        regions.append(SoilRegion(s.name, cls, a, rho, s.polygon))
    return Field(regions, **kw)


def wheel_speed_ratios(kappa: float, track: float, wheelbase: float) -> np.ndarray:
    """g_i = v_i / v of FL, FR, RL, RR for path curvature κ [1/m] of the rear-axle midpoint (module doc)."""
    hw = 0.5 * track * kappa
    fl = math.sqrt((1.0 - hw) ** 2 + (kappa * wheelbase) ** 2)
    fr = math.sqrt((1.0 + hw) ** 2 + (kappa * wheelbase) ** 2)
    return np.array([fl, fr, 1.0 - hw, 1.0 + hw])


def axle_loads(veh: VehicleParams, hitch: HitchSpec, m: float, fdx: float, accel: float, theta: float
               ) -> tuple[float, float]:
    """(front, rear) axle loads [N] from moments about the rear tyre contact (module doc, item 2).

    F_zf L = m g cos θ x_cg − (m g sin θ + m a) h_cg − F_dx (h_hitch + x_h tan β),
    F_zr   = m g cos θ + F_dx tan β − F_zf,
    x_cg = static front fraction × L ahead of the rear axle, x_h the drawbar pin behind it, β the pull angle.
    """
    L = veh.wheelbase_m
    x_cg = veh.static_front_fraction * L
    tb = math.tan(math.radians(hitch.pull_angle_deg))
    w = m * G
    fzf = (w * math.cos(theta) * x_cg - (w * math.sin(theta) + m * accel) * veh.cg_height_m
           - fdx * (veh.hitch_height_m + hitch.behind_rear_axle_m * tb)) / L
    fzr = w * math.cos(theta) + fdx * tb - fzf
    return fzf, fzr


def _path_curvature(plan) -> np.ndarray:
    """Curvature of the plan's path along the body's forward axis [1/m] (dψ/ds × direction of travel)."""
    psi = np.unwrap(plan.heading)
    k = np.gradient(psi, DS)
    # The plan's heading jumps nowhere; a cusp (reverse) keeps the heading, so the gradient is the arc's.
    return np.clip(k, -1.0, 1.0) * plan.direction


def _steering_curvature(plan, nk: int) -> np.ndarray:
    """The path curvature (:func:`_path_curvature`) smoothed over ``nk`` samples (one wheelbase): a steering
    system cannot step the steering angle while the machine rolls.  Within each stretch of one direction of
    travel only, its heading's gradient taken inside the stretch: at a cusp the machine stands, and the
    steering turns there, so the arc before a cusp keeps its curvature to the end and the leg after it starts
    with its own.  A window (or a central difference) across the cusp gives the wheels a yaw rate v κ that
    the plan's positions and heading (the GNSS course) do not have: half an arc's curvature over half a
    wheelbase on each side, with the sign of travel flipped after the cusp, a heading disagreement of
    κ L / 4 (0.07 rad after a 9 m quarter circle with L = 2.5 m).  Without a cusp: the plain smoothing."""
    d = plan.direction
    cut = np.flatnonzero(d[1:] != d[:-1]) + 1
    if not len(cut):
        k = _path_curvature(plan)
        return np.convolve(np.pad(k, (nk // 2, nk - 1 - nk // 2), mode="edge"), np.ones(nk) / nk, mode="valid")
    psi = np.unwrap(plan.heading)
    out = np.zeros(len(psi))
    for i0, i1 in zip(np.r_[0, cut], np.r_[cut, len(psi)]):
        if i1 - i0 < 2:
            continue                     # a one-sample stretch: no arc, the steering stands at 0
        k = np.clip(np.gradient(psi[i0:i1], DS), -1.0, 1.0) * d[i0:i1]
        out[i0:i1] = np.convolve(np.pad(k, (nk // 2, nk - 1 - nk // 2), mode="edge"), np.ones(nk) / nk,
                                 mode="valid")
    return out


def simulate_physical(scn):
    """Run the physical truth model; deterministic for a given ``scn.seed``.  Returns a TruthTrace."""
    ps: PhysicalSpec = scn.physical
    if ps is None:
        raise ValueError(f"scenario {scn.name}: truth 'physical' needs Scenario.physical")
    rng = np.random.default_rng(scn.seed)
    veh = scn.vehicle
    fld = scn.field
    plan = scn.plan
    ctl = scn.controller
    imp = scn.implement
    dt = scn.control_dt
    n_sub = max(1, int(round(dt / H_INT)))
    h = dt / n_sub
    m = veh.mass_kg
    tyre = ps.tyre
    dtr = ps.drivetrain
    mech = dtr.kind == "mechanical"
    L, track = veh.wheelbase_m, veh.track_width_m
    if scn.effects:
        raise ValueError(f"scenario {scn.name}: effects ({', '.join(scn.effects)}) belong to the paper truth model; "
                         "the physical model has its own physics")
    if len(ps.soils) != len(fld.regions):
        raise ValueError(f"scenario {scn.name}: {len(ps.soils)} physical soils for {len(fld.regions)} field regions")

    # Soils of the Bekker / Janosi–Hanamoto model (:mod:`.terramech`) instead of Brixius': all or none.
    bekker = [isinstance(s, tm.BekkerSoil) for s in ps.soils]
    if any(bekker) and not all(bekker):
        raise ValueError(f"scenario {scn.name}: Brixius and Bekker soils in one field are not supported")
    bekker = all(bekker) and len(ps.soils) > 0
    if not bekker:
        soil_ci = np.array([s.cone_index_pa for s in ps.soils])
        soil_law = np.array([ty.LAW_ID[s.law] for s in ps.soils], dtype=float)
        soil_shape = np.array([s.s_shape for s in ps.soils])
    soil_draft = np.array([s.draft_factor for s in ps.soils])
    reg_a = np.array([r.a for r in fld.regions])

    # Duration (as the paper model: plan length at the mean target speed, plus stops at cusps).
    est_time = plan.length / max(float(np.mean(plan.v_target)), 0.1) * 1.2 + 20.0
    cusps = plan.cusps
    if len(cusps):
        vmax = float(np.max(plan.v_target))
        est_time += len(cusps) * (ctl.shuttle_dwell_s + vmax / ctl.stop_decel + vmax / ctl.accel_max + 5.0)
    t_end = est_time if scn.duration_s is None else min(scn.duration_s, DURATION_CAP * est_time)
    n_max = int(round(t_end / dt)) + 1

    phi = math.exp(-dt / imp.draft_tau_s)
    draft_w = rng.standard_normal(n_max) * imp.draft_cv * math.sqrt(1 - phi * phi)
    fluct = rng.standard_normal() * imp.draft_cv

    # Along the path: wheel positions (reference point = rear-axle midpoint), soils, curvature, grade.
    off_fwd = np.array([L, L, 0.0, 0.0])
    off_lat = np.array([track / 2, -track / 2, track / 2, -track / 2])
    ch_p, sh_p = np.cos(plan.heading), np.sin(plan.heading)
    wx_p = plan.x[:, None] + off_fwd * ch_p[:, None] - off_lat * sh_p[:, None]
    wy_p = plan.y[:, None] + off_fwd * sh_p[:, None] + off_lat * ch_p[:, None]
    soil_w_p = fld.soil_index(wx_p, wy_p)
    soil_c_p = fld.soil_index(plan.x, plan.y)
    kappa_p = _steering_curvature(plan, max(1, int(round(L / DS))))
    theta_p = np.asarray(fld.grade(plan.x, plan.y, plan.heading), dtype=float)
    alt_p = np.asarray(fld.elevation(plan.x, plan.y), dtype=float)
    n_path = len(plan.s)

    # Drive-line parameters.
    p = np.zeros(14)
    p[0] = m
    p[2] = tyre.rho_t
    p[3] = tyre.carcass_stiffness_npm
    hub = dtr.hub
    md_ = dtr.mech
    if mech:
        jw = veh.wheel_inertia_kgm2          # tyre and rim; the drive-line's inertia sits in the node
        eng = md_.engine
        p[5] = 1.0
        p[8], p[10] = md_.rear_stiffness_nmprad, md_.front_stiffness_nmprad
        p[9] = 2 * md_.damping_ratio * math.sqrt(md_.rear_stiffness_nmprad * 2 * jw)
        p[11] = 2 * md_.damping_ratio * math.sqrt(md_.front_stiffness_nmprad * 2 * jw)
        p[12] = md_.front_lead
    else:
        jw = hub.wheel_inertia_kgm2
        p[5] = 0.0
        p[6], p[7], p[8], p[9], p[10] = hub.efficiency, hub.drag_nms, hub.stiffness_nmprad, hub.damping_nmsprad, hub.motor_inertia_kgm2
    p[1] = jw

    shuttle = Shuttle(plan, ctl, dt)

    v0 = shuttle.direction * scn.v0
    fzf, fzr = axle_loads(veh, ps.hitch, m, 0.0, 0.0, 0.0)
    fz = np.array([fzf / 2, fzf / 2, fzr / 2, fzr / 2])
    r = ty.rolling_radius(fz, veh.r0_m, tyre, veh.tyre_pressure_pa)
    x = np.zeros(K.N_STATE)
    x[0:4] = v0 / r
    x[8] = v0
    # Nominal radius the machine's own controller knows (declared r0, its own deflection guess).
    r_ctl = veh.r0_m * 0.97
    if mech:
        gear = md_.gear_for(max(abs(v0), 0.5), r_ctl)
        x[9] = v0 / r[2]
        ratio = md_.gears[gear - 1] * md_.final_drive
        omega_e = x[9] * ratio * shuttle.direction
        t_e = 0.0
        shift_t = -1.0
        omega_set = omega_e
    else:
        x[9:13] = x[0:4]
        md_act = np.zeros(4)
    mfwd_on = bool(mech and md_.mfwd)
    work_level = 0.0
    accel = 0.0
    v_ref = v0
    integ = 0.0
    share = np.array([veh.static_front_fraction / 2] * 2 + [(1 - veh.static_front_fraction) / 2] * 2)
    w = np.zeros((9, 4))
    outb = np.zeros((4, 4))
    d = 0.0
    keys = ("t", "omega", "v", "md", "fz", "fzf", "fdx", "mu", "slip", "rho_s", "a", "a_wheel", "soil", "soil_wheel",
            "x", "y", "heading", "alt", "theta", "work", "direction", "v_wheel", "curvature", "omega_sensor")
    mkeys = ("engine_torque", "engine_speed", "gear", "gear_ratio", "front_lead", "mfwd")
    out: dict[str, list] = {k: [] for k in keys + (mkeys if mech else ())}
    aero_k = 0.5 * AIR_DENSITY * veh.cd_area_m2
    tb = math.tan(math.radians(ps.hitch.pull_angle_deg))

    for k in range(n_max):
        t = k * dt
        if d >= plan.length - 0.5:
            break
        ip = min(max(int(d / DS), 0), n_path - 1)
        v_tgt, work = float(plan.v_target[ip]), bool(plan.work[ip])
        soil_w = soil_w_p[ip]
        soil_c = int(soil_c_p[ip])
        theta = float(theta_p[ip])
        kappa = float(kappa_p[ip])
        v = x[8]

        # Implement: level, draft from ASABE D497 (speed and soil texture), Gauss–Markov fluctuation.
        target_level = 1.0 if work else 0.0
        stp = dt / imp.lower_time_s
        work_level = min(work_level + stp, target_level) if work_level < target_level else max(work_level - stp, target_level)
        fluct = phi * fluct + draft_w[k]
        hp = ps.hitch
        v_kmh_ref = 3.6 * max(float(np.max(plan.v_target)), 0.5)
        speed_f = (hp.draft_a + hp.draft_b * 3.6 * abs(v)) / (hp.draft_a + hp.draft_b * v_kmh_ref)
        fdx = imp.draft_n * work_level * (1.0 + fluct) * speed_f * soil_draft[soil_c]
        if ps.draft_cycle is not None:
            lo, hi, per = ps.draft_cycle
            fdx *= lo + (hi - lo) * (0.5 - 0.5 * math.cos(2.0 * math.pi * d / per))

        # Change of direction at cusps (as the paper model: brake, stand, dwell, shuttle).
        at_cusp = shuttle.at_cusp(d, v_ref)
        if at_cusp:
            integ *= shuttle.hold_decay
        d = shuttle.advance(at_cusp, d, v)
        v_tgt = shuttle.direction * shuttle.brake(v_tgt, d)
        dv_ref = max(-ctl.accel_max * dt, min(ctl.accel_max * dt, v_tgt - v_ref))
        v_ref += dv_ref
        a_ref = dv_ref / dt
        e = v_ref - v

        # Loads from geometry, tyre radii, soil terms under each wheel.
        fzf, fzr = axle_loads(veh, ps.hitch, m, fdx, accel, theta)
        fzf = max(fzf, 200.0)
        fzr = max(fzr, 200.0)
        # Lateral load transfer in a turn: centripetal acceleration v² κ at the CG height, shared by the
        # axles as their loads; the outer wheels gain what the inner lose (κ > 0: left turn, right wheels outer).
        # Statics of the rigid body: the axles' outer-minus-inner differences 2 δ_axle times half the track
        # balance the roll moment, Σ_axles δ_axle · track = m v² κ h_cg, so each axle's outer wheel gains its
        # share of d_lat = m v² κ h_cg / track (not half of it).
        d_lat = m * v * v * kappa * veh.cg_height_m / track if ps.lateral_load_transfer else 0.0
        share_f = fzf / (fzf + fzr)
        dlf = min(max(d_lat * share_f, -0.45 * fzf), 0.45 * fzf)
        dlr = min(max(d_lat * (1 - share_f), -0.45 * fzr), 0.45 * fzr)
        fz = np.array([fzf / 2 - dlf, fzf / 2 + dlf, fzr / 2 - dlr, fzr / 2 + dlr])
        r = ty.rolling_radius(fz, veh.r0_m, tyre, veh.tyre_pressure_pa)
        g = wheel_speed_ratios(kappa, track, L)
        w[0] = fz
        w[1] = r
        w[2] = g
        if bekker:
            for i in range(4):
                tmax_i, j0_i, rho_c_i = ps.soils[soil_w[i]].terms(fz[i], veh.tyre_width_m, veh.r0_m, tyre,
                                                                  veh.tyre_pressure_pa)
                w[3, i], w[5, i], w[6, i] = tmax_i, j0_i, rho_c_i
            w[4] = tm.LAW_JANOSI
            w[7] = 0.0
        else:
            bn = ty.mobility_number(soil_ci[soil_w], fz, veh.tyre_width_m, veh.r0_m, tyre, veh.tyre_pressure_pa)
            w[3] = 0.88 * (1.0 - np.exp(-0.1 * bn))
            w[4] = soil_law[soil_w]
            w[5] = soil_shape[soil_w]
            w[6] = 1.0 / bn
            w[7] = 0.5 / np.sqrt(bn)
        f_ext = fdx + m * G * math.sin(theta) + aero_k * v * abs(v)
        p[4] = f_ext

        ff_dir = max(-1.0, min(1.0, v_ref / K.V_SIGN_BAND))
        f_cmd = m * (a_ref + ps.kp * e + integ) + fdx + ff_dir * ctl.rho_guess * m * G
        if not mech:
            md_cmd = np.clip(f_cmd * share * r_ctl, -veh.max_wheel_torque_nm, veh.max_wheel_torque_nm)
            p_wheel = float(np.sum(np.abs(md_cmd * x[9:13])))
            saturated = bool(np.any(np.abs(md_cmd) >= veh.max_wheel_torque_nm))
            if p_wheel > veh.rated_power_w:
                md_cmd *= veh.rated_power_w / p_wheel
                saturated = True
            if not saturated or e * integ < 0:
                integ += ps.ki * e * dt
            md_act += (md_cmd - md_act) * (1.0 - math.exp(-dt / hub.torque_tau_s))
            w[8] = md_act
        else:
            # MFWD management: off above the steering angle of the inner front wheel.
            steer = math.degrees(math.atan(L * abs(kappa) / max(1.0 - abs(kappa) * track / 2, 1e-3)))
            mfwd_on = md_.mfwd and steer <= md_.mfwd_off_steer_deg
            p[13] = 1.0 if mfwd_on else 0.0
            # Driver / ground-speed management: gear for the target speed, engine speed set from the speed loop.
            v_cmd = max(abs(v_ref) + ps.kp * 0.5 * (abs(v_ref) - abs(v)) + integ, 0.0)
            want = md_.gear_for(max(abs(v_ref), 0.3), r_ctl)
            need_rpm = v_cmd / r_ctl * md_.gears[gear - 1] * md_.final_drive / RPM
            if shift_t < 0 and want != gear and (need_rpm > md_.shift_up_rpm or need_rpm < md_.shift_down_rpm
                                                  or abs(v_ref) < 0.3):
                gear = want
                shift_t = 0.0
            ratio = md_.gears[gear - 1] * md_.final_drive
            omega_set = min(max(v_cmd / r_ctl * ratio, eng.idle_rpm * RPM), 2350 * RPM)
            omega_e = abs(x[9]) * ratio
            # All-speed governor with ≈ 8 % droop to full load, fuel response lag.
            droop = 0.08 * 2200 * RPM
            t_cmd = 434.0 * (omega_set - omega_e) / droop + eng.aux_torque_nm
            t_max = eng.full_load(omega_e)
            t_cmd = min(max(t_cmd, -eng.friction_nm), t_max)
            t_e += (t_cmd - t_e) * (1.0 - math.exp(-dt / eng.governor_tau_s))
            saturated = t_e >= t_max - 1.0
            if not saturated or e * integ < 0:
                integ += ps.ki * 0.5 * (abs(v_ref) - abs(v)) * dt
            net = t_e - eng.aux_torque_nm
            eff = md_.efficiency if net >= 0 else 1.0 / md_.efficiency
            dip = 1.0
            if shift_t >= 0:
                dip = 0.3 + 0.7 * abs(1.0 - 2.0 * shift_t / md_.shift_time_s)
                shift_t += dt
                if shift_t >= md_.shift_time_s:
                    shift_t = -1.0
            p[6] = shuttle.direction * net * eff * ratio * dip
            p[7] = eng.inertia_kgm2 * ratio * ratio

        accel = K.integrate(x, w, p, h, n_sub)
        d = min(d + abs(x[8]) * dt, shuttle.next_cusp)
        K.outputs(x, w, p, outb)
        trac = outb[1]
        # Paper-terms truth (module doc).
        drho = tyre.rho_t - veh.rho_t
        sgn_w = np.clip(r * x[0:4] / K.V_SIGN_BAND, -1.0, 1.0)
        mu = trac + drho * sgn_w
        rho_i = w[6] + w[7] * np.abs(x[4:8]) + drho
        vw = g * x[8]
        s_eq6 = outb[3].copy()

        out["t"].append(t + dt)
        out["omega"].append(x[0:4].copy())
        out["v"].append(x[8])
        out["fz"].append(fz.copy())
        out["fzf"].append(fzf)
        out["fdx"].append(fdx)
        out["mu"].append(mu)
        out["slip"].append(s_eq6)
        out["rho_s"].append(float(np.sum(rho_i * fz) / np.sum(fz)))
        out["a"].append(reg_a[soil_c])
        out["a_wheel"].append(reg_a[soil_w])
        out["soil"].append(soil_c)
        out["soil_wheel"].append(soil_w.copy())
        out["x"].append(float(plan.x[ip]))
        out["y"].append(float(plan.y[ip]))
        out["heading"].append(float(plan.heading[ip]))
        out["alt"].append(float(alt_p[ip]))
        out["theta"].append(theta)
        out["work"].append(work_level >= 1.0)
        out["direction"].append(shuttle.direction)
        out["v_wheel"].append(vw)
        out["curvature"].append(kappa)
        if mech:
            out["md"].append(outb[2].copy())
            out["omega_sensor"].append(x[0:4].copy())
            ratio_now = md_.gears[gear - 1] * md_.final_drive
            out["engine_torque"].append(t_e)
            out["engine_speed"].append(abs(x[9]) * ratio_now)
            out["gear"].append(shuttle.direction * gear)
            out["gear_ratio"].append(md_.gears[gear - 1])
            out["front_lead"].append(md_.front_lead)
            out["mfwd"].append(bool(mfwd_on))
        else:
            out["md"].append(md_act.copy())
            out["omega_sensor"].append(x[9:13].copy())

    arr = {k: np.asarray(vv) for k, vv in out.items()}
    arr["direction"] = arr["direction"].astype(np.int8)
    return TruthTrace(**arr)

