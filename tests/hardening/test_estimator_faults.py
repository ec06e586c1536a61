"""NaN, Inf, saturated sensor values and absurd torque steps into ``Estimator.step``.

A clean seeded run is the reference.  The same run is repeated with a
FAULT_S window of hostile samples (a different kind every step) starting at
T_FAULT.  At every step the state must stay finite and P positive definite
(Cholesky); after the window the estimate must come back to the clean run's
(|Δμ| ≤ MU_TOL on every wheel, |Δρ_s| ≤ RHO_TOL) and stay there, within
RECOVERY_LIMIT_S.  The measured recovery time is printed.
"""

from __future__ import annotations

import math

import numpy as np
from est_synth import synth_run

from tractionecu.config import VehicleParams
from tractionecu.estimation.estimator import Estimator

DURATION_S = 30.0
T_FAULT = 12.0
FAULT_S = 3.0
MU_TOL = 0.02
RHO_TOL = 0.01
RECOVERY_LIMIT_S = 8.0

SAT_OMEGA = 32.767       # largest WheelSpeed_* the DBC can carry [rad/s]
SAT_TORQUE = 65534.0     # largest DriveTorque_* [N·m]
SAT_LOAD = 327675.0      # largest FrontAxleLoad [N]


def hostile(k: int, inputs: dict, meas: dict) -> tuple[dict, dict]:
    """The k-th hostile step: cycles through every kind of bad value."""
    inputs, meas = dict(inputs), dict(meas)
    kind = k % 10
    if kind == 0:
        meas["omega"] = np.array([math.nan, 3.0, 3.0, 3.0])
    elif kind == 1:
        inputs["Md"] = np.array([math.inf, 0.0, -math.inf, 0.0])
    elif kind == 2:
        meas["omega"] = np.full(4, SAT_OMEGA)
    elif kind == 3:
        inputs["Md"] = np.full(4, SAT_TORQUE)          # absurd step up ...
    elif kind == 4:
        inputs["Md"] = np.full(4, -SAT_TORQUE)         # ... and down, 10 ms later
    elif kind == 5:
        inputs["Fzf"], inputs["Fdx"] = SAT_LOAD, -320000.0
    elif kind == 6:
        meas["v"] = math.nan
        inputs["Fzf"] = math.inf
    elif kind == 7:
        meas["omega"] = np.full(4, -SAT_OMEGA)
        meas["v"] = 1e9
    elif kind == 8:
        inputs["Md"] = np.array([1e308, 1e308, 1e308, 1e308])   # finite, but the sum overflows
    else:
        meas["omega"] = np.zeros(4)
        inputs["Fdx"] = math.nan
    return inputs, meas


def run(steps, faulty: bool):
    est = Estimator(VehicleParams())
    out = []
    worst_min_eig = math.inf
    for k, (t, inputs, meas) in enumerate(steps):
        if faulty and T_FAULT <= t < T_FAULT + FAULT_S:
            inputs, meas = hostile(k, inputs, meas)
        e = est.step(t, inputs, meas)
        if est.ukf is not None:
            x, P = est.ukf.x, est.ukf.P
            assert np.isfinite(x).all(), f"state not finite at t={t:.2f}: {x}"
            assert np.isfinite(P).all(), f"P not finite at t={t:.2f}"
            np.linalg.cholesky(P)                      # raises unless positive definite
            worst_min_eig = min(worst_min_eig, float(np.linalg.eigvalsh(0.5 * (P + P.T))[0]))
        out.append(e)
    return out, worst_min_eig, est.counters


def test_hostile_inputs_keep_the_filter_finite_and_it_recovers() -> None:
    steps = synth_run(seed=11, duration=DURATION_S).steps
    ref, _, _ = run(steps, faulty=False)
    bad, min_eig, counters = run(steps, faulty=True)
    assert min_eig > 0
    assert counters["rejected_inputs"] > 0 and counters["rejected_measurements"] > 0
    t_end = T_FAULT + FAULT_S
    ok_since = None
    for r, b in zip(ref, bad):
        if b.t < t_end:
            continue
        close = (np.all(np.abs(np.asarray(b.mu) - np.asarray(r.mu)) <= MU_TOL)
                 and abs(float(b.rho_s) - float(r.rho_s)) <= RHO_TOL)
        if close and ok_since is None:
            ok_since = b.t
        elif not close:
            ok_since = None
    assert ok_since is not None, "never came back to the clean run's estimate"
    recovery = ok_since - t_end
    print(f"\nestimator recovery after {FAULT_S:.0f} s of NaN/Inf/saturated/torque-step input: {recovery:.2f} s "
          f"(|dmu| <= {MU_TOL}, |drho_s| <= {RHO_TOL}, held to t = {DURATION_S:.0f} s); "
          f"min eig(P) during the run {min_eig:.3g}; counters {dict(counters)}")
    assert recovery <= RECOVERY_LIMIT_S
