"""Machine-level traction estimation for engine-driven tractors (mechanical and power-split drivetrains).

The hub estimator (:mod:`.estimator`, paper section 3) needs a drive torque
and a speed per wheel.  A tractor with one engine, a gearbox and a
mechanical front-wheel drive (MFWD) puts one engine torque, one gear ratio
and one or two wheel-based speeds on the bus (J1939 EEC1, ETC2, CCVS1 /
WBSD, EBC2).  That supports one adhesion for the whole machine, not one
per wheel: this module estimates what the signals support and says so.

Level and what is claimed
-------------------------
The estimate is **machine level** (status bit :data:`MACHINE_LEVEL`):

* one adhesion μ for all driven wheels, μ = ΣF_h / ΣF_z (the load-weighted
  mean of the wheels' adhesions), written to all four wheels of the
  :class:`~.estimator.Estimate` (the broadcast and the map carry it so,
  flagged);
* ρ_s, from eq. 8 with the measured draft; **without a draft sensor**
  ρ_s and the implement's draft are one term of eq. 8 and cannot be
  separated: the filter estimates their sum ρ_Σ = ρ_s + F_dx/(m g)
  (:attr:`MachineEstimate.resistance`), sets :data:`DRAFT_NOT_SEPARATED`
  and reports ρ_s as NaN, never as a number;
* slip per axle, from the kinematics of the drivetrain (rear wheels at the
  drive speed, front wheels ``front_lead`` faster when the MFWD is
  engaged);
* a of μ(s) from the machine-level (μ, s) pair (:mod:`.curve`), with the
  effective slip s_e of the machine: g(s_e) = Σ_axles w_a g(s_a), w_a the
  axle's share of the driven load, so that μ = a·g(s_e) holds exactly when
  every wheel follows μ_i = a·g(s_i);
* **no μ while the bus cannot support it**: during a gear shift or clutch slip, in a turn the rigid
  MFWD kinematics do not hold in, with the front axle off its coupling ratio, or at a net torque under
  10 %, status :data:`MACHINE_UNSUPPORTED` makes the estimate not valid (the map rejects it, the curve
  takes no pair from it; :class:`MachineValidity`);
* a variance of μ that includes the efficiency tolerance:
  P_μ + (σ_η/η · μ)², σ_η/η = ``efficiency_tolerance`` (a bias the data
  cannot reveal: η and a scale the force alike), in ``P_diag`` (so in
  ``sigma_mu``); the same bias moves ρ_s by as much through eq. 8, which
  ``P_diag`` of ρ_s includes likewise.

Model
-----
State x = (ω, v, μ, ρ), ω the rear wheel angular speed [rad/s] (the
drive speed; the drivetrain couples every wheel to it), v the ground speed,
ρ = ρ_s (ρ_Σ without a draft sensor).  Inputs: the wheel torque

    M = d · (p − p_f)/100 · T_ref · i · η,    i = i_g · i_f,

p the EEC1 actual percent torque (SPN 513), p_f the nominal friction percent
torque (``engine_friction_percent``), T_ref the EC1 reference torque
(SPN 544), i_g the ETC2 actual gear ratio (SPN 526) or the ratio learnt from
engine speed over wheel speed, i_f the final drive, η the efficiency, d = ±1
the direction of travel.  With the MFWD engaged the front wheels turn at
k = 1 + λ times ω (λ the front-axle lead, declared as the front over rear
circumferential speed at the tyres' nominal radii, which are equal here: one
``r0_m``): the gears fix the angular speed ratio, so the loaded radii do not
enter it, and a lighter front axle on a larger rolling radius r_f runs at a
front slip above the rear's by more than λ (s_f = 1 − v/(k ω r_f)); the power
balance of the rigid drivetrain, summed eq. 2 over the wheels, and eq. 8 give

    J_eq ω̇ = M − (μ + ρ_t sgn ω) · (r_r F_zr + k r_f F_zf)
    m v̇   = μ (F_zr + F_zf) − F_dx − ρ m g sgn v,
    J_eq  = J_e i² + 2 J_w (1 + k²)

(front disengaged: the front wheels roll, F_h,f = −ρ_t F_zf, the rear
wheels carry F_h,r = μ ΣF_z + ρ_t F_zf, and the rear torque balance reads
J_eq ω̇ = M − (μ + ρ_t) r_r ΣF_z with the same machine μ; the μ(s) pair is
then the rear axle's, (F_h,r/F_zr, s_r)).  The axle loads are the measured front-axle load, or
the static share less the draft's load transfer F_dx h_hitch / L; r_d per
axle from eq. 9.  The right-hand side is constant between sign changes of ω
and v, so one Euler step is its exact solution (the RK4 of the hub model
reduces to it likewise).  Sigma points go through it in one vectorised call
of the same :class:`~.ukf.UnscentedFilter`; Q is adapted by the same
covariance matching and fuzzy supervisor (:mod:`.supervisor`).

Measurements, in state units: the drive speed ω from the engine speed over
the total ratio (EEC1 at 10-20 ms), else from the wheel-based speed (CCVS1
or WBSD, over ``wheel_speed_radius_m``), else from EBC2's front-axle speed
over (1 + λ) r_r; the ground speed from GBSD (radar) and the GNSS, each
when it arrives.  EBC2's left and right rear wheels tell a turn (for the
radius calibration); ``[drivetrain] wheel_speeds = "machine"`` leaves EBC2
out.  With gear_ratio = "learnt" (or no ETC2 on the bus) the engine speed over the learnt ratio is the
drive speed at EEC1's rate, its variance with the learnt ratio's.  Axle-level estimation (a torque split set by a centre differential)
is not implemented: with a rigid MFWD coupling the bus supports the
machine level only.

Equation numbers follow the paper's source; see :mod:`tractionecu.estimation`.
"""

from __future__ import annotations

import copy
import math
from collections import deque
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
from numpy.typing import NDArray
from scipy.special import erfcinv

from ..config import SensorSpec, VehicleParams, setting, validate
from ..errors import EstimatorError
from ..model.mucurve import SoilClass
from ..model.vehicle import compiled, rolling_radius
from .config import EstimatorConfig
from .curve import CurveState
from .machine_curve import MachineCurveState, machine_curve_estimator, resolve_prior
from .estimator import (COV_REPAIRED, DRAFT_TIMEOUT, GPS_TIMEOUT, INPUT_REJECTED, MEAS_GATED, NOT_CONVERGED,
                        STANDSTILL, TORQUE_TIMEOUT, WHEEL_TIMEOUT, AXLE_TIMEOUT, DRAFT_NOT_SEPARATED, INVALID_MASK,
                        MACHINE_LEVEL, MACHINE_UNSUPPORTED, Estimate)
from .calibration import RadiusCalibration
from .rates import BusRates
from .supervisor import CovarianceMatching, DynamicsMonitor, FuzzySupervisor
from .ukf import UnscentedFilter

__all__ = ["DRAFT_NOT_SEPARATED", "MACHINE_LEVEL", "MACHINE_UNSUPPORTED", "MachineEstimate", "MachineEstimator",
           "MachineSensors", "MachineValidity"]

N_MACHINE = 4
IX_W, IX_V, IX_MU, IX_RHO = 0, 1, 2, 3
SMOOTH_INDEX = (IX_MU, IX_MU, IX_MU, IX_MU, IX_RHO)
"""The state index of each reported μ1..4 and ρ_s (the fixed-lag smoother's, Estimate.transition)."""
_EYE = np.eye(N_MACHINE)
_OUT_W, _OUT_V, _OUT_VR = 0, 1, 2


