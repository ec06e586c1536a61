"""A small, seeded truth loop for estimator tests (no simulator needed).

Truth: the paper's model (eqs. 2, 4, 6, 8, 9) with μ_i = a·g(s_i) of one
surface class, integrated with explicit Euler at ``substep`` (the
wheel–slip coupling has a time constant of a few ms, so 1 ms steps are
used).  A proportional speed controller with draft feed-forward sets the four
drive torques.  Sensors add the noise of :class:`SensorSpec` at their rates.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tractionecu.config import G, SensorSpec, VehicleParams
from tractionecu.model.mucurve import SOIL_CLASSES, SoilClass
from tractionecu.model.vehicle import rolling_radius, slip


@dataclass
class SynthRun:
    steps: list = field(default_factory=list)
    """(t, inputs, measurements) per 10 ms step, only new samples present."""
    t: np.ndarray | None = None
    mu: np.ndarray | None = None
    slip: np.ndarray | None = None
    v: np.ndarray | None = None
    rho_s: np.ndarray | None = None
    a: np.ndarray | None = None


def synth_run(seed: int = 0, duration: float = 20.0, cls: SoilClass = SOIL_CLASSES["stubble"], a: float = 0.7,
              rho_s: float = 0.07, change: tuple[float, float, float] | None = None, v_target: float = 2.5,
              draft: float = 15000.0, sensors: SensorSpec | None = None, veh: VehicleParams | None = None,
              substep: float = 1e-3, dt: float = 0.01) -> SynthRun:
    """Simulate ``duration`` s; ``change`` = (t, a2, rho2) switches the soil at t."""
    veh = veh or VehicleParams()
    sp = sensors or SensorSpec()
    rng = np.random.default_rng(seed)
    m, J, W = veh.mass_kg, veh.wheel_inertia_kgm2, veh.weight_n
    fzf = veh.static_front_load_n()
    fz = np.array([fzf / 2, fzf / 2, (W - fzf) / 2, (W - fzf) / 2])
    r = rolling_radius(fz, veh)
    share = fz / fz.sum()
    v = 1.0
    omega = v / r * 1.01
    n = int(round(duration / dt))
    nsub = int(round(dt / substep))
    out = SynthRun()
    T, MU, S, V, RH, A = [], [], [], [], [], []
    md = np.zeros(4)
    fluct = 0.0
    for k in range(n):
        t = (k + 1) * dt
        a_now, rho_now = (change[1], change[2]) if change is not None and t >= change[0] else (a, rho_s)
        v_ref = min(v_target, 1.0 + 0.3 * t)
        fluct = 0.98 * fluct + 0.02 * rng.standard_normal() * 5.0
        fdx = draft * min(1.0, t / 2.0) * (1.0 + 0.05 * fluct)
        f_cmd = m * 1.5 * (v_ref - v) + fdx + 0.07 * W
        md += (f_cmd * share * r - md) * 0.2
        for _ in range(nsub):
            s = slip(omega, v, r)
            mu = a_now * cls.g(s)
            domega = (md - r * fz * (mu + veh.rho_t * np.sign(omega))) / J
            dv = (float(mu @ fz) - fdx - rho_now * W * np.sign(v)) / m
            omega = omega + substep * domega
            v = v + substep * dv
        s = slip(omega, v, r)
        mu = a_now * cls.g(s)
        T.append(t); MU.append(mu); S.append(s); V.append(v); RH.append(rho_now); A.append(a_now)
        om_m = omega + (sp.wheel_speed_sigma_abs + sp.wheel_speed_sigma_rel * np.abs(omega)) * rng.standard_normal(4)
        md_m = md + (sp.torque_sigma_abs + sp.torque_sigma_rel * np.abs(md)) * rng.standard_normal(4)
        inputs = {"Md": md_m}
        if k % 2 == 0:
            inputs["Fzf"] = fzf + sp.axle_sigma_n * rng.standard_normal()
            inputs["Fdx"] = fdx + sp.draft_sigma_n * rng.standard_normal()
        meas = {"omega": om_m}
        if k % 10 == 9:
            meas["v"] = v + sp.gps_speed_sigma * rng.standard_normal()
        out.steps.append((t, inputs, meas))
    out.t, out.mu, out.slip, out.v, out.rho_s, out.a = (np.array(x) for x in (T, MU, S, V, RH, A))
    return out
