"""Calibrated 95 % intervals of fitted effect parameters: HAC-scaled profile likelihood and block jackknife.

The sandwich interval x̂ ± 1.96 SE (:func:`.fit.sandwich`) is right when the cost is quadratic in the
parameters near the solution and the model holds.  Two things break that on tractor logs:

* **Trade-offs with bounded or nonlinear nuisance.**  A rolling-radius error ε and the zero-slip
  traction ratio μ_0 (nuisance of the slip channel, range :data:`.channels.MU0_RANGE`) move the
  slip alike; at the solution μ_0 may sit on its bound, where the finite-difference curvature sees
  μ_0 held and the cost looks steep, while away from the solution μ_0 leaves the bound and the cost
  is flat over a wide range of ε.  The interval must follow the cost, not its curvature at one point.
* **A plant that is not the nominal model.**  The estimate then depends on which stretch of the
  recording it sees (speed steps, soils, turns), beyond what the noise explains.

Profile likelihood, scaled by the long-run variance
---------------------------------------------------
For parameter j the profile of the weighted cost C(x) = Σ_c ‖e_c(x)‖²/σ_c² (nuisance of the channels
re-fitted inside each residual, the other fitted parameters re-fitted at each point) is

    P_j(v) = min_{x: x_j = v} C(x),        ΔP_j(v) = P_j(v) − C(x̂).

With independent unit-variance residuals ΔP_j ~ χ²₁ at the true value.  The residuals of a vehicle
log are autocorrelated, so the curvature of C overstates the information: near x̂,
ΔP_j(v) ≈ (v − x̂_j)² / (A⁻¹)_jj with A = J̃ᵀJ̃, while the parameter's variance is the sandwich's
V_jj (HAC, Newey–West).  The interval is

    { v : ΔP_j(v) ≤ χ²₁,₀.₉₅ · κ_j },     κ_j = V_jj / (A⁻¹)_jj,

(the adjustment of a misspecified likelihood's ratio statistic by its sandwich, Chandler & Bate
2007, for one parameter).  Where the cost is quadratic this is exactly x̂_j ± 1.96 √V_jj; where a
nuisance parameter trades off or leaves its bound the cost is flatter and the interval wider; on a
library bound it is one-sided and reaches the bound.  Each edge is found by walking out from x̂_j
(first step the sandwich edge, then growing by the quadratic extrapolation of ΔP) and bisecting
on √ΔP, which is linear in v where the cost is quadratic (so one or two evaluations usually suffice).

Block jackknife over the recording
----------------------------------
The recording is cut into G contiguous time blocks (:data:`JACKKNIFE_BLOCKS`); the fit is repeated
G times, each without one block (from x̂, nuisance re-fitted), and

    SE_J² = (G − 1)/G Σ_g (x̂_(g) − x̄)²,   interval x̂ ± t_{G−1, 0.975} SE_J.

Under the model SE_J estimates the same variance as the sandwich (blocks longer than the residuals'
correlation), and (G − 1) SE_J²/SE² is roughly χ²_{G−1}; on a plant that is not the model the
estimate moves with the data it sees and SE_J grows.  The blocks *disagree* when

    (G − 1) SE_J² / V_jj > χ²_{G−1, 0.95}     (:func:`heterogeneous`, 5 % test),

and only then does the jackknife interval join the profile's: the reported interval is their union
(each a 95 % interval under its own assumptions), else the profile interval alone, so a recording
that fits the model keeps the profile's width (always taking the union would cover 99 % at 25 %
more width there).  This replaces the two held-out folds' disagreement |x̂₀ − x̂₁|/2, a
one-degree-of-freedom estimate of the same spread, for the reported fit.  The interval is clipped
to the library range; one that spans nearly the whole range is reported *not identified*
(:func:`.engine.identified`).

The age of a bus signal's value (a delay the data cannot measure)
-------------------------------------------------------------------
A GNSS latency is measured against the drive-line signals' time base: the GNSS speed is compared
with the speed integrated from the wheel torques, and the fit returns the delay between the two,
τ̂ = τ − A, where A is how old a torque value already is when its frame is stamped.  A periodic
CAN signal (J1939 / ISO 11783 PGNs every 10–100 ms) carries the value its sender computed at some
point within its last cycle, so 0 ≤ A ≤ T_s, the signal's period, and nothing in the recording tells
where (the logger stamps reception).  That is a type-B component (GUM, JCGM 100:2008, 4.3.7: bounds
known, nothing else): the latency's interval is extended on its upper side by T_s,
[lo, hi + T_s] (:func:`sample_age_extension`, :data:`SAMPLE_AGE_PARAMS`), with T_s the raw
wheel-speed and torque period of the recording (10 ms at 100 Hz).  The estimate is not moved.

The tyre law behind a pressure (a conversion the data cannot check)
--------------------------------------------------------------------
A tyre pressure acts on the data through the rolling radius it changes; the pressure that made a radius
follows from the tyre's deflection and the carcass's share of its stiffness, which no recording measures.
Their ranges (:data:`tractionecu.model.effects.TYRE_DEFLECTION_RATIO_RANGE`,
:data:`~tractionecu.model.effects.TYRE_CARCASS_SHARE_RANGE`) are another type-B component: the fitted
p/p_0 interval is widened to every pressure that gives the radius terms at its ends within them
(:func:`tyre_law_extension`).

A load pin's gain behind an axle-load offset (a calibration the data cannot check)
--------------------------------------------------------------------------------------
The front-axle load channel fits the load-transfer heights as a nuisance, so a gain error k of the pin,
F_meas = (1 + k) F_zf, reads as an offset k · F_zf,static plus heights scaled by 1 + k: exactly an
axle-load offset of that size.  The vehicle file's ``[sensors] axle_gain_tol_rel`` bounds |k| (a
rectangular bound, as every sensor tolerance here), another type-B component: the offset's interval is
widened to the expanded combination √(U_A² + (1.96 · b/√3)²) with b = tolerance × the static front
load (:func:`gain_tolerance_extension`; the estimate is not moved).

In the diagnosis (:func:`.fit.refine_intervals`) the sandwich interval x̂ ± 1.96 √V_jj is kept
inside the profile's: the profile only widens it.  A profile edge nearer than the sandwich's is
what a steeper-than-quadratic cost gives, but also what a re-fit of the other parameters that
stopped early gives, and one recording cannot tell the two apart.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from numpy.typing import NDArray

__all__ = ["CHI2_1_95", "JACKKNIFE_BLOCKS", "Edge", "Interval", "hac_inflation", "profile_edge",
           "profile_interval", "block_labels", "jackknife_se", "heterogeneous", "t_quantile", "union",
           "SAMPLE_AGE_PARAMS", "sample_age_extension", "tyre_law_extension", "PIN_GAIN_PARAMS",
           "gain_tolerance_extension"]

CHI2_1_95 = 3.841458820694124
"""95 % quantile of χ² with one degree of freedom (1.959964²)."""

JACKKNIFE_BLOCKS = 8
"""Contiguous time blocks of the block jackknife (a 7-minute recording: blocks of about 50 s, longer
than the residuals' correlation; t quantile with 7 degrees of freedom, 2.36)."""

PROFILE_MAX_EVALS = 10
"""Profile evaluations per edge at most (walk out and bisection)."""

PROFILE_RTOL = 0.05
"""An edge is located when its bracket is narrower than this share of its distance from x̂ ..."""

PROFILE_ROOT_TOL = 0.01
"""... or when √ΔP at a trial is within this share of √(threshold) (about 1 % of the half-width)."""


@dataclass
class Edge:
    value: float
    """Where ΔP first reaches the threshold (or the limit)."""
    at_limit: bool
    """The profile stayed below the threshold up to the limit (the library bound)."""
    evals: int


@dataclass
class Interval:
    lo: float
    hi: float
    kappa: float = math.nan
    """HAC inflation κ_j of the likelihood ratio."""
    evals: int = 0
    method: str = ""


def hac_inflation(cov: NDArray, a_inv: NDArray, j: int) -> float:
    """κ_j = V_jj / (A⁻¹)_jj: how much the residuals' autocorrelation (and any variance added to the
    sandwich) inflates the parameter's variance over what the cost's curvature says; nan if undefined."""
    v = float(cov[j, j]) if cov is not None else math.nan
    a = float(a_inv[j, j]) if a_inv is not None else math.nan
    if not (math.isfinite(v) and math.isfinite(a)) or v <= 0 or a <= 0:
        return math.nan
    return v / a


def profile_edge(delta: Callable[[float], float], x_hat: float, limit: float, step: float, thresh: float,
                 max_evals: int = PROFILE_MAX_EVALS, rtol: float = PROFILE_RTOL) -> Edge:
    """Walk from ``x_hat`` toward ``limit`` to where ``delta`` (the profile's rise ΔP, 0 at x_hat)
    reaches ``thresh``.

    The first trial is ``step`` away (the sandwich edge); while ΔP stays below the threshold the step
    grows by the quadratic extrapolation √(thresh/ΔP) (between 1.25 and 4 times); once bracketed the
    edge is interpolated on √ΔP, linear in v where the cost is quadratic.
    """
    dist = abs(limit - x_hat)
    sgn = 1.0 if limit >= x_hat else -1.0
    if not (dist > 0) or not (thresh > 0):
        return Edge(float(x_hat), True, 0)
    h = min(step if (math.isfinite(step) and step > 0) else 0.1 * dist, dist)
    t_in, d_in = 0.0, 0.0
    evals = 0
    d_out = math.nan
    while True:
        d = float(delta(x_hat + sgn * h))
        evals += 1
        if not math.isfinite(d):
            d = math.inf
        if d >= thresh:
            t_out, d_out = h, d
            break
        t_in, d_in = h, max(d, 0.0)
        if h >= dist * (1 - 1e-12) or evals >= max_evals:
            return Edge(float(x_hat + sgn * h), h >= dist * (1 - 1e-12), evals)
        grow = math.sqrt(thresh / d) if d > 0 else 4.0
        h = min(h * float(np.clip(1.1 * grow, 1.25, 4.0)), dist)
    rt = math.sqrt(thresh)
    while True:
        if math.isfinite(d_out) and abs(math.sqrt(d_out) - rt) <= PROFILE_ROOT_TOL * rt:
            return Edge(float(x_hat + sgn * t_out), False, evals)
        r_in = math.sqrt(d_in)
        r_out = math.sqrt(d_out) if math.isfinite(d_out) else math.inf
        if math.isfinite(r_out) and r_out > r_in:
            t = t_in + (rt - r_in) * (t_out - t_in) / (r_out - r_in)
        else:
            t = 0.5 * (t_in + t_out)
        t = float(np.clip(t, t_in, t_out))
        if t_out - t_in <= rtol * max(t_out, 1e-300) or evals >= max_evals:
            return Edge(float(x_hat + sgn * t), False, evals)
        # Keep the trial off the bracket's ends so that the bracket shrinks from both sides.
        w = t_out - t_in
        t = float(np.clip(t, t_in + 0.02 * w, t_out - 0.02 * w))
        d = float(delta(x_hat + sgn * t))
        evals += 1
        if not math.isfinite(d):
            d = math.inf
        if abs(math.sqrt(max(d, 0.0)) - rt) <= PROFILE_ROOT_TOL * rt:
            return Edge(float(x_hat + sgn * t), False, evals)
        if d >= thresh:
            t_out, d_out = t, d
        else:
            t_in, d_in = t, max(d, 0.0)


def profile_interval(delta: Callable[[float], float], x_hat: float, lo: float, hi: float, se: float,
                     kappa: float, level_chi2: float = CHI2_1_95, reset: Callable[[], None] | None = None) -> Interval:
    """{v : ΔP(v) ≤ χ² κ} within [lo, hi], walking out from ``x_hat`` both ways (module doc).

    ``se`` is the sandwich standard error (the first step is 1.96 se); ``reset`` is called before each
    side (a profile that warm-starts its nuisance from the last point starts again from x̂)."""
    thresh = level_chi2 * kappa
    step = math.sqrt(level_chi2) * se
    if not (math.isfinite(thresh) and thresh > 0):
        return Interval(math.nan, math.nan, kappa, 0, "profile")
    edges = []
    for limit in (lo, hi):
        if reset is not None:
            reset()
        edges.append(profile_edge(delta, x_hat, limit, step, thresh))
    return Interval(min(edges[0].value, x_hat), max(edges[1].value, x_hat), kappa,
                    edges[0].evals + edges[1].evals, "profile")


def block_labels(t: NDArray, t0: float, t1: float, n_blocks: int = JACKKNIFE_BLOCKS) -> NDArray[np.int64]:
    """Contiguous time block (0 … n_blocks − 1) of each time in [t0, t1]."""
    span = max(t1 - t0, 1e-12)
    return np.clip(np.floor((np.asarray(t, dtype=float) - t0) / span * n_blocks), 0, n_blocks - 1).astype(np.int64)


def jackknife_se(estimates: NDArray) -> NDArray:
    """Delete-one-block jackknife standard error of each column of ``estimates`` (G, k)."""
    est = np.asarray(estimates, dtype=float)
    if est.ndim == 1:
        est = est[:, None]
    g = est.shape[0]
    if g < 2:
        return np.full(est.shape[1], np.nan)
    dev = est - est.mean(axis=0)
    return np.sqrt((g - 1) / g * np.sum(dev * dev, axis=0))


def heterogeneous(se_jack: float, se_sandwich: float, n_est: int, p: float = 0.95) -> bool:
    """True when the delete-one-block estimates spread more than the sandwich allows:
    (G − 1) SE_J² / SE² above the χ²_{G−1} quantile ``p`` (G = ``n_est`` re-fits)."""
    from scipy.stats import chi2

    if n_est < 3 or not (math.isfinite(se_jack) and math.isfinite(se_sandwich)) or se_sandwich <= 0:
        return bool(n_est >= 3 and math.isfinite(se_jack) and se_jack > 0 and not se_sandwich > 0)
    return bool((n_est - 1) * (se_jack / se_sandwich) ** 2 > chi2.ppf(p, n_est - 1))


def t_quantile(df: int, p: float = 0.975) -> float:
    """Student-t quantile (the jackknife's G − 1 degrees of freedom)."""
    from scipy.stats import t as student

    return float(student.ppf(p, df))


def union(a: tuple[float, float], b: tuple[float, float]) -> tuple[float, float]:
    """Smallest interval holding both (nan ends ignored)."""
    los = [v for v in (a[0], b[0]) if math.isfinite(v)]
    his = [v for v in (a[1], b[1]) if math.isfinite(v)]
    return (min(los) if los else math.nan, max(his) if his else math.nan)


SAMPLE_AGE_PARAMS = frozenset({("gps_latency", "tau_s")})
"""(effect, parameter) pairs that are a delay of the GNSS signals against the drive-line signals' time
base: the age A ∈ [0, T_s] of a bus signal's value at its time stamp adds to them unseen (module doc)."""


def sample_age_extension(effect: str, param: str, interval: tuple[float, float], period_s: float,
                         upper_limit: float = math.inf) -> tuple[float, float]:
    """The 95 % interval of ``effect.param`` with the type-B bound of the drive-line samples' age: for a
    delay of the GNSS against the bus signals (:data:`SAMPLE_AGE_PARAMS`), τ = τ̂ + A with
    0 ≤ A ≤ ``period_s`` [s], so the upper end moves up by the period (clipped to ``upper_limit``);
    other parameters, and a period that is not a positive finite number, leave the interval as it is."""
    lo, hi = interval
    if (effect, param) not in SAMPLE_AGE_PARAMS or not (math.isfinite(period_s) and period_s > 0.0):
        return lo, hi
    return lo, min(upper_limit, hi + period_s)


def tyre_law_extension(effect: str, param: str, interval: tuple[float, float], lower_limit: float = -math.inf,
                       upper_limit: float = math.inf) -> tuple[float, float]:
    """The 95 % interval of ``effect.param`` with the type-B bound of the tyre law: a tyre pressure is fitted
    through its radius term under the library's nominal δ_0/r_0 and carcass share, so its interval is widened
    to every pressure that gives the same radius terms within those figures' ranges
    (:func:`tractionecu.model.effects.tyre_pressure_law_range`), clipped to the parameter's bounds; other
    parameters are left as they are."""
    lo, hi = interval
    if (effect, param) != ("tyre_pressure", "p_ratio") or not (math.isfinite(lo) and math.isfinite(hi)):
        return lo, hi
    from ..model.effects import tyre_pressure_law_range

    a, b = tyre_pressure_law_range(lo, hi)
    return max(lower_limit, a), min(upper_limit, b)


PIN_GAIN_PARAMS = frozenset({("axle_load_offset", "b0_n")})
"""(effect, parameter) pairs that a load pin's gain error within its tolerance produces unseen (module doc)."""


def gain_tolerance_extension(effect: str, param: str, interval: tuple[float, float], estimate: float,
                             bound: float, lower_limit: float = -math.inf,
                             upper_limit: float = math.inf) -> tuple[float, float]:
    """The 95 % interval of ``effect.param`` with the type-B bound ``bound`` (same unit) of a load pin's gain
    tolerance (:data:`PIN_GAIN_PARAMS`): each side's distance from ``estimate`` becomes
    √(d² + (1.96 · bound/√3)²), clipped to the parameter's limits; other parameters, and a bound that is
    not a positive finite number, leave the interval as it is."""
    lo, hi = interval
    if ((effect, param) not in PIN_GAIN_PARAMS or not (math.isfinite(bound) and bound > 0.0)
            or not (math.isfinite(lo) and math.isfinite(hi) and math.isfinite(estimate))):
        return lo, hi
    ub = 1.959964 * bound / math.sqrt(3.0)
    dlo, dhi = max(0.0, estimate - lo), max(0.0, hi - estimate)
    return max(lower_limit, estimate - math.hypot(dlo, ub)), min(upper_limit, estimate + math.hypot(dhi, ub))