@dataclass(frozen=True)
class MachineSensors:
    """Noise figures of the standard messages the machine-level estimator reads (R and input noise).

    Sources: SAE J1939-71 resolutions (EEC1 engine speed 0.125 rpm/bit,
    percent torque 1 %/bit; CCVS1 1/256 km/h/bit); the ripple of speeds
    measured from tooth periods as for :class:`~tractionecu.config.SensorSpec`;
    the engine ECU's torque is computed from the injected fuel quantity,
    which makes its percent torque repeat within about ±2 % of the reference
    in steady running (its bias is the efficiency tolerance's part);
    Doppler radar ground-speed sensors are specified to 1-3 % of the speed on
    field surfaces (e.g. the dickey-john RADAR III and Raven data sheets).
    """

    engine_speed_sigma_rel: float = setting(0.002, "engine-speed ripple, relative [-] (crank-wheel tooth periods)", 0.0, 0.5)
    engine_speed_quant: float = setting(math.pi / 240.0, "engine-speed resolution [rad/s] (0.125 rpm/bit)", 1e-6, 10.0)
    torque_sigma_pct: float = setting(2.0, "engine percent torque noise [%] of the reference torque", 0.0, 50.0)
    torque_quant_pct: float = setting(1.0, "percent torque resolution [%] (1 %/bit)", 1e-3, 10.0)
    wheel_speed_sigma_rel: float = setting(0.005, "wheel-based speed noise, relative [-]", 0.0, 0.5)
    wheel_speed_sigma_abs: float = setting(0.005, "wheel-based speed noise floor [m/s]", 0.0, 1.0)
    wheel_speed_quant: float = setting(1.0 / 256.0 / 3.6, "wheel-based speed resolution [m/s] (CCVS1 1/256 km/h)", 1e-6, 1.0)
    radar_sigma_rel: float = setting(0.02, "radar ground-speed noise, relative [-] (1-3 % of speed)", 0.0, 0.5)
    radar_sigma_abs: float = setting(0.01, "radar ground-speed noise floor [m/s]", 0.0, 1.0)

    def __post_init__(self) -> None:
        validate(self, "machine_sensors")


@dataclass(frozen=True)
class MachineValidity:
    """When the bus cannot support a machine-level μ (status :data:`MACHINE_UNSUPPORTED`, not valid).

    * **Gear shift or clutch slip**: ETC2's actual gear ratio (or current gear) changed, or the engine speed
      over the wheel-based speed disagrees with the reported total ratio by more than ``ratio_tolerance``
      (a slipping clutch or a powershift changeover: the engine torque does not reach the wheels as
      M = (p − p_f) T_ref i η says).  Held ``shift_hold_s`` after the last such sample: a powershift
      changes over in 0.3–1 s and the filter's μ, which took the torque step meanwhile, settles after it.
      A power-split / CVT transmission (``kind = "power-split"``) moves its reported ratio continuously
      without interrupting the torque: there only the speed check, neutral and a change of ETC2's current
      gear (a range change) count.
    * **Front axle not coupled as modelled** (MFWD declared engaged): in a turn the front axle travels a
      longer path than the rear, √(1 + (Lκ)²) times, which the rigid coupling's kinematics (front wheels
      (1 + λ) r_r/r_f times the rear's angular speed on a straight line) do not hold; beyond
      ``max_front_path_excess`` the front slip of the model is that far off, and tractors with automatic
      MFWD management disengage it at some steering angle.  κ from EBC2's rear wheels (left − right
      over the track) or the GNSS course rate over the speed.  The course rate is the least-squares slope
      of the course over the last ``course_window_s`` (at least three epochs above 0.5 m/s), and a turn is
      one whose rate exceeds the limit by twice the slope's standard error: the course's own noise, σ_χ =
      σ_v/|v| per epoch (the Doppler velocity across the track), is 1.1° at 2.5 m/s, more than a 17 m
      radius turns it between two 10 Hz epochs (0.8°), so a rate from two epochs flagged straight passes
      as turns (0.13 % of the steps valid).  Also when EBC2's front-axle over rear-wheel
      speed, smoothed over ``coupling_tau_s``, departs by more than ``coupling_tolerance`` times the lead
      from its value learnt over ``coupling_ref_tau_s`` (the engaged axle's fixed gear ratio; a disengaged
      front axle rolls and its ratio falls by λ + s_r).  A disengagement that lasts much longer than
      ``coupling_ref_tau_s`` is learnt as the normal ratio: declare ``front_drive`` as it is driven, or
      ``front_drive = "auto"``: then EBC2's front over rear angular speed ratio (fixed by the gears while
      engaged, whatever the loads; learnt outside turns and shifts) falling by more than
      ``coupling_tolerance`` times the lead switches the model to the rolling front axle (back above half
      of it), held unsupported like a shift (:meth:`MachineEstimator._mfwd_from_bus`; the DBC has no MFWD
      state parameter, EBC2's speeds are the bus's evidence).  In a tight turn a rolling front axle runs
      faster than the rear on its longer path (+25 % at the simulated headlands), so the state is not told
      there; such turns are unsupported anyway.
    * **Too little drive torque**: the net percent torque p − p_f below ``min_net_torque_pct``: at 10 % a
      1 % error of the friction percent (its resolution) is already a 10 % error of μ.
    """

    ratio_tolerance: float = setting(0.03, "engine speed / (wheel speed x total ratio) tolerance [-]", 0.001, 1.0)
    shift_hold_s: float = setting(2.0, "time after a ratio change or clutch slip with μ not supported [s]", 0.0, 60.0)
    max_front_path_excess: float = setting(0.01, "front-axle path over the rear's in a turn, less 1 [-]", 0.0, 1.0)
    turn_hold_s: float = setting(1.0, "time after a turn beyond the limit with μ not supported [s]", 0.0, 60.0)
    course_window_s: float = setting(1.0, "window of the GNSS course rate's least-squares slope [s]", 0.2, 10.0)
    coupling_tau_s: float = setting(3.0, "smoothing of the front/rear speed ratio [s]", 0.0, 60.0)
    coupling_ref_tau_s: float = setting(30.0, "time constant of the learnt coupled front/rear speed ratio [s]",
                                        1.0, 3600.0)
    coupling_tolerance: float = setting(1.0, "front/rear ratio departure tolerated, in units of the lead [-]",
                                        0.0, 10.0)
    min_net_torque_pct: float = setting(10.0, "net percent torque below which μ is not supported [%]", 0.0, 100.0)

    def __post_init__(self) -> None:
        validate(self, "machine_validity")


@dataclass(slots=True)
class MachineEstimate(Estimate):
    """An :class:`~.estimator.Estimate` of the machine-level estimator (module doc): the same μ on every
    wheel, slip per axle, ρ_s NaN without a draft sensor; plus its level and the resistance sum."""

    level: str = "machine"
    """``"machine"``: one μ for the machine (status :data:`MACHINE_LEVEL`)."""
    resistance: float = math.nan
    """ρ_s + F_dx/(m g) [-]: the sum eq. 8 resists with; the filter's state without a draft sensor."""
    total_ratio: float = math.nan
    """Engine to rear wheel speed ratio i in use [-] (bus or learnt)."""
    front_engaged: bool = True
    """Whether the model drives the front axle (MFWD engaged: declared, or from EBC2 with ``auto``)."""


def _slip1(w: float, v: float, r_d: float) -> float:
    """Eq. 6 of one wheel, as :func:`~tractionecu.model.vehicle.slip` computes it, with floats."""
    vw = abs(r_d * w)
    va = abs(v)
    if max(vw, va) < 1e-6:
        return 0.0
    return 1.0 - va / vw if va <= vw else -1.0 + vw / va


RHO_S_PRIOR_SIGMA = 0.03
"""Spread (1σ) of a soil's ρ_s about its class's typical value [-], used without a draft sensor
(:meth:`MachineEstimator._draft_from_sum`): an assumption of about half the step between neighbouring
classes' typical values (stubble 0.06, tilled 0.12; :data:`~tractionecu.model.mucurve.SOIL_CLASSES`)."""

PAIR_S = 0.025
"""An engine speed at most this old [s] is compared with a wheel-based speed sample (EEC1 every 10-20 ms,
plus the bus's jitter)."""

WHEEL_SPEED_WINDOW_S = 0.1
"""The window a wheel-based speed sample averages over [s] (CCVS1 / WBSD every 100 ms from tooth periods)."""

RATIO_GAIN = 0.05
"""Exponential smoothing gain of the ratio learnt from engine speed over wheel speed, per wheel-based speed
sample (10 Hz: a time constant of 2 s) [-]."""

_ABSENT = object()
_SLICES = {(a, b): slice(a, b + 1) for a in range(3) for b in range(a, 3)}
"""Output slices of the update, made once: the filter caches its fast path per slice object."""
_NAN2 = np.full(2, np.nan)
_ONE2 = np.ones(2)
_INPUT_KEYS = ("Te", "Tref", "gear", "Fzf", "Fdx")


