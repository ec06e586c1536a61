"""Sensor models: rates, noise and quantisation of real tractor hardware.

The figures are :class:`~tractionecu.config.SensorSpec` (core configuration,
each with its source in the field docs; README's "Sensors" table repeats
them).  The simulator adds this noise and the estimator takes its
measurement noise from the same figures, never tuned against the truth.

Quantisation is applied twice in a recording, as on a real machine: once by
the sensor/ECU (modelled here) and once by the DBC scaling when the value is
put on the bus (done by the codec).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..config import SensorSpec

__all__ = ["SensorSpec", "ou_noise", "quantise", "torque_meas", "wheel_speed_meas"]


def quantise(x: NDArray[np.float64], q: float) -> NDArray[np.float64]:
    """Round to the resolution q."""
    return np.round(np.asarray(x, dtype=float) / q) * q


def wheel_speed_meas(omega: NDArray[np.float64], spec: SensorSpec, rng: np.random.Generator) -> NDArray[np.float64]:
    """Measured wheel speeds [rad/s]."""
    sig = spec.wheel_speed_sigma_abs + spec.wheel_speed_sigma_rel * np.abs(omega)
    return quantise(omega + sig * rng.standard_normal(np.shape(omega)), spec.wheel_speed_quant)


def torque_meas(md: NDArray[np.float64], spec: SensorSpec, rng: np.random.Generator) -> NDArray[np.float64]:
    """Measured drive torques [N·m]."""
    sig = spec.torque_sigma_abs + spec.torque_sigma_rel * np.abs(md)
    return quantise(md + sig * rng.standard_normal(np.shape(md)), spec.torque_quant)


def ou_noise(n: int, dt: float, sigma: float, tau: float, rng: np.random.Generator) -> NDArray[np.float64]:
    """Ornstein–Uhlenbeck (first-order Gauss–Markov) noise, stationary std ``sigma``, time constant ``tau`` [s]."""
    phi = np.exp(-dt / tau)
    w = rng.standard_normal(n) * sigma * np.sqrt(1.0 - phi * phi)
    out = np.empty(n)
    acc = rng.standard_normal() * sigma
    for i in range(n):
        acc = phi * acc + w[i]
        out[i] = acc
    return out
