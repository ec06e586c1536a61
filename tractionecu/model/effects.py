"""Effect library: physics the paper's model leaves out.

Each effect is defined once here, with its formula, units and parameters.  The
simulator switches effects on in its truth model through these functions, and
the diagnosis tool proposes and fits the same definitions.  All effects are
off by default.

Identifiers (a contract): ``grade, load_transfer, gps_latency, wheel_radius,
relaxation, draft_speed, drivetrain, mass, aero``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..config import G
from ..errors import ConfigError

AIR_DENSITY = 1.2
"""Air density ρ_air [kg/m³] at 20 °C, sea level."""


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of an effect."""

    name: str
    unit: str
    default: float
    lo: float
    hi: float
    doc: str


@dataclass(frozen=True)
class EffectDef:
    """Definition of one effect: the single source of truth for sim and diagnosis."""

    name: str
    doc: str
    formula: str
    signature: str
    params: tuple[ParamSpec, ...] = field(default_factory=tuple)

    def defaults(self) -> dict[str, float]:
        return {p.name: p.default for p in self.params}


EFFECTS: dict[str, EffectDef] = {
    e.name: e
    for e in (
        EffectDef(
            "grade",
            "Field grade: the slope component of weight acts along the track.",
            "F_grade = m g sin θ,  θ = atan(dh/ds) from the terrain elevation along the track",
            "speed-equation residual follows dh/ds and flips sign between opposite passes",
            (ParamSpec("scale", "-", 1.0, 0.0, 5.0, "multiplier on the terrain relief (1 = real terrain)"),),
        ),
        EffectDef(
            "load_transfer",
            "Longitudinal load transfer from drawbar pull, acceleration and grade.",
            "ΔF_z,rear = (F_dx h_hitch + m a h_cg + m g sin θ h_cg) / L;  the front axle loses ΔF_z,rear",
            "front and rear slip residuals move in opposite directions; front axle load falls with pull",
            (ParamSpec("h_hitch_m", "m", 0.5, 0.0, 2.0, "effective hitch height"),
             ParamSpec("h_cg_m", "m", 1.0, 0.0, 3.0, "centre-of-gravity height")),
        ),
        EffectDef(
            "gps_latency",
            "GNSS speed is reported late.",
            "v_gps(t) = v(t − τ)",
            "GPS speed residual ∝ dv/dt; cross-correlation peak at lag τ",
            (ParamSpec("tau_s", "s", 0.15, 0.0, 2.0, "latency τ"),),
        ),
        EffectDef(
            "wheel_radius",
            "The true rolling radius differs from the nominal formula (tyre wear, pressure, tyre model).",
            "r_true = (1 + ε) r_d,nominal;  s_meas ≈ s + ε(1 − s)",
            "constant slip offset when net traction is zero",
            (ParamSpec("epsilon", "-", 0.02, -0.1, 0.1, "relative radius error ε"),),
        ),
        EffectDef(
            "relaxation",
            "Tyre relaxation length: the force follows slip with a first-order lag.",
            "ds_dyn/dt = (|v|/σ)(s − s_dyn),  F_h = μ(s_dyn) F_z",
            "residual during torque steps; lag grows at low speed",
            (ParamSpec("sigma_m", "m", 0.8, 0.01, 5.0, "relaxation length σ"),),
        ),
        EffectDef(
            "draft_speed",
            "Implement draft depends on speed (ASABE D497: D = F_i (A + B S + C S²) W T).",
            "F_dx = D_0 (1 + c (v² − v_ref²)),  c = C/(A + C v_ref²) in SI",
            "draft and speed residual correlate with v²",
            (ParamSpec("c_s2pm2", "s²/m²", 0.04, 0.0, 0.5, "quadratic speed coefficient c"),
             ParamSpec("v_ref_mps", "m/s", 2.5, 0.1, 10.0, "reference speed of the nominal draft")),
        ),
        EffectDef(
            "drivetrain",
            "Drivetrain efficiency and loss torque between the measured drive torque and the wheel.",
            "M_wheel = η M_d − M_loss sgn(ω)",
            "a torque-proportional error that μ's parameter a absorbs",
            (ParamSpec("eta", "-", 0.93, 0.5, 1.0, "efficiency η"),
             ParamSpec("loss_nm", "N·m", 40.0, 0.0, 2000.0, "loss torque M_loss per wheel")),
        ),
        EffectDef(
            "mass",
            "The vehicle mass differs from nominal (ballast, fuel, implement).",
            "m_true = m + Δm, distributed front/rear with share f_front",
            "speed residual ∝ dv/dt during acceleration; higher axle loads",
            (ParamSpec("delta_kg", "kg", 600.0, -3000.0, 5000.0, "mass difference Δm"),
             ParamSpec("front_share", "-", 1.0, 0.0, 1.0, "share of Δm carried by the front axle (front ballast = 1)")),
        ),
        EffectDef(
            "aero",
            "Aerodynamic drag.",
            "F_aero = ½ ρ_air C_d A v²",
            "only at transport speed (≈ 17 N at 2.5 m/s: negligible in the field)",
            (ParamSpec("cd_area_m2", "m²", 4.5, 0.0, 50.0, "drag area C_d A"),),
        ),
    )
}

