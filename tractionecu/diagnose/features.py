"""Physical quantities diagnosis derives from a :class:`~tractionecu.diagnose.data.Frame`.

Everything is computed from recorded signals and the nominal vehicle file:

- wheel loads from the measured front-axle load (paper section 3.1):
  F_z,front = F_zf/2,  F_z,rear = (m g − F_zf)/2, and in a turn the lateral load
  transfer of the estimator's model (:func:`lateral_load_transfer`);
- the path curvature κ(t) of the rear-axle centre (:func:`path_curvature`) and each
  wheel's ground speed k_i(κ)·v, against which its slip is taken (model doc
  "Kinematics in turns"), and the wheels' force on v, Σ k_i F_h,i (virtual work,
  :attr:`WheelState.fx_sum`);
- rolling radius r_d(F_z) (paper eq. 9);
- the per-wheel horizontal force from the torque balance (paper eq. 2),
  F_h,i = (M_i − J ω̇_i)/r_i − ρ_t F_z,i sgn ω_i, and μ_i = F_h,i / F_z,i;
- the force-integrated speed v_int(t) = (1/m) ∫ (Σ F_h,i − F_dx) dt
  (paper eq. 8 without the unknown resistances);
- a fused ground speed v_ref = v_int + b(t), b a cubic B-spline (knots every
  :data:`SPLINE_KNOT_S`) fitted to the GNSS speed: GNSS accuracy at low
  frequency, the force balance's smoothness at high frequency;
- the grade along the track θ = atan(dh/ds) from the GNSS altitude, by a
  local-linear kernel surface h(x, y) pooled over all passes (Gaussian kernel
  of :data:`DEM_BANDWIDTH_M`), so that independent altitude errors of
  different passes average out;
- work segments (passes), pass direction, spatial cells on the field and
  held-out folds.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import BSpline
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree

from ..config import G
from ..model.vehicle import rolling_radius, wheel_loads, wheel_speed_factors
from .data import DIRECTION_MIN_RAD_S, Frame, mean_wheel_speed

SPLINE_KNOT_S = 3.0
"""Knot spacing of the low-frequency speed correction b(t) [s]."""
DEM_BANDWIDTH_M = 20.0
"""Gaussian kernel standard deviation of the pooled altitude surface [m]."""
CELL_M = 40.0
"""Edge of a spatial cell of the field, along and across the passes [m]."""
CELL_MIN_S = 10.0
"""Cells with less data than this [s] are merged into the nearest cell."""
FOLD_BLOCK_S = 40.0
"""Length of the alternating time blocks that form the two held-out folds [s]."""
MOVING_MPS = 0.5
"""Below this speed [m/s] samples are not used (slip and grade undefined)."""
BREAK_GAP_S = 5.0
"""A stretch this long [s] without any sample (CAN or GNSS) is a break in the recording: the logger
was off, and the machine may have been driven or stood anywhere meanwhile."""
BREAK_JUMP_M = 5.0
"""A GNSS position step longer [m] than the speed allows by this much is a break too (the recording
restarts elsewhere without a gap in time: a logger restart, joined files)."""
BREAK_MARGIN_S = 2.0
"""Samples this close to a break [s] are not used (filters and windows would reach across it)."""


@dataclass
class Features:
    """Derived arrays over the frame grid (n,) or (n, 4)."""

    frame: Frame
    valid: NDArray[np.bool_]
    """Moving, with the signals the force balance needs."""
    omega_dot: NDArray[np.float64] | None
    v_gps: NDArray[np.float64] | None
    v_ref: NDArray[np.float64] | None
    """Fused ground speed [m/s]."""
    accel: NDArray[np.float64] | None
    """dv_ref/dt [m/s²]."""
    theta: NDArray[np.float64] | None
    """Grade along the heading from the GNSS altitude [rad] (NaN where unknown)."""
    grade: "GradeEstimate | None"
    """How θ was obtained (calibration λ, method)."""
    segment: NDArray[np.int64]
    """Work segment index (−1 outside work)."""
    direction: NDArray[np.int64]
    """+1 / −1 along / against the field's main axis, 0 unknown."""
    cell: NDArray[np.int64]
    """Spatial cell index (0 when positions are unknown)."""
    n_cells: int
    fold: NDArray[np.int64]
    """Held-out fold (0 or 1) by alternating time blocks."""
    u: NDArray[np.float64] | None = None
    """Position along the field's main axis [m]."""
    w: NDArray[np.float64] | None = None
    """Position across the main axis [m]."""
    notes: list[str] = field(default_factory=list)
    sensor_faults: list[dict] = field(default_factory=list)
    """Wheel-speed holds and dropouts found and repaired (:func:`wheel_speed_faults`)."""
    v_int: NDArray[np.float64] | None = None
    """The nominal force integral v_int [m/s] that ``v_ref`` is fused from (:func:`fused_speed`); None without
    wheel speeds or GNSS speed."""

    @property
    def n(self) -> int:
        return self.frame.n


# --------------------------------------------------------------------------- turns
TURN_COURSE_M = 5.0
"""Distance travelled [m] over which the GNSS course's change gives the course curvature that confirms a
turn (:func:`path_curvature`)."""
TURN_MARGIN_S = 1.0
"""A confirmed turn is widened by this much on either side [s] (the course's window and a GNSS latency
lag the wheels)."""


def turn_threshold(track_m: float) -> float:
    """Smallest curvature [1/m] taken as a turn: a rear slip difference of
    ``BETA_MAX_SIGMAS × SLIP_DIFF_MAX`` (the estimator's bound of a slip difference,
    :mod:`tractionecu.estimation.kinematics`) over the track width reads as this curvature in the
    wheel-speed ratio, so below it the wheels cannot tell a turn from a slip difference."""
    from ..estimation.kinematics import BETA_MAX_SIGMAS, SLIP_DIFF_MAX

    return BETA_MAX_SIGMAS * SLIP_DIFF_MAX / track_m


def course_curvature(fr: Frame) -> NDArray[np.float64]:
    """|dψ/ds| [1/m] of the GNSS course over :data:`TURN_COURSE_M` of travel (NaN where the course or the
    speed is missing, or the machine stands: then nothing is travelled).

    The course changes by the same rate as the body's heading forwards and in reverse (it is turned by
    180°), so its rate over the distance is |κ| either way; the sign is not used.  Differentiating over a
    distance rather than a time keeps the course noise (σ_χ ≈ σ_v/|v| per epoch) from growing at low
    speed: 0.03 rad over 5 m is 0.006 1/m."""
    out = np.full(fr.n, np.nan)
    if fr.heading is None or fr.v_gps is None:
        return out
    ok = np.isfinite(fr.heading) & np.isfinite(fr.v_gps)
    if ok.sum() < 3:
        return out
    idx = np.flatnonzero(ok)
    speed = np.abs(fr.v_gps[idx])
    s = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(fr.t[idx]))])
    psi = np.unwrap(fr.heading[idx])
    half = 0.5 * TURN_COURSE_M
    lo = np.interp(s - half, s, psi)
    hi = np.interp(s + half, s, psi)
    span = np.clip(s + half, s[0], s[-1]) - np.clip(s - half, s[0], s[-1])
    with np.errstate(divide="ignore", invalid="ignore"):
        k = np.where(span >= 0.5 * TURN_COURSE_M, np.abs(hi - lo) / span, np.nan)
    k[speed <= MOVING_MPS] = np.nan
    out[idx] = k
    return out


