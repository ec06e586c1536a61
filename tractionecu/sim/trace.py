"""The truth trace: the true signals of a simulated run, as both truth models return them.

:func:`tractionecu.sim.simulator.simulate` (paper truth) and
:func:`tractionecu.sim.physical.simulate_physical` (physical truth) fill it;
the writers turn it into a recording.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass
class TruthTrace:
    """True signals at the control rate; arrays over time (n,) or (n, 4)."""

    t: NDArray[np.float64]
    omega: NDArray[np.float64]
    v: NDArray[np.float64]
    """Ground speed along the body's forward axis [m/s], negative in reverse."""
    md: NDArray[np.float64]
    """Drive torque at the motor (what the inverter reports) [N·m]."""
    fz: NDArray[np.float64]
    fzf: NDArray[np.float64]
    fdx: NDArray[np.float64]
    mu: NDArray[np.float64]
    """Adhesion coefficient F_h/F_z per wheel [-], signed along the body axis (negative when the wheel
    pulls backwards, e.g. driving in reverse)."""
    slip: NDArray[np.float64]
    """Slip per wheel, paper eq. 6 [-]: positive when the wheel drives (turns faster than the ground
    passes), in either direction of travel."""
    rho_s: NDArray[np.float64]
    """Load-weighted soil rolling resistance Σρ_s,i F_z,i / (m g) [-]."""
    a: NDArray[np.float64]
    """Curve parameter a of the soil under the GPS antenna [-]."""
    a_wheel: NDArray[np.float64]
    soil: NDArray[np.int64]
    soil_wheel: NDArray[np.int64]
    x: NDArray[np.float64]
    y: NDArray[np.float64]
    heading: NDArray[np.float64]
    alt: NDArray[np.float64]
    theta: NDArray[np.float64]
    work: NDArray[np.bool_]
    direction: NDArray[np.int8]
    """Direction of travel selected (transmission): +1 forwards, −1 reverse; changes only at standstill."""
    # Physical truth only (None from the paper model):
    v_wheel: NDArray[np.float64] | None = None
    """Ground speed of each wheel along its own heading [m/s] (signed like v); slip is against it."""
    curvature: NDArray[np.float64] | None = None
    """Path curvature of the rear-axle midpoint [1/m], positive turning left."""
    omega_sensor: NDArray[np.float64] | None = None
    """Speed at each wheel's speed pickup, reflected to the wheel [rad/s] (hub: the motor shaft)."""
    engine_torque: NDArray[np.float64] | None = None
    """Mechanical: engine net brake torque [N·m]."""
    engine_speed: NDArray[np.float64] | None = None
    """Mechanical: engine speed [rad/s]."""
    gear: NDArray[np.int64] | None = None
    """Mechanical: gear engaged (negative in reverse)."""
    gear_ratio: NDArray[np.float64] | None = None
    """Mechanical: gearbox ratio, input/output [-]."""
    front_lead: NDArray[np.float64] | None = None
    """Mechanical: front-axle lead [-]."""
    mfwd: NDArray[np.bool_] | None = None
    """Mechanical: MFWD engaged."""
