"""Path curvature and the course-against-heading direction test (kinematics in turns).

The estimator's model (:mod:`tractionecu.model.vehicle`, "Kinematics in
turns") needs the path curvature κ [1/m] of the rear-axle centre, κ = ψ̇/v.
Two sources measure it:

* the **rear wheels** (not steered, on the reference axle): with equal slip
  on both sides, r ω_RR / r ω_RL = (1 + κb/2)/(1 − κb/2), so

      κ_w = (2/b)·(ω_RR − ω_RL)/(ω_RR + ω_RL),

  b the track width, for either sign of travel and whatever the common slip.
  Precise (wheel-speed noise of a few 0.1 %), but a slip difference Δs =
  s_RR − s_RL between the two wheels reads as curvature: κ_w ≈ κ + Δs/b;
* the **GNSS course over ground** (RMC/VTG): unbiased, but its noise,
  σ_χ ≈ σ_v/|v| per epoch (the Doppler velocity noise across the track,
  ``SensorSpec.gps_speed_sigma``), makes a differentiated course useless at
  work speed (0.02 rad per epoch at 2.5 m/s, 0.3 rad/s between 10 Hz epochs).

:class:`CurvatureFilter` fuses them as a heading filter fuses a gyro with a
GNSS course: the state is (heading h, curvature bias β = Δs/b); h is
propagated with (κ_w − β)·v, v the estimator's signed speed, and every GNSS
epoch (|v| above ``min_speed``) updates h with the course, turned by 180° in
reverse.  β is a first-order Gauss–Markov process in the distance
travelled, dβ/ds = −β/D + w, D = :data:`BIAS_DIST_M`, whose stationary
standard deviation is a rear slip difference of :data:`SLIP_DIFF_MAX` over
the track (an assumption: lateral load transfer at 30 m radius and 2.5 m/s
moves about 4 % of a rear wheel's load, a few thousandths of slip, and soil
varies under the two tracks; both change with the ground and the path under
the wheels, so with distance, not time):

    β ← φ β,   P_ββ ← φ² P_ββ + σ_β² (1 − φ²),   P_hβ ← φ P_hβ,
    φ = exp(−|v| Δt / D),   σ_β = SLIP_DIFF_MAX / b.

A slip difference is bounded and forgets itself (it follows the torques,
loads and soil of the moment); a random walk would let β drift without
bound, and then a course that turns while the wheels do not (a heading
disagreement that no slip difference explains) is absorbed into a bias of
several σ_β, which then bends every wheel's ground speed long after the
turn (0.11 1/m, 20 σ_β, after the 9 m quarter circles of ``headland-reverse``
on the paper truth, whose wheels all roll at v).  A bounded variance alone
does not stop a persistent disagreement from pulling β̂ into the tail (0.095
1/m on the same quarter circle, ``tests/estimation/test_kinematics.py``): an
estimate beyond :data:`BETA_MAX_SIGMAS` σ_β is
no slip difference, and the heading restarts from the course with β = 0,
so κ stays the wheels' within a plausible slip difference; the wheels
measure the ground speeds that each wheel's slip is taken against.  At
standstill (:meth:`CurvatureFilter.standstill`) there is no slip,
so no slip difference: β returns to 0 with its stationary variance.
κ = κ_w − β̂ with the variance of the (low-passed) wheel term plus P_ββ.  Without GNSS the wheel term is used
alone and P_ββ grows back to σ_β²; without wheel speeds, or below ``min_speed``, κ is not
known (0 with an infinite variance: the caller limits it).

The wheel term is low-passed with :data:`YAW_TAU_S`: the curvature of a
work pass changes over metres (a clothoid between S-curve arcs), the
wheel-speed noise over one sample.  The heading integrates the unfiltered
wheel term (its integral averages the noise, and the low pass's lag would
become a heading error that the course then explains as a bias).

Heading convention: course convention (clockwise from true north, rad), so
h decreases in a left turn: ḣ = −κ v.

Direction test: once the heading is known (σ_h below ``sigma_max_rad``),
a course within 60° of the heading means forwards and within 60° of the
opposite means reverse (:meth:`CurvatureFilter.course_direction`); the
estimator uses it when neither the machine's direction bit nor the sign of
wheel rotation decides.
"""

from __future__ import annotations

import math

__all__ = ["BIAS_DIST_M", "BIAS_TAU_S", "CurvatureFilter", "SLIP_DIFF_MAX", "YAW_TAU_S"]

SLIP_DIFF_MAX = 0.01
"""Stationary standard deviation of the rear slip difference (right − left) [-] (module doc)."""

BIAS_DIST_M = 25.0
"""Correlation distance of that difference [m] (module doc)."""

BIAS_TAU_S = 10.0
"""Its correlation time at work speed (2.5 m/s) [s]: the curvature error's correlation time in the estimator's
process noise."""

