import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tractionecu.mapping.fill import band_radii_cells, diamond_sums, paper_fill, paper_fill_naive


def reference_fill(m, res, eps=(10.0, 5.0, 1.5), weights=(0.1, 0.5, 4.0)):
    """Literal per-cell reading of the paper with the normalised sum: for every
    cell, loop over every other cell, put it in a band by its Manhattan
    distance in metres, average each band, weight, normalise."""
    e_low, e_mid, e_high = eps
    w_low, w_mid, w_high = weights
    h, w = m.shape
    out = np.full(m.shape, np.nan)
    tol = 1 + 1e-9
    for i in range(h):
        for j in range(w):
            sums = [0.0, 0.0, 0.0]
            counts = [0, 0, 0]
            for e in range(h):
                for f in range(w):
                    if not np.isfinite(m[e, f]):
                        continue
                    d = res * (abs(e - i) + abs(f - j))
                    if d <= e_high * tol:
                        b = 0
                    elif d <= e_mid * tol:
                        b = 1
                    elif d <= e_low * tol:
                        b = 2
                    else:
                        continue
                    sums[b] += m[e, f]
                    counts[b] += 1
            num = den = 0.0
            for b, wb in enumerate((w_high, w_mid, w_low)):
                if counts[b]:
                    num += wb * sums[b] / counts[b]
                    den += wb
            if den:
                out[i, j] = num / den
    return out


def sparse_random(rng, shape, frac):
    m = rng.uniform(0.2, 1.0, shape)
    m[rng.uniform(size=shape) > frac] = np.nan
    return m


@pytest.mark.parametrize("res,shape,frac", [(0.5, (13, 17), 0.15), (1.0, (25, 22), 0.1),
                                            (0.7, (16, 15), 0.3), (2.0, (9, 12), 0.5)])
def test_matches_per_cell_reference(res, shape, frac):
    rng = np.random.default_rng(11)
    m = sparse_random(rng, shape, frac)
    ref = reference_fill(m, res)
    got = paper_fill(m, res)
    assert np.array_equal(np.isnan(got), np.isnan(ref))
    assert np.nanmax(np.abs(got - ref)) < 1e-9
    # blocking does not change the result
    assert np.nanmax(np.abs(paper_fill(m, res, block_cells=4) - ref)) < 1e-9


def test_naive_matches_vectorised_on_a_larger_grid():
    rng = np.random.default_rng(5)
    m = sparse_random(rng, (60, 70), 0.05)
    a = paper_fill(m, 0.5)
    b = paper_fill_naive(m, 0.5)
    assert np.array_equal(np.isnan(a), np.isnan(b))
    assert np.nanmax(np.abs(a - b)) < 1e-9


def test_bands_are_inclusive_at_the_outer_limit():
    # 0.5 m cells: ε_high = 1.5 m is 3 cells, ε_mid = 5 m is 10, ε_low = 10 m is 20
    assert band_radii_cells(0.5) == (20, 10, 3)
    m = np.full((1, 45), np.nan)
    m[0, 0] = 1.0
    f = paper_fill(m, 0.5)
    assert np.isfinite(f[0, 20]) and np.isnan(f[0, 21])
    # the innermost band includes the cell itself (d = 0)
    m = np.full((1, 9), np.nan)
    m[0, 4] = 2.0
    m[0, 0] = 0.0  # 2 m away: middle band for cell 4
    f = paper_fill(m, 0.5)
    assert f[0, 4] == pytest.approx((4.0 * 2.0 + 0.5 * 0.0) / 4.5)


def test_weights_and_normalisation_of_populated_bands():
    # cell 0 at the centre; one value in each band
    m = np.full((1, 41), np.nan)
    m[0, 20] = 1.0  # d = 0 → high
    m[0, 25] = 2.0  # d = 2.5 m → mid
    m[0, 34] = 3.0  # d = 7 m → low
    f = paper_fill(m, 0.5)
    assert f[0, 20] == pytest.approx((4 * 1.0 + 0.5 * 2.0 + 0.1 * 3.0) / 4.6, rel=1e-12)
    # the unnormalised paper sum would be 4.6 times a constant: check it is not
    c = np.where(np.isfinite(m), 0.8, np.nan)
    assert paper_fill(c, 0.5)[0, 20] == pytest.approx(0.8, rel=1e-12)


def test_constant_field_stays_constant():
    rng = np.random.default_rng(3)
    m = np.full((80, 90), np.nan)
    m[rng.uniform(size=m.shape) < 0.02] = 0.731
    f = paper_fill(m, 0.5)
    assert np.isfinite(f).sum() > 0.5 * f.size
    assert np.nanmax(np.abs(f - 0.731)) < 1e-12


@settings(max_examples=40, deadline=None)
@given(c=st.floats(-1e3, 1e3, allow_nan=False), res=st.sampled_from([0.25, 0.5, 0.8, 1.0, 3.0]),
       seed=st.integers(0, 2**31), frac=st.floats(0.01, 1.0), h=st.integers(1, 30), w=st.integers(1, 30))
def test_constant_field_stays_constant_property(c, res, seed, frac, h, w):
    rng = np.random.default_rng(seed)
    m = np.full((h, w), np.nan)
    m[rng.uniform(size=m.shape) < frac] = c
    f = paper_fill(m, res)
    fin = np.isfinite(f)
    assert np.all(np.abs(f[fin] - c) <= 1e-12 * max(1.0, abs(c)))
    # every measured cell gets a value
    assert np.all(fin[np.isfinite(m)])


def test_empty_and_preserve_measured():
    assert np.isnan(paper_fill(np.full((5, 5), np.nan), 0.5)).all()
    m = np.full((10, 10), np.nan)
    m[2, 2], m[2, 4] = 1.0, 3.0
    f = paper_fill(m, 0.5, preserve_measured=True)
    assert f[2, 2] == 1.0 and f[2, 4] == 3.0
    assert paper_fill(m, 0.5)[2, 2] != 1.0


def test_diamond_sums_counts():
    rng = np.random.default_rng(1)
    valid = rng.uniform(size=(15, 11)) < 0.4
    vals = np.where(valid, rng.normal(size=valid.shape), 0.0)
    (s, c), = diamond_sums(vals, valid, [4])
    ii, jj = np.indices(valid.shape)
    for i, j in [(0, 0), (7, 5), (14, 10), (3, 9)]:
        ball = (np.abs(ii - i) + np.abs(jj - j)) <= 4
        assert c[i, j] == valid[ball].sum()
        assert s[i, j] == pytest.approx(vals[ball].sum(), abs=1e-12)


def test_rejects_bad_arguments():
    with pytest.raises(ValueError):
        paper_fill(np.zeros((3, 3)), 0.0)
    with pytest.raises(ValueError):
        paper_fill(np.zeros((3, 3)), 0.5, eps_m=(1.0, 5.0, 10.0))
    with pytest.raises(ValueError):
        paper_fill(np.zeros(3), 0.5)
