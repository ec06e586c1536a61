"""Terrain elevation model for the grade effect, from a real field track.

The packaged DEM ``tractionecu/data/henrys_field_dem.npz`` is derived from the
Montana State University on-farm experiment data set OFPEDATA2 (field
"HENRYS", 2018-07-18, combine yield monitor track with GNSS elevation; MIT
licence, paulhegedus/OFPEDATA2).  Build it again with::

    python -m tractionecu.sim.terrain SRC.csv tractionecu/data/henrys_field_dem.npz

Method: the 31 k track points (lon/lat in WGS84 degrees, elevation in feet)
are projected to a local east–north plane (equirectangular about the track's
mean latitude: < 1 mm error over 2 km), binned into 10 m cells (mean per cell),
gaps filled by nearest neighbour, and smoothed with a 20 m Gaussian to remove
the GNSS altitude noise (≈ 0.3 m) that would otherwise appear as spurious
grade.  Elevation is converted to metres.

The simulator places its field on this relief with a configurable offset, so a
pass pattern sees the real slopes (≈ 12 m of relief over 1 × 2 km, grades up
to a few per cent).
"""

from __future__ import annotations

import csv
import sys
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

FT = 0.3048
EARTH_R = 6378137.0


@dataclass
class Terrain:
    """Elevation grid h[i, j] [m] at x = x0 + j·res (east), y = y0 + i·res (north)."""

    h: NDArray[np.float64]
    x0: float
    y0: float
    res: float
    source: str = ""

    @classmethod
    def flat(cls) -> "Terrain":
        return cls(np.zeros((2, 2)), -1e6, -1e6, 2e6, "flat")

    @classmethod
    def henrys_field(cls) -> "Terrain":
        """The packaged real relief (see module doc)."""
        with resources.files("tractionecu.data").joinpath("henrys_field_dem.npz").open("rb") as fh:
            d = np.load(fh)
            return cls(d["h"].astype(float), float(d["x0"]), float(d["y0"]), float(d["res"]),
                       "OFPEDATA2 HENRYS 2018 (MIT)")

    def elevation(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """Bilinear elevation [m] at metric (x, y); clamped at the grid edge."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        ny, nx = self.h.shape
        fj = np.clip((x - self.x0) / self.res, 0, nx - 1.000001)
        fi = np.clip((y - self.y0) / self.res, 0, ny - 1.000001)
        j = np.floor(fj).astype(int)
        i = np.floor(fi).astype(int)
        tj = fj - j
        ti = fi - i
        h = self.h
        return ((1 - ti) * ((1 - tj) * h[i, j] + tj * h[i, j + 1])
                + ti * ((1 - tj) * h[i + 1, j] + tj * h[i + 1, j + 1]))

    def grade(self, x: ArrayLike, y: ArrayLike, heading_rad: ArrayLike, ds: float = 2.0) -> NDArray[np.float64]:
        """Grade angle θ = atan(dh/ds) [rad] along the heading (0 = east, CCW positive)."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        c, s = np.cos(heading_rad), np.sin(heading_rad)
        dh = self.elevation(x + c * ds, y + s * ds) - self.elevation(x - c * ds, y - s * ds)
        return np.arctan(dh / (2 * ds))


def build_dem(src_csv: str | Path, res: float = 10.0, smooth_m: float = 20.0) -> Terrain:
    """Build the DEM from the OFPEDATA2 CSV (columns lon_deg, lat_deg, elevation_ft)."""
    from scipy import ndimage

    lon, lat, el = [], [], []
    with open(src_csv, newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            try:
                lon.append(float(row["lon_deg"]))
                lat.append(float(row["lat_deg"]))
                el.append(float(row["elevation_ft"]) * FT)
            except (KeyError, ValueError):
                continue
    lon_a, lat_a, el_a = np.array(lon), np.array(lat), np.array(el)
    lat0, lon0 = lat_a.mean(), lon_a.mean()
    x = np.radians(lon_a - lon0) * EARTH_R * np.cos(np.radians(lat0))
    y = np.radians(lat_a - lat0) * EARTH_R
    x0, y0 = x.min(), y.min()
    nx = int((x.max() - x0) / res) + 1
    ny = int((y.max() - y0) / res) + 1
    j = ((x - x0) / res).astype(int)
    i = ((y - y0) / res).astype(int)
    s = np.zeros((ny, nx))
    n = np.zeros((ny, nx))
    np.add.at(s, (i, j), el_a)
    np.add.at(n, (i, j), 1)
    h = np.where(n > 0, s / np.maximum(n, 1), np.nan)
    idx = ndimage.distance_transform_edt(np.isnan(h), return_distances=False, return_indices=True)
    h = h[tuple(idx)]
    h = ndimage.gaussian_filter(h, smooth_m / res)
    h -= h.min()
    # Re-centre: x, y relative to the grid's south-west corner.
    return Terrain(h, 0.0, 0.0, res, "OFPEDATA2 HENRYS 2018 (MIT)")


if __name__ == "__main__":  # pragma: no cover - maintenance tool
    t = build_dem(sys.argv[1])
    np.savez_compressed(sys.argv[2], h=t.h.astype(np.float32), x0=t.x0, y0=t.y0, res=t.res)
    print(f"DEM {t.h.shape} cells at {t.res} m, relief {t.h.max() - t.h.min():.1f} m")