EFFECT_NAMES = tuple(EFFECTS)


def parse_effect_arg(arg: str) -> tuple[str, dict[str, float]]:
    """Parse ``name`` or ``name=value`` or ``name:param=value,param=value``.

    ``name=value`` sets the effect's first parameter.
    """
    if ":" in arg:
        name, rest = arg.split(":", 1)
        items = [kv.split("=", 1) for kv in rest.split(",") if kv]
    elif "=" in arg:
        name, val = arg.split("=", 1)
        items = [[EFFECTS[name].params[0].name, val]] if name in EFFECTS else []
    else:
        name, items = arg, []
    name = name.strip()
    if name not in EFFECTS:
        raise ConfigError(f"effect {name!r}: unknown (known: {', '.join(EFFECT_NAMES)})")
    params = EFFECTS[name].defaults()
    for kv in items:
        if len(kv) != 2:
            raise ConfigError(f"effect {name}: cannot parse {arg!r}")
        k, v = kv[0].strip(), kv[1].strip()
        if k not in params:
            raise ConfigError(f"effect {name}.{k}: unknown parameter (known: {', '.join(params)})")
        try:
            params[k] = float(v)
        except ValueError as exc:
            raise ConfigError(f"effect {name}.{k}: {v!r} is not a number") from exc
    return name, validate_params(name, params)


def validate_params(name: str, params: Mapping[str, float]) -> dict[str, float]:
    """Check an effect's parameters against their ranges; ConfigError names the key."""
    out = EFFECTS[name].defaults()
    for spec in EFFECTS[name].params:
        v = float(params.get(spec.name, spec.default))
        if not np.isfinite(v) or not spec.lo <= v <= spec.hi:
            raise ConfigError(f"effect {name}.{spec.name} = {v} outside [{spec.lo}, {spec.hi}] {spec.unit}")
        out[spec.name] = v
    unknown = set(params) - set(out)
    if unknown:
        raise ConfigError(f"effect {name}.{sorted(unknown)[0]}: unknown parameter")
    return out


# ---- the physics, one pure function per effect ---------------------------------

def grade_force(mass_kg: ArrayLike, theta_rad: ArrayLike) -> NDArray[np.float64]:
    """grade: F = m g sin θ [N], resisting when climbing (θ > 0)."""
    return np.asarray(mass_kg, dtype=float) * G * np.sin(np.asarray(theta_rad, dtype=float))


def load_transfer_rear(fdx: ArrayLike, accel: ArrayLike, theta_rad: ArrayLike, mass_kg: float,
                       wheelbase_m: float, h_hitch_m: float, h_cg_m: float) -> NDArray[np.float64]:
    """load_transfer: ΔF_z,rear [N] = (F_dx h_hitch + m a h_cg + m g sin θ h_cg)/L."""
    return (np.asarray(fdx, dtype=float) * h_hitch_m
            + mass_kg * np.asarray(accel, dtype=float) * h_cg_m
            + mass_kg * G * np.sin(np.asarray(theta_rad, dtype=float)) * h_cg_m) / wheelbase_m


def draft_speed_factor(v: ArrayLike, c_s2pm2: float, v_ref_mps: float) -> NDArray[np.float64]:
    """draft_speed: multiplier on nominal draft, 1 + c (v² − v_ref²) [-] (ASABE D497 quadratic form)."""
    v = np.asarray(v, dtype=float)
    return 1.0 + c_s2pm2 * (v * v - v_ref_mps * v_ref_mps)


