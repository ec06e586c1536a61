"""AUKF-FS estimator with a push API: ``Estimator.step(t, inputs, measurements) -> Estimate``.

Its tuning, :class:`EstimatorConfig` and :func:`load_estimator_config`, lives
in :mod:`.config` and is re-exported here; the divergence monitor and the
bus-rate trackers have their own modules.  The rest stays in one module
(about 600 lines): the noise model, the step with its input holds, timeouts
and status bits, and the hand-over to the curve fit act on one filter state
in one order, which the paper's section 3 describes as one algorithm.

Paper section 3: state x = (ω1..4, v, μ1..4, ρ_s), output y = (ω1..4, v),
input u = (M_d1..4, F_zf, F_dx).  Sigma points go through
:meth:`tractionecu.model.vehicle.FilterModel.step` (eqs. 2, 4, 8, 9 with RK4)
in one call per step (:mod:`.ukf`); the process noise is adapted by
covariance matching and the fuzzy supervisor (:mod:`.supervisor`, eqs.
16–17); a and the surface class come from (μ̂, ŝ) pairs (:mod:`.curve`,
eq. 18); slip is eq. 6 with r_d from eqs. 9–10.  Beyond the paper, from the vehicle file: the reported
motor torque reaches the wheel as η M − c ω (hub efficiency, ``drivetrain.hub_drag_nms``), and with a
declared ``tyre_carcass_stiffness_npm`` μ follows slip through the carcass (:meth:`Estimator._relax`,
model doc "Tyre carcass"); with a declared two-inertia hub as well (``drivetrain.hub_stiffness_nmprad``,
``hub_damping_nmsprad``, ``hub_motor_inertia_kgm2``) the filter carries the motor speeds the pickup measures,
the rim speeds and the hub twists, 18 states, while the carcass term is on (:meth:`Estimator._set_hub`, model
doc "Two-inertia hub"); at wheel-speed rates too slow for the carcass term on the paper's model (20 Hz) the
hub's filter is the period-mean filter, 26 states, which takes each wheel-speed sample as the mean over its
period and carries the carcass's relaxed slips (:meth:`Estimator._pm_wanted`, model doc "Period-mean wheel
speeds").

Noise model
-----------
Measurement noise R comes from :class:`~tractionecu.config.SensorSpec`
(the machine's sensor figures: vehicle file and service ``[sensors]``,
else the documented defaults), never from the truth:

    R_ω,i = (σ_ω,abs + σ_ω,rel |ω_i|)² + q_ω²/12,   R_v = σ_gps,v².

With a declared tyre carcass whose mode the wheel-speed rate cannot follow (the carcass term off,
:meth:`Estimator._relax`), R_ω,i is the larger of that and the mode's variance in the samples, estimated
from the innovations (:meth:`Estimator._ring_noise`).

Process noise Q_k = Q_in,k + f_k · A_k · diag(q) · Δt (see :mod:`.supervisor`):

* Q_in is the measured-input noise (same SensorSpec) mapped through the
  model: torque noise σ_M,i = σ_abs + σ_rel |M_d,i| acts on ω̇_i with gain
  1/J; axle-load noise on all wheel torques and on v̇ through F_z = (F_zf/2,
  F_zf/2, (mg−F_zf)/2, (mg−F_zf)/2); draft noise on v̇ with gain −1/m.  A
  held (zero-order-hold) white sample of variance σ² and period T has the
  spectral density σ² T, hence Q_in = G Σ_u Gᵀ·T·Δt, with each input's T
  as observed on the bus (:mod:`.rates`; the SensorSpec rate until then).
* q = (q_ω ×4, q_v, q_μ ×4, q_ρ) are the tuning densities: model error for
  ω and v, random walks for μ and ρ_s (paper: "their dynamics are neglected").

Timing and robustness
---------------------
Inputs given at t are the inputs over (t_prev, t]; each key is held
(zero-order hold) until it is refreshed.  An input that is None, NaN or
Inf is rejected (the held value stays, bit 0x40) and the step is predict
only.  A sensor not refreshed within its timeout (its configured floor or
``timeout_periods`` of its observed period, the longer: :mod:`.rates`) sets
its status bit; an input timeout makes the step predict only; a missing
measurement simply skips its part of the update.  Gaps longer than ``max_step_s`` are
predicted in sub-steps.  Nothing depends on wall-clock time, so the same
input sequence always gives the same estimates (offline = online).

Equation numbers follow the paper's source; see :mod:`tractionecu.estimation`.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
from numpy.typing import NDArray
from scipy.special import erfcinv

from ..config import G, SensorSpec, VehicleParams
from ..errors import EstimatorError
from ..model.mucurve import SOIL_CLASSES
from ..model.vehicle import (IU_KAPPA, IX_MU, IX_OMEGA, IX_OMEGA_W, IX_PMEAN, IX_RELAX, IX_RHO, IX_TWIST, IX_V,
                             N_INPUT, N_STATE, N_STATE_HUB, N_STATE_PMEAN, FilterModel, relax_slips,
                             relax_slips_own, wheel_radii, wheel_speed_factor_slopes)
from . import _kernels
from ._kernels import JIT
from .config import EstimatorConfig, load_estimator_config  # noqa: F401  (load_estimator_config: re-exported)
from .calibration import RadiusCalibration
from .curve import CurveEstimator
from .divergence import DivergenceMonitor
from .kinematics import BIAS_TAU_S, CurvatureFilter
from .rates import BusRates
from .supervisor import CovarianceMatching, DynamicsMonitor, FuzzySupervisor
from .ukf import UnscentedFilter
from .uncertainty import SystematicUncertainty

SLIP_STEADY_S = 1.0
"""Time [s] over which a wheel's rolled speed must be steady for an averaged slip to stand for the slip now
(:meth:`Estimator._slip_window`): the drive-line's and the tyre's slip transients after a change of speed at
1 m/s settle within about a second."""


# ----------------------------------------------------------------------------- status bits
WHEEL_TIMEOUT = 0x01
GPS_TIMEOUT = 0x02
TORQUE_TIMEOUT = 0x04
AXLE_TIMEOUT = 0x08
DRAFT_TIMEOUT = 0x10
NOT_CONVERGED = 0x20
INPUT_REJECTED = 0x40
MEAS_GATED = 0x80
COV_REPAIRED = 0x100
FILTER_LOST = 0x200
"""The filter lost the vehicle (:mod:`.divergence`) and was re-initialised; set until it re-converges."""
STANDSTILL = 0x400
"""Ground speed below ``standstill_speed_mps``: ρ_s and slip are not supported by the data."""
UNVERIFIED = 0x800
"""The reported σ of μ or ρ_s is mostly the systematic part from the sensor tolerances (:mod:`.uncertainty`):
it rests on bounds (sensor calibration, tyre radius, draft zero) the data cannot check.  A notice, not invalid."""

STATUS_NAMES = {WHEEL_TIMEOUT: "wheel_speed_timeout", GPS_TIMEOUT: "ground_speed_timeout",
                TORQUE_TIMEOUT: "torque_timeout", AXLE_TIMEOUT: "axle_load_timeout",
                DRAFT_TIMEOUT: "draft_timeout", NOT_CONVERGED: "not_converged",
                INPUT_REJECTED: "input_rejected", MEAS_GATED: "measurement_gated",
                COV_REPAIRED: "covariance_repaired", FILTER_LOST: "filter_lost", STANDSTILL: "standstill",
                UNVERIFIED: "unverified_assumptions"}
SLIP_UNCERTAIN = 0x2000
"""The slip's standard deviation from the filter's covariance (σ_v, σ_κ through eq. 6 with k_i(κ)·v) exceeds
``slip_sigma_max`` on some wheel (creeping, manoeuvring, the first seconds after a start): slip is not supported
by the data.  The last supported slip is held (as at standstill) and no (μ, s) pair goes to the curve, so ``a``
holds too.  Also set, with the slip held, where the curvature input is at its clip ``KAPPA_MAX`` (a turn tighter
than the model's range: eq. 6's wheel ground speeds k_i(κ)·v are not known, nor an average over the last metres),
and there too no pair goes to the curve.  μ and ρ_s do not rest on the slip (eqs. 2 and 8 take the torques, loads
and v̇): their validity is their own, and this bit alone does not make the estimate invalid; a consumer of ``slip``
checks it."""
STATUS_NAMES[SLIP_UNCERTAIN] = "slip_not_supported"
MACHINE_UNSUPPORTED = 0x1000
"""The machine-level μ is not supported by the bus now (:class:`.machine.MachineValidity`: gear shift or clutch
slip, front axle not coupled as modelled, too little drive torque): not valid."""
STATUS_NAMES[MACHINE_UNSUPPORTED] = "machine_mu_unsupported"
INVALID_MASK = (WHEEL_TIMEOUT | GPS_TIMEOUT | TORQUE_TIMEOUT | AXLE_TIMEOUT | DRAFT_TIMEOUT | NOT_CONVERGED
                | INPUT_REJECTED | FILTER_LOST | STANDSTILL | MACHINE_UNSUPPORTED)
"""Bits that make an estimate not ``valid`` (gating and a repaired covariance are notices only)."""
MACHINE_LEVEL = 0x4000
"""One μ for the whole machine (:mod:`.machine`: an engine-driven tractor's bus supports no more): the same μ
on every wheel.  A notice, not invalid."""
DRAFT_NOT_SEPARATED = 0x8000
"""No draft sensor: ρ_s and the implement's draft are one term of eq. 8; their sum is estimated and ρ_s is
reported as NaN (:mod:`.machine`).  A notice, not invalid."""
STATUS_NAMES.update({MACHINE_LEVEL: "machine_level", DRAFT_NOT_SEPARATED: "rho_s_and_draft_not_separated"})
SLIP_AVERAGED = 0x10000
"""The slip of this step is not supported by its own σ (it would be ``SLIP_UNCERTAIN``), but its average over
the last metres of travel is (:meth:`Estimator._slip_window`): ``slip`` is that average over the stretch of at
most ``slip_avg_max_m`` (in one direction, without a standstill) whose σ (the filter's P_vv with the
ground-speed error correlated over ``slip_avg_corr_s``, the curvature's σ, and the lag of a mean behind a
changing μ) is the smallest, when that σ is within ``slip_sigma_max``.  Reversing and creeping.
No (μ, s) pair goes to the curve or the map from it.  A notice, not invalid.  Above the 16 bits of the
DBC's EstimateStatus: on the bus it is bit 0 of EstimateStatusExt (the status's bits 16–23)."""
STATUS_NAMES[SLIP_AVERAGED] = "slip_averaged"


def status_names(status: int) -> list[str]:
    """Names of the bits set in an ``EstimateStatus`` word."""
    return [name for bit, name in STATUS_NAMES.items() if status & bit]


# ----------------------------------------------------------------------------- estimate
@dataclass(slots=True)
class Estimate:
    """One estimator output (docs/architecture.md).

    Read-only by contract: consumers never change it (the fixed-lag smoother, the estimator's last stage,
    revises ``mu``, ``rho_s`` and a live ``slip`` before it delivers it, :mod:`.smoother`).  It is not a frozen
    dataclass because a frozen one costs 1.2 µs more to build (one
    ``object.__setattr__`` per field), at 100 Hz on the estimator's path, and
    its arrays were never frozen anyway.
    """

    t: float
    """Time [s] (the caller's clock, e.g. epoch seconds)."""
    mu: NDArray[np.float64]
    """Adhesion coefficient μ per wheel FL, FR, RL, RR [-]."""
    rho_s: float
    """Soil-deformation rolling resistance ρ_s [-]."""
    a: float
    """Curve parameter a of μ(s) (eq. 18) of the best class [-]; NaN until identified."""
    soil_class: str
    """Name of the best-fitting surface class."""
    slip: NDArray[np.float64]
    """Slip per wheel (eq. 6) [-]; the last supported value while ``STANDSTILL`` or ``SLIP_UNCERTAIN`` is set."""
    v: float
    """Ground speed [m/s]."""
    omega: NDArray[np.float64]
    """Wheel speeds [rad/s]."""
    P_diag: NDArray[np.float64]
    """Diagonal of the state covariance, order (ω1..4, v, μ1..4, ρ_s), in squared state units."""
    nis: float
    """Normalised innovation squared of this step's update [-]; NaN without an update."""
    adapt: float
    """Effective adaptation of the μ process noise f_k·mean(A_k,μ) [-]."""
    status: int
    """EstimateStatus bitfield (see module constants)."""
    valid: bool
    """Converged and no timeout / rejected input."""
    nis_dof: int = 0
    """Degrees of freedom of ``nis`` (number of accepted output components)."""
    soil_class_index: int = 0
    """Index of ``soil_class`` in the configured classes (DBC SoilClassIndex)."""
    lost_since: float = math.nan
    """On the step the filter is declared lost: the time the lost period began [s] (estimates
    since then were not trustworthy, whatever they said); NaN on every other step."""
    sys_var: Any = None
    """Systematic variances (u_μ1..4², u_ρs²) (5,) from the sensor tolerances (:mod:`.uncertainty`), shared
    between estimates until they are recomputed (adaptation period); None: none."""
    radius_scale: Any = dataclasses.field(default_factory=lambda: np.full(2, np.nan))
    """Rolling-radius scale r_true / r_d per axle (front, rear) (2,) [-] from the self-calibration
    (:mod:`.calibration`); NaN until estimated."""
    radius_halfwidth: Any = dataclasses.field(default_factory=lambda: np.full(2, np.nan))
    """95 % half-width of ``radius_scale`` (2,) [-]; NaN until estimated."""
    radius_applied: Any = dataclasses.field(default_factory=lambda: np.ones(2))
    """Scale the filter uses per axle (2,) [-]: 1 until the calibration's interval is tight enough."""
    curve_state: Any = None
    """The curve identification (:class:`~.curve.CurveState`) this estimate reports ``a`` from."""
    kappa: float = 0.0
    """Path curvature of the rear-axle centre used as the filter's input [1/m], positive in a left turn
    (:mod:`.kinematics`); 0 when not known."""
    transition: Any = None
    """For the fixed-lag smoother (:mod:`.smoother`, ``EstimatorConfig.smoother_lag_s`` > 0), on a step with a
    filter: (link, x⁺, x⁻, G): whether this step's prediction started from the previous estimate's x⁺ and has
    its gain, the state after this step's update x⁺, the prior x⁻ it was updated from and the prediction's
    gain G (None without link); with the two-inertia hub a fifth element, the state index of the reported μ, ρ_s,
    ω (the rims') and v (:data:`.smoother.STATE_INDEX`).  The smoother drops it when it delivers the estimate;
    None otherwise."""

    @property
    def sigma_mu(self) -> NDArray[np.float64]:
        """Reported standard uncertainty of μ per wheel (4,) [-]: the filter's √P combined with the
        systematic part from the sensor tolerances, √(P_μi + u_μi²) (:mod:`.uncertainty`); the band
        μ ± 2σ is meant to hold the truth 95 % of the time.  ``P_diag`` stays the filter's own covariance."""
        p = self.P_diag[5:9]
        return np.sqrt(p if self.sys_var is None else p + self.sys_var[:4])

    @property
    def sigma_rho_s(self) -> float:
        """Reported standard uncertainty of ρ_s [-], √(P_ρs + u_ρs²) (as ``sigma_mu``)."""
        p = float(self.P_diag[9])
        return math.sqrt(p if self.sys_var is None else p + float(self.sys_var[4]))

    @property
    def curve(self) -> Any:
        """The identified μ(s) (:class:`~tractionecu.model.mucurve.MuCurve`: callable, parameters,
        covariance), None until identified."""
        return None if self.curve_state is None else self.curve_state.curve

    @property
    def curve_path(self) -> str:
        """``"class:<name>"`` (one parameter a, eq. 18) or ``"shape:<form>"`` (shape identified)."""
        return "" if self.curve_state is None else self.curve_state.curve_path


# ----------------------------------------------------------------------------- estimator
_INPUT_KEYS = ("Md", "Fzf", "Fdx")
KAPPA_NOISE_MIN = 0.003
"""Below this path curvature [1/m] (radius above 330 m) the curvature's term in Q is left out: it grows with
κ², and there it is below 0.1 % of the model-error term q_v (:func:`._kernels.add_kappa_noise`: the curvature
error is mostly the slowly varying bias of the wheel curvature, correlated over ``BIAS_TAU_S``, so its spectral
density is taken as σ_κ²·BIAS_TAU_S; it moves v̇ through the front forces' direction and, with the lateral load
transfer, every wheel's load)."""
KAPPA_MAX = 0.25
"""Largest path curvature of the rear-axle centre [1/m] (a tractor's tightest turn, ≈ 4 m radius): the
curvature input is limited to ±this, and so is its standard deviation when it is not known.  At the clip the
slip is reported not supported (SLIP_UNCERTAIN)."""
RELAX_DEFAULT_M = 0.5
"""Relaxation length of the carcass model before a μ(s) curve is identified [m] (Pacejka 2006, ch. 7: about
the rolling radius's order for a large tyre near zero slip; :meth:`Estimator._relax`)."""
RELAX_MIN_M = 0.05
RELAX_MAX_M = 1.0
"""Bounds of the carcass model's relaxation length [m] (a slip stiffness near zero on the flat of μ(s), or a
steep curve at zero slip, would give 0 or several metres)."""
CARCASS_MAX_FT = 0.08
"""Largest f_c·T (carcass mode × wheel-speed sample period) at which the carcass term is used: the period
mean's lag π f_c T ≤ 0.25 rad (:meth:`Estimator._relax`); 6.5 Hz at 100 Hz: 0.065, at 20 Hz: 0.33 (off)."""
PMEAN_MAX_FT = 0.4
"""Largest f_c·T at which a declared two-inertia hub keeps the carcass term beyond CARCASS_MAX_FT, in the
period-mean filter (model doc "Period-mean wheel speeds"): the wheel-speed rate at least 2.5 f_c, above the
mode's Nyquist rate 2 f_c with a margin for the period mean's attenuation (sinc(π f_c T): 0.76 at 0.4).  20 Hz
with the physical truth's 5.8–6.5 Hz: 0.29–0.33 (on); 10 Hz: 0.58–0.65 (off, the paper's μ and the ring noise)."""
PM_ANGLE_VAR = 1e-12
"""Variance [rad²] of the motors' angles after a sample's reset: known exactly; a floor that keeps P positive
definite for the sigma points' Cholesky factor (1 µrad, against ω T ≈ 0.17 rad over a 50 ms period)."""
PM_ANGLE_Q = 1e-10
"""Process-noise density of the angles [rad²/s]: a numerical floor; their uncertainty is the motor speeds',
which the sigma points carry through φ̇ = ω_m."""
PM_RELAX_Q = 1e-4
"""Process-noise density of the relaxed slips [1/s]: the relaxation rate |v|/L_r is uncertain by the relaxation
length's, which is the identified curve's slope over the carcass stiffness (or 0.5 m before a curve): taken as
±50 %; at 2.5 m/s and L_r 0.5 m (5 1/s), on a slip that moves against σ̄ by 0.007 rms over 0.1 s (the ring),
that is (0.5 · 5 · 0.007)² · 2 · 0.1 s ≈ 6e-5 1/s; rounded up to its order (1e-5 and 1e-4 move the μ error
of ``physical-declared-exact`` at 20/10 Hz by 0.03 points)."""
PM_RELAX_SD0 = 0.02
"""σ of the relaxed slips when the period-mean filter starts [-] (from the slips of the speeds then: the
uncertainty of a slip of ω_m r_d against v at σ_v 0.05 m/s and 2.5 m/s)."""
PM_HOLD_PERIODS = 1.5
"""The convergence verdict of the period-mean filter is taken at its wheel-speed updates and held for at most
this many observed sample periods after one (:meth:`Estimator._estimate`)."""
_ABSENT = object()
_AXLE_SGN = np.array([-0.5, -0.5, 0.5, 0.5])
"""−∂F_z,i/∂F_zf of the wheels FL, FR, RL, RR (front F_zf/2, rear (mg − F_zf)/2): the axle-load term of Q."""
_SL_W = slice(0, 4)
_SL_WV = slice(0, 5)
_SL_V = slice(4, 5)
_HUB_OUT = np.array([10, 11, 12, 13, 4, 5, 6, 7, 8, 9])
"""States of the two-inertia hub model the estimate reports, in the paper's order (rim speeds for ω)."""
_HUB_SMOOTH_INDEX = tuple(int(_HUB_OUT[i]) for i in (*range(IX_MU.start, IX_MU.stop), IX_RHO,
                                                     *range(IX_OMEGA.start, IX_OMEGA.stop), IX_V))
"""The two-inertia hub's state index of each reported μ1..4, ρ_s, ω1..4 (the rims') and v, in the order of the
fixed-lag smoother's :data:`.smoother.STATE_INDEX`: where :data:`_HUB_OUT` puts each."""


def _curve_slope_params(cs: Any) -> tuple[float, float, float, float, float]:
    """(a, p, α1, α2, c0) such that c0 + a g(s), g of eq. 14, is the identified μ(s) curve of ``cs`` (a
    :class:`~.curve.CurveState`): its own parameters on the shape path (``exp1_offset`` c + (a − c)(1 − e^{α s})
    as (a − c, 1, α, α, c)), the class's exponents with its a on the class path (c0 = 0); a = NaN (the default
    relaxation length) before a curve is identified."""
    c = cs.curve
    if c is None:
        return math.nan, 0.0, -1.0, -1.0, 0.0
    if c.form == "exp1_offset":
        th = c.theta
        return float(th[1] - th[0]), 1.0, float(th[2]), float(th[2]), float(th[0])
    return float(c.a), float(c.p), float(c.alpha1), float(c.alpha2), 0.0


class Estimator:
    """AUKF-FS traction estimator (paper section 3).

    Parameters
    ----------
    vehicle : nominal vehicle parameters.
    cfg : tuning (default: ``EstimatorConfig()``).
    sensors : sensor noise figures used for R and the input part of Q
        (default: the documented ``SensorSpec()``).
    """

    def __init__(self, vehicle: VehicleParams, cfg: EstimatorConfig | None = None, sensors: SensorSpec | None = None):
        self.vehicle = vehicle
        self.cfg = cfg = cfg or EstimatorConfig()
        self.sensors = sensors or SensorSpec()
        self.model = FilterModel(vehicle)
        self.m = vehicle.mass_kg
        self.J = vehicle.wheel_inertia_kgm2
        sp = self.sensors
        self._gate = math.inf if cfg.gate_probability <= 0 else float(2.0 * erfcinv(cfg.gate_probability) ** 2)
        self._q_tune = np.array([cfg.q_omega] * 4 + [cfg.q_v] + [cfg.q_mu] * 4 + [cfg.q_rho])
        self._lo = np.array([-np.inf] * 5 + [cfg.mu_min] * 4 + [cfg.rho_min])
        self._hi = np.array([np.inf] * 5 + [cfg.mu_max] * 4 + [cfg.rho_max])
        # Sensor figures (SensorSpec) used in R and Q_in.
        self._w_abs, self._w_rel = sp.wheel_speed_sigma_abs, sp.wheel_speed_sigma_rel
        self._w_q2 = sp.wheel_speed_quant ** 2 / 12.0
        self._r_v = sp.gps_speed_sigma ** 2
        self._tq_abs, self._tq_rel = sp.torque_sigma_abs, sp.torque_sigma_rel
        self._tq_q2 = sp.torque_quant ** 2 / 12.0
        self._fz_var = sp.axle_sigma_n ** 2 + sp.axle_quant_n ** 2 / 12.0
        self._fd_var = sp.draft_sigma_n ** 2 + sp.draft_quant_n ** 2 / 12.0
        self._weight = vehicle.weight_n
        # Drive torque input: the reported motor torque through the hub reduction's declared efficiency η
        # (M_d = η M_motor driving, M_motor/η braking; model doc "Declared drivetrain"); 1: the paper's model.
        dtr = getattr(vehicle, "drivetrain", None)
        self._eta = float(dtr.efficiency) if dtr is not None and not dtr.engine_driven else 1.0
        # and less the hub reduction's declared no-load drag c ω (drivetrain.hub_drag_nms; 0: none declared)
        self._drag = float(dtr.hub_drag_nms) if dtr is not None and not dtr.engine_driven else 0.0
        self._unc = SystematicUncertainty(sp, vehicle) if cfg.systematic_uncertainty else None
        # Tyre carcass (model doc "Tyre carcass"): its longitudinal stiffness c_x [N/m]; 0: the paper's μ.
        # The mode of the wheel on the carcass, f_c = √(r0² c_x / J)/2π, must be sampled finely enough (_relax).
        self._cx = self.model.cx
        self._f_carcass = math.sqrt(vehicle.r0_m ** 2 * self._cx / self.J) / (2.0 * math.pi)
        # Two-inertia hub (model doc "Two-inertia hub"): (k, c, J_m, J_w) from the vehicle file, or None (the
        # paper's one inertia per wheel).  Declared together with the carcass, the filter carries the rim speeds
        # and hub twists too while the carcass term is on (_hub_wanted, _set_hub); _hub_on: it does now.
        self._hub = self.model.hub if self._cx != 0.0 else None
        self._hub_on = False
        # the period-mean filter (model doc "Period-mean wheel speeds"): _pm while the filter is one, _t_pm the
        # time its angles restarted, _pm_curve the relaxation's curve (_curve_slope_params) for its process model
        self._pm = False
        self._t_pm = math.nan
        self._pm_curve = (math.nan, 0.0, -1.0, -1.0, 0.0)
        # Hold periods (Q_in) and timeouts follow the periods observed on the bus (.rates);
        # the SensorSpec rates until enough samples were seen.
        self._rates = BusRates(
            {"Md": 1.0 / sp.wheel_rate_hz, "Fzf": 1.0 / sp.loadpin_rate_hz, "Fdx": 1.0 / sp.loadpin_rate_hz,
             "omega": 1.0 / sp.wheel_rate_hz, "v": 1.0 / sp.gps_rate_hz},
            {"Md": cfg.torque_timeout_s, "Fzf": cfg.axle_timeout_s, "Fdx": cfg.draft_timeout_s,
             "omega": cfg.wheel_timeout_s, "v": cfg.gps_timeout_s},
            cfg.timeout_periods, cfg.rate_window, cfg.max_gap_s)
        self._rate_push = {key: tr.push for key, tr in self._rates.trackers.items()}
        self._kin = CurvatureFilter(vehicle.track_width_m, sp.gps_speed_sigma)
        self._hb = 0.5 * vehicle.track_width_m
        self._ones4 = np.ones(4)
        self._monitor = DivergenceMonitor(cfg.lost_after_s, cfg.lost_nis_alpha, cfg.rho_max,
                                          max(cfg.direction_min_speed_mps, cfg.standstill_speed_mps))
        self._smooth = cfg.smoother_lag_s > 0.0       # each estimate carries its transition (.smoother)
        self.reset()

    # ------------------------------------------------------------------ lifecycle
    def no_data(self, t: float) -> Estimate:
        """The estimate of a time ``t`` [s] at which nothing is stepped because the wheel speeds have been silent
        longer than replay's grid gap (:data:`~tractionecu.pipeline.steps.GRID_MAX_GAP_S`; the service's loop):
        every value NaN, not converged, wheel speeds timed out.  The filter is not moved; its next step, after
        the gap, restarts it (``max_gap_s``) as in replay."""
        return self._estimate(t, WHEEL_TIMEOUT | NOT_CONVERGED, None)

    def reset(self) -> None:
        """Forget everything (as after power-up)."""
        cfg = self.cfg
        self.ukf: UnscentedFilter | None = None
        self.t: float | None = None
        self.t_init: float | None = None
        self._u = np.full(N_INPUT, np.nan)
        self._u[IU_KAPPA] = 0.0
        self._kappa_var = KAPPA_MAX ** 2
        self._kin.reset()
        self._md_sum = math.nan
        self._t_in = {k: -math.inf for k in _INPUT_KEYS}
        self._t_omega = -math.inf
        self._t_v = -math.inf
        self._t_upd_w = self._t_upd_v = -math.inf
        self._om_upd: list[float] = []                  # the wheel speeds and ground speed of the last update
        self._v_upd = math.nan
        self._dm_var = np.zeros(4)
        self._last_v_meas: float | None = None
        self._rates.reset()
        self._dir = 1.0
        self._dir_bus = 0.0
        self._t_dir_bus = -math.inf
        self._held: tuple[float, NDArray[np.float64]] | None = None
        self._win_reset()
        self._t_relax: float | None = None
        self._twist_relax: tuple[float, NDArray[np.float64]] | None = None   # (t, θ̂ (4,)) of the last _relax
        self._ring = [0.0, 0.0, 0.0, 0.0, 0.0]   # the carcass mode's variance per wheel [rad²/s²], time seen [s]
        self._conv = False                # last convergence verdict (hysteresis, EstimatorConfig.conv_exit_factor)
        self._lost = False
        self._fuzzy = FuzzySupervisor(cfg.fuzzy)
        self._dyn = DynamicsMonitor(cfg.dynamics_tau_s)
        self._cm = CovarianceMatching(N_STATE, cfg.adapt_window, cfg.adapt_min, cfg.adapt_max)
        self._A = np.ones(N_STATE)
        self._f = 1.0
        self._Qbase: NDArray[np.float64] | None = None
        self._Qdt = math.nan
        self._tq_gain = 0.0
        self._adapt_mu = 1.0
        self._t_adapt = -math.inf
        self._curve = CurveEstimator.from_config(cfg, fz_ref_n=self.vehicle.mass_kg * G / 4.0)   # μ(s) at the mean wheel load
        self._curve_state = self._curve.state()
        self._t_curve = -math.inf
        self._fz = np.zeros(4)
        self._rd = np.full(4, self.vehicle.r0_m)
        # reported uncertainty (.uncertainty) and rolling-radius calibration (.calibration)
        self._sys_var: NDArray[np.float64] | None = None
        self._sys_flag = False
        self._r_lat = 0.0
        self._cal = RadiusCalibration(cfg.calibration) if cfg.calibration.enabled else None
        self._kf = self._kr = 1.0
        self._md_inv: NDArray[np.float64] | None = None
        self._cal_blocks = 0
        nan2 = np.full(2, np.nan)
        self._rad = (nan2, nan2.copy(), np.ones(2))
        self.counters = {"steps": 0, "updates": 0, "gated": 0, "rejected_inputs": 0, "rejected_measurements": 0,
                         "chol_repairs": 0, "resets": 0, "gap_resets": 0, "lost": 0, "rejected_times": 0,
                         "time_backwards": 0, "repeated_measurements": 0}
        self._monitor.reset()
        # the fixed-lag smoother's transition of the step (Estimate.transition): the last estimate's x⁺, and
        # this step's prior and gain (a prior only where the step's prediction links to that x⁺)
        self._sm_xf: NDArray[np.float64] | None = None
        self._sm_xp: NDArray[np.float64] | None = None
        self._sm_G: NDArray[np.float64] | None = None

    # ------------------------------------------------------------------ noise
    def _loads(self) -> None:
        """self._fz, self._rd (4,) for the held F_zf (cached by the model per F_zf)."""
        self._fz, self._rd, _ = self.model._load_terms(float(self._u[4]), float(self._u[5]))

    def _R_omega(self, z: NDArray[np.float64]) -> NDArray[np.float64]:
        s = self._w_abs + self._w_rel * np.abs(z)
        return s * s + self._w_q2

    def _R_list(self, w: list[float]) -> list[float]:
        """_R_omega of the wheel speeds as floats (same operations)."""
        a, r, q2 = self._w_abs, self._w_rel, self._w_q2
        out = []
        for x in w:
            s = a + r * abs(x)
            out.append(s * s + q2)
        return out

    def _Q(self, dt: float) -> NDArray[np.float64]:
        """Process noise covariance for one step of dt [s] (module doc).

        The parts that change slowly (tuning × adaptation, axle-load and draft
        terms, which depend on μ̂ and r_d) are rebuilt when the adaptation is
        recomputed or dt changes; the torque term is added every step.
        """
        if self._Qbase is None or abs(dt - self._Qdt) > 1e-6 * dt:
            # (steps of the same period differ in their last bits on epoch-second grids: the same Q)
            self._rebuild_Q(dt)
        if not self.cfg.input_noise:
            return self._Qbase  # type: ignore[return-value]
        if JIT:
            Q = np.empty((N_STATE, N_STATE))
            _kernels.add_torque_noise(self._Qbase, self._u, self._tq_abs, self._tq_rel, self._tq_q2,
                                      self._tq_gain, Q)
        else:
            Q = self._Qbase.copy()  # type: ignore[union-attr]
            sm = self._tq_abs + self._tq_rel * np.abs(self._u[:4])
            Q.flat[0:4 * (N_STATE + 1):N_STATE + 1] += (sm * sm + self._tq_q2) * self._tq_gain
        kap = float(self._u[IU_KAPPA])
        if (kap > KAPPA_NOISE_MIN or kap < -KAPPA_NOISE_MIN) and self.ukf is not None:
            # v's term only (J = ∞: no wheel rows), as on the two-inertia hub: the loads' part is an error
            # correlated over 10 s, and as white noise on the wheel speeds it frees their left-against-right
            # mode to follow the wheel-speed noise (μ_RL − μ_RR moved by 0.12 σ for a 5e-4 rad/s change of the
            # wheel speeds' quantisation, against 0.035 σ without it) and gave no accuracy (s-curves-30m μ
            # error 2.56 % without it, 2.59 % with it; physical-declared-exact 1.25 % both)
            _kernels.add_kappa_noise(Q, self.ukf.x, self._u, self.model._kc, math.inf, 0,
                                     self._kappa_var * BIAS_TAU_S * dt)
        return Q

    def _Q_hub(self, dt: float) -> NDArray[np.float64]:
        """Process noise of the two-inertia hub model (18 states, model doc "Two-inertia hub"; 26 in the
        period-mean filter, the angles' and relaxed slips' :data:`PM_ANGLE_Q`, :data:`PM_RELAX_Q`) for dt [s].

        The paper's terms, each where it acts in the two-mass model: the drive-torque noise on the motor
        speeds (gain 1/J_m), the axle-load noise on the rim speeds through the ground force (gain
        r_d (μ + ρ_t)/(2 J_w)) and on v, the draft noise on v; the model-error density q_ω on the motor and
        on the rim speeds alike; the twist none (θ̇ = ω_m − ω_w exactly).  Rebuilt as :meth:`_Q`."""
        if self._Qbase is None or abs(dt - self._Qdt) > 1e-6 * dt:
            k_h, c_h, jm, jw = self._hub
            period = self._rates.period
            self._tq_gain = period("Md") * dt / (jm * jm)
            n = N_STATE_PMEAN if self._pm else N_STATE_HUB
            q = self._q_tune * (self._f * dt)
            q *= self._A
            Q = np.zeros((n, n))
            d = np.arange(N_STATE)
            Q[d, d] = q
            Q[d[:4] + 10, d[:4] + 10] = q[:4]
            if self._pm:
                Q[d[:4] + IX_PMEAN.start, d[:4] + IX_PMEAN.start] = PM_ANGLE_Q * dt
                Q[d[:4] + IX_RELAX.start, d[:4] + IX_RELAX.start] = PM_RELAX_Q * dt
            if self.cfg.input_noise and self.ukf is not None:
                self._loads()
                mu = self.ukf.x[IX_MU]
                g = np.zeros(n)
                g[IX_OMEGA_W] = _AXLE_SGN * self._rd * (mu + self.vehicle.rho_t) / jw
                g[IX_V] = -float(_AXLE_SGN @ mu) / self.m
                Q += np.outer(g, g) * (self._fz_var * period("Fzf") * dt)
                Q[IX_V, IX_V] += self._fd_var * period("Fdx") * dt / (self.m * self.m)
            self._Qbase = Q
            self._Qdt = dt
        Q = self._Qbase.copy()
        if self.cfg.input_noise:
            sm = self._tq_abs + self._tq_rel * np.abs(self._u[:4])
            nn = Q.shape[0]
            Q.flat[0:4 * (nn + 1):nn + 1] += (sm * sm + self._tq_q2) * self._tq_gain
        kap = float(self._u[IU_KAPPA])
        if (kap > KAPPA_NOISE_MIN or kap < -KAPPA_NOISE_MIN) and self.ukf is not None:
            # v's term only (J = ∞: no wheel rows): the load's part would act at the rims, which no sensor
            # measures, and as white noise for an error correlated over 10 s it lets the rims' speeds wander
            # left against right (s-curves-30m-hub-declared: slip_lr 0.0038 without it, 0.0076 with it)
            _kernels.add_kappa_noise(Q, self.ukf.x, self._u, self.model._kc, math.inf, IX_OMEGA_W.start,
                                     self._kappa_var * BIAS_TAU_S * dt)
        return Q

    @property
    def smoother_wheel_rate_hz(self) -> float:
        """The declared wheel-speed rate [Hz] the fixed-lag smoother's lag holds two periods of
        (:meth:`.smoother.FixedLagSmoother.for_estimator`)."""
        return self.sensors.wheel_rate_hz

    def _hub_wanted(self) -> bool:
        """Whether the filter should carry the declared two-inertia hub: with the carcass term (the hub changes
        the ring of motor and wheel on the carcass, which the wheel-speed rate must be able to follow, the
        rule of :meth:`_carcass_wanted`)."""
        return self._hub is not None and self._carcass_wanted()

    def _carcass_wanted(self) -> bool:
        """Whether the carcass term is used (:meth:`_relax`): f_c T ≤ :data:`CARCASS_MAX_FT`, or with a
        declared two-inertia hub f_c T ≤ :data:`PMEAN_MAX_FT` (in the period-mean filter, :meth:`_pm_wanted`)."""
        ft = self._rates.period("omega") * self._f_carcass
        return ft <= CARCASS_MAX_FT or (self._hub is not None and ft <= PMEAN_MAX_FT)

    def _pm_wanted(self) -> bool:
        """Whether the hub's filter is the period-mean filter (model doc "Period-mean wheel speeds"): a declared
        two-inertia hub and CARCASS_MAX_FT < f_c T ≤ PMEAN_MAX_FT."""
        ft = self._rates.period("omega") * self._f_carcass
        return self._hub is not None and CARCASS_MAX_FT < ft <= PMEAN_MAX_FT

    def _hub_states(self, omega: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Initial means and σ of the hub's states (rim speeds, twists) for motor speeds ω (4,): the rims at the
        motor speeds, the twists carrying the drive torque (ω̇ = 0: M_h = M_d), their σ the sensor's R_ω and that
        of the ground torque σ_μ0 r_d F_z through the stiffness."""
        k_h = self._hub[0]
        self._loads()
        x = np.concatenate([omega, self._u[:4] / k_h])
        sd = np.concatenate([np.sqrt(self._R_omega(omega)), self.cfg.sigma_mu0 * self._rd * self._fz / k_h])
        return x, sd

    def _new_filter(self, x0: NDArray[np.float64], P0: NDArray[np.float64]) -> UnscentedFilter:
        """A filter of the paper's ten states or, with ``_hub_on``, of the two-inertia hub's 18, or with ``_pm``
        the period-mean filter's 26 (its wheel-speed outputs are the angles x[18:22], its smoother gains
        those of the hub's 18 states: ``gain_n``, the angles' reset is no transition the smoother could
        invert)."""
        cfg = self.cfg
        fx, lo, hi = self.model.step, self._lo, self._hi
        meas = range(5)
        if self._hub_on:
            n = N_STATE_PMEAN if self._pm else N_STATE_HUB
            fx = self._fx_pm if self._pm else self.model.step_hub
            lo = np.concatenate([lo, np.full(n - N_STATE, -np.inf)])
            hi = np.concatenate([hi, np.full(n - N_STATE, np.inf)])
            if self._pm:
                meas = [*range(IX_PMEAN.start, IX_PMEAN.stop), IX_V]
                lo[IX_RELAX], hi[IX_RELAX] = -1.0, 1.0          # relaxed slips are slips (eq. 6's range)
        ukf = UnscentedFilter(fx, x0, P0, meas, alpha=cfg.alpha, beta=cfg.beta, kappa=cfg.kappa, x_lo=lo,
                              x_hi=hi, gate_chi2=self._gate, gate_max_consecutive=cfg.gate_max_consecutive)
        ukf.track_gain = self._smooth
        if self._pm:
            ukf.gain_n = N_STATE_HUB
        return ukf

    def _set_hub(self, on: bool) -> None:
        """Switch the filter between the paper's ten states, the two-inertia hub's 18 and the period-mean
        filter's 26 (model doc), keeping the states both have: the hub's states start as in :meth:`_hub_states`,
        the angles at 0 (their period starts with the next sample) and the relaxed slips at the slips of the
        speeds then (:meth:`_slips_now`), uncorrelated; states the new filter has not are dropped.  Its process
        noise follows (:meth:`_Q_hub`)."""
        pm = on and self._pm_wanted()
        self._hub_on = on
        self._pm = pm
        self._Qbase = None
        if on:
            self._Q = self._Q_hub           # type: ignore[method-assign]
        else:
            self.__dict__.pop("_Q", None)
        ukf = self.ukf
        n = N_STATE_PMEAN if pm else N_STATE_HUB if on else N_STATE
        if ukf is None or ukf.n == n:
            return
        k = min(n, ukf.n)
        x0 = np.zeros(n)
        P0 = np.zeros((n, n))
        x0[:k] = ukf.x[:k]
        P0[:k, :k] = ukf.P[:k, :k]
        if k < N_STATE_HUB <= n:
            xh, sd = self._hub_states(ukf.x[IX_OMEGA].copy())
            x0[N_STATE:N_STATE_HUB] = xh
            i = np.arange(N_STATE, N_STATE_HUB)
            P0[i, i] = sd * sd
        if n == N_STATE_PMEAN:
            P0[IX_PMEAN, IX_PMEAN] = np.eye(4) * PM_ANGLE_VAR
            x0[IX_RELAX] = self._slips_now(x0)
            P0[IX_RELAX, IX_RELAX] = np.eye(4) * PM_RELAX_SD0 ** 2
            self._t_pm = math.nan
        repairs = ukf.chol_repairs
        self.ukf = self._new_filter(x0, P0)
        self.ukf.chol_repairs = repairs

    def _rebuild_Q(self, dt: float) -> None:
        J = self.J
        period = self._rates.period
        self._tq_gain = period("Md") * dt / (J * J)
        inputs = self.cfg.input_noise and self.ukf is not None
        if JIT:
            # the numpy code below, compiled (same operations: tests/estimation/test_speed_equivalence.py)
            Q = np.empty((N_STATE, N_STATE))
            g_v = c_fz = c_fd = 0.0
            x = self._q_tune
            if inputs:
                self._loads()
                x = self.ukf.x  # type: ignore[union-attr]
                g_v = -float(_AXLE_SGN @ x[IX_MU]) / self.m
                c_fz = self._fz_var * period("Fzf") * dt
                c_fd = self._fd_var * period("Fdx") * dt / (self.m * self.m)
            _kernels.process_noise(self._q_tune, self._f * dt, self._A, inputs, self._rd, x, self.vehicle.rho_t,
                                   J, g_v, c_fz, c_fd, Q)
            self._Qbase = Q
            self._Qdt = dt
            return
        q = self._q_tune * (self._f * dt)
        q *= self._A
        Q = np.diag(q)
        if inputs:
            self._loads()
            mu = self.ukf.x[IX_MU]  # type: ignore[union-attr]
            # axle load: dω̇_i/dF_zf = ∓ r_i (μ_i + ρ_t)/(2J), dv̇/dF_zf = (μ1+μ2−μ3−μ4)/(2m)
            g = np.zeros(N_STATE)
            sgn = _AXLE_SGN
            g[:4] = sgn * self._rd * (mu + self.vehicle.rho_t) / J
            g[IX_V] = -float(sgn @ mu) / self.m
            Q += np.outer(g, g) * (self._fz_var * period("Fzf") * dt)
            Q[IX_V, IX_V] += self._fd_var * period("Fdx") * dt / (self.m * self.m)
        self._Qbase = Q
        self._Qdt = dt

    # ------------------------------------------------------------------ init
    def _init_filter(self, t: float, omega: NDArray[np.float64]) -> None:
        cfg = self.cfg
        self._loads()
        md, fz, rd = self._u[:4], self._fz, self._rd
        mu0 = np.clip(md / (rd * fz) - self.vehicle.rho_t * np.sign(omega), cfg.mu_min, cfg.mu_max)  # eq. 2, ω̇ = 0
        if self._last_v_meas is not None and t - self._t_v <= cfg.gps_timeout_s:
            v0 = self._last_v_meas
        else:
            v0 = float(np.mean(rd * omega))
        rho0 = float(np.clip((float(mu0 @ fz) - self._u[5]) / (self.m * G), cfg.rho_min, cfg.rho_max))  # eq. 8, v̇ = 0
        x0 = np.concatenate([omega, [v0], mu0, [rho0]])
        sd = np.concatenate([np.sqrt(self._R_omega(omega)), [cfg.sigma_v0], [cfg.sigma_mu0] * 4, [cfg.sigma_rho0]])
        if self._hub is None:
            self.ukf = UnscentedFilter(self.model.step, x0, np.diag(sd * sd), range(5), alpha=cfg.alpha,
                                       beta=cfg.beta, kappa=cfg.kappa, x_lo=self._lo, x_hi=self._hi,
                                       gate_chi2=self._gate, gate_max_consecutive=cfg.gate_max_consecutive)
            self.ukf.track_gain = self._smooth
        else:                                   # the declared two-inertia hub, while it is followed (_set_hub)
            self.ukf = None
            self._set_hub(self._hub_wanted())
            if self._hub_on:
                xh, sdh = self._hub_states(omega)
                x0 = np.concatenate([x0, xh])
                sd = np.concatenate([sd, sdh])
            if self._pm:
                x0 = np.concatenate([x0, np.zeros(4), np.zeros(4)])
                x0[IX_RELAX] = self._slips_now(x0)
                sd = np.concatenate([sd, np.full(4, math.sqrt(PM_ANGLE_VAR)), np.full(4, PM_RELAX_SD0)])
                self._t_pm = t
            self.ukf = self._new_filter(x0, np.diag(sd * sd))
        self.t_init = t
        self._conv = False
        self._t_relax = None
        self._ring = [0.0, 0.0, 0.0, 0.0, 0.0]
        self._win_reset()
        self._monitor.reset()

    # ------------------------------------------------------------------ step
    def step(self, t: float, inputs: Mapping[str, Any] | None = None,
             measurements: Mapping[str, Any] | None = None) -> Estimate:
        """Advance to time t [s] with new inputs and measurements (any subset; see module doc).

        inputs: ``"Md"`` (4,) [N·m], ``"Fzf"`` [N], ``"Fdx"`` [N].
        measurements: ``"omega"`` (4,) [rad/s], ``"v"`` [m/s].
        """
        cfg = self.cfg
        t = float(t)
        status = 0
        predict_only = False
        counters = self.counters
        counters["steps"] += 1
        self._sm_xp = None
        if not math.isfinite(t):
            # a time that is no time: the step is refused, the state untouched (one NaN time stamp had made
            # the supervisor's acceleration NaN for good and re-initialised the filter on every later step)
            counters["rejected_times"] += 1
            return self._estimate(self.t if self.t is not None else math.nan, INPUT_REJECTED, None)
        if self.t is not None and t < self.t:
            # the caller's clock stepped back (an NTP correction of epoch seconds): every hold, timeout and
            # window is in the future of the new time; start again from the next data, as after a gap (without
            # it the predictions stopped, the timeouts never fired and a stale μ stayed valid for the step)
            kept = self.counters
            self.reset()
            self.counters = kept
            counters["time_backwards"] += 1
        t_in = self._t_in
        u = self._u
        # ---- inputs (zero-order hold, rejection)
        foh: list[tuple[int, Any, float]] = []     # (index, previous value, its arrival time) of new Md, F_dx
        if inputs:
            val = inputs.get("Md", _ABSENT)
            if val is not _ABSENT:
                arr = None if val is None else np.asarray(val, dtype=float)
                if arr is None or arr.shape != (4,):
                    status |= INPUT_REJECTED
                else:
                    a0, a1, a2, a3 = arr.tolist()
                    sm = a0 + a1 + a2 + a3           # = arr.sum(): also catches an overflowing sum
                    if math.isfinite(sm):
                        foh = [(0, u[:4].copy(), t_in["Md"])]
                        if self._eta != 1.0:           # motor to wheel torque (losses against the power flow)
                            arr = arr * np.where(arr * self._dir >= 0.0, self._eta, 1.0 / self._eta)
                        if self._drag != 0.0 and self.ukf is not None:
                            arr = arr - self._drag * self.ukf.x[IX_OMEGA]     # the hub's drag at the wheel speed
                        u[:4] = arr if self._md_inv is None else arr * self._md_inv
                        self._md_sum = sm
                        t_in["Md"] = t
                    else:
                        status |= INPUT_REJECTED
            for key, i in (("Fzf", 4), ("Fdx", 5)):
                val = inputs.get(key, _ABSENT)
                if val is _ABSENT:
                    continue
                fv = math.nan if val is None else float(val)
                # The front-axle load must leave both axles loaded: 0 < F_zf < m g
                # (F_zf = 0 would divide by zero in μ = F_h / F_z).
                if math.isfinite(fv) and (i != 4 or 0.0 < fv < self._weight):
                    if i == 5:
                        foh.append((5, float(u[5]), t_in[key]))
                    u[i] = fv
                    t_in[key] = t
                else:
                    status |= INPUT_REJECTED
        if status & INPUT_REJECTED:
            counters["rejected_inputs"] += 1
            predict_only = True
        rates = self._rates
        timeout = rates.timeout_s
        push = self._rate_push
        for key in _INPUT_KEYS:
            if t_in[key] == t and push[key](t):
                rates.refresh(key)
        if t - t_in["Md"] > timeout["Md"]:
            status |= TORQUE_TIMEOUT
            predict_only = True
        if t - t_in["Fzf"] > timeout["Fzf"]:
            status |= AXLE_TIMEOUT
            predict_only = True
        if t - t_in["Fdx"] > timeout["Fdx"]:
            status |= DRAFT_TIMEOUT
            predict_only = True
        # ---- measurements
        omega = v_meas = v_wheel = None
        r_om: list[float] | None = None
        wl: list[float] = []
        if measurements:
            om = measurements.get("omega")
            if om is not None:
                omega = np.asarray(om, dtype=float)
                if omega.shape != (4,):
                    omega = None
                    status |= INPUT_REJECTED
                else:
                    wl = omega.tolist()
                    if math.isfinite(wl[0] + wl[1] + wl[2] + wl[3]):
                        self._t_omega = t
                        # direction of travel from the sign of wheel rotation (held when creeping)
                        _, _, rdf, rdr = self.model.load_floats(float(u[4]), float(u[5]))
                        v_wheel = 0.25 * (rdf * (wl[0] + wl[1]) + rdr * (wl[2] + wl[3]))
                        if v_wheel != v_wheel:
                            v_wheel = None
                        elif t - self._t_dir_bus <= cfg.gps_timeout_s:
                            self._dir = self._dir_bus          # the machine's own direction bit first
                        elif v_wheel >= cfg.direction_min_speed_mps:
                            self._dir = 1.0
                        elif v_wheel <= -cfg.direction_min_speed_mps:
                            self._dir = -1.0
                        r_om = self._R_list(wl)         # R_ω, also the update's
                        self._kin.wheels(t, wl[2], wl[3], r_om[2], r_om[3],
                                         float(self.ukf.x[IX_V]) if self.ukf is not None else v_wheel)
                    else:
                        fin = np.isfinite(omega)
                        status |= INPUT_REJECTED
                        counters["rejected_measurements"] += int((~fin).sum())
                        if fin.any():
                            self._t_omega = t
            d = measurements.get("dir")
            if d is not None and (d == 0 or d == 1):          # WBSD SPN 1864: 0 reverse, 1 forward
                self._dir_bus = self._dir = 1.0 if d == 1 else -1.0
                self._t_dir_bus = t
            vm = measurements.get("v")
            crs = measurements.get("course")
            if vm is not None and crs is not None:
                # GNSS course against the heading: the direction when neither the machine's bit nor the
                # wheels decide (creeping); then the course updates the heading (.kinematics)
                c, sp = float(crs), abs(float(vm))
                if (t - self._t_dir_bus > cfg.gps_timeout_s
                        and (v_wheel is None or abs(v_wheel) < cfg.direction_min_speed_mps)):
                    dc = self._kin.course_direction(c, sp)
                    if dc != 0.0:
                        self._dir = dc
                self._kin.course(t, c, sp, self._dir)
            if vm is not None:
                # GNSS speed over ground is unsigned (RMC/VTG): it takes the direction of travel
                v_meas = abs(float(vm)) * self._dir
                if math.isfinite(v_meas):
                    self._t_v = t
                    self._last_v_meas = v_meas
                else:
                    status |= INPUT_REJECTED
                    counters["rejected_measurements"] += 1
                    v_meas = None
        if self._t_omega == t and push["omega"](t):
            rates.refresh("omega")
        if self._t_v == t and push["v"](t):
            rates.refresh("v")
        if t - self._t_omega > timeout["omega"]:
            status |= WHEEL_TIMEOUT
        if t - self._t_v > timeout["v"]:
            status |= GPS_TIMEOUT
        # ---- path curvature of the rear-axle centre (input u[6], .kinematics)
        ukf = self.ukf
        v_ref = float(ukf.x[IX_V]) if ukf is not None else (v_wheel if v_wheel is not None else 0.0)
        if -cfg.standstill_speed_mps < v_ref < cfg.standstill_speed_mps:
            self._kin.standstill()              # no slip, no slip difference (.kinematics)
        kap, kvar = self._kin.curvature(v_ref, cfg.standstill_speed_mps)
        if kap > KAPPA_MAX:
            kap = KAPPA_MAX
        elif kap < -KAPPA_MAX:
            kap = -KAPPA_MAX
        u[IU_KAPPA] = kap
        self._kappa_var = kvar if kvar < KAPPA_MAX * KAPPA_MAX else KAPPA_MAX * KAPPA_MAX
        # ---- initialisation
        if ukf is None:
            if (omega is not None and np.isfinite(omega).all()
                    and all(math.isfinite(t_in[k]) for k in _INPUT_KEYS)):
                self._init_filter(t, omega)
                self.t = t
            return self._estimate(t, status | NOT_CONVERGED, None)
        # ---- predict
        dt = t - self.t if self.t is not None else 0.0
        if dt > cfg.max_gap_s:
            # A gap in the data (logger paused, bus down): propagating the model
            # blindly across it means nothing; start again from the next data.
            counters["gap_resets"] += 1
            self.ukf = None
            self.t = t
            return self._estimate(t, status | NOT_CONVERGED, None)
        if dt > 0.0:
            n_sub = max(1, int(math.ceil(dt / cfg.max_step_s - 1e-9)))
            h = dt / n_sub
            # the smoother's link: this prediction starts from the last estimate's state, every sub-step has its gain
            xf = self._sm_xf
            # (bytes: array_equal costs 2.7 µs; a state is never NaN here, a repaired or restarted one has no link)
            link = self._smooth and xf is not None and xf.shape == ukf.x.shape and ukf.x.tobytes() == xf.tobytes()
            try:
                G = ukf.predict_steps(u, h, n_sub, self._Q)
                link = link and G is not None
            except EstimatorError:
                self._recover(t)
                status |= COV_REPAIRED
                ukf = self.ukf
                link = False
            if ukf.repaired_last:
                status |= COV_REPAIRED
            if foh:
                self._first_order_hold(foh, t, self.t)
            self.t = t
            if link:
                self._sm_xp = ukf.x.copy()
                self._sm_G = G
        # ---- update
        # the same measurement again at the time it was already applied (a caller stepping one time stamp
        # twice) is no new information: applied again it shrank P, σ_ω by half after five repeats
        if omega is not None and t == self._t_upd_w and wl[:4] == self._om_upd:
            omega = None
            counters["repeated_measurements"] += 1
        if v_meas is not None and t == self._t_upd_v and v_meas == self._v_upd:
            v_meas = None
            counters["repeated_measurements"] += 1
        updated = False
        wheel_out = ground_out = None
        if r_om is not None and self._cx != 0.0 and cfg.carcass_ring_tau_s > 0.0 and not predict_only:
            self._ring_noise(r_om, wl)
        v_prior = float(ukf.x[IX_V]) if self._cx != 0.0 else 0.0     # only the carcass's σ̄ needs it
        wl0 = wl
        if self._pm and omega is not None:
            # the period-mean filter measures the angles over the sample period, ω̄ T (model doc); no period
            # yet (the first sample of a new filter): no update of the wheel speeds
            pm_T = t - self._t_pm
            if pm_T > 0.0:
                wl = [w * pm_T for w in wl]
                r_om = [r * pm_T * pm_T for r in (r_om if r_om is not None else self._R_list(wl0))]
                omega = np.array(wl)
            else:
                omega = None
        if not predict_only and (omega is not None or v_meas is not None):
            if omega is not None and v_meas is not None:
                R = r_om if r_om is not None else self._R_list(wl)
                R.append(self._r_v + self._r_lat)
                wl.append(v_meas)
                ukf.update(np.array(wl), _SL_WV, np.array(R))
            elif omega is not None:
                ukf.update(omega, _SL_W, np.array(r_om if r_om is not None else self._R_list(wl)))
            else:
                ukf.update(np.array([v_meas]), _SL_V, np.array([self._r_v + self._r_lat]))
            g = ukf.last_gated
            out = ukf.last_outside          # bit j: output component j (ω1..4, v) outside the gate
            if omega is not None:
                wheel_out = (out & 0xF) != 0
            if v_meas is not None:
                ground_out = (out & 0x10) != 0
            if g:
                status |= MEAS_GATED
                counters["gated"] += bin(g).count("1")
            if ukf.last_dof:
                updated = True
                if omega is not None:
                    self._t_upd_w = t
                    self._om_upd = wl0[:4]
                if v_meas is not None:
                    self._t_upd_v = t
                    self._v_upd = v_meas
                counters["updates"] += 1
                if cfg.adaptation:
                    if not self._hub_on:
                        self._cm.push(*ukf.correction())
                    else:                       # the paper's ten states adapt; the hub's follow q_ω
                        dxc, ksk = ukf.correction()
                        self._cm.push(dxc[:N_STATE], ksk[:N_STATE])
        wl = wl0
        if self._pm and wl and self._t_omega == t:      # a sample (used or not) ends the angles' period
            self._pm_reset(ukf, t)
        if self._cx != 0.0:
            if updated and not self._pm:
                self._revise_relaxed(float(ukf.x[IX_V]) - v_prior, v_prior)
            self._relax(t, ukf.x)
            ukf = self.ukf
        # ---- divergence: a filter that has lost the vehicle starts again from the measurements
        x = ukf.x
        xl = x.tolist()
        since = self._monitor.update(t, wheel_out, ground_out, ukf.last_nis if updated else math.nan,
                                     ukf.last_dof if updated else 0, xl[IX_V], v_wheel, xl[IX_RHO])
        if since is not None:
            return self._declare_lost(t, since, status)
        # ---- adaptation and supervisor (paper eqs. 16–17, FLS)
        self._dyn.update(t, float(x[IX_V]), self._md_sum)
        if t - self._t_adapt >= cfg.adapt_period_s:
            self._t_adapt = t
            if cfg.adaptation:
                self._A = self._cm.compute()
            if cfg.supervisor:
                self._f = self._fuzzy.factor(abs(self._dyn.accel), abs(self._dyn.torque_rate))
            self._adapt_mu = self._f * float(self._A[IX_MU].mean())
            self._Qbase = None
            self._systematic(ukf)
        counters["chol_repairs"] = ukf.chol_repairs
        e = self._estimate(t, status, x, updated)
        if self._cal is not None and v_meas is not None and omega is not None:
            self._calibrate(t, v_meas, wl, e)
        return e

    # ------------------------------------------------------------------ uncertainty, radius calibration
    def _systematic(self, ukf: UnscentedFilter) -> None:
        """Systematic variances of μ and ρ_s (the estimates' ``sys_var``), the GNSS latency term of R_v
        and the UNVERIFIED test (:mod:`.uncertainty`), at the adaptation period."""
        unc = self._unc
        if unc is None:
            return
        pd = ukf.P.diagonal()[5:10]
        u = self._u
        _, _, rdf, rdr = self.model.load_floats(float(u[4]), float(u[5]))
        ur = self._cal.radius_sigma(unc.u_r) if self._cal is not None else (unc.u_r, unc.u_r)
        vm, vr = unc.variances(u[:4].tolist(), float(u[4]), float(u[5]), rdf * self._kf, rdr * self._kr, *ur)
        vm.append(vr)
        sv = np.array(vm)
        if not np.isfinite(sv).all():
            sv[:] = 0.0
        self._sys_var = sv                 # a new array: the estimates already made keep theirs
        self._sys_flag = bool((sv > pd).any())
        self._r_lat = unc.gnss_latency_var(self._dyn.accel)

    def _calibrate(self, t: float, v_meas: float, wl: list[float], e: Estimate) -> None:
        """Feed the radius calibration one GNSS epoch; apply a new scale (torques ÷ k, slip with k·r_d)."""
        cal = self._cal
        _, _, rdf, rdr = self.model.load_floats(float(self._u[4]), float(self._u[5]))
        cs = self._curve_state
        cal.push(t, v_meas, wl, rdf, rdr, e.mu.tolist(), self._dyn.accel, e.valid, cs.a, cs.class_name)
        n = cal._axles[0].n
        if n != self._cal_blocks:
            self._cal_blocks = n
            f, r = cal.state()
            kf, kr = cal.applied
            self._rad = (np.array([f.scale, r.scale]), np.array([f.halfwidth, r.halfwidth]), np.array([kf, kr]))
            if kf != self._kf or kr != self._kr:
                new_inv = np.array([1.0 / kf, 1.0 / kf, 1.0 / kr, 1.0 / kr])
                old_inv = self._md_inv if self._md_inv is not None else np.ones(4)
                self._u[:4] *= new_inv / old_inv          # the held torques in the new scale
                self._md_inv = new_inv
                self._kf, self._kr = kf, kr

    def calibration_summary(self) -> dict[str, Any]:
        """The rolling-radius calibration per axle (:meth:`.calibration.RadiusCalibration.summary`); empty
        when it is disabled."""
        return self._cal.summary() if self._cal is not None else {}

    def _first_order_hold(self, foh: list[tuple[int, Any, float]], t: float, t_prev: float) -> None:
        """Move the predicted mean from the held inputs to their first-order hold (samples slower than the step).

        A sample of an input is held from its arrival (zero-order hold); the
        step it arrives on already applies it over (t_prev, t].  When the
        samples come slower than the steps, the steps in between propagated
        the previous sample, while the truth moved from the previous sample's
        value to the new one: over (t0, t] (t0 the later of the previous
        sample's arrival and the last update of the output the input drives:
        the wheel speeds for M_d, the ground speed for F_dx) the best input
        is the straight line between the two samples.  ω̇_i is affine in M_d,i
        with gain 1/J and v̇ in F_dx with gain −1/m (eqs. 2, 8), so the
        prediction with that line differs from the held one by a shift of the
        mean only (P is unchanged):

            Δω_i = (∫ M_FOH − ∫ M_ZOH)/J,   Δv = −(∫ F_dx,FOH − ∫ F_dx,ZOH)/m.

        Torque feed-forward: the paper's model holds μ constant over a step
        (a random walk), so μ̂ learns of a new torque only through the wheel
        speeds one sample later.  But a wheel's slip settles within a few
        milliseconds, far below a 50–100 ms sample period: a torque change
        between samples is met by the ground force, Δμ_i ≈ ΔM_i/(r_d,i F_z,i).
        The prediction therefore moves μ̂_i by w_i ΔM_i/(r_d,i F_z,i), w_i =
        1 − 2σ_M,i²/E[ΔM_i²] the share of the sample-to-sample change that is
        signal rather than sensor noise (σ_M from SensorSpec, E[ΔM²] a running
        mean of the observed changes), and adds the noise part's variance
        (w_i/(r_d,i F_z,i))²·2σ_M,i² to P_μμ.

        With every sample on every step (t0 = t_prev) nothing changes.  The
        slowly varying front-axle load stays held.  Measured with
        ``benchmarks/bus_rates.py`` (paper-three-soils, seed 7): μ̂ lagged the
        truth by ≈ 75 ms at 20 Hz wheel and torque data; with the hold and
        the feed-forward the μ error went from 1.96 % to 1.34 %.
        """
        ukf = self.ukf
        if ukf is None:
            return
        for i, old, t_old in foh:
            t0 = max(self._t_upd_w if i == 0 else self._t_upd_v, t_old)
            if not t0 < t_prev or not t - t_old <= self.cfg.max_gap_s:
                continue                       # one step, or no previous sample: the hold is exact enough
            new = self._u[:4] if i == 0 else float(self._u[5])     # (a float: plain arithmetic, same result)
            # mean over (t0, t] of the line from (t_old, old) to (t, new), times the span, minus the held integral
            w = (0.5 * (t0 + t) - t_old) / (t - t_old)
            d = (old + (new - old) * w) * (t - t0) - (old * (t_prev - t0) + new * (t - t_prev))
            x = ukf.x
            if i == 0:
                x[:4] += d / self.J
                if self._hub_on:                # over a sample period motor and rim move together
                    x[IX_OMEGA_W] += d / self.J
                if self._pm:
                    # the period-mean filter: the angles move by the speeds' shift integrated over the span, which
                    # grows as the square of the time into it: (d/J)(t − t0)/3.  No torque feed-forward on μ:
                    # its carcass term moves μ with the slip the torque makes
                    x[IX_PMEAN] += d / self.J * (t - t0) / 3.0
                    continue
                dm = new - old
                ev = self._dm_var
                ev += 0.05 * (dm * dm - ev)
                sm = self._tq_abs + self._tq_rel * np.abs(new)
                nv = 2.0 * (sm * sm + self._tq_q2)
                w = np.clip(1.0 - nv / np.maximum(ev, 1e-9), 0.0, 1.0)
                self._loads()
                g = w / (self._rd * self._fz)
                x[5:9] += g * dm
                # the sensor-noise part of the feed-forward: its variance into P_μμ
                n = ukf.n
                ukf.P.flat[5 * (n + 1):9 * (n + 1):n + 1] += g * g * nv
            else:
                x[IX_V] -= d / self.m

    def _revise_relaxed(self, dv: float, v: float) -> None:
        """Revise the carcass model's relaxed slips σ̄_i with an update's revision of the speed, v → v + Δv:
        σ̄_i −= (1 − |σ̄_i|) Δv / v, the change of eq. 6's slip with v at fixed wheel speed (∂s/∂v = −(1 − |s|)/v
        on both branches).

        σ̄ is the slip history over the last relaxation length (tens of ms) taken against the filter's speed.
        An update that moves v (the GNSS speed every 100 ms, and the wheel speeds through the states'
        correlation) revises the belief about that speed, and the filter's speed error lasts far longer than
        σ̄'s memory (v is the integral of the forces over the vehicle's mass), so it revises the speed σ̄ was
        taken against as well.  Without the revision the carcass term saw the update's step in v as a slip
        step, s − σ̄, and moved μ by (∂μ/∂s) Δs until σ̄ caught up; the torque balance then took it back
        within a few wheel-speed samples: a μ ripple at the GNSS rate driven by the GNSS speed's noise
        (``physical-declared-exact``: μ error 1.17 % with the datasheet's 0.05 m/s, 0.88 % with a noiseless GNSS
        speed; with the revision 0.91 %, seeds 0 and 1).  Nothing at standstill (v within
        ``standstill_speed_mps``), where the slip has no speed to be taken against."""
        if self.model.cx == 0.0 or dv == 0.0 or not (abs(v) > self.cfg.standstill_speed_mps):
            return
        sb = self.model.relaxed_slip
        for i in range(4):
            if sb[i] == sb[i]:
                sb[i] = sb[i] - (1.0 - abs(sb[i])) * dv / v

    def _relax(self, t: float, x: NDArray[np.float64]) -> None:
        """Move the carcass model's relaxed slips σ̄_i towards the filter's slips s_i (model doc "Tyre
        carcass"): σ̄_i += min(1, Δt |v_i| / L_r,i)(s_i − σ̄_i), Pacejka's first-order relaxation, with the
        relaxation length L_r,i = F_z,i (∂μ/∂s)_i / c_x of the identified μ(s) at σ̄_i (the slip stiffness
        over the carcass stiffness), within [RELAX_MIN_M, RELAX_MAX_M]; RELAX_DEFAULT_M until a curve is
        identified.  A new filter starts from σ̄ = s.

        The term is used only while the wheel speeds come often enough to follow the carcass mode: a wheel
        speed measured by period counting is the mean over its sample period T, which lags the mode f_c by
        π f_c T; the term is on while f_c T ≤ CARCASS_MAX_FT (a lag of at most 0.25 rad, 14°), else off (μ̇ = 0,
        the paper's model).

        With a declared two-inertia hub (model doc "Two-inertia hub") the filter carries the hub while the
        term is on (:meth:`_set_hub`), and then: the slips s_i that σ̄ relaxes towards are those of the rims'
        speeds over the step, ω_m − Δθ̂/Δt (ω_m the motor speeds x[0:4], where the pickup sits; Δθ̂ the change
        of the filter's mean twists x[14:18] since the last relaxation; the first relaxation of a filter takes
        the motor speeds).  The force builds up on the rim's slip, which differs from the motor's by the twist
        rate, ω_w = ω_m − θ̇; below the hub's mode the twist follows the torque, θ ≈ r_d F_z μ/k, and its rate
        is not small (at 2 Hz on a front wheel r_d θ̇/v ≈ 0.2 δμ against the force slip's δμ/(∂μ/∂s) ≈ 0.3 δμ).
        Relaxed towards the motor's slips, σ̄ took it up (1.15–1.37× the truth's force slip at 1–5.5 Hz, 0.25
        rad ahead), closed the gap s − σ̄ that drives μ̇ too early, and the front wheels' μ followed the truth's
        at 0.77–0.90× (physical-declared-exact).  Not the rim-speed states x[10:14] themselves: they are not
        measured, and their difference to the motor's had a persistent part that the twist's corrections
        absorbed (relaxed towards them, σ̄ kept it and held μ off by 2–4 % for tens of seconds); the twist is
        held by the hub's spring, so its change has none.  And the slope ∂μ/∂s is that of the
        identified curve itself (:func:`_curve_slope_params`: on the shape path its own p, α1, α2), not the
        class's exponents with the shape's a, through each wheel's own μ (:func:`~tractionecu.model.vehicle.
        relax_slips_own`: the curve is identified at the mean wheel load, the front wheels are a third lighter)."""
        model = self.model
        on = self._carcass_wanted()
        if on != (model.cx != 0.0):
            model.set_carcass(on)
            self._t_relax = None
        if self._hub is not None and (on != self._hub_on or (on and self._pm_wanted() != self._pm)):
            self._set_hub(on)
            x = self.ukf.x  # type: ignore[union-attr]
        if not on:
            return
        if self._pm:
            # the period-mean filter relaxes σ̄ in its process model (_fx_pm); the term's v̄ is the mean speed
            # now, its σ̄ the states' mean (read by the relaxed_slip property), the relaxation's curve this one
            model._kc[15] = x[IX_V]
            model._kc[11:15] = x[IX_RELAX]
            self._pm_curve = _curve_slope_params(self._curve_state)
            return
        ff, fr, rdf, rdr = model.load_floats(float(self._u[4]), float(self._u[5]))
        t_prev = self._t_relax
        self._t_relax = t
        init = t_prev is None
        cs = self._curve_state
        if self._hub_on:
            a, p, al1, al2, c0 = _curve_slope_params(cs)
            th = x[IX_TWIST].copy()
            tw = self._twist_relax
            self._twist_relax = (t, th)
            xs = x
            if not init and tw is not None and tw[0] == t_prev and t > t_prev:
                xs = x[:N_STATE].copy()         # the rims' speeds over the step, ω_m − Δθ̂/Δt (docstring)
                xs[IX_OMEGA] -= (th - tw[1]) / (t - t_prev)
            relax_slips_own(xs, model._kc, float(self._u[IU_KAPPA]), 0.0 if init else t - t_prev, ff, fr, rdf, rdr,
                            a, p, al1, al2, c0, RELAX_MIN_M, RELAX_MAX_M, RELAX_DEFAULT_M, init)
            return
        cls = SOIL_CLASSES.get(cs.class_name)
        a = cs.a if cls is not None else math.nan
        p, al1, al2 = (cls.p, cls.alpha1, cls.alpha2) if cls is not None else (0.0, -1.0, -1.0)
        relax_slips(x, model._kc, float(self._u[IU_KAPPA]), 0.0 if init else t - t_prev, ff, fr, rdf, rdr,
                    a, p, al1, al2, RELAX_MIN_M, RELAX_MAX_M, RELAX_DEFAULT_M, init)

    def _slips_now(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Eq. 6's slips of the rims' speeds x[10:14] against v x[4], the relaxed slips' start in a new
        period-mean filter (:func:`~tractionecu.model.vehicle.relax_slips`' init on a copy of the model's
        constants)."""
        ff, fr, rdf, rdr = self.model.load_floats(float(self._u[4]), float(self._u[5]))
        kk = self.model._kc.copy()
        xs = x[:N_STATE].copy()
        xs[IX_OMEGA] = x[IX_OMEGA_W]
        relax_slips(xs, kk, float(self._u[IU_KAPPA]), 0.0, ff, fr, rdf, rdr, math.nan, 0.0, -1.0, -1.0,
                    RELAX_MIN_M, RELAX_MAX_M, RELAX_DEFAULT_M, True)
        return kk[11:15].copy()

    def _fx_pm(self, x: NDArray[np.float64], u: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
        """Process model of the period-mean filter for sigma points x (N, 26) over dt [s]
        (:func:`~tractionecu.model.vehicle._rk4_hub_pm`, model doc "Period-mean wheel speeds"), with the
        relaxation lengths of the identified curve as :meth:`_relax` takes them."""
        return self.model.step_hub_pm(x, u, dt, *self._pm_curve, RELAX_MIN_M, RELAX_MAX_M, RELAX_DEFAULT_M)

    def _pm_reset(self, ukf: UnscentedFilter, t: float) -> None:
        """A wheel-speed sample at t ends the period of the period-mean filter's angles: they start again from
        0, known exactly (their rows and columns of P zeroed, :data:`PM_ANGLE_VAR` on the diagonal)."""
        ukf.x[IX_PMEAN] = 0.0
        ukf.P[IX_PMEAN, :] = 0.0
        ukf.P[:, IX_PMEAN] = 0.0
        ukf.P[IX_PMEAN, IX_PMEAN] = np.eye(4) * PM_ANGLE_VAR
        self._t_pm = t

    def _ring_noise(self, r_om: list[float], wl: list[float]) -> None:
        """The carcass mode in the wheel speeds as measurement noise, when the rate cannot follow it.

        With a declared carcass the wheel rings on it (f_c, :meth:`_relax`).  While the wheel-speed period T
        is too long for the carcass term (f_c T > ``CARCASS_MAX_FT``) the filter's μ is the paper's random
        walk and the ring is not in the model; a period-mean sample then carries it, ≈ πf_cT late, and the
        update would turn it into a μ that moves against the truth's (half a period late at 20 Hz).  The
        ring is therefore taken as what it is for this model, a part of the measured speed it does not
        describe: its variance per wheel, the mean excess of the squared innovation over the predicted
        P_ωω (covariance matching on R, Mehra 1972), E[ν_i² − P_ii] over ``carcass_ring_tau_s``, replaces
        R_ω,i where it is larger (the sensor's R stays the floor).  Updates outside the gate are left out
        (they are faults, not the ring); nothing is added before one time constant of samples was seen.
        ``r_om`` (R_ω of this sample, from the sensor figures) is changed in place."""
        T = self._rates.period("omega")
        if T * self._f_carcass <= CARCASS_MAX_FT or self._pm:   # the mode is modelled (carcass term, or the
            return                                              # period-mean filter)
        ukf = self.ukf
        x, P = ukf.x, ukf.P                                # predicted mean and covariance of this step
        tau = self.cfg.carcass_ring_tau_s
        ring = self._ring
        ex = []
        for i in range(4):
            nu = wl[i] - float(x[i])
            nu *= nu
            pi = float(P[i, i])
            if not nu <= self._gate * (pi + r_om[i]):
                break
            ex.append(nu - pi)
        else:
            g = T / tau if T < tau else 1.0
            for i in range(4):
                ring[i] += g * (ex[i] - ring[i])
            ring[4] += T
        if ring[4] >= tau:
            for i in range(4):
                if ring[i] > r_om[i]:
                    r_om[i] = ring[i]

    def _declare_lost(self, t: float, since: float, status: int) -> Estimate:
        """Drop the filter (it restarts from the next measurements, :meth:`_init_filter`) and say so."""
        self.counters["lost"] += 1
        self._lost = True
        self.ukf = None
        self._cm = CovarianceMatching(N_STATE, self.cfg.adapt_window, self.cfg.adapt_min, self.cfg.adapt_max)
        self._A = np.ones(N_STATE)
        self._Qbase = None
        e = self._estimate(t, status | FILTER_LOST, None)
        return dataclasses.replace(e, lost_since=since)

    def _recover(self, t: float) -> None:
        """Restart the filter from the last finite mean after a numerical failure."""
        self.counters["resets"] += 1
        old = self.ukf
        x = old.x if old is not None and np.isfinite(old.x).all() else None
        self.ukf = None
        if x is not None:
            self._init_filter(t, x[:4])
            if self.ukf.n == x.shape[0]:  # type: ignore[union-attr]
                self.ukf.x = x.copy()  # type: ignore[union-attr]
            else:
                self.ukf.x[:N_STATE] = x[:N_STATE]  # type: ignore[union-attr]

    # ------------------------------------------------------------------ output
    def _wheel_factors(self, kap: float) -> NDArray[np.float64]:
        """Ground speed of each wheel over v at path curvature κ [1/m]: :func:`~tractionecu.model.vehicle.
        wheel_speed_factors` (FL, FR, RL, RR) from floats."""
        h = self._hb * kap
        lk = self.vehicle.wheelbase_m * kap
        left, right = 1.0 - h, 1.0 + h
        return np.array([math.sqrt(left * left + lk * lk), math.sqrt(right * right + lk * lk), left, right])

    def _wheel_radii(self, v: float) -> list[float]:
        """Each wheel's rolling radius [m] for the reported slip: the held axle loads' (eq. 9, times the radius
        calibration's scale) with the lateral load transfer at speed v [m/s] and the curvature input
        (:func:`~tractionecu.model.vehicle.wheel_radii`, as ``_kernels.estimate_outputs``)."""
        _, _, rdf, rdr = self.model.load_floats(float(self._u[4]), float(self._u[5]))
        out = np.empty(4)
        wheel_radii(self.model._kc, self._u, v, float(self._u[IU_KAPPA]), rdf * self._kf, rdr * self._kr, out)
        return out.tolist()

    def _slip(self, w: list[float], v: float, k: list[float]) -> list[float]:
        """Slip per wheel (eq. 6, :func:`~tractionecu.model.vehicle.slip`) from floats, same operations,
        each wheel against its own ground speed k_i·v (``k``: :meth:`_wheel_factors`), on its own radius
        (:meth:`_wheel_radii`)."""
        out = []
        for x, rd, ki in zip(w, self._wheel_radii(v), k):
            va = abs(v * ki)
            vw = abs(rd * x)
            if vw < 1e-6 and va < 1e-6:
                out.append(0.0)
            elif va <= vw:
                out.append(1.0 - va / vw)
            else:
                out.append(-1.0 + vw / va if va != 0.0 else math.nan)
        return out

    def _slip_supported(self, v: float, kap: float, kw: NDArray[np.float64], omega: NDArray[np.float64],
                        pd: NDArray[np.float64]) -> bool:
        """Whether every wheel's slip standard deviation is within ``slip_sigma_max`` (SLIP_UNCERTAIN).

        Eq. 6 against the wheel's ground speed k_i(κ)·v: ∂s_i/∂v = k_i/(r_d,i|ω_i|) and ∂s_i/∂κ =
        v ∂k_i/∂κ/(r_d,i|ω_i|) (driving; braking the same to first order in s), so
        σ_s,i² = (P_vv k_i² + (v ∂k_i/∂κ)² σ_κ²)/(r_d,i ω_i)².  At 2.5 m/s with the datasheet GNSS
        speed noise σ_s ≈ 0.010; at 1 m/s ≈ 0.025.  With numba, ``_kernels.estimate_outputs`` runs the
        same test compiled: change both (tests/estimation/test_speed_equivalence.py holds them equal).
        """
        bound = self.cfg.slip_sigma_max
        if not bound > 0.0:
            return True
        rds = self._wheel_radii(v)
        pv = float(pd[IX_V])
        kv = self._kappa_var
        hb = self._hb
        dks = wheel_speed_factor_slopes(kap, 2.0 * hb, self.vehicle.wheelbase_m) if kv > 0.0 else (0.0,) * 4
        lim = bound * bound
        for ki, dk, w, rd in zip(kw.tolist(), dks, omega.tolist(), rds):
            vw = rd * w
            vi = v * dk
            if not pv * ki * ki + vi * vi * kv <= lim * vw * vw:        # (NaN: not supported either)
                return False
        return True

    def _win_reset(self) -> None:
        """Forget the travel the averaged slip is taken over (:meth:`_slip_window`)."""
        self.slip_window = (0.0, math.nan)
        """Length [m] and largest per-wheel σ [-] of the stretch the last SLIP_AVERAGED slip was averaged over."""
        self._win_n = 0
        self._win_dir = 0.0
        # cumulative sums since the window began, one entry per step: time, ground distance Σ|v|Δt,
        # Σ P_vv Δt, per wheel ground distance Σ k_i|v|Δt, rolled distance Σ r_d,i|ω_i|Δt, Σ |v ∂k_i/∂κ|Δt,
        # Σ μ_i|v|Δt
        self._win_t: list[float] = []
        self._win_s: list[float] = []
        self._win_p: list[float] = []
        self._win_c: list[tuple[float, ...]] = []

    def _slip_window(self, t: float, v: float, kw: NDArray[np.float64], omega: NDArray[np.float64],
                     mu: NDArray[np.float64], pvv: float, kap: float) -> NDArray[np.float64] | None:
        """The slip averaged over the last metres of travel, or None when even that is not supported.

        Called on the steps whose own slip σ exceeds ``slip_sigma_max`` while moving; the window restarts
        at a standstill, a change of direction, a gap, a new filter and whenever the step's own slip is
        supported.  Over a stretch of T seconds the slip of wheel i is that of the distances (eq. 6 on
        their sums): s̄_i = 1 − G_i/W_i driving, −1 + W_i/G_i braking, G_i = Σ k_i|v|Δt the wheel's ground
        distance, W_i = Σ r_d,i|ω_i|Δt its rolled distance.  Its σ, taken in quadrature:

        * noise: G_i's error is that of the filter's speed integrated over T, variance
          k̄_i² P̄_vv T² c(T), P̄_vv the mean of the filter's P_vv and c(T) = 2(τ/T)(1 − (τ/T)(1 − e^(−T/τ)))
          the variance ratio of the mean of an error correlated exponentially over τ = ``slip_avg_corr_s``;
        * curvature: (Σ|v ∂k_i/∂κ|Δt) σ_κ, not reduced by averaging (the curvature error is a slow bias);
        * lag: the slip now differs from the stretch's mean as μ does, |μ̂_i − μ̄_i| / (dμ/ds)(s̄_i) on the
          identified μ(s) (μ̄_i distance-weighted over the stretch); without an identified curve no
          average is reported.

        σ_s̄,i is the first two through ∂s̄/∂G_i, with the lag added.

        Steady travel only: a distance mean is the slip now only while the wheels roll steadily.  When the
        machine starts or stops a leg at 1 m/s the slip swings by 0.03–0.05 within a second (the drive-line's
        and the tyre's relaxation over L_r/|v|) while μ, and so the lag term, hardly moves
        (physical-headland-reverse seed 0: the averaged slips in speed changes were off by 0.018, in steady
        travel by 0.003).  No average is reported while a wheel's rolled speed now, r_d,i|ω_i|, differs from
        its mean over the last :data:`SLIP_STEADY_S` by more than ``slip_sigma_max`` of it (conservative when
        the ground speed follows at a constant slip).  Of the stretches ending now of
        ``slip_avg_max_m`` × 0.8^m metres (m = 0 … 15, none shorter than two steps), the one with the
        smallest largest-wheel σ is reported if that σ is within ``slip_sigma_max``.
        """
        cfg = self.cfg
        d = 1.0 if v > 0.0 else -1.0
        n = self._win_n
        if n and (d != self._win_dir or not 0.0 < t - self._win_t[-1] <= cfg.max_gap_s):
            self._win_reset()
            n = 0
        if n == 0:
            self._win_dir = d
            self._win_t.append(t)
            self._win_s.append(0.0)
            self._win_p.append(0.0)
            self._win_c.append((0.0,) * 16)
            self._win_n = 1
            return None
        _, _, rdf, rdr = self.model.load_floats(float(self._u[4]), float(self._u[5]))
        rdf *= self._kf
        rdr *= self._kr
        av = abs(v)
        dt = t - self._win_t[-1]
        dks = wheel_speed_factor_slopes(kap, 2.0 * self._hb, self.vehicle.wheelbase_m)
        ml = mu.tolist()
        ml_om = omega.tolist()
        inc = ([ki * av * dt for ki in kw.tolist()]
               + [abs(rd * w) * dt for rd, w in zip((rdf, rdf, rdr, rdr), ml_om)]
               + [abs(v * dk) * dt for dk in dks] + [m * av * dt for m in ml])
        self._win_t.append(t)
        self._win_s.append(self._win_s[-1] + av * dt)
        self._win_p.append(self._win_p[-1] + pvv * dt)
        self._win_c.append(tuple(a + b for a, b in zip(self._win_c[-1], inc)))
        n += 1
        self._win_n = n
        ws = self._win_s
        j_lo = bisect.bisect_left(ws, ws[-1] - cfg.slip_avg_max_m)    # first start within slip_avg_max_m
        if j_lo > 4096:                                               # drop what no window reaches any more
            # (nor the steadiness test's look-back over SLIP_STEADY_S, which at over slip_avg_max_m per
            # SLIP_STEADY_S reaches further back than the distance windows: kept as the compiled loop keeps it)
            j_lo = min(j_lo, bisect.bisect_left(self._win_t, t - SLIP_STEADY_S))
            for lst in (self._win_t, self._win_s, self._win_p, self._win_c):
                del lst[:j_lo]
            n -= j_lo
            self._win_n = n
        curve = self._curve_state.curve
        if curve is None or n < 3:
            return None
        tau = cfg.slip_avg_corr_s
        kv = self._kappa_var
        wt, wp, wc = self._win_t, self._win_p, self._win_c
        cn = wc[-1]
        # steady travel only (docstring): each wheel's rolled speed now against its mean over SLIP_STEADY_S
        jq = bisect.bisect_left(wt, t - SLIP_STEADY_S)
        if jq > n - 2:
            jq = n - 2
        tq = t - wt[jq]
        cq = wc[jq]
        for i, rd in enumerate((rdf, rdf, rdr, rdr)):
            rq = (cn[4 + i] - cq[4 + i]) / tq
            if not (rq > 0.0 and abs(abs(rd * ml_om[i]) - rq) <= cfg.slip_sigma_max * rq):
                return None
        best: list[float] | None = None
        top_best = s_best = math.inf
        length = cfg.slip_avg_max_m
        last = -1
        for _ in range(16):
            j = bisect.bisect_left(ws, ws[-1] - length)
            length *= 0.8
            if j == last or j > n - 3:
                continue
            last = j
            T = wt[-1] - wt[j]
            S = ws[-1] - ws[j]
            if not (T > 0.0 and S > 0.0):
                continue
            r = tau / T
            var_v = (wp[-1] - wp[j]) / T * 2.0 * r * (1.0 - r * (1.0 - math.exp(-1.0 / r)))
            cj = wc[j]
            out = []
            sig = []
            for i in range(4):
                g = cn[i] - cj[i]
                w = cn[4 + i] - cj[4 + i]
                kk = cn[8 + i] - cj[8 + i]
                # a wheel that rolled less than half its ground distance (s̄ < −0.5) is locked or its speed is dead:
                # no driven wheel slides so under drive torque, and its σ from the distances is near zero (four
                # wheel speeds stuck at 0 reported slip −1 as supported)
                if not (g > 0.0 and w > 0.5 * g):
                    out = []
                    break
                sg = math.sqrt(g * g / (S * S) * var_v * T * T + kk * kk * kv)      # σ of G_i [m]
                if g <= w:
                    out.append(1.0 - g / w)
                    sig.append(sg / w)
                else:
                    out.append(-1.0 + w / g)
                    sig.append(sg * w / (g * g))
            if not out or max(sig) > cfg.slip_sigma_max:
                # σ with the lag only grows (quadrature): a stretch over the bound here is never reported
                continue
            slope = np.abs(curve.dmu_ds(np.abs(np.array(out)))).tolist()
            top = 0.0
            for i in range(4):
                lag = abs(ml[i] - (cn[12 + i] - cj[12 + i]) / S) / slope[i] if slope[i] > 0.0 else math.inf
                si = math.sqrt(sig[i] * sig[i] + lag * lag)
                top = si if si > top else top
            if top < top_best:
                top_best, best, s_best = top, out, S
        if best is None or not top_best <= cfg.slip_sigma_max:
            return None
        self.slip_window = (s_best, top_best)
        return np.array(best)

    def _estimate(self, t: float, status: int, x: NDArray[np.float64] | None, updated: bool = False) -> Estimate:
        cfg = self.cfg
        ukf = self.ukf
        if self._lost:
            status |= FILTER_LOST
        if x is None or ukf is None:
            self._sm_xf = None
            if self._win_n:
                self._win_reset()
            nan4 = np.full(4, np.nan)
            rad = self._rad
            return Estimate(t, nan4, math.nan, math.nan, self._curve_state.class_name, nan4.copy(), math.nan,
                            nan4.copy(), np.full(N_STATE, np.nan), math.nan, self._f, status | NOT_CONVERGED, False,
                            0, self._curve_state.class_index, math.nan, None,
                            rad[0], rad[1], rad[2])
        c_mu = cfg.conv_sigma_mu ** 2
        c_rho = cfg.conv_sigma_rho ** 2
        if self._conv:
            # hysteresis: once converged, the bounds to leave are conv_exit_factor × the bounds to enter (the
            # σ's sawtooth between the samples of a slow wheel-speed stream is not a loss of convergence)
            f2 = cfg.conv_exit_factor * cfg.conv_exit_factor
            c_mu *= f2
            c_rho *= f2
        kap = float(self._u[IU_KAPPA])
        P = ukf.P
        x_state = x                     # the filter's whole state (the smoother's transition)
        if self._hub_on:
            # the two-inertia hub: the wheels' speeds (ω, slip eq. 6) are the rims', the rest the paper's states
            x = x[_HUB_OUT]
            P = P[_HUB_OUT[:, None], _HUB_OUT]
        if JIT:
            # the numpy path below with _wheel_factors and _slip_supported in one compiled call (same operations)
            _, _, rdf, rdr = self.model.load_floats(float(self._u[4]), float(self._u[5]))
            buf = np.empty(26)
            code = _kernels.estimate_outputs(x, P, rdf * self._kf, rdr * self._kr, c_mu, c_rho, kap, self._hb,
                                             self.vehicle.wheelbase_m, self._kappa_var, cfg.slip_sigma_max, buf,
                                             self.model._kc, self._u)
            mu, s, omega, pd, kw = buf[0:4], buf[4:8], buf[8:12], buf[12:22], buf[22:26]
            v = float(x[IX_V])
            conv_p = (code & 1) == 1
            slip_ok = code >= 2
        else:
            kw = self._ones4 if kap == 0.0 else self._wheel_factors(kap)
            xl = x.tolist()
            v = xl[IX_V]
            s = np.array(self._slip(xl[:4], v, kw.tolist()))
            pd = P.diagonal().copy()
            pl = pd.tolist()
            mu = x[IX_MU].copy()
            omega = x[:4].copy()
            conv_p = (pl[5] < c_mu and pl[6] < c_mu and pl[7] < c_mu and pl[8] < c_mu and pl[IX_RHO] < c_rho)
            slip_ok = self._slip_supported(v, kap, kw, omega, pd)
        # curve parameter a (paper section 3.2) at the curve rate; not fed by a filter that was lost, nor with the
        # curvature input at its clip (the slips there are not known: SLIP_UNCERTAIN)
        if (t - self._t_curve >= cfg.curve_period_s and abs(v) >= cfg.curve_min_speed_mps and not self._lost
                and slip_ok and -KAPPA_MAX < kap < KAPPA_MAX):
            self._t_curve = t
            self._loads()
            # ∂s/∂v·σ_v and ∂s/∂κ·σ_κ of eq. 6 with the wheel's ground speed k_i(κ)·v
            dk = np.array(wheel_speed_factor_slopes(kap, self.vehicle.track_width_m, self.vehicle.wheelbase_m))
            sig_vi = np.sqrt(pd[IX_V] * kw * kw + (v * dk) ** 2 * self._kappa_var)
            sig_s = sig_vi / np.maximum(self._rd * np.abs(omega), 1e-3)
            self._curve_state = self._curve.update(t, mu, s, np.sqrt(pd[IX_MU]), sig_s, self._fz)
        if self._pm and self._t_upd_w < t <= self._t_upd_w + PM_HOLD_PERIODS * self._rates.period("omega"):
            # the period-mean filter between two wheel-speed samples: its σ_μ rises through the carcass spring
            # until the next sample (a sawtooth of +25–30 % at 20 Hz, against +19 % on the paper's model), which
            # is no loss of convergence; the verdict is the last sample's.  Not past 1.5 periods after one:
            # samples that stop or are gated are judged on the growing σ again
            conv_p = self._conv
        conv = self.t_init is not None and t - self.t_init >= cfg.conv_min_s and conv_p
        self._conv = conv
        if not conv:
            status |= NOT_CONVERGED
        elif self._lost:
            self._lost = False          # re-converged: the lost period ends with this step
            status &= ~FILTER_LOST
        rho = float(x[IX_RHO])
        if abs(v) < cfg.standstill_speed_mps:
            # ρ_s drops out of eq. 8 and slip is 0/0: report the last moving values, flagged (the
            # filter's own covariance of ρ_s keeps growing meanwhile)
            status |= STANDSTILL
            if self._held is not None:
                rho, s = self._held
            if self._win_n:
                self._win_reset()
        else:
            # the curvature input at its clip (|κ| ≥ KAPPA_MAX: a turn tighter than the model's range): the wheels'
            # ground speeds k_i(κ)·v of eq. 6 are not known, so neither is the slip nor its average over the last
            # metres; the last supported slip, flagged (μ and ρ_s do not rest on it)
            clipped = not -KAPPA_MAX < kap < KAPPA_MAX
            if clipped:
                status |= SLIP_UNCERTAIN
                if self._held is not None:
                    s = self._held[1]
                if self._win_n:
                    self._win_reset()
            elif not slip_ok:
                # slip not supported (creeping, reversing): its average over the last metres if that is
                # supported (SLIP_AVERAGED), else the last supported slip, flagged; ρ_s stays live
                avg = self._slip_window(t, v, kw, omega, mu, float(pd[IX_V]), kap) if cfg.slip_avg_max_m > 0.0 else None
                if avg is not None:
                    s = avg
                    status |= SLIP_AVERAGED
                else:
                    status |= SLIP_UNCERTAIN
                    if self._held is not None:
                        s = self._held[1]
            elif self._win_n:
                self._win_reset()
            if conv and ((slip_ok and not clipped) or self._held is not None):
                self._held = (rho, s)
        cs = self._curve_state
        nis, dof = (ukf.last_nis, ukf.last_dof) if updated else (math.nan, 0)
        if self._sys_flag:
            status |= UNVERIFIED
        rad = self._rad
        tr = None
        if self._smooth:
            xf = x_state.copy()
            xp = self._sm_xp
            link = xp is not None and xp.shape == xf.shape
            if self._pm:                # the smoother runs on the hub's states, the marginal (ukf.gain_n)
                tr = (link, xf[:N_STATE_HUB].copy(), xp[:N_STATE_HUB].copy() if link else None,
                      self._sm_G if link else None)
            else:
                tr = (link, xf, xp if link else None, self._sm_G if link else None)
            if self._hub_on:            # the reported wheel speeds are the rims' (the smoother's slip)
                tr += (_HUB_SMOOTH_INDEX,)
            self._sm_xf = xf
        return Estimate(t, mu, rho, cs.a, cs.class_name, s, v, omega, pd, nis,
                        self._adapt_mu, status, (status & INVALID_MASK) == 0, dof, cs.class_index, math.nan,
                        self._sys_var, rad[0], rad[1], rad[2], cs, kap, tr)
