"""Truth model of the field simulator: a four-wheel-drive tractor pulling an implement.

Two truth models exist (``Scenario.truth``): ``paper``, this module, and
``physical`` (:mod:`.physical`), whose tyre–soil forces, load transfer,
turning kinematics and drive-line are not the filter's.  :func:`simulate`
runs the one the scenario names.  What follows describes the paper model.

The truth model is the paper's model (section 2) with the true μ(s) curve of
the soil under each wheel, plus the effects from :mod:`tractionecu.model.effects`
that a scenario switches on.  Per wheel i (FL, FR, RL, RR):

    J ω̇_i = M_w,i − r_i F_z,i (μ_i(s_i) + ρ_t sgn ω_i)                 (paper eq. 2, 4)
    m v̇   = Σ μ_i F_z,i − F_dx − Σ ρ_s,i F_z,i − F_grade − F_aero        (paper eq. 8)

with s_i the two-branch slip (eq. 6) from ω_i, v and the rolling radius
r_i = r_d(F_z,i) (eq. 9).  The wheel–slip coupling is stiff (time constant
J v / (r² F_z μ') ≈ 2 ms at field speed), so the ω, v system is integrated
with a linearly implicit (Rosenbrock–Euler) step of 5 ms using the analytic
Jacobian; it is L-stable, so the stiffness costs nothing.

A PI speed controller with feed-forward sets four drive torques (shared by
static axle load, limited by wheel torque and total power, with a 50 ms
first-order inverter lag).  The implement's draft is a nominal force with
Gauss–Markov fluctuation, ramped in and out as the implement is lowered and
raised.

Travel in both directions.  Speeds, wheel speeds, torques and forces are
signed along the body's forward axis (v < 0 in reverse).  Eq. 6 is written
with magnitudes, so the paper's μ(s) is the adhesion in the direction of
travel; the truth model uses the equivalent signed form

    σ_i = (r_i ω_i − v) / max(r_i |ω_i|, |v|, V_SLIP_MIN),   F_h,i = a g(σ_i) F_z,i   (g odd)

which is eq. 6 (σ = s) when travelling forwards and −s in reverse, so a
driving torque in reverse (ω, M_d < 0) gives s > 0 and a traction force
(μ = F_h/F_z) < 0, and stays defined when a wheel turns against the motion
or the machine stands still (below V_SLIP_MIN the slip is regularised, as
tyre models do at standstill).  Rolling resistances oppose the motion
(sgn ω, sgn v, smoothed within V_SIGN_BAND of zero so that the machine can
stand still).  The plan's direction changes only at standstill: the speed
reference brakes to a stop at each cusp (``ControllerSpec.stop_decel``),
holds still for ``shuttle_dwell_s``, then accelerates the other way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from ..config import G, SensorSpec, VehicleParams
from ..model import effects as fx
from ..model.vehicle import rolling_radius, slip as slip_fn
from .control import V_STANDSTILL, ControllerSpec, Shuttle  # noqa: F401  (V_STANDSTILL re-exported)
from .field import Field
from .physical import PhysicalSpec, simulate_physical
from .plan import DS, DURATION_CAP, Plan
from .trace import TruthTrace

V_SLIP_MIN = 0.1
"""Speed below which the slip's denominator is held [m/s] (low-speed regularisation of eq. 6)."""
V_SIGN_BAND = 0.02
"""Speed band around zero [m/s] in which sgn(v), sgn(ω) of the rolling resistances are linear."""
TRUTH_MODELS = ("paper", "physical")
"""Truth models a scenario can select (``Scenario.truth``)."""


@dataclass(frozen=True)
class ImplementSpec:
    """Drawn implement."""

    draft_n: float = 17000.0
    """Nominal draft in work [N]: a 6 m shallow cultivator/harrow at 9 km/h (ASABE D497.7
    Table 1: field cultivator 46–64 N per tine-cm depth; ≈ 2.8 kN/m at 10 cm)."""
    draft_cv: float = 0.08
    """Coefficient of variation of the draft fluctuation [-] (tillage draft varies 5–15 % within a field pass)."""
    draft_tau_s: float = 0.7
    """Correlation time of the draft fluctuation [s]."""
    lower_time_s: float = 1.5
    """Time to lower or raise the implement [s]."""


