"""Tyre–soil force of the physical truth model (independent of the filter's μ(s) family).

Traction law: Brixius (1987) mobility-number equations, as ASABE D497.7
gives them for the traction of wheeled tractors:

    B_n = (CI b d / W) · (1 + 5 δ/h) / (1 + 3 b/d)                  mobility number [-]
    GT  = 0.88 (1 − e^{−0.1 B_n}) (1 − e^{−7.5 s}) + 0.04          gross traction ratio  [-]
    MR  = 1/B_n + 0.04 + 0.5 s / √B_n                              motion resistance ratio [-]
    NT  = GT − MR                                                  net traction ratio [-]

with CI the cone index of the soil [Pa], b the tyre section width, d the
unloaded diameter, h the section height, δ the tyre deflection [m] and W
the wheel load [N].  GT is the wheel torque over (r W); MR the force that
the wheel loses to deformation.  The constant 0.04 appears in both: it is
the tyre's internal (hysteresis) loss, which consumes torque but never
reaches the body.  The traction term depends on the wheel load through B_n,
so the same soil gives a different μ(s) under a front and a rear wheel, and
ρ_s grows with slip: both differ from the filter's one-curve-per-soil,
constant-ρ_s model.

Soils whose μ(s) is none of the filter's classes (:mod:`tractionecu.model.mucurve`)
replace Brixius' slip function 1 − e^{−7.5 s} (``law``):

* ``"brixius"``: 1 − e^{−7.5 s} (Brixius 1987);
* ``"peaked"``: a wet, plastic clay whose pull falls after a peak near
  s ≈ 0.2: the sine–arctangent shape of the Magic Formula (Pacejka 2006) without its curvature term, sin(C atan(B s)), C = 1.5, B
  from the peak slip, so that the pull at s = 0.5 is ≈ 10 % below the peak;
* ``"sigmoid"``: loose sand / freshly tilled soil where the lugs must sink
  before the soil shears: a Weibull rise 1 − exp(−(s/s0)^k), k = 1.6, whose
  slope at s = 0 is zero (no exponential sum has that).

Transient force build-up: the force follows the kinematic slip through a
first-order relaxation length L_r [m] (Pacejka 2006, Tire and Vehicle
Dynamics, transient slip), of the order of half a tyre radius to a radius
(0.3–1 m) for large agricultural tyres:

    dσ_f/dt = (max(|v_w|, V_RELAX_MIN) / L_r) (σ − σ_f),   L_r = F_z T_max f'(σ_f) / c_x

The relaxation length is the slip stiffness over the carcass' longitudinal
stiffness c_x (Pacejka 2006): 0.5 m at zero slip under a 15 kN
load on firm soil, shorter at working slip where μ(s) flattens, which damps
the wheel–tyre oscillation as real tyres do.

Rolling radius: the effective rolling radius of a radial tyre lies between
the unloaded and the static loaded radius, r_e ≈ r0 − δ/3 (TMeasy, Rill 2011,
"Road Vehicle Dynamics"), with the static deflection δ = W/k_z
from a vertical stiffness that grows linearly with inflation pressure
(Wong 2008, "Theory of Ground Vehicles", chapter 1).  356 kN/m for a
540/65R34 at 1.6 bar is an assumption of this model (deflection ≈ 5 cm at
18 kN, about 1/7 of the section height).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

LAWS = ("brixius", "peaked", "sigmoid")
LAW_ID = {name: i for i, name in enumerate(LAWS)}

GT_INTERNAL = 0.04
"""Brixius' constant term of GT and MR: the tyre's internal loss ratio [-]."""


@dataclass(frozen=True)
class PhysSoil:
    """One soil of the physical truth model, given by what a soil survey measures."""

    name: str
    cone_index_pa: float
    """Cone index CI [Pa] (ASABE S313: 30° cone, 323 mm² base). Firm stubble 1.2–2 MPa,
    tilled 0.6–1 MPa, soft/wet 0.3–0.6 MPa (ASABE D497.7 gives B_n ≈ 50 firm, 30 tilled, 20 soft)."""
    law: str = "brixius"
    """Slip function: ``brixius``, ``peaked`` or ``sigmoid`` (module doc)."""
    s_shape: float = 0.2
    """Peak slip (``peaked``) or scale slip s0 (``sigmoid``) [-]."""
    draft_factor: float = 1.0
    """Soil texture factor F_i of the implement draft (ASABE D497.7 Table 1: fine 1.0, medium ≈ 0.85, coarse ≈ 0.65)."""
    polygon: tuple[tuple[float, float], ...] = ()
    """Outline (x, y) [m]; empty = background soil."""

    def __post_init__(self) -> None:
        if self.law not in LAW_ID:
            raise ValueError(f"soil {self.name}: law {self.law!r} (known: {', '.join(LAWS)})")
        if not (self.cone_index_pa > 0 and 0.01 < self.s_shape < 1.0):
            raise ValueError(f"soil {self.name}: cone index > 0 Pa and 0.01 < s_shape < 1")


@dataclass(frozen=True)
class TyreSpec:
    """Tyre of the physical model (a 540/65R34-class radial by default)."""

    k_z_carcass_npm: float = 1.0e5
    """Vertical stiffness of the carcass at zero inflation [N/m]."""
    k_z_per_pa: float = 1.6
    """Vertical stiffness per Pa of inflation pressure [N/m/Pa] (1.6 bar gives 356 kN/m)."""
    aspect_ratio: float = 0.65
    """Section height / width h/b [-] (the "65" of 540/65R34)."""
    carcass_stiffness_npm: float = 2.0e5
    """Longitudinal carcass stiffness c_x [N/m]: the relaxation length is L_r = C_Fκ / c_x (Pacejka 2006), 0.5 m at zero slip under a 15 kN wheel load on firm soil, shorter where μ(s) flattens."""
    rho_t: float = GT_INTERNAL
    """Internal (hysteresis) loss ratio of the tyre [-]: Brixius' 0.04."""


