"""Sensor models: rates, noise and quantisation of real tractor hardware.

Every figure has its source in :class:`SensorSpec`'s field docs; README's
"Sensors" table repeats them.  The estimator's default measurement noise is
taken from the same spec, never tuned against the truth.

Quantisation is applied twice in a recording, as on a real machine: once by
the sensor/ECU (modelled here) and once by the DBC scaling when the value is
put on the bus (done by the codec).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class SensorSpec:
    """Rates [Hz], noise standard deviations and quantisation of the simulated sensors."""

    wheel_rate_hz: float = field(default=100.0, metadata={"doc": "wheel speed and drive torque frame rate; 10 ms is the usual drive-train PGN period (ISO 11783-7 / J1939-71 engine and transmission speed PGNs are 10–20 ms)"})
    wheel_speed_sigma_rel: float = field(default=0.002, metadata={"doc": "wheel-speed noise, relative [-]: period-measured 60-tooth pulse rings / hub-motor resolvers give 0.1–0.5 % speed ripple"})
    wheel_speed_sigma_abs: float = field(default=0.005, metadata={"doc": "wheel-speed noise floor [rad/s]"})
    wheel_speed_quant: float = field(default=0.001, metadata={"doc": "wheel-speed resolution [rad/s] (the DBC's 0.001 rad/s/bit)"})
    torque_sigma_rel: float = field(default=0.01, metadata={"doc": "drive-torque noise, relative [-]: inverter torque estimates from phase currents, 1 % ripple (current-sensor noise of Hall/shunt sensors ≈ 0.5–1 % FS)"})
    torque_sigma_abs: float = field(default=5.0, metadata={"doc": "drive-torque noise floor [N·m]"})
    torque_quant: float = field(default=2.0, metadata={"doc": "drive-torque resolution [N·m] (DBC 2 N·m/bit)"})
    loadpin_rate_hz: float = field(default=50.0, metadata={"doc": "load-pin sample rate [Hz]: strain-gauge/magnetoelastic hitch pins with CAN output run at 10–100 Hz; ISO 11783-7 hitch status is sent every 100 ms, 50 Hz here"})
    draft_sigma_n: float = field(default=300.0, metadata={"doc": "draft load-pin noise [N]: ±0.3 % of a 100 kN full scale (typical strain-gauge load-pin accuracy 0.25–1 % FS)"})
    draft_quant_n: float = field(default=10.0, metadata={"doc": "draft resolution [N] (ISO 11783-7 rear draft 10 N/bit)"})
    axle_sigma_n: float = field(default=300.0, metadata={"doc": "front-axle load-pin noise [N]: ±0.3 % of 100 kN FS"})
    axle_quant_n: float = field(default=5.0, metadata={"doc": "front-axle load resolution [N] (DBC 5 N/bit)"})
    gps_rate_hz: float = field(default=10.0, metadata={"doc": "GNSS epoch rate [Hz]: agricultural receivers output 10 Hz (u-blox ZED-F9P: up to 20 Hz RTK)"})
    gps_speed_sigma: float = field(default=0.05, metadata={"doc": "GNSS Doppler speed noise [m/s] (ZED-F9P datasheet: velocity accuracy 0.05 m/s)"})
    gps_pos_sigma: float = field(default=0.30, metadata={"doc": "GNSS horizontal position noise [m], slowly varying (SBAS/DGPS: 0.3–0.6 m CEP; ZED-F9P with SBAS 1.0 m CEP, RTK 0.01 m)"})
    gps_pos_tau_s: float = field(default=30.0, metadata={"doc": "correlation time of the position error [s] (multipath/ionosphere residuals vary over tens of seconds)"})
    gps_alt_sigma: float = field(default=0.5, metadata={"doc": "GNSS altitude noise [m] (vertical error ≈ 1.5–2× horizontal)"})
    gps_fix_quality: int = field(default=2, metadata={"doc": "GGA fix quality: 2 = DGPS/SBAS (4 = RTK fixed)"})
    gps_hdop: float = field(default=0.9, metadata={"doc": "typical HDOP in open field with 15–20 satellites (GPS+Galileo+GLONASS)"})
    gps_nsat: int = field(default=16, metadata={"doc": "satellites used"})
    can_jitter_s: float = field(default=0.0003, metadata={"doc": "CAN reception timestamp jitter [s]: arbitration delay of a 250 kbit/s bus at 30–50 % load is up to a few frame times (≈ 0.5 ms per 8-byte frame)"})


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