def path_curvature(fr: Frame) -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_]]:
    """Path curvature κ(t) of the rear-axle centre [1/m] (positive in a left turn, κ = ψ̇/v for either sign of
    v: model doc "Kinematics in turns"), whether it is known, and where it is a turn.

    Returns (κ, known, turn); κ = 0 where not a turn or not known.

    Choice of source.  The value is the rear wheels' speed ratio, κ_w = (2/b)(ω_RR − ω_RL)/(ω_RR + ω_RL)
    (b the track width), which holds for either sign of travel; the GNSS course only decides *where* the
    machine turns.  Why:

    - the slip of each wheel is taken against its own ground speed k_i(κ)·v, and the rear wheels measure
      those ground speeds directly (the estimator's curvature is the wheels' too, corrected by the course
      only within a plausible slip difference, :mod:`tractionecu.estimation.kinematics`);
    - precision: on the physical truth's 3-m headland turns (κ = 0.335 1/m) κ_w of the 10-Hz bin means is
      off by 0.004 1/m RMS, a course differentiated between epochs by 0.06;
    - the wheel ratio also reads a rear slip (or radius) difference Δs as curvature, κ_w ≈ κ + Δs/b, and
      on a straight pass that bias would make the two rear slips equal.  So κ is used only where the
      course confirms a turn: its curvature over :data:`TURN_COURSE_M` of travel
      (:func:`course_curvature`) at least :func:`turn_threshold` (a rear slip difference of 0.03), widened
      by :data:`TURN_MARGIN_S`.  Where the course is missing (no GNSS, standstill) the wheels decide with
      the same threshold;
    - a truth whose wheels do not follow the path (the paper's straight-line model driven round a
      headland: its wheels all roll at v while the course turns) keeps κ_w ≈ 0 there, as the recording
      has it, instead of the course's turn.

    At standstill (rear wheels' mean speed below :data:`MOVING_MPS` on the nominal radius) or without rear
    wheel speeds κ is undefined: 0, and ``known`` is False.
    """
    n = fr.n
    kappa = np.zeros(n)
    known = np.zeros(n, dtype=bool)
    turn = np.zeros(n, dtype=bool)
    if fr.omega is None:
        return kappa, known, turn
    veh = fr.vehicle
    b = veh.track_width_m
    wl, wr = fr.omega[:, 2], fr.omega[:, 3]
    tot = wl + wr
    known = np.isfinite(wl) & np.isfinite(wr) & (0.5 * np.abs(tot) * veh.r0_m > MOVING_MPS)
    with np.errstate(divide="ignore", invalid="ignore"):
        kw = np.where(known, (2.0 / b) * (wr - wl) / np.where(known, tot, 1.0), 0.0)
    k_min = turn_threshold(b)
    kc = course_curvature(fr)
    have_course = np.isfinite(kc)
    turn = np.where(have_course, np.nan_to_num(kc) >= k_min, np.abs(kw) >= k_min)
    m = int(math.ceil(TURN_MARGIN_S * fr.rate_hz))
    if m > 0 and turn.any():
        from scipy.ndimage import binary_dilation

        turn = binary_dilation(turn, structure=np.ones(2 * m + 1, dtype=bool))
    turn &= known
    if turn.any() and fr.fzf is not None:
        kw = _radius_corrected(fr, kw, turn)
    kappa[turn] = kw[turn]
    return kappa, known, turn


def _radius_corrected(fr: Frame, kw: NDArray[np.float64], turn: NDArray[np.bool_]) -> NDArray[np.float64]:
    """κ_w from the rear wheels' circumferential speeds r_i ω_i rather than their angular speeds: in a turn
    the outer wheel carries more load, rolls on a smaller radius (eq. 9) and turns faster, which the plain
    ratio reads as 2–3 % more curvature at a_y ≈ 0.8 m/s².  The radii follow the loads, which follow κ, so
    the ratio is iterated (a contraction of a few per cent: converged to 1e-10 within 6 steps); rows
    without a load keep the plain ratio."""
    veh = fr.vehicle
    b = veh.track_width_m
    fz0 = wheel_loads(fr.fzf, veh)
    v2 = turn_speed(fr) ** 2
    wl, wr = fr.omega[:, 2], fr.omega[:, 3]
    k = np.where(turn, kw, 0.0)
    for _ in range(8):
        r = rolling_radius(lateral_load_transfer(fz0, v2 * k, veh, veh.mass_kg), veh)
        cl, cr = r[:, 2] * wl, r[:, 3] * wr
        with np.errstate(divide="ignore", invalid="ignore"):
            k_new = np.where(turn, (2.0 / b) * (cr - cl) / (cr + cl), 0.0)
        k_new = np.where(np.isfinite(k_new), k_new, kw)
        done = float(np.max(np.abs(k_new - k))) < 1e-10
        k = k_new
        if done:
            break
    return k


def lateral_load_transfer(fz: NDArray[np.float64], a_lat: NDArray[np.float64], veh,
                          mass_kg: float) -> NDArray[np.float64]:
    """Wheel loads (n, 4) [N] of axle-split loads ``fz`` with the lateral load transfer of a turn (the
    estimator's model, doc "Lateral load transfer" in :mod:`tractionecu.model.vehicle`):

        F_z,FL/FR = F_zf/2 ∓ δ_f,   F_z,RL/RR = F_zr/2 ∓ δ_r,
        δ_f = λ_f m a_y h_cg / b,   δ_r = (1 − λ_f) m a_y h_cg / b,   a_y = v² κ,

    each δ within ±0.9 of the wheel's axle share; λ_f is the vehicle file's ``front_roll_share``, m
    the mass (with a fitted mass effect), h_cg the centre-of-gravity height and b the track width."""
    lam = float(getattr(veh, "front_roll_share", 0.25))
    c = mass_kg * veh.cg_height_m / veh.track_width_m * np.asarray(a_lat, dtype=float)
    out = np.array(fz, dtype=float)
    for j, share in ((0, lam), (2, 1.0 - lam)):
        half = out[:, j]
        lim = 0.9 * half
        d = np.minimum(np.maximum(share * c, -lim), lim)
        out[:, j + 1] = half + d
        out[:, j] = half - d
    return out


def turn_speed(fr: Frame) -> NDArray[np.float64]:
    """Speed [m/s] for the lateral acceleration v² κ: the GNSS speed, the rear wheels' mean circumferential
    speed on the nominal radius where it is missing (0 where neither is known)."""
    v = np.full(fr.n, np.nan) if fr.v_gps is None else np.abs(fr.v_gps).astype(float)
    if fr.omega is not None:
        vw = 0.5 * np.abs(fr.omega[:, 2] + fr.omega[:, 3]) * fr.vehicle.r0_m
        v = np.where(np.isfinite(v), v, vw)
    return np.nan_to_num(v)


# --------------------------------------------------------------------------- wheel physics
@dataclass
class WheelState:
    """Per-wheel quantities (n, 4) under a set of effect parameters."""

    fz: NDArray[np.float64]
    r: NDArray[np.float64]
    fh: NDArray[np.float64]
    mu: NDArray[np.float64]
    slip: NDArray[np.float64] | None
    fx_sum: NDArray[np.float64] | None = None
    """Σ_i k_i F_h,i (n,) [N]: the wheels' generalised force on the speed v of the rear-axle centre (eq. 8 in
    a turn, NaN wheels count 0); Σ F_h,i on a straight.

    With the body's one degree of freedom v and no side slip, wheel i moves k_i(κ)·v along its own heading
    (model doc "Kinematics in turns"), so a virtual displacement δs of the reference point does the work
    Σ F_h,i k_i δs; the tyres' lateral forces are constraint forces and do no work.  The estimator's force
    balance along the body (front forces at their steer angle, cos δ = (1 ∓ κb/2)/k_i) drops the lateral
    forces' along-body components, which is first order in κ only: in the 3-m headland turns of the
    physical truth it left the speed equation's squared error in the turn rows at 8.2e6 N² (phys_null_c),
    the plain sum at 5.2e6, the weights k_i at 3.6e6."""


