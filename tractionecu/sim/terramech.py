"""A second tyre–soil model for the physical truth: Bekker pressure–sinkage and Janosi–Hanamoto shear.

The physical truth's default tyre–soil force (:mod:`.tyre`) is Brixius' (1987) mobility-number
equations, the basis of ASABE D497.7.  The machine-level estimator may assume D497's slip term
1 − e^{−7.5 s} as its μ(s) prior (:mod:`tractionecu.estimation.machine_curve`), so on those soils it is
measured against its own family.  The soils of this module come from terramechanics instead: the soil is
given by the parameters a bevameter measures, not by a cone index, and μ(s) follows from the shear
stress–displacement relation integrated over the contact patch.  Nothing here uses a D497 term.

Equations (per wheel, load W [N], tyre section width b [m], unloaded diameter D = 2 r0 [m])
------------------------------------------------------------------------------------------------
Contact patch of a flexible tyre on its flat portion (Wong 2008, *Theory of Ground Vehicles*, 4th ed.,
ch. 2, flexible tyre in its elastic mode: the tyre deflects and carries the load on a flat patch):

    δ = W / k_z                              tyre deflection, the truth's own stiffness (:func:`.tyre.deflection`)
    l = 2 √(D δ − δ²)                        contact length: chord of the undeformed tyre at depth δ [m]
    p = W / (b l)                            mean ground pressure on the patch [Pa]

Sinkage and compaction resistance (Bekker 1956, *Theory of Land Locomotion*; Wong 2008 ch. 2):

    p = (k_c / b + k_φ) z₀ⁿ                  pressure–sinkage relation  →  z₀ = (p / (k_c/b + k_φ))^{1/n}
    R_c = b (k_c / b + k_φ) z₀^{n+1} / (n+1) the work of making a rut of depth z₀, per unit length [N]

Tractive force (Janosi & Hanamoto 1961, Proc. 1st ISTVS Conf., Turin; Wong 2008 ch. 2 for a contact of
length l under uniform normal pressure, the shear displacement growing as j = i x from the front of the patch):

    τ(j) = (c + p tan φ) (1 − e^{−j/K})      shear stress–displacement (Janosi–Hanamoto)
    F(i) = (A c + W tan φ) [1 − K/(i l) (1 − e^{−i l/K})],   A = b l

So with T_max = c/p + tan φ and the slip scale j₀ = K/l [-]:

    T(i) = F/W = T_max f(i / j₀),   f(x) = 1 − (1 − e^{−x}) / x

f rises as x/2 at small slip and approaches 1 as 1 − 1/x: a slower, algebraic tail where D497's
exponential saturates.  The wheel load enters through the patch: a heavier wheel has a longer patch, so
its μ(s) rises more steeply (j₀ smaller) and reaches a lower T_max (c/p smaller); Brixius' load
dependence is in the amplitude instead.  ρ_s = R_c / W does not grow with slip (no slip sinkage in this
model); with the patch's p ∝ √W (δ ∝ W, l ∝ √δ) it goes with the load roughly as W^{(1−n)/(2n)}: up for n < 1, down
for n > 1.  The tyre's internal loss is the tyre's (:attr:`.tyre.TyreSpec.rho_t`), not the soil's, and is
the same as on the Brixius soils.

Soil parameters
---------------
n, k_c, k_φ, c and φ are published bevameter measurements of Canadian farm soils (Wong 2008 ch. 2 terrain-value
table, after Wong 1989, *Terramechanics and Off-Road Vehicles*): Upland sandy loam at 51 % moisture, North
Gower clayey loam at 46 %, Rubicon sandy loam at 43 %.  The values agree with an independent public
transcription of the same table (a Project Chrono SCM soil-parameter listing citing Wong 2008).  The shear
deformation modulus K is not in that table; Wong gives K ≈ 1 cm for firm sandy terrain, ≈ 2.5 cm for
loose sand and ≈ 0.6 cm for clay at maximum compaction (2008, ch. 2).  The K of each soil below is taken
from that guidance by the soil's state, before any estimator run (:data:`WONG_AGRICULTURAL`); they are
assumptions of this model, said so in the soil's ``source``.

This model's simplifications (said, not hidden): a flat patch at its mean pressure (no pressure
distribution, no rigid-wheel mode, no bulldozing, no slip sinkage, no multi-pass effect), the shear
displacement over the flat patch only.  It is a plant that is not Brixius, of the textbook kind, not a
better one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import tyre as ty

LAW_JANOSI = 3
"""Law id of the Janosi–Hanamoto slip function in :mod:`._physical_kernel` (``w[5]`` carries j₀ = K/l)."""

TRACTION_MODEL = "bekker-janosi-hanamoto"
"""Name written to ``truth.toml`` for soils of this model."""


@dataclass(frozen=True)
class BekkerSoil:
    """One soil of the physical truth given by its bevameter parameters (module doc)."""

    name: str
    n: float
    """Exponent of sinkage [-]."""
    k_c: float
    """Cohesive modulus of deformation k_c [N/m^(n+1)]."""
    k_phi: float
    """Frictional modulus of deformation k_φ [N/m^(n+2)]."""
    cohesion_pa: float
    """Cohesion c [Pa]."""
    phi_deg: float
    """Angle of internal shearing resistance φ [deg]."""
    shear_k_m: float
    """Shear deformation modulus K [m] (Janosi–Hanamoto)."""
    source: str = ""
    """Where the parameters come from (and which are assumptions)."""
    draft_factor: float = 1.0
    """Soil texture factor F_i of the implement draft (ASABE D497.7 Table 1: fine 1.0, medium ≈ 0.85, coarse ≈ 0.65)."""
    polygon: tuple[tuple[float, float], ...] = ()
    """Outline (x, y) [m]; empty = background soil."""

    law = "janosi"
    """The slip function's name (the Brixius soils' ``law`` field, for readers of both kinds)."""

    def __post_init__(self) -> None:
        ok = (self.n > 0 and self.k_c >= 0 and self.k_phi > 0 and self.cohesion_pa >= 0
              and 0 < self.phi_deg < 60 and 1e-3 <= self.shear_k_m <= 0.2)
        if not ok:
            raise ValueError(f"soil {self.name}: need n > 0, k_c >= 0, k_phi > 0, c >= 0, 0 < phi < 60 deg, "
                             f"1 mm <= K <= 0.2 m")

    def terms(self, fz: ArrayLike, width_m: float, r0_m: float, tyre: ty.TyreSpec, pressure_pa: float
              ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """(T_max, j₀, ρ_c) under wheel load ``fz`` [N]: :func:`wheel_terms`."""
        return wheel_terms(self, fz, width_m, r0_m, tyre, pressure_pa)

    def paper_mu(self, s: ArrayLike, fz: float, width_m: float, r0_m: float, tyre: ty.TyreSpec, pressure_pa: float,
                 rho_t_declared: float) -> NDArray[np.float64]:
        """μ(s) in the paper's split (as :func:`.tyre.paper_mu`): T_max f(s/j₀) + ρ_t,tyre − ρ_t,declared, s ≥ 0."""
        tmax, j0, _ = self.terms(fz, width_m, r0_m, tyre, pressure_pa)
        return tmax * janosi_shape(s, j0) + (tyre.rho_t - rho_t_declared)

    def paper_rho_s(self, s: ArrayLike, fz: float, width_m: float, r0_m: float, tyre: ty.TyreSpec, pressure_pa: float,
                    rho_t_declared: float) -> NDArray[np.float64]:
        """ρ_s in the paper's split: R_c/W + ρ_t,tyre − ρ_t,declared (independent of slip) [-]."""
        _, _, rho_c = self.terms(fz, width_m, r0_m, tyre, pressure_pa)
        return rho_c + (tyre.rho_t - rho_t_declared) + 0.0 * np.abs(np.asarray(s, dtype=float))

    def toml_lines(self) -> list[str]:
        """The soil's own parameters for ``truth.toml`` (beside its class-equivalent and sampled μ(s))."""
        return [f'traction_model = "{TRACTION_MODEL}"', f'law = "{self.law}"', f"n = {self.n!r}",
                f"k_c = {self.k_c!r}", f"k_phi = {self.k_phi!r}", f"cohesion_pa = {self.cohesion_pa!r}",
                f"phi_deg = {self.phi_deg!r}", f"shear_k_m = {self.shear_k_m!r}",
                'source = "' + self.source.replace('"', "'") + '"']


