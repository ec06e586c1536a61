"""The simulated GNSS receiver's output, shared by both recording writers (:mod:`.writer`,
:mod:`.physwriter`): one epoch's NMEA sentences and the course over ground of the motion."""

from __future__ import annotations

import datetime as _dt
import math

import numpy as np

from ..config import SensorSpec
from ..gnss import nmea

GNSS_COURSE_HOLD_MPS = 0.1
"""Speed over ground below which the receiver holds its last course over ground [m/s]."""


def gnss_sentences(spec: SensorSpec, t0: float, t: float, lat_deg: float, lon_deg: float, alt_m: float,
                   speed_mps: float, course_deg: float) -> tuple[str, str, str]:
    """GGA, RMC and VTG of one receiver epoch at ``t`` [s] after the epoch ``t0`` [UTC s]: the receiver's
    epoch is the UTC time of the fix (lines leave the receiver a few ms later); speed over ground is a
    magnitude; HDOP wanders slowly about ``spec.gps_hdop``."""
    utc = _dt.datetime.fromtimestamp(round(t0 + t, 2), tz=_dt.timezone.utc)
    hdop = spec.gps_hdop + 0.05 * math.sin(t / 60.0)
    sog = max(speed_mps, 0.0)
    return (nmea.format_gga(utc, lat_deg, lon_deg, spec.gps_fix_quality, spec.gps_nsat, round(hdop, 2), alt_m),
            nmea.format_rmc(utc, lat_deg, lon_deg, sog, course_deg),
            nmea.format_vtg(sog, course_deg))


def course_over_ground(heading, v, sigma_v_mps: float = 0.0, rng: np.random.Generator | None = None):
    """Course over ground [deg, clockwise from north] of the motion: the body heading [rad, 0 = east,
    counter-clockwise], + 180° when v < 0, with the receiver's noise; held at its last value while
    |v| < GNSS_COURSE_HOLD_MPS.

    The receiver computes the course from its Doppler velocity, so the velocity noise across the track,
    ``sigma_v_mps`` per axis (``SensorSpec.gps_speed_sigma``: ZED-F9P velocity accuracy 0.05 m/s), turns it
    by atan(n/|v|): σ ≈ σ_v/|v|, 1.1° at 2.5 m/s, tens of degrees when creeping.  ``rng`` draws that noise
    (a generator of its own, so the other noise of a recording does not move with it).  The physical truth's
    receiver has it (:mod:`.physwriter`); the paper truth's writes the course of the motion, so the paper's
    scenario stays byte for byte what it was."""
    motion = np.where(v < 0.0, heading + np.pi, heading)
    course = (90.0 - np.degrees(motion)) % 360.0
    if sigma_v_mps > 0.0 and rng is not None and len(course):
        n_cross = sigma_v_mps * rng.standard_normal(len(course))
        course = (course + np.degrees(np.arctan2(n_cross, np.maximum(np.abs(v), 1e-9)))) % 360.0
    for j in range(1, len(course)):
        if abs(v[j]) < GNSS_COURSE_HOLD_MPS:
            course[j] = course[j - 1]
    return course