@dataclass
class Scenario:
    """Everything that defines one simulated run."""

    name: str
    field: Field
    plan: Plan
    vehicle: VehicleParams = field(default_factory=VehicleParams)
    implement: ImplementSpec = field(default_factory=ImplementSpec)
    controller: ControllerSpec = field(default_factory=ControllerSpec)
    sensors: SensorSpec = field(default_factory=SensorSpec)
    effects: dict[str, dict[str, float]] = field(default_factory=dict)
    seed: int = 0
    duration_s: float | None = None
    """Stop after this many seconds; None = at the end of the plan."""
    v0: float = 0.3
    """Initial (creep) speed [m/s]."""
    start_epoch: float = 1783670400.0
    """UTC epoch of t = 0 [s] (2026-07-10 08:00:00 UTC)."""
    control_dt: float = 0.01
    """Control and recording period [s]."""
    substeps: int = 2
    """Integration substeps per control period."""
    truth: str = "paper"
    """Truth model: ``paper`` (this module: the paper's equations and curve family) or ``physical``
    (:mod:`.physical`: Brixius tyre–soil forces, geometric load transfer, turning kinematics, drive-line
    compliance and losses; never the filter's equations)."""
    physical: "PhysicalSpec | None" = None
    """Soils, tyre, drive-line, hitch and sensor fittings of the physical truth model."""

    def __post_init__(self) -> None:
        if self.truth not in TRUTH_MODELS:
            raise ValueError(f"scenario {self.name}: truth {self.truth!r} (known: {', '.join(TRUTH_MODELS)})")