def declared_wheel_torque(md: NDArray[np.float64], omega: NDArray[np.float64], veh) -> NDArray[np.float64]:
    """The wheel torque [N·m] a hub drive's reported motor torque ``md`` gives through its declared reduction:
    η M driving, M/η braking (losses against the power flow, M ω < 0), less the declared no-load drag c ω
    (``drivetrain.efficiency``, ``drivetrain.hub_drag_nms``), as the estimator takes it (model doc "Declared
    drivetrain").  The power flow's direction is the sign of M ω here, of M times the direction of travel in the
    estimator (which has no per-row wheel speed at the torque's arrival): the two differ only where a wheel
    stands or turns against the travel.  An engine-driven machine's torques, a declared η of 1 and no drag:
    ``md`` itself.

    Every hub drive loses torque in its reduction; left out, the wheel forces read 1/η high (5 % on the physical
    truth's η = 0.95), a force error that grows with the pull and so with the slip and the draft.  On
    phys_mass_drift of the diagnosis suite (800 kg heavier than its file) the speed equation's window error then
    regressed on Σ F_z |s| at 0.34 N per N, beyond the motion resistance's largest slip coefficient 0.15, the
    part left over went into the mass's acceleration regressor, and the squared error was least at Δm = 0
    (2.06e7 N² at 0, 2.19e7 at 800); with the declared η it is least near the truth (1.54e7 at 0, 1.49e7 at 800,
    1.67e7 at 2000) and the slip coefficient is 0.08."""
    dtr = getattr(veh, "drivetrain", None)
    if dtr is None or dtr.engine_driven:
        return md
    eta, drag = float(dtr.efficiency), float(dtr.hub_drag_nms)
    eta = eta if math.isfinite(eta) and eta > 0.0 else 1.0
    drag = drag if math.isfinite(drag) else 0.0
    if eta == 1.0 and drag == 0.0:
        return md
    out = md * np.where(md * omega >= 0.0, eta, 1.0 / eta) if eta != 1.0 else md
    if drag != 0.0:
        out = out - drag * omega
    return out


def wheel_torque(md: NDArray[np.float64], omega: NDArray[np.float64], veh, *, eta: float | None = None,
                 loss_nm: float = 0.0, gain: tuple[float, float] = (0.0, 0.0),
                 offset_nm: tuple[float, float] = (0.0, 0.0)) -> NDArray[np.float64]:
    """The wheel torque [N·m] of the reported drive torques ``md`` (rows × FL, FR, RL, RR) at wheel speeds
    ``omega`` [rad/s]: the reading corrected for a torque sensor's gain and offset per axle (effects
    ``torque_gain``, ``torque_offset``), then through a fitted drivetrain effect M_wheel = η M − M_loss sgn ω
    (``eta``, ``loss_nm``), whose η replaces the declared one, or else through the declared reduction
    (:func:`declared_wheel_torque`).  One function for the bin means (:func:`wheel_state`) and the torque at the
    bin edges (the relaxation's μ̇)."""
    from ..model import effects as fx

    if gain != (0.0, 0.0) or offset_nm != (0.0, 0.0):
        k = np.array([gain[0], gain[0], gain[1], gain[1]])
        b = np.array([offset_nm[0], offset_nm[0], offset_nm[1], offset_nm[1]])
        md = fx.torque_true(md, k, b)
    if eta is not None or loss_nm != 0.0:
        return fx.drivetrain_torque(md, omega, 1.0 if eta is None else eta, loss_nm)
    return declared_wheel_torque(md, omega, veh)