YAW_TAU_S = 0.03
"""Time constant of the low pass on the wheel curvature [s] (module doc).  A ramp κ̇ is lagged by κ̇·τ: between
two S-curve arcs of 30 m the curvature turns by 2/30 1/m within about a second, so 0.1 s lagged it by
0.006 1/m there (measured on ``s-curves-30m``: the mean curvature error in work was 0.0022 1/m, 0.0059 in the
transitions); the wheel term's own noise, ≈ 0.0013 1/m per 100 Hz sample with the datasheet wheel-speed noise,
through a low pass of τ is ≈ 0.0013·√(Δt/2τ), 0.0005 1/m at 0.03 s: the sum of both is smallest near 0.02–0.03 s."""

FAR_EPOCHS = 5
"""GNSS epochs in a row with the course far outside the heading's gate (16 σ²) after which the heading is
restarted from the course and the bias forgotten: a heading that refuses every course can never recover."""

BETA_MAX_SIGMAS = 3.0
"""A bias estimate beyond this many stationary σ_β (a rear slip difference of 3 × SLIP_DIFF_MAX) is not a slip
difference: the course disagrees with the wheels (a truth or machine whose wheel speeds do not follow the path, a
wrong track width, side slip); the heading restarts from the course with β = 0 (module doc)."""

BETA0_VAR_FACTOR = 1.0
"""Initial variance of the bias in units of (SLIP_DIFF_MAX / b)²."""

SIGMA_H0 = math.pi
"""Initial heading uncertainty [rad] (unknown until the first GNSS course)."""


def _wrap(a: float) -> float:
    """Angle into (−π, π]."""
    return a - 2.0 * math.pi * math.floor((a + math.pi) / (2.0 * math.pi))