def stiffness(tyre: TyreSpec, pressure_pa: float) -> float:
    """Vertical tyre stiffness k_z [N/m]."""
    return tyre.k_z_carcass_npm + tyre.k_z_per_pa * pressure_pa


def deflection(fz: ArrayLike, tyre: TyreSpec, pressure_pa: float) -> NDArray[np.float64]:
    """Static tyre deflection δ = W/k_z [m]."""
    return np.asarray(fz, dtype=float) / stiffness(tyre, pressure_pa)


def rolling_radius(fz: ArrayLike, r0: float, tyre: TyreSpec, pressure_pa: float) -> NDArray[np.float64]:
    """Effective rolling radius r_e = r0 − δ/3 [m] (TMeasy, module doc)."""
    return r0 - deflection(fz, tyre, pressure_pa) / 3.0


def mobility_number(ci_pa: ArrayLike, fz: ArrayLike, width_m: float, r0_m: float, tyre: TyreSpec,
                    pressure_pa: float) -> NDArray[np.float64]:
    """Brixius mobility number B_n [-] (module doc); W = fz [N], d = 2 r0."""
    fz = np.maximum(np.asarray(fz, dtype=float), 1.0)
    d = 2.0 * r0_m
    h = tyre.aspect_ratio * width_m
    delta = deflection(fz, tyre, pressure_pa)
    return (np.asarray(ci_pa, dtype=float) * width_m * d / fz) * (1.0 + 5.0 * delta / h) / (1.0 + 3.0 * width_m / d)


def gross_traction_ratio(s: ArrayLike, bn: ArrayLike) -> NDArray[np.float64]:
    """Brixius GT(s) for s ≥ 0 [-]."""
    s = np.asarray(s, dtype=float)
    return 0.88 * (1.0 - np.exp(-0.1 * np.asarray(bn))) * (1.0 - np.exp(-7.5 * s)) + GT_INTERNAL


