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

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..config import SensorSpec

__all__ = ["SensorBiases", "SensorSpec", "ToothedPickup", "draw_biases", "ou_noise", "pickup_speeds", "quantise",
           "torque_meas", "wheel_speed_meas"]


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


# ----------------------------------------------------------------------------- physical truth sensors
@dataclass(frozen=True)
class ToothedPickup:
    """A toothed ring and an inductive / Hall pickup whose ECU measures speed by period counting.

    Each frame the ECU takes the edges inside its window: speed = (edges − 1) pitches over the time
    between the first and the last edge, both read off a free-running capture timer.  With no two edges
    inside the window it uses the last tooth period, until ``timeout_s`` without an edge reads zero.
    The errors are those of real rings: each tooth's edge sits off its nominal angle (pitch error,
    fixed for the ring), the ring runs eccentric to its shaft (a once-per-revolution sinusoid), and the
    timer quantises the edge times.  Both ring errors repeat every revolution: coloured, not white.

    Figures: 60 teeth (the SensorSpec's "60-tooth pulse ring"); tooth-position error 0.5 % of the pitch
    (1σ; ISO 1328-1 accuracy grade 8–9 for a sintered/stamped ring of module ≈ 2.5: single pitch
    deviation ≈ 15–20 µm on a 6° pitch of ≈ 3 mm); eccentricity 0.1 mm on a 60 mm ring radius
    (1.7e-3 rad); 1 µs capture timer (ECU timers run at 1–40 MHz, a 1 MHz tick is the coarse end).
    """

    teeth: int = 60
    pitch_error: float = 0.005
    """Tooth-edge position error, 1σ, fraction of the pitch [-]."""
    eccentricity_rad: float = 1.7e-3
    """Amplitude of the once-per-revolution angle error [rad]."""
    timer_s: float = 1e-6
    """Capture-timer resolution [s]."""
    timeout_s: float = 0.5
    """Time without an edge after which the speed reads zero [s]."""


def pickup_speeds(t: NDArray[np.float64], omega: NDArray[np.float64], frame_t: NDArray[np.float64],
                  window_s: float, pickup: ToothedPickup, ratio: float, rng: np.random.Generator
                  ) -> NDArray[np.float64]:
    """Speeds [rad/s, reflected to the wheel by ``ratio``] an ECU measures at ``frame_t`` from a pickup on a
    shaft turning ``ratio`` × ``omega`` (truth samples at times ``t``).  The sign is the truth's (the
    drive knows its direction of rotation)."""
    omega = np.asarray(omega, dtype=float)
    shaft = np.abs(omega) * ratio
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (shaft[1:] + shaft[:-1]) * np.diff(t))])
    t0 = t[0]
    pitch = 2.0 * math.pi / pickup.teeth
    err = rng.standard_normal(pickup.teeth) * pickup.pitch_error * pitch
    phase = rng.uniform(0.0, 2.0 * math.pi)
    n_edges = int(psi[-1] / pitch)
    j = np.arange(1, n_edges)
    ang = j * pitch + err[j % pickup.teeth] + pickup.eccentricity_rad * np.sin(j * pitch + phase)
    inc = np.flatnonzero(np.diff(psi) > 0)
    if len(j) < 2 or len(inc) == 0:
        return np.zeros(len(frame_t))
    # Interpolate the edge times on the strictly increasing part of ψ(t).
    keep = np.concatenate([[0], inc + 1])
    edge_t = np.interp(ang, psi[keep], t[keep])
    edge_t = t0 + np.floor((edge_t - t0) / pickup.timer_s) * pickup.timer_s
    last = np.searchsorted(edge_t, frame_t, side="right") - 1
    first = np.searchsorted(edge_t, frame_t - window_s, side="right")
    out = np.zeros(len(frame_t))
    span = last - first
    ok = (span >= 1) & (last >= 0)
    dtw = edge_t[np.clip(last, 0, None)] - edge_t[np.clip(first, 0, len(edge_t) - 1)]
    out[ok] = span[ok] * pitch / np.maximum(dtw[ok], pickup.timer_s)
    one = ~ok & (last >= 1)
    fresh = one & (frame_t - edge_t[np.clip(last, 0, None)] < pickup.timeout_s)
    per = edge_t[np.clip(last, 0, None)] - edge_t[np.clip(last - 1, 0, None)]
    out[fresh] = pitch / np.maximum(per[fresh], pickup.timer_s)
    sign = np.sign(np.interp(frame_t, t, omega))
    return out / ratio * sign


@dataclass(frozen=True)
class SensorBiases:
    """Systematic sensor errors of one run, drawn once from the seed inside the tolerances of
    :class:`~tractionecu.config.SensorSpec` (uniform over ± the bound)."""

    torque_gain: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    """Relative gain error of each drive-torque report (mechanical: [0] is the engine torque) [-]."""
    torque_offset_nm: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    """Zero offset of each drive-torque report [N·m]."""
    axle_offset_n: float = 0.0
    axle_gain: float = 0.0
    draft_offset_n: float = 0.0
    draft_gain: float = 0.0
    radar_gain: float = 0.0
    """Relative gain error of the ground-speed radar (mounting angle) [-]."""
    gnss_latency_s: float = 0.0


def draw_biases(spec: SensorSpec, rng: np.random.Generator, *, latency_s: float = 0.0) -> SensorBiases:
    """Draw the run's :class:`SensorBiases` inside the tolerances of ``spec``.

    The GNSS latency is ``latency_s`` when given (> 0), else drawn uniformly in [50 ms, the tolerance
    bound] (the bound's source: 20–100 ms from epoch to the last NMEA byte).  The radar's gain error is
    uniform in ±2 % (a ±1.5° mounting-angle tolerance at a 35° beam angle changes cos by ±1.9 %).
    """
    u = lambda b, n=None: rng.uniform(-b, b, n)  # noqa: E731
    tg = getattr(spec, "torque_gain_tol_rel", 0.02)
    to = getattr(spec, "torque_offset_tol_nm", 20.0)
    lat_hi = max(getattr(spec, "gps_latency_tol_s", 0.1), 0.05)
    return SensorBiases(
        torque_gain=tuple(float(x) for x in u(tg, 4)),
        torque_offset_nm=tuple(float(x) for x in u(to, 4)),
        axle_offset_n=float(u(getattr(spec, "axle_offset_tol_n", 300.0))),
        axle_gain=float(u(getattr(spec, "axle_gain_tol_rel", 0.005))),
        draft_offset_n=float(u(getattr(spec, "draft_offset_tol_n", 300.0))),
        draft_gain=float(u(getattr(spec, "draft_gain_tol_rel", 0.005))),
        radar_gain=float(u(0.02)),
        gnss_latency_s=float(latency_s if latency_s > 0 else rng.uniform(0.05, lat_hi)),
    )
