"""The centred map window: online (service) and offline (replay) give the same values."""

from types import SimpleNamespace

import numpy as np
import pytest

from tractionecu.mapping.sampler import CentredSampler, centred_map_values
from tractionecu.model.mucurve import SOIL_CLASSES


def _run(n=400, seed=0):
    rng = np.random.default_rng(seed)
    t = 1000.0 + 0.1 * np.arange(n)
    s_true = np.where(t < t[n // 2], 0.05, 0.10)
    a_true = np.where(t < t[n // 2], 0.8, 0.6)
    slip = s_true[:, None] + rng.normal(0, 0.003, (n, 4))
    mu = SOIL_CLASSES["stubble"].mu(s_true, a_true)[:, None] + rng.normal(0, 0.003, (n, 4))
    var_mu = np.full((n, 4), 1e-5)
    v = np.full(n, 2.5)
    rho = 0.06 + rng.normal(0, 0.002, n)
    cls = ["stubble"] * n
    return t, mu, slip, var_mu, v, rho, cls, a_true


def test_online_equals_offline():
    t, mu, slip, var_mu, v, rho, cls, _ = _run()
    off = centred_map_values(t, mu, slip, var_mu, v, rho, cls, half_window_s=2.0)
    smp = CentredSampler(half_window_s=2.0)
    got = []
    for k in range(t.size):
        P = np.zeros(10)
        P[5:9] = var_mu[k]
        est = SimpleNamespace(mu=mu[k], slip=slip[k], P_diag=P, v=v[k], rho_s=rho[k], valid=True, status=0,
                              soil_class="stubble")
        got += smp.push(float(t[k]), 47.0, 8.0, 4, 0.8, est)
    got += smp.drain()
    assert [g[0] for g in got] == pytest.approx(list(t))
    for key in ("a", "rho_s", "mu", "p"):
        assert np.array([g[3][key] for g in got]) == pytest.approx(off[key], rel=1e-9, nan_ok=True)


def test_window_is_centred_so_boundaries_do_not_move():
    t, mu, slip, var_mu, v, rho, cls, a_true = _run(n=600)
    off = centred_map_values(t, mu, slip, var_mu, v, rho, cls, half_window_s=3.0)
    # Away from the change by more than the window, a is the true value; at the change it is in between.
    far = np.abs(t - t[300]) > 3.5
    assert np.nanmax(np.abs(off["a"][far] - a_true[far])) < 0.03
    mid = off["a"][299:301].mean()
    assert 0.65 < mid < 0.75


def test_ill_conditioned_pairs_give_nan_not_garbage():
    t, mu, slip, var_mu, v, rho, cls, _ = _run(n=50)
    slip[:] = 0.001  # below MIN_SLIP everywhere
    off = centred_map_values(t, mu, slip, var_mu, v, rho, cls, half_window_s=1.0)
    assert np.all(np.isnan(off["a"]))


def test_a_lost_period_is_not_mapped_and_leaves_every_window():
    """After ``invalidate_since`` (the estimator was lost since then) the samples of that period come out
    not valid with the lost bit, and the windows of the samples before it no longer hold their values."""
    from tractionecu.mapping.store import STATUS_FILTER_LOST

    t, mu, slip, var_mu, v, rho, cls, _ = _run()
    t_lost = float(t[150])
    mu_bad = mu.copy()
    mu_bad[150:] = 0.05                       # what a lost filter said
    smp = CentredSampler(half_window_s=2.0)
    got = []
    for k in range(t.size):
        if k == 165:                          # found 1.5 s late, while t[149]'s window (to t[169]) is open
            smp.invalidate_since(t_lost)
        P = np.zeros(10)
        P[5:9] = var_mu[k]
        m = mu_bad[k] if k < 165 else mu[k]
        est = SimpleNamespace(mu=m, slip=slip[k], P_diag=P, v=v[k], rho_s=rho[k], valid=True, status=0,
                              soil_class="stubble")
        got += smp.push(float(t[k]), 47.0, 8.0, 4, 0.8, est)
    got += smp.drain()
    tt = np.array([g[0] for g in got])
    lost = (tt >= t_lost) & (tt < t[165])
    assert not any(g[4] for g, bad in zip(got, lost) if bad)
    assert all(g[5] & STATUS_FILTER_LOST for g, bad in zip(got, lost) if bad)
    assert all(g[4] for g, bad in zip(got, lost) if not bad)
    # the last sample before the lost period averages the good values around it, none of the lost ones
    k = int(np.flatnonzero(tt < t_lost)[-1])
    mu_ref, rho_ref = mu[:170].copy(), rho[:170].copy()
    mu_ref[150:165] = np.nan
    rho_ref[150:165] = np.nan
    ref = centred_map_values(t[:170], mu_ref, slip[:170], var_mu[:170], v[:170], rho_ref, cls[:170], 2.0)
    assert got[k][3]["a"] == pytest.approx(ref["a"][149], rel=1e-9)
    assert got[k][3]["rho_s"] == pytest.approx(ref["rho_s"][149], rel=1e-9)


@pytest.mark.parametrize("bit", [0x2000, 0x10000])
def test_held_or_averaged_slip_makes_no_pair_for_the_map(bit):
    """A slip the step's own σ does not support (0x2000) or one averaged over the last metres of travel
    (0x10000, reversing or creeping) beside this step's μ gives the map no (μ, s) pair, so no a."""
    t, mu, slip, var_mu, v, rho, cls, _ = _run(n=60)
    smp = CentredSampler(half_window_s=2.0)
    got = []
    for k in range(t.size):
        P = np.zeros(10)
        P[5:9] = var_mu[k]
        est = SimpleNamespace(mu=mu[k], slip=slip[k], P_diag=P, v=v[k], rho_s=rho[k], valid=True,
                              status=bit, soil_class="stubble")
        got += smp.push(float(t[k]), 47.0, 8.0, 4, 0.8, est)
    got += smp.drain()
    assert len(got) == t.size
    assert all(np.isnan(g[3]["a"]) for g in got)
    assert all(np.isfinite(g[3]["rho_s"]) for g in got)


def test_a_curve_shape_outside_the_surface_classes_maps_its_a_and_shape():
    """The machine-level estimator's ``d497`` prior (model.mucurve.CURVE_SHAPES) is no surface class: its
    a layer was NaN (the class was looked up in SOIL_CLASSES only); it is a = μ/g_d497(s), online and offline."""
    from tractionecu.model.mucurve import CURVE_SHAPES

    d497 = CURVE_SHAPES["d497"]
    rng = np.random.default_rng(3)
    n = 300
    t = 0.1 * np.arange(n)
    s_true = np.full(n, 0.06)
    slip = s_true[:, None] + rng.normal(0, 0.002, (n, 4))
    mu = d497.mu(s_true, 0.8)[:, None] + rng.normal(0, 0.003, (n, 4))
    var_mu, v, rho, cls = np.full((n, 4), 1e-5), np.full(n, 2.5), np.full(n, 0.06), ["d497"] * n
    off = centred_map_values(t, mu, slip, var_mu, v, rho, cls, half_window_s=2.0)
    assert np.isfinite(off["a"]).all() and np.abs(off["a"] - 0.8).max() < 0.03
    assert set(off["p"]) == {1.0} and set(off["alpha1"]) == set(off["alpha2"]) == {-7.5}
    smp = CentredSampler(half_window_s=2.0)
    got = []
    for k in range(n):
        P = np.zeros(10)
        P[5:9] = var_mu[k]
        est = SimpleNamespace(mu=mu[k], slip=slip[k], P_diag=P, v=v[k], rho_s=rho[k], valid=True, status=0,
                              soil_class="d497")
        got += smp.push(float(t[k]), 47.0, 8.0, 4, 0.8, est)
    got += smp.drain()
    for key in ("a", "p", "alpha1", "alpha2"):
        assert np.array([g[3][key] for g in got]) == pytest.approx(off[key], rel=1e-9)
    # a name in neither registry still maps no a (and no shape), as before
    none = centred_map_values(t, mu, slip, var_mu, v, rho, ["loam"] * n, half_window_s=2.0)
    assert np.isnan(none["a"]).all() and np.isnan(none["p"]).all()