class MachineEstimator:
    """Machine-level AUKF-FS for an engine-driven tractor (module doc).

    Parameters
    ----------
    vehicle : the machine, with its ``[drivetrain]``.
    cfg : tuning (the hub estimator's :class:`~.config.EstimatorConfig`).
    sensors : the GNSS figures (``gps_speed_sigma``, ``gps_rate_hz``) and load-pin figures.
    draft : whether the hitch measures the draft; False: ρ_s and draft are estimated as their sum.
    front_load : whether the front-axle load is measured (default: ``[drivetrain] load_sensing``).
    machine_sensors : noise of the standard messages (:class:`MachineSensors`).
    curve_prior : the one shape a·g(s) the machine's μ(s) is fitted with (:mod:`.machine_curve`: ``"d497"``,
        or a surface class name or :class:`~tractionecu.model.mucurve.SoilClass`); None: the configuration's
        ``machine_curve_prior``, and when that is empty its ``soil_classes``.

    ``step(t, inputs, measurements)`` takes the keys of
    :data:`tractionecu.pipeline.signals.MACHINE_GROUPS` and the GNSS speed ``v``.
    """

    level = "machine"

    def __init__(self, vehicle: VehicleParams, cfg: EstimatorConfig | None = None,
                 sensors: SensorSpec | None = None, *, draft: bool = True, front_load: bool | None = None,
                 machine_sensors: MachineSensors | None = None, validity: MachineValidity | None = None,
                 curve_prior: str | SoilClass | None = None) -> None:
        dt = vehicle.drivetrain
        if not dt.engine_driven:
            raise EstimatorError("MachineEstimator: the vehicle's [drivetrain] kind is 'hub' (per-wheel torques: "
                                 "use Estimator)")
        self.vehicle = vehicle
        self.dt = dt
        self.cfg = cfg = cfg or EstimatorConfig()
        self._smooth = getattr(cfg, "smoother_lag_s", 0.0) > 0.0    # estimates carry transitions (.smoother)
        self.sensors = sp = sensors or SensorSpec()
        self.ms = machine_sensors or MachineSensors()
        self.validity = validity or MachineValidity()
        self._prior = resolve_prior(curve_prior if curve_prior is not None else (cfg.machine_curve_prior or None))
        self.draft = bool(draft)
        self.front_load = (dt.load_sensing == "front-axle") if front_load is None else bool(front_load)
        self.m = vehicle.mass_kg
        self.W = vehicle.weight_n
        self._auto = dt.front_drive == "auto"          # MFWD state from EBC2 (MachineValidity)
        self._lead_d = dt.front_lead
        self.engaged = dt.front_drive != "disengaged"
        self.lead = dt.front_lead if self.engaged else 0.0
        self.r_ws = dt.wheel_speed_radius_m or vehicle.r0_m
        self._gate = math.inf if cfg.gate_probability <= 0 else float(2.0 * erfcinv(cfg.gate_probability) ** 2)
        self._q_tune = np.array([cfg.q_omega, cfg.q_v, cfg.q_mu, cfg.q_rho])
        self._lo = np.array([-np.inf, -np.inf, cfg.mu_min, cfg.rho_min if draft else -1.0])
        self._hi = np.array([np.inf, np.inf, cfg.mu_max, cfg.rho_max if draft else 5.0])
        self._r_v = sp.gps_speed_sigma ** 2
        self._fz_var = sp.axle_sigma_n ** 2 + sp.axle_quant_n ** 2 / 12.0
        self._fd_var = sp.draft_sigma_n ** 2 + sp.draft_quant_n ** 2 / 12.0
        bus = 0.01
        self._rates = BusRates(
            {"Te": bus, "gear": 0.1, "Fzf": 1.0 / sp.loadpin_rate_hz, "Fdx": 1.0 / sp.loadpin_rate_hz,
             "omega": bus, "v": 1.0 / sp.gps_rate_hz},
            {"Te": cfg.torque_timeout_s, "gear": cfg.torque_timeout_s, "Fzf": cfg.axle_timeout_s,
             "Fdx": cfg.draft_timeout_s, "omega": cfg.wheel_timeout_s, "v": cfg.gps_timeout_s},
            cfg.timeout_periods, cfg.rate_window, cfg.max_gap_s)
        self._hold_s = min(cfg.torque_timeout_s, cfg.wheel_timeout_s)
        """A step without new samples is held (:meth:`step`) at most this long [s] after the last step with data,
        and never past the first time a stream could time out."""
        self._consts = np.array([vehicle.rho_t, self.W, self.m])
        self._tan_pull = math.tan(math.radians(vehicle.pull_angle_deg))
        self._r_cal = dt.rolling_radius_m
        self._ebc2 = dt.wheel_speeds != "machine"      # EBC2's front-axle and wheel speeds used
        self._cvt = dt.kind == "power-split"           # its reported ratio moves without interrupting the torque
        self._rdr_static = float(rolling_radius(0.5 * (1.0 - vehicle.static_front_fraction) * self.W, vehicle))
        self._cal_cfg = cfg.calibration if hasattr(cfg, "calibration") else None
        self.reset()
        self._cls0 = self._curve.classes[0]            # the first configured class: the effective slip's g
        grid = np.linspace(0.0, 1.0, 4001)
        self._g_table = (self._cls0.g(grid), grid)

    # ------------------------------------------------------------------ lifecycle
    def _course_turn(self, t: float, course_rad: float, val: MachineValidity) -> None:
        """A turn from the GNSS course (class :class:`MachineValidity`, "front axle not coupled"): the course
        rate as the least-squares slope over ``course_window_s``, tested against the limits less twice its
        standard error."""
        v = abs(self._last_v or 0.0)
        w = self._courses
        if v < 0.5 or (w and t - w[-1][0] > val.course_window_s):
            w.clear()                                          # creeping (the course is noise), or a gap
            self._turning_gnss = False
            if v < 0.5:
                return
        if w:
            if t <= w[-1][0]:
                return
            course_rad = w[-1][1] + (course_rad - w[-1][1] + math.pi) % (2.0 * math.pi) - math.pi
        w.append((t, course_rad))
        while t - w[0][0] > val.course_window_s:
            del w[0]
        n = len(w)
        if n < 3:
            return
        tm = sum(x for x, _ in w) / n
        cm = sum(c for _, c in w) / n
        stt = sum((x - tm) ** 2 for x, _ in w)
        if stt <= 0.0:
            return
        slope = sum((x - tm) * (c - cm) for x, c in w) / stt
        sigma_chi = math.sqrt(self._r_v) / v                   # the course's noise per epoch [rad]
        rate = max(0.0, abs(slope) - 2.0 * sigma_chi / math.sqrt(stt))
        self._turning_gnss = rate > self._radius.cfg.max_turn_rel / self.vehicle.track_width_m * v
        lk = self.vehicle.wheelbase_m * rate / v
        if math.sqrt(1.0 + lk * lk) - 1.0 > val.max_front_path_excess:
            self._t_turn = t

    def no_data(self, t: float) -> MachineEstimate:
        """As :meth:`Estimator.no_data <tractionecu.estimation.estimator.Estimator.no_data>`: nothing stepped in a
        wheel-speed silence longer than replay's grid gap; every value NaN, not converged."""
        return self._estimate(t, WHEEL_TIMEOUT | NOT_CONVERGED, None, math.nan)

    def reset(self) -> None:
        """Forget everything (as after power-up)."""
        cfg = self.cfg
        self.ukf: UnscentedFilter | None = None
        self.t: float | None = None
        self.t_init: float | None = None
        tref = self.dt.engine_reference_torque_nm          # declared, until EC1 says otherwise
        self._in = {"Te": math.nan, "Tref": tref if tref > 0.0 else math.nan, "gear": math.nan, "Fzf": math.nan,
                    "Fdx": math.nan}
        self._t_in = {k: -math.inf for k in _INPUT_KEYS}
        self._t_omega = -math.inf
        self._t_v = -math.inf
        self._last_v: float | None = None
        self._dir = 1.0
        self._t_dir_bus = -math.inf
        self._ratio_learnt = math.nan
        self._ratio_jump = 0
        self._vwb: float | None = None
        self._we_window: deque[tuple[float, float]] = deque()
        self._t_shift = -math.inf
        self._t_turn = -math.inf
        self._gear_seen: tuple[float, float] = (math.nan, math.nan)
        self._coupling = math.nan
        self._coupling_ref = math.nan
        self._wr, self._wr_ref, self._t_wr = math.nan, math.nan, -math.inf     # front_drive = "auto"
        if self._auto:
            self.engaged, self.lead = True, self._lead_d
        self._t_coupling = -math.inf
        self._rates.reset()
        self._fuzzy = FuzzySupervisor(cfg.fuzzy)
        self._dyn = DynamicsMonitor(cfg.dynamics_tau_s)
        self._cm = CovarianceMatching(N_MACHINE, cfg.adapt_window, cfg.adapt_min, cfg.adapt_max)
        self._A = np.ones(N_MACHINE)
        self._f = 1.0
        self._adapt_mu = 1.0
        self._t_adapt = -math.inf
        self._curve = machine_curve_estimator(cfg, self._prior)
        self._curve_state = self._with_prior(self._curve.state())
        self._t_curve = -math.inf
        self._held: tuple[float, list[float]] | None = None
        self._conv = False
        self._fdx_est = 0.0
        self._Q_cache: dict[tuple, NDArray[np.float64]] = {}
        self._adapt_version = 0
        self._radius = RadiusCalibration(self._cal_cfg)
        self._radius_version = 0
        self._turning = False
        self._turning_gnss = False
        self._courses: list[tuple[float, float]] = []      # (t [s], unwrapped course [rad]) of the window
        self._loads_key: tuple[float, float, int] | None = None
        self._loads = (math.nan,) * 4
        self._terms_key: float | None = None
        self._terms_val = (math.nan,) * 5
        self.counters = {"steps": 0, "updates": 0, "gated": 0, "rejected_inputs": 0, "rejected_measurements": 0,
                         "chol_repairs": 0, "resets": 0, "gap_resets": 0, "gear_changes": 0, "held_steps": 0,
                         "unsupported_steps": 0, "not_available": 0, "mfwd_changes": 0, "rejected_times": 0,
                         "time_backwards": 0}
        self._last: MachineEstimate | None = None
        self._hold_until = -math.inf
        # the fixed-lag smoother's transition (Estimate.transition, as the hub estimator's): the last estimate's
        # x⁺ and its μ and ρ_s as made, this step's prior and gain (a prior only where its prediction links)
        self._sm_xf: NDArray[np.float64] | None = None
        self._sm_raw: tuple[NDArray[np.float64], float] | None = None
        self._sm_xp: NDArray[np.float64] | None = None
        self._sm_G: NDArray[np.float64] | None = None

    @property
    def smoother_wheel_rate_hz(self) -> float:
        """The rate [Hz] of the wheel speeds this estimator reads, CCVS1's, WBSD's and EBC2's 100 ms (and GBSD's
        ground speed): the fixed-lag smoother's lag holds two of their periods, as the hub estimator's holds two
        of its wheel speeds' (:meth:`.smoother.FixedLagSmoother.for_estimator`)."""
        return 1.0 / WHEEL_SPEED_WINDOW_S

    # ------------------------------------------------------------------ drivetrain terms
    def ratio(self) -> float:
        """Engine to rear wheel speed ratio i = i_g·i_f [-] in use: ETC2's gear ratio times the final drive,
        or the ratio learnt from engine speed over wheel speed; NaN while unknown."""
        if self.dt.gear_ratio == "bus":
            g = self._in["gear"]
            if math.isfinite(g) and g > 0.0:
                return g * self.dt.final_drive_ratio
            if not self.dt.final_drive_ratio >= 1.0:
                return self._ratio_learnt
            return self._ratio_learnt if not math.isfinite(self._in["gear"]) else math.nan
        return self._ratio_learnt

    def loads(self) -> tuple[float, float, float, float]:
        """(F_zf, F_zr [N], r_d front, r_d rear [m]): measured front-axle load, else the static share less
        the draft's load transfer F_dx h_hitch / L; the rear carries the rest of m g + F_dx tan β (the line of
        pull, ``pull_angle_deg``); F_dx the measured draft, or without a draft sensor the draft the
        resistance sum implies (:meth:`_draft_from_sum`); r_d per axle from eq. 9 (moved to the declared ``rolling_radius_m`` at the
        rear wheels' static load, when given), times the rear axle's self-calibrated scale
        (:mod:`.calibration`, once applied)."""
        key = (self._in["Fzf"], self._in["Fdx"] if self.draft else self._fdx_est, self._radius_version)
        if key == self._loads_key:
            return self._loads
        veh = self.vehicle
        fdx = key[1] if math.isfinite(key[1]) else 0.0
        fzf = key[0] if self.front_load and math.isfinite(key[0]) else math.nan
        if not math.isfinite(fzf):
            fzf = veh.static_front_fraction * self.W - fdx * veh.hitch_height_m / veh.wheelbase_m
            fzf = min(max(fzf, 0.05 * self.W), 0.95 * self.W)
        fzr = self.W + fdx * self._tan_pull - fzf
        rdf, rdr = rolling_radius(np.array([0.5 * fzf, 0.5 * fzr]), veh).tolist()
        if self._r_cal > 0.0:                  # the calibrated radius, with eq. 9's change from its static load
            shift = self._r_cal - self._rdr_static
            rdf, rdr = rdf + shift, rdr + shift
        k = self._radius.applied[1]
        self._loads_key, self._loads = key, (fzf, fzr, rdf * k, rdr * k)
        self._terms_key = None
        return self._loads

    def _terms(self, i_tot: float) -> tuple[float, float, float, float, float]:
        """(A_w [N·m per unit μ], F_zd [N], c_free [N], J_eq [kg·m²], k front/rear angular speed [-])."""
        fzf, fzr, rdf, rdr = self.loads()
        if self._terms_key == i_tot:
            return self._terms_val
        self._terms_key = i_tot
        self._terms_val = self._terms_of(i_tot, fzf, fzr, rdf, rdr)
        return self._terms_val

    def _terms_of(self, i_tot: float, fzf: float, fzr: float, rdf: float, rdr: float
                  ) -> tuple[float, float, float, float, float]:
        jw = self.vehicle.wheel_inertia_kgm2
        if self.engaged:
            k = 1.0 + self.lead                # the gears fix the angular ratio (module doc)
            a_w = rdr * fzr + k * rdf * fzf
            return a_w, fzf + fzr, 0.0, self.dt.engine_inertia_kgm2 * i_tot * i_tot + 2.0 * jw * (1.0 + k * k), k
        # front rolling: F_h,f = −ρ_t F_zf, so the rear carries μ ΣF_z + ρ_t F_zf and the same machine μ balances
        return rdr * (fzf + fzr), fzf + fzr, 0.0, self.dt.engine_inertia_kgm2 * i_tot * i_tot + 2.0 * jw, math.nan

    # ------------------------------------------------------------------ process model
    def fx(self, sig: NDArray[np.float64], u: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
        """One step of dt [s] for all sigma points (module doc); u = (M, A_w, F_zd, c_free, F_dx, J_eq)."""
        return _machine_step(np.ascontiguousarray(sig), u, self._consts, float(dt))

    def _Q(self, dt: float, u: NDArray[np.float64], t_te: float) -> NDArray[np.float64]:
        key = (dt, self._i_last, self._in["Tref"], t_te, self._rates.period("Fdx"), float(u[5]), self._adapt_version)
        Q = self._Q_cache.get(key)
        if Q is None:
            if len(self._Q_cache) >= 8:
                self._Q_cache.clear()
            Q = self._Q_cache[key] = self._build_Q(dt, u, t_te)
        return Q

    def _build_Q(self, dt: float, u: NDArray[np.float64], t_te: float) -> NDArray[np.float64]:
        q = self._q_tune * (self._f * dt) * self._A
        Q = np.diag(q)
        if self.cfg.input_noise:
            J = float(u[5])
            ms = self.ms
            per_pct = self._in["Tref"] / 100.0 * self._i_last * self.dt.efficiency     # N·m at the wheels per %
            s_m = per_pct * math.hypot(ms.torque_sigma_pct, ms.torque_quant_pct / math.sqrt(12.0))
            Q[IX_W, IX_W] += (s_m / J) ** 2 * t_te * dt
            if self.draft:
                Q[IX_V, IX_V] += self._fd_var * self._rates.period("Fdx") * dt / (self.m * self.m)
        return Q

    def _pct_net(self) -> float:
        return self._in["Te"] - self.dt.engine_friction_percent

    def _torque(self, i_tot: float) -> float:
        """Wheel torque M [N·m] of the held inputs (module doc), NaN while an input is unknown."""
        return self._dir * self._pct_net() / 100.0 * self._in["Tref"] * i_tot * self.dt.efficiency

    def _speed(self, x: Any) -> float | None:
        """A speed sample [rad/s or m/s], None when there is none: NaN (J1939 "not available" / "error") is
        counted as ``not_available``, a negative or infinite value as ``rejected_measurements``."""
        if x is None:
            return None
        x = float(x)
        if math.isnan(x):
            self.counters["not_available"] += 1
            return None
        if not (math.isfinite(x) and x >= 0.0):
            self.counters["rejected_measurements"] += 1
            return None
        return x

    # ------------------------------------------------------------------ step
    def step(self, t: float, inputs: Mapping[str, Any] | None = None,
             measurements: Mapping[str, Any] | None = None) -> MachineEstimate:
        """Advance to time t [s] with new inputs and measurements (any subset; see module doc).

        A step that brings no new sample, while no stream can have timed out since the last data
        (:attr:`hold_s`), changes nothing the data support: it returns the last estimate at the new time
        and the filter predicts across it at the next step with data (the right-hand side is constant
        meanwhile, so the prediction of the mean is the same).
        """
        t = float(t)
        if not math.isfinite(t):            # as Estimator.step: refused, the state untouched
            self.counters["steps"] += 1
            self.counters["rejected_times"] += 1
            return self._estimate(self.t if self.t is not None else math.nan, INPUT_REJECTED | NOT_CONVERGED,
                                  None, math.nan)
        if self.t is not None and t < self.t:
            kept = self.counters           # the caller's clock stepped back: start again from the next data
            self.reset()
            self.counters = kept
            kept["time_backwards"] += 1
        last = self._last
        if not inputs and not measurements and last is not None and t < self._hold_until and t > last.t:
            self.counters["steps"] += 1
            self.counters["held_steps"] += 1
            e = copy.copy(last)
            e.t, e.nis, e.nis_dof = t, math.nan, 0
            if self._sm_raw is not None and self._sm_xf is not None:
                # the same state at a later time: to the smoother a step whose prediction is the identity (the
                # smoother may have revised ``last`` already: the held copy carries the values as made)
                e.mu, e.rho_s = self._sm_raw
                e.transition = (True, self._sm_xf, self._sm_xf, _EYE, SMOOTH_INDEX)
            return e
        cfg = self.cfg
        self._last = None
        self._sm_xp = None
        status = MACHINE_LEVEL | (0 if self.draft else DRAFT_NOT_SEPARATED)
        predict_only = False
        counters = self.counters
        counters["steps"] += 1
        rates = self._rates
        # ---- inputs (zero-order hold, rejection)
        if inputs:
            for key in _INPUT_KEYS:
                val = inputs.get(key, _ABSENT)
                if val is _ABSENT or (key == "Fdx" and not self.draft):
                    continue                           # no sample, or a draft this estimator does not use
                fv = math.nan if val is None else float(val)
                if math.isnan(fv):
                    # J1939 "not available" / "error" (decoded as NaN): no sample, never a number; the held
                    # value ages out by its stream's time-out
                    counters["not_available"] += 1
                    continue
                ok = math.isfinite(fv)
                if key == "Te":
                    ok = ok and -125.0 <= fv <= 125.0
                elif key in ("Tref", "gear"):
                    ok = ok and fv > 0.0
                elif key == "Fzf":
                    ok = ok and 0.0 < fv < self.W
                if ok:
                    self._in[key] = fv
                    self._t_in[key] = t
                    if key in rates.trackers and rates.trackers[key].push(t):
                        rates.refresh(key)
                elif key == "gear" and fv == 0.0:
                    self._in["gear"] = math.nan        # neutral: no drive through the gearbox
                    self._t_in["gear"] = t
                else:
                    status |= INPUT_REJECTED
        if inputs and "gear" in inputs:
            g = self._in["gear"]
            if (g != self._gear_seen[0] and not (math.isnan(g) and math.isnan(self._gear_seen[0]))
                    and (not self._cvt or math.isnan(g) or math.isnan(self._gear_seen[0]))):
                self._t_shift = t          # a gearbox's ratio change (or neutral): a shift; a CVT's is not
            self._gear_seen = (g, self._gear_seen[1])
        if status & INPUT_REJECTED:
            counters["rejected_inputs"] += 1
            predict_only = True
        timeout = rates.timeout_s
        if t - self._t_in["Te"] > timeout["Te"] or not math.isfinite(self._in["Tref"]):
            status |= TORQUE_TIMEOUT
            predict_only = True
        if self.dt.gear_ratio == "bus" and t - self._t_in["gear"] > timeout["gear"] and not math.isfinite(
                self._ratio_learnt):
            status |= TORQUE_TIMEOUT
            predict_only = True
        if self.front_load and t - self._t_in["Fzf"] > timeout["Fzf"]:
            status |= AXLE_TIMEOUT
        if self.draft and t - self._t_in["Fdx"] > timeout["Fdx"]:
            status |= DRAFT_TIMEOUT
            predict_only = True
        # ---- measurements
        meas = measurements or {}
        d = meas.get("dir")
        if d is not None and (d == 0 or d == 1):               # WBSD SPN 1864: 0 reverse, 1 forward
            self._dir = 1.0 if d == 1 else -1.0
            self._t_dir_bus = t
        cg = meas.get("cgear")
        if cg is not None and math.isfinite(cg):
            if cg != self._gear_seen[1] and math.isfinite(self._gear_seen[1]):
                self._t_shift = t                              # ETC2 current gear changed
            self._gear_seen = (self._gear_seen[0], float(cg))
        if cg is not None and math.isfinite(cg) and cg != 0 and t - self._t_dir_bus > cfg.gps_timeout_s:
            self._dir = 1.0 if cg > 0 else -1.0                # ETC2 current gear: negative in reverse
        vwb = None
        for key in ("vwb", "vwbsd"):
            x = self._speed(meas.get(key))
            if x is not None:
                vwb = x
        we = self._speed(meas.get("we"))
        vfa = meas.get("vfa") if self._ebc2 else None
        if vfa is not None and not (math.isfinite(vfa) and vfa >= 0.0):
            vfa = None
        wq = self._we_window
        if we is not None:
            wq.append((t, we))
        # the wheel-based speed (CCVS1: tooth periods over its 100 ms) beside the engine speed over the same
        # window: the mean of the EEC1 samples of the last WHEEL_SPEED_WINDOW_S, the latest at most PAIR_S
        # old (EEC1 and CCVS1 are not sent in phase; one engine sample against the wheels' 100 ms mean would
        # compare across the driveline's torsional oscillation)
        while wq and t - wq[0][0] > WHEEL_SPEED_WINDOW_S:
            wq.popleft()
        we_pair = (sum(x for _, x in wq) / len(wq) if vwb is not None and wq and t - wq[-1][0] <= PAIR_S
                   else None)
        if vwb is not None:
            self._vwb = vwb
            if we_pair is not None:
                self._learn_ratio(we_pair, vwb)
        i_tot = self.ratio()
        fzf, fzr, rdf, rdr = self.loads()
        val = self.validity
        if we_pair is not None and vwb > 0.5 and i_tot > 0.0:
            if abs(we_pair * self.r_ws / (vwb * i_tot) - 1.0) > val.ratio_tolerance:
                self._t_shift = t                              # engine and wheels not at the reported ratio
        z_w = r_w = None
        bus_ratio = self.dt.gear_ratio == "bus" and math.isfinite(self._in["gear"])
        learnt = not bus_ratio and i_tot == self._ratio_learnt and self._ratio_jump == 0
        engine_drive = (bus_ratio or learnt) and i_tot > 0     # the engine speed is the drive speed
        from_engine = we is not None and engine_drive
        if from_engine:
            # the engine speed over the ratio: the drive speed at EEC1's rate; over a learnt ratio with the
            # learnt ratio's own error beside the engine speed's (:meth:`_learn_ratio`)
            s_e = self.ms.engine_speed_sigma_rel * we + self.ms.engine_speed_quant / math.sqrt(12.0)
            z_w, r_w = self._dir * we / i_tot, (s_e / i_tot) ** 2
            if learnt:
                r_w += (we / i_tot * self.ms.wheel_speed_sigma_rel) ** 2 * RATIO_GAIN / (2.0 - RATIO_GAIN)
        elif vwb is not None:
            s_w = self.ms.wheel_speed_sigma_abs + self.ms.wheel_speed_sigma_rel * vwb
            z_w, r_w = self._dir * vwb / self.r_ws, (s_w * s_w + self.ms.wheel_speed_quant ** 2 / 12.0) / self.r_ws ** 2
        elif vfa is not None and self.engaged:
            s_w = self.ms.wheel_speed_sigma_abs + self.ms.wheel_speed_sigma_rel * vfa
            den = (1.0 + self.lead) * self.r_ws            # EBC2's axle speed: ω_f over the ECU's radius
            z_w, r_w = self._dir * vfa / den, (s_w * s_w + self.ms.wheel_speed_quant ** 2 / 12.0) / den ** 2
        if z_w is not None:
            self._t_omega = t
            # One source sets the drive speed's period: the engine speed where it is the drive speed, else the
            # wheel-based or axle speed.  Pushed together, EEC1 and CCVS1/WBSD samples one step apart read as a
            # 10 ms stream, whose timeout then tripped between two 10 Hz samples (EEC1 at 10 Hz: 12 % valid).
            if from_engine == engine_drive and rates.trackers["omega"].push(t):
                rates.refresh("omega")
        rel = meas.get("rel_r")                                # EBC2 rear wheels relative to the front axle
        if rel is not None and vfa is not None and vfa > 0.5:
            rl = np.asarray(rel, dtype=float)
            if rl.shape == (2,) and np.isfinite(rl).all():
                self._turning = abs(float(rl[0] - rl[1])) > self._radius.cfg.max_turn_rel * vfa
                v_rear = vfa + 0.5 * float(rl[0] + rl[1])
                if v_rear > 0.5:
                    lk = self.vehicle.wheelbase_m * abs(float(rl[0] - rl[1])) / (self.vehicle.track_width_m * v_rear)
                    if math.sqrt(1.0 + lk * lk) - 1.0 > val.max_front_path_excess:
                        self._t_turn = t
                    if self._auto and self._lead_d > 0.0:
                        self._mfwd_from_bus(t, vfa / v_rear, rdf, rdr)
                    if self.engaged and self.lead > 0.0:       # front axle over rear wheels, against the coupling
                        q = vfa / v_rear / (1.0 + self.lead) - 1.0
                        a = 1.0 if t - self._t_coupling > 5.0 * max(val.coupling_tau_s, 0.1) else min(
                            1.0, (t - self._t_coupling) / max(val.coupling_tau_s, 1e-3))
                        self._coupling = q if not math.isfinite(self._coupling) else self._coupling + a * (
                            q - self._coupling)
                        if self.engaged:               # the engaged axle's ratio is learnt while engaged
                            b = min(1.0, (t - self._t_coupling) / val.coupling_ref_tau_s) if math.isfinite(
                                self._t_coupling) else 0.0
                            self._coupling_ref = (self._coupling if not math.isfinite(self._coupling_ref) else
                                                  self._coupling_ref + b * (self._coupling - self._coupling_ref))
                        self._t_coupling = t
        crs = meas.get("course")                               # GNSS course: a turn bends it
        if crs is not None and math.isfinite(crs):
            self._course_turn(t, math.radians(float(crs)), val)
        zv: list[tuple[int, float, float]] = []
        vm = meas.get("v")
        if vm is not None:
            v_g = abs(float(vm)) * self._dir
            if math.isfinite(v_g):
                zv.append((_OUT_V, v_g, self._r_v))
            else:
                counters["rejected_measurements"] += 1
        vr = meas.get("vr")
        if vr is not None:
            if math.isfinite(vr) and vr >= 0.0:
                s_r = self.ms.radar_sigma_abs + self.ms.radar_sigma_rel * vr
                zv.append((_OUT_VR, self._dir * float(vr), s_r * s_r))
            else:
                counters["rejected_measurements"] += 1
        if zv:
            self._t_v = t
            self._last_v = zv[0][1]
            if rates.trackers["v"].push(t):
                rates.refresh("v")
        if t - self._t_omega > timeout["omega"]:
            status |= WHEEL_TIMEOUT
        if t - self._t_v > timeout["v"]:
            status |= GPS_TIMEOUT
        # the next time a stream could time out: steps without data before it are held (see above)
        t_in = self._t_in
        self._hold_until = min(t + self._hold_s, t_in["Te"] + timeout["Te"], self._t_omega + timeout["omega"],
                               self._t_v + timeout["v"], t_in["gear"] + timeout["gear"],
                               t_in["Fdx"] + timeout["Fdx"] if self.draft else math.inf,
                               t_in["Fzf"] + timeout["Fzf"] if self.front_load else math.inf)
        M = self._torque(i_tot)
        if (t - self._t_shift < val.shift_hold_s or t - self._t_turn < val.turn_hold_s
                or self._pct_net() < val.min_net_torque_pct
                or (self.engaged and math.isfinite(self._coupling) and t - self._t_coupling < 1.0
                    and abs(self._coupling - self._coupling_ref) > val.coupling_tolerance * self.lead)):
            status |= MACHINE_UNSUPPORTED
            counters["unsupported_steps"] += 1
        # ---- initialisation
        ukf = self.ukf
        if ukf is None:
            if z_w is not None and math.isfinite(M) and not predict_only:
                self._init_filter(t, z_w, r_w, M, i_tot)
                self.t = t
            return self._estimate(t, status | NOT_CONVERGED, None, i_tot)
        # ---- predict
        dt_s = t - self.t if self.t is not None else 0.0
        if dt_s > cfg.max_gap_s:
            counters["gap_resets"] += 1
            self.ukf = None
            self.t = t
            return self._estimate(t, status | NOT_CONVERGED, None, i_tot)
        if not math.isfinite(M):
            M, i_tot = self._u_last[0], self._i_last
        a_w, fzd, c_free, J, _ = self._terms(i_tot)
        fdx = self._in["Fdx"] if self.draft and math.isfinite(self._in["Fdx"]) else 0.0
        u = np.array([M, a_w, fzd, c_free, fdx, J])
        self._u_last, self._i_last = u, i_tot
        if dt_s > 0.0:
            n_sub = max(1, int(math.ceil(dt_s / cfg.max_step_s - 1e-9)))
            h = dt_s / n_sub
            Q = self._Q(h, u, rates.period("Te"))
            xf = self._sm_xf
            link = self._smooth and xf is not None and ukf.x.tobytes() == xf.tobytes()
            try:
                G = ukf.predict_steps(u, h, n_sub, lambda _h: Q)
                link = link and G is not None
            except EstimatorError:
                counters["resets"] += 1
                self.ukf = None
                return self._estimate(t, status | COV_REPAIRED | NOT_CONVERGED, None, i_tot)
            if ukf.repaired_last:
                status |= COV_REPAIRED
            self.t = t
            if link:
                self._sm_xp, self._sm_G = ukf.x.copy(), G
        # ---- update
        updated = False
        if not predict_only and (z_w is not None or zv):
            idx = ([_OUT_W] if z_w is not None else []) + [k for k, _, _ in zv]
            z = ([z_w] if z_w is not None else []) + [x for _, x, _ in zv]
            R = ([r_w] if z_w is not None else []) + [r for _, _, r in zv]
            sl = _SLICES.get((idx[0], idx[-1])) if idx[-1] - idx[0] == len(idx) - 1 else None
            ukf.update(np.array(z), sl if sl is not None else np.array(idx, dtype=np.intp), np.array(R))
            if ukf.last_gated:
                status |= MEAS_GATED
                counters["gated"] += bin(ukf.last_gated).count("1")
            if ukf.last_dof:
                updated = True
                counters["updates"] += 1
                if cfg.adaptation:
                    self._cm.push(*ukf.correction())
        x = ukf.x
        if vm is not None and self._radius.cfg.enabled and zv and zv[0][0] == _OUT_V:
            self._calibrate(t, zv[0][1], x)
        # ---- adaptation and supervisor (paper eqs. 16-17, FLS)
        self._dyn.update(t, float(x[IX_V]), M)
        if t - self._t_adapt >= cfg.adapt_period_s:
            self._t_adapt = t
            if not self.draft:
                self._draft_from_sum(float(x[IX_RHO]), float(x[IX_V]))
            if cfg.adaptation:
                self._A = self._cm.compute()
            if cfg.supervisor:
                self._f = self._fuzzy.factor(abs(self._dyn.accel), abs(self._dyn.torque_rate))
            self._adapt_mu = self._f * float(self._A[IX_MU])
            self._adapt_version += 1
        counters["chol_repairs"] = ukf.chol_repairs
        return self._estimate(t, status, x, i_tot, updated)

    def _calibrate(self, t: float, v_gnss: float, x: NDArray[np.float64]) -> None:
        """One GNSS epoch to the rolling-radius self-calibration (:class:`~.calibration.RadiusCalibration`,
        the hub estimator's): the rear wheels at the drive speed, the front at the kinematic ratio; samples
        while turning (EBC2 left/right wheels, or the GNSS course) are refused.  Its rear scale, once applied,
        scales both axles' radii (the front axle's speed is not measured apart from the lead)."""
        w, v, mu = float(x[IX_W]), float(x[IX_V]), float(x[IX_MU])
        fzf, fzr, rdf, rdr = self.loads()
        k0 = self._radius.applied[1]
        rdf0, rdr0 = rdf / k0, rdr / k0
        kf = 1.0 + self.lead if self.engaged else 1.0
        ok = self._conv and abs(v) >= self.cfg.standstill_speed_mps and not (self._turning or self._turning_gnss)
        cs = self._curve_state
        self._radius.push(t, v_gnss, [kf * w, kf * w, w, w], rdf0, rdr0, [mu] * 4, self._dyn.accel, ok,
                          cs.a, cs.class_name)
        if self._radius.applied[1] != k0:
            self._radius_version += 1
            self._terms_key = None

    def _mfwd_from_bus(self, t: float, ratio: float, rdf: float, rdr: float) -> None:
        """``front_drive = "auto"``: the MFWD state from EBC2.  ``ratio``: its front-axle over rear-wheel speed,
        both from wheel angular speeds over the ECU's one radius, so the front over rear angular speed [-].
        Engaged, the gears fix it at 1 + λ whatever the loads (λ the lead; learnt, smoothed over
        ``coupling_tau_s``, while engaged outside turns and shifts, with time constant ``coupling_ref_tau_s``,
        from the declared lead at the first sample); disengaged, the front axle rolls at the ground speed and the
        ratio falls by about λ + s_r ≥ λ (s_r the rear slip).  Disengaged below −``coupling_tolerance``·λ of the
        learnt ratio, engaged again above half of it; either change is held unsupported like a shift (the
        model's torque balance changes: module doc)."""
        val = self.validity
        a = 1.0 if t - self._t_wr > 5.0 * max(val.coupling_tau_s, 0.1) else min(
            1.0, (t - self._t_wr) / max(val.coupling_tau_s, 1e-3))
        self._wr = ratio if not math.isfinite(self._wr) else self._wr + a * (ratio - self._wr)
        if not math.isfinite(self._wr_ref):
            self._wr_ref = 1.0 + self._lead_d
        elif self.engaged and t - self._t_turn > val.turn_hold_s and t - self._t_shift > val.shift_hold_s:
            self._wr_ref += min(1.0, (t - self._t_wr) / val.coupling_ref_tau_s) * (self._wr - self._wr_ref)
        self._t_wr = t
        dq = self._wr / self._wr_ref - 1.0
        tol = val.coupling_tolerance * self._lead_d
        if self.engaged and dq < -tol:
            self.engaged, self.lead = False, 0.0
        elif not self.engaged and dq > -0.5 * tol:
            self.engaged, self.lead = True, self._lead_d
        else:
            return
        self._terms_key = None
        self._t_shift = t
        self.counters["mfwd_changes"] += 1

    def _draft_from_sum(self, rho_sum: float, v: float) -> None:
        """Without a draft sensor: the draft the converged resistance sum implies, F_dx ≈ (ρ_Σ − ρ_s,typ) m g
        (≥ 0), ρ_s,typ the identified soil class's typical ρ_s (:class:`~tractionecu.model.mucurve.SoilClass`),
        for the wheel loads only (:meth:`loads`: the line of pull's F_dx tan β and the load transfer).
        Taking F_dx = 0 there put ΣF_z low by F_dx tan β (4-5 % of m g for 20 kN at 9°) and μ as much high.
        ρ_s itself stays unreported: ρ_s,typ is a class's typical value, its spread
        (:data:`RHO_S_PRIOR_SIGMA`) is in μ's variance."""
        if not (self._conv and abs(v) >= self.cfg.standstill_speed_mps):
            return
        cs = self._curve_state
        cls = self._curve.classes
        rho_typ = cls[cs.class_index if 0 <= cs.class_index < len(cls) else 0].rho_s_typical
        self._fdx_est = round(max(0.0, (rho_sum - rho_typ) * self.W), -1)      # 10 N: the loads' cache key

    def _learn_ratio(self, we: float, vwb: float) -> None:
        """Engine speed over wheel speed [-], smoothed (gain :data:`RATIO_GAIN` per wheel-based speed sample: the
        learnt ratio's relative variance is the sample's times α/(2 − α)); a change of more than 5 % held for
        three samples is a gear change and is taken at once."""
        if vwb < 0.3:                       # below 1 km/h the ratio of two quantised speeds means little
            return
        raw = we * self.r_ws / vwb
        cur = self._ratio_learnt
        if not math.isfinite(cur):
            self._ratio_learnt = raw
            return
        if abs(raw / cur - 1.0) > 0.05:
            self._ratio_jump += 1
            if self._ratio_jump >= 3:
                self._ratio_learnt = raw
                self._ratio_jump = 0
                self.counters["gear_changes"] += 1
            return
        self._ratio_jump = 0
        self._ratio_learnt = cur + RATIO_GAIN * (raw - cur)

    def _init_filter(self, t: float, w0: float, r_w: float, M: float, i_tot: float) -> None:
        cfg = self.cfg
        a_w, fzd, c_free, J, _ = self._terms(i_tot)
        mu0 = float(np.clip(M / a_w - self.vehicle.rho_t * np.sign(w0), cfg.mu_min, cfg.mu_max))   # ω̇ = 0
        if self._last_v is not None and t - self._t_v <= cfg.gps_timeout_s:
            v0 = self._last_v
        else:
            _, _, _, rdr = self.loads()
            v0 = rdr * w0 * (1.0 - 0.05)
        fdx = self._in["Fdx"] if self.draft and math.isfinite(self._in["Fdx"]) else 0.0
        rho0 = float(np.clip((mu0 * fzd - c_free - fdx) / self.W, self._lo[IX_RHO], self._hi[IX_RHO]))   # v̇ = 0
        x0 = np.array([w0, v0, mu0, rho0])
        sd = np.array([math.sqrt(r_w), cfg.sigma_v0, cfg.sigma_mu0, cfg.sigma_rho0])
        self.ukf = UnscentedFilter(self.fx, x0, np.diag(sd * sd), (IX_W, IX_V, IX_V), alpha=cfg.alpha,
                                   beta=cfg.beta, kappa=cfg.kappa, x_lo=self._lo, x_hi=self._hi,
                                   gate_chi2=self._gate, gate_max_consecutive=cfg.gate_max_consecutive)
        self.ukf.track_gain = self._smooth
        self._u_last = np.array([M, a_w, fzd, c_free, fdx, J])
        self._i_last = i_tot
        self.t_init = t
        self._conv = False

    # ------------------------------------------------------------------ output
    def _with_prior(self, cs: CurveState) -> CurveState:
        """The curve state, carrying the prior's shape when a ``curve_prior`` is set (:mod:`.machine_curve`)."""
        return cs if self._prior is None else MachineCurveState.of(cs, self._prior)

    def _effective_slip(self, s_f: float, s_r: float, fzf: float, fzr: float) -> float:
        """s_e with g(s_e) = Σ w_a g(s_a) (module doc), the first configured class's g."""
        if not self.engaged:
            return s_r
        if not (math.isfinite(s_f) and math.isfinite(s_r)):
            return math.nan
        sign = 1.0 if s_r >= 0 else -1.0
        g = self._cls0.g(np.array([abs(s_f), abs(s_r)]))
        ge = (fzf * float(g[0]) + fzr * float(g[1])) / (fzf + fzr)
        gs, sg = self._g_table
        return sign * float(np.interp(ge, gs, sg))

    def _converged(self, t: float, pmu: float, prho: float, mu: float) -> bool:
        """Whether the filter's μ and ρ are converged (status ``not_converged`` otherwise), with the
        filter's own variances P_μ, P_ρ.

        Entry: both standard deviations below the configured bounds c_μ = ``conv_sigma_mu``, c_ρ =
        ``conv_sigma_rho``, no earlier than ``conv_min_s`` after the filter started.  Once converged, the
        estimate stays so while P_μ ≤ c_μ² + (σ_η/η·μ)² and P_ρ ≤ c_ρ² + (σ_η/η·μ)²: the declared
        drivetrain efficiency leaves σ_η/η·μ of μ (and as much of ρ, eq. 8) unknown whatever the data
        say (``efficiency_tolerance``; the reported variance carries it), so the filter's random part
        moving inside the total it was accepted with does not change what the estimate is good for, while
        one beyond it (a soil change, a restart) has lost what it had and re-enters below c.  A single
        bound made the status flicker as the adapted process noise moved P_μ across it.  The hub
        estimator's hysteresis (``conv_exit_factor`` × the bounds, for the growth of P between slow
        wheel-speed samples) is the same setting here: the wider of the two bounds applies (at a working
        μ of 0.35-0.4 and σ_η/η = 0.03 they are 1.4-1.6 and 1.5 times c)."""
        cfg = self.cfg
        c_mu, c_rho = cfg.conv_sigma_mu ** 2, cfg.conv_sigma_rho ** 2
        if self._conv:
            sys_var = (self.dt.efficiency_tolerance * mu) ** 2
            f2 = getattr(cfg, "conv_exit_factor", 1.0) ** 2
            c_mu, c_rho = max(c_mu + sys_var, f2 * c_mu), max(c_rho + sys_var, f2 * c_rho)
        self._conv = (self.t_init is not None and t - self.t_init >= cfg.conv_min_s and pmu <= c_mu
                      and prho <= c_rho)
        return self._conv

    def _estimate(self, t: float, status: int, x: NDArray[np.float64] | None, i_tot: float,
                  updated: bool = False) -> MachineEstimate:
        cfg = self.cfg
        ukf = self.ukf
        cs = self._curve_state
        if x is None or ukf is None:
            self._conv = False
            self._sm_xf = self._sm_raw = None
            nan4 = np.full(4, np.nan)
            return MachineEstimate(t, nan4, math.nan, math.nan, cs.class_name, nan4.copy(), math.nan, nan4.copy(),
                                   np.full(10, np.nan), math.nan, self._f, status | NOT_CONVERGED, False, 0,
                                   cs.class_index, radius_scale=_NAN2, radius_halfwidth=_NAN2,
                                   radius_applied=_ONE2, curve_state=cs, level=self.level, total_ratio=i_tot,
                                   front_engaged=self.engaged)
        w, v, mu, rho = x.tolist()
        P = ukf.P
        pw, pv, pmu, prho = P[0, 0], P[1, 1], P[2, 2], P[3, 3]
        fzf, fzr, rdf, rdr = self.loads()
        k = 1.0 + self.lead if self.engaged else math.nan
        s_r = _slip1(w, v, rdr)
        if self.engaged:
            w_f = k * w
            s_f = _slip1(w_f, v, rdf)
        else:                                  # a rolling front axle: its speed is not modelled
            w_f, s_f = math.nan, math.nan
        s = [s_f, s_f, s_r, s_r]
        # curve parameter a from the machine-level pair; not while the engine torque or the wheel speed is
        # missing: μ is then the held prediction beside a slip that moves on (10 s of EEC1 "not available" left
        # an exp1 curve at its α1 bound with a below the μ it was fed, for the rest of the run)
        if (t - self._t_curve >= cfg.curve_period_s and abs(v) >= cfg.curve_min_speed_mps
                and not status & (MACHINE_UNSUPPORTED | TORQUE_TIMEOUT | WHEEL_TIMEOUT)):
            self._t_curve = t
            s_e = self._effective_slip(s_f, s_r, fzf, fzr)
            sig_s = math.sqrt(pv) / max(rdr * abs(w), 1e-3)
            mu_c = mu if self.engaged else (mu * (fzf + fzr) + self.vehicle.rho_t * fzf) / fzr   # rear axle's
            self._curve_state = cs = self._with_prior(self._curve.update(
                t, np.array([mu_c]), np.array([s_e]), np.array([math.sqrt(pmu)]), np.array([sig_s])))
        conv = self._converged(t, pmu, prho, mu)
        if not conv:
            status |= NOT_CONVERGED
        fdx = self._in["Fdx"] if self.draft and math.isfinite(self._in["Fdx"]) else math.nan
        if self.draft:
            rho_s, resistance = rho, rho + fdx / self.W
        else:
            rho_s, resistance = math.nan, rho
        if abs(v) < cfg.standstill_speed_mps:
            status |= STANDSTILL
            if self._held is not None:
                rho_s, s = self._held
        elif conv:
            self._held = (rho_s, s)
        var_mu = pmu + (self.dt.efficiency_tolerance * mu) ** 2
        if not self.draft:                     # the draft from the sum: ΣF_z uncertain by tan β σ_ρs m g
            var_mu += (mu * self._tan_pull * RHO_S_PRIOR_SIGMA * self.W / (fzf + fzr)) ** 2
        var_w_f = k * k * pw if self.engaged else math.nan
        pd = np.array([var_w_f, var_w_f, pw, pw, pv, var_mu, var_mu, var_mu, var_mu,
                       prho + (self.dt.efficiency_tolerance * mu) ** 2 if self.draft else math.nan])
        nis, dof = (ukf.last_nis, ukf.last_dof) if updated else (math.nan, 0)
        tr = None
        mu4 = np.full(4, mu)
        if self._smooth:
            xs = x.copy()
            link = self._sm_xp is not None
            tr = (link, xs, self._sm_xp if link else None, self._sm_G if link else None, SMOOTH_INDEX)
            self._sm_xf, self._sm_raw = xs, (mu4, rho_s)
        self._last = MachineEstimate(t, mu4, rho_s, cs.a, cs.class_name, np.array(s, dtype=float), v,
                               np.array([w_f, w_f, w, w]), pd, nis, self._adapt_mu, status,
                               (status & INVALID_MASK) == 0, dof, cs.class_index, radius_scale=_NAN2, radius_halfwidth=_NAN2,
                               radius_applied=np.full(2, self._radius.applied[1]), curve_state=cs, level=self.level,
                               resistance=resistance, total_ratio=i_tot, front_engaged=self.engaged,
                               transition=tr)
        return self._last


def _machine_step(sig, u, c, dt):                             # pragma: no cover - compiled
    """:meth:`MachineEstimator.fx` for every row of sig (N, 4): the exact step of the piecewise-constant
    right-hand side (module doc); u = (M, A_w, F_zd, c_free, F_dx, J_eq), c = (ρ_t, m g, m)."""
    M, a_w, fzd, c_free, fdx, J = u[0], u[1], u[2], u[3], u[4], u[5]
    rho_t, W, m = c[0], c[1], c[2]
    out = sig.copy()
    for p in range(sig.shape[0]):
        w, v, mu, rho = sig[p, 0], sig[p, 1], sig[p, 2], sig[p, 3]
        sw = 1.0 if w > 0.0 else (-1.0 if w < 0.0 else 0.0)
        sv = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
        out[p, 0] = w + dt * (M - (mu + rho_t * sw) * a_w) / J
        out[p, 1] = v + dt * (mu * fzd - c_free * sv - fdx - rho * W * sv) / m
    return out


_machine_step = compiled(_machine_step)
