"""Shared synthetic field for the mapping tests: three soils, back-and-forth passes."""

from __future__ import annotations

import numpy as np

ORIGIN = (50.91, 13.34)
"""Field origin [deg] (UTM zone 33N)."""
SOIL_A = {0: 0.75, 1: 0.60, 2: 0.42}
SOIL_RHO = {0: 0.06, 1: 0.09, 2: 0.14}
SOIL_NAMES = {0: "stubble", 1: "grass", 2: "wet loam"}


def soil_xy(x, y):
    """True soil id at local (x, y) [m]: stubble west of x = 30 m, then grass
    north of a slanted line and wet loam south of it."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    return np.where(x < 30.0, 0, np.where(y > 0.5 * (x - 30.0) + 20.0, 1, 2))


def passes(width_m=70.0, length_m=50.0, spacing_m=6.0, step_m=0.25, x_start=3.13, y_start=0.07):
    """Back-and-forth track (x, y) [m] with samples every ``step_m``, offset so
    that no sample lies exactly on a cell edge."""
    xs, ys = [], []
    for k, x in enumerate(np.arange(x_start, width_m, spacing_m)):
        y = np.arange(y_start, length_m, step_m)
        if k % 2:
            y = y[::-1]
        xs.append(np.full_like(y, x))
        ys.append(y)
    return np.concatenate(xs), np.concatenate(ys)


def fill_store(store, x, y, rng, noise_a=0.02, noise_rho=0.004, t0=0.0):
    """Add noisy samples of the synthetic field at local (x, y); returns the values added."""
    lat, lon = store.to_latlon(x, y)
    sid = soil_xy(x, y)
    a = np.vectorize(SOIL_A.get)(sid) + rng.normal(0.0, noise_a, len(x))
    rho = np.vectorize(SOIL_RHO.get)(sid) + rng.normal(0.0, noise_rho, len(x))
    for i in range(len(x)):
        assert store.add(float(lat[i]), float(lon[i]), {"a": a[i], "rho_s": rho[i], "mu": 0.4}, t0 + 0.1 * i)
    return a, rho
