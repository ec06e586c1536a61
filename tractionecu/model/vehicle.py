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

Vertical loads come from the measured front-axle load F_zf: each front wheel
carries F_zf/2 and each rear wheel (m g − F_zf)/2 (paper section 3.1: "the rear
wheel vertical force can then be calculated using vehicle parameters").
Rolling resistances act against the direction of motion (sign of ω resp. v).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..config import G, VehicleParams

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
N_INPUT = 6
STATE_NAMES = ("omega_FL", "omega_FR", "omega_RL", "omega_RR", "v", "mu_FL", "mu_FR", "mu_RL", "mu_RR", "rho_s")


def tyre_deflection(fz: ArrayLike, params: VehicleParams) -> NDArray[np.float64]:
    """Tyre deflection Δr [m] from vertical load F_z [N] (paper eq. 9, p_t in Pa)."""
    fz = np.asarray(fz, dtype=float)
    k = 2.0 * np.pi * params.tyre_pressure_pa * np.sqrt(params.tyre_width_m / 2.0 * params.r0_m)
    return np.clip(fz, 0.0, None) / k


def rolling_radius(fz: ArrayLike, params: VehicleParams) -> NDArray[np.float64]:
    """Dynamic rolling radius r_d = r0 − Δr(F_z) [m], Δr limited to 30 % of r0."""
    return params.r0_m - np.minimum(tyre_deflection(fz, params), 0.3 * params.r0_m)


def wheel_loads(fzf: ArrayLike, params: VehicleParams, weight_n: float | None = None) -> NDArray[np.float64]:
    """Per-wheel vertical loads (..., 4) [N] from the front-axle load F_zf [N]."""
    fzf = np.asarray(fzf, dtype=float)
    w = params.weight_n if weight_n is None else weight_n
    front = 0.5 * fzf
    rear = 0.5 * (w - fzf)
    return np.stack([front, front, rear, rear], axis=-1)


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
    derivatives are zero; process noise lets them move between steps.
    """

    def __init__(self, params: VehicleParams):
        self.params = params
        self.m = params.mass_kg
        self.J = params.wheel_inertia_kgm2
        self.rho_t = params.rho_t

    def loads(self, u: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(F_z (..., 4) [N], r_d (..., 4) [m]) from the inputs."""
        fz = wheel_loads(u[..., IU_FZF], self.params)
        return fz, rolling_radius(fz, self.params)

    def rhs(self, x: NDArray[np.float64], u: NDArray[np.float64], fz: NDArray[np.float64] | None = None,
            r_d: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        """dx/dt for states x (..., 10) under input u (6,) or (..., 6)."""
        if fz is None or r_d is None:
            fz, r_d = self.loads(u)
        omega = x[..., IX_OMEGA]
        v = x[..., IX_V]
        mu = x[..., IX_MU]
        rho_s = x[..., IX_RHO]
        md = u[..., IU_MD]
        fh = mu * fz                                                   # eq. 4
        domega = (md - r_d * fh - r_d * self.rho_t * fz * np.sign(omega)) / self.J   # eq. 2
        dv = (fh.sum(axis=-1) - u[..., IU_FDX] - rho_s * self.m * G * np.sign(v)) / self.m  # eq. 8
        dx = np.zeros(np.broadcast_shapes(x.shape, u.shape[:-1] + (N_STATE,)))
        dx[..., IX_OMEGA] = domega
        dx[..., IX_V] = dv
        return dx

    def step(self, x: NDArray[np.float64], u: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
        """One RK4 step of length dt [s] for all states at once (paper section 3.1)."""
        fz, r_d = self.loads(u)
        return rk4(lambda y: self.rhs(y, u, fz, r_d), x, dt)

    def outputs(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """y = h(x) = (ω1..4, v)."""
        return x[..., :5]


def rk4(f, x: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
    """Classical fourth-order Runge–Kutta step for an autonomous f(x)."""
    k1 = f(x)
    k2 = f(x + 0.5 * dt * k1)
    k3 = f(x + 0.5 * dt * k2)
    k4 = f(x + dt * k3)
    return x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