class CurvatureFilter:
    """Heading and curvature bias from the rear wheel speeds and the GNSS course (module doc).

    Parameters
    ----------
    track_m : rear track width b [m].
    course_sigma_mps : GNSS velocity noise across the track [m/s] (σ_χ = this / |v|).
    min_speed_mps : no course update and no curvature below this speed [m/s].
    """

    def __init__(self, track_m: float, course_sigma_mps: float, min_speed_mps: float = 0.5) -> None:
        self.b = float(track_m)
        self.course_sigma = max(float(course_sigma_mps), 1e-4)
        self.min_speed = float(min_speed_mps)
        self.var_beta = (SLIP_DIFF_MAX / self.b) ** 2                      # stationary P_ββ [1/m²]
        self.reset()

    def reset(self) -> None:
        """Forget the heading and the bias."""
        self.h = math.nan
        """Heading [rad], course convention; NaN until the first GNSS course."""
        self.P = [SIGMA_H0 ** 2, 0.0, BETA0_VAR_FACTOR * self.var_beta]     # P_hh, P_hβ, P_ββ
        self._far = 0
        self.beta = 0.0
        """Curvature bias of the wheel term [1/m]."""
        self.kappa_w = math.nan
        """Low-passed wheel curvature κ_w [1/m]."""
        self.var_w = math.inf
        """Its variance [1/m²]."""
        self._k_raw = math.nan              # the last sample's wheel curvature, unfiltered [1/m], and its variance
        self._var_raw = math.inf
        self.v = 0.0
        self.restarts = 0
        """Times the heading was restarted from the course (:data:`FAR_EPOCHS`)."""
        self._t = math.nan
        self._tw = math.nan

    # ------------------------------------------------------------------ sources
    def wheels(self, t: float, w_rl: float, w_rr: float, var_rl: float, var_rr: float, v: float) -> None:
        """Rear wheel speeds ω_RL, ω_RR [rad/s] at t [s] with their noise variances, and the signed
        speed v [m/s] of the rear-axle centre (the heading moves with κ v; None or NaN: unknown, taken as 0)."""
        sm = w_rr + w_rl
        if not math.isfinite(sm) or abs(sm) < 1e-9:
            return
        self._predict(t)
        # an unknown speed (no GNSS yet and no axle load for the rolling radius) moves nothing: the heading
        # and the bias hold until a speed arrives
        self.v = v if v is not None and math.isfinite(v) else 0.0
        k = 2.0 / self.b * (w_rr - w_rl) / sm
        # ∂κ_w/∂ω_RR = (4/b) ω_RL / sm², ∂κ_w/∂ω_RL = −(4/b) ω_RR / sm²
        g = 4.0 / (self.b * sm * sm)
        var = g * g * (w_rl * w_rl * var_rr + w_rr * w_rr * var_rl)
        self._k_raw, self._var_raw = k, var
        dt = t - self._tw if self._tw == self._tw else math.inf
        self._tw = t
        if not self.kappa_w == self.kappa_w or not dt < 10.0 * YAW_TAU_S:
            self.kappa_w, self.var_w = k, var
            return
        a = dt / (YAW_TAU_S + dt)
        self.kappa_w += a * (k - self.kappa_w)
        # white input noise through the low pass (a/(2 − a) of it once settled)
        self.var_w = (1.0 - a) * (1.0 - a) * self.var_w + a * a * var

    def _predict(self, t: float) -> None:
        dt = t - self._t if self._t == self._t else 0.0
        self._t = t
        if not dt > 0.0:
            return
        P = self.P
        if self.h == self.h and self._k_raw == self._k_raw:
            # ḣ = −(κ_w − β) v: h ← h − (κ_w − β) v dt, ∂h/∂β = v dt.  The heading integrates the
            # unfiltered wheel curvature (the integral itself averages its noise): the low pass's lag,
            # integrated over a change of curvature (0.1 s × 2/30 1/m × 2.5 m/s ≈ 0.017 rad between two
            # S-curve arcs), would be a heading error that the course then explains as a bias
            vd = self.v * dt
            self.h = _wrap(self.h - (self._k_raw - self.beta) * vd)
            phh = P[0] + 2.0 * vd * P[1] + vd * vd * P[2] + self._var_raw * vd * vd
            phb = P[1] + vd * P[2]
            P[0], P[1] = phh, phb
        # β: first-order Gauss–Markov (module doc)
        phi = math.exp(-abs(self.v) * dt / BIAS_DIST_M)
        self.beta *= phi
        P[1] *= phi
        P[2] = phi * phi * P[2] + self.var_beta * (1.0 - phi * phi)

    def standstill(self) -> None:
        """The machine stands: no slip, so no slip difference; β returns to 0 with its stationary
        variance and its correlation with the heading is dropped (module doc).  The heading is kept."""
        self.beta = 0.0
        self.P[1] = 0.0
        self.P[2] = self.var_beta

    def course(self, t: float, course_deg: float, speed_mps: float, direction: float) -> None:
        """A GNSS course over ground [deg from north] at t [s] with the speed [m/s] and the direction of travel
        (+1 forwards, −1 reverse: the course then points 180° from the heading)."""
        if not (math.isfinite(course_deg) and math.isfinite(speed_mps)) or abs(speed_mps) < self.min_speed:
            return
        self._predict(t)
        z = math.radians(course_deg) + (math.pi if direction < 0 else 0.0)
        r = (self.course_sigma / abs(speed_mps)) ** 2
        if self.h != self.h:
            self.h = _wrap(z)
            self.P[0] = r
            self.P[1] = 0.0
            return
        P = self.P
        nu = _wrap(z - self.h)
        s = P[0] + r
        if nu * nu > 16.0 * s:
            # a course far from the heading: a direction change not seen yet, or a glitch; the
            # heading is not moved by it.  Persistently far: the heading (or the bias that moved it)
            # is wrong: start again from the course, the bias unknown
            self._far += 1
            if self._far >= FAR_EPOCHS:
                self.restarts += 1
                self.h = _wrap(z)
                self.beta = 0.0
                self.P[:] = [r, 0.0, BETA0_VAR_FACTOR * self.var_beta]
                self._far = 0
            return
        self._far = 0
        kh, kb = P[0] / s, P[1] / s
        self.h = _wrap(self.h + kh * nu)
        self.beta += kb * nu                 # β is seen through its correlation with h (P_hβ)
        p00, p01, p11 = P
        P[0] = p00 - kh * p00
        P[1] = p01 - kh * p01
        P[2] = p11 - kb * p01
        if self.beta * self.beta > BETA_MAX_SIGMAS * BETA_MAX_SIGMAS * self.var_beta:
            # no slip difference explains what the course says the wheels do not (module doc): the wheels
            # measure the ground speeds the slip needs; start the heading again from the course
            self.restarts += 1
            self.h = _wrap(z)
            self.beta = 0.0
            self.P[:] = [r, 0.0, self.var_beta]

    # ------------------------------------------------------------------ outputs
    def curvature(self, v: float, min_speed_mps: float) -> tuple[float, float]:
        """(κ [1/m], its variance [1/m²]) of the rear-axle centre moving at the signed speed v [m/s].

        Below ``min_speed_mps`` (or without wheel speeds) the curvature is not known: (0, ∞).
        """
        if not self.kappa_w == self.kappa_w or abs(v) < min_speed_mps:
            return 0.0, math.inf
        return self.kappa_w - self.beta, self.var_w + self.P[2]


    def course_direction(self, course_deg: float, speed_mps: float, sigma_max_rad: float = 0.35) -> float:
        """+1 when the course points along the heading, −1 when against it, 0 when undecided."""
        if (self.h != self.h or not math.isfinite(course_deg) or abs(speed_mps) < self.min_speed
                or self.P[0] > sigma_max_rad * sigma_max_rad):
            return 0.0
        d = abs(_wrap(math.radians(course_deg) - self.h))
        if d < math.pi / 3.0:
            return 1.0
        if d > 2.0 * math.pi / 3.0:
            return -1.0
        return 0.0