def simulate(scn: Scenario) -> TruthTrace:
    """Run the scenario's truth model (``scn.truth``); deterministic for a given ``scn.seed``."""
    if scn.truth == "physical":
        return simulate_physical(scn)
    rng = np.random.default_rng(scn.seed)
    veh = scn.vehicle
    eff = scn.effects
    fld = scn.field
    plan = scn.plan
    dt = scn.control_dt
    h = dt / scn.substeps

    m_nom = veh.mass_kg
    dm = eff["mass"]["delta_kg"] if "mass" in eff else 0.0
    front_share = eff["mass"]["front_share"] if "mass" in eff else 0.0
    m = m_nom + dm
    J = veh.wheel_inertia_kgm2
    rho_t = veh.rho_t
    L = veh.wheelbase_m
    fzf_static = veh.static_front_fraction * m_nom * G + dm * G * front_share
    fzr_static = m * G - fzf_static
    r_scale = 1.0 + eff["wheel_radius"]["epsilon"] if "wheel_radius" in eff else 1.0
    relax = eff.get("relaxation")
    share = np.array([veh.static_front_fraction / 2] * 2 + [(1 - veh.static_front_fraction) / 2] * 2)

    # Regions as arrays for fast lookup.
    reg_a = np.array([r.a for r in fld.regions])
    reg_rho = np.array([r.rho_s for r in fld.regions])
    reg_cls = [r.cls for r in fld.regions]
    reg_p = np.array([c.p for c in reg_cls])
    reg_a1 = np.array([c.alpha1 for c in reg_cls])
    reg_a2 = np.array([c.alpha2 for c in reg_cls])

    # Duration.
    est_time = plan.length / max(float(np.mean(plan.v_target)), 0.1) * 1.15 + 20.0
    cusps = plan.cusps
    if len(cusps):
        # Each change of direction: brake, dwell, accelerate again.
        ctl = scn.controller
        vmax = float(np.max(plan.v_target))
        est_time += len(cusps) * (ctl.shuttle_dwell_s + vmax / ctl.stop_decel + vmax / ctl.accel_max + 5.0)
    t_end = est_time if scn.duration_s is None else min(scn.duration_s, DURATION_CAP * est_time)
    n_max = int(round(t_end / dt)) + 1

    # Draft fluctuation: Gauss–Markov at the control rate.
    phi = math.exp(-dt / scn.implement.draft_tau_s)
    draft_w = rng.standard_normal(n_max) * scn.implement.draft_cv * math.sqrt(1 - phi * phi)

    # Direction of travel and the next change of direction (cusp) ahead.
    shuttle = Shuttle(plan, scn.controller, dt)

    # State.
    v = shuttle.direction * scn.v0
    fz = np.array([fzf_static / 2] * 2 + [fzr_static / 2] * 2)
    r = rolling_radius(fz, veh) * r_scale
    omega = np.full(4, v / r[0]) * (r[0] / r)
    s_dyn = np.zeros(4)
    d = 0.0
    v_ref = v
    integ = 0.0
    md_act = np.zeros(4)
    work_level = 0.0
    fluct = rng.standard_normal() * scn.implement.draft_cv
    accel = 0.0

    out = {k: [] for k in ("t", "omega", "v", "md", "fz", "fzf", "fdx", "mu", "slip", "rho_s", "a", "a_wheel",
                           "soil", "soil_wheel", "x", "y", "heading", "alt", "theta", "work",
                           "direction")}
    half_l = L / 2.0
    half_w = veh.track_width_m / 2.0
    off_fwd = np.array([half_l, half_l, -half_l, -half_l])
    off_lat = np.array([half_w, -half_w, half_w, -half_w])  # left positive

    # Soil under each wheel, grade and altitude along the whole path, computed once.
    ch_p, sh_p = np.cos(plan.heading), np.sin(plan.heading)
    wx_p = plan.x[:, None] + off_fwd * ch_p[:, None] - off_lat * sh_p[:, None]
    wy_p = plan.y[:, None] + off_fwd * sh_p[:, None] + off_lat * ch_p[:, None]
    soil_w_p = fld.soil_index(wx_p, wy_p)
    soil_c_p = fld.soil_index(plan.x, plan.y)
    if "grade" in eff:
        theta_p = fld.grade(plan.x, plan.y, plan.heading)
        alt_p = fld.elevation(plan.x, plan.y)
    else:
        theta_p = np.zeros(len(plan.x))
        alt_p = np.zeros(len(plan.x))
    n_path = len(plan.s)

    for k in range(n_max):
        t = k * dt
        if d >= plan.length - 0.5:
            break
        ip = min(max(int(d / DS), 0), n_path - 1)
        x, y, hd = float(plan.x[ip]), float(plan.y[ip]), float(plan.heading[ip])
        v_tgt, work = float(plan.v_target[ip]), bool(plan.work[ip])
        soil_w = soil_w_p[ip]
        soil_c = int(soil_c_p[ip])
        theta = float(theta_p[ip])
        alt = float(alt_p[ip])

        # Implement and draft.
        target_level = 1.0 if work else 0.0
        step = dt / scn.implement.lower_time_s
        work_level = min(work_level + step, target_level) if work_level < target_level else max(work_level - step, target_level)
        fluct = phi * fluct + draft_w[k]
        fdx = scn.implement.draft_n * work_level * (1.0 + fluct)
        if "draft_speed" in eff:
            p = eff["draft_speed"]
            fdx *= float(fx.draft_speed_factor(v, p["c_s2pm2"], p["v_ref_mps"]))

        # Change of direction: only at the cusp, at standstill, after the dwell.
        at_cusp = shuttle.at_cusp(d, v_ref)
        if at_cusp:
            integ *= shuttle.hold_decay
        d = shuttle.advance(at_cusp, d, v)
        v_tgt = shuttle.brake(v_tgt, d)                # brake so as to stand still at the cusp

        # Speed controller (signed speeds; the rolling-resistance feed-forward opposes the reference motion).
        v_tgt = shuttle.direction * v_tgt
        dv_ref = max(-scn.controller.accel_max * dt, min(scn.controller.accel_max * dt, v_tgt - v_ref))
        v_ref += dv_ref
        a_ref = dv_ref / dt
        e = v_ref - v
        ff_dir = max(-1.0, min(1.0, v_ref / V_SIGN_BAND))
        f_cmd = m_nom * (a_ref + scn.controller.kp * e + integ) + fdx + ff_dir * scn.controller.rho_guess * m_nom * G
        r_nom = rolling_radius(fz, veh)
        md_cmd = f_cmd * share * r_nom
        md_cmd = np.clip(md_cmd, -veh.max_wheel_torque_nm, veh.max_wheel_torque_nm)
        p_wheel = float(np.sum(np.abs(md_cmd * omega)))
        saturated = False
        if p_wheel > veh.rated_power_w:
            md_cmd *= veh.rated_power_w / p_wheel
            saturated = True
        if np.any(np.abs(md_cmd) >= veh.max_wheel_torque_nm):
            saturated = True
        if not saturated or e * integ < 0:
            integ += scn.controller.ki * e * dt
        md_act += (md_cmd - md_act) * (1.0 - math.exp(-dt / scn.controller.torque_tau_s))
        md_wheel = md_act
        if "drivetrain" in eff:
            md_wheel = fx.drivetrain_torque(md_act, omega, eff["drivetrain"]["eta"], eff["drivetrain"]["loss_nm"])

        # Loads.
        fz = np.array([fzf_static / 2] * 2 + [fzr_static / 2] * 2)
        if "load_transfer" in eff:
            lt = eff["load_transfer"]
            dfr = float(fx.load_transfer_rear(fdx, accel, theta, m, L, lt["h_hitch_m"], lt["h_cg_m"]))
            fz = fz + np.array([-dfr / 2, -dfr / 2, dfr / 2, dfr / 2])
        fz = np.maximum(fz, 100.0)
        r = rolling_radius(fz, veh) * r_scale
        a_w = reg_a[soil_w]
        rho_w = reg_rho[soil_w]
        p_w, a1_w, a2_w = reg_p[soil_w], reg_a1[soil_w], reg_a2[soil_w]
        f_other = fdx + (fx.grade_force(m, theta) if "grade" in eff else 0.0)
        aero = eff.get("aero")

        for _ in range(scn.substeps):
            if aero is not None:
                f_ext = f_other + float(fx.aero_force(v, aero["cd_area_m2"]))
            else:
                f_ext = f_other
            omega, v, s_dyn, accel = _implicit_step(omega, v, s_dyn, h, md_wheel, fz, r, a_w, p_w, a1_w, a2_w,
                                                    rho_w, rho_t, J, m, f_ext, relax)
            d = min(d + abs(v) * h, shuttle.next_cusp)

        s_kin = slip_fn(omega, v, r)
        s_force = s_dyn if relax is not None else _signed_slip(omega, v, r, s_kin)
        mu = a_w * _g(s_force, p_w, a1_w, a2_w)
        out["t"].append(t + dt)
        out["omega"].append(omega.copy())
        out["v"].append(v)
        out["md"].append(md_act.copy())
        out["fz"].append(fz.copy())
        out["fzf"].append(fz[0] + fz[1])
        out["fdx"].append(fdx)
        out["mu"].append(mu)
        out["slip"].append(s_kin)
        out["rho_s"].append(float(np.sum(rho_w * fz) / (m * G)))
        out["a"].append(reg_a[soil_c])
        out["a_wheel"].append(a_w.copy())
        out["soil"].append(soil_c)
        out["soil_wheel"].append(soil_w.copy())
        out["x"].append(x)
        out["y"].append(y)
        out["heading"].append(hd)
        out["alt"].append(alt)
        out["theta"].append(theta)
        out["work"].append(work_level >= 1.0)
        out["direction"].append(shuttle.direction)

    arr = {k: np.asarray(vv) for k, vv in out.items()}
    arr["direction"] = arr["direction"].astype(np.int8)
    return TruthTrace(**arr)


