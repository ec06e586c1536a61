"""Vehicle model of the paper, section 2 (eqs. 1–9), vectorised over many states.

Wheel order is FL, FR, RL, RR.  Every function broadcasts over leading axes so
that all 2n+1 sigma points go through one call.

Equations (paper numbering)
---------------------------
(2)  J_w ω̇_i = M_d,i − r_d,i F_h,i − r_d,i ρ_t F_z,i          torque balance per wheel
(4)  F_h,i = μ_i F_z,i                                          adhesion
(5)  κ = μ − ρ_s                                                 net traction ratio
(6)  two-branch slip, s ∈ [−1, 1]
(7)  η = κ/(κ + ρ)·(1 − s), ρ = ρ_s + ρ_t                       traction efficiency
(8)  m v̇ = Σ F_h,i − F_dx − ρ_s m g                             longitudinal dynamics
(9)  r_d = r0 − Δr,  Δr = F_z / (2π p_t √(b_t r0 / 2))          (Guskov 1988, p_t in Pa)

Kinematics in turns (beyond the paper, which drives straight)
-------------------------------------------------------------
The reference point of v is the centre of the rear axle; the path
curvature κ [1/m] of that point is positive in a left (counter-clockwise)
turn, κ = ψ̇ / v with the body yaw rate ψ̇ and the signed speed v, so the same
κ describes the same circle forwards and in reverse.  With no lateral slip
of the rigid body, each wheel's ground speed along its own heading is
v_i = k_i(κ)·v (:func:`wheel_speed_factors`, b the track width, L the
wheelbase, front wheels steered to roll without side slip):

    k_RL,RR = 1 ∓ κb/2,     k_FL,FR = √((1 ∓ κb/2)² + (κL)²)

and a front wheel's longitudinal force acts along the wheel, at the steer
angle δ_i to the body axis, cos δ_i = (1 ∓ κb/2)/k_i: eq. 8 becomes
m v̇ = Σ F_h,i cos δ_i − F_dx − ρ_s m g.  (The along-body components of the
front lateral force and of the centripetal acceleration of the centre of
mass cancel to first order in κ and are left out.)  κ is the model's input
u[6]; without it (six inputs) κ = 0, the paper's straight-line model.

Vertical loads come from the measured front-axle load F_zf: each front wheel
carries F_zf/2 and each rear wheel (m g + F_dx tan β − F_zf)/2 (paper section
3.1: "the rear wheel vertical force can then be calculated using vehicle
parameters"; β the line of pull above the horizontal at the hitch,
``pull_angle_deg``: the implement's pull has a vertical component
F_dx tan β that the ground takes through the rear axle, ASABE D497.7 4.1.4;
β = 0, the paper's horizontal pull, gives (m g − F_zf)/2).

Lateral load transfer (beyond the paper, which drives straight): in a turn
the centripetal acceleration a_y = v²κ acts at the centre of gravity, h_cg
above the ground, and the roll moment m a_y h_cg moves load from the inner
to the outer wheels.  Each axle's left–right difference carries its share:

    F_z,FL/FR = F_zf/2 ∓ δ_f,   F_z,RL/RR = F_zr/2 ∓ δ_r,
    δ_f = λ_f m v²κ h_cg / b,   δ_r = (1 − λ_f) m v²κ h_cg / b

(κ > 0 a left turn: the right wheels are outer), so that the moments about
the vehicle's centre line, (δ_f + δ_r) b, balance m a_y h_cg (a rigid
body in a steady turn; roll of the body on its tyres and springs moves the
centre of gravity by a few centimetres and is left out).  λ_f is the
declared ``front_roll_share`` (default 0.25: a pivoting front axle carries
only its lateral force times the pivot height, :mod:`tractionecu.config`); a
chassis with springs or a rigid front axle shares the moment by the axles'
roll stiffness.  Each δ is limited to 0.9 of the wheel's axle share (the
inner wheel lifting off is outside the model).  Each wheel's rolling radius
follows its own load through eq. 9.  v is each state's own speed at the
start of the step (the loads are held over a step, as the axle loads are);
a_y at the rear-axle centre stands for the centre of gravity's (they differ
by the wheelbase's part of the yaw acceleration, zero in a steady turn).

Declared drivetrain (beyond the paper, whose motors act on the wheels
without losses): the estimator maps the reported motor torque to the wheel
torque M_d = η M_motor (M_motor/η braking), η the declared
``drivetrain.efficiency`` (:mod:`tractionecu.estimation.estimator`), and a
declared ``drivetrain.rolling_radius_m`` (the wheel-speed distance
calibration: the rear wheels' rolling radius at their static load)
replaces eq. 9's deflection stiffness 2π p_t √(b_t r0/2) by the one that
calibration measures, k = F_z,static/(r0 − r_cal), so that eq. 9 goes through
r0 unloaded and r_cal at the static load (:func:`radius_law`; all four wheels
carry the same tyre in this model).
Rolling resistances act against the direction of motion (sign of ω resp. v).

Tyre carcass (beyond the paper, whose μ is a random walk, "their dynamics
neglected"): with a declared longitudinal carcass stiffness c_x
(``tyre_carcass_stiffness_npm`` > 0) the ground force builds up through the
carcass as in Pacejka's first-order transient slip model (Pacejka 2006,
"Tyre and Vehicle Dynamics", ch. 7): the force follows the slip with the
relaxation length L_r = C_Fκ/c_x (C_Fκ the slip stiffness), so that

    μ̇_i = c_x |k_i v| (s_i − σ̄_i) / F_z,i

with s_i eq. 6 of ω_i against the wheel's ground speed k_i v̄ and σ̄_i the
relaxed slip, which follows s_i at the rate |k_i v|/L_r (the estimator moves
it between steps, :meth:`tractionecu.estimation.estimator.Estimator._relax`,
and revises it with the speed when an update revises v,
:meth:`~tractionecu.estimation.estimator.Estimator._revise_relaxed`; here it is
held over a step).  v̄ is the filter's mean speed at the start of
the step, the same for every sigma point: the vehicle's speed hardly moves
over the carcass's time scales (its mass is two orders above the wheel's
equivalent), and a v that entered the carcass term would let the wheel
speeds' ring "measure" v through the exactly-known σ̄ (on the physical truth
that biased v by 3 % and slip by −0.03).  At steady slip σ̄ = s and μ is the paper's
random walk; a slip change moves μ through the carcass spring r² c_x at
once, so the filter predicts the wheel-on-carcass oscillation from the
wheel speeds and the torque instead of following it from the innovations.
c_x = 0 (the default) is the paper's model, unchanged bit for bit.

Two-inertia hub (beyond the paper, whose wheel is one rigid inertia J_w in
eq. 2): on a hub drive the motor drives the wheel through the planetary
reduction, whose gear meshes, carrier, hub and rim are a torsional spring k
with a damper c, and the wheel-speed pickup sits on the motor shaft.  With
a declared ``drivetrain.hub_stiffness_nmprad`` (and the motor side's
inertia J_m, the wheel side J_w = ``wheel_inertia_kgm2`` − J_m) the filter
carries the standard two-mass drive-line model (e.g. Schröder 2009,
"Elektrische Antriebe – Regelung von Antriebssystemen", ch. 18, the
two-mass system; Ellis 2012, "Control System Design Guide", ch. 16,
resonance of a compliant load), all quantities reflected to the wheel:

    J_m ω̇_m,i = M_d,i − M_h,i                         motor side (M_d = η M − c_d ω_m)
    J_w ω̇_w,i = M_h,i − r_d,i F_h,i − r_d,i ρ_t F_z,i sign(ω_w,i)    eq. 2 at the rim
    θ̇_i = ω_m,i − ω_w,i,   M_h,i = k θ_i + c (ω_m,i − ω_w,i)

State (18, :data:`N_STATE_HUB`): x[0:4] are the motor speeds ω_m,i (what the
pickup measures, so the output y = (x[0:4], v) is unchanged), x[4:10] as in
the paper, x[10:14] the rim speeds ω_w,i and x[14:18] the twists θ_i [rad].
The carcass term's slip is the rim's.  J_m + J_w = J and k → ∞ give back
eq. 2.  The hub's mode (≈ 14–16 Hz on the physical truth) is integrated
with RK4 in sub-steps of at most 0.5/ω_max (:func:`hub_substeps`), well
inside RK4's stability bound (ω h < 2.8).

Period-mean wheel speeds (beyond the paper, whose wheel speeds are samples
of ω): an ECU that measures speed by period counting reports the angle the
toothed ring turned over its sample period T, over T, the mean speed of the
period; at 100 Hz that is the speed ≈ 5 ms earlier, at 20 Hz a mean over
50 ms, which lags the carcass mode (5.8–6.5 Hz) by π f_c T ≈ 1 rad.  The
period-mean filter (26 states) takes the sample for what it is: x[18:22]
are the angles φ_i the motors turned since the last sample, φ̇_i = ω_m,i
(by the trapezoid over each step), the measurement is φ_i = T ω̄_i with
R_ω T², and after each sample φ_i restarts from 0, known exactly (its rows
and columns of P zeroed; the standard treatment of an integrating sensor,
e.g. Gelb 1974, "Applied Optimal Estimation", ch. 4 on augmented states, or
the delta-range measurements of GNSS/INS filters).  Over 50 ms between
samples the carcass's relaxed slips σ̄_i can no longer be moved outside the
filter from its mean after each step (a loop the filter does not see: at
20 Hz it rang the filter's own carcass mode until the gate rejected the
samples); they are states too, x[22:26], each sigma point relaxing its own
towards the slips of its rims' mean speed over the step, against the mean
speed v̄ as the carcass term (:func:`_rk4_hub_pm`).
"""