def wheel_state(fr: Frame, omega_dot: NDArray[np.float64], v: NDArray[np.float64] | None, *,
                delta_m: float = 0.0, eps_r: float = 0.0, eta: float | None = None, loss_nm: float = 0.0,
                gain: tuple[float, float] = (0.0, 0.0), offset_nm: tuple[float, float] = (0.0, 0.0),
                fzf_offset: NDArray[np.float64] | float = 0.0, rho_t_factor: float = 1.0) -> WheelState:
    """Wheel loads, radii, forces, μ and slip for the recorded inputs.

    In a turn (``fr.kappa`` non-zero, :func:`path_curvature`) the loads carry the lateral load
    transfer at ``fr.lat_accel`` = v² κ (:func:`lateral_load_transfer`, with the mass Δm included) and each
    wheel's slip is taken against its own ground speed k_i(κ)·v (:func:`~tractionecu.model.vehicle.wheel_speed_factors`,
    rear 1 ∓ κb/2, front √((1 ∓ κb/2)² + (κL)²)); where κ = 0 both are the straight-line model's.

    ``delta_m`` [kg] adds mass (the rear wheels carry what the front pin does
    not see: F_z,rear = ((m + Δm) g − F_zf)/2); ``eps_r`` scales the rolling
    radius r = (1 + ε) r_d (effect ``wheel_radius``); ``eta``, ``loss_nm`` are
    the drivetrain effect M_wheel = η M_d − M_loss sgn ω, whose η replaces the declared one; without
    it the nominal model takes the hub drive's declared efficiency and drag
    (:func:`declared_wheel_torque`), as the estimator does.  Sensor faults:
    ``gain``, ``offset_nm`` (front, rear) undo a torque gain and offset,
    M = (M_meas − b)/(1 + k); ``fzf_offset`` [N] is removed from the measured
    front-axle load; ``rho_t_factor`` scales ρ_t (tyre pressure).
    """
    from ..model import effects as fx

    veh = fr.vehicle
    fzf = fr.fzf
    if np.any(np.asarray(fzf_offset) != 0.0):
        fzf = fzf - fzf_offset
    fz = wheel_loads(fzf, veh, weight_n=(veh.mass_kg + delta_m) * G)
    turning = fr.kappa is not None and bool(np.any(fr.kappa != 0.0))
    if turning and fr.lat_accel is not None:
        fz = lateral_load_transfer(fz, fr.lat_accel, veh, veh.mass_kg + delta_m)
    r = rolling_radius(fz, veh)
    if eps_r != 0.0:
        r = fx.wheel_radius_true(r, eps_r)
    md = wheel_torque(fr.md, fr.omega, veh, eta=eta, loss_nm=loss_nm, gain=gain, offset_nm=offset_nm)
    fh = (md - veh.wheel_inertia_kgm2 * omega_dot) / r - veh.rho_t * rho_t_factor * fz * np.sign(fr.omega)
    if turning:
        fx_sum = np.nansum(fh * wheel_speed_factors(fr.kappa, veh.track_width_m, veh.wheelbase_m), axis=1)
    else:
        fx_sum = np.nansum(fh, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        mu = fh / fz
        slip = None
        if v is not None:
            vw = np.abs(r * fr.omega)
            va = np.abs(v)[:, None]
            if turning:
                va = va * wheel_speed_factors(fr.kappa, veh.track_width_m, veh.wheelbase_m)
            slip = np.where(va <= vw, 1.0 - va / vw, -1.0 + vw / va)
    return WheelState(fz, r, fh, mu, slip, fx_sum)


# --------------------------------------------------------------------------- helpers
def balance_acceleration(fr: Frame, force: NDArray[np.float64], mass_kg: float) -> NDArray[np.float64]:
    """The acceleration the force-integrated speed integrates [m/s²]: the balance ``force``/m while the wheels
    turn; where they stand or creep (mean |ω| ≤ :data:`~.data.DIRECTION_MIN_RAD_S`) the wheels' own, r₀ dω̄/dt.

    At standstill the torque balance's force is not the machine's: a standing machine's drive torque is
    held by the tyre–soil contact or the brakes, and the rolling resistance's sgn ω flickers with the
    pickups' noise.  Integrated, it moved the speed through every stop: on a healthy recording that reverses at
    each headland (`phys_null_reverse`) the fused speed read −0.28 m/s while the machine stood and 0.1 m/s
    low for seconds after it pulled away, a slip error of 0.1–0.17 there.  Where the wheels do not turn they
    measure the speed (0) better than the balance, and while they creep their sense of rotation is the
    speed's."""
    a = force / mass_kg
    if fr.omega is None:
        return a
    w = mean_wheel_speed(fr.omega)
    creep = np.isfinite(w) & (np.abs(w) <= DIRECTION_MIN_RAD_S)
    if not creep.any():
        return a
    kin = np.gradient(np.nan_to_num(w) * fr.vehicle.r0_m, fr.dt)
    return np.where(creep, kin, a)


def speed_integral(fr: Frame, accel: NDArray[np.float64]) -> NDArray[np.float64]:
    """v_int = ∫ ``accel`` dt [m/s] from 0 on the frame's rows, read at GNSS time: the force samples of bin k
    stand for time t_k + δ (δ = ``can_time_offset_s``), the GNSS speed is at t_k."""
    v = cumtrapz0(accel, fr.dt)
    if fr.can_time_offset_s:
        v = np.interp(fr.t, fr.t + fr.can_time_offset_s, v)
    return v


def held_out_folds(t: NDArray[np.float64]) -> NDArray[np.int64]:
    """Held-out fold (0 or 1) of each frame time ``t`` [s]: alternating blocks of :data:`FOLD_BLOCK_S`; a
    recording shorter than two such blocks gets four blocks of a quarter of its span instead.  (Blocks of
    40 s put all of a 40-s recording into one fold: every fit "on the other fold" then had no rows, and
    the held-out scores and the generic model's reduction were NaN or a fit to nothing.)"""
    t = np.asarray(t, dtype=float)
    if t.size == 0:
        return np.zeros(0, dtype=np.int64)
    t0, span = float(t[0]), float(t[-1] - t[0])
    if span >= 2.0 * FOLD_BLOCK_S or not span > 0.0:
        return np.floor(t / FOLD_BLOCK_S).astype(np.int64) % 2
    return np.minimum(np.floor(4.0 * (t - t0) / span), 3.0).astype(np.int64) % 2


def moving_mean(x: NDArray[np.float64], k: int, min_count: float = 0.0) -> NDArray[np.float64]:
    """Centred mean of ``x`` over ``k`` rows, of the finite samples in each window only (NaN where the
    window holds none, or fewer than ``min_count``).  A plain ``np.convolve(nan_to_num(x), ones(k)/k,
    "same")`` averages the missing rows, and the rows past either end of the recording, as zeros: within
    k/2 rows of an end or a gap it pulls the mean towards 0 (a front-axle load of 20 kN read as 10 kN on
    the last row)."""
    x = np.asarray(x, dtype=float)
    if k <= 1 and min_count <= 1:
        return x.copy()
    ok = np.isfinite(x)
    w = np.ones(max(k, 1))
    cnt = np.convolve(ok.astype(float), w, mode="same")
    tot = np.convolve(np.where(ok, x, 0.0), w, mode="same")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where((cnt > 0) & (cnt >= min_count), tot / np.maximum(cnt, 1.0), np.nan)


def cumtrapz0(y: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
    """Cumulative trapezoid integral starting at 0 (NaN treated as 0)."""
    y = np.nan_to_num(y)
    out = np.zeros_like(y)
    out[1:] = np.cumsum(0.5 * (y[1:] + y[:-1])) * dt
    return out


def spline_basis(t: NDArray[np.float64], knot_s: float, t_eval: NDArray[np.float64] | None = None,
                 sparse: bool = False, breaks: tuple[float, ...] = ()):
    """Cubic B-spline design matrix with knots every ``knot_s`` [s] over the span of ``t``,
    evaluated at ``t_eval`` (default ``t``; clamped to the span); with ``breaks`` (times at which
    the recording starts again) one independent basis per piece (:func:`_piecewise_basis`).

    Each row has at most four non-zeros; ``sparse`` returns it as a CSR matrix (its dense form has
    one column per ``knot_s`` of the recording, so it grows with the square of the length: a
    4-hour recording at 10 Hz would need 5.5 GB)."""
    if breaks:
        return _piecewise_basis(t, knot_s, t if t_eval is None else t_eval, breaks, sparse)
    t0, t1 = float(np.min(t)), float(np.max(t))
    nk = max(int(math.ceil((t1 - t0) / knot_s)), 1)
    inner = np.linspace(t0, t1, nk + 1)
    k = 3
    knots = np.concatenate([[t0] * k, inner, [t1] * k])
    tt = np.clip(t if t_eval is None else t_eval, t0, t1)
    B = BSpline.design_matrix(tt, knots, k)
    return csr_matrix(B) if sparse else B.toarray()


def _piecewise_basis(t: NDArray[np.float64], knot_s: float, t_eval: NDArray[np.float64],
                     breaks, sparse: bool):
    """One independent cubic B-spline basis per piece between ``breaks`` (times at which a piece
    starts): the columns of a piece are zero outside it, so a fit is free to jump at a break.  Each
    point of ``t_eval`` belongs to the piece holding it and is clamped to that piece's span of ``t``."""
    from scipy.sparse import coo_matrix

    edges = np.concatenate([[-np.inf], np.sort(np.asarray(breaks, dtype=float)), [np.inf]])
    piece_t = np.searchsorted(edges, t, side="right") - 1
    piece_e = np.searchsorted(edges, t_eval, side="right") - 1
    rows, cols, vals = [], [], []
    off = 0
    for j in range(edges.size - 1):
        tj = t[piece_t == j]
        if tj.size == 0:
            continue
        ej = np.flatnonzero(piece_e == j)
        Bj = spline_basis(tj, knot_s, t_eval=t_eval[ej], sparse=True).tocoo()
        rows.append(ej[Bj.row])
        cols.append(Bj.col + off)
        vals.append(Bj.data)
        off += Bj.shape[1]
    B = csr_matrix(coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                              shape=(t_eval.size, off)))
    return B if sparse else B.toarray()


SPLINE_RIDGE = 1e-9
"""Ridge added to the normal equations of a spline fit, as a share of their mean diagonal: it only
decides the coefficients that the data leave free (a basis function whose support holds a single
sample at the edge of a gap), where it gives the minimum-norm solution, as a pseudo-inverse would."""


class SplineFit:
    """Least squares on a cubic B-spline basis ``B`` (sparse, rows = the samples fitted), in time and
    memory linear in the number of samples: BᵀB is banded (a cubic B-spline overlaps three neighbours),
    so the normal equations are solved by a banded Cholesky factor.  Columns without support in the
    rows (their sum ≤ ``min_support``) are dropped."""

    def __init__(self, B, min_support: float = 1e-9) -> None:
        from scipy.linalg import cholesky_banded

        B = csr_matrix(B)
        self.cols = np.asarray(B.sum(axis=0)).ravel() > min_support
        self.B = csr_matrix(B[:, np.flatnonzero(self.cols)])
        G = csr_matrix(self.B.T @ self.B)
        p = G.shape[0]
        ab = np.zeros((4, p))
        for d in range(4):
            if d < p:
                ab[3 - d, d:] = G.diagonal(d)
        ab[3] += SPLINE_RIDGE * float(np.sum(ab[3])) / max(p, 1)
        self._cf = cholesky_banded(ab) if p else ab

    def coef(self, y: NDArray[np.float64]) -> NDArray[np.float64]:
        """Coefficients β minimising ‖y − B β‖² (over the kept columns)."""
        from scipy.linalg import cho_solve_banded

        if not self.B.shape[1]:
            return np.zeros(0)
        return cho_solve_banded((self._cf, False), self.B.T @ y)

    def project(self, y: NDArray[np.float64]) -> NDArray[np.float64]:
        """B β: the fitted values at the rows."""
        return self.B @ self.coef(y)


def smooth_derivative(y: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
    """Central difference dy/dt [unit/s] (one-sided at the ends)."""
    return np.gradient(y, dt, axis=0)


def runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """[start, stop) index pairs of the True runs of ``mask``."""
    m = np.concatenate([[False], mask.astype(bool), [False]])
    d = np.diff(m.astype(int))
    return list(zip(np.nonzero(d == 1)[0], np.nonzero(d == -1)[0]))


def fused_speed(fr: Frame, v_int: NDArray[np.float64], valid: NDArray[np.bool_],
                tau_s: float = 0.0, clock: tuple[float, float] | None = None) -> NDArray[np.float64]:
    """Fused ground speed v_ref(t) = v_int(t) + b(t) [m/s] on the CAN rows' time.

    v_int is the force integral (1/m) ∫ (Σ F_h,i − F_dx) dt (:attr:`Features.v_int`: :func:`speed_integral`
    of :func:`balance_acceleration`); the slow correction b is a cubic
    B-spline fitted to the GNSS speed.  With a GNSS latency τ the fit is
    v_gps(t) = v_int(t − τ) + b(t − τ) (effect ``gps_latency``) and the
    returned speed is undelayed.  With a CAN clock running δ(t) ahead of GNSS
    time (``clock`` = (δ_0 [s], κ [ppm]), effect ``clock_skew``) the CAN row
    stamped t holds the state of GNSS time t − δ: the fit is v_gps(t) =
    v_int(t + δ) + b(t + δ) and the returned speed is b's at t − δ (a GNSS
    latency of −δ(t) and the latency's together, τ − δ).
    """
    from ..model.effects import clock_shift_s, delayed

    ok = np.flatnonzero(valid & np.isfinite(fr.v_gps))
    B = spline_basis(fr.t, SPLINE_KNOT_S, sparse=True, breaks=fr.break_t)
    if clock is not None:
        shift = clock_shift_s(fr.t, clock[0], clock[1]) - tau_s       # the CAN data lag GNSS time by this
        model = np.interp(fr.t, fr.t - shift, v_int)
    else:
        model = delayed(fr.t, v_int, tau_s) if tau_s else v_int
    sf = SplineFit(B[ok])
    beta = sf.coef(fr.v_gps[ok] - model[ok])
    cols = np.flatnonzero(sf.cols)
    if clock is not None:
        B = spline_basis(fr.t, SPLINE_KNOT_S, t_eval=fr.t - shift, sparse=True, breaks=fr.break_t)
    elif tau_s:
        B = spline_basis(fr.t, SPLINE_KNOT_S, t_eval=fr.t + tau_s, sparse=True, breaks=fr.break_t)
    v = v_int + B[:, cols] @ beta
    if fr.break_t:
        # While the logger was off nothing was measured, and next to a break the spline has no data
        # (its edge coefficients would reach hundreds of m/s there): no speed.
        v[logger_off(fr) | near_breaks(fr)] = np.nan
    return v


DEM_CHUNK = 64
"""Evaluation points whose kernel neighbourhoods are gathered at once (bounds the pairs held)."""


def _dem_gradient(x, y, h, tf, ex, ey, te, bw: float, axis: float, dt_min: float = 0.0,
                  dt_max: float = math.inf) -> tuple[NDArray, NDArray]:
    """Local-linear kernel fit h ≈ h0 + g_u·Δu along the field's main axis, from the fit points
    whose time differs from the evaluation point's by ``dt_min < |Δt| < dt_max`` [s].

    Returns (h0, g_u) at (ex, ey); ``h`` of shape (n, K) gives K fits of the same points, (m, K) each.
    Only the slope along the passes is fitted: across them the
    passes lie a few metres apart and each carries its own slowly wandering GNSS altitude error,
    so a cross slope would be that error, not relief.  A point needs 8 fit points within 3 kernel
    widths (before and after the time condition).  The neighbourhoods of :data:`DEM_CHUNK`
    evaluation points are gathered at once as index pairs and summed by point (``np.bincount``), so
    memory is bounded by one chunk's pairs.
    """
    tree = cKDTree(np.c_[x, y])
    hk = h if h.ndim == 2 else h[:, None]                 # K altitude vectors fitted on the same pairs
    h0 = np.full((ex.size, hk.shape[1]), np.nan)
    gu = np.full((ex.size, hk.shape[1]), np.nan)
    ca, sa = math.cos(axis), math.sin(axis)
    r = 3.0 * bw
    for a in range(0, ex.size, DEM_CHUNK):
        b = min(a + DEM_CHUNK, ex.size)
        m = b - a
        pairs = cKDTree(np.c_[ex[a:b], ey[a:b]]).sparse_distance_matrix(tree, r, output_type="ndarray")
        i = pairs["i"].astype(np.int64)
        j = pairs["j"].astype(np.int64)
        # query_ball_point's rule (distance ≤ r); sparse_distance_matrix keeps distance ≤ r as well.
        n_all = np.bincount(i, minlength=m)
        k = n_all[i] >= 8
        i, j = i[k], j[k]
        adt = np.abs(tf[j] - te[a + i])
        k = (adt > dt_min) & (adt < dt_max)
        i, j = i[k], j[k]
        cnt = np.bincount(i, minlength=m)
        k = cnt[i] >= 8
        i, j = i[k], j[k]
        if not i.size:
            continue
        dx = x[j] - ex[a + i]
        dy = y[j] - ey[a + i]
        wgt = np.exp(-0.5 * (dx * dx + dy * dy) / (bw * bw))
        du = dx * ca + dy * sa
        sw = np.bincount(i, weights=wgt, minlength=m)
        ok = sw > 0
        swd = np.where(ok, sw, 1.0)
        mu_ = np.bincount(i, weights=wgt * du, minlength=m) / swd
        dc = du - mu_[i]
        suu = np.bincount(i, weights=wgt * dc * dc, minlength=m)
        good = ok & (cnt >= 8) & ~(suu < 1e-3 * sw * bw * bw)
        for col in range(hk.shape[1]):
            hj = hk[j, col]
            mh = np.bincount(i, weights=wgt * hj, minlength=m) / swd
            suh = np.bincount(i, weights=wgt * dc * (hj - mh[i]), minlength=m)
            g = np.where(good, suh / np.where(good, suu, 1.0), np.nan)
            h0[a:b, col] = np.where(good, mh - g * mu_, np.nan)
            gu[a:b, col] = g
    return (h0, gu) if h.ndim == 2 else (h0[:, 0], gu[:, 0])


MAX_GRADE_POINTS = 6000
"""Most samples the altitude surface is fitted to (50 minutes of driving at 2 Hz; a longer recording
is thinned evenly: about one point every 2 s (5 m) at 4 hours, still several per kernel width)."""
RELIEF_SNR = 1.5
"""Relief counts as real when the altitude surfaces of passes with independent errors agree:
cov(h_own, h_other) ≥ RELIEF_SNR · var(h_own − h_other)/2 (relief variance against error variance).
Calibrated on flat simulated fields, where the ratio stayed below 1."""
RELIEF_MIN_M = 4.0
"""Altitude range [m] that counts as relief when no second pass can check it (4 × a 1 m DGPS error)."""
ALT_INDEPENDENT_S = 90.0
"""GNSS altitude errors further apart in time than this [s] are treated as independent
(three correlation times of a DGPS receiver's slowly wandering error)."""


@dataclass
class GradeEstimate:
    """Grade along the track from the GNSS altitude (see :func:`grade_from_altitude`)."""

    theta: NDArray[np.float64]
    """Calibrated grade θ_cal = atan(λ · dh/ds_other) [rad] (NaN where unknown)."""
    theta_raw: NDArray[np.float64]
    """Grade from all passes pooled, uncalibrated [rad]."""
    reliability: float
    """λ = cov(own, other)/var(pooled): share of the pooled slope's variance that is relief [-]
    (NaN when no pass overlaps another)."""
    reliability_se: float
    """Block-jackknife standard error of λ [-]."""
    relief: bool
    """The altitude shows relief beyond its error (else θ is zero: no grade to test)."""
    method: str
    drift_rel_se: float = math.nan
    """Relative standard error of the calibrated grade's scale from the GNSS altitude error's slow drift
    (:func:`altitude_drift_rel_se`) [-]; NaN when not computed."""


def grade_from_altitude(fr: Frame, valid: NDArray[np.bool_], bw: float = DEM_BANDWIDTH_M) -> GradeEstimate | None:
    """Grade θ along the heading from the pooled GNSS altitude surface,
    θ = atan(g_u cos(ψ − ψ_axis)) with g_u the slope along the field's main axis.

    A classical error in the regressor attenuates a fitted grade force, so the
    slope used as regressor is calibrated: with g_own the slope from the same
    pass (|Δt| < 20 s) and g_other the slope from data at least
    :data:`ALT_INDEPENDENT_S` away in time (other passes over the same
    ground), whose altitude errors are independent,

        λ = Σ g_own g_other / Σ g_pooled²,   θ_cal = atan(λ g_pooled),

    where g_pooled uses all data: cov(own, other) estimates the variance of
    the true slope, so λ g_pooled is the best linear predictor of the true
    slope given the pooled one (regression calibration).  Without overlapping passes the pooled slope is used and
    the method says so.
    """
    if not fr.has("alt", "x", "y", "heading"):
        return None
    ok = valid & np.isfinite(fr.alt) & np.isfinite(fr.x) & np.isfinite(fr.y) & np.isfinite(fr.heading)
    if ok.sum() < 20:
        return None
    idx = np.nonzero(ok)[0]
    # 2 Hz is plenty for a 20 m kernel; on a long recording fewer points still (at most
    # MAX_GRADE_POINTS): each point's neighbourhood fills up as the same field is driven again, so the
    # kernel fits would cost the square of the recording's length.
    step = max(1, int(round(fr.rate_hz / 2)), int(math.ceil(idx.size / MAX_GRADE_POINTS)))
    sub = idx[::step]
    x, y, h, t = fr.x[sub], fr.y[sub], fr.alt[sub], fr.t[sub]
    hd = fr.heading[sub]

    xy = np.c_[x, y] - np.c_[x, y].mean(axis=0)
    ax_vec = np.linalg.svd(xy, full_matrices=False)[2][0]
    axis = math.atan2(ax_vec[1], ax_vec[0])
    along = np.cos(hd - axis)

    def surface(dt_min: float, dt_max: float) -> tuple[NDArray, NDArray]:
        h0, gu = _dem_gradient(x, y, h, t, x, y, t, bw, axis, dt_min, dt_max)
        return h0, gu * along

    _, g_all = surface(-1.0, math.inf)
    h_other, g_other = surface(ALT_INDEPENDENT_S, math.inf)
    lam = float("nan")
    lam_se = float("nan")
    snr_relief = float("nan")
    if np.isfinite(g_other).sum() >= 0.3 * sub.size:
        h_own, g_own = surface(-1.0, 20.0)
        pair = np.isfinite(g_other) & np.isfinite(g_own) & np.isfinite(g_all)
        den = float(np.sum(g_all[pair] ** 2))
        if den > 0 and pair.sum() > 10:
            # cov(own, other) estimates the relief's variance (independent errors); var(pooled) its
            # variance plus the pooled error's.  λ = var(relief)/var(pooled) gives the best linear
            # predictor λ·g_pooled of the true slope.
            prod = g_own[pair] * g_other[pair]
            lam = float(np.clip(np.sum(prod) / den, 0.0, 1.0))
            # Block jackknife over K slabs across the field's main axis (each slab holds every pass
            # over that ground): the relief has few independent features, so λ is uncertain and
            # that uncertainty belongs in a fitted grade's interval.
            K = 8
            pos = xy[pair] @ ax_vec
            edges = np.quantile(pos, np.linspace(0, 1, K + 1)[1:-1])
            blk = np.searchsorted(edges, pos)
            g2 = g_all[pair] ** 2
            loo = np.array([np.sum(prod[blk != k]) / max(np.sum(g2[blk != k]), 1e-30) for k in range(K)])
            lam_se = float(math.sqrt((K - 1) / K * np.sum((loo - loo.mean()) ** 2)))
            a = h_own[pair] - h_own[pair].mean()
            b = h_other[pair] - h_other[pair].mean()
            noise = float(np.var(a - b)) / 2.0
            snr_relief = float(np.mean(a * b)) / noise if noise > 0 else math.inf
    if np.isfinite(lam):
        if not snr_relief >= RELIEF_SNR:
            return GradeEstimate(np.zeros(fr.n), np.full(fr.n, np.nan), 0.0, math.nan, False,
                                 f"no relief beyond the GNSS altitude error: relief/error variance ratio "
                                 f"{snr_relief:.2f} < {RELIEF_SNR}")
        g_use = lam * g_all
        real = True
        method = (f"pooled GNSS altitude surface (kernel {bw:.0f} m), slope calibrated by λ = {lam:.2f} ± {lam_se:.2f} "
                  f"(regression calibration: relief variance from passes with independent altitude errors, "
                  f"relief/error variance ratio {snr_relief:.1f})")
    else:
        alt = h[np.isfinite(h)]
        relief = float(np.percentile(alt, 95) - np.percentile(alt, 5)) if alt.size > 10 else 0.0
        real = relief >= RELIEF_MIN_M
        if not real:
            return GradeEstimate(np.zeros(fr.n), np.full(fr.n, np.nan), math.nan, math.nan, False,
                                 f"altitude range {relief:.1f} m < {RELIEF_MIN_M:.0f} m and no overlapping pass to "
                                 "check it against: no relief beyond the GNSS altitude error")
        g_use = g_all
        method = (f"GNSS altitude along the track (kernel {bw:.0f} m), altitude range {relief:.1f} m; no "
                  "overlapping pass to calibrate the altitude error: a fitted grade may be attenuated")
    good = np.isfinite(g_use)
    if good.sum() < 2:
        return None
    drift = altitude_drift_rel_se(x, y, t, bw, axis, along, g_use, 1.0 if not np.isfinite(lam) else lam,
                                  float(fr.sensors.gps_alt_sigma), float(fr.sensors.gps_pos_tau_s))
    th = np.full(fr.n, np.nan)
    th_raw = np.full(fr.n, np.nan)
    # Interpolate the slope along the axis in time, then project on each sample's own heading.
    gu_use = np.where(np.abs(along) > 1e-6, g_use / np.where(np.abs(along) > 1e-6, along, 1.0), np.nan)
    okg = np.isfinite(gu_use) & (np.abs(along) > 0.3)
    if okg.sum() < 2:
        return None
    th[idx] = np.arctan(np.interp(fr.t[idx], t[okg], gu_use[okg]) * np.cos(fr.heading[idx] - axis))
    gu_all = np.where(np.abs(along) > 0.3, g_all / np.where(np.abs(along) > 0.3, along, 1.0), np.nan)
    g2 = np.isfinite(gu_all)
    if g2.sum() >= 2:
        th_raw[idx] = np.arctan(np.interp(fr.t[idx], t[g2], gu_all[g2]) * np.cos(fr.heading[idx] - axis))
    return GradeEstimate(th, th_raw, lam, lam_se, real, method, drift)


DRIFT_DRAWS = 16
"""Altitude-error draws of :func:`altitude_drift_rel_se` (its relative SE is known to about 1/√(2·16) = 18 %)."""


def altitude_drift_rel_se(x: NDArray, y: NDArray, t: NDArray, bw: float, axis: float, along: NDArray,
                          g_use: NDArray, lam: float, sigma_m: float, tau_s: float) -> float:
    """Relative standard error of a grade scale fitted against the slope ``g_use`` (per surface point,
    along the track) that the GNSS altitude error's slow drift leaves in the surface.

    The receiver's altitude error is first-order Gauss–Markov (σ, τ of the vehicle file's ``[sensors]``:
    ``gps_alt_sigma``, ``gps_pos_tau_s``).  Over a pass of a minute or two it drifts by a fair part of σ,
    which reads as a slope along the pass; on a few passes those slopes do not average out, and the
    regression calibration λ (which sees only the error's variance) does not remove them.  Measured on
    `multi_grade_latency` with another seed: the surface's slope was 0.75× the truth's, the scale 1.30
    [1.08, 1.53] for 1.  The surface is linear in the altitudes, so the error's own surface is fitted to
    draws of that error on the recording's own points (fixed seed: the diagnosis stays deterministic) and
    projected on ``g_use``: c_k = λ Σ e_k g / Σ g², the RMS of the c_k is the relative SE (type B,
    GUM 4.3: from the receiver's specification, not from the recording).
    """
    ok = np.isfinite(g_use)
    den = float(np.sum(g_use[ok] ** 2))
    if not (sigma_m > 0 and tau_s > 0 and den > 0 and ok.sum() > 10):
        return math.nan
    rng = np.random.default_rng(20260707)
    dt = np.diff(t, prepend=t[0])
    phi = np.exp(-np.maximum(dt, 0.0) / tau_s)
    e = np.empty((t.size, DRIFT_DRAWS))
    e[0] = rng.standard_normal(DRIFT_DRAWS) * sigma_m
    w = rng.standard_normal((t.size, DRIFT_DRAWS)) * sigma_m * np.sqrt(1.0 - phi * phi)[:, None]
    for i in range(1, t.size):
        e[i] = phi[i] * e[i - 1] + w[i]
    _, ge = _dem_gradient(x, y, e, t, x, y, t, bw, axis, -1.0, math.inf)
    ge = ge * along[:, None]
    c = [lam * float(np.nansum(np.where(ok, ge[:, k] * g_use, np.nan))) / den for k in range(DRIFT_DRAWS)]
    return float(np.sqrt(np.mean(np.square(c))))


def main_axis(fr: Frame, mask: NDArray[np.bool_]) -> float | None:
    """Direction [rad] of the field's main pass axis (heading modulo π, weighted by speed)."""
    if fr.heading is None:
        return None
    h = fr.heading[mask & np.isfinite(fr.heading)]
    if h.size < 10:
        return None
    c = np.mean(np.cos(2 * h))
    s = np.mean(np.sin(2 * h))
    return 0.5 * math.atan2(s, c)


def _cells(u: NDArray, w: NDArray, ok: NDArray[np.bool_], rate_hz: float) -> tuple[NDArray[np.int64], int]:
    u0 = float(np.min(u[ok])) if ok.any() else 0.0
    w0 = float(np.min(w[ok])) if ok.any() else 0.0
    iu = np.floor((u - u0) / CELL_M).astype(np.int64)
    iw = np.floor((w - w0) / CELL_M).astype(np.int64)
    key = np.where(ok, iu * 100003 + iw, -1)
    uniq, inv, cnt = np.unique(key[ok], return_inverse=True, return_counts=True)
    cent_u = np.bincount(inv, weights=u[ok]) / cnt
    cent_w = np.bincount(inv, weights=w[ok]) / cnt
    big = cnt >= CELL_MIN_S * rate_hz
    if not big.any():
        big[np.argmax(cnt)] = True
    bi = np.nonzero(big)[0]
    remap = np.empty(uniq.size, dtype=np.int64)
    for j in range(uniq.size):
        if big[j]:
            remap[j] = j
        else:
            d = (cent_u[bi] - cent_u[j]) ** 2 + (cent_w[bi] - cent_w[j]) ** 2
            remap[j] = bi[np.argmin(d)]
    labels = np.unique(remap[bi])
    dense = {int(l): k for k, l in enumerate(labels)}
    cell = np.zeros(u.size, dtype=np.int64)
    cell[ok] = np.array([dense[int(remap[j])] for j in inv]) if inv.size else 0
    # Samples without a position join the cell nearest in time.
    if (~ok).any() and ok.any():
        t_idx = np.nonzero(ok)[0]
        near = t_idx[np.clip(np.searchsorted(t_idx, np.nonzero(~ok)[0]), 0, t_idx.size - 1)]
        cell[~ok] = cell[near]
    return cell, len(labels)


HOLD_MIN_S = 1.0
"""A wheel speed frozen, zero or missing for at least this long [s] while the others move is a sensor fault."""
HOLD_MOVING_RADPS = 1.0
"""The other wheels must turn faster than this [rad/s] (≈ 0.8 m/s on 1.6 m tyres) for a hold to count."""


def modelled_front_load(fr: Frame) -> NDArray[np.float64]:
    """Front-axle load [N] when no pin measures it: the static split minus the load transfer of the
    vehicle file's hitch and centre-of-gravity heights (effect ``load_transfer``, part of the
    nominal model), with the acceleration from the GNSS speed (1 s central difference) and no grade."""
    from ..model import effects as fx

    veh = fr.vehicle
    k = max(1, int(round(fr.rate_hz)))
    vs = np.nan_to_num(moving_mean(fr.v_gps, k)) if fr.v_gps is not None else np.zeros(fr.n)
    acc = np.gradient(vs, fr.dt)
    fdx = np.nan_to_num(fr.fdx) if fr.fdx is not None else np.zeros(fr.n)
    dfr = fx.load_transfer_rear(fdx, acc, np.zeros(fr.n), veh.mass_kg, veh.wheelbase_m, veh.hitch_height_m,
                                veh.cg_height_m)
    return veh.static_front_load_n() - dfr


def wheel_speed_faults(fr: Frame) -> tuple[list[dict], NDArray[np.bool_]]:
    """Find wheel-speed sensor holds and dropouts (library fault ``wheel_speed_hold``) and repair them.

    A wheel whose speed is missing, zero, exactly constant, or of the sign opposite to the three others' for at
    least :data:`HOLD_MIN_S` while the other three turn faster than :data:`HOLD_MOVING_RADPS` (and, for a hold,
    change) is a sensor fault, not physics.  Its samples take the speed of the other wheel on the same axle (so
    the force balance stays continuous) and the rows are returned as bad (slip and fits skip them). Returns
    (faults, bad rows).
    """
    bad = np.zeros(fr.n, dtype=bool)
    out: list[dict] = []
    if fr.omega is None or fr.n < 3:
        return out, bad
    om = fr.omega
    names = ("FL", "FR", "RL", "RR")
    kmin = max(2, int(round(HOLD_MIN_S * fr.rate_hz)))
    for i in range(4):
        others = [j for j in range(4) if j != i]
        oth = om[:, others]
        fin = np.isfinite(oth)
        moving = np.all(fin, axis=1) & (np.min(np.abs(np.where(fin, oth, np.inf)), axis=1) > HOLD_MOVING_RADPS)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)   # rows without any wheel speed (logger off): NaN
            med = np.nanmedian(np.abs(oth), axis=1)
        wi = om[:, i]
        missing = ~np.isfinite(wi)
        zero = np.isfinite(wi) & (np.abs(wi) < 0.05 * med)
        d = np.diff(wi, prepend=np.nan)
        with np.errstate(invalid="ignore"):
            do = np.max(np.nan_to_num(np.abs(np.diff(oth, axis=0, prepend=np.nan)), nan=0.0), axis=1)
        held = (d == 0.0) & (do > 0.0)
        held = (held | np.concatenate([held[1:], [False]])) & ~zero   # the first sample of the run too
        # turning the other way from the three others (a sign flipped in the sensor or its decoding: the
        # wheels of a tractor never turn against each other while all of them move)
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)   # rows without any other wheel speed: NaN
            ref = np.nanmedian(oth, axis=1)
            sign = (np.isfinite(wi) & ~zero & (np.sign(wi) * np.sign(ref) < 0)
                    & np.all(np.sign(oth) == np.sign(ref)[:, None], axis=1))
        for kind, mask in (("missing", missing), ("dropout", zero), ("hold", held), ("sign flip", sign)):
            for a, b in runs(mask & moving):
                if b - a < kmin:
                    continue
                bad[a:b] = True
                out.append({"name": "wheel_speed_hold", "kind": kind, "wheel": names[i],
                            "t0_s": float(fr.t[a]), "duration_s": float((b - a) * fr.dt)})
                mate = i ^ 1   # the other wheel on the same axle
                fill = om[a:b, mate]
                if not np.all(np.isfinite(fill)):
                    fill = np.nanmean(oth[a:b], axis=1)
                om[a:b, i] = fill
                if fr.hf_omega is not None:
                    k = fr.hf_omega.shape[0] // fr.n
                    fr.hf_omega[a * k:b * k, i] = fr.hf_omega[a * k:b * k, mate]
    if out and fr.omega_dot is not None:
        fr.omega_dot[bad] = np.nan   # recomputed from the repaired speeds below
    return out, bad