def drivetrain_torque(md: ArrayLike, omega: ArrayLike, eta: float, loss_nm: float) -> NDArray[np.float64]:
    """drivetrain: M_wheel = η M_d − M_loss sgn(ω) [N·m]."""
    return eta * np.asarray(md, dtype=float) - loss_nm * np.sign(np.asarray(omega, dtype=float))


def aero_force(v: ArrayLike, cd_area_m2: float) -> NDArray[np.float64]:
    """aero: F = ½ ρ_air C_d A v |v| [N]."""
    v = np.asarray(v, dtype=float)
    return 0.5 * AIR_DENSITY * cd_area_m2 * v * np.abs(v)


def relaxation_rate(s_ss: ArrayLike, s_dyn: ArrayLike, v: ArrayLike, sigma_m: float) -> NDArray[np.float64]:
    """relaxation: ds_dyn/dt = (|v|/σ)(s_ss − s_dyn) [1/s]."""
    return np.abs(np.asarray(v, dtype=float)) / sigma_m * (np.asarray(s_ss, dtype=float) - np.asarray(s_dyn, dtype=float))


def delayed(t: ArrayLike, x: ArrayLike, tau_s: float) -> NDArray[np.float64]:
    """gps_latency: x(t − τ) by linear interpolation on the sample times t [s]."""
    t = np.asarray(t, dtype=float)
    return np.interp(t - tau_s, t, np.asarray(x, dtype=float))


def wheel_radius_true(r_nominal: ArrayLike, epsilon: float) -> NDArray[np.float64]:
    """wheel_radius: r_true = (1 + ε) r_nominal [m]."""
    return (1.0 + epsilon) * np.asarray(r_nominal, dtype=float)


# ---- sensor faults and engine-level terms -----------------------------------------
# Faults of the measuring chain, not of the machine's physics: the simulator never switches them
# on (its truth stays physical); tests and the diagnosis suite inject them into a written
# recording (``tractionecu.evaluation.faults``), and diagnosis fits them like the effects above.

TYRE_DEFLECTION_RATIO = 0.05
"""Static tyre deflection over unloaded radius at the rated pressure, δ_0/r_0 [-] (agricultural
radial tyres at rated load and pressure deflect about 4–6 % of their radius; ETRTO load tables)."""
TYRE_DEFLECTION_RATIO_RANGE = (0.04, 0.06)
"""The range of δ_0/r_0 behind :data:`TYRE_DEFLECTION_RATIO` (its 4–6 %)."""
TYRE_ROLLING_RADIUS_SHARE = 1.0 / 3.0
"""Share of the static deflection by which the effective rolling radius falls, r_e ≈ r_0 − δ/3 [-]: a
radial's belt does not stretch, so the rolling radius lies between the unloaded and the loaded radius,
about a third of the way (Rill 2011, *Road Vehicle Dynamics*, TMeasy's dynamic rolling radius)."""
TYRE_CARCASS_SHARE = 0.2
"""Share of the vertical stiffness at the rated pressure that the carcass carries without inflation, c in
k_z(p) = k_z(p_0) (c + (1 − c) p/p_0) [-].  The stiffness of an agricultural tyre rises with inflation
pressure from a non-zero intercept, the carcass's own stiffness, which soil-compaction work states as an
equivalent pressure added to the inflation pressure (Misiewicz et al. 2016, Biosystems Engineering 147,
183–192).  The share is an assumption of this library, not a measured figure: its range
:data:`TYRE_CARCASS_SHARE_RANGE` enters the interval of a fitted pressure."""
TYRE_CARCASS_SHARE_RANGE = (0.1, 0.35)
TYRE_RR_PRESSURE_EXPONENT = 0.4
"""Exponent α of the tyre-deformation rolling resistance against inflation pressure, ρ_t ∝ p^−α
(≈ 0.4 for pneumatic tyres on firm ground; Wong, *Theory of Ground Vehicles*, ch. 1)."""

