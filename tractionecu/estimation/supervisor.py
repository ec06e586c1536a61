"""Adaptation of the process noise: fuzzy-logic supervisor and covariance matching.

Paper section 3.1: the effective state noise covariance is A_k·Q, with the
adaptation matrix A_k from covariance matching over the last M innovations
(eqs. 16–17, after Jiang et al. 2007), and a fuzzy-logic system (FLS) that
"sets the adaptation factor high if the vehicle undergoes a phase of intense
dynamics, small if the dynamics are steady" (Abdelnour et al. 1993;
Osinenko et al. 2014, 2015).  The estimator uses

    Q_k = Q_in,k + f_k · A_k · Q_tune · Δt

with Q_in the input-noise part (from the sensor specs, not adapted), Q_tune
the diagonal random-walk densities of the tuning, A_k = diag(a_1..a_n) from
:class:`CovarianceMatching` and f_k from :class:`FuzzySupervisor`.

Fuzzy supervisor
----------------
Inputs (both low-pass filtered by :class:`DynamicsMonitor`):

* e₁ = |dv/dt| [m/s²], ground acceleration of the estimated speed;
* e₂ = |dM_d/dt| [N·m/s], rate of change of the total drive torque ΣM_d,i.

Memberships (trapezoid ``trap(a, b, c, d)``, triangle ``tri(a, b, c)``;
breakpoints are :class:`FuzzyConfig` fields):

=========  ===========================  ===========================
set        e₁ = |dv/dt|                 e₂ = |dM_d/dt|
=========  ===========================  ===========================
LOW        trap(0, 0, a₁, a₂)           trap(0, 0, m₁, m₂)
MEDIUM     tri(a₁, a₂, a₃)              tri(m₁, m₂, m₃)
HIGH       trap(a₂, a₃, ∞, ∞)           trap(m₂, m₃, ∞, ∞)
=========  ===========================  ===========================

Output: intensity c ∈ [0, 1] with SMALL = tri(0, 0, 0.5),
MEDIUM = tri(0.25, 0.5, 0.75), LARGE = tri(0.5, 1, 1).

Rule table (rows e₁, columns e₂):

==============  ========  ========  ========
|dv/dt| \\ |dM/dt|  LOW       MEDIUM    HIGH
==============  ========  ========  ========
LOW             SMALL     MEDIUM    LARGE
MEDIUM          MEDIUM    MEDIUM    LARGE
HIGH            LARGE     LARGE     LARGE
==============  ========  ========  ========

Inference is Mamdani: AND = min, implication = min (clipping), aggregation =
max; defuzzification = centroid ∫c·μ(c)dc / ∫μ(c)dc of the aggregated set,
integrated with the trapezoid rule on a uniform grid of the output universe.  The adaptation factor is the log-linear map
f = f_min·(f_max/f_min)^c, so MEDIUM (c = 0.5) gives the geometric mean.

Covariance matching
-------------------
Paper eq. 17: S̄_k = 1/(M−1) Σ_{i=k−M+1..k} ν_i ν_iᵀ.  In state space the
corrections Δx_i = K_i ν_i have the empirical covariance K S̄ Kᵀ and the model
covariance K S Kᵀ (= P_{k|k−1} − P_{k|k}).  Eq. 16 asks for the A_k that
matches the two; with a diagonal A_k and the parameter states dominated by
their random-walk noise the solution is the per-state ratio

    a_j = Σ_window (Δx_j)² / Σ_window (K S Kᵀ)_jj,   clipped to [A_min, A_max]

(Mohamed & Schwarz 1999, covariance matching; Jiang et al. 2007 use it for the
UKF).  Windowed sums over the last M updates make it work with partial
updates of varying size (wheels at 100 Hz, GPS at 10 Hz).

Equation numbers follow the paper's source; see :mod:`tractionecu.estimation`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..config import setting, validate
from ..errors import ConfigError
from . import _kernels
from ._kernels import JIT


# --------------------------------------------------------------------- memberships
def trimf(x: ArrayLike, a: float, b: float, c: float) -> NDArray[np.float64]:
    """Triangular membership with feet a, c and peak b (a ≤ b ≤ c); a == b or b == c give shoulders."""
    x = np.asarray(x, dtype=float)
    left = np.ones_like(x) if b == a else (x - a) / (b - a)
    right = np.ones_like(x) if c == b else (c - x) / (c - b)
    y = np.minimum(left, right)
    y = np.where((x < a) | (x > c), 0.0, y)
    return np.clip(y, 0.0, 1.0)


def trapmf(x: ArrayLike, a: float, b: float, c: float, d: float) -> NDArray[np.float64]:
    """Trapezoidal membership: 0 below a, rising to 1 at b, 1 up to c, falling to 0 at d (∞ allowed)."""
    x = np.asarray(x, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        rise = np.ones_like(x) if b == a else (x - a) / (b - a)
        fall = np.ones_like(x) if (d == c or math.isinf(d)) else (d - x) / (d - c)
    y = np.minimum(np.minimum(rise, 1.0), fall)
    y = np.where(x < a, 0.0, y)
    if not math.isinf(d):
        y = np.where(x > d, 0.0, y)
    return np.clip(y, 0.0, 1.0)


@dataclass(frozen=True)
class FuzzyConfig:
    """Breakpoints and output range of the fuzzy supervisor."""

    accel_low_mps2: float = setting(0.06, "|dv/dt| where LOW starts to fall (a₁) [m/s²]", 0.0, 10.0)
    accel_mid_mps2: float = setting(0.15, "|dv/dt| peak of MEDIUM (a₂) [m/s²]", 0.0, 10.0)
    accel_high_mps2: float = setting(0.30, "|dv/dt| where HIGH is full (a₃) [m/s²]", 0.0, 10.0)
    torque_rate_low_nmps: float = setting(2000.0, "|dΣM_d/dt| where LOW starts to fall (m₁) [N·m/s]", 0.0, 1e7)
    torque_rate_mid_nmps: float = setting(5000.0, "|dΣM_d/dt| peak of MEDIUM (m₂) [N·m/s]", 0.0, 1e7)
    torque_rate_high_nmps: float = setting(10000.0, "|dΣM_d/dt| where HIGH is full (m₃) [N·m/s]", 0.0, 1e7)
    factor_min: float = setting(0.5, "adaptation factor at intensity 0 (steady) [-]", 1e-3, 1e3)
    factor_max: float = setting(8.0, "adaptation factor at intensity 1 (intense) [-]", 1e-3, 1e3)
    grid_points: int = setting(101, "points of the output universe used for the centroid [-]", 11, 10001)

    def __post_init__(self) -> None:
        validate(self, "estimator.fuzzy")
        if not (self.accel_low_mps2 < self.accel_mid_mps2 < self.accel_high_mps2):
            raise ConfigError("estimator.fuzzy.accel_*_mps2: need low < mid < high")
        if not (self.torque_rate_low_nmps < self.torque_rate_mid_nmps < self.torque_rate_high_nmps):
            raise ConfigError("estimator.fuzzy.torque_rate_*_nmps: need low < mid < high")
        if not self.factor_min <= self.factor_max:
            raise ConfigError(f"estimator.fuzzy.factor_min = {self.factor_min} must be ≤ "
                              f"estimator.fuzzy.factor_max = {self.factor_max}")


# Output sets on the intensity universe [0, 1] and the rule table (row: |dv/dt|, column: |dM/dt|).
SMALL, MEDIUM, LARGE = 0, 1, 2
OUTPUT_SETS = ((0.0, 0.0, 0.5), (0.25, 0.5, 0.75), (0.5, 1.0, 1.0))
RULES = np.array([[SMALL, MEDIUM, LARGE],
                  [MEDIUM, MEDIUM, LARGE],
                  [LARGE, LARGE, LARGE]])


_RULES_L = RULES.tolist()


def _min(a: float, b: float) -> float:
    """np.minimum of two floats (NaN if either is NaN)."""
    if a != a or b != b:
        return math.nan
    return a if a <= b else b


def _max(a: float, b: float) -> float:
    """np.maximum of two floats (NaN if either is NaN)."""
    if a != a or b != b:
        return math.nan
    return a if a >= b else b


def _tri1(x: float, a: float, b: float, c: float) -> float:
    """:func:`trimf` of one float."""
    left = 1.0 if b == a else (x - a) / (b - a)
    right = 1.0 if c == b else (c - x) / (c - b)
    y = 0.0 if (x < a or x > c) else _min(left, right)
    return _min(_max(y, 0.0), 1.0)


def _trap1(x: float, a: float, b: float, c: float, d: float) -> float:
    """:func:`trapmf` of one float (b > a, or the rise is 1)."""
    rise = 1.0 if b == a else (x - a) / (b - a)
    fall = 1.0 if (d == c or math.isinf(d)) else (d - x) / (d - c)
    y = _min(_min(rise, 1.0), fall)
    if x < a or (not math.isinf(d) and x > d):
        y = 0.0
    return _min(_max(y, 0.0), 1.0)


class FuzzySupervisor:
    """Mamdani fuzzy system mapping dynamic intensity to the Q adaptation factor (rule table in module doc)."""

    def __init__(self, cfg: FuzzyConfig | None = None):
        self.cfg = c = cfg or FuzzyConfig()
        self.grid = np.linspace(0.0, 1.0, c.grid_points)
        self.out_mf = np.stack([trimf(self.grid, *abc) for abc in OUTPUT_SETS])   # (3, G)
        h = self.grid[1] - self.grid[0]
        self._w = np.full(self.grid.size, h)          # trapezoid-rule weights
        self._w[[0, -1]] = 0.5 * h
        self._xw = self.grid * self._w
        self.centroid_table = np.ascontiguousarray(np.vstack([self.out_mf, self._w, self._xw]))
        """(5, G): the output sets, the trapezoid weights w and x·w (:func:`._kernels.fuzzy_centroid`'s ``fz``)."""
        self._log_ratio = math.log(c.factor_max / c.factor_min)
        self._memo: dict[tuple[float, float, float], float] = {}
        self._st = np.empty(3)

    def memberships(self, accel_abs: float, torque_rate_abs: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Degrees (LOW, MEDIUM, HIGH) of e₁ = |dv/dt| [m/s²] and e₂ = |dM_d/dt| [N·m/s]."""
        mu1, mu2 = self._degrees(accel_abs, torque_rate_abs)
        return np.array(mu1, dtype=float), np.array(mu2, dtype=float)

    def _degrees(self, accel_abs: float, torque_rate_abs: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """:meth:`memberships` as floats (scalar :func:`trapmf` / :func:`trimf`, same operations)."""
        c = self.cfg
        a1, a2, a3 = c.accel_low_mps2, c.accel_mid_mps2, c.accel_high_mps2
        m1, m2, m3 = c.torque_rate_low_nmps, c.torque_rate_mid_nmps, c.torque_rate_high_nmps
        e1 = abs(float(accel_abs))
        e2 = abs(float(torque_rate_abs))
        return ((_trap1(e1, 0.0, 0.0, a1, a2), _tri1(e1, a1, a2, a3), _trap1(e1, a2, a3, math.inf, math.inf)),
                (_trap1(e2, 0.0, 0.0, m1, m2), _tri1(e2, m1, m2, m3), _trap1(e2, m2, m3, math.inf, math.inf)))

    def intensity(self, accel_abs: float, torque_rate_abs: float) -> float:
        """Defuzzified intensity c ∈ [0, 1] (centroid of the aggregated output set)."""
        if JIT:                                                # the same as the loop below, compiled
            c = self.cfg
            st = self._st
            _kernels.fuzzy_strengths(abs(float(accel_abs)), abs(float(torque_rate_abs)), c.accel_low_mps2,
                                     c.accel_mid_mps2, c.accel_high_mps2, c.torque_rate_low_nmps,
                                     c.torque_rate_mid_nmps, c.torque_rate_high_nmps, RULES, st)
            strength = st.tolist()
        else:
            mu1, mu2 = self._degrees(accel_abs, torque_rate_abs)
            strength = [0.0, 0.0, 0.0]
            for i in range(3):                                 # AND = min, one strength per output set (max)
                for j in range(3):
                    k = _RULES_L[i][j]
                    strength[k] = _max(strength[k], _min(mu1[i], mu2[j]))
        # c is a function of the three strengths alone: steady driving repeats the same ones (all LOW:
        # (1, 0, 0)), and their centroid is kept rather than integrated again
        key = (strength[0], strength[1], strength[2])
        c = self._memo.get(key)
        if c is not None:
            return c
        # the centroid summed in grid order by one function, compiled or not: the compiled loop calls the same
        c = _kernels.fuzzy_centroid(key[0], key[1], key[2], self.centroid_table)
        if len(self._memo) >= 64:
            self._memo.clear()
        self._memo[key] = c
        return c

    def factor(self, accel_abs: float, torque_rate_abs: float) -> float:
        """Adaptation factor f = f_min·(f_max/f_min)^c [-]."""
        return self.cfg.factor_min * math.exp(self._log_ratio * self.intensity(accel_abs, torque_rate_abs))


class DynamicsMonitor:
    """Low-pass filtered |dv/dt| [m/s²] and |dΣM_d/dt| [N·m/s] for the supervisor.

    Speed and total torque are first smoothed with first-order low-pass filters
    of time constant ``tau_s`` [s], differentiated by backward difference and
    smoothed again with the same time constant.  Deterministic for a given
    sequence of (t, v, ΣM_d).
    """

    def __init__(self, tau_s: float = 0.2):
        if not tau_s > 0:
            raise ValueError("tau_s must be > 0")
        self.tau = float(tau_s)
        self._t: float | None = None
        self._v = 0.0
        self._m = 0.0
        self.accel = 0.0
        """Filtered dv/dt [m/s²]."""
        self.torque_rate = 0.0
        """Filtered dΣM_d/dt [N·m/s]."""
        self._dt = math.nan
        self._k = math.nan

    def update(self, t: float, v: float, m_total: float) -> None:
        if self._t is None:
            self._t, self._v, self._m = t, v, m_total
            return
        dt = t - self._t
        if not dt > 0.0:                    # also a NaN time: it would make the filtered rates NaN for good
            return
        if dt != self._dt:                  # the step period repeats: the same gain
            self._dt = dt
            self._k = 1.0 - math.exp(-dt / self.tau)
        k = self._k
        v_new = self._v + k * (v - self._v)
        m_new = self._m + k * (m_total - self._m)
        self.accel += k * ((v_new - self._v) / dt - self.accel)
        self.torque_rate += k * ((m_new - self._m) / dt - self.torque_rate)
        self._t, self._v, self._m = t, v_new, m_new


class CovarianceMatching:
    """Diagonal adaptation matrix A_k from the last M state corrections (paper eqs. 16–17).

    Parameters
    ----------
    n : state dimension.
    window : M, the number of updates in the window [-].
    a_min, a_max : clip range of the diagonal entries [-].
    """

    def __init__(self, n: int, window: int, a_min: float, a_max: float):
        if window < 2:
            raise ValueError("window M must be ≥ 2")
        self.n = n
        self.M = int(window)
        self.a_min, self.a_max = float(a_min), float(a_max)
        self._emp = np.zeros((self.M, n))    # (Δx_j)² per update
        self._mod = np.zeros((self.M, n))    # (K S Kᵀ)_jj per update
        self._i = 0
        self.count = 0
        self.A = np.ones(n)
        """Current diagonal of A_k [-]."""

    def push(self, dx: NDArray[np.float64], ksk_diag: NDArray[np.float64]) -> None:
        """Add one update's correction Δx = Kν (n,) and diag(K S Kᵀ) (n,)."""
        i = self._i
        if JIT:
            _kernels.cm_push(self._emp, self._mod, i, dx, ksk_diag)
        else:
            np.multiply(dx, dx, out=self._emp[i])
            self._mod[i] = ksk_diag
        i += 1
        self._i = 0 if i == self.M else i
        if self.count < self.M:
            self.count += 1

    def compute(self) -> NDArray[np.float64]:
        """Recompute A_k from the window (A = 1 until the window is full)."""
        if self.count < self.M:
            self.A = np.ones(self.n)
            return self.A
        if JIT:
            A = np.empty(self.n)
            _kernels.cm_ratio(self._emp, self._mod, self.a_min, self.a_max, A)
            self.A = A
            return A
        with np.errstate(divide="ignore", invalid="ignore"):
            r = self._emp.sum(axis=0) / self._mod.sum(axis=0)
        r = np.where(np.isfinite(r), r, 1.0)
        self.A = np.clip(r, self.a_min, self.a_max)
        return self.A
