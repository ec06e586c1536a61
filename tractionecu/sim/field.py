"""The field: soil regions on a local metric plane, with optional real relief.

Local frame: x east, y north [m], origin at (origin_lat, origin_lon).  The
conversion to WGS84 is a local tangent plane (equirectangular about the
origin), accurate to millimetres over a few kilometres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..model.mucurve import SOIL_CLASSES, SoilClass
from .terrain import Terrain

EARTH_R = 6378137.0
"""WGS84 equatorial radius [m]."""


@dataclass(frozen=True)
class SoilRegion:
    """One soil: μ(s) class shape, its curve parameter a and rolling resistance ρ_s."""

    name: str
    soil_class: str
    a: float
    """Curve parameter a [-]."""
    rho_s: float
    """Soil-deformation rolling resistance ρ_s [-]."""
    polygon: tuple[tuple[float, float], ...] = ()
    """Outline (x, y) [m]; empty = background soil."""

    @property
    def cls(self) -> SoilClass:
        return SOIL_CLASSES[self.soil_class]


@dataclass
class Field:
    """Soil regions (later regions overlay earlier ones; region 0 is the background)."""

    regions: list[SoilRegion]
    origin_lat: float = 47.8816
    """Origin latitude [deg] (default: near the HENRYS field, Montana)."""
    origin_lon: float = -110.5534
    """Origin longitude [deg]."""
    origin_alt: float = 862.0
    """Ellipsoidal/MSL altitude of the origin [m]."""
    terrain: Terrain = field(default_factory=Terrain.flat)
    terrain_offset: tuple[float, float] = (0.0, 0.0)
    """Where the field's origin sits on the terrain grid [m]."""
    relief_scale: float = 1.0

    def soil_index(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.int64]:
        """Index of the region under each point."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        out = np.zeros(np.broadcast(x, y).shape, dtype=np.int64)
        for k, reg in enumerate(self.regions):
            if k == 0 or not reg.polygon:
                continue
            out = np.where(point_in_polygon(x, y, reg.polygon), k, out)
        return out

    def elevation(self, x: ArrayLike, y: ArrayLike) -> NDArray[np.float64]:
        """Terrain height above the origin altitude [m]."""
        ox, oy = self.terrain_offset
        return self.relief_scale * self.terrain.elevation(np.asarray(x) + ox, np.asarray(y) + oy)

    def grade(self, x: ArrayLike, y: ArrayLike, heading: ArrayLike) -> NDArray[np.float64]:
        """Grade angle along the heading [rad]."""
        ox, oy = self.terrain_offset
        return np.arctan(self.relief_scale * np.tan(self.terrain.grade(np.asarray(x) + ox, np.asarray(y) + oy, heading)))

    def to_latlon(self, x: ArrayLike, y: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Local (x, y) [m] to WGS84 (lat, lon) [deg]."""
        lat = self.origin_lat + np.degrees(np.asarray(y, dtype=float) / EARTH_R)
        lon = self.origin_lon + np.degrees(np.asarray(x, dtype=float) / (EARTH_R * np.cos(np.radians(self.origin_lat))))
        return lat, lon

    def to_xy(self, lat: ArrayLike, lon: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """WGS84 (lat, lon) [deg] to local (x, y) [m]."""
        y = np.radians(np.asarray(lat, dtype=float) - self.origin_lat) * EARTH_R
        x = np.radians(np.asarray(lon, dtype=float) - self.origin_lon) * EARTH_R * np.cos(np.radians(self.origin_lat))
        return x, y


def point_in_polygon(x: NDArray[np.float64], y: NDArray[np.float64], poly: tuple[tuple[float, float], ...]) -> NDArray[np.bool_]:
    """Even–odd ray casting, vectorised over points."""
    inside = np.zeros(np.broadcast(x, y).shape, dtype=bool)
    n = len(poly)
    for k in range(n):
        x1, y1 = poly[k]
        x2, y2 = poly[(k + 1) % n]
        if y1 == y2:
            continue
        cond = (y1 > y) != (y2 > y)
        xint = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
        inside ^= cond & (x < xint)
    return inside