from __future__ import annotations

import math
import os

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..config import MAX_DEFLECTION, G, VehicleParams

JIT_ENV = "TRACTIONECU_JIT"
"""Environment variable: ``0`` runs the filter core in plain numpy even when numba is installed."""


def _load_njit():
    if os.environ.get(JIT_ENV, "1").strip().lower() in ("0", "false", "no", "off"):
        return None
    try:
        from numba import njit
    except ImportError:  # pragma: no cover - numba is a dependency; the numpy path stays as fallback
        return None
    return njit


njit = _load_njit()
"""``numba.njit`` when the compiled filter core is in use, else None (plain numpy)."""
JIT = njit is not None


def compiled(fn, inline: bool = False):
    """``fn`` compiled with numba (cached on disk when a cache directory is writable, in the directory of its
    module's version: :mod:`.jitcache`), or ``fn`` itself without numba.  Float division by zero gives inf/NaN
    as in numpy (``error_model="numpy"``)."""
    if njit is None:
        return fn
    import inspect

    from numba.core import config as numba_config

    from .jitcache import kernel_cache_dir

    kw = {"error_model": "numpy", "inline": "always" if inline else "never"}
    saved = numba_config.CACHE_DIR
    # numba picks the cache directory when the function is decorated (its locator keeps it)
    numba_config.CACHE_DIR = kernel_cache_dir(inspect.getfile(fn)) or saved
    try:
        return njit(cache=True, **kw)(fn)
    except RuntimeError:     # numba found no writable cache directory (see README): compile per process
        return njit(**kw)(fn)
    finally:
        numba_config.CACHE_DIR = saved

N_WHEELS = 4
WHEELS = ("FL", "FR", "RL", "RR")

# State and input layout of the estimator (paper section 3.1).
IX_OMEGA = slice(0, 4)
IX_V = 4
IX_MU = slice(5, 9)
IX_RHO = 9
N_STATE = 10
IU_MD = slice(0, 4)
IU_FZF = 4
IU_FDX = 5
IU_KAPPA = 6
N_INPUT = 7
STATE_NAMES = ("omega_FL", "omega_FR", "omega_RL", "omega_RR", "v", "mu_FL", "mu_FR", "mu_RL", "mu_RR", "rho_s")
IX_OMEGA_W = slice(10, 14)
"""Rim speeds ω_w,i of the two-inertia hub (module doc "Two-inertia hub")."""
IX_TWIST = slice(14, 18)
"""Hub twists θ_i [rad] at the wheel side (module doc "Two-inertia hub")."""
N_STATE_HUB = 18
IX_PMEAN = slice(18, 22)
"""Angles φ_i [rad] the motors turned since the last wheel-speed sample (module doc "Period-mean wheel
speeds")."""
IX_RELAX = slice(22, 26)
"""Relaxed slips σ̄_i [-] of the carcass model, filter states of the period-mean filter (module doc)."""
N_STATE_PMEAN = 26
HUB_STEP_WH = 0.5
"""Largest ω_max·h of one RK4 sub-step of the hub model [-] (:func:`hub_substeps`)."""


def tyre_deflection(fz: ArrayLike, params: VehicleParams) -> NDArray[np.float64]:
    """Tyre deflection Δr [m] from vertical load F_z [N] (paper eq. 9, p_t in Pa; the declared rolling
    radius's stiffness when given, :func:`radius_law`)."""
    fz = np.asarray(fz, dtype=float)
    return np.clip(fz, 0.0, None) / radius_law(params)[1]


def rolling_radius(fz: ArrayLike, params: VehicleParams) -> NDArray[np.float64]:
    """Dynamic rolling radius r_d = r0 − Δr(F_z) [m], Δr limited to 30 % of r0 (:func:`radius_law`)."""
    r0 = radius_law(params)[0]
    return r0 - np.minimum(tyre_deflection(fz, params), MAX_DEFLECTION * params.r0_m)


def radius_law(params: VehicleParams) -> tuple[float, float]:
    """(r0 [m], k [N/m]) of r_d = r0 − F_z/k (eq. 9).

    Eq. 9's k = 2π p_t √(b_t r0/2), unless the vehicle declares
    ``drivetrain.rolling_radius_m`` r_cal > 0 (module doc): then the line
    through r0 at no load and r_cal at the rear wheels' static load
    F_s = (1 − f_front) m g/2, k = F_s/(r0 − r_cal).  A declared r_cal ≥ r0
    (no deflection explains it) keeps eq. 9's k and moves r0 to r_cal + F_s/k.
    """
    k = 2.0 * math.pi * params.tyre_pressure_pa * math.sqrt(params.tyre_width_m / 2.0 * params.r0_m)
    dt = getattr(params, "drivetrain", None)
    r_cal = getattr(dt, "rolling_radius_m", 0.0) if dt is not None else 0.0
    if not r_cal > 0.0:
        return params.r0_m, k
    f_s = 0.5 * (1.0 - params.static_front_fraction) * params.weight_n
    if r_cal < params.r0_m:
        return params.r0_m, f_s / (params.r0_m - r_cal)
    return r_cal + f_s / k, k


def wheel_loads(fzf: ArrayLike, params: VehicleParams, weight_n: float | None = None) -> NDArray[np.float64]:
    """Per-wheel vertical loads (..., 4) [N] from the front-axle load F_zf [N]."""
    fzf = np.asarray(fzf, dtype=float)
    w = params.weight_n if weight_n is None else weight_n
    front = 0.5 * fzf
    rear = 0.5 * (w - fzf)
    return np.stack([front, front, rear, rear], axis=-1)


def wheel_speed_factors(kappa: ArrayLike, track_m: float, wheelbase_m: float) -> NDArray[np.float64]:
    """Ground speed of each wheel over the rear-axle centre's speed, (..., 4) FL, FR, RL, RR [-] (module doc).

    ``kappa`` [1/m] is the path curvature of the rear-axle centre, positive
    in a left turn, for either sign of v.
    """
    k = np.asarray(kappa, dtype=float)
    h = 0.5 * track_m * k
    lk = wheelbase_m * k
    left, right = 1.0 - h, 1.0 + h
    return np.stack([np.sqrt(left * left + lk * lk), np.sqrt(right * right + lk * lk), left, right], axis=-1)


def wheel_speed_factor_slopes(kappa: float, track_m: float, wheelbase_m: float) -> tuple[float, float, float, float]:
    """∂k_i/∂κ [m] of :func:`wheel_speed_factors` at one κ (FL, FR, RL, RR)."""
    h = 0.5 * track_m
    left, right = 1.0 - h * kappa, 1.0 + h * kappa
    lk = wheelbase_m * kappa
    kfl = math.sqrt(left * left + lk * lk)
    kfr = math.sqrt(right * right + lk * lk)
    return ((-h * left + wheelbase_m * lk) / kfl, (h * right + wheelbase_m * lk) / kfr, -h, h)


