"""Self-calibration of the rolling radius: a scale per axle from low-slip stretches.

The filter's rolling radius is eq. 9, r_d = r0 − Δr(F_z), from the nominal
tyre data.  A real tyre differs from it (ETRTO / TRA allow ±3 % on the
diameter; wear, pressure and the tyre model do the rest), and a radius error
ε reads as a slip offset ε(1 − s) (eq. 6) and as a μ error −ε(μ + ρ_t)
(eq. 2).  Where the wheels barely slip, the wheel's circumferential speed
and the ground speed must agree, which measures the true radius:

    y = |v_GNSS| / (r_d |ω̄|) = k (1 − s),      k = r_true / r_d,

per axle (ω̄ the mean of its left and right wheel, so that a gentle curve
cancels to first order).  The slip is not zero even with the implement
raised: the wheels still carry the rolling resistance, μ ≈ ρ_s ≈ 0.05–0.1,
which on stubble is ≈ 0.6 % slip.  It is predicted from the identified μ(s)
curve (:func:`slip_at`, the inverse of eq. 14 at the axle's μ̂) and its
scale is estimated with the radius:

    y = k − θ·s_pred,    θ = k·β,  prior β = 1 ± ``slope_prior_rel``,

an ordinary linear regression in (k, θ); the intercept k is the radius
scale at zero traction, the slope absorbs an error of the curve's slip
prediction.  With little spread of μ the prior on θ keeps the intercept
defined and widens its interval honestly.

Which samples count (all must hold, per GNSS epoch)
---------------------------------------------------
* the filter is converged and valid, not at standstill;
* |v| ≥ ``min_speed_mps`` (the GNSS speed noise is relative to speed);
* |μ̄_axle| ≤ ``max_mu`` (implement raised, transport, headland: the linear
  low-slip part of the curve) and the predicted slip ≤ ``max_slip``;
* |dv/dt| ≤ ``max_accel_mps2`` (a GNSS latency τ shifts the speed by τ·dv/dt);
* the left–right wheel-speed difference of both axles ≤ ``max_turn_rel``
  of their mean (path curvature ≤ 0.02/1.8 m ≈ 1/90 m: the front axle's
  extra path L²κ²/2 stays below 0.04 %);
* wheels turning the way the machine moves.

Robust, recursive, bounded memory
---------------------------------
Samples are averaged over blocks of ``block_s`` (consecutive passing
epochs; a failing epoch ends the block, blocks of fewer than half the
expected epochs are dropped), so that the GNSS and wheel-speed noise,
correlated within a fraction of a second, enters as roughly independent
block means.  Each block updates six running sums of the regression with
exponential forgetting (time constant ``tau_s`` of accepted blocks, so a
tyre that wears or a changed pressure is followed) and a Huber weight
(residual beyond ``huber_k`` residual standard deviations down-weighted).
The 95 % interval of k is the regression's: t_{0.975, n−2}·√(s²·(A⁻¹)_kk)
with s² the weighted residual variance and A the normal matrix including
the prior.  Memory is constant.

When it is applied
------------------
The estimator uses k_axle (the filter's radius r_d·k, see
:class:`~tractionecu.estimation.estimator.Estimator`) once at least
``min_blocks`` blocks were accepted and the 95 % half-width is at most
``apply_halfwidth`` (0.5 % by default, a sixth of the tyre tolerance);
after that the applied value follows the estimate as long as the
half-width stays within that bound, and is held otherwise.  Until then the
nominal radius is used and the tyre tolerance enters the reported
uncertainty (:mod:`.uncertainty`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from scipy.stats import t as _student_t

from ..config import setting, validate
from ..model.mucurve import SOIL_CLASSES, curve_class

AXLES = ("front", "rear")


@dataclass(frozen=True)
class CalibrationConfig:
    """Rolling-radius self-calibration (``[estimator.calibration]``)."""

    enabled: bool = setting(True, "estimate a rolling-radius scale per axle from low-slip stretches and apply it "
                                  "once its interval is tight")
    block_s: float = setting(1.0, "samples are averaged over blocks of this length before the regression [s]",
                             0.1, 60.0)
    tau_s: float = setting(1800.0, "forgetting time constant, in accepted block time [s]", 10.0, 1e7)
    min_speed_mps: float = setting(1.0, "lowest ground speed of a calibration sample [m/s]", 0.1, 20.0)
    max_mu: float = setting(0.15, "largest |μ̂| of an axle in a calibration sample (low-slip part of μ(s)) [-]",
                            0.01, 0.5)
    max_slip: float = setting(0.02, "largest slip the identified curve predicts at that μ̂ [-]", 0.001, 0.2)
    max_accel_mps2: float = setting(0.05, "largest |dv/dt| of a calibration sample (GNSS latency) [m/s²]",
                                    0.001, 5.0)
    max_turn_rel: float = setting(0.02, "largest left–right wheel-speed difference of an axle, relative to its mean "
                                        "(straight travel) [-]", 0.001, 0.5)
    slope_prior_rel: float = setting(0.3, "relative standard deviation of the prior on the slip-prediction slope [-]",
                                     0.01, 10.0)
    huber_k: float = setting(2.5, "Huber threshold in residual standard deviations [-]", 0.5, 100.0)
    min_blocks: int = setting(20, "accepted blocks before the scale may be applied [-]", 3, 100000)
    apply_halfwidth: float = setting(0.005, "the scale is applied once its 95 % half-width is at most this [-]",
                                     1e-5, 0.3)

    def __post_init__(self) -> None:
        validate(self, "estimator.calibration")


def slip_at(mu: float, a: float, p: float, alpha1: float, alpha2: float) -> float:
    """Slip s ≥ 0 with a·g(s) = |μ| (inverse of eq. 14 on its rising branch) [-]; NaN if |μ| ≥ 0.95 a.

    Newton's method from the linear guess |μ|/(a g'(0)); g is concave, so
    the iterates rise monotonically to the root.
    """
    m = abs(mu)
    if not (a > 0.0) or m >= 0.95 * a:
        return math.nan
    r = m / a
    d0 = -p * alpha1 - (1.0 - p) * alpha2
    s = r / d0
    for _ in range(8):
        e1, e2 = math.exp(alpha1 * s), math.exp(alpha2 * s)
        g = 1.0 - p * e1 - (1.0 - p) * e2
        dg = -p * alpha1 * e1 - (1.0 - p) * alpha2 * e2
        step = (g - r) / dg
        s -= step
        if abs(step) < 1e-10:
            break
    return s


@dataclass(frozen=True)
class AxleScale:
    """Rolling-radius scale of one axle."""

    scale: float
    """Estimated k = r_true / r_d(F_z) [-]; NaN until three blocks were accepted."""
    halfwidth: float
    """95 % half-width of ``scale`` [-]; NaN until three blocks were accepted."""
    blocks: int
    """Accepted blocks (ever)."""
    applied: float
    """The scale the estimator uses [-]: 1.0 until the interval is tight enough (module doc)."""


class _Axle:
    """Forgetting, Huber-weighted regression y = k − θ x of one axle (module doc)."""

    def __init__(self, cfg: CalibrationConfig) -> None:
        self.cfg = cfg
        self.sw = self.sx = self.sxx = self.sy = self.sxy = self.syy = 0.0
        self.n = 0
        self.k = math.nan
        self.theta = 1.0
        self.hw = math.nan
        self.s2 = math.nan
        self.applied = 1.0
        self.is_applied = False

    def add(self, y: float, x: float) -> None:
        cfg = self.cfg
        if self.n >= 3 and math.isfinite(self.k) and self.s2 > 0.0:
            r = y - (self.k - self.theta * x)
            sd = math.sqrt(self.s2)
            w = 1.0 if abs(r) <= cfg.huber_k * sd else cfg.huber_k * sd / abs(r)
        else:
            w = 1.0
        lam = math.exp(-cfg.block_s / cfg.tau_s)
        self.sw = lam * self.sw + w
        self.sx = lam * self.sx + w * x
        self.sxx = lam * self.sxx + w * x * x
        self.sy = lam * self.sy + w * y
        self.sxy = lam * self.sxy + w * x * y
        self.syy = lam * self.syy + w * y * y
        self.n += 1
        self._solve()

    def _solve(self) -> None:
        cfg = self.cfg
        if self.n < 3:
            return
        # Normal equations of y = k − θ x with the prior θ ~ N(1, σθ²) as a pseudo-observation whose
        # weight is s²/σθ² (s² the residual variance of the last solution; a first guess without one).
        s2 = self.s2 if self.s2 > 0.0 else 1e-6
        wp = s2 / (cfg.slope_prior_rel ** 2)
        a11, a12, a22 = self.sw, -self.sx, self.sxx + wp
        b1, b2 = self.sy, -self.sxy + wp * 1.0
        det = a11 * a22 - a12 * a12
        if not det > 0.0:
            return
        k = (a22 * b1 - a12 * b2) / det
        th = (a11 * b2 - a12 * b1) / det
        # weighted residual sum of squares from the sums
        rss = (self.syy - 2.0 * k * self.sy + 2.0 * th * self.sxy + k * k * self.sw - 2.0 * k * th * self.sx
               + th * th * self.sxx)
        dof = max(self.sw - 1.0, 1.0)              # two parameters, one of them carried by the prior
        s2_new = max(rss, 0.0) / dof
        if not s2_new > 0.0:
            s2_new = 1e-12
        self.k, self.theta, self.s2 = k, th, s2_new
        # covariance s²·A⁻¹, with A rebuilt for the new s² of the prior's weight
        wp = s2_new / (cfg.slope_prior_rel ** 2)
        a22 = self.sxx + wp
        det = a11 * a22 - a12 * a12
        var_k = s2_new * a22 / det if det > 0.0 else math.inf
        tq = float(_student_t.ppf(0.975, max(dof, 1.0)))
        self.hw = tq * math.sqrt(var_k)
        if self.n >= cfg.min_blocks and self.hw <= cfg.apply_halfwidth:
            self.applied = k
            self.is_applied = True

    def state(self) -> AxleScale:
        return AxleScale(self.k if self.n >= 3 else math.nan, self.hw if self.n >= 3 else math.nan, self.n,
                         self.applied)


class RadiusCalibration:
    """Rolling-radius scale per axle (front, rear) from low-slip stretches (module doc).

    :meth:`push` once per GNSS speed sample with the estimator's current
    values; :meth:`state` gives the two :class:`AxleScale`; ``applied`` is
    the pair (front, rear) the estimator uses, and ``version`` counts its
    changes.
    """

    def __init__(self, cfg: CalibrationConfig | None = None) -> None:
        self.cfg = cfg or CalibrationConfig()
        self.reset()

    def reset(self) -> None:
        self._axles = (_Axle(self.cfg), _Axle(self.cfg))
        self._blk = [0.0, 0.0, 0.0, 0.0, 0]       # Σy_f, Σx_f, Σy_r, Σx_r, n
        self._t0 = math.nan
        self._period = math.nan
        self._t_last = math.nan
        self.applied = (1.0, 1.0)
        self.version = 0
        self.samples = 0
        self.rejected = 0

    def _end_block(self) -> None:
        b = self._blk
        n = b[4]
        span = (self._t_last - self._t0) * n / (n - 1) if n > 1 else 0.0      # n samples cover n periods
        expect = span / self._period if self._period > 0.0 else n
        if n >= 2 and span >= 0.5 * self.cfg.block_s and n >= 0.5 * expect:
            self._axles[0].add(b[0] / n, b[1] / n)
            self._axles[1].add(b[2] / n, b[3] / n)
            applied = (self._axles[0].applied, self._axles[1].applied)
            if applied != self.applied:
                self.applied = applied
                self.version += 1
        self._blk = [0.0, 0.0, 0.0, 0.0, 0]
        self._t0 = math.nan

    def push(self, t: float, v: float, omega: list[float], rdf: float, rdr: float, mu: list[float],
             accel: float, ok: bool, a: float, class_name: str) -> None:
        """One GNSS epoch: time t [s], GNSS speed v [m/s], wheel speeds ω (4) [rad/s], nominal rolling
        radii r_d of a front and a rear wheel [m], μ̂ (4), dv/dt [m/s²], ``ok`` (filter valid and
        moving), the identified a and class of μ(s) (NaN a: the class's typical a)."""
        if math.isfinite(self._t_last) and t > self._t_last:
            dt = t - self._t_last
            self._period = dt if not self._period > 0.0 else 0.9 * self._period + 0.1 * dt
        cfg = self.cfg
        good = ok and self._sample_ok(v, omega, mu, accel)
        if good:
            cls = curve_class(class_name) or SOIL_CLASSES["stubble"]
            aa = a if a > 0.0 else cls.a_typical
            mf, mr = 0.5 * (mu[0] + mu[1]), 0.5 * (mu[2] + mu[3])
            xf = slip_at(mf, aa, cls.p, cls.alpha1, cls.alpha2)
            xr = slip_at(mr, aa, cls.p, cls.alpha1, cls.alpha2)
            good = xf <= cfg.max_slip and xr <= cfg.max_slip          # NaN fails
        if not good:
            self.rejected += 1
            if self._blk[4]:
                self._end_block()
            self._t_last = t
            return
        va = abs(v)
        yf = va / (rdf * 0.5 * abs(omega[0] + omega[1]))
        yr = va / (rdr * 0.5 * abs(omega[2] + omega[3]))
        if not self._blk[4]:
            self._t0 = t
        b = self._blk
        b[0] += yf
        b[1] += xf
        b[2] += yr
        b[3] += xr
        b[4] += 1
        self.samples += 1
        self._t_last = t
        n = self._blk[4]
        if n >= 2 and (t - self._t0) * n / (n - 1) >= cfg.block_s - 1e-9:     # n samples cover n periods
            self._end_block()

    def _sample_ok(self, v: float, omega: list[float], mu: list[float], accel: float) -> bool:
        cfg = self.cfg
        if not (abs(v) >= cfg.min_speed_mps and abs(accel) <= cfg.max_accel_mps2):
            return False
        sgn = 1.0 if v > 0.0 else -1.0
        for i in (0, 2):
            wl, wr = omega[i] * sgn, omega[i + 1] * sgn
            mean = 0.5 * (wl + wr)
            if not (wl > 0.0 and wr > 0.0) or abs(wl - wr) > cfg.max_turn_rel * mean:
                return False
            if not abs(0.5 * (mu[i] + mu[i + 1])) <= cfg.max_mu:
                return False
        return True

    def state(self) -> tuple[AxleScale, AxleScale]:
        """(front, rear) scale estimates."""
        return self._axles[0].state(), self._axles[1].state()

    def radius_sigma(self, tol_sigma: float) -> tuple[float, float]:
        """Standard uncertainty of the radius in use per axle [-]: the calibration's (95 % half-width / 1.96)
        once applied, else ``tol_sigma`` (the tyre tolerance's)."""
        out = []
        for ax in self._axles:
            out.append(ax.hw / 1.96 if ax.is_applied and math.isfinite(ax.hw) and ax.hw / 1.96 < tol_sigma
                       else tol_sigma)
        return out[0], out[1]

    def summary(self) -> dict[str, dict[str, float | int | bool]]:
        """Per axle: scale, 95 % half-width (None until estimated), accepted blocks, applied scale and whether it
        is applied."""
        out: dict[str, dict[str, float | int | bool]] = {}
        for name, st, ax in zip(AXLES, self.state(), self._axles):
            out[name] = {"scale": _num(st.scale), "halfwidth95": _num(st.halfwidth), "blocks": st.blocks,
                         "applied_scale": st.applied, "applied": ax.is_applied}
        return out


def _num(x: float) -> float | None:
    """x, or None for NaN (a summary written as JSON)."""
    return None if math.isnan(x) else x
