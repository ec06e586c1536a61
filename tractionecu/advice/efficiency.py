"""Traction efficiency η(s) and the optimal slip s* from the identified μ(s) curve (paper eq. 7).

Per wheel (paper eqs. 5, 7, ``model/vehicle.py: traction_efficiency``)::

    κ = μ − ρ_s,   ρ = ρ_s + ρ_t,   η = κ/(κ + ρ)·(1 − s) = (μ − ρ_s)/(μ + ρ_t)·(1 − s)

the drawbar power over the wheel power: the wheel's torque pushes
(μ + ρ_t)·F_z at the wheel's circumferential speed v/(1 − s); what pulls is
(μ − ρ_s)·F_z at the ground speed v.  For the machine, the wheels' powers add::

    η_machine = Σ F_z,i κ_i / Σ F_z,i (κ_i + ρ)/(1 − s_i)

With the identified curve μ(s) = a·g(s) (paper eq. 14, :mod:`~tractionecu.model.mucurve`),
η(s) is one function of slip for every wheel; it is zero where μ(s) = ρ_s and
falls again at high slip, so it has one maximum η* = η(s*) in between
(:func:`optimum`).  The pull available at s* is (μ(s*) − ρ_s)·W, W the weight
on the driven wheels.

Uncertainty.  s* and η* are functions of θ = (a, p, α1, α2, ρ_s).  Their
standard errors come from the covariance of θ by the delta method with
central differences (:func:`optimum_with_interval`); the parameters with no
covariance given are held fixed (the class shape when only ``a`` is
identified).  Without a covariance of a from the curve identification,
:func:`sigma_a_from_estimate` propagates the filter's own uncertainties: a =
μ/g(s), δa/a = √((δμ/μ)²/n + (g'(s)·δs/g(s))²), with δs = (1 − s)·δv/v from the
speed variance.  The slip error is the speed error, shared by all wheels and
correlated over seconds, so neither the number of wheels nor the curve
smoothing shrinks it: the bound is deliberately not optimistic.

"Say so instead of a number".  :class:`EfficiencyReport` carries a validity
bitfield (:data:`FLAGS`); s* and η* are given only when the curve is
identified, the operating slip has excited it (low slip, g → 0, leaves a
undetermined) and the interval of s* is narrow enough.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..model.mucurve import curve_class

G = 9.80665

CURVE_NOT_IDENTIFIED = 0x01
"""a (or the class) unknown: no curve yet."""
LOW_EXCITATION = 0x02
"""The operating slip stayed too low to pin the curve down (g(s) → 0 near s = 0)."""
INTERVAL_WIDE = 0x04
"""The interval of s* from the parameters' uncertainty is wider than allowed."""
ESTIMATE_INVALID = 0x08
"""The estimate itself is not valid (input timeout, not converged, filter lost, standstill)."""
NOT_PULLING = 0x10
"""Too slow or too little traction for a current η (η of a wheel that does not pull is meaningless)."""
NO_RHO_S = 0x20
"""The estimate is valid but holds no soil rolling resistance ρ_s: a machine without a draft sensor, where ρ_s
and the implement's draft are not separable (EstimateStatus ``DRAFT_NOT_SEPARATED``); eq. 7 needs ρ_s."""
FLAGS = {CURVE_NOT_IDENTIFIED: "curve not identified", LOW_EXCITATION: "slip too low to identify the curve",
         INTERVAL_WIDE: "optimal slip too uncertain", ESTIMATE_INVALID: "estimate not valid",
         NOT_PULLING: "not pulling", NO_RHO_S: "no rho_s without a draft sensor"}
"""Validity bits of :attr:`EfficiencyReport.flags` (also the DBC's ``EfficiencyValidity``)."""
S_STAR_BITS = CURVE_NOT_IDENTIFIED | LOW_EXCITATION | INTERVAL_WIDE | ESTIMATE_INVALID | NO_RHO_S
"""Any of these set: no s*, η* or pull at s*."""
ETA_BITS = ESTIMATE_INVALID | NOT_PULLING | NO_RHO_S
"""Any of these set: no current η."""

S_MAX = 0.6
"""Highest slip searched for the optimum [-]."""
_GRID = np.concatenate([np.linspace(0.002, 0.2, 199), np.linspace(0.2025, S_MAX, 160)])