def slip(omega: ArrayLike, v: ArrayLike, r_d: ArrayLike, eps: float = 1e-6) -> NDArray[np.float64]:
    """Two-branch slip (paper eq. 6) in [−1, 1].

    s = 1 − |v|/(r_d|ω|)  if |v| ≤ r_d|ω|   (driving; s = 1 spinning on the spot)
    s = −1 + r_d|ω|/|v|   if |v| > r_d|ω|   (braking; s = −1 locked wheel)
    Both speeds ≈ 0 gives s = 0.
    """
    vw = np.abs(np.asarray(r_d, dtype=float) * np.asarray(omega, dtype=float))
    va = np.abs(np.asarray(v, dtype=float))
    vw, va = np.broadcast_arrays(vw, va)
    with np.errstate(divide="ignore", invalid="ignore"):
        drive = 1.0 - va / vw
        brake = -1.0 + vw / va
    s = np.where(va <= vw, drive, brake)
    return np.where(np.maximum(vw, va) < eps, 0.0, s)


def traction_efficiency(kappa: ArrayLike, rho: ArrayLike, s: ArrayLike) -> NDArray[np.float64]:
    """Traction efficiency η = κ/(κ+ρ)·(1 − s) (paper eq. 7), ρ the total rolling resistance."""
    kappa = np.asarray(kappa, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return kappa / (kappa + np.asarray(rho, dtype=float)) * (1.0 - np.asarray(s, dtype=float))


class FilterModel:
    """Continuous-time model of the AUKF-FS state x = (ω1..4, v, μ1..4, ρ_s).

    Inputs u = (M_d1..4 [N·m], F_zf [N], F_dx [N]).  μ and ρ_s are modelled as
    constant over one step (paper: "their dynamics are neglected"), so their
    derivatives are zero; process noise lets them move between steps.  With a
    declared carcass stiffness μ̇ is the carcass term (module doc "Tyre carcass").
    """

    def __init__(self, params: VehicleParams):
        self.params = params
        self.m = params.mass_kg
        self.J = params.wheel_inertia_kgm2
        self.rho_t = params.rho_t
        # Constants of the compiled step: m g, the deflection stiffness of eq. 9, the 30 % limit, r0, ρ_t, J, m,
        # half the track width, the wheelbase.
        # (r0 and k of eq. 9, or of the declared rolling radius: radius_law), tan β of the line of pull.
        r0, k = radius_law(params)
        self.tan_pull = math.tan(math.radians(params.pull_angle_deg))
        # Tyre carcass (module doc "Tyre carcass"): c_x, the relaxed slips σ̄_i and the speed v̄ they are taken
        # against (kc[10], kc[11:15], kc[15]).
        self.cx = float(getattr(params, "tyre_carcass_stiffness_npm", 0.0))
        # Lateral load transfer (module doc): δ_f, δ_r per unit lateral acceleration, λ_f m h_cg/b and
        # (1 − λ_f) m h_cg/b [N/(m/s²)] (kc[16], kc[17]).
        lat = self.m * params.cg_height_m / params.track_width_m
        lam = float(getattr(params, "front_roll_share", 0.0))
        self._kc = np.array([params.weight_n, k, MAX_DEFLECTION * params.r0_m, r0, self.rho_t, self.J, self.m,
                             0.5 * params.track_width_m, params.wheelbase_m, self.tan_pull, self.cx,
                             0.0, 0.0, 0.0, 0.0, 0.0, lam * lat, (1.0 - lam) * lat])
        # Two-inertia hub (module doc): (k, c, J_m, J_w, ω_max) or None.
        hub = getattr(params, "hub_two_inertia", None)
        self.hub = hub
        self._hc = np.zeros(5)
        if hub is not None:
            k_h, c_h, jm, jw = hub
            self._hc[:4] = hub
            self._hc[4] = hub_max_rate(k_h, c_h, jm, jw, params.r0_m, self.cx)
        self._fzf_key: tuple[float, float] | None = None
        self._floats = (math.nan,) * 4
        self._consts: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None = None

    def loads(self, u: NDArray[np.float64], v: ArrayLike | None = None
              ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(F_z (..., 4) [N], r_d (..., 4) [m]) from the inputs (rear: + F_dx tan β / 2 each, module doc) and,
        given the speed v [m/s] (..., ) and a curvature input, the lateral load transfer (module doc)."""
        fz = wheel_loads(u[..., IU_FZF], self.params)
        if self.tan_pull != 0.0:          # same operations as load_floats()
            fr = 0.5 * ((self.params.weight_n - u[..., IU_FZF]) + u[..., IU_FDX] * self.tan_pull)
            fz[..., 2] = fr
            fz[..., 3] = fr
        if v is not None and u.shape[-1] > IU_KAPPA:
            fz = self.lateral_loads(fz, v, u[..., IU_KAPPA])
        return fz, rolling_radius(fz, self.params)

    def lateral_loads(self, fz: NDArray[np.float64], v: ArrayLike, kappa: ArrayLike) -> NDArray[np.float64]:
        """Wheel loads (..., 4) [N] of axle-split loads ``fz`` with the lateral load transfer at speed v [m/s] and
        path curvature κ [1/m] (module doc; the operations of the compiled :func:`_lat_shift`)."""
        kap = np.asarray(kappa, dtype=float)
        v = np.asarray(v, dtype=float)
        if not np.any(kap != 0.0):
            return fz
        a = (v * v) * kap
        out = np.array(np.broadcast_to(fz, np.broadcast_shapes(fz.shape, a.shape + (4,))), dtype=float)
        for j, c in ((0, self._kc[16]), (2, self._kc[17])):
            half = out[..., j]
            lim = 0.9 * half
            d = np.minimum(np.maximum(c * a, -lim), lim)
            out[..., j + 1] = half + d
            out[..., j] = half - d
        return out

    def rhs(self, x: NDArray[np.float64], u: NDArray[np.float64], fz: NDArray[np.float64] | None = None,
            r_d: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        """dx/dt for states x (..., 10) under input u (6,) or (..., 6); the loads, when not given, with the lateral
        load transfer at the states' own speeds."""
        if fz is None or r_d is None:
            fz, r_d = self.loads(u, x[..., IX_V])
        omega = x[..., IX_OMEGA]
        v = x[..., IX_V]
        mu = x[..., IX_MU]
        rho_s = x[..., IX_RHO]
        md = u[..., IU_MD]
        fh = mu * fz                                                   # eq. 4
        domega = (md - r_d * fh - r_d * self.rho_t * fz * np.sign(omega)) / self.J   # eq. 2
        if u.shape[-1] > IU_KAPPA:                                     # front forces along the steered wheels
            c = self.front_cosines(u[..., IU_KAPPA])
            fx = fh[..., 0] * c[..., 0] + fh[..., 1] * c[..., 1] + fh[..., 2] + fh[..., 3]
        else:
            fx = fh.sum(axis=-1)
        dv = (fx - u[..., IU_FDX] - rho_s * self.m * G * np.sign(v)) / self.m  # eq. 8
        dx = np.zeros(np.broadcast_shapes(x.shape, u.shape[:-1] + (N_STATE,)))
        dx[..., IX_OMEGA] = domega
        dx[..., IX_V] = dv
        if self.cx != 0.0:                                             # the carcass (module doc)
            if u.shape[-1] > IU_KAPPA:
                kw = wheel_speed_factors(u[..., IU_KAPPA], self.params.track_width_m, self.params.wheelbase_m)
            else:
                kw = np.ones(4)
            vi = kw * self._kc[15]
            dx[..., IX_MU] = self.cx * np.abs(vi) * (slip(omega, vi, r_d) - self._kc[11:15]) / fz
        return dx

    @property
    def relaxed_slip(self) -> NDArray[np.float64]:
        """σ̄_i (4,) of the carcass model [-] (a view: :meth:`set_relaxed_slip` changes it)."""
        return self._kc[11:15]

    def set_carcass(self, on: bool) -> None:
        """Switch the carcass term of μ̇ on (the declared c_x) or off (μ̇ = 0, the paper's model)."""
        self.cx = float(getattr(self.params, "tyre_carcass_stiffness_npm", 0.0)) if on else 0.0
        self._kc[10] = self.cx

    def set_relaxed_slip(self, sbar, v_ref: float | None = None) -> None:
        """Set the relaxed slips σ̄_i (4,) that the carcass term of μ̇ relaxes against and, when given, the
        speed v̄ [m/s] the slips are taken against in that term (module doc)."""
        self._kc[11:15] = sbar
        if v_ref is not None:
            self._kc[15] = v_ref

    def front_cosines(self, kappa: ArrayLike) -> NDArray[np.float64]:
        """cos δ of the front wheels FL, FR (..., 2) at path curvature κ [1/m] (module doc); 1 at κ = 0."""
        k = np.asarray(kappa, dtype=float)
        h = 0.5 * self.params.track_width_m * k
        lk = self.params.wheelbase_m * k
        left, right = 1.0 - h, 1.0 + h
        return np.stack([left / np.sqrt(left * left + lk * lk), right / np.sqrt(right * right + lk * lk)], axis=-1)

    def load_floats(self, fzf: float, fdx: float = 0.0) -> tuple[float, float, float, float]:
        """(F_z front, F_z rear [N], r_d front, r_d rear [m]) of one front-axle load F_zf [N] and draft
        F_dx [N] (used with a line of pull β ≠ 0 only, module doc).

        Plain floats, equal to :func:`wheel_loads` and :func:`rolling_radius`
        (same operations, bit for bit); the last (F_zf, F_dx) is cached.
        """
        tb = self.tan_pull
        key = (fzf, fdx if tb != 0.0 else 0.0)
        if key != self._fzf_key:
            w_n, k, lim, r0 = self._kc[0], self._kc[1], self._kc[2], self._kc[3]
            ff = 0.5 * fzf
            fr = 0.5 * (w_n - fzf) if tb == 0.0 else 0.5 * ((w_n - fzf) + fdx * tb)
            rd = []
            for fz in (ff, fr):
                d = (0.0 if fz <= 0.0 else fz) if not fz > 0.0 else fz    # clip(F_z, 0, None), NaN kept
                d = d / k
                rd.append(r0 - (lim if d > lim else d))
            self._floats = (float(ff), float(fr), float(rd[0]), float(rd[1]))
            self._fzf_key = key
            self._consts = None
        return self._floats

    def _load_terms(self, fzf: float, fdx: float = 0.0
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """(F_z, r_d, r_d ρ_t F_z) arrays (4,) for one front-axle load and draft, kept until they change."""
        ff, fr, rdf, rdr = self.load_floats(fzf, fdx)
        if self._consts is None:
            fz = np.array([ff, ff, fr, fr])
            r_d = np.array([rdf, rdf, rdr, rdr])
            self._consts = (fz, r_d, r_d * self.rho_t * fz)
        return self._consts

    def step(self, x: NDArray[np.float64], u: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
        """One RK4 step of length dt [s] for all states at once (paper section 3.1).

        With μ, ρ_s and u held over the step, ω̇ and v̇ depend on ω and v only
        through sign(ω) and sign(v) (rolling resistance against the motion).
        When no state's ω or v changes sign within the step (checked on the
        stage states x + dt/2·k1 and x + dt·k1), all four RK4 stages are equal,
        k1 = k2 = k3 = k4, and the step is evaluated from k1 alone with the
        same arithmetic as :func:`rk4`, so the result is bit for bit the full
        RK4 step.  Otherwise the four stages are evaluated.  With numba (see
        :data:`JIT`) the four stages run compiled, in the same operation order.
        """
        if u.ndim != 1 or x.ndim > 2 or x.shape[-1] != N_STATE:
            fz, r_d = self.loads(u, x[..., IX_V])
            return rk4(lambda y: self.rhs(y, u, fz, r_d), x, dt)
        if JIT and x.dtype == np.float64 and u.dtype == np.float64 and u.shape[0] in (N_INPUT - 1, N_INPUT):
            # Compiled RK4 (all four stages, same operation order as rk4(rhs)).
            if x.ndim == 1:
                return _rk4_points(np.ascontiguousarray(x).reshape(1, N_STATE), np.ascontiguousarray(u),
                                   self._kc, float(dt))[0]
            return _rk4_points(np.ascontiguousarray(x), np.ascontiguousarray(u), self._kc, float(dt))
        if (u.shape[0] > IU_KAPPA and u[IU_KAPPA] != 0.0) or self.cx != 0.0:   # in a turn, or μ̇ ≠ 0: general
            fz, r_d = self.loads(u, x[..., IX_V])
            return rk4(lambda y: self.rhs(y, u, fz, r_d), x, dt)
        fz, r_d, c = self._load_terms(float(u[IU_FZF]), float(u[IU_FDX]))
        k = np.empty(x.shape[:-1] + (5,))
        fh = x[..., IX_MU] * fz                                          # eq. 4
        kom = k[..., IX_OMEGA]
        np.subtract(u[IU_MD], r_d * fh, out=kom)                         # eq. 2
        kom -= c * np.sign(x[..., IX_OMEGA])
        kom /= self.J
        kv = k[..., IX_V]
        np.subtract(fh.sum(axis=-1), u[IU_FDX], out=kv)                  # eq. 8
        kv -= x[..., IX_RHO] * self.m * G * np.sign(x[..., IX_V])
        kv /= self.m
        x5 = x[..., :5]
        y = dt * k
        y += x5
        y *= x5
        if not (y > 0.0).all():      # a sign change (or a zero / non-finite speed): all four stages
            return rk4(lambda y: self.rhs(y, u, fz, r_d), x, dt)
        k2 = 2.0 * k
        s = k + k2                   # k1 + 2 k2 + 2 k3 + k4 with k1 = k2 = k3 = k4, same order as rk4()
        s += k2
        s += k
        s *= dt / 6.0
        out = x + dt / 6.0 * 0.0     # the zero increment of μ and ρ_s, as in rk4()
        out[..., :5] += s
        return out

    def outputs(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """y = h(x) = (ω1..4, v)."""
        return x[..., :5]

    def rhs_hub(self, x: NDArray[np.float64], u: NDArray[np.float64], fz: NDArray[np.float64] | None = None,
                r_d: NDArray[np.float64] | None = None, sbar: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        """dx/dt of the two-inertia hub model (module doc), x (..., 18), u (7,) or (6,); numpy.  The loads, when
        not given, with the lateral load transfer at the states' own speeds; the carcass term's relaxed slips
        σ̄ the model's, or ``sbar`` (..., 4) (each row's own: the period-mean filter's)."""
        k_h, c_h, jm, jw = self.hub
        if fz is None or r_d is None:
            fz, r_d = self.loads(u, x[..., IX_V])
        wm = x[..., IX_OMEGA]
        ww = x[..., IX_OMEGA_W]
        mh = k_h * x[..., IX_TWIST] + c_h * (wm - ww)
        fh = x[..., IX_MU] * fz                                        # eq. 4
        dx = np.zeros(x.shape)
        dx[..., IX_OMEGA] = (u[..., IU_MD] - mh) / jm
        dx[..., IX_OMEGA_W] = (mh - r_d * fh - r_d * self.rho_t * fz * np.sign(ww)) / jw    # eq. 2 at the rim
        dx[..., IX_TWIST] = wm - ww
        if u.shape[-1] > IU_KAPPA:
            c = self.front_cosines(u[..., IU_KAPPA])
            fx = fh[..., 0] * c[..., 0] + fh[..., 1] * c[..., 1] + fh[..., 2] + fh[..., 3]
            kw = wheel_speed_factors(u[..., IU_KAPPA], self.params.track_width_m, self.params.wheelbase_m)
        else:
            fx = fh.sum(axis=-1)
            kw = np.ones(4)
        dx[..., IX_V] = (fx - u[..., IU_FDX] - x[..., IX_RHO] * self.m * G * np.sign(x[..., IX_V])) / self.m  # eq. 8
        if self.cx != 0.0:
            vi = kw * self._kc[15]
            sb = self._kc[11:15] if sbar is None else sbar
            dx[..., IX_MU] = self.cx * np.abs(vi) * (slip(ww, vi, r_d) - sb) / fz
        return dx

    def step_hub_pm(self, x: NDArray[np.float64], u: NDArray[np.float64], dt: float, a: float, p: float,
                    al1: float, al2: float, c0: float, lmin: float, lmax: float, ldef: float) -> NDArray[np.float64]:
        """The period-mean filter's process model for sigma points x (N, 26) over dt [s] (module doc
        "Period-mean wheel speeds"; the relaxation's curve a, p, α1, α2, c0 and length bounds as
        :func:`relax_slips_own` takes them): compiled (:func:`_rk4_hub_pm`), else numpy, the same steps."""
        n = hub_substeps(float(self._hc[4]), dt)
        ff, fr, rdf, rdr = self.load_floats(float(u[4]), float(u[5]))
        kap = float(u[IU_KAPPA]) if u.shape[0] > IU_KAPPA else 0.0
        if JIT and x.dtype == np.float64 and u.dtype == np.float64:
            return _rk4_hub_pm(np.ascontiguousarray(x), np.ascontiguousarray(u), self._kc, self._hc, float(dt), n,
                               ff, fr, rdf, rdr, a, p, al1, al2, c0, lmin, lmax, ldef, kap)
        y = self.step_hub(x[:, :N_STATE_HUB], u, dt, sbar=x[:, IX_RELAX])
        out = np.empty(x.shape)
        out[:, :N_STATE_HUB] = y
        out[:, IX_PMEAN] = x[:, IX_PMEAN] + (0.5 * dt) * (x[:, IX_OMEGA] + y[:, IX_OMEGA])
        kk = self._kc.copy()
        xs = np.empty(N_STATE)
        for j in range(x.shape[0]):                    # the relaxation of each row's own σ̄ (a scalar kernel)
            kk[11:15] = x[j, IX_RELAX]
            xs[:] = y[j, :N_STATE]
            xs[IX_OMEGA] = 0.5 * (x[j, IX_OMEGA_W] + y[j, IX_OMEGA_W])
            xs[IX_V] = self._kc[15]
            _relax_slips(xs, kk, kap, float(dt), ff, fr, rdf, rdr, a, p, al1, al2, c0, lmin, lmax, ldef, False, True)
            out[j, IX_RELAX] = kk[11:15]
        return out

    def step_hub(self, x: NDArray[np.float64], u: NDArray[np.float64], dt: float,
                 sbar: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        """RK4 over dt [s] in :func:`hub_substeps` sub-steps for the two-inertia hub states x (N, 18) (module
        doc); compiled with numba (:func:`_rk4_hub`), else numpy (:meth:`rhs_hub`; with ``sbar`` (N, 4) each
        row's own relaxed slips in the carcass term, always numpy: :meth:`step_hub_pm`'s fallback)."""
        n = hub_substeps(float(self._hc[4]), dt)
        if JIT and sbar is None and x.ndim == 2 and x.dtype == np.float64 and u.dtype == np.float64:
            return _rk4_hub(np.ascontiguousarray(x), np.ascontiguousarray(u), self._kc, self._hc, float(dt), n)
        h = dt / n
        y = np.array(x, dtype=float)
        fz, r_d = self.loads(u, y[..., IX_V])          # held over the step (module doc)
        for _ in range(n):
            y = rk4(lambda z: self.rhs_hub(z, u, fz, r_d, sbar), y, h)
        return y


def hub_max_rate(k: float, c: float, jm: float, jw: float, r0: float, cx: float) -> float:
    """An upper bound of the two-inertia hub's fastest rate [1/s]: the undamped natural frequencies are at
    most √max(2k/J_m, (2k + r0² c_x)/J_w) (Gershgorin's bound on J⁻¹K, the carcass r0² c_x a spring to the
    ground), the damped decay rate at most c (1/J_m + 1/J_w)."""
    return max(math.sqrt(max(2.0 * k / jm, (2.0 * k + r0 * r0 * cx) / jw)), c * (1.0 / jm + 1.0 / jw))


def hub_substeps(w_max: float, dt: float) -> int:
    """Number of RK4 sub-steps over dt [s] so that w_max·h ≤ :data:`HUB_STEP_WH`."""
    return max(1, int(math.ceil(w_max * dt / HUB_STEP_WH - 1e-9)))


def rk4(f, x: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
    """Classical fourth-order Runge–Kutta step for an autonomous f(x)."""
    k1 = f(x)
    k2 = f(x + 0.5 * dt * k1)
    k3 = f(x + 0.5 * dt * k2)
    k4 = f(x + dt * k3)
    return x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def _sign(a: float) -> float:
    """np.sign of one float: ±1, 0 for ±0, NaN for NaN."""
    if a > 0.0:
        return 1.0
    if a < 0.0:
        return -1.0
    if a == 0.0:
        return 0.0
    return a


def _rhs5(w0, w1, w2, w3, v, mu0, mu1, mu2, mu3, rho, u, lw, J, m, c0, c1):  # pragma: no cover - compiled
    """(ω̇1..4, v̇) of one state, with FilterModel.rhs's operation order.

    lw: the wheels' (F_z (4) [N], r_d (4) [m], r_d ρ_t F_z (4)) (:func:`_wheel_terms`); c0, c1: cos δ of the
    front wheels (1 on a straight path).
    """
    fh0 = mu0 * lw[0]
    fh1 = mu1 * lw[1]
    fh2 = mu2 * lw[2]
    fh3 = mu3 * lw[3]
    if c0 == 1.0 and c1 == 1.0:
        fx = ((fh0 + fh1) + fh2) + fh3
    else:
        fx = ((fh0 * c0 + fh1 * c1) + fh2) + fh3
    return (((u[0] - lw[4] * fh0) - lw[8] * _sign(w0)) / J,
            ((u[1] - lw[5] * fh1) - lw[9] * _sign(w1)) / J,
            ((u[2] - lw[6] * fh2) - lw[10] * _sign(w2)) / J,
            ((u[3] - lw[7] * fh3) - lw[11] * _sign(w3)) / J,
            ((fx - u[5]) - rho * m * G * _sign(v)) / m)


def _lat_shift(c, v, kap, half):                             # pragma: no cover - compiled
    """δ of one axle (module doc "Lateral load transfer"): c (v² κ) within ±0.9 of the wheel's share ``half``."""
    d = c * ((v * v) * kap)
    lim = 0.9 * half
    if d > lim:
        d = lim
    elif d < -lim:
        d = -lim
    return d


def _lateral_on(kc, kap):                                    # pragma: no cover - compiled
    """Whether the lateral load transfer moves the loads at curvature ``kap`` (kc[16], kc[17] declared)."""
    return kap != 0.0 and kc.shape[0] > 17 and (kc[16] != 0.0 or kc[17] != 0.0)


def wheel_radii(kc, u, v, kap, rdf, rdr, out):               # pragma: no cover - compiled
    """out (4,) = each wheel's rolling radius [m] with the lateral load transfer at speed v and curvature kap
    (module doc), from the axle radii ``rdf``, ``rdr`` as the caller scales them (a calibration's factor): r_d,i ×
    its axle's r_d/r_d(axle load) of eq. 9; [rdf, rdf, rdr, rdr] exactly when the transfer does not act.
    kc: FilterModel._kc, u the inputs (F_zf u[4], F_dx u[5]) as in :func:`_rk4_points`."""
    if not _lateral_on(kc, kap):
        out[0] = rdf
        out[1] = rdf
        out[2] = rdr
        out[3] = rdr
        return
    fzf = u[4]
    ff = 0.5 * fzf
    fr = 0.5 * (kc[0] - fzf)
    if kc[9] != 0.0:
        fr = 0.5 * ((kc[0] - fzf) + u[5] * kc[9])
    r0f = _radius(ff, kc[3], kc[1], kc[2])
    r0r = _radius(fr, kc[3], kc[1], kc[2])
    lw = np.empty(12)
    _wheel_terms(kc, True, v, kap, ff, fr, r0f, r0r, lw)
    out[0] = rdf * (lw[4] / r0f)
    out[1] = rdf * (lw[5] / r0f)
    out[2] = rdr * (lw[6] / r0r)
    out[3] = rdr * (lw[7] / r0r)


def _wheel_terms(kc, lat, v, kap, ff, fr, rdf, rdr, lw):    # pragma: no cover - compiled
    """lw (12,) = (F_z (4) [N], r_d (4) [m], r_d ρ_t F_z (4)) of the wheels FL, FR, RL, RR: the axle split
    (ff, fr, their radii rdf, rdr) and, with ``lat``, the lateral load transfer at speed v and curvature kap
    (module doc), each radius from its own load (eq. 9, :func:`_radius`)."""
    if lat:
        df = _lat_shift(kc[16], v, kap, ff)
        dr = _lat_shift(kc[17], v, kap, fr)
        lw[0] = ff - df
        lw[1] = ff + df
        lw[2] = fr - dr
        lw[3] = fr + dr
        for i in range(4):
            lw[4 + i] = _radius(lw[i], kc[3], kc[1], kc[2])
    else:
        lw[0] = ff
        lw[1] = ff
        lw[2] = fr
        lw[3] = fr
        lw[4] = rdf
        lw[5] = rdf
        lw[6] = rdr
        lw[7] = rdr
    for i in range(4):
        lw[8 + i] = lw[4 + i] * kc[4] * lw[i]


def _radius(fz, r0, k, lim):                                  # pragma: no cover - compiled
    """rolling_radius() of one load: r0 − min(max(F_z, 0)/k, lim)."""
    if fz < 0.0:
        fz = 0.0
    d = fz / k
    if d > lim:
        d = lim
    return r0 - d


def _rk4_points(x, u, kc, dt):                              # pragma: no cover - compiled
    """Classical RK4 over dt for every row of x (N, 10), as rk4(FilterModel.rhs) computes it.

    kc = (m g, k of eq. 9, 0.3 r0, r0, ρ_t, J, m, b/2, L, tan β, carcass (6), lateral transfer (2)) (see
    FilterModel._kc).  The stage states of μ and ρ_s are x + h·0 (their derivative is zero), as in rk4().
    u[6], when given, is the path curvature κ (module doc); in a turn each row's loads carry the lateral
    load transfer at that row's v, held over the step.
    """
    w_n, k, lim, r0, rho_t, J, m = kc[0], kc[1], kc[2], kc[3], kc[4], kc[5], kc[6]
    cosl = 1.0
    cosr = 1.0
    if u.shape[0] > 6 and u[6] != 0.0:
        hk = kc[7] * u[6]
        lk = kc[8] * u[6]
        cosl = (1.0 - hk) / math.sqrt((1.0 - hk) * (1.0 - hk) + lk * lk)
        cosr = (1.0 + hk) / math.sqrt((1.0 + hk) * (1.0 + hk) + lk * lk)
    fzf = u[4]
    ff = 0.5 * fzf                     # wheel_loads()
    fr = 0.5 * (w_n - fzf)
    if kc[9] != 0.0:                   # the line of pull's vertical component (module doc)
        fr = 0.5 * ((w_n - fzf) + u[5] * kc[9])
    rdf = _radius(ff, r0, k, lim)
    rdr = _radius(fr, r0, k, lim)
    kap = u[6] if u.shape[0] > 6 else 0.0
    lat = _lateral_on(kc, kap)
    if kc.shape[0] > 10 and kc[10] != 0.0:      # the carcass: μ̇ ≠ 0 (model doc "Tyre carcass")
        return _rk4_carcass(x, u, kc, dt, ff, fr, rdf, rdr, lat, kap, cosl, cosr)
    lw = np.empty(12)
    _wheel_terms(kc, False, 0.0, kap, ff, fr, rdf, rdr, lw)
    npt = x.shape[0]
    out = np.empty_like(x)
    h = 0.5 * dt
    w = dt / 6.0
    zh = h * 0.0
    zd = dt * 0.0
    zw = w * 0.0
    for p in range(npt):
        x0, x1, x2, x3, x4 = x[p, 0], x[p, 1], x[p, 2], x[p, 3], x[p, 4]
        m0, m1, m2, m3, r = x[p, 5], x[p, 6], x[p, 7], x[p, 8], x[p, 9]
        if lat:                                  # the loads at this state's speed (module doc)
            _wheel_terms(kc, True, x4, kap, ff, fr, rdf, rdr, lw)
        a0, a1, a2, a3, a4 = _rhs5(x0, x1, x2, x3, x4, m0, m1, m2, m3, r, u, lw, J, m, cosl, cosr)
        h0, h1, h2, h3, hr = m0 + zh, m1 + zh, m2 + zh, m3 + zh, r + zh
        b0, b1, b2, b3, b4 = _rhs5(x0 + h * a0, x1 + h * a1, x2 + h * a2, x3 + h * a3, x4 + h * a4,
                                   h0, h1, h2, h3, hr, u, lw, J, m, cosl, cosr)
        c0, c1, c2, c3, c4 = _rhs5(x0 + h * b0, x1 + h * b1, x2 + h * b2, x3 + h * b3, x4 + h * b4,
                                   h0, h1, h2, h3, hr, u, lw, J, m, cosl, cosr)
        d0, d1, d2, d3, d4 = _rhs5(x0 + dt * c0, x1 + dt * c1, x2 + dt * c2, x3 + dt * c3, x4 + dt * c4,
                                   m0 + zd, m1 + zd, m2 + zd, m3 + zd, r + zd, u, lw, J, m, cosl, cosr)
        out[p, 0] = x0 + w * (((a0 + 2.0 * b0) + 2.0 * c0) + d0)
        out[p, 1] = x1 + w * (((a1 + 2.0 * b1) + 2.0 * c1) + d1)
        out[p, 2] = x2 + w * (((a2 + 2.0 * b2) + 2.0 * c2) + d2)
        out[p, 3] = x3 + w * (((a3 + 2.0 * b3) + 2.0 * c3) + d3)
        out[p, 4] = x4 + w * (((a4 + 2.0 * b4) + 2.0 * c4) + d4)
        out[p, 5] = m0 + zw
        out[p, 6] = m1 + zw
        out[p, 7] = m2 + zw
        out[p, 8] = m3 + zw
        out[p, 9] = r + zw
    return out


def _mudot(w, v, k, rd, fz, sb, cx):                         # pragma: no cover - compiled
    """μ̇ of one wheel with the carcass: c_x |k v| (s − σ̄)/F_z, s eq. 6 of ω against k·v (as slip())."""
    vi = k * v
    va = abs(vi)
    vw = abs(rd * w)
    if vw < 1e-6 and va < 1e-6:
        s = 0.0
    elif va <= vw:
        s = 1.0 - va / vw
    else:
        s = -1.0 + vw / va
    return ((cx * va) * (s - sb)) / fz


def _rk4_carcass(x, u, kc, dt, ff, fr, rdf, rdr, lat, kap, cosl, cosr):   # pragma: no cover - compiled
    """_rk4_points with the carcass term of μ̇ (kc[10] = c_x ≠ 0, kc[11:15] = σ̄): the four RK4 stages of
    ω, v and μ, as rk4(FilterModel.rhs) computes them; ρ_s as in _rk4_points."""
    J, m, cx = kc[5], kc[6], kc[10]
    lw = np.empty(12)
    _wheel_terms(kc, False, 0.0, kap, ff, fr, rdf, rdr, lw)
    s0, s1, s2, s3, vb = kc[11], kc[12], kc[13], kc[14], kc[15]
    k0 = k1 = k2 = k3 = 1.0
    if u.shape[0] > 6 and u[6] != 0.0:           # wheel_speed_factors()
        hk = kc[7] * u[6]
        lk = kc[8] * u[6]
        left = 1.0 - hk
        right = 1.0 + hk
        k0 = math.sqrt(left * left + lk * lk)
        k1 = math.sqrt(right * right + lk * lk)
        k2 = left
        k3 = right
    npt = x.shape[0]
    out = np.empty_like(x)
    h = 0.5 * dt
    w = dt / 6.0
    zh = h * 0.0
    zd = dt * 0.0
    zw = w * 0.0
    for p in range(npt):
        x0, x1, x2, x3, x4 = x[p, 0], x[p, 1], x[p, 2], x[p, 3], x[p, 4]
        m0, m1, m2, m3, r = x[p, 5], x[p, 6], x[p, 7], x[p, 8], x[p, 9]
        if lat:                                  # the loads at this state's speed (module doc)
            _wheel_terms(kc, True, x4, kap, ff, fr, rdf, rdr, lw)
        a0, a1, a2, a3, a4 = _rhs5(x0, x1, x2, x3, x4, m0, m1, m2, m3, r, u, lw, J, m, cosl, cosr)
        e0 = _mudot(x0, vb, k0, lw[4], lw[0], s0, cx)
        e1 = _mudot(x1, vb, k1, lw[5], lw[1], s1, cx)
        e2 = _mudot(x2, vb, k2, lw[6], lw[2], s2, cx)
        e3 = _mudot(x3, vb, k3, lw[7], lw[3], s3, cx)
        y0, y1, y2, y3, y4 = x0 + h * a0, x1 + h * a1, x2 + h * a2, x3 + h * a3, x4 + h * a4
        n0, n1, n2, n3 = m0 + h * e0, m1 + h * e1, m2 + h * e2, m3 + h * e3
        b0, b1, b2, b3, b4 = _rhs5(y0, y1, y2, y3, y4, n0, n1, n2, n3, r + zh, u, lw, J, m,
                                   cosl, cosr)
        f0 = _mudot(y0, vb, k0, lw[4], lw[0], s0, cx)
        f1 = _mudot(y1, vb, k1, lw[5], lw[1], s1, cx)
        f2 = _mudot(y2, vb, k2, lw[6], lw[2], s2, cx)
        f3 = _mudot(y3, vb, k3, lw[7], lw[3], s3, cx)
        y0, y1, y2, y3, y4 = x0 + h * b0, x1 + h * b1, x2 + h * b2, x3 + h * b3, x4 + h * b4
        n0, n1, n2, n3 = m0 + h * f0, m1 + h * f1, m2 + h * f2, m3 + h * f3
        c0, c1, c2, c3, c4 = _rhs5(y0, y1, y2, y3, y4, n0, n1, n2, n3, r + zh, u, lw, J, m,
                                   cosl, cosr)
        g0 = _mudot(y0, vb, k0, lw[4], lw[0], s0, cx)
        g1 = _mudot(y1, vb, k1, lw[5], lw[1], s1, cx)
        g2 = _mudot(y2, vb, k2, lw[6], lw[2], s2, cx)
        g3 = _mudot(y3, vb, k3, lw[7], lw[3], s3, cx)
        y0, y1, y2, y3, y4 = x0 + dt * c0, x1 + dt * c1, x2 + dt * c2, x3 + dt * c3, x4 + dt * c4
        n0, n1, n2, n3 = m0 + dt * g0, m1 + dt * g1, m2 + dt * g2, m3 + dt * g3
        d0, d1, d2, d3, d4 = _rhs5(y0, y1, y2, y3, y4, n0, n1, n2, n3, r + zd, u, lw, J, m,
                                   cosl, cosr)
        q0 = _mudot(y0, vb, k0, lw[4], lw[0], s0, cx)
        q1 = _mudot(y1, vb, k1, lw[5], lw[1], s1, cx)
        q2 = _mudot(y2, vb, k2, lw[6], lw[2], s2, cx)
        q3 = _mudot(y3, vb, k3, lw[7], lw[3], s3, cx)
        out[p, 0] = x0 + w * (((a0 + 2.0 * b0) + 2.0 * c0) + d0)
        out[p, 1] = x1 + w * (((a1 + 2.0 * b1) + 2.0 * c1) + d1)
        out[p, 2] = x2 + w * (((a2 + 2.0 * b2) + 2.0 * c2) + d2)
        out[p, 3] = x3 + w * (((a3 + 2.0 * b3) + 2.0 * c3) + d3)
        out[p, 4] = x4 + w * (((a4 + 2.0 * b4) + 2.0 * c4) + d4)
        out[p, 5] = m0 + w * (((e0 + 2.0 * f0) + 2.0 * g0) + q0)
        out[p, 6] = m1 + w * (((e1 + 2.0 * f1) + 2.0 * g1) + q1)
        out[p, 7] = m2 + w * (((e2 + 2.0 * f2) + 2.0 * g2) + q2)
        out[p, 8] = m3 + w * (((e3 + 2.0 * f3) + 2.0 * g3) + q3)
        out[p, 9] = r + zw
    return out


def _relax_slips(x, kc, kap, dt, ff, fr, rdf, rdr, a, p, al1, al2, c0, lmin, lmax, ldef, init, own):  # pragma: no cover
    """The relaxation of :func:`relax_slips` (``own`` false) and :func:`relax_slips_own` (``own`` true: the
    slope through each wheel's own μ level, c0 the curve's μ(0⁺)); one body, the operations of each as
    documented there."""
    cx = kc[10]
    k0 = k1 = k2 = k3 = 1.0
    if kap != 0.0:
        hk = kc[7] * kap
        lk = kc[8] * kap
        left = 1.0 - hk
        right = 1.0 + hk
        k0 = math.sqrt(left * left + lk * lk)
        k1 = math.sqrt(right * right + lk * lk)
        k2 = left
        k3 = right
    v = x[4]
    kc[15] = v
    lw = np.empty(12)
    _wheel_terms(kc, _lateral_on(kc, kap), v, kap, ff, fr, rdf, rdr, lw)
    for i in range(4):
        k = k0 if i == 0 else (k1 if i == 1 else (k2 if i == 2 else k3))
        rd = lw[4 + i]
        va = abs(k * v)
        vw = abs(rd * x[i])
        if vw < 1e-6 and va < 1e-6:
            s = 0.0
        elif va <= vw:
            s = 1.0 - va / vw
        else:
            s = -1.0 + vw / va
        sb = kc[11 + i]
        if init or sb != sb:
            kc[11 + i] = s
            continue
        if a == a:
            sa = abs(sb)
            e1 = math.exp(al1 * sa)
            e2 = math.exp(al2 * sa)
            dg = -p * al1 * e1 - (1.0 - p) * al2 * e2
            if own:
                mc = c0 + a * (p * (1.0 - e1) + (1.0 - p) * (1.0 - e2))
                f = 1.0
                if mc > 0.02:
                    f = x[5 + i] / mc
                    f = RELAX_SCALE_BOUNDS[0] if f < RELAX_SCALE_BOUNDS[0] else (
                        RELAX_SCALE_BOUNDS[1] if f > RELAX_SCALE_BOUNDS[1] else f)
                lr = lw[i] * f * a * dg / cx
            else:
                lr = lw[i] * a * dg / cx
            lr = lmin if lr < lmin else (lmax if lr > lmax else lr)
        else:
            lr = ldef
        g = dt * va / lr
        kc[11 + i] = sb + (1.0 if g > 1.0 else g) * (s - sb)


def relax_slips(x, kc, kap, dt, ff, fr, rdf, rdr, a, p, al1, al2, lmin, lmax, ldef, init):  # pragma: no cover
    """Move the relaxed slips σ̄_i = kc[11:15] towards the slips s_i of the state x (Pacejka's first-order
    relaxation, Estimator._relax): σ̄_i += min(1, dt |k_i v|/L_r,i)(s_i − σ̄_i), L_r,i = F_z,i a g'(|σ̄_i|)/c_x
    of the class (p, α1, α2) within [lmin, lmax], ldef when a is NaN (no curve); init (or σ̄ NaN): σ̄ = s.
    s_i is eq. 6 against k_i(κ) v as slip() computes it; F_z,i and r_d,i carry the lateral load transfer at the
    state's v (module doc; ff, fr, rdf, rdr: the axle split)."""
    _relax_slips(x, kc, kap, dt, ff, fr, rdf, rdr, a, p, al1, al2, 0.0, lmin, lmax, ldef, init, False)


def _hub_deriv(y, u, kc, hc, lw, cosl, cosr, kw, d):  # pragma: no cover - compiled
    """dx/dt of one two-inertia hub state y (18,) into d (18,) (FilterModel.rhs_hub, module doc); lw the wheels'
    loads, radii and rolling-resistance torques (:func:`_wheel_terms`)."""
    k_h, c_h, jm, jw = hc[0], hc[1], hc[2], hc[3]
    m = kc[6]
    fx = 0.0
    for i in range(4):
        fz = lw[i]
        rd = lw[4 + i]
        cz = lw[8 + i]
        wm = y[i]
        ww = y[10 + i]
        mh = k_h * y[14 + i] + c_h * (wm - ww)
        fh = y[5 + i] * fz
        d[i] = (u[i] - mh) / jm
        d[10 + i] = ((mh - rd * fh) - cz * _sign(ww)) / jw
        d[14 + i] = wm - ww
        fx += fh * (cosl if i == 0 else (cosr if i == 1 else 1.0))
        if kc[10] != 0.0:
            d[5 + i] = _mudot(ww, kc[15], kw[i], rd, fz, kc[11 + i], kc[10])
        else:
            d[5 + i] = 0.0
    d[4] = ((fx - u[5]) - y[9] * m * G * _sign(y[4])) / m
    d[9] = 0.0


def _rk4_hub(x, u, kc, hc, dt, nsub):                        # pragma: no cover - compiled
    """RK4 of the two-inertia hub model over dt in nsub equal sub-steps for every row of x (N, 18);
    kc: FilterModel._kc (loads, carcass), hc = (k, c, J_m, J_w, ω_max)."""
    w_n, k, lim, r0, rho_t = kc[0], kc[1], kc[2], kc[3], kc[4]
    cosl = 1.0
    cosr = 1.0
    kw = np.ones(4)
    if u.shape[0] > 6 and u[6] != 0.0:
        hk = kc[7] * u[6]
        lk = kc[8] * u[6]
        left = 1.0 - hk
        right = 1.0 + hk
        kw[0] = math.sqrt(left * left + lk * lk)
        kw[1] = math.sqrt(right * right + lk * lk)
        kw[2] = left
        kw[3] = right
        cosl = left / kw[0]
        cosr = right / kw[1]
    fzf = u[4]
    ff = 0.5 * fzf
    fr = 0.5 * (w_n - fzf)
    if kc[9] != 0.0:
        fr = 0.5 * ((w_n - fzf) + u[5] * kc[9])
    rdf = _radius(ff, r0, k, lim)
    rdr = _radius(fr, r0, k, lim)
    kap = u[6] if u.shape[0] > 6 else 0.0
    lat = _lateral_on(kc, kap)
    lw = np.empty(12)
    _wheel_terms(kc, False, 0.0, kap, ff, fr, rdf, rdr, lw)
    npt, n = x.shape
    out = np.empty_like(x)
    h = dt / nsub
    k1 = np.empty(n)
    k2 = np.empty(n)
    k3 = np.empty(n)
    k4 = np.empty(n)
    y = np.empty(n)
    yt = np.empty(n)
    for p in range(npt):
        for j in range(n):
            y[j] = x[p, j]
        if lat:                                  # the loads at this state's speed, held over the step
            _wheel_terms(kc, True, y[4], kap, ff, fr, rdf, rdr, lw)
        for _ in range(nsub):
            _hub_deriv(y, u, kc, hc, lw, cosl, cosr, kw, k1)
            for j in range(n):
                yt[j] = y[j] + 0.5 * h * k1[j]
            _hub_deriv(yt, u, kc, hc, lw, cosl, cosr, kw, k2)
            for j in range(n):
                yt[j] = y[j] + 0.5 * h * k2[j]
            _hub_deriv(yt, u, kc, hc, lw, cosl, cosr, kw, k3)
            for j in range(n):
                yt[j] = y[j] + h * k3[j]
            _hub_deriv(yt, u, kc, hc, lw, cosl, cosr, kw, k4)
            for j in range(n):
                y[j] = y[j] + h / 6.0 * (((k1[j] + 2.0 * k2[j]) + 2.0 * k3[j]) + k4[j])
        for j in range(n):
            out[p, j] = y[j]
    return out


def _rk4_hub_pm(x, u, kc, hc, dt, nsub, ff, fr, rdf, rdr, a, p, al1, al2, c0, lmin, lmax, ldef, kap):  # pragma: no cover
    """The period-mean filter's process model for every row of x (N, 26) (module doc "Period-mean wheel
    speeds"): the two-inertia hub's RK4 (:func:`_rk4_hub`) with the row's own relaxed slips x[22:26] in the
    carcass term, the motors' angles x[18:22] by the trapezoid of the motor speeds over dt, and the relaxed
    slips relaxed over dt towards the slips of the rims' mean speeds against the mean speed v̄ = kc[15]
    (:func:`_relax_slips`, the slope through each wheel's own μ)."""
    npt = x.shape[0]
    out = np.empty_like(x)
    kk = kc.copy()
    row = np.empty((1, 18))
    xs = np.empty(10)
    for j in range(npt):
        for q in range(kc.shape[0]):
            kk[q] = kc[q]
        for i in range(4):
            kk[11 + i] = x[j, 22 + i]
        for q in range(18):
            row[0, q] = x[j, q]
        r = _rk4_hub(row, u, kk, hc, dt, nsub)
        for q in range(18):
            out[j, q] = r[0, q]
        for q in range(10):
            xs[q] = r[0, q]
        for i in range(4):
            out[j, 18 + i] = x[j, 18 + i] + (0.5 * dt) * (x[j, i] + r[0, i])
            xs[i] = 0.5 * (x[j, 10 + i] + r[0, 10 + i])
        xs[4] = kc[15]
        _relax_slips(xs, kk, kap, dt, ff, fr, rdf, rdr, a, p, al1, al2, c0, lmin, lmax, ldef, False, True)
        for i in range(4):
            out[j, 22 + i] = kk[11 + i]
    return out


RELAX_SCALE_BOUNDS = (0.5, 2.0)
"""Bounds of a wheel's μ level over the identified curve's, μ̂_i/μ(σ̄_i), in :func:`relax_slips_own` [-]."""


def relax_slips_own(x, kc, kap, dt, ff, fr, rdf, rdr, a, p, al1, al2, c0, lmin, lmax, ldef, init):  # pragma: no cover
    """:func:`relax_slips` with the slope of μ(s) through each wheel's own operating point: L_r,i = F_z,i f_i
    a g'(|σ̄_i|)/c_x, f_i = μ_i/(c0 + a g(|σ̄_i|)) the wheel's μ (x[5 + i]) over the identified curve's at its
    relaxed slip, within RELAX_SCALE_BOUNDS (1 where the curve's μ is below 0.02).  The curve is identified at
    the mean wheel load; a wheel at another load (the lighter front wheels) sits on the same shape at its own μ
    level, and so does its slip stiffness.  c0: the curve's μ(0⁺) (``exp1_offset``'s c, else 0); a, p, α1, α2 of
    eq. 14 such that c0 + a g(s) is the curve.  x[0:4] the speeds whose slips σ̄ relaxes towards."""
    _relax_slips(x, kc, kap, dt, ff, fr, rdf, rdr, a, p, al1, al2, c0, lmin, lmax, ldef, init, True)

_sign = compiled(_sign, inline=True)
_rhs5 = compiled(_rhs5, inline=True)
_radius = compiled(_radius, inline=True)
_mudot = compiled(_mudot, inline=True)
_lat_shift = compiled(_lat_shift, inline=True)
_lateral_on = compiled(_lateral_on, inline=True)
_wheel_terms = compiled(_wheel_terms, inline=True)
wheel_radii = compiled(wheel_radii)
_rk4_carcass = compiled(_rk4_carcass)
_relax_slips = compiled(_relax_slips)
relax_slips = compiled(relax_slips)
relax_slips_own = compiled(relax_slips_own)
_rk4_points = compiled(_rk4_points)
_hub_deriv = compiled(_hub_deriv, inline=True)
_rk4_hub = compiled(_rk4_hub)
_rk4_hub_pm = compiled(_rk4_hub_pm)