def contact_length(fz: ArrayLike, r0_m: float, tyre: ty.TyreSpec, pressure_pa: float) -> NDArray[np.float64]:
    """Flat-patch length l = 2 √(D δ − δ²) [m], δ the tyre's deflection under ``fz`` (module doc)."""
    d = 2.0 * r0_m
    delta = np.minimum(ty.deflection(np.maximum(np.asarray(fz, dtype=float), 1.0), tyre, pressure_pa), 0.5 * d)
    return 2.0 * np.sqrt(d * delta - delta * delta)


def ground_pressure(fz: ArrayLike, width_m: float, r0_m: float, tyre: ty.TyreSpec, pressure_pa: float
                    ) -> NDArray[np.float64]:
    """Mean pressure on the patch p = W/(b l) [Pa]."""
    fz = np.maximum(np.asarray(fz, dtype=float), 1.0)
    return fz / (width_m * contact_length(fz, r0_m, tyre, pressure_pa))


def sinkage(p_pa: ArrayLike, soil: BekkerSoil, width_m: float) -> NDArray[np.float64]:
    """Bekker's sinkage z₀ = (p/(k_c/b + k_φ))^{1/n} [m]."""
    k = soil.k_c / width_m + soil.k_phi
    return (np.asarray(p_pa, dtype=float) / k) ** (1.0 / soil.n)