@dataclass(frozen=True)
class CurveParams:
    """μ(s) = a·(1 − p e^{α1 s} − (1 − p) e^{α2 s}) (paper eq. 14) and the covariance of its parameters.

    ``cov`` is over :attr:`names` (a subset of ``("a", "p", "alpha1", "alpha2")``
    in that order; None: only ``sigma_a``, NaN when unknown).
    """

    a: float
    p: float
    alpha1: float
    alpha2: float
    sigma_a: float = math.nan
    cov: NDArray[np.float64] | None = None
    names: tuple[str, ...] = ("a",)
    class_name: str = ""
    theta: tuple[float, ...] | None = None
    """Parameters of a curve of another form (``model.mucurve.MuCurve``: ``names``, ``cov`` over them),
    evaluated by ``eval_theta(theta, s)``; None: eq. 14 from a, p, α1, α2."""
    eval_theta: Any = None

    def mu(self, s: ArrayLike) -> NDArray[np.float64]:
        """μ(s) [-], odd in s."""
        s = np.asarray(s, dtype=float)
        if self.eval_theta is not None:
            return np.asarray(self.eval_theta(self.theta, s), dtype=float)
        sa = np.abs(s)
        return np.sign(s) * self.a * (1.0 - self.p * np.exp(self.alpha1 * sa) - (1.0 - self.p) * np.exp(self.alpha2 * sa))

    def g(self, s: float) -> float:
        """g(s) = μ(s)/a for s ≥ 0 [-]."""
        if self.eval_theta is not None:
            return float(self.mu(s)) / self.a
        return 1.0 - self.p * math.exp(self.alpha1 * s) - (1.0 - self.p) * math.exp(self.alpha2 * s)

    def dg(self, s: float) -> float:
        """dg/ds for s ≥ 0 [-]."""
        if self.eval_theta is not None:
            h = 1e-5
            return (float(self.mu(s + h)) - float(self.mu(max(s - h, 0.0)))) / (s + h - max(s - h, 0.0)) / self.a
        return -self.p * self.alpha1 * math.exp(self.alpha1 * s) - (1.0 - self.p) * self.alpha2 * math.exp(self.alpha2 * s)

    def with_values(self, **kw: float) -> "CurveParams":
        if self.eval_theta is not None:
            th = list(self.theta or ())
            for k, v in kw.items():
                th[self.names.index(k)] = v
            return replace(self, theta=tuple(th))
        d = dict(a=self.a, p=self.p, alpha1=self.alpha1, alpha2=self.alpha2)
        d.update(kw)
        return replace(self, **d)

    def value(self, name: str) -> float:
        """A parameter's value by name."""
        if self.eval_theta is not None:
            return float((self.theta or ())[self.names.index(name)])
        return float(getattr(self, name))

    def covariance(self) -> tuple[tuple[str, ...], NDArray[np.float64]]:
        """``(names, covariance)`` of the identified parameters (a alone from ``sigma_a`` without ``cov``)."""
        if self.cov is not None:
            return self.names, np.asarray(self.cov, dtype=float)
        s = self.sigma_a if math.isfinite(self.sigma_a) else math.inf
        return ("a",), np.array([[s * s]])