SENSOR_FAULTS: dict[str, EffectDef] = {
    e.name: e
    for e in (
        EffectDef(
            "torque_gain",
            "Drive-torque sensor gain error, per axle (strain-gauge calibration, motor-model error).",
            "M_meas = (1 + k_axle) M_true",
            "μ from the torque balance scales by 1/(1 + k): the curve parameter a absorbs it on one surface; "
            "the speed equation's force scales with torque (acceleration and pull)",
            (ParamSpec("k_front", "-", 0.05, -0.3, 0.3, "relative gain error of the front-axle torques"),
             ParamSpec("k_rear", "-", 0.05, -0.3, 0.3, "relative gain error of the rear-axle torques")),
        ),
        EffectDef(
            "torque_offset",
            "Drive-torque sensor offset, per axle (zero drift of a strain gauge).",
            "M_meas = M_true + b_axle",
            "adhesion μ offset of b/(r F_z) at zero slip; a constant force in the speed equation",
            (ParamSpec("b_front_nm", "N·m", 100.0, -2000.0, 2000.0, "offset of each front-wheel torque"),
             ParamSpec("b_rear_nm", "N·m", 100.0, -2000.0, 2000.0, "offset of each rear-wheel torque")),
        ),
        EffectDef(
            "draft_offset",
            "Draft sensor (hitch load pin) offset and linear drift.",
            "F_dx,meas = F_dx + b_0 + b_1 t",
            "the speed equation's residual force grows with time (drift) and remains with the implement lifted; "
            "a constant offset alone is a constant resistance (ρ_s)",
            (ParamSpec("b0_n", "N", 500.0, -10000.0, 10000.0, "offset b_0"),
             ParamSpec("b1_npm", "N/min", 0.0, -2000.0, 2000.0, "drift b_1 per minute")),
        ),
        EffectDef(
            "axle_load_offset",
            "Front-axle load sensor offset and linear drift.",
            "F_zf,meas = F_zf + b_0 + b_1 t",
            "front-axle residual level (and trend) without inertia; wheel loads shift between the axles",
            (ParamSpec("b0_n", "N", 1000.0, -20000.0, 20000.0, "offset b_0"),
             ParamSpec("b1_npm", "N/min", 0.0, -5000.0, 5000.0, "drift b_1 per minute")),
        ),
        EffectDef(
            "clock_skew",
            "The CAN logger's clock runs apart from GNSS time (offset and rate error).",
            "t_CAN = t_GNSS + δ_0 + κ t",
            "GNSS speed against the force-integrated speed ∝ dv/dt with a lag that grows with time; "
            "a constant δ_0 alone is the GNSS latency with the opposite sign",
            (ParamSpec("offset_s", "s", 0.1, -2.0, 2.0, "offset δ_0"),
             ParamSpec("rate_ppm", "ppm", 100.0, -5000.0, 5000.0, "rate error κ [10⁻⁶ s/s]")),
        ),
        EffectDef(
            "tyre_pressure",
            "Inflation pressure differs from the rated one: rolling radius and tyre rolling resistance change together.",
            "r = r_d (1 − (δ_0/3r_0)(1/(c + (1 − c) p/p_0) − 1)),  ρ_t = ρ_t,0 (p_0/p)^α   (δ_0/r_0 = 0.05, c = 0.2, α = 0.4)",
            "a slip offset (radius) together with a larger rolling resistance (lower pressure)",
            (ParamSpec("p_ratio", "-", 0.7, 0.3, 2.0, "pressure over the rated pressure p/p_0"),),
        ),
        EffectDef(
            "wheel_speed_hold",
            "A wheel-speed sensor drops out (reads 0) or holds its last value for a while.",
            "ω_meas,i(t) = 0 or ω_i(t_0) for t_0 ≤ t < t_0 + d",
            "one wheel's speed frozen or zero while the other three follow the ground speed",
            (ParamSpec("wheel", "-", 0.0, 0.0, 3.0, "wheel index (FL, FR, RL, RR)"),
             ParamSpec("t0_s", "s", 0.0, 0.0, 1e7, "start t_0"),
             ParamSpec("duration_s", "s", 3.0, 0.0, 1e7, "duration d")),
        ),
    )
}

ENGINE_TERMS: dict[str, EffectDef] = {
    e.name: e
    for e in (
        EffectDef(
            "zero_slip_offset",
            "Traction ratio already present at zero slip: rolling resistance, transmission losses and "
            "power to the PTO and hydraulics that the engine torque carries but the soil does not.",
            "μ_soil = μ_engine − μ_0,  μ(s) = a g(s) for the soil's share",
            "the slip–traction points cross zero slip at μ ≈ μ_0 > 0",
            (ParamSpec("mu0", "-", 0.2, -0.5, 1.0, "traction ratio at zero slip μ_0"),),
        ),
        EffectDef(
            "aux_power",
            "Auxiliary power draw (PTO, hydraulics, fan) taken from the engine before the wheels.",
            "F_h = (η T_e ω_e − P_aux)/v_w",
            "a traction-ratio offset that grows at low speed as 1/v",
            (ParamSpec("p_aux_w", "W", 10000.0, -50000.0, 200000.0, "auxiliary power P_aux"),),
        ),
        EffectDef(
            "drivetrain_efficiency",
            "Transmission efficiency between the engine and the wheels (engine-level data).",
            "F_h = η T_e ω_e / v_w",
            "scales the traction ratio like the curve parameter a: separable only with a draft or a known a",
            (ParamSpec("eta", "-", 0.88, 0.5, 1.0, "efficiency η"),),
        ),
    )
}

