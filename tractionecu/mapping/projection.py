"""WGS84 → metric field frame.

Choice: UTM, computed here in plain numpy/math
---------------------------------------------
The map lives in the UTM zone of the field origin (EPSG:326zz north,
EPSG:327zz south).  Local map coordinates are UTM easting/northing minus the
easting/northing of the fixed field origin::

    x = E(lat, lon) − E(origin)      [m], east along the UTM grid
    y = N(lat, lon) − N(origin)      [m], north along the UTM grid

Why UTM rather than a local tangent plane (ENU):

* every export (GeoTIFF, GeoJSON via WGS84, ISO-XML via WGS84) can name a
  standard EPSG code, so GIS and farm software overlay the map on other
  layers without a custom PROJ string;
* the error of treating UTM metres as ground metres is the UTM scale factor,
  0.9996 … 1.0010 inside a zone: at most 1 mm per metre, i.e. 0.5 mm across a
  0.5 m cell and 1 m across a 1 km field.  That is below GNSS error and far
  below the 1.5/5/10 m fill bands;
* a tangent plane has smaller scale error near the origin but needs the origin
  to be carried to every consumer to be reproduced exactly.

The projection is *not* delegated to pyproj: pyproj plus its PROJ database is
~35 MB, too heavy for the in-cab install (it is only in the ``maps`` extra).
Instead the transverse Mercator is evaluated with Krüger's series to 6th order
in the third flattening n (Karney 2011, "Transverse Mercator with an accuracy
of a few nanometers", J. Geodesy 85:475–485, eqs. 35–36 and 7–11).  Within a
UTM zone (and a few degrees beyond it) the error is below 1 µm; the tests
compare against pyproj to 1 mm.

Angles in degrees where named ``_deg`` / ``lat`` / ``lon``; lengths in m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

# WGS84 ellipsoid
WGS84_A = 6378137.0
"""Semi-major axis [m]."""
WGS84_F = 1.0 / 298.257223563
"""Flattening [-]."""
UTM_K0 = 0.9996
"""UTM central scale factor [-]."""
UTM_FALSE_EASTING = 500_000.0
"""[m]"""
UTM_FALSE_NORTHING_SOUTH = 10_000_000.0
"""[m]"""

_N = WGS84_F / (2.0 - WGS84_F)
_E2 = WGS84_F * (2.0 - WGS84_F)
_E = math.sqrt(_E2)
_A_RECT = WGS84_A / (1.0 + _N) * (1.0 + _N**2 / 4.0 + _N**4 / 64.0 + _N**6 / 256.0)
"""Rectifying radius A [m]."""

_n = _N
_ALPHA = (
    _n / 2 - 2 * _n**2 / 3 + 5 * _n**3 / 16 + 41 * _n**4 / 180 - 127 * _n**5 / 288 + 7891 * _n**6 / 37800,
    13 * _n**2 / 48 - 3 * _n**3 / 5 + 557 * _n**4 / 1440 + 281 * _n**5 / 630 - 1983433 * _n**6 / 1935360,
    61 * _n**3 / 240 - 103 * _n**4 / 140 + 15061 * _n**5 / 26880 + 167603 * _n**6 / 181440,
    49561 * _n**4 / 161280 - 179 * _n**5 / 168 + 6601661 * _n**6 / 7257600,
    34729 * _n**5 / 80640 - 3418889 * _n**6 / 1995840,
    212378941 * _n**6 / 319334400,
)
_BETA = (
    _n / 2 - 2 * _n**2 / 3 + 37 * _n**3 / 96 - _n**4 / 360 - 81 * _n**5 / 512 + 96199 * _n**6 / 604800,
    _n**2 / 48 + _n**3 / 15 - 437 * _n**4 / 1440 + 46 * _n**5 / 105 - 1118711 * _n**6 / 3870720,
    17 * _n**3 / 480 - 37 * _n**4 / 840 - 209 * _n**5 / 4480 + 5569 * _n**6 / 90720,
    4397 * _n**4 / 161280 - 11 * _n**5 / 504 - 830251 * _n**6 / 7257600,
    4583 * _n**5 / 161280 - 108847 * _n**6 / 3991680,
    20648693 * _n**6 / 638668800,
)
del _n


def utm_zone(lat_deg: float, lon_deg: float) -> tuple[int, bool]:
    """UTM zone number and hemisphere (``south``) of a point.

    Includes the Norway (32V) and Svalbard (31X–37X) exceptions.
    """
    if not (-80.0 <= lat_deg <= 84.0):
        raise ValueError(f"latitude {lat_deg}° outside the UTM range [-80, 84]")
    lon = ((lon_deg + 180.0) % 360.0) - 180.0
    zone = int(math.floor((lon + 180.0) / 6.0)) + 1
    zone = min(zone, 60)
    if 56.0 <= lat_deg < 64.0 and 3.0 <= lon < 12.0:
        zone = 32
    if lat_deg >= 72.0:
        if 0.0 <= lon < 9.0:
            zone = 31
        elif 9.0 <= lon < 21.0:
            zone = 33
        elif 21.0 <= lon < 33.0:
            zone = 35
        elif 33.0 <= lon < 42.0:
            zone = 37
    return zone, lat_deg < 0.0


def utm_epsg(zone: int, south: bool) -> int:
    """EPSG code of a WGS84 / UTM zone."""
    if not 1 <= zone <= 60:
        raise ValueError(f"UTM zone {zone} outside 1..60")
    return (32700 if south else 32600) + zone


class TransverseMercator:
    """Ellipsoidal transverse Mercator on WGS84 (Krüger series, order 6).

    ``forward`` / ``inverse`` accept scalars (evaluated with :mod:`math`,
    ~3 µs) or arrays (numpy, vectorised).
    """

    def __init__(self, lon0_deg: float, k0: float = UTM_K0, false_easting: float = UTM_FALSE_EASTING,
                 false_northing: float = 0.0) -> None:
        self.lon0_deg = float(lon0_deg)
        self.k0 = float(k0)
        self.false_easting = float(false_easting)
        self.false_northing = float(false_northing)
        self._ka = self.k0 * _A_RECT

    # -- scalar -------------------------------------------------------------
    def _forward_scalar(self, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        phi = math.radians(lat_deg)
        lam = math.radians(((lon_deg - self.lon0_deg + 180.0) % 360.0) - 180.0)
        tau = math.tan(phi)
        sigma = math.sinh(_E * math.atanh(_E * tau / math.hypot(1.0, tau)))
        taup = tau * math.hypot(1.0, sigma) - sigma * math.hypot(1.0, tau)
        coslam = math.cos(lam)
        xip = math.atan2(taup, coslam)
        etap = math.asinh(math.sin(lam) / math.hypot(taup, coslam))
        xi, eta = xip, etap
        for j, al in enumerate(_ALPHA, start=1):
            xi += al * math.sin(2 * j * xip) * math.cosh(2 * j * etap)
            eta += al * math.cos(2 * j * xip) * math.sinh(2 * j * etap)
        return self.false_easting + self._ka * eta, self.false_northing + self._ka * xi

    def _inverse_scalar(self, easting: float, northing: float) -> tuple[float, float]:
        xi = (northing - self.false_northing) / self._ka
        eta = (easting - self.false_easting) / self._ka
        xip, etap = xi, eta
        for j, be in enumerate(_BETA, start=1):
            xip -= be * math.sin(2 * j * xi) * math.cosh(2 * j * eta)
            etap -= be * math.cos(2 * j * xi) * math.sinh(2 * j * eta)
        sh = math.sinh(etap)
        c = math.cos(xip)
        taup = math.sin(xip) / math.hypot(sh, c)
        lam = math.atan2(sh, c)
        tau = taup
        for _ in range(5):
            sq = math.hypot(1.0, tau)
            sig = math.sinh(_E * math.atanh(_E * tau / sq))
            taui = tau * math.hypot(1.0, sig) - sig * sq
            dtau = (taup - taui) / math.hypot(1.0, taui) * (1.0 + (1.0 - _E2) * tau * tau) / ((1.0 - _E2) * sq)
            tau += dtau
            if abs(dtau) < 1e-15:
                break
        lon = self.lon0_deg + math.degrees(lam)
        lon = ((lon + 180.0) % 360.0) - 180.0
        return math.degrees(math.atan(tau)), lon

    # -- vectorised ----------------------------------------------------------
    def forward(self, lat_deg: ArrayLike, lon_deg: ArrayLike):
        """(lat, lon) [deg] → (easting, northing) [m]."""
        if np.ndim(lat_deg) == 0 and np.ndim(lon_deg) == 0:
            return self._forward_scalar(float(lat_deg), float(lon_deg))  # type: ignore[arg-type]
        phi = np.radians(np.asarray(lat_deg, dtype=float))
        lam = np.radians(((np.asarray(lon_deg, dtype=float) - self.lon0_deg + 180.0) % 360.0) - 180.0)
        tau = np.tan(phi)
        sigma = np.sinh(_E * np.arctanh(_E * tau / np.hypot(1.0, tau)))
        taup = tau * np.hypot(1.0, sigma) - sigma * np.hypot(1.0, tau)
        coslam = np.cos(lam)
        xip = np.arctan2(taup, coslam)
        etap = np.arcsinh(np.sin(lam) / np.hypot(taup, coslam))
        xi = xip.copy()
        eta = etap.copy()
        for j, al in enumerate(_ALPHA, start=1):
            xi += al * np.sin(2 * j * xip) * np.cosh(2 * j * etap)
            eta += al * np.cos(2 * j * xip) * np.sinh(2 * j * etap)
        return self.false_easting + self._ka * eta, self.false_northing + self._ka * xi

    def inverse(self, easting: ArrayLike, northing: ArrayLike):
        """(easting, northing) [m] → (lat, lon) [deg]."""
        if np.ndim(easting) == 0 and np.ndim(northing) == 0:
            return self._inverse_scalar(float(easting), float(northing))  # type: ignore[arg-type]
        xi = (np.asarray(northing, dtype=float) - self.false_northing) / self._ka
        eta = (np.asarray(easting, dtype=float) - self.false_easting) / self._ka
        xi, eta = np.broadcast_arrays(xi, eta)
        xip = xi.copy()
        etap = eta.copy()
        for j, be in enumerate(_BETA, start=1):
            xip -= be * np.sin(2 * j * xi) * np.cosh(2 * j * eta)
            etap -= be * np.cos(2 * j * xi) * np.sinh(2 * j * eta)
        sh = np.sinh(etap)
        c = np.cos(xip)
        taup = np.sin(xip) / np.hypot(sh, c)
        lam = np.arctan2(sh, c)
        tau = taup.copy()
        for _ in range(5):
            sq = np.hypot(1.0, tau)
            sig = np.sinh(_E * np.arctanh(_E * tau / sq))
            taui = tau * np.hypot(1.0, sig) - sig * sq
            tau = tau + (taup - taui) / np.hypot(1.0, taui) * (1.0 + (1.0 - _E2) * tau * tau) / ((1.0 - _E2) * sq)
        lon = self.lon0_deg + np.degrees(lam)
        lon = ((lon + 180.0) % 360.0) - 180.0
        return np.degrees(np.arctan(tau)), lon


def meridian_radius(lat_deg: float) -> float:
    """Meridional radius of curvature M(φ) [m]."""
    s = math.sin(math.radians(lat_deg))
    return WGS84_A * (1.0 - _E2) / (1.0 - _E2 * s * s) ** 1.5


def normal_radius(lat_deg: float) -> float:
    """Prime-vertical radius of curvature N(φ) [m]."""
    s = math.sin(math.radians(lat_deg))
    return WGS84_A / math.sqrt(1.0 - _E2 * s * s)


@dataclass(frozen=True)
class FieldFrame:
    """Metric map frame: UTM of the origin's zone, shifted to the origin.

    ``x`` [m] points along UTM grid east, ``y`` [m] along UTM grid north; the
    origin (``origin_lat``, ``origin_lon`` [deg]) is (0, 0).  ``zone`` /
    ``south`` default to the origin's zone; give them to pin a zone.
    """

    origin_lat: float
    origin_lon: float
    zone: int = 0
    south: bool | None = None
    easting0: float = field(init=False, default=0.0)
    """UTM easting of the origin [m] (derived)."""
    northing0: float = field(init=False, default=0.0)
    """UTM northing of the origin [m] (derived)."""

    def __post_init__(self) -> None:
        lat, lon = float(self.origin_lat), float(self.origin_lon)
        if not (math.isfinite(lat) and math.isfinite(lon)):
            raise ValueError("field origin must be finite")
        if not -180.0 <= lon <= 180.0:
            raise ValueError(f"origin longitude {lon}° outside [-180, 180]")
        zone, south = utm_zone(lat, lon)
        if self.zone:
            zone = int(self.zone)
        if self.south is not None:
            south = bool(self.south)
        object.__setattr__(self, "zone", zone)
        object.__setattr__(self, "south", south)
        tm = TransverseMercator(lon0_deg=-183.0 + 6.0 * zone,
                                false_northing=UTM_FALSE_NORTHING_SOUTH if south else 0.0)
        object.__setattr__(self, "_tm", tm)
        e0, n0 = tm.forward(lat, lon)
        object.__setattr__(self, "easting0", e0)
        object.__setattr__(self, "northing0", n0)


    @property
    def epsg(self) -> int:
        return utm_epsg(self.zone, bool(self.south))

    @property
    def crs(self) -> str:
        """CRS as an ``EPSG:nnnnn`` string."""
        return f"EPSG:{self.epsg}"

    def to_local(self, lat_deg: ArrayLike, lon_deg: ArrayLike):
        """(lat, lon) [deg] → local (x, y) [m]."""
        e, n = self._tm.forward(lat_deg, lon_deg)  # type: ignore[attr-defined]
        return e - self.easting0, n - self.northing0

    def to_latlon(self, x: ArrayLike, y: ArrayLike):
        """Local (x, y) [m] → (lat, lon) [deg]."""
        if np.ndim(x) == 0 and np.ndim(y) == 0:
            return self._tm.inverse(float(x) + self.easting0, float(y) + self.northing0)  # type: ignore[attr-defined,arg-type]
        return self._tm.inverse(np.asarray(x, dtype=float) + self.easting0,  # type: ignore[attr-defined]
                                np.asarray(y, dtype=float) + self.northing0)


__all__ = [
    "FieldFrame",
    "TransverseMercator",
    "meridian_radius",
    "normal_radius",
    "utm_epsg",
    "utm_zone",
]
