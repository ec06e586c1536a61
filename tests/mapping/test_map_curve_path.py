"""Per map cell: how its μ(s) was identified (class path or fitted shape), and the sampler mapping
a fitted shape's parameters (issue 13, item 6)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from tractionecu.mapping.sampler import CentredSampler, centred_map_values
from tractionecu.mapping.store import MapStore
from tractionecu.model.mucurve import SOIL_CLASSES, MuCurve

LAT0, LON0 = 47.88, -110.55
STUBBLE = SOIL_CLASSES["stubble"]
SHAPE = MuCurve("eq14", (0.85, -1.5, -20.0, -12.0), np.eye(4) * 1e-4, "shape:eq14")


def _values(c):
    return {"a": c.a, "p": c.p, "alpha1": c.alpha1, "alpha2": c.alpha2, "rho_s": 0.06, "mu": 0.3}


def test_cells_report_their_curve_path(tmp_path):
    with MapStore(tmp_path / "m", LAT0, LON0, resolution_m=1.0) as store:
        lat_w, lon_w = store.to_latlon(0.5, 0.5)
        lat_e, lon_e = store.to_latlon(5.5, 0.5)
        lat_x, lon_x = store.to_latlon(9.5, 0.5)
        for k in range(3):
            assert store.add(lat_w, lon_w, _values(MuCurve.from_class(STUBBLE, 0.7 + 0.01 * k)), float(k))
            assert store.add(lat_e, lon_e, _values(SHAPE), float(k))
        # a cell of mixed paths has no single class shape: not a class cell
        store.add(lat_x, lon_x, _values(MuCurve.from_class(STUBBLE, 0.7)), 3.0)
        store.add(lat_x, lon_x, _values(SHAPE), 4.0)
        paths = store.curve_paths()
        g = store.grid("p")
    col = lambda x: int(math.floor((x - g.x0) / g.res))  # noqa: E731
    row = int(math.floor((0.5 - g.y0) / g.res))
    assert paths[row, col(0.5)] == "class:stubble"
    assert paths[row, col(5.5)] == "shape"
    assert paths[row, col(9.5)] == "shape"
    assert paths[row, col(3.5)] == ""                         # no sample


def test_sampler_maps_the_fitted_shape():
    n = 40
    t = np.arange(n) * 0.1
    s = np.full((n, 4), 0.08)
    mu = np.full((n, 4), float(STUBBLE.mu(0.08, 0.7)))
    curves = [None] * 20 + [SHAPE] * 20
    vals = centred_map_values(t, mu, s, np.full((n, 4), 1e-4), np.full(n, 2.0), np.full(n, 0.06),
                              ["stubble"] * n, 1.0, curves=curves)
    assert vals["p"][0] == STUBBLE.p and vals["a"][0] == np.float64(vals["a"][0])
    assert (vals["a"][-1], vals["p"][-1], vals["alpha1"][-1], vals["alpha2"][-1]) == SHAPE.theta
    # online, the same per sample
    smp = CentredSampler(1.0)
    out = []
    for k in range(n):
        est = SimpleNamespace(mu=mu[k], slip=s[k], P_diag=np.full(10, 1e-4), v=2.0, rho_s=0.06, valid=True,
                              status=0, soil_class="stubble", curve=curves[k])
        out += smp.push(float(t[k]), LAT0, LON0, 4, 0.8, est)
    out += smp.drain()
    assert out[0][3]["p"] == STUBBLE.p and out[-1][3]["alpha2"] == SHAPE.alpha2 and out[-1][3]["a"] == SHAPE.a


def test_a_curve_shape_outside_the_surface_classes_is_a_class_cell(tmp_path):
    """Cells of the machine-level estimator's d497 prior (model.mucurve.CURVE_SHAPES) are on the class path:
    ``class:d497``, not ``shape`` (they were, with the surface classes only)."""
    from tractionecu.model.mucurve import CURVE_SHAPES

    with MapStore(tmp_path / "m", LAT0, LON0, resolution_m=1.0) as store:
        lat, lon = store.to_latlon(0.5, 0.5)
        for k in range(3):
            assert store.add(lat, lon, _values(MuCurve.from_class(CURVE_SHAPES["d497"], 0.8 + 0.01 * k)), float(k))
        paths = store.curve_paths()
        g = store.grid("p")
    assert paths[int(math.floor((0.5 - g.y0) / g.res)), int(math.floor((0.5 - g.x0) / g.res))] == "class:d497"