def _g(s: NDArray[np.float64], p: NDArray[np.float64], a1: NDArray[np.float64], a2: NDArray[np.float64]) -> NDArray[np.float64]:
    sa = np.abs(s)
    return np.sign(s) * (1.0 - p * np.exp(a1 * sa) - (1.0 - p) * np.exp(a2 * sa))


def _dg(s: NDArray[np.float64], p: NDArray[np.float64], a1: NDArray[np.float64], a2: NDArray[np.float64]) -> NDArray[np.float64]:
    sa = np.abs(s)
    return -p * a1 * np.exp(a1 * sa) - (1.0 - p) * a2 * np.exp(a2 * sa)


def _regular(omega, v, r) -> bool:
    """Every wheel turns the way the machine moves and the speeds are above V_SLIP_MIN: plain eq. 6."""
    return bool(np.all((omega * v > 0.0) & (np.maximum(r * np.abs(omega), abs(v)) >= V_SLIP_MIN)))


def _signed_slip(omega, v, r, s_eq6):
    """Signed slip σ (module doc) per wheel, given the eq. 6 slip ``s_eq6`` of the same ω, v, r."""
    if _regular(omega, v, r):
        return s_eq6 if v > 0 else -s_eq6
    return _slip_and_partials(omega, v, r)[0]


def _slip_and_partials(omega, v, r):
    """Signed slip σ (module doc) and its partial derivatives ∂σ/∂ω, ∂σ/∂v for each wheel.

    When every wheel turns the way the machine moves, above V_SLIP_MIN, σ is
    eq. 6 times the direction of travel; otherwise the general signed form
    (clipped to [−1, 1], zero derivatives where clipped).
    """
    vw = r * np.abs(omega)
    va = abs(v)
    if _regular(omega, v, r):
        vw = np.maximum(vw, 1e-4)
        vas = max(va, 1e-4)
        drive = va <= vw
        s = np.where(drive, 1.0 - va / vw, -1.0 + vw / vas)
        sgn_w = np.sign(omega) + (omega == 0)
        sgn_v = 1.0 if v >= 0 else -1.0
        ds_dw = np.where(drive, va * r * sgn_w / (vw * vw), r * sgn_w / vas)
        ds_dv = np.where(drive, -sgn_v / vw, -vw * sgn_v / (vas * vas))
        if v > 0:
            return s, ds_dw, ds_dv
        return -s, -ds_dw, -ds_dv
    u = r * omega
    den = np.maximum(np.maximum(vw, va), V_SLIP_MIN)
    raw = (u - v) / den
    by_w = (vw >= va) & (vw >= V_SLIP_MIN)          # den = r|ω|
    by_v = (va > vw) & (va >= V_SLIP_MIN)           # den = |v|
    ds_dw = np.where(by_w, r * v * np.sign(u) / (den * den), r / den)
    ds_dv = np.where(by_v, -u * math.copysign(1.0, v) / (den * den), -1.0 / den)
    inside = np.abs(raw) <= 1.0
    return np.clip(raw, -1.0, 1.0), np.where(inside, ds_dw, 0.0), np.where(inside, ds_dv, 0.0)


