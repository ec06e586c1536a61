"""Compiled (numba) right-hand side and RK4 integrator of the physical truth model.

State vector x (17):

====  ==========================================================================
0–3   wheel speeds ω_w,i [rad/s] (FL, FR, RL, RR)
4–7   relaxed (force) slip σ_f,i [-]
8     body speed v along the forward axis at the rear-axle midpoint [m/s]
9–16  drive-line: hub: motor speeds ω_m,i (9–12) and shaft twists θ_i (13–16), wheel side;
      mechanical: node speed ω_t (9, gearbox output reflected to a rear wheel),
      rear and front drive-line twists θ_r, θ_f (10, 11)
====  ==========================================================================

Per-wheel inputs ``w`` (rows): 0 F_z [N], 1 r_e [m], 2 g_i = v_i/v (own ground speed over body speed),
3 T_max, 4 law id (0 Brixius, 1 peaked, 2 sigmoid,
3 Janosi–Hanamoto of :mod:`.terramech`), 5 s_shape (law 3: j₀ = K/l), 6 soil resistance at zero slip 1/B_n (law 3: R_c/W),
7 its growth with |slip| 0.5/√B_n (law 3: 0), 8 hub motor torque at the wheel side [N·m].
Scalars ``p``: 0 mass [kg], 1 J_w, 2 ρ_t tyre, 3 longitudinal carcass stiffness c_x [N/m], 4 F_ext [N] (draft, grade, air; against the
forward axis), 5 drive-line kind (0 hub, 1 mechanical), hub: 6 η, 7 drag, 8 k, 9 c, 10 J_m;
mechanical: 6 node torque [N·m], 7 J_node, 8 k_r, 9 c_r, 10 k_f, 11 c_f, 12 lead, 13 MFWD (0/1).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

V_SLIP_MIN = 0.1
"""Speed below which the slip's denominator is held [m/s] (tyre models' low-speed regularisation)."""
V_SIGN_BAND = 0.02
"""Speed band around zero [m/s] in which the resistances' sign functions are linear."""
V_RELAX_MIN = 0.3
"""Least speed in the relaxation rate [m/s]: the force still builds up at standstill (Pacejka 2006: low-speed relaxation)."""
PEAK_C = 1.5
SIGMOID_K = 1.6
L_MIN = 0.05
"""Shortest relaxation length [m] (on the flat or falling part of μ(s) the force follows slip at once)."""
L_MAX = 1.0
"""Longest relaxation length [m]."""
N_STATE = 17


@njit(cache=True)
def janosi(x):
    """Janosi–Hanamoto slip function over a contact patch, f(x) = 1 − (1 − e^{−x})/x, x = s/j₀ ≥ 0
    (:mod:`tractionecu.sim.terramech`)."""
    if x < 1e-8:
        return 0.5 * x
    return 1.0 + math.expm1(-x) / x


@njit(cache=True)
def janosi_slope(x):
    """df/dx of :func:`janosi`: (1 − e^{−x} − x e^{−x}) / x², series 1/2 − x/3 + x²/8 near zero."""
    if x < 1e-3:
        return 0.5 - x / 3.0 + x * x / 8.0
    e = math.exp(-x)
    return (1.0 - e - x * e) / (x * x)


@njit(cache=True)
def shape(s, law, s_shape):
    """Normalised slip function f(s), odd in s (see :mod:`tractionecu.sim.tyre`)."""
    sa = abs(s)
    if law == 0:
        f = 1.0 - math.exp(-7.5 * sa)
    elif law == 1:
        b = math.tan(math.pi / (2.0 * PEAK_C)) / s_shape
        f = math.sin(PEAK_C * math.atan(b * sa))
    elif law == 3:
        f = janosi(sa / s_shape)
    else:
        f = 1.0 - math.exp(-((sa / s_shape) ** SIGMOID_K))
    return f if s >= 0.0 else -f


@njit(cache=True)
def shape_slope(s, law, s_shape):
    """df/ds of :func:`shape` (even in s)."""
    sa = abs(s)
    if law == 0:
        return 7.5 * math.exp(-7.5 * sa)
    if law == 1:
        b = math.tan(math.pi / (2.0 * PEAK_C)) / s_shape
        return PEAK_C * math.cos(PEAK_C * math.atan(b * sa)) * b / (1.0 + (b * sa) ** 2)
    if law == 3:
        return janosi_slope(sa / s_shape) / s_shape
    u = sa / s_shape
    if u <= 0.0:
        return 0.0
    return SIGMOID_K / s_shape * u ** (SIGMOID_K - 1.0) * math.exp(-(u ** SIGMOID_K))


@njit(cache=True)
def relaxation_length(fz, tmax, sf, law, s_shape, c_x):
    """L_r = C_Fκ / c_x: the slip stiffness F_z T_max f'(σ_f) over the carcass' longitudinal stiffness
    (Pacejka 2006), within [L_MIN, L_MAX]."""
    return min(L_MAX, max(L_MIN, fz * tmax * shape_slope(sf, law, s_shape) / c_x))


@njit(cache=True)
def slip_signed(omega, r, vw):
    """Signed slip σ = (r ω − v_w) / max(r|ω|, |v_w|, V_SLIP_MIN), clipped to [−1, 1]."""
    u = r * omega
    den = max(abs(u), abs(vw), V_SLIP_MIN)
    s = (u - vw) / den
    return min(1.0, max(-1.0, s))