def _recorded(fr: Frame) -> NDArray[np.bool_]:
    """Rows with a sample of any recorded signal (wheel speeds, torques, measured front-axle load,
    draft, GNSS)."""
    seen = np.zeros(fr.n, dtype=bool)
    for a in (fr.omega, fr.md, None if fr.fzf_modelled else fr.fzf, fr.fdx, fr.v_gps, fr.x):
        if a is not None:
            f = np.isfinite(a)
            seen |= f.any(axis=1) if f.ndim == 2 else f
    return seen


def logger_off(fr: Frame) -> NDArray[np.bool_]:
    """Rows inside a stretch of at least :data:`BREAK_GAP_S` without any sample (the logger off)."""
    seen = np.flatnonzero(_recorded(fr))
    off = np.zeros(fr.n, dtype=bool)
    if seen.size == 0:
        off[:] = True
        return off
    gap = np.diff(fr.t[seen]) >= BREAK_GAP_S
    for a, b in zip(seen[:-1][gap], seen[1:][gap]):
        off[a + 1:b] = True
    return off


def near_breaks(fr: Frame) -> NDArray[np.bool_]:
    """Rows from :data:`BREAK_MARGIN_S` before the last sample ahead of each break in ``fr.break_t``
    (across the logger's off time) to the margin after the break."""
    out = np.zeros(fr.n, dtype=bool)
    if not fr.break_t:
        return out
    m = int(math.ceil(BREAK_MARGIN_S * fr.rate_hz))
    seen = np.flatnonzero(_recorded(fr))
    for b in np.searchsorted(fr.t, np.asarray(fr.break_t) - 1e-9):
        j = int(np.searchsorted(seen, b))
        last = int(seen[j - 1]) if j > 0 else int(b) - 1
        out[max(last + 1 - m, 0):b + m] = True
    return out