def motion_resistance_ratio(s: ArrayLike, bn: ArrayLike) -> NDArray[np.float64]:
    """Brixius MR(s) for s ≥ 0 [-]."""
    bn = np.asarray(bn, dtype=float)
    return 1.0 / bn + GT_INTERNAL + 0.5 * np.asarray(s, dtype=float) / np.sqrt(bn)


def traction_max(bn: ArrayLike) -> NDArray[np.float64]:
    """Amplitude of the soil's traction term 0.88 (1 − e^{−0.1 B_n}) [-]."""
    return 0.88 * (1.0 - np.exp(-0.1 * np.asarray(bn, dtype=float)))


PEAK_C = 1.5
SIGMOID_K = 1.6


def shape(s: ArrayLike, law: int, s_shape: float) -> NDArray[np.float64]:
    """Normalised slip function f(s), odd in s, f → ±1 (brixius, sigmoid) or peak 1 (peaked) [-]."""
    s = np.asarray(s, dtype=float)
    sa = np.abs(s)
    if law == 0:
        f = 1.0 - np.exp(-7.5 * sa)
    elif law == 1:
        b = math.tan(math.pi / (2.0 * PEAK_C)) / s_shape
        f = np.sin(PEAK_C * np.arctan(b * sa))
    else:
        f = 1.0 - np.exp(-(sa / s_shape) ** SIGMOID_K)
    return np.sign(s) * f


def soil_terms(soil: PhysSoil, fz: ArrayLike, width_m: float, r0_m: float, tyre: TyreSpec,
               pressure_pa: float) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """(traction amplitude T_max, soil resistance 1/B_n, slip-resistance slope 0.5/√B_n) under load fz."""
    bn = mobility_number(soil.cone_index_pa, fz, width_m, r0_m, tyre, pressure_pa)
    return traction_max(bn), 1.0 / bn, 0.5 / np.sqrt(bn)


def paper_mu(s: ArrayLike, soil: PhysSoil, fz: float, width_m: float, r0_m: float, tyre: TyreSpec,
             pressure_pa: float, rho_t_declared: float) -> NDArray[np.float64]:
    """μ(s) in the paper's split (torque = r F_z (μ + ρ_t) with the machine's declared ρ_t), s ≥ 0.

    μ = T_max f(s) + (ρ_t,tyre − ρ_t,declared): the truth's μ is what the wheel torque shows after the
    declared tyre loss is taken off, so it is observable from torque (module doc of
    :mod:`tractionecu.sim.physical`).
    """
    if not isinstance(soil, PhysSoil):   # a soil of another tyre–soil model (e.g. terramech.BekkerSoil)
        return soil.paper_mu(s, fz, width_m, r0_m, tyre, pressure_pa, rho_t_declared)
    tmax, _, _ = soil_terms(soil, fz, width_m, r0_m, tyre, pressure_pa)
    return tmax * shape(s, LAW_ID[soil.law], soil.s_shape) + (tyre.rho_t - rho_t_declared)


def paper_rho_s(s: ArrayLike, soil: PhysSoil, fz: float, width_m: float, r0_m: float, tyre: TyreSpec,
                pressure_pa: float, rho_t_declared: float) -> NDArray[np.float64]:
    """ρ_s(s) in the paper's split: MR − ρ_t,declared = 1/B_n + 0.5 s/√B_n + (ρ_t,tyre − ρ_t,declared) [-]."""
    if not isinstance(soil, PhysSoil):   # a soil of another tyre–soil model (e.g. terramech.BekkerSoil)
        return soil.paper_rho_s(s, fz, width_m, r0_m, tyre, pressure_pa, rho_t_declared)
    _, inv_bn, slope = soil_terms(soil, fz, width_m, r0_m, tyre, pressure_pa)
    return inv_bn + slope * np.abs(np.asarray(s, dtype=float)) + (tyre.rho_t - rho_t_declared)