@njit(cache=True)
def sgn_band(x):
    return min(1.0, max(-1.0, x / V_SIGN_BAND))


@njit(cache=True)
def deriv(x, w, p, dx):
    m = p[0]
    jw = p[1]
    rho_t = p[2]
    c_x = p[3]
    f_ext = p[4]
    v = x[8]
    shaft = np.empty(4)
    kind = int(p[5])
    if kind == 0:
        eta, drag, k, c, jm = p[6], p[7], p[8], p[9], p[10]
        for i in range(4):
            wm = x[9 + i]
            ms = k * x[13 + i] + c * (wm - x[i])
            mm = w[8, i]
            fac = eta if mm * wm >= 0.0 else 1.0 / eta
            dx[9 + i] = (mm * fac - drag * wm - ms) / jm
            dx[13 + i] = wm - x[i]
            shaft[i] = ms
    else:
        t_node, j_node, kr, cr, kf, cf, lead, mfwd = p[6], p[7], p[8], p[9], p[10], p[11], p[12], p[13]
        wt = x[9]
        wr = 0.5 * (x[2] + x[3])
        wf = 0.5 * (x[0] + x[1])
        t_r = kr * x[10] + cr * (wt - wr)
        dx[10] = wt - wr
        if mfwd > 0.5:
            t_f = kf * x[11] + cf * ((1.0 + lead) * wt - wf)
            dx[11] = (1.0 + lead) * wt - wf
        else:
            t_f = 0.0
            dx[11] = -x[11] / 0.05
        dx[9] = (t_node - t_r - (1.0 + lead) * t_f) / j_node
        shaft[0] = shaft[1] = 0.5 * t_f
        shaft[2] = shaft[3] = 0.5 * t_r
        for i in range(12, N_STATE):
            dx[i] = 0.0
    fsum = 0.0
    for i in range(4):
        fz = w[0, i]
        r = w[1, i]
        g = w[2, i]
        vw = g * v
        sig = slip_signed(x[i], r, vw)
        sf = x[4 + i]
        trac = w[3, i] * shape(sf, int(w[4, i]), w[5, i])
        dx[i] = (shaft[i] - r * fz * (trac + rho_t * sgn_band(r * x[i]))) / jw
        lr = relaxation_length(fz, w[3, i], sf, int(w[4, i]), w[5, i], c_x)
        dx[4 + i] = max(abs(vw), V_RELAX_MIN) / lr * (sig - sf)
        res = fz * (w[6, i] + w[7, i] * abs(sf)) * sgn_band(vw)
        fsum += g * (fz * trac - res)
    dx[8] = (fsum - f_ext) / m


@njit(cache=True)
def integrate(x, w, p, h, n):
    """n RK4 steps of h [s] from x (in place); returns the body acceleration of the last step [m/s²]."""
    k1 = np.empty(N_STATE)
    k2 = np.empty(N_STATE)
    k3 = np.empty(N_STATE)
    k4 = np.empty(N_STATE)
    xt = np.empty(N_STATE)
    acc = 0.0
    for _ in range(n):
        deriv(x, w, p, k1)
        for j in range(N_STATE):
            xt[j] = x[j] + 0.5 * h * k1[j]
        deriv(xt, w, p, k2)
        for j in range(N_STATE):
            xt[j] = x[j] + 0.5 * h * k2[j]
        deriv(xt, w, p, k3)
        for j in range(N_STATE):
            xt[j] = x[j] + h * k3[j]
        deriv(xt, w, p, k4)
        v0 = x[8]
        for j in range(N_STATE):
            x[j] += h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
        for i in range(4):
            x[4 + i] = min(1.0, max(-1.0, x[4 + i]))
        acc = (x[8] - v0) / h
    return acc


@njit(cache=True)
def slip_eq6(omega, r, vw):
    """Paper eq. 6 slip of a wheel against its own ground speed v_w (magnitudes; s > 0 driving)."""
    u = abs(r * omega)
    va = abs(vw)
    if max(u, va) < 1e-6:
        return 0.0
    if va <= u:
        return 1.0 - va / u
    return -1.0 + u / va


@njit(cache=True)
def outputs(x, w, p, out):
    """Per-wheel signed slip σ (own ground speed), traction term T, shaft torque and eq. 6 slip into
    out (4, 4)."""
    for i in range(4):
        vw = w[2, i] * x[8]
        out[0, i] = slip_signed(x[i], w[1, i], vw)
        out[1, i] = w[3, i] * shape(x[4 + i], int(w[4, i]), w[5, i])
        out[3, i] = slip_eq6(x[i], w[1, i], vw)
    if int(p[5]) == 0:
        for i in range(4):
            out[2, i] = p[8] * x[13 + i] + p[9] * (x[9 + i] - x[i])
    else:
        t_r = p[8] * x[10] + p[9] * (x[9] - 0.5 * (x[2] + x[3]))
        t_f = 0.0
        if p[13] > 0.5:
            t_f = p[10] * x[11] + p[11] * ((1.0 + p[12]) * x[9] - 0.5 * (x[0] + x[1]))
        out[2, 0] = out[2, 1] = 0.5 * t_f
        out[2, 2] = out[2, 3] = 0.5 * t_r