def find_breaks(fr: Frame) -> NDArray[np.int64]:
    """Rows at which the recording starts again after a break (ascending):

    - the first sample after at least :data:`BREAK_GAP_S` without any sample of the wheel speeds,
      torques, front-axle load, draft or GNSS (the logger was off);
    - a GNSS fix farther than the speed allows from the fix before it (within :data:`BREAK_GAP_S`),
      distance > (max |v| + 1 m/s) Δt + :data:`BREAK_JUMP_M` with v the GNSS speed at both fixes:
      the track restarts elsewhere without a gap in time.

    A real day's log has both (a logger switched off over a break, a restart after a fault); across
    a break the drive does not continue, so nothing is fitted or compared across it."""
    seen = _recorded(fr)
    out: list[int] = []
    idx = np.flatnonzero(seen)
    if idx.size > 1:
        gap = np.diff(fr.t[idx])
        out += idx[1:][gap >= BREAK_GAP_S].tolist()
    if fr.x is not None and fr.y is not None:
        fix = np.flatnonzero(np.isfinite(fr.x) & np.isfinite(fr.y))
        if fix.size > 1:
            dt = np.diff(fr.t[fix])
            d = np.hypot(np.diff(fr.x[fix]), np.diff(fr.y[fix]))
            v = np.abs(np.nan_to_num(fr.v_gps[fix])) if fr.v_gps is not None else np.zeros(fix.size)
            allowed = (np.maximum(v[1:], v[:-1]) + 1.0) * dt + BREAK_JUMP_M
            out += fix[1:][(dt < BREAK_GAP_S) & (d > allowed)].tolist()
    return np.unique(np.asarray(out, dtype=np.int64))