def compaction_resistance(p_pa: ArrayLike, soil: BekkerSoil, width_m: float) -> NDArray[np.float64]:
    """R_c = b (k_c/b + k_φ) z₀^{n+1}/(n+1) [N] (Bekker; module doc)."""
    k = soil.k_c / width_m + soil.k_phi
    z = sinkage(p_pa, soil, width_m)
    return width_m * k * z ** (soil.n + 1.0) / (soil.n + 1.0)


def wheel_terms(soil: BekkerSoil, fz: ArrayLike, width_m: float, r0_m: float, tyre: ty.TyreSpec, pressure_pa: float
                ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """(T_max = c/p + tan φ, j₀ = K/l, ρ_c = R_c/W) under wheel load ``fz`` [N] (module doc)."""
    fz = np.maximum(np.asarray(fz, dtype=float), 1.0)
    l = contact_length(fz, r0_m, tyre, pressure_pa)
    p = fz / (width_m * l)
    tmax = soil.cohesion_pa / p + math.tan(math.radians(soil.phi_deg))
    j0 = soil.shear_k_m / l
    rho_c = compaction_resistance(p, soil, width_m) / fz
    return tmax, j0, rho_c


def janosi_shape(s: ArrayLike, j0: ArrayLike) -> NDArray[np.float64]:
    """f(s) = 1 − (1 − e^{−x})/x, x = |s|/j₀, odd in s (x/2 near zero) [-]."""
    s = np.asarray(s, dtype=float)
    x = np.abs(s) / np.asarray(j0, dtype=float)
    safe = np.where(x > 1e-8, x, 1.0)
    f = np.where(x > 1e-8, 1.0 + np.expm1(-safe) / safe, 0.5 * x)
    return np.sign(s) * f


def _wong(name, n, k_c_kn, k_phi_kn, c_kpa, phi_deg, k_cm, state, polygon=()):
    return BekkerSoil(name, n=n, k_c=k_c_kn * 1e3, k_phi=k_phi_kn * 1e3, cohesion_pa=c_kpa * 1e3, phi_deg=phi_deg,
                      shear_k_m=k_cm / 100.0, polygon=polygon,
                      source=(f"n, k_c, k_phi, c, phi: Wong 2008 ch. 2 terrain values ({name}); K = {k_cm} cm assumed for "
                              f"{state} (Wong 2008 ch. 2: ~1 cm firm sandy, ~2.5 cm loose)"))


WONG_AGRICULTURAL = {
    "upland-sandy-loam": lambda polygon=(): _wong("upland-sandy-loam", 1.10, 74.6, 2080.0, 3.3, 33.7, 1.0,
                                                 "a firm sandy loam", polygon),
    "north-gower-clayey-loam": lambda polygon=(): _wong("north-gower-clayey-loam", 0.73, 41.6, 2471.0, 6.1, 26.6, 1.5,
                                                       "a clayey loam between firm and loose", polygon),
    "rubicon-sandy-loam": lambda polygon=(): _wong("rubicon-sandy-loam", 0.66, 6.9, 752.0, 3.7, 29.8, 2.5,
                                                  "a loose sandy loam", polygon),
}
"""Agricultural soils of Wong's terrain-value table (bevameter data of Canadian farm soils), by name: ``factory(polygon)``."""
