import math

import numpy as np
import pytest

from tractionecu.mapping.projection import FieldFrame, TransverseMercator, utm_epsg, utm_zone

pyproj = pytest.importorskip("pyproj")


@pytest.mark.parametrize("lat0,lon0", [(50.91, 13.34), (-33.9, 151.2), (60.5, 5.3), (78.2, 15.6),
                                       (0.2, -0.4), (45.0, -93.2), (-45.0, 170.0)])
def test_utm_matches_pyproj_to_a_millimetre(lat0, lon0):
    rng = np.random.default_rng(7)
    f = FieldFrame(lat0, lon0)
    tr = pyproj.Transformer.from_crs("EPSG:4326", f.crs, always_xy=True)
    lat = lat0 + rng.uniform(-0.2, 0.2, 500)
    lon = lon0 + rng.uniform(-0.3, 0.3, 500)
    e_ref, n_ref = tr.transform(lon, lat)
    x, y = f.to_local(lat, lon)
    assert np.max(np.hypot(x + f.easting0 - e_ref, y + f.northing0 - n_ref)) < 1e-3
    # scalar path agrees with the vectorised one
    xs, ys = f.to_local(float(lat[3]), float(lon[3]))
    assert abs(xs - x[3]) < 1e-9 and abs(ys - y[3]) < 1e-9
    # inverse round trip: 1e-9 deg ≈ 0.1 mm
    la, lo = f.to_latlon(x, y)
    assert np.max(np.abs(la - lat)) < 1e-9 and np.max(np.abs(lo - lon)) < 1e-9


def test_origin_is_zero_and_axes_point_east_north():
    f = FieldFrame(50.91, 13.34)
    assert f.to_local(50.91, 13.34) == pytest.approx((0.0, 0.0), abs=1e-9)
    x, y = f.to_local(50.91 + 1e-3, 13.34)  # ~111 m north
    assert 110.0 < y < 112.0
    # true north is rotated from grid north by the meridian convergence
    # γ ≈ (λ0 − λ)·sin φ (here the origin is 1.66° west of the central meridian 15° E)
    gamma = (15.0 - 13.34) * math.sin(math.radians(50.91))
    assert math.degrees(math.atan2(x, y)) == pytest.approx(gamma, abs=0.01)
    x, y = f.to_local(50.91, 13.34 + 1e-3)  # ~70 m east
    assert 69.0 < x < 71.0 and abs(y) < 2.0


def test_zone_rules_and_epsg():
    assert utm_zone(50.9, 13.3) == (33, False)
    assert utm_zone(-33.9, 151.2) == (56, True)
    assert utm_zone(60.0, 5.0) == (32, False)  # Norway exception
    assert utm_zone(78.0, 10.0) == (33, False)  # Svalbard exception
    assert utm_epsg(33, False) == 32633 and utm_epsg(56, True) == 32756
    with pytest.raises(ValueError):
        utm_zone(85.0, 0.0)


def test_scalar_inverse_matches_pyproj():
    tm = TransverseMercator(15.0)
    tr = pyproj.Transformer.from_crs("EPSG:32633", "EPSG:4326", always_xy=True)
    lon, lat = tr.transform(412345.6, 5641234.5)
    la, lo = tm.inverse(412345.6, 5641234.5)
    assert math.isclose(la, lat, abs_tol=1e-10) and math.isclose(lo, lon, abs_tol=1e-10)
