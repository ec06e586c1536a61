"""The raw-rate wheel-speed grid of the diagnosis frame (diagnose/data.py): every grid time between two
raw samples gets a value, whatever the samples' phase against the grid.

Regression: the grid was filled by windows one raw period wide around each grid time.  Where the
samples' phase drifted onto the windows' edges, reception jitter put two samples into one window and
none into the next; the empty windows were read downstream as a wheel at standstill."""

import dataclasses

import numpy as np
from tractionecu.diagnose import data
from tractionecu.pipeline.signals import WHEEL_SPEEDS
from tractionecu.recording.containers import Series
from tractionecu.recording.reader import read_recording

DT = 0.01              # raw period [s]
JITTER = 0.0003        # reception jitter [s] (the CAN jitter of the simulated recordings)


def _grid(n_bins: int, k: int = 10, period: float = 0.1) -> np.ndarray:
    g = 1000.0 + np.arange(n_bins) * period
    return (g[:, None] + (np.arange(k) - (k - 1) / 2.0)[None, :] * DT).ravel()


def _edge_samples(grid: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Sample times on the edges of the one-period windows about the grid times, with jitter."""
    edges = np.concatenate([grid - DT / 2, [grid[-1] + DT / 2]])
    return np.sort(edges + rng.uniform(-JITTER / 2, JITTER / 2, edges.size))


def test_samples_on_the_window_edges_leave_no_grid_time_empty():
    rng = np.random.default_rng(3)
    tg = _grid(200)
    ts = _edge_samples(tg, rng)
    # What the one-period windows held: some none, some two.
    lo = np.searchsorted(ts, tg - DT / 2, side="left")
    hi = np.searchsorted(ts, tg + DT / 2, side="left")
    assert ((hi - lo) == 0).sum() > 100 and ((hi - lo) == 2).sum() > 100
    # A linear signal is read exactly at every grid time.
    rg = data._RawGrid(tg, DT, width=1)
    rg.add(ts, 3.0 + 0.5 * (ts - 1000.0))
    v = rg.mean()[:, 0]
    inside = (tg >= ts[0]) & (tg <= ts[-1])
    assert inside.all()
    assert np.isfinite(v).all()
    np.testing.assert_allclose(v, 3.0 + 0.5 * (tg - 1000.0), rtol=0, atol=1e-9)


def test_fed_in_blocks_the_grid_equals_the_grid_fed_whole():
    rng = np.random.default_rng(4)
    tg = _grid(120)
    ts = _edge_samples(tg, rng)
    vs = np.sin(2.0 * np.pi * 1.3 * (ts - 1000.0)) + rng.normal(0.0, 0.01, ts.size)
    whole = data._RawGrid(tg, DT, width=2)
    whole.add(ts, vs, 1)
    parts = data._RawGrid(tg, DT, width=2)
    cuts = np.sort(rng.choice(np.arange(1, ts.size - 1), 17, replace=False))
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, ts.size]):
        parts.add(ts[a:b], vs[a:b], 1)
    np.testing.assert_array_equal(parts.mean()[:, 1], whole.mean()[:, 1])
    assert np.isnan(parts.mean()[:, 0]).all()          # a column never fed stays missing


def test_a_lost_frame_leaves_only_its_grid_times_missing():
    tg = _grid(20)
    ts = np.arange(tg[0] - DT / 2, tg[-1] + DT, DT) + 0.0001
    lost = 57
    keep = np.ones(ts.size, dtype=bool)
    keep[lost] = False
    vs = np.ones(ts.size)
    vs[lost + 5] = np.nan                              # a sample without a value is lost too
    rg = data._RawGrid(tg, DT, width=1)
    rg.add(ts[keep], vs[keep])
    v = rg.mean()[:, 0]
    gone = ((tg > ts[lost - 1]) & (tg < ts[lost + 1])) | ((tg > ts[lost + 4]) & (tg < ts[lost + 6]))
    assert gone.sum() == 4
    assert np.isnan(v[gone]).all()
    assert np.isfinite(v[~gone & (tg >= ts[0])]).all()


def test_a_recording_whose_wheel_samples_sit_on_the_window_edges_has_a_full_raw_grid(short_recording):
    """The frame of a recording whose wheel-speed time stamps are moved onto the old windows' edges
    (with jitter): no raw-rate point is missing, and the values follow the samples."""
    from tractionecu.config import load_vehicle

    rec = read_recording(short_recording)
    veh = load_vehicle(short_recording / "vehicle.toml")
    ref = data.frame_from_recording(rec, veh)
    assert ref.hf_t is not None
    k = ref.hf_omega.shape[0] // ref.n
    hf_epoch = ref.hf_t + ref.t0_epoch
    rng = np.random.default_rng(11)
    sig = dict(rec.signals)
    for name in WHEEL_SPEEDS:
        s = sig[name]
        n = len(s)
        # Sample j stamped on the lower edge of raw window j of the grid (± half the jitter), spacing kept.
        t_new = hf_epoch[0] - DT / 2 + np.arange(n) * DT + rng.uniform(-JITTER / 2, JITTER / 2, n)
        sig[name] = Series(np.sort(t_new), s.value.copy(), s.sa.copy(), s.unit)
    moved = dataclasses.replace(rec, signals=sig)
    fr = data.frame_from_recording(moved, veh)
    assert fr.hf_omega.shape == ref.hf_omega.shape and fr.n == ref.n and k == 10
    tg = fr.hf_t + fr.t0_epoch
    t0, v0 = sig[WHEEL_SPEEDS[0]].t, sig[WHEEL_SPEEDS[0]].value
    # The one-period windows of before would leave some of these grid times without a sample.
    lo = np.searchsorted(t0, tg - DT / 2, side="left")
    hi = np.searchsorted(t0, tg + DT / 2, side="left")
    inside = tg <= min(float(sig[nm].t[-1]) for nm in WHEEL_SPEEDS)
    assert inside.sum() > 0.9 * inside.size
    assert ((hi - lo)[inside] == 0).sum() > 50
    assert np.isfinite(fr.hf_omega[inside]).all()
    # The values are the samples' (interpolated): within the wheel's change over one raw period.
    step = np.nanmax(np.abs(np.diff(v0)))
    direct = np.interp(tg[inside], t0, v0)
    assert np.max(np.abs(fr.hf_omega[inside, 0] - direct)) <= step + 1e-12