def curve_of(est: Any, sigma_a: float = math.nan) -> CurveParams | None:
    """The identified curve of an estimate, None while a is unknown.

    Reads the estimate's identified curve when it carries one (``est.curve``:
    a :class:`~tractionecu.model.mucurve.MuCurve` of any form, evaluated by
    its ``eval_theta`` with ``cov`` over its ``names``; or any object with
    ``a, p, alpha1, alpha2`` and optionally ``cov`` over ``names``); else the
    estimate's class shape (:func:`~tractionecu.model.mucurve.curve_class`) with its ``a`` and
    ``sigma_a``.  A covariance not known yet (NaN) leaves σ(a) to
    :func:`sigma_a_from_estimate` when only a is identified, and makes the
    interval unknown (s* not given) for a fitted shape.
    """
    c = getattr(est, "curve", None)
    if c is not None and all(hasattr(c, k) for k in ("a", "p", "alpha1", "alpha2")):
        a = _f(c.a)
        if not (math.isfinite(a) and a > 0):
            return None
        cov = getattr(c, "cov", None)
        cov = None if cov is None else np.asarray(cov, dtype=float)
        names = tuple(getattr(c, "names", ("a", "p", "alpha1", "alpha2")))
        if cov is not None and (cov.shape != (len(names), len(names)) or not np.isfinite(cov).all()):
            cov = None                   # not known yet: σ(a) from the estimate when only a is identified
        name = str(getattr(est, "soil_class", ""))
        theta = getattr(c, "theta", None)
        if theta is not None and hasattr(c, "eval_theta"):      # model.mucurve.MuCurve (any form)
            if cov is None and names != ("a",):
                cov = np.full((len(names), len(names)), np.inf)   # a shape without its covariance: unknown
            return CurveParams(a, _f(c.p), _f(c.alpha1), _f(c.alpha2), sigma_a, cov, names,
                               str(getattr(c, "path", name)).split(":")[-1], tuple(float(x) for x in theta),
                               c.eval_theta)
        return CurveParams(a, _f(c.p), _f(c.alpha1), _f(c.alpha2), _f(getattr(c, "sigma_a", sigma_a)), cov,
                           names, name)
    a = _f(getattr(est, "a", math.nan))
    cls = curve_class(str(getattr(est, "soil_class", "")))
    if cls is None or not (math.isfinite(a) and a > 0):
        return None
    return CurveParams(a, cls.p, cls.alpha1, cls.alpha2, sigma_a, None, ("a",), cls.name)


def _f(x: Any) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return math.nan


def eta_curve(s: ArrayLike, curve: CurveParams, rho_s: float, rho_t: float) -> NDArray[np.float64]:
    """η(s) on the curve (paper eq. 7 with μ = μ(s)) [-]; negative where μ(s) < ρ_s."""
    s = np.asarray(s, dtype=float)
    mu = curve.mu(s)
    with np.errstate(divide="ignore", invalid="ignore"):
        return (mu - rho_s) / (mu + rho_t) * (1.0 - s)