def _implicit_step(omega, v, s_dyn, h, md, fz, r, a, p, a1, a2, rho_s, rho_t, J, m, f_ext, relax):
    """One linearly implicit Euler step of (ω1..4, v[, s_dyn1..4]) with the analytic Jacobian.

    Signed: ω, v, md and the slip σ are negative in reverse; ``f_ext`` [N] is the external force
    against the body's forward axis (draft, grade, air).
    """
    s, ds_dw, ds_dv = _slip_and_partials(omega, v, r)
    # Rolling resistances against the motion; linear within V_SIGN_BAND of standstill.
    u = r * omega
    sgn_w = np.clip(u / V_SIGN_BAND, -1.0, 1.0)
    sgn_v = max(-1.0, min(1.0, v / V_SIGN_BAND))
    band_w = np.abs(u) < V_SIGN_BAND
    band_v = abs(v) < V_SIGN_BAND
    sf = s if relax is None else s_dyn
    mu = a * _g(sf, p, a1, a2)
    dmu = a * _dg(sf, p, a1, a2)
    f_om = (md - r * fz * (mu + rho_t * sgn_w)) / J
    f_v = ((mu * fz).sum() - f_ext - (rho_s * fz).sum() * sgn_v) / m
    # ∂ω̇_i/∂ω_i and ∂v̇/∂v of the rolling resistances inside the band (zero outside).
    rr_w = np.where(band_w, -r * r * fz * rho_t / (J * V_SIGN_BAND), 0.0) if band_w.any() else None
    rr_v = -(rho_s * fz).sum() / (m * V_SIGN_BAND) if band_v else None
    if relax is None:
        # (I − hJ)Δz = h f with J an arrow matrix (wheels couple only through v):
        # solved in closed form by eliminating Δω.
        k_om = -r * fz * dmu / J
        diag_w = k_om * ds_dw
        if rr_w is not None:
            diag_w = diag_w + rr_w
        d_inv = 1.0 / (1.0 - h * diag_w)
        c = k_om * ds_dv                       # ∂ω̇_i/∂v
        b = fz * dmu * ds_dw / m               # ∂v̇/∂ω_i
        e = (fz * dmu * ds_dv).sum() / m       # ∂v̇/∂v
        if rr_v is not None:
            e = e + rr_v
        hf_om = h * f_om
        dv = (h * f_v + h * (b * d_inv * hf_om).sum()) / (1.0 - h * e - h * h * (b * d_inv * c).sum())
        d_om = d_inv * (hf_om + h * c * dv)
        return omega + d_om, v + dv, s_dyn, dv / h
    # With relaxation the force follows the lagged slip state s_dyn: a full 9×9 solve.
    # The relaxation rate |v|/σ is held at V_SLIP_MIN/σ near standstill.
    sigma = relax["sigma_m"]
    jac = np.zeros((9, 9))
    idx = np.arange(4)
    rate = max(abs(v), V_SLIP_MIN) / sigma
    f_s = rate * (s - s_dyn)
    jac[idx, 5 + idx] = -r * fz * dmu / J
    jac[4, 5 + idx] = fz * dmu / m
    jac[5 + idx, idx] = rate * ds_dw
    if abs(v) >= V_SLIP_MIN:
        jac[5 + idx, 4] = rate * ds_dv + math.copysign(1.0, v) / sigma * (s - s_dyn)
    else:
        jac[5 + idx, 4] = rate * ds_dv
    jac[5 + idx, 5 + idx] = -rate
    if rr_w is not None:
        jac[idx, idx] = rr_w
    if rr_v is not None:
        jac[4, 4] = rr_v
    f = np.concatenate([f_om, [f_v], f_s])
    dz = np.linalg.solve(np.eye(9) - h * jac, h * f)
    return omega + dz[:4], v + dz[4], np.clip(s_dyn + dz[5:9], -1.0, 1.0), dz[4] / h