def compute(fr: Frame) -> Features:
    """All derived features of a frame that has per-wheel drive data."""
    notes: list[str] = []
    n = fr.n
    if fr.has("omega", "md") and not fr.has("fzf"):
        fr.fzf = modelled_front_load(fr)
        fr.fzf_modelled = True
        veh = fr.vehicle
        notes.append(f"no front-axle load signal: wheel loads from the static split and the load transfer of the "
                     f"vehicle file's heights (hitch {veh.hitch_height_m:g} m, centre of gravity {veh.cg_height_m:g} m)")
    sensor_faults: list[dict] = []
    fault_rows = np.zeros(n, dtype=bool)
    if fr.omega is not None:
        fr.omega = fr.omega.copy()
        if fr.hf_omega is not None:
            fr.hf_omega = fr.hf_omega.copy()
        if fr.omega_dot is not None:
            fr.omega_dot = fr.omega_dot.copy()
        sensor_faults, fault_rows = wheel_speed_faults(fr)
        for f in sensor_faults:
            notes.append(f"wheel-speed sensor {f['wheel']}: {f['kind']} for {f['duration_s']:.1f} s from "
                         f"t = {f['t0_s']:.1f} s; those samples are left out")
    have_wheels = fr.has("omega", "md", "fzf")
    v_gps = fr.v_gps if fr.has("v_gps") else None
    valid = np.ones(n, dtype=bool)
    if v_gps is not None:
        valid &= np.isfinite(v_gps)
    if have_wheels:
        valid &= np.all(np.isfinite(fr.omega), axis=1) & np.all(np.isfinite(fr.md), axis=1) & np.isfinite(fr.fzf)
    valid &= ~fault_rows
    brk = find_breaks(fr)
    near_break = np.zeros(n, dtype=bool)
    if brk.size:
        fr.break_t = tuple(float(x) for x in fr.t[brk])
        near_break = near_breaks(fr)
        valid &= ~near_break
        notes.append(f"{brk.size} break(s) in the recording (the logger off for {BREAK_GAP_S:g} s or more, or the "
                     f"track restarting elsewhere) at t = " + ", ".join(f"{x:.1f}" for x in fr.break_t[:5])
                     + (" ..." if brk.size > 5 else "") + " s: nothing is fitted or compared across them")
    if have_wheels:
        kappa, known, turn = path_curvature(fr)
        fr.kappa = kappa
        fr.kappa_known = known
        fr.lat_accel = turn_speed(fr) ** 2 * kappa
        if turn.any():
            notes.append(f"turns (wheel-speed curvature, confirmed by the GNSS course) on {turn.mean():.1%} of the "
                         f"recording, |κ| up to {np.max(np.abs(kappa)):.3g} 1/m: wheel loads with the lateral load "
                         f"transfer (front roll share {getattr(fr.vehicle, 'front_roll_share', 0.25):g}) and each "
                         "wheel's slip against its own ground speed")
    omega_dot = None
    if have_wheels:
        omega_dot = fr.omega_dot if fr.omega_dot is not None else smooth_derivative(np.nan_to_num(fr.omega), fr.dt)
        omega_dot = np.where(np.isfinite(omega_dot), omega_dot, smooth_derivative(np.nan_to_num(fr.omega), fr.dt))
    v_ref = accel = v_int = None
    if have_wheels and v_gps is not None:
        if fr.fdx is not None:
            ws = wheel_state(fr, omega_dot, None)
            # Bin-mean acceleration of the force balance, (Σ F_h − F_dx)/m (the wheels' own where they stand or
            # creep), plus the slope of the slow correction b = v_ref − v_int (resistances the balance does not
            # know).
            a_bal = balance_acceleration(fr, ws.fx_sum - np.nan_to_num(fr.fdx), fr.vehicle.mass_kg)
            v_int = speed_integral(fr, a_bal)
        else:
            # No draft signal: the pull is unknown, so is the force balance (taken without the pull, its speed
            # ran ahead whenever the implement pulled and the slip's lag was named a tyre relaxation of 3.6 m);
            # the ground speed is the slow correction alone, the spline through the GNSS speed.
            a_bal = v_int = np.zeros(n)
        v_ref = fused_speed(fr, v_int, valid)
        accel = a_bal + smooth_derivative(v_ref - v_int, fr.dt)
    elif v_gps is not None:
        v_ref = v_gps
        accel = smooth_derivative(np.nan_to_num(v_gps), fr.dt)
    if v_ref is not None:
        valid &= np.abs(v_ref) > MOVING_MPS
    grade = grade_from_altitude(fr, valid)
    theta = grade.theta if grade is not None and grade.relief else None
    if grade is None:
        notes.append("no usable GNSS altitude/position: grade cannot be tested")
    elif not grade.relief:
        notes.append(grade.method)

    # Work segments.
    segment = np.full(n, -1, dtype=np.int64)
    if fr.work is not None:
        k = 0
        for a, b in runs(fr.work & ~near_break):
            if (b - a) * fr.dt >= 5.0:
                segment[a:b] = k
                k += 1
    # Field axis, direction, cells.
    axis = main_axis(fr, valid & (segment >= 0) if (segment >= 0).any() else valid)
    direction = np.zeros(n, dtype=np.int64)
    u = w = None
    if axis is not None and fr.has("x", "y"):
        ca, sa = math.cos(axis), math.sin(axis)
        u = fr.x * ca + fr.y * sa
        w = -fr.x * sa + fr.y * ca
        direction = np.where(np.cos(fr.heading - axis) >= 0, 1, -1)
        okp = np.isfinite(u) & np.isfinite(w)
        cell, n_cells = _cells(np.nan_to_num(u), np.nan_to_num(w), okp, fr.rate_hz)
    else:
        cell, n_cells = np.zeros(n, dtype=np.int64), 1
        # one soil for the whole recording: a field of several soils then leaves a slow resistive force that
        # no effect explains (a healthy recording without its GNSS log came out "unexplained" without a word)
        notes.append("no GNSS positions: the soil is taken as one for the whole recording (no cells on the "
                     "field), so a change of soil shows as an unexplained resistive force")
    fold = held_out_folds(fr.t)
    feat = Features(fr, valid, omega_dot, v_gps, v_ref, accel, theta, grade, segment, direction, cell,
                    n_cells, fold, u, w, notes)
    feat.sensor_faults = sensor_faults
    feat.v_int = v_int
    return feat