def eta_wheels(mu: ArrayLike, slip: ArrayLike, rho_s: float, rho_t: float) -> NDArray[np.float64]:
    """η per wheel from its estimated μ and s (paper eq. 7) [-]."""
    mu = np.asarray(mu, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return (mu - rho_s) / (mu + rho_t) * (1.0 - np.asarray(slip, dtype=float))


def eta_machine(mu: ArrayLike, slip: ArrayLike, fz: ArrayLike, rho_s: float, rho_t: float) -> float:
    """η of a group of wheels (an axle, the machine): Σ F_z κ / Σ F_z (κ + ρ)/(1 − s) [-] (module doc)."""
    mu = np.asarray(mu, dtype=float)
    s = np.asarray(slip, dtype=float)
    fz = np.asarray(fz, dtype=float)
    den = float(np.sum(fz * (mu + rho_t) / (1.0 - s)))
    if not (den > 0 and math.isfinite(den)):
        return math.nan
    return float(np.sum(fz * (mu - rho_s))) / den


def optimum(curve: CurveParams, rho_s: float, rho_t: float) -> tuple[float, float]:
    """``(s*, η*)``: the slip that maximises η(s) on the curve, and η there (NaN, NaN if η ≤ 0 everywhere).

    Dense grid, then a parabola through the best point and its neighbours.
    """
    e = eta_curve(_GRID, curve, rho_s, rho_t)
    if not np.isfinite(e).any():
        return math.nan, math.nan
    k = int(np.nanargmax(e))
    if not e[k] > 0:
        return math.nan, math.nan
    if 0 < k < len(_GRID) - 1:
        x0, x1, x2 = _GRID[k - 1:k + 2]
        y0, y1, y2 = e[k - 1:k + 2]
        den = (x0 - x1) * (x0 - x2) * (x1 - x2)
        A = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / den
        B = (x2 * x2 * (y0 - y1) + x1 * x1 * (y2 - y0) + x0 * x0 * (y1 - y2)) / den
        if A < 0:
            s = min(max(-B / (2 * A), x0), x2)
            return float(s), float(eta_curve(s, curve, rho_s, rho_t))
    return float(_GRID[k]), float(e[k])


_STEPS = {"a": 0.01, "p": 0.01, "alpha1": 0.5, "alpha2": 0.1, "rho_s": 0.002}


def optimum_with_interval(curve: CurveParams, rho_s: float, rho_t: float,
                          var_rho_s: float = 0.0) -> tuple[float, float, float, float]:
    """``(s*, η*, σ(s*), σ(η*))``: the optimum and its standard errors (delta method, module doc)."""
    s0, e0 = optimum(curve, rho_s, rho_t)
    if not math.isfinite(s0):
        return math.nan, math.nan, math.nan, math.nan
    names, cov = curve.covariance()
    names = tuple(names) + ("rho_s",)
    n = len(names)
    C = np.zeros((n, n))
    C[:n - 1, :n - 1] = cov
    C[n - 1, n - 1] = max(var_rho_s, 0.0) if math.isfinite(var_rho_s) else math.inf
    if not np.isfinite(C).all():
        return s0, e0, math.inf, math.inf
    J = np.zeros((2, n))
    for j, name in enumerate(names):
        if name == "rho_s":
            h = _STEPS[name]
            sp, ep = optimum(curve, rho_s + h, rho_t)
            sm, em = optimum(curve, max(rho_s - h, 0.0), rho_t)
            hh = (rho_s + h) - max(rho_s - h, 0.0)
        else:
            v = curve.value(name)
            h = _STEPS.get(name, 0.01 * max(abs(v), 0.1))
            sp, ep = optimum(curve.with_values(**{name: v + h}), rho_s, rho_t)
            sm, em = optimum(curve.with_values(**{name: v - h}), rho_s, rho_t)
            hh = 2 * h
        J[0, j] = (sp - sm) / hh
        J[1, j] = (ep - em) / hh
    V = J @ C @ J.T
    return s0, e0, math.sqrt(max(V[0, 0], 0.0)), math.sqrt(max(V[1, 1], 0.0))


def sigma_a_from_estimate(curve: CurveParams, mu: ArrayLike, slip: ArrayLike, v: float,
                          P_diag: ArrayLike) -> float:
    """Standard error of a from the filter's uncertainties at one instant (module doc); inf at low slip."""
    mu = np.asarray(mu, dtype=float)
    s = np.asarray(slip, dtype=float)
    P = np.asarray(P_diag, dtype=float)
    if not (math.isfinite(v) and abs(v) > 0.1) or P.shape[-1] < 9:
        return math.inf
    ok = np.isfinite(mu) & np.isfinite(s) & (s > 0.002) & (mu > 0)
    if not ok.any():
        return math.inf
    sm = float(np.mean(s[ok]))
    mm = float(np.mean(mu[ok]))
    g = curve.g(sm)
    if g <= 1e-6:
        return math.inf
    sig_v = math.sqrt(max(P[4], 0.0))
    sig_s = (1.0 - sm) * sig_v / abs(v)
    sig_mu = math.sqrt(max(float(np.mean(P[5:9][ok])), 0.0) / int(ok.sum()))
    rel = math.hypot(sig_mu / mm, curve.dg(sm) * sig_s / g)
    return curve.a * rel


@dataclass
class EfficiencyReport:
    """η now and at s*, with what it rests on (module doc).  Numbers are NaN where a flag says why."""

    t: float
    flags: int
    s_star: float = math.nan
    s_star_lo: float = math.nan
    s_star_hi: float = math.nan
    eta_star: float = math.nan
    eta_star_sigma: float = math.nan
    eta: float = math.nan
    eta_front: float = math.nan
    eta_rear: float = math.nan
    eta_wheels: list[float] = field(default_factory=lambda: [math.nan] * 4)
    slip: float = math.nan
    """Load-weighted operating slip of the machine [-]."""
    slip_ok: bool = False
    """The slip is measured (fresh wheel and ground speeds, moving, pulling), even if μ or ρ_s have not
    converged: slip comes from the speeds alone (eq. 6)."""
    pull_n: float = math.nan
    """Net pull now, Σ (μ_i − ρ_s) F_z,i [N]."""
    pull_at_s_star_n: float = math.nan
    """Net pull available at s*, (μ(s*) − ρ_s)·W [N]."""
    a: float = math.nan
    sigma_a: float = math.nan
    rho_s: float = math.nan
    class_name: str = ""

    @property
    def eta_lost(self) -> float:
        """η* − η: efficiency lost against the optimum [-]."""
        return self.eta_star - self.eta

    @property
    def s_star_valid(self) -> bool:
        return not (self.flags & S_STAR_BITS)

    @property
    def eta_valid(self) -> bool:
        return not (self.flags & ETA_BITS)

    def reasons(self) -> list[str]:
        return [text for bit, text in FLAGS.items() if self.flags & bit]

    def as_dict(self) -> dict[str, Any]:
        def c(x: float) -> float | None:
            return None if not math.isfinite(x) else round(float(x), 5)

        return {"t": self.t, "flags": self.flags, "reasons": self.reasons(), "s_star": c(self.s_star),
                "s_star_lo": c(self.s_star_lo), "s_star_hi": c(self.s_star_hi), "eta_star": c(self.eta_star),
                "eta_star_sigma": c(self.eta_star_sigma), "eta": c(self.eta), "eta_front": c(self.eta_front),
                "eta_rear": c(self.eta_rear), "eta_wheels": [c(x) for x in self.eta_wheels],
                # the slip and pull now only while the estimate supports them: held from a reversing or a
                # standstill they were shown as live values ("slip now 1.3 %" frozen for 12 s)
                "eta_lost": c(self.eta_lost), "slip": c(self.slip) if self.slip_ok else None,
                "slip_ok": self.slip_ok,
                "pull_n": c(self.pull_n) if not self.flags & (ESTIMATE_INVALID | NOT_PULLING) else None,
                "pull_at_s_star_n": c(self.pull_at_s_star_n), "a": c(self.a), "sigma_a": c(self.sigma_a),
                "rho_s": c(self.rho_s), "class": self.class_name}


# EstimateStatus bits that make an estimate unusable for efficiency: timeouts of wheel speed, ground
# speed, torque, axle load, not converged, rejected input, filter lost, standstill, machine-level μ not
# supported (gear shift, clutch slip), slip not supported by its own σ (η of eq. 7 carries the factor
# 1 − s, and the estimator then holds an old slip) or averaged over the last metres of travel (a mean of
# several seconds, not this step's slip) (estimator module).
INVALID_STATUS = 0x01 | 0x02 | 0x04 | 0x08 | 0x20 | 0x40 | 0x200 | 0x400 | 0x1000 | 0x2000 | 0x10000
# ... and the bits that make the slip itself unusable: wheel or ground speed timed out, rejected input,
# filter lost, standstill, slip not supported by its own σ (creeping, manoeuvring).
SLIP_INVALID_STATUS = 0x01 | 0x02 | 0x40 | 0x200 | 0x400 | 0x2000
# ... and the bit saying that ρ_s is not reported by design (no draft sensor).
DRAFT_NOT_SEPARATED = 0x8000


@dataclass
class EfficiencyConfig:
    """Thresholds of :class:`EfficiencyTracker` (the service's ``[advice]`` holds them)."""

    rho_t: float = 0.015
    """Tyre-deformation rolling resistance ρ_t [-] (the vehicle's)."""
    weight_n: float = 6300.0 * G
    """Weight on the driven wheels W [N]."""
    front_fraction: float = 0.40
    """Static share of the weight on the front axle [-]."""
    wheelbase_m: float = 2.5
    hitch_height_m: float = 0.5
    min_speed_mps: float = 0.5
    """Slower than this: no current η [m/s]."""
    min_mu: float = 0.10
    """Less adhesion than this: not pulling, no current η [-]."""
    excitation_slip: float = 0.02
    """The curve counts as excited once the operating slip reached this within the window [-]."""
    excitation_window_s: float = 60.0
    """... within this many seconds [s]."""
    max_sigma_s_star: float = 0.01
    """s* is given only with σ(s*) at or below this [-]."""


class EfficiencyTracker:
    """Feeds on estimates (about 10 Hz), reports η, s* and their validity (module doc)."""

    def __init__(self, cfg: EfficiencyConfig | None = None) -> None:
        self.cfg = cfg or EfficiencyConfig()
        self._excited_t = -math.inf
        self._slip_seen_t = -math.inf
        self._sigma_a = math.nan
        self._cache: tuple[tuple[Any, ...], tuple[float, float, float, float]] | None = None

    def wheel_loads(self, pull_n: float) -> NDArray[np.float64]:
        """F_z per wheel [N]: the static split, the rear gaining pull·h_hitch/L from the front (physics.md)."""
        c = self.cfg
        dz = (pull_n * c.hitch_height_m / c.wheelbase_m) if math.isfinite(pull_n) and pull_n > 0 else 0.0
        f = max(c.weight_n * c.front_fraction - dz, 0.0)
        r = c.weight_n - f
        return np.array([f / 2, f / 2, r / 2, r / 2])

    def update(self, est: Any, *, with_optimum: bool = True) -> EfficiencyReport:
        """Report for one estimate; ``with_optimum`` False reuses the last s* (cheap 10 Hz path)."""
        c = self.cfg
        t = _f(getattr(est, "t", math.nan))
        flags = 0
        status = int(getattr(est, "status", 0) or 0)
        if status & INVALID_STATUS or not bool(getattr(est, "valid", True)):
            flags |= ESTIMATE_INVALID
        mu = np.asarray(getattr(est, "mu", [math.nan] * 4), dtype=float)
        s = np.asarray(getattr(est, "slip", [math.nan] * 4), dtype=float)
        rho_s = _f(getattr(est, "rho_s", math.nan))
        v = _f(getattr(est, "v", math.nan))
        P = np.asarray(getattr(est, "P_diag", [math.nan] * 10), dtype=float)
        rep = EfficiencyReport(t, 0, rho_s=rho_s)
        fz0 = self.wheel_loads(0.0)
        pull = float(np.sum(fz0 * (mu - rho_s)))
        fz = self.wheel_loads(pull)
        # the resistance s* is sought against, its variance's scale and the weight it is pulled with
        rho_opt, var_scale, w_opt = rho_s, 1.0, c.weight_n
        driven = np.ones(4, dtype=bool)
        if getattr(est, "front_engaged", True) is False:
            # MFWD disengaged (the machine-level estimator's μ is ΣF_h/ΣF_z, the front slip unknown): the front
            # wheels roll undriven, F_h = −ρ_t F_z, and take no power; the rear wheels' μ follows.  Read with a
            # front slip of NaN as "not pulling", a tractor working with its front drive off had no η, s* or advice.
            fzf, fzr = float(fz[:2].sum()), float(fz[2:].sum())
            mu_r = (float(np.mean(mu)) * c.weight_n + c.rho_t * fzf) / fzr
            mu = np.array([-c.rho_t, -c.rho_t, mu_r, mu_r])
            s = np.array([0.0, 0.0, s[2], s[3]])
            driven[:2] = False
            # η(s) of the rear axle with the front's rolling loss: eq. 7 with ρ_s' = (ρ_t F_zf + ρ_s m g)/F_zr
            rho_opt, var_scale, w_opt = (c.rho_t * fzf + rho_s * c.weight_n) / fzr, (c.weight_n / fzr) ** 2, fzr
        rep.pull_n = float(np.sum(fz * (mu - rho_s)))
        rep.slip = float(np.sum(fz[driven] * s[driven]) / np.sum(fz[driven]))
        pulling = (math.isfinite(v) and abs(v) >= c.min_speed_mps and bool(np.isfinite(mu).all())
                   and bool(np.isfinite(s).all()) and float(np.mean(mu[driven])) >= c.min_mu)
        if not math.isfinite(rho_s):
            flags |= NO_RHO_S if status & DRAFT_NOT_SEPARATED else ESTIMATE_INVALID
        rep.slip_ok = bool(pulling and not status & SLIP_INVALID_STATUS and math.isfinite(rep.slip))
        if not pulling:
            flags |= NOT_PULLING
        else:
            rep.eta_wheels = [float(x) if d else math.nan for x, d in zip(eta_wheels(mu, s, rho_s, c.rho_t), driven)]
            rep.eta = eta_machine(mu, s, fz, rho_s, c.rho_t)
            rep.eta_front = eta_machine(mu[:2], s[:2], fz[:2], rho_s, c.rho_t) if driven[0] else math.nan
            rep.eta_rear = eta_machine(mu[2:], s[2:], fz[2:], rho_s, c.rho_t)
        if rep.slip_ok and rep.slip >= c.excitation_slip:
            self._excited_t = t
        if not flags & ESTIMATE_INVALID and not status & SLIP_INVALID_STATUS and math.isfinite(rep.slip):
            self._slip_seen_t = t
        # "slip too low" only once the estimator has reported a slip it supports: before that (start-up, not
        # converged) the estimate's own flags say why (it read so from the first step of every run, at a slip
        # of 0.55 too)
        if math.isfinite(self._slip_seen_t) and not (math.isfinite(t) and t - self._excited_t <= c.excitation_window_s):
            flags |= LOW_EXCITATION
        curve = curve_of(est)
        if curve is None:
            flags |= CURVE_NOT_IDENTIFIED
        else:
            rep.a = curve.a
            rep.class_name = curve.class_name
            if pulling and not flags & ESTIMATE_INVALID:
                self._sigma_a = sigma_a_from_estimate(curve, mu, s, v, P)
            if curve.cov is None:
                curve = replace(curve, sigma_a=self._sigma_a, names=("a",))
            rep.sigma_a = curve.sigma_a if curve.cov is None else math.sqrt(max(float(curve.covariance()[1][0, 0]), 0.0))
            var_rho = (float(P[9]) if P.shape[-1] > 9 else math.nan) * var_scale
            key = (curve.a, curve.p, curve.alpha1, curve.alpha2, curve.sigma_a, rho_opt, var_rho, curve.theta,
                   curve.class_name, curve.names)
            # a curve of another form (a class, a fitted shape) is a new curve: its s* is computed now (the last
            # one's s* was reported as valid for up to a second after the estimator's curve became a fit whose
            # parameters it gave as unknown)
            if with_optimum or self._cache is None or self._cache[0][-2:] != key[-2:]:
                if math.isfinite(rho_opt):
                    self._cache = (key, optimum_with_interval(curve, rho_opt, c.rho_t, var_rho))
            if self._cache is not None:
                s_star, e_star, ss, se = self._cache[1]
                if not (math.isfinite(s_star) and ss <= c.max_sigma_s_star):
                    flags |= INTERVAL_WIDE
                rep.s_star, rep.eta_star, rep.eta_star_sigma = s_star, e_star, se
                rep.s_star_lo, rep.s_star_hi = s_star - 2 * ss, s_star + 2 * ss
                if math.isfinite(s_star):
                    rep.pull_at_s_star_n = (float(curve.mu(s_star)) - rho_opt) * w_opt
        rep.flags = flags
        if flags & S_STAR_BITS:
            rep.s_star = rep.s_star_lo = rep.s_star_hi = rep.eta_star = rep.eta_star_sigma = math.nan
            rep.pull_at_s_star_n = math.nan
        if flags & ETA_BITS:
            rep.eta = rep.eta_front = rep.eta_rear = math.nan
            rep.eta_wheels = [math.nan] * 4
        return rep


def efficiency_config_for(vehicle: Any, **kw: Any) -> EfficiencyConfig:
    """:class:`EfficiencyConfig` of a :class:`~tractionecu.config.VehicleParams` (ρ_t, weight, geometry)."""
    return EfficiencyConfig(rho_t=float(vehicle.rho_t), weight_n=float(vehicle.weight_n),
                            front_fraction=float(vehicle.static_front_fraction),
                            wheelbase_m=float(vehicle.wheelbase_m), hitch_height_m=float(vehicle.hitch_height_m), **kw)


def true_optimum(a: float, rho_s: float, rho_t: float, soil_class: str) -> tuple[float, float]:
    """``(s*, η*)`` of a true curve (a simulation's truth file) [-]."""
    cls = curve_class(soil_class)
    if cls is None:
        raise KeyError(f"curve class {soil_class!r}: neither a surface class nor a known curve shape")
    return optimum(CurveParams(a, cls.p, cls.alpha1, cls.alpha2), rho_s, rho_t)


__all__: Sequence[str] = ("CurveParams", "EfficiencyConfig", "EfficiencyReport", "EfficiencyTracker", "FLAGS",
                          "curve_of", "eta_curve", "eta_machine", "eta_wheels", "optimum", "optimum_with_interval",
                          "sigma_a_from_estimate", "true_optimum", "efficiency_config_for")