LIBRARY: dict[str, EffectDef] = {**EFFECTS, **SENSOR_FAULTS}
"""Everything diagnosis can name on per-wheel recordings: the physical effects and the sensor faults."""


def torque_true(md_meas: ArrayLike, gain: ArrayLike, offset_nm: ArrayLike) -> NDArray[np.float64]:
    """torque_gain / torque_offset: M_true = (M_meas − b)/(1 + k) [N·m] (per wheel, broadcast)."""
    return (np.asarray(md_meas, dtype=float) - np.asarray(offset_nm, dtype=float)) / (1.0 + np.asarray(gain, dtype=float))


def offset_drift(t_s: ArrayLike, b0: float, b1_per_min: float) -> NDArray[np.float64]:
    """draft_offset / axle_load_offset: b_0 + b_1 t (b_1 per minute, t in seconds)."""
    return b0 + b1_per_min * np.asarray(t_s, dtype=float) / 60.0


def clock_shift_s(t_s: ArrayLike, offset_s: float, rate_ppm: float) -> NDArray[np.float64]:
    """clock_skew: δ(t) = δ_0 + κ t [s] by which the CAN clock runs ahead of GNSS time."""
    return offset_s + rate_ppm * 1e-6 * np.asarray(t_s, dtype=float)


def tyre_pressure_terms(p_ratio: float, deflection_ratio: float = TYRE_DEFLECTION_RATIO,
                        carcass_share: float = TYRE_CARCASS_SHARE) -> tuple[float, float]:
    """tyre_pressure: (ε, ρ_t factor) for p/p_0 = ``p_ratio``:
    ε = −(δ_0/(3 r_0)) (1/(c + (1 − c) p/p_0) − 1)  (the deflection δ = δ_0 k_z(p_0)/k_z(p), the rolling
    radius falling by a third of it), ρ_t/ρ_t,0 = (p_0/p)^α."""
    k_rel = carcass_share + (1.0 - carcass_share) * float(p_ratio)
    eps = -deflection_ratio * TYRE_ROLLING_RADIUS_SHARE * (1.0 / k_rel - 1.0)
    return eps, (1.0 / float(p_ratio)) ** TYRE_RR_PRESSURE_EXPONENT


def tyre_pressure_from_radius(eps: float, deflection_ratio: float = TYRE_DEFLECTION_RATIO,
                              carcass_share: float = TYRE_CARCASS_SHARE) -> float:
    """The p/p_0 whose radius term (:func:`tyre_pressure_terms`) is ``eps``: inf where no finite pressure gives
    it (a radius gain of a third of the rated deflection or more), below 0 where none does (a radius loss beyond
    the uninflated carcass's deflection)."""
    den = 1.0 - float(eps) / (deflection_ratio * TYRE_ROLLING_RADIUS_SHARE)
    if not den > 0.0:
        return math.inf
    return (1.0 / den - carcass_share) / (1.0 - carcass_share)


def tyre_pressure_law_range(p_lo: float, p_hi: float) -> tuple[float, float]:
    """The interval [p_lo, p_hi] of p/p_0 fitted with the nominal tyre law, widened by the law's own
    uncertainty: the radius terms at its ends mapped back through every corner of
    (:data:`TYRE_DEFLECTION_RATIO_RANGE`, :data:`TYRE_CARCASS_SHARE_RANGE`).  The radius is what the data
    measure; which pressure made it depends on the tyre."""
    lo, hi = p_lo, p_hi
    for end in (p_lo, p_hi):
        eps = tyre_pressure_terms(end)[0]
        for d in TYRE_DEFLECTION_RATIO_RANGE:
            for c in TYRE_CARCASS_SHARE_RANGE:
                p = tyre_pressure_from_radius(eps, d, c)
                lo, hi = min(lo, p), max(hi, p)
    return lo, hi
