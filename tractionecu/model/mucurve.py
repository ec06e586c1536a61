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

Curve shapes that are no surface class (:data:`CURVE_SHAPES`, e.g. ``d497``, the μ(s) prior of the
machine-level estimator) live in a second registry; :func:`curve_class` looks a name up in both.
"""

from __future__ import annotations

import math
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


CURVE_SHAPES: dict[str, SoilClass] = {
    c.name: c
    for c in (
        SoilClass("d497", p=1.0, alpha1=-7.5, alpha2=-7.5, a_typical=0.80, rho_s_typical=0.06,
                  source="ASABE D497.7 (Brixius 1987) gross traction ratio: slip term 1 - exp(-7.5 s); "
                         "a = 0.88 (1 - exp(-0.1 B_n)), 0.80 at B_n = 25; typical rho_s as the paper's "
                         "stubble class, so that the no-draft load split does not move with the prior"),
    )
}
"""Curve shapes a·g(s) in eq. 14 form that are not surface classes, by name: the μ(s) priors of the
machine-level estimator (:mod:`tractionecu.estimation.machine_curve`).  They are kept apart from
:data:`SOIL_CLASSES`, the registry of surface classes that the simulator writes its truth against and that
``estimator.soil_classes`` chooses from.  Look a class up by name with :func:`curve_class`, which knows both.

- ``d497``: the slip term 1 − e^{−7.5 s} of the ASABE D497.7 / Brixius (1987) gross traction ratio
  GT(s) = 0.88 (1 − e^{−0.1 B_n}) (1 − e^{−7.5 s}) + 0.04: eq. 14 with p = 1, α1 = α2 = −7.5."""

CLASS_CODES: dict[str, int] = {"stubble": 200, "grassland": 201, "tilled": 202, "road": 203, "d497": 204}
"""Fixed codes of every named curve class (:data:`SOIL_CLASSES` and :data:`CURVE_SHAPES`) for the bus's
``SoilClassIndex`` when the class is not one of the configured ``estimator.soil_classes`` (whose index,
below 200, it carries otherwise): :func:`class_index`.  A new class gets a new code; a code is never reused."""


def curve_class(name: str) -> SoilClass | None:
    """The class (eq. 14 shape p, α1, α2) of ``name``: a surface class (:data:`SOIL_CLASSES`) or a curve
    shape that is none (:data:`CURVE_SHAPES`); None for an unknown name.  Every consumer that turns an
    estimate's ``soil_class`` name into a shape looks it up here."""
    return SOIL_CLASSES.get(name) or CURVE_SHAPES.get(name)


def class_index(name: str, configured: "tuple[str, ...] | list[str]") -> int | None:
    """The bus's ``SoilClassIndex`` of the class ``name`` (DBC TECU_EstSoil): its index in ``configured``
    (``estimator.soil_classes``) when it is there, else its fixed code in :data:`CLASS_CODES` (200 + k), so
    that a receiver mapping indices below 200 through the configured classes never reads another class;
    None (not available) for a name that is neither."""
    names = list(configured)
    if name in names:
        return names.index(name)
    return CLASS_CODES.get(name)


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


# ----------------------------------------------------------------------------- identified curves
CURVE_FORMS: dict[str, tuple[str, ...]] = {
    "class": ("a",),
    "exp1": ("a", "alpha1"),
    "exp1_offset": ("c", "a", "alpha1"),
    "eq14": ("a", "p", "alpha1", "alpha2"),
}
"""Curve forms an identified μ(s) can take and the names of their parameters, in ``theta`` order:

- ``class``: a·g_class(s), the paper's path (eq. 18): p, α1, α2 fixed by the class;
- ``exp1``: a(1 − e^{α1 s}), α1 < 0 [-]: eq. 14 with p = 1 (one time constant; the slip term of
  Brixius 1987 and of Wismer & Luth 1974 has this shape, α1 = −7.5 in Brixius');
- ``exp1_offset``: c + (a − c)(1 − e^{α1 s}) for s > 0: the same with an offset μ(0⁺) = c
  (Brixius' gross traction ratio with its 0.04 term), a the asymptote;

Parameters that are eq. 14's carry its names (a, p, alpha1, alpha2), so that a consumer that
knows eq. 14 reads every form but ``exp1_offset`` (whose ``c`` it does not know).
- ``eq14``: a(1 − p e^{α1 s} − (1−p) e^{α2 s}), α1 < α2 < 0, 0 ≤ p ≤ 1: paper eq. 14 with its
  shape free.
"""


