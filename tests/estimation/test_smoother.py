"""The fixed-lag smoother (:mod:`tractionecu.estimation.smoother`).

On a linear-Gaussian model the unscented filter is the Kalman filter and the unscented RTS smoother the RTS
smoother: the smoother's states are checked against a textbook Kalman filter and RTS smoother written here in
numpy, over windows of every length.  Then the delivery rules (the lag, the chain's breaks, the held values, the
flush) and the two ways in (one by one and as arrays), the slip of the smoothed speeds, and on a simulated recording of
the physical truth, whose force builds up through a relaxation length, that the smoothed μ and slip are nearer the
truth than the filter's.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from tractionecu.estimation.config import EstimatorConfig
from tractionecu.estimation.smoother import FixedLagSmoother
from tractionecu.estimation.ukf import UnscentedFilter

N = 10                     # the estimator's state size (μ at 5..8, ρ_s at 9)


@dataclasses.dataclass
class Est:
    """The fields of an Estimate the smoother reads and writes."""
    t: float
    mu: np.ndarray
    rho_s: float
    transition: Any = None


def _linear_run(steps: int, seed: int = 0, breaks: tuple[int, ...] = ()) -> tuple[list[Est], dict[str, np.ndarray]]:
    """A linear model x' = F x + w, y = x[0:5] + v filtered by UnscentedFilter with its gains tracked: the
    estimates (with their transitions) and, for the check, the filter's own x⁺, P⁺, x⁻, P⁻ per step.  At the
    steps in ``breaks`` the state is nudged after the update (the next prediction no longer starts from the
    estimate's x⁺: a break of the chain)."""
    rng = np.random.default_rng(seed)
    F = np.eye(N) + 0.02 * rng.standard_normal((N, N))
    Q = np.diag(rng.uniform(1e-4, 1e-3, N))
    R = np.full(5, 1e-2)

    def fx(sig: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        return sig @ F.T

    ukf = UnscentedFilter(fx, np.zeros(N), np.eye(N), range(5))
    ukf.track_gain = True
    x_true = rng.standard_normal(N)
    out: list[Est] = []
    rec: dict[str, list[np.ndarray]] = {"xf": [], "Pf": [], "xp": [], "Pp": []}
    xf_prev = None
    for k in range(steps):
        x_true = F @ x_true + rng.multivariate_normal(np.zeros(N), Q)
        link = False
        G = None
        if k > 0:
            link = xf_prev is not None and bool(np.array_equal(ukf.x, xf_prev))
            ukf.predict(np.zeros(6), 0.01, Q)
            G = ukf.last_gain
            link = link and G is not None
        xp, Pp = ukf.x.copy(), ukf.P.copy()
        ukf.update(x_true[:5] + rng.normal(0.0, 0.1, 5), slice(0, 5), R)
        xf = ukf.x.copy()
        rec["xf"].append(xf)
        rec["Pf"].append(ukf.P.copy())
        rec["xp"].append(xp)
        rec["Pp"].append(Pp)
        out.append(Est(0.01 * k, xf[5:9].copy(), float(xf[9]), (link, xf, xp if link else None, G if link else None)))
        xf_prev = xf
        if k in breaks:
            ukf.x = ukf.x + 1e-6
    return out, {key: np.array(v) for key, v in rec.items()} | {"F": F}


def _orig(ests: list[Est]) -> list[Est]:
    """Copies of the estimates as the filter made them (the smoother revises its input in place)."""
    return [Est(e.t, e.mu.copy(), e.rho_s, e.transition) for e in ests]


def _rts(rec: dict[str, np.ndarray], k: int, j: int) -> np.ndarray:
    """The textbook RTS smoother's mean at step k given the steps up to j (Rauch, Tung, Striebel 1965)."""
    F = rec["F"]
    s = rec["xf"][j]
    for i in range(j, k, -1):
        Gi = rec["Pf"][i - 1] @ F.T @ np.linalg.inv(rec["Pp"][i])
        s = rec["xf"][i - 1] + Gi @ (s - rec["xp"][i])
    return s


@pytest.mark.parametrize("lag_steps", [1, 3, 7, 40])
def test_linear_gaussian_equals_the_rts_smoother(lag_steps: int) -> None:
    ests, rec = _linear_run(60)
    orig = _orig(ests)
    sm = FixedLagSmoother(0.01 * lag_steps + 1e-9)
    got = []
    for e in ests:
        got.extend(sm.push(e))
    got.extend(sm.flush())
    assert [g.t for g in got] == [e.t for e in ests]
    assert all(g.transition is None for g in got)
    for k, g in enumerate(got):
        ref = _rts(rec, k, min(k + lag_steps, len(ests) - 1))
        assert np.allclose(g.mu, ref[5:9], rtol=0, atol=1e-9)
        assert abs(g.rho_s - ref[9]) <= 1e-9
    # smoothing changes the estimates (it is not the identity), most where the window is longest
    dev = np.array([np.abs(g.mu - e.mu).max() for g, e in zip(got, orig)])
    assert dev[:-1].min() > 0.0 and dev[-1] == 0.0


def test_estimates_are_delivered_after_the_lag_and_in_order() -> None:
    ests, _ = _linear_run(30)
    sm = FixedLagSmoother(0.05 + 1e-9)
    seen: list[float] = []
    for k, e in enumerate(ests):
        out = sm.push(e)
        # a step is due once a step more than the lag after it has arrived: k − 6 at 100 Hz and 0.05 s
        assert [o.t for o in out] == ([ests[k - 6].t] if k >= 6 else [])
        seen.extend(o.t for o in out)
    seen.extend(o.t for o in sm.flush())
    assert seen == [e.t for e in ests]
    assert sm.flush() == []


def test_a_break_ends_the_window_there() -> None:
    ests, rec = _linear_run(30, breaks=(12,))
    orig = _orig(ests)
    assert ests[13].transition[0] is False and ests[12].transition[0] is True
    sm = FixedLagSmoother(10.0)                 # the window would reach the end but for the break
    got = [o for e in ests for o in sm.push(e)]
    assert [o.t for o in got] == [e.t for e in ests[:13]]      # due at the break
    got += sm.flush()
    for k in (0, 5, 12):
        assert np.allclose(got[k].mu, _rts(rec, k, 12)[5:9], rtol=0, atol=1e-9)
    assert np.array_equal(got[12].mu, orig[12].mu)              # the last step before the break: its own
    assert np.allclose(got[13].mu, _rts(rec, 13, 29)[5:9], rtol=0, atol=1e-9)


def test_held_values_follow_the_smoothed_value_they_were_held_from_and_no_filter_passes() -> None:
    ests, _ = _linear_run(20)
    held = ests[10].rho_s
    for k in (11, 12, 13):                       # ρ_s held at standstill: the filter's x⁺ moves on
        ests[k] = dataclasses.replace(ests[k], rho_s=held)
    nan4 = np.full(4, np.nan)
    ests[16] = Est(ests[16].t, nan4, math.nan, None)          # a step without a filter
    orig = _orig(ests)
    sm = FixedLagSmoother(0.03 + 1e-9)
    got = [o for e in ests for o in sm.push(e)] + sm.flush()
    assert got[10].rho_s != held
    assert got[11].rho_s == got[12].rho_s == got[13].rho_s == got[10].rho_s
    assert np.isnan(got[16].mu).all() and math.isnan(got[16].rho_s)
    assert np.array_equal(got[15].mu, orig[15].mu)             # the step before no filter is not revised
    assert sm.smoothed == 19


def test_arrays_equal_one_by_one() -> None:
    ests, _ = _linear_run(50, breaks=(20,))
    ests[30] = dataclasses.replace(ests[30], rho_s=ests[29].rho_s)
    ests2 = _orig(ests)
    one = FixedLagSmoother(0.05 + 1e-9, (-0.1, 1.2), (0.0, 0.3))
    a = [o for e in ests2 for o in one.push(e)] + one.flush()

    def block(es: list[Est]) -> dict[str, Any]:
        return {"t": np.array([e.t for e in es]), "mu": np.array([e.mu for e in es]),
                "rho_s": np.array([e.rho_s for e in es]), "valid": np.ones(len(es), dtype=bool),
                "sm_link": np.array([e.transition[0] for e in es]),
                "sm_xf": np.array([e.transition[1] for e in es]),
                "sm_xp": np.array([e.transition[2] if e.transition[0] else np.full(N, np.nan) for e in es]),
                "sm_G": np.array([e.transition[3] if e.transition[0] else np.full((N, N), np.nan) for e in es])}

    arr = FixedLagSmoother(0.05 + 1e-9, (-0.1, 1.2), (0.0, 0.3))
    blocks = [block(ests[i:i + 7]) for i in range(0, 50, 7)]
    kept = [{k: v.copy() for k, v in b.items()} for b in blocks]
    parts = [p for b in blocks for p in arr.push_arrays(b)] + arr.flush_arrays()
    # the blocks given are left as they were (the smoothing moved rows within its own copies; it once shifted the
    # first block's times in place and delivered rows 1-5 smoothed against the wrong window)
    assert all(np.array_equal(b[k], c[k], equal_nan=True) for b, c in zip(blocks, kept) for k in b)
    assert not any(k.startswith("sm_") for p in parts for k in p)
    mu = np.concatenate([p["mu"] for p in parts])
    rho = np.concatenate([p["rho_s"] for p in parts])
    assert np.array_equal(mu, np.array([e.mu for e in a]))
    assert np.array_equal(rho, np.array([e.rho_s for e in a]))
    assert arr.smoothed == one.smoothed


@dataclasses.dataclass
class EstS(Est):
    """With the fields the slip's revision reads."""
    slip: np.ndarray = None
    omega: np.ndarray = None
    v: float = math.nan
    status: int = 0


def _slip(w: np.ndarray, v: float, c: np.ndarray) -> np.ndarray:
    """Eq. 6 with ρ = c|v|/|ω| (c = |k|/|r|): 1 − ρ driving, −1 + 1/ρ braking."""
    rho = c * abs(v) / np.abs(w)
    return np.where(rho <= 1.0, 1.0 - rho, -1.0 + 1.0 / rho)


def test_a_live_slip_is_eq6_at_the_smoothed_speeds_and_a_held_one_stays() -> None:
    """The slip of each estimate is eq. 6 again at the textbook RTS smoother's wheel speeds and v, with the step's
    own wheel factor; a slip the estimator could not support, averaged or froze at standstill (its status bits)
    stays as it was unless it is the last live slip held, which holds that slip's smoothed value; and an estimator
    whose index names no wheel speeds (the machine level's five) revises none."""
    from tractionecu.estimation.estimator import SLIP_AVERAGED, SLIP_UNCERTAIN, STANDSTILL

    ests, rec = _linear_run(30)
    c = np.array([0.93, 1.04, 0.97, 1.01])        # each wheel's |k|/|r|: some drive, some brake
    shift = np.r_[np.full(4, 3.0), 2.0, np.zeros(5)]  # speeds away from 0 (the states are centred on it)

    def estimates(index: tuple[int, ...] | None = None) -> list[EstS]:
        out = []
        for k, e in enumerate(ests):
            tr = e.transition
            tr = (tr[0], tr[1] + shift, None if tr[2] is None else tr[2] + shift, tr[3])
            if index is not None:
                tr += (index,)
            w, v = tr[1][:4], float(tr[1][4])
            status = {5: SLIP_UNCERTAIN, 6: SLIP_AVERAGED, 7: STANDSTILL, 8: STANDSTILL}.get(k, 0)
            out.append(EstS(e.t, e.mu.copy(), e.rho_s, tr, _slip(w, v, c), w.copy(), v, status))
        out[8].slip = out[4].slip.copy()          # held at standstill: the last live slip (step 4's)
        return out

    rich = estimates()
    orig = [r.slip.copy() for r in rich]
    lag = 4
    sm = FixedLagSmoother(0.01 * lag + 1e-9)
    got = [o for e in rich for o in sm.push(e)] + sm.flush()
    for k in range(30):
        if k in (5, 6, 7):
            assert np.array_equal(got[k].slip, orig[k])
            continue
        if k == 8:                                # the held slip holds the smoothed value it was held from
            assert np.array_equal(got[8].slip, got[4].slip) and not np.array_equal(got[8].slip, orig[8])
            continue
        xs = _rts(rec, k, min(k + lag, 29)) + shift
        np.testing.assert_allclose(got[k].slip, _slip(xs[:4], xs[4], c), rtol=0, atol=1e-9)
        if k < 29:
            assert not np.allclose(got[k].slip, orig[k], rtol=0, atol=1e-12)

    # as arrays (the compiled loop's way in): the same slips
    es = estimates()
    blocks = [{"t": np.array([e.t for e in b]), "mu": np.array([e.mu for e in b]),
               "rho_s": np.array([e.rho_s for e in b]), "slip": np.array([e.slip for e in b]),
               "omega": np.array([e.omega for e in b]), "v": np.array([e.v for e in b]),
               "status": np.array([e.status for e in b]),
               "sm_link": np.array([e.transition[0] for e in b]), "sm_xf": np.array([e.transition[1] for e in b]),
               "sm_xp": np.array([e.transition[2] if e.transition[0] else np.full(N, np.nan) for e in b]),
               "sm_G": np.array([e.transition[3] if e.transition[0] else np.full((N, N), np.nan) for e in b])}
              for b in (es[i:i + 8] for i in range(0, 30, 8))]
    arr = FixedLagSmoother(0.01 * lag + 1e-9)
    parts = [q for b in blocks for q in arr.push_arrays(b)] + arr.flush_arrays()
    assert np.array_equal(np.concatenate([q["slip"] for q in parts]), np.array([g.slip for g in got]))

    sm = FixedLagSmoother(0.01 * lag + 1e-9)
    got = [o for e in estimates((5, 6, 7, 8, 9)) for o in sm.push(e)] + sm.flush()
    assert sm.smoothed == 30 and all(np.array_equal(g.slip, o) for g, o in zip(got, orig))


def test_lag_zero_passes_everything_at_once() -> None:
    ests, _ = _linear_run(5)
    sm = FixedLagSmoother(0.0)
    for e, e0 in zip(ests, _orig(ests)):
        (o,) = sm.push(e)
        assert np.array_equal(o.mu, e0.mu) and o.rho_s == e0.rho_s and o.transition is None
    with pytest.raises(ValueError, match="lag"):
        FixedLagSmoother(math.nan)


def test_the_estimator_config_takes_the_lag_and_checks_it() -> None:
    assert EstimatorConfig().smoother_lag_s == 0.05
    sm = FixedLagSmoother.from_config(EstimatorConfig(smoother_lag_s=0.1))
    assert sm.lag_s == 0.1
    from tractionecu.errors import ConfigError

    with pytest.raises(ConfigError, match="smoother_lag_s"):
        EstimatorConfig(smoother_lag_s=-0.01)


@pytest.mark.parametrize("rate_hz, lag", [(100.0, 0.05), (50.0, 0.05), (20.0, 0.1), (10.0, 0.2)])
def test_the_lag_holds_two_wheel_speed_periods(rate_hz: float, lag: float) -> None:
    """The hub estimator's smoother holds at least MIN_WHEEL_PERIODS of the declared wheel-speed period beside
    the configured lag; lag 0 (off) stays off; an object without a wheel-speed rate keeps the configured lag."""
    from tractionecu.config import SensorSpec, VehicleParams
    from tractionecu.estimation.estimator import Estimator
    from tractionecu.estimation.smoother import MIN_WHEEL_PERIODS

    est = Estimator(VehicleParams(), sensors=SensorSpec(wheel_rate_hz=rate_hz))
    assert FixedLagSmoother.for_estimator(est).lag_s == pytest.approx(lag, rel=1e-12)
    assert lag == max(0.05, MIN_WHEEL_PERIODS / rate_hz)
    off = Estimator(VehicleParams(), EstimatorConfig(smoother_lag_s=0.0), sensors=SensorSpec(wheel_rate_hz=rate_hz))
    assert FixedLagSmoother.for_estimator(off).lag_s == 0.0
    assert FixedLagSmoother.for_estimator(object()).lag_s == 0.0

    class NoRate:                       # no wheel-speed rate: the configured lag
        cfg = EstimatorConfig()
    assert FixedLagSmoother.for_estimator(NoRate()).lag_s == 0.05


def test_the_machine_levels_lag_holds_two_periods_of_its_wheel_speeds() -> None:
    """The machine-level estimator reads its wheel speeds from CCVS1, WBSD and EBC2 every 100 ms: its smoother's
    lag holds two of those periods, 0.2 s, beside a shorter configured lag; a longer one and 0 (off) stay."""
    from tractionecu.config import DrivetrainSpec, VehicleParams
    from tractionecu.estimation.machine import MachineEstimator

    veh = VehicleParams(drivetrain=DrivetrainSpec(kind="mechanical", final_drive_ratio=20.0))
    assert FixedLagSmoother.for_estimator(MachineEstimator(veh)).lag_s == pytest.approx(0.2, rel=1e-12)
    longer = MachineEstimator(veh, EstimatorConfig(smoother_lag_s=0.5))
    assert FixedLagSmoother.for_estimator(longer).lag_s == 0.5
    off = MachineEstimator(veh, EstimatorConfig(smoother_lag_s=0.0))
    assert FixedLagSmoother.for_estimator(off).lag_s == 0.0


def test_smoothing_brings_mu_and_slip_nearer_the_physical_truth(tmp_path) -> None:
    """The physical truth's tyre force builds up through its relaxation length: the filter's random-walk μ trails
    it, and the steps after each estimate take the lag back (docs/results/estimator.md).  The slip of the smoothed
    wheel speeds and v is nearer the truth's too (measured 3.7 % nearer on this recording, 11 % on
    `physical-three-soils` and `s-curves-30m`)."""
    from tractionecu.estimation.estimator import SLIP_AVERAGED, SLIP_UNCERTAIN, STANDSTILL
    from tractionecu.evaluation.scoring import read_truth
    from tractionecu.pipeline.replay import replay
    from tractionecu.recording.reader import read_recording
    from tractionecu.sim.player import simulate_recording

    simulate_recording("physical-declared-exact", 0, tmp_path / "rec", duration_s=40.0)
    rec = read_recording(tmp_path / "rec")
    tr = read_truth(rec.truth_csv_path, rec.truth_toml_path)
    errs, slip_errs = {}, {}
    for lag in (0.0, 0.05):
        a = replay(rec, cfg=EstimatorConfig(smoother_lag_s=lag)).arrays
        k = np.clip(np.searchsorted(tr.t, a["t"] + 1e-9, side="right") - 1, 0, len(tr.t) - 1)
        mt = tr.mu[k]
        ok = a["valid"][:, None] & (np.abs(mt) >= 0.05)
        errs[lag] = float(np.mean((np.abs(a["mu"] - mt) / np.abs(mt))[ok]))
        live = a["valid"] & ((a["status"] & (SLIP_UNCERTAIN | SLIP_AVERAGED | STANDSTILL)) == 0)
        slip_errs[lag] = float(np.mean(np.abs(a["slip"] - tr.slip[k])[live]))
    assert errs[0.05] < 0.9 * errs[0.0]
    assert slip_errs[0.05] < 0.98 * slip_errs[0.0]


def test_the_machine_level_estimator_is_smoothed_too(tmp_path) -> None:
    """The mechanical tractor's machine-level μ (one state for the four wheels, SMOOTH_INDEX): its estimates
    carry transitions with their state index, and smoothing brings μ nearer the truth's ΣF/ΣF_z."""
    from tractionecu.estimation.machine import SMOOTH_INDEX
    from tractionecu.evaluation.machine_score import machine_scorecard
    from tractionecu.evaluation.scoring import read_truth
    from tractionecu.pipeline.replay import machine_of, replay
    from tractionecu.recording.reader import read_recording
    from tractionecu.sim.player import simulate_recording

    simulate_recording("mechanical-three-soils", 0, tmp_path / "rec", duration_s=60.0)
    rec = read_recording(tmp_path / "rec")
    tr = read_truth(rec.truth_csv_path, rec.truth_toml_path)
    mass = machine_of(rec)[0].mass_kg
    seen = []
    errs = {}
    for lag in (0.0, 0.05):
        a = replay(rec, cfg=EstimatorConfig(smoother_lag_s=lag),
                   on_estimate=seen.append if lag else None).arrays
        errs[lag] = machine_scorecard(a, tr, rec.truth_csv_path, mass)["mu_mean_abs_rel_error"]
    assert all(e.transition is None for e in seen)              # dropped on delivery
    assert all(np.unique(e.mu[np.isfinite(e.mu)]).size <= 1 for e in seen)   # still one μ for the machine
    assert errs[0.05] < 0.9 * errs[0.0]
    assert SMOOTH_INDEX == (2, 2, 2, 2, 3)


def test_the_model_path_gain_equals_the_general_cross_covariance() -> None:
    """predict_model_gain takes the gain from P's Cholesky factor and the sigma-point pairs (pair_gain); the general
    sum over every sigma point (cross_gain, the process-model path's) gives the same gain."""
    from tractionecu.config import VehicleParams
    from tractionecu.estimation import _kernels as K
    from tractionecu.model.vehicle import FilterModel

    model = FilterModel(VehicleParams())
    ukf = UnscentedFilter(model.step, np.zeros(N), np.eye(N), range(5))
    rng = np.random.default_rng(4)
    A = rng.standard_normal((N, N)) * 0.02
    P = A @ A.T + np.diag(np.full(N, 1e-4))
    x = np.array([3.1, 3.0, 3.2, 3.15, 2.4, 0.31, 0.29, 0.35, 0.33, 0.06])
    u = np.array([2100.0, 2000.0, 3100.0, 3000.0, 25000.0, 10000.0, 0.01])
    Q = np.diag(np.full(N, 1e-6))
    sig, xo, Po, G = np.empty((2 * N + 1, N)), np.empty(N), np.empty((N, N)), np.empty((N, N))
    assert K.predict_model_gain(x, P, u, 0.01, Q, ukf._w, model._kc, sig, xo, Po, G) == 0
    sf = model.step(sig, u, 0.01)
    ref = np.empty((N, N))
    assert K.cross_gain(sig, sf, ukf.Wc, x, xo, Po, ref)
    assert np.allclose(G, ref, rtol=1e-9, atol=1e-12)
    assert np.abs(G).max() > 0.1                    # a gain, not zeros


@pytest.mark.parametrize("jit", [True, False])
def test_a_gain_over_the_leading_states_is_their_marginal(jit: bool, monkeypatch) -> None:
    """UnscentedFilter.gain_n: the smoother's gain over the first gain_n states (the period-mean filter's hub
    states) is C (P⁻)⁻¹ of those states' sigma points alone; the states after them (angles restarted at each
    sample) take no part, compiled or numpy."""
    from tractionecu.estimation import _kernels as K
    from tractionecu.estimation import ukf as U

    monkeypatch.setattr(U, "JIT", jit and K.JIT)
    rng = np.random.default_rng(8)
    A = rng.standard_normal((6, 6)) * 0.1
    F = np.eye(6) + 0.05 * rng.standard_normal((6, 6))

    def fx(x, u, dt):
        return x @ F.T + 0.01 * np.sin(x)

    ukf = UnscentedFilter(fx, rng.standard_normal(6), A @ A.T + 0.01 * np.eye(6), range(3))
    ukf.track_gain = True
    ukf.gain_n = 4
    x0 = ukf.x.copy()
    sig0 = ukf.sigma_points().copy()
    ukf.predict(np.zeros(6), 0.01, 1e-4 * np.eye(6))
    G = ukf.last_gain
    assert G.shape == (4, 4)
    sf = fx(sig0, None, 0.01)
    C = ((sig0[:, :4] - x0[:4]).T * ukf.Wc) @ (sf[:, :4] - ukf.x[:4])
    np.testing.assert_allclose(G, C @ np.linalg.inv(ukf.P[:4, :4]), rtol=1e-9, atol=1e-12)
    assert np.abs(G).max() > 0.5
