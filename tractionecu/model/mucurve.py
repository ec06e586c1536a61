"""Adhesion–slip characteristic μ(s) and surface classes (paper eq. 14, section 3.2).

μ(s) = a − p·a·e^{α1 s} − a(1−p)·e^{α2 s}  =  a·g(s),
g(s) = 1 − p·e^{α1 s} − (1−p)·e^{α2 s},

with α1, α2 < 0 so that μ(0) = 0 and μ → a as s → 1.  For braking (s < 0) the
curve is extended as an odd function, μ(−s) = −μ(s).

Within one surface class p, α1, α2 are fixed and only ``a`` varies (paper
section 3.2, Fig. 5); ``a`` is then solved from one estimated (μ, s) pair:
a = μ / g(s).  Near s = 0, g(s) → 0 and that division amplifies the slip
error: δa/a = δμ/μ ⊕ (g'(s)/g(s))·δs.  :func:`solve_a` reports such points.

Surface classes
---------------
The shapes are chosen so that the classes reproduce published tractive
coefficient ranges; the typical ``a`` is the asymptotic gross traction ratio.

- ``stubble``: the paper's reference class.  Two time constants: a quick rise
  from tyre tread deflection (α1 = −25) and the slower soil-shear rise
  (α2 = −5); μ(0.10) ≈ 0.68 a, μ(0.20) ≈ 0.83 a.  Typical a = 0.75: gross
  traction ratio 0.5–0.6 at 10–15 % slip on firm stubble (Schreiber & Kutzbach
  2008, Fig. 3; Brixius 1987 with mobility number B_n ≈ 50).
- ``grassland``: as stubble but softer tread-soil coupling (α1 = −20,
  α2 = −4, p = 0.5), typical a = 0.70 (Battiato & Diserens 2017: grass/meadow
  traction ratios slightly under stubble).
- ``tilled``: loose, cultivated soil; shear develops slowly (p = 0.35,
  α1 = −18, α2 = −3.5), typical a = 0.60 (ASABE D497.7 Fig. 2: tilled soil,
  B_n ≈ 30).
- ``road``: firm surface (concrete/asphalt); the curve saturates within a few
  per cent slip (p = 0.8, α1 = −40, α2 = −12), typical a = 0.90 (Pacejka 2006,
  ch. 1, dry road peak ≈ 0.9–1.0 for agricultural tyres, which are lower than
  car tyres).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray


@dataclass(frozen=True)
class SoilClass:
    """Shape parameters of one surface class (paper eq. 14)."""

    name: str
    p: float
    """Weight of the first exponential [-], 0 ≤ p ≤ 1."""
    alpha1: float
    """First exponent [-], < 0."""
    alpha2: float
    """Second exponent [-], < 0."""
    a_typical: float
    """Typical asymptotic adhesion a [-]."""
    rho_s_typical: float
    """Typical soil-deformation rolling resistance ρ_s [-]."""
    source: str = ""

    def __post_init__(self) -> None:
        if not (0.0 <= self.p <= 1.0):
            raise ValueError(f"soil class {self.name}: p={self.p} outside [0, 1]")
        if self.alpha1 >= 0 or self.alpha2 >= 0:
            raise ValueError(f"soil class {self.name}: α1, α2 must be negative")

    def g(self, s: ArrayLike) -> NDArray[np.float64]:
        """Normalised curve g(s) = μ(s)/a, odd in s [-]."""
        s = np.asarray(s, dtype=float)
        sa = np.abs(s)
        val = 1.0 - self.p * np.exp(self.alpha1 * sa) - (1.0 - self.p) * np.exp(self.alpha2 * sa)
        return np.sign(s) * val

    def dg(self, s: ArrayLike) -> NDArray[np.float64]:
        """Derivative dg/ds (even in s) [-]."""
        sa = np.abs(np.asarray(s, dtype=float))
        return -self.p * self.alpha1 * np.exp(self.alpha1 * sa) - (1 - self.p) * self.alpha2 * np.exp(self.alpha2 * sa)

    def mu(self, s: ArrayLike, a: ArrayLike) -> NDArray[np.float64]:
        """μ(s) = a·g(s) [-]."""
        return np.asarray(a, dtype=float) * self.g(s)


SOIL_CLASSES: dict[str, SoilClass] = {
    c.name: c
    for c in (
        SoilClass("stubble", p=0.55, alpha1=-25.0, alpha2=-5.0, a_typical=0.75, rho_s_typical=0.06,
                  source="Schreiber & Kutzbach 2008; Brixius 1987 (B_n≈50)"),
        SoilClass("grassland", p=0.50, alpha1=-20.0, alpha2=-4.0, a_typical=0.70, rho_s_typical=0.05,
                  source="Battiato & Diserens 2017"),
        SoilClass("tilled", p=0.35, alpha1=-18.0, alpha2=-3.5, a_typical=0.60, rho_s_typical=0.12,
                  source="ASABE D497.7 (tilled, B_n≈30)"),
        SoilClass("road", p=0.80, alpha1=-40.0, alpha2=-12.0, a_typical=0.90, rho_s_typical=0.005,
                  source="Pacejka 2006 ch. 1"),
    )
}


def mu_curve(s: ArrayLike, a: ArrayLike, p: float, alpha1: float, alpha2: float) -> NDArray[np.float64]:
    """Paper eq. 14 for explicit parameters (odd extension for s < 0)."""
    s = np.asarray(s, dtype=float)
    sa = np.abs(s)
    return np.sign(s) * np.asarray(a, dtype=float) * (1.0 - p * np.exp(alpha1 * sa) - (1.0 - p) * np.exp(alpha2 * sa))


@dataclass(frozen=True)
class ASolution:
    """Result of solving ``a`` from one (μ, s) pair."""

    a: float
    """Solved a [-] (NaN when ill-conditioned)."""
    rel_err: float
    """Propagated relative standard error of a [-]."""
    ok: bool
    """False when the point is ill-conditioned (low slip) or inconsistent."""
    reason: str = ""


def solve_a(mu: float, s: float, cls: SoilClass, *, sigma_mu: float = 0.01, sigma_s: float = 0.003,
            max_rel_err: float = 0.15, min_slip: float = 0.01) -> ASolution:
    """Solve a = μ/g(s) for one pair and say whether the result can be trusted.

    Parameters
    ----------
    mu, s : adhesion [-] and slip [-] of one wheel.
    cls : the surface class supplying p, α1, α2.
    sigma_mu, sigma_s : standard errors of μ and s used to propagate the error.
    max_rel_err : points whose propagated relative error exceeds this are
        reported ill-conditioned.
    min_slip : |s| below this is ill-conditioned outright (g → 0).

    The relative error is δa/a = sqrt((δμ/μ)² + (g'(s)·δs/g(s))²).
    """
    if not (np.isfinite(mu) and np.isfinite(s)):
        return ASolution(float("nan"), float("inf"), False, "non-finite input")
    if abs(s) < min_slip:
        return ASolution(float("nan"), float("inf"), False, f"|s|={abs(s):.4f} < {min_slip}: ill-conditioned")
    g = float(cls.g(s))
    if abs(g) < 1e-9 or abs(mu) < 1e-6:
        return ASolution(float("nan"), float("inf"), False, "denominator or μ ≈ 0")
    a = mu / g
    if a <= 0:
        return ASolution(float("nan"), float("inf"), False, "μ and s of opposite sign")
    rel = float(np.hypot(sigma_mu / abs(mu), float(cls.dg(s)) * sigma_s / abs(g)))
    if rel > max_rel_err:
        return ASolution(a, rel, False, f"propagated error {rel:.2f} > {max_rel_err}: ill-conditioned")
    return ASolution(a, rel, True)


def solve_a_array(mu: ArrayLike, s: ArrayLike, cls: SoilClass, *, sigma_mu: float = 0.01, sigma_s: float = 0.003,
                  max_rel_err: float = 0.15, min_slip: float = 0.01) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Vectorised :func:`solve_a`: returns (a, rel_err, ok) arrays; a is NaN where not ok."""
    mu = np.asarray(mu, dtype=float)
    s = np.asarray(s, dtype=float)
    g = cls.g(s)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = mu / g
        rel = np.hypot(sigma_mu / np.abs(mu), cls.dg(s) * sigma_s / np.abs(g))
    ok = np.isfinite(mu) & np.isfinite(s) & (np.abs(s) >= min_slip) & (np.abs(g) > 1e-9) & (a > 0) & (rel <= max_rel_err)
    return np.where(ok, a, np.nan), rel, ok