@dataclass(frozen=True)
class MuCurve:
    """An identified adhesion–slip curve μ(s): callable, with its parameters and their covariance.

    ``curve(s)`` (or :meth:`mu`) gives μ [-] for slip s [-] (arrays broadcast), odd in s like
    :func:`mu_curve`.  ``theta`` holds the parameters named by ``names`` (see
    :data:`CURVE_FORMS`); ``cov`` is their covariance (k × k, NaN when unknown), from the fit's
    Jacobian and its residual scatter.  :meth:`jac` is ∂μ/∂θ and :meth:`mu_sigma` the standard
    error of μ(s) by the delta method, so that a quantity derived from the curve (traction
    efficiency, the optimal slip s*) can carry an interval: var f = ∇f C ∇fᵀ.

    The eq. 14 parameters of any form are :attr:`a`, :attr:`p`, :attr:`alpha1`, :attr:`alpha2`
    (``exp1`` is eq. 14 with p = 1 and α2 = α1; ``exp1_offset`` has no eq. 14 form: p and α2 are
    NaN).
    """

    form: str
    """One of :data:`CURVE_FORMS`."""
    theta: tuple[float, ...]
    """Parameters in the order of :attr:`names`."""
    cov: NDArray[np.float64]
    """Covariance of ``theta`` (k × k) in squared parameter units; NaN when unknown."""
    path: str
    """How it was identified: ``"class:<name>"`` (one parameter a, paper eq. 18) or ``"shape:<form>"``."""
    soil_class: SoilClass | None = None
    """The class supplying p, α1, α2 (form ``class`` only)."""
    s_range: tuple[float, float] = (math.nan, math.nan)
    """Slip range [-] of the data the curve rests on: the bin mean slips it was fitted to on the shape path,
    those of the soil's binned pairs on the class path (NaN when not known).  Outside it the curve is an
    extrapolation (:meth:`extrapolated`): the form's (or the class's) shape, not a measurement."""
    load_q: float = 0.0
    """Load sensitivity q of the curve's amplitude [-]: μ(s; F_z) = (1 + q (F_z/F_z,ref − 1)) μ(s)
    (the load influence on the friction coefficient of Pacejka 2006, eq. 4.E13, p_Dx2; q < 0: the
    heavier wheel grips less, as Brixius' mobility number B_n ∝ 1/F_z says for soil).  0: one curve
    for every load (the paper's model)."""
    load_q_sigma: float = math.nan
    """Standard error of :attr:`load_q` [-] (NaN when q was not identified)."""
    fz_ref_n: float = math.nan
    """Reference wheel load F_z,ref [N] at which ``theta`` describes the curve (the static mean wheel
    load m g/4 of the machine); NaN: no load dependence identified."""

    def __post_init__(self) -> None:
        if self.form not in CURVE_FORMS:
            raise ValueError(f"unknown curve form {self.form!r} (known: {', '.join(CURVE_FORMS)})")
        if len(self.theta) != len(CURVE_FORMS[self.form]):
            raise ValueError(f"form {self.form}: {len(CURVE_FORMS[self.form])} parameters, got {len(self.theta)}")
        if self.form == "class" and self.soil_class is None:
            raise ValueError("form 'class' needs its soil_class")

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_class(cls, soil_class: SoilClass, a: float, var_a: float = math.nan) -> "MuCurve":
        """The paper's one-parameter curve a·g_class(s) with var(a) [-²]."""
        return cls("class", (float(a),), np.array([[float(var_a)]]), f"class:{soil_class.name}", soil_class)

    # ------------------------------------------------------------------ parameters
    @property
    def names(self) -> tuple[str, ...]:
        """Names of ``theta``."""
        return CURVE_FORMS[self.form]

    @property
    def params(self) -> dict[str, float]:
        """{name: value} of ``theta``."""
        return dict(zip(self.names, self.theta))

    @property
    def a(self) -> float:
        """Asymptotic adhesion a = μ(s → ∞) [-]."""
        return self.theta[1] if self.form == "exp1_offset" else self.theta[0]

    @property
    def p(self) -> float:
        """Eq. 14 weight p [-] (NaN where the form has none)."""
        return {"class": lambda: self.soil_class.p, "exp1": lambda: 1.0,  # type: ignore[union-attr]
                "eq14": lambda: self.theta[1]}.get(self.form, lambda: math.nan)()

    @property
    def alpha1(self) -> float:
        """Eq. 14 exponent α1 [-] (NaN where the form has none)."""
        return {"class": lambda: self.soil_class.alpha1, "exp1": lambda: self.theta[1],  # type: ignore[union-attr]
                "exp1_offset": lambda: self.theta[2], "eq14": lambda: self.theta[2]}[self.form]()

    @property
    def alpha2(self) -> float:
        """Eq. 14 exponent α2 [-] (NaN where the form has none)."""
        return {"class": lambda: self.soil_class.alpha2, "exp1": lambda: self.theta[1],  # type: ignore[union-attr]
                "eq14": lambda: self.theta[3]}.get(self.form, lambda: math.nan)()

    @property
    def sigma_a(self) -> float:
        """Standard error of :attr:`a` [-] (NaN when unknown)."""
        return self.sigma["a"]

    @property
    def sigma(self) -> dict[str, float]:
        """{name: standard error} of ``theta`` (NaN when unknown)."""
        d = np.diag(np.asarray(self.cov, dtype=float)) if np.size(self.cov) else np.full(len(self.theta), np.nan)
        return {n: float(math.sqrt(v)) if v >= 0 else math.nan for n, v in zip(self.names, d)}

    # ------------------------------------------------------------------ evaluation
    def eval_theta(self, theta: ArrayLike, s: ArrayLike) -> NDArray[np.float64]:
        """μ(s) [-] of this form for parameters ``theta`` (odd in s)."""
        th = np.asarray(theta, dtype=float)
        s = np.asarray(s, dtype=float)
        sa = np.abs(s)
        if self.form == "class":
            return th[0] * self.soil_class.g(s)  # type: ignore[union-attr]
        if self.form == "exp1":
            val = th[0] * -np.expm1(th[1] * sa)
        elif self.form == "exp1_offset":
            val = np.where(sa > 0, th[0] + (th[1] - th[0]) * -np.expm1(th[2] * sa), 0.0)
        else:
            a, p, a1, a2 = th
            val = a * (1.0 - p * np.exp(a1 * sa) - (1.0 - p) * np.exp(a2 * sa))
        return np.sign(s) * val

    @property
    def load_aware(self) -> bool:
        """True when the curve carries an identified load dependence (q ≠ 0 at a known F_z,ref)."""
        return self.load_q != 0.0 and self.fz_ref_n == self.fz_ref_n

    def load_factor(self, fz: ArrayLike) -> NDArray[np.float64]:
        """1 + q (F_z/F_z,ref − 1) for wheel loads F_z [N] (1 where no load dependence is known)."""
        fz = np.asarray(fz, dtype=float)
        if not self.load_aware:
            return np.ones_like(fz)
        return 1.0 + self.load_q * (fz / self.fz_ref_n - 1.0)

    def mu(self, s: ArrayLike, fz: ArrayLike | None = None) -> NDArray[np.float64]:
        """μ(s) [-] at the reference load, or at the wheel load ``fz`` [N] (broadcast with s)."""
        val = self.eval_theta(self.theta, s)
        return val if fz is None else val * self.load_factor(fz)

    __call__ = mu

    def g(self, s: ArrayLike) -> NDArray[np.float64]:
        """Normalised curve μ(s)/a [-]."""
        return self.mu(s) / self.a

    def dmu_ds(self, s: ArrayLike) -> NDArray[np.float64]:
        """dμ/ds [-] (even in s; at s = 0 the right derivative)."""
        sa = np.abs(np.asarray(s, dtype=float))
        th = self.theta
        if self.form == "class":
            return th[0] * self.soil_class.dg(sa)  # type: ignore[union-attr]
        if self.form == "exp1":
            return -th[0] * th[1] * np.exp(th[1] * sa)
        if self.form == "exp1_offset":
            return -(th[1] - th[0]) * th[2] * np.exp(th[2] * sa)
        a, p, a1, a2 = th
        return -a * (p * a1 * np.exp(a1 * sa) + (1.0 - p) * a2 * np.exp(a2 * sa))

    def jac(self, s: ArrayLike) -> NDArray[np.float64]:
        """∂μ(s)/∂θ, shape s.shape + (k,) (central differences)."""
        s = np.asarray(s, dtype=float)
        th = np.asarray(self.theta, dtype=float)
        out = np.empty(s.shape + (th.size,))
        for j in range(th.size):
            h = 1e-6 * max(abs(th[j]), 1e-3)
            tp, tm = th.copy(), th.copy()
            tp[j] += h
            tm[j] -= h
            out[..., j] = (self.eval_theta(tp, s) - self.eval_theta(tm, s)) / (2 * h)
        return out

    def extrapolated(self, s: ArrayLike) -> NDArray[np.bool_]:
        """Where |s| lies outside :attr:`s_range` (True everywhere when the range is not known)."""
        x = np.abs(np.asarray(s, dtype=float))
        lo, hi = self.s_range
        if not (lo == lo and hi == hi):
            return np.ones(x.shape, dtype=bool)
        return (x < lo) | (x > hi)

    def mu_sigma(self, s: ArrayLike) -> NDArray[np.float64]:
        """Standard error of μ(s) [-] from ``cov`` (delta method; NaN when ``cov`` is unknown)."""
        J = self.jac(s)
        C = np.asarray(self.cov, dtype=float)
        return np.sqrt(np.maximum(np.einsum("...i,ij,...j->...", J, C, J), 0.0))
