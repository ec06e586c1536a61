import math

import numpy as np
import pytest

from tractionecu.mapping.grid import TileStats
from tractionecu.mapping.store import MapStore

from map_synth import ORIGIN


def test_welford_cells_match_numpy():
    rng = np.random.default_rng(2)
    layers = ("a", "rho_s", "mu")
    ts = TileStats(layers, 8)
    samples: dict[tuple[int, int, int], list[float]] = {}
    for _ in range(3000):
        r, c = int(rng.integers(0, 8)), int(rng.integers(0, 3))
        present = [li for li in range(3) if rng.uniform() < 0.7]
        pairs = [(li, float(rng.normal(0.06 * (li + 1), 1e-3) + 1e4 * (li == 2))) for li in present]
        ts.add(r, c, pairs)
        for li, v in pairs:
            samples.setdefault((li, r, c), []).append(v)
    var = ts.variance()
    for (li, r, c), vs in samples.items():
        v = np.array(vs)
        assert ts.count[li, r, c] == len(v)
        assert ts.mean[li, r, c] == pytest.approx(v.mean(), rel=1e-13, abs=1e-15)
        if len(v) >= 2:
            assert var[li, r, c] == pytest.approx(v.var(ddof=1), rel=1e-9)
        else:
            assert math.isnan(var[li, r, c])
    untouched = np.ones((3, 8, 8), bool)
    for li, r, c in samples:
        untouched[li, r, c] = False
    assert np.all(ts.count[untouched] == 0) and np.all(np.isnan(var[untouched]))


def test_batch_merge_equals_sequential():
    rng = np.random.default_rng(4)
    a = TileStats(("a",), 4)
    b = TileStats(("a",), 4)
    rows = rng.integers(0, 4, 500)
    cols = rng.integers(0, 4, 500)
    vals = rng.normal(0.7, 0.05, 500)
    for r, c, v in zip(rows[:200], cols[:200], vals[:200]):
        a.add(int(r), int(c), [(0, float(v))])
        b.add(int(r), int(c), [(0, float(v))])
    for r, c, v in zip(rows[200:], cols[200:], vals[200:]):
        a.add(int(r), int(c), [(0, float(v))])
    b.merge_batch(0, rows[200:], cols[200:], vals[200:])
    assert np.array_equal(a.count, b.count)
    assert np.allclose(a.mean, b.mean, rtol=1e-13, atol=1e-15)
    assert np.allclose(a.m2, b.m2, rtol=1e-9, atol=1e-15)


def test_store_grid_statistics_match_numpy(tmp_path):
    rng = np.random.default_rng(9)
    st = MapStore(tmp_path / "m", *ORIGIN, resolution_m=1.0, tile_cells=4)
    x = rng.uniform(0, 9.99, 4000)
    y = rng.uniform(-5, 4.99, 4000)
    lat, lon = st.to_latlon(x, y)
    a = rng.normal(0.6, 0.1, 4000)
    for i in range(4000):
        assert st.add(float(lat[i]), float(lon[i]), {"a": a[i]}, 0.1 * i)
    # the cell of every sample from its (independently rounded) local position
    xs, ys = st.to_local(lat, lon)
    col, row = np.floor(xs).astype(int), np.floor(ys).astype(int)
    g = st.grid("a")
    assert (g.x0, g.y0, g.res) == (col.min() * 1.0, row.min() * 1.0, 1.0)
    assert g.shape == (row.max() - row.min() + 1, col.max() - col.min() + 1)
    for r in range(row.min(), row.max() + 1):
        for c in range(col.min(), col.max() + 1):
            sel = (row == r) & (col == c)
            k = (r - row.min(), c - col.min())
            assert g.count[k] == sel.sum()
            if sel.any():
                assert g.mean[k] == pytest.approx(a[sel].mean(), rel=1e-12)
                if sel.sum() > 1:
                    assert g.var[k] == pytest.approx(a[sel].var(ddof=1), rel=1e-9)
            else:
                assert np.isnan(g.mean[k])
    mean, x0, y0, res = st.mean_grid("a")
    assert np.array_equal(mean, g.mean, equal_nan=True) and (x0, y0, res) == (g.x0, g.y0, 1.0)
    # a layer never added has an empty extent
    assert st.mean_grid("rho_s")[0].shape == (0, 0)
    st.close()
