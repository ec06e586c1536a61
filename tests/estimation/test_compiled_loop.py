"""The compiled estimator loop (tractionecu.estimation.compiled_loop) against the step path.

Its contract: every estimate column equal to :meth:`Estimator.step`'s within 1e-9, and the filter's state
after every step equal to the Python estimator's.  Checked step by step on a seeded synthetic run with the
rare paths put in (a rejected torque, an axle load out of range, a non-finite wheel speed, outliers the gate
rejects, a data gap that restarts the filter), and through batch replay on simulated recordings: the
paper's three soils, S-curves (turns, a declared hub efficiency) and a headland turn that reverses and stops.
Configurations it does not cover run the Python estimator, and say so.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tractionecu.config import VehicleParams
from tractionecu.estimation import _loop_kernel as K
from tractionecu.estimation.compiled_loop import CompiledLoop, supported
from tractionecu.estimation.estimator import (FILTER_LOST, INPUT_REJECTED, MEAS_GATED, NOT_CONVERGED, SLIP_AVERAGED,
                                              STANDSTILL, Estimator)
from tractionecu.pipeline.batch import max_differences, replay_batch
from tractionecu.pipeline.replay import replay
from tractionecu.recording.reader import read_recording

from est_synth import synth_run

TOL = 1e-9


def _assert_vectors(row, k: int, pairs) -> None:
    """The compiled loop's output ``row`` of step ``k`` holds each (column, Python estimate's vector) of
    ``pairs``: the same NaN pattern, the values within TOL."""
    for col, val in pairs:
        got = row[col:col + len(val)]
        assert np.array_equal(np.isnan(got), np.isnan(val)), f"NaN pattern at step {k}"
        np.testing.assert_allclose(got, val, rtol=0.0, atol=TOL, err_msg=f"step {k}")


def _steps_with_rare_paths() -> list:
    """8 s of the synthetic truth loop with the rare paths of a step put in (module doc)."""
    steps = [(t, dict(i), dict(m)) for t, i, m in synth_run(seed=3, duration=8.0).steps]
    for k, (t, inputs, meas) in enumerate(steps):
        if "v" in meas:
            meas["course"] = 90.0 + 0.5 * np.sin(t)      # a GNSS course with the speed
        if k % 50 == 7:
            meas["dir"] = 1.0                             # the machine's direction bit (forwards)
    steps[150][1]["Md"] = np.array([np.nan, 1.0, 2.0, 3.0])          # rejected input: predict only
    steps[180][1]["Fzf"] = 0.0                                         # axle load out of range: rejected
    om = np.array(steps[220][2]["omega"], dtype=float)
    om[2] = np.nan
    steps[220][2]["omega"] = om                                         # non-finite component: general update
    for k in (300, 301, 302):
        steps[k][2]["omega"] = np.asarray(steps[k][2]["omega"]) * 1.3   # outliers: gated (general update)
    # a gap of 2.5 s (longer than max_gap_s): the filter restarts from the next data
    return [s for s in steps if not 4.0 < s[0] < 6.5]


def test_state_after_every_step_equals_the_python_estimator():
    steps = _steps_with_rare_paths()
    veh = VehicleParams()
    est = Estimator(veh)
    loop = CompiledLoop(Estimator(veh))
    IN = CompiledLoop.inputs_from_steps(steps)
    statuses = 0
    for k, (t, inputs, meas) in enumerate(steps):
        e = est.step(t, inputs, meas)
        row = loop.step_block(IN[k:k + 1])[0]
        statuses |= e.status
        assert row[K.OUT_STATUS] == e.status, f"status at step {k}"
        assert bool(row[K.OUT_VALID]) == e.valid
        _assert_vectors(row, k, ((K.OUT_MU, e.mu), (K.OUT_SLIP, e.slip), (K.OUT_OM, e.omega), (K.OUT_P, e.P_diag),
                                 (K.OUT_SIGMU, e.sigma_mu)))
        for col, val in ((K.OUT_RHO, e.rho_s), (K.OUT_V, e.v), (K.OUT_NIS, e.nis), (K.OUT_ADAPT, e.adapt),
                         (K.OUT_SIGRHO, e.sigma_rho_s)):
            np.testing.assert_allclose(row[col], val, rtol=0.0, atol=TOL, err_msg=f"step {k}")
        # the curve state the step reports (made from the compiled curve update's records) is the step path's
        cs, ref = loop.states[int(row[K.OUT_CS])], est._curve_state
        assert (cs.n_used, cs.segment, cs.curve_path) == (ref.n_used, ref.segment, ref.curve_path), f"step {k}"
        assert np.array_equal([cs.a, *cs.a_per_class, *cs.nll_per_class], [ref.a, *ref.a_per_class,
                                                                            *ref.nll_per_class], equal_nan=True)
        # the filter's state itself, and the held inputs
        assert (est.ukf is None) == (loop.I[K.I_UKF] == 0)
        if est.ukf is not None:
            np.testing.assert_allclose(loop._x, est.ukf.x, rtol=1e-12, atol=0.0, err_msg=f"x at step {k}")
            np.testing.assert_allclose(loop._P, est.ukf.P, rtol=1e-9, atol=1e-15, err_msg=f"P at step {k}")
        np.testing.assert_array_equal(loop._u, est._u)
        assert loop.F[K.F_F] == est._f and np.array_equal(loop.F[K.F_A:K.F_A + 10], est._A)
        # the radius calibration's state (the epochs it rejects with no block open are screened compiled)
        ca, cb = est._cal, loop.est._cal
        assert (ca.rejected, ca.samples, ca._blk, ca.applied) == (cb.rejected, cb.samples, cb._blk, cb.applied)
        assert np.array_equal([ca._period, ca._t_last, ca._t0], [cb._period, cb._t_last, cb._t0], equal_nan=True)
    assert loop.counters == est.counters
    # the rare paths were taken
    assert statuses & INPUT_REJECTED and statuses & MEAS_GATED and statuses & NOT_CONVERGED
    assert est.counters["gap_resets"] == 1 and est.counters["rejected_inputs"] >= 2
    assert loop.events["init"] == 2 and loop.events["update"] >= 3
    # the curve updated compiled within the loop (no return to Python for it), the supervisor's new strengths'
    # centroids too (in its memo)
    assert loop.I[K.I_CS_VER] > 0 and loop.events["curve"] == 0 and est._cal.rejected > 0
    assert "fuzzy" not in loop.events and loop.I[K.I_FZ_N] > 1


def test_curve_update_in_the_loop_with_full_records_and_history():
    """The μ(s) curve's update runs compiled in the loop, on the estimator's own curve state; it returns to Python
    for the once-a-second span and fit, and, having changed nothing, when its records or the shape
    identification's history ring are full (they grow, and Python does that update).  Records and ring start
    tiny here; every step's curve state equals the step path's."""
    steps = [(t, dict(i), dict(m)) for t, i, m in synth_run(seed=7, duration=30.0).steps]
    veh = VehicleParams()
    est = Estimator(veh)
    loop = CompiledLoop(Estimator(veh))
    sh = loop.est._curve.shape
    loop.states.CR = np.zeros((2, 5))
    sh._HT, sh._HP = np.zeros((2, 3)), np.zeros((4, 5))
    loop._cv = loop._curve_arrays()
    refs = []
    for t, inputs, meas in steps:
        est.step(t, inputs, meas)
        refs.append(est._curve_state)
    IN = CompiledLoop.inputs_from_steps(steps)
    out = np.concatenate([loop.step_block(IN[k:k + 700]) for k in range(0, len(steps), 700)])
    for k, ref in enumerate(refs):
        cs = loop.states[int(out[k, K.OUT_CS])]
        assert (cs.n_used, cs.segment, cs.curve_path, cs.s_range) == (ref.n_used, ref.segment, ref.curve_path,
                                                                       ref.s_range), f"step {k}"
        assert np.array_equal([cs.a, cs.var_a, cs.slip_span, *cs.nll_per_class],
                              [ref.a, ref.var_a, ref.slip_span, *ref.nll_per_class], equal_nan=True), f"step {k}"
    n_upd = int(loop.I[K.I_CS_VER])
    assert n_upd > 100 and loop.states.CR.shape[0] > n_upd and sh._HT.shape[0] > 2
    assert 0 < loop.events["curvefit"] < n_upd and loop.events["curve"] == 0


def _compare(path, rate_hz: float = 100.0, compiled: bool = True) -> tuple:
    rec = read_recording(path)
    step = replay(rec, rate_hz=rate_hz)
    batch = replay_batch(rec, rate_hz=rate_hz)
    assert (batch.loop == "compiled") if compiled else batch.loop.startswith("python:")
    diff = max_differences(step.arrays, batch.arrays)
    bad = {k: v for k, v in diff.items() if not v <= TOL}
    assert not bad, f"columns differing by more than {TOL}: {bad}"
    for col in ("mu", "rho_s", "a", "slip", "v", "omega", "P_diag", "nis", "adapt", "sigma_mu", "sigma_rho_s",
                "radius_scale", "radius_halfwidth", "radius_applied", "status", "valid", "nis_dof",
                "soil_class"):
        assert col in diff
    assert batch.counters == step.counters
    assert [c.path if c is not None else "" for c in step.arrays["curve"]] == batch.arrays["curve_path"]
    return step, batch


def test_paper_three_soils_every_column(make_recording):
    step, _ = _compare(make_recording("paper-three-soils", 0, 20.0))
    a = step.arrays
    assert a["valid"].sum() > 1000 and np.isfinite(a["a"]).any()


def test_the_curve_cache_stays_bounded_and_changes_nothing(make_recording, monkeypatch, tmp_path):
    """The run directory resolves every row's curve (estimates.csv's curve_path): the loop kept one curve per
    version of the run, 31 000 over a 1.04 h replay, and the replay's memory grew with it (4.04 h: 494 MB peak, 446 MB
    bounded).  Bounded to a few versions, the cache is refilled on demand and every row is as before."""
    import tractionecu.estimation.compiled_loop as CL
    import tractionecu.pipeline.batch as batch_module
    from tractionecu.pipeline.rundir import replay_to_dir

    path = make_recording("paper-three-soils", 0, 20.0)
    _, _, ref = replay_to_dir(path, tmp_path / "ref", write_map=False, keep_arrays=True)
    calls = []                          # (cache size before, versions asked, cache size after) per call
    orig = CL.CompiledLoop.resolve_curves

    def resolve(self, arr):
        n0, keys = len(self._curves), len(set(np.asarray(arr.get("curve_key", [])).tolist()))
        out = orig(self, arr)
        calls.append((n0, keys, len(self._curves)))
        return out

    monkeypatch.setattr(CL, "CURVE_CACHE_MAX", 8)
    monkeypatch.setattr(CL.CompiledLoop, "resolve_curves", resolve)
    monkeypatch.setattr(batch_module, "BLOCK", 256)          # blocks of 256 steps: many calls over 20 s
    summary, _, got = replay_to_dir(path, tmp_path / "small", write_map=False, keep_arrays=True)
    assert summary["loop"] == "compiled" and len(calls) > 3
    assert all(after <= (n0 if n0 <= 8 else 0) + keys for n0, keys, after in calls)
    assert any(n0 > 8 and after < n0 for n0, _, after in calls)        # cleared at least once
    assert (tmp_path / "small" / "estimates.csv").read_bytes() == (tmp_path / "ref" / "estimates.csv").read_bytes()
    assert got.arrays["curve_path"] == ref.arrays["curve_path"]


def test_soil_segments_close_within_the_loop(make_recording):
    """90 s of paper-three-soils (two soil segments close there: test_curve_speed's reference pins the count): the
    change test fires within the compiled curve update, the segment closes in Python and the pairs go on in the
    loop; every column and every step's identified curve (path, parameters, covariance, slip range) equal the step
    path's."""
    step, batch = _compare(make_recording("paper-three-soils", 0, 90.0))

    def text(c):
        return None if c is None else (c.path, c.theta, np.asarray(c.cov).tobytes(), c.s_range)

    got = [text(c) for c in batch.arrays["curve"]]
    assert got == [text(c) for c in step.arrays["curve"]]
    assert len({g[3] for g in got if g is not None}) > 10          # the soil's slip range moved on


def test_slow_replay_rate_with_sub_steps(make_recording):
    """At 20 Hz a step spans 50 ms: the prediction is sub-stepped (max_step_s) with its own Q, and several
    bus samples fall into one step (the latest is passed)."""
    step, batch = _compare(make_recording("paper-three-soils", 0, 20.0), rate_hz=20.0)
    assert step.arrays["valid"].sum() > 200


def test_s_curves_with_declared_hub_efficiency(make_recording):
    """S-curves on the physical machine: turns, gated wheel speeds, a declared hub efficiency (ported).  Should
    its vehicle file declare a feature the loop does not port (a carcass, a two-inertia hub), batch replay
    falls back, says so, and stays equal."""
    path = make_recording("s-curves-30m", 1, 20.0)
    rec = read_recording(path)
    from tractionecu.pipeline.replay import machine_of

    veh, sensors = machine_of(rec)
    assert veh.drivetrain.efficiency < 1.0                          # the ported drivetrain losses are in play
    covered = supported(Estimator(veh, sensors=sensors))[0]
    step, _ = _compare(path, compiled=covered)
    assert (step.arrays["status"] & MEAS_GATED).any()


def test_headland_turn_reversing_and_standstill(make_recording):
    """The three-point turn after the first pass: stop, 12 m back at 1 m/s (averaged slip), stop."""
    step, _ = _compare(make_recording("headland-reverse", 0, 120.0))
    a = step.arrays
    assert (a["v"] < -0.5).sum() > 200
    assert (a["status"] & STANDSTILL).any() and (a["status"] & SLIP_AVERAGED).any()


def test_unsupported_configurations_run_the_python_estimator(make_recording):
    veh = VehicleParams()
    assert supported(Estimator(veh)) == (True, "")
    carcass = dataclasses.replace(veh, tyre_carcass_stiffness_npm=2.0e6)
    ok, why = supported(Estimator(carcass))
    assert not ok and "carcass" in why
    with pytest.raises(ValueError, match="carcass"):
        CompiledLoop(Estimator(carcass))
    stepped = Estimator(veh)
    stepped.step(0.0, {}, {})
    assert not supported(stepped)[0]
    # the machine-level estimator (engine-driven tractor): batch replay falls back, and says so
    path = make_recording("mechanical-three-soils", 0, 6.0)
    rec = read_recording(path)
    batch = replay_batch(rec)
    assert batch.loop.startswith("python:") and "MachineEstimator" in batch.loop
    diff = max_differences(replay(rec).arrays, batch.arrays)
    assert diff and max(diff.values()) <= TOL
    forced = replay_batch(rec, compiled=False)
    assert forced.loop == "python: compiled=False"


def _run_both(steps: list, prepare=None) -> tuple:
    """Step the Python estimator and the compiled loop on ``steps``; compare every step (as the test above);
    ``prepare(k, est, loop)`` may change both states identically before step k."""
    veh = VehicleParams()
    est = Estimator(veh)
    loop = CompiledLoop(Estimator(veh))
    IN = CompiledLoop.inputs_from_steps(steps)
    lost_since = []
    for k, (t, inputs, meas) in enumerate(steps):
        if prepare is not None:
            prepare(k, est, loop)
        e = est.step(t, inputs, meas)
        row = loop.step_block(IN[k:k + 1])[0]
        assert row[K.OUT_STATUS] == e.status, f"status at step {k}"
        _assert_vectors(row, k, ((K.OUT_MU, e.mu), (K.OUT_OM, e.omega), (K.OUT_P, e.P_diag), (K.OUT_SLIP, e.slip)))
        np.testing.assert_allclose(row[K.OUT_V], e.v, rtol=0.0, atol=TOL)
        assert np.isnan(row[K.OUT_LOST]) == np.isnan(e.lost_since)
        if not np.isnan(e.lost_since):
            assert row[K.OUT_LOST] == e.lost_since
            lost_since.append(e.lost_since)
        if est.ukf is not None:
            np.testing.assert_allclose(loop._x, est.ukf.x, rtol=1e-12, atol=0.0, err_msg=f"x at step {k}")
    assert loop.counters == est.counters
    return est, loop, lost_since


def test_lost_filter_is_declared_and_restarted_as_the_python_estimator_does():
    """Wheel speeds of the wrong sign for half a second (a wiring fault): wheels and vehicle travel opposite
    ways, the divergence monitor declares the filter lost, and it restarts from the data."""
    steps = [(t, dict(i), dict(m)) for t, i, m in synth_run(seed=5, duration=9.0).steps]
    for k in range(500, 550):
        steps[k][2]["omega"] = -np.asarray(steps[k][2]["omega"])
    est, loop, lost = _run_both(steps)
    assert est.counters["lost"] >= 1 and lost
    assert loop.events["init"] >= 2
    # the sinks mark the lost period's estimates alike (a whole block through keep_arrays)
    from tractionecu.pipeline.batch import BatchSink
    from tractionecu.pipeline.replay import _Sink

    ref = _Sink(keep_all=True)
    py = Estimator(VehicleParams())
    for t, inputs, meas in steps:
        ref.keep(py.step(t, inputs, meas))
    ref.close()
    comp = CompiledLoop(Estimator(VehicleParams()))
    sink = BatchSink(keep_all=True)
    sink.resolve = comp.resolve_curves
    sink.keep_arrays(comp.arrays(comp.step_block(CompiledLoop.inputs_from_steps(steps))))
    sink.close()
    a, b = ref.arrays(), sink.arrays()
    assert (a["status"] & FILTER_LOST).any() and not a["valid"][a["status"] & FILTER_LOST != 0].any()
    diff = max_differences(a, b)
    assert diff and max(diff.values()) <= TOL, diff


def test_covariance_repair_and_non_finite_prediction_as_the_python_estimator():
    """A covariance that is not positive definite (the filter's Cholesky repair) and a torque that makes
    the prediction overflow (the restart from the last finite mean) go through the estimator's own filter."""
    steps = [(t, dict(i), dict(m)) for t, i, m in synth_run(seed=6, duration=5.0).steps]
    steps[400][1]["Md"] = np.array([1e307, 0.0, 0.0, 0.0])      # finite sum, the prediction overflows

    def prepare(k, est, loop):
        if k == 300:                                               # the same indefinite covariance in both
            P = est.ukf.P.copy()
            P[5, 6] = P[6, 5] = 2.0 * np.sqrt(P[5, 5] * P[6, 6])
            est.ukf.P = P.copy()
            loop._P[:, :] = P

    est, loop, _ = _run_both(steps, prepare)
    assert est.counters["chol_repairs"] >= 1 or loop.events["predict"] >= 1
    assert loop.events["predict"] >= 1
    assert est.counters["resets"] == 1 and loop.events["recover"] == 1


@pytest.fixture(scope="module")
def synth_steps() -> list:
    return [(t, dict(i), dict(m)) for t, i, m in synth_run(seed=2, duration=6.0).steps]


@pytest.mark.parametrize("change", [
    {"adaptation": False}, {"supervisor": False}, {"input_noise": False}, {"systematic_uncertainty": False},
    {"calibration": "off"}, {"slip_avg_max_m": 0.0}, {"gate_probability": 0.0}, {"lost_after_s": 0.0},
    {"slip_sigma_max": 0.0}, {"max_step_s": 0.004}])
def test_configuration_switches_as_the_python_estimator(synth_steps, change):
    """The estimator's switches the compiled loop ports (adaptation, supervisor, input noise, systematic
    uncertainty, calibration, averaged slip, gate, divergence monitor, slip bound, sub-steps): equal step by step."""
    from tractionecu.estimation.estimator import EstimatorConfig

    base = EstimatorConfig()
    kw = {k: (dataclasses.replace(base.calibration, enabled=False) if v == "off" else v) for k, v in change.items()}
    cfg = dataclasses.replace(base, **kw)
    est = Estimator(VehicleParams(), cfg)
    loop = CompiledLoop(Estimator(VehicleParams(), cfg))
    IN = CompiledLoop.inputs_from_steps(synth_steps)
    for k, (t, inputs, meas) in enumerate(synth_steps):
        e = est.step(t, inputs, meas)
        row = loop.step_block(IN[k:k + 1])[0]
        assert row[K.OUT_STATUS] == e.status, f"status at step {k}"
        _assert_vectors(row, k, ((K.OUT_MU, e.mu), (K.OUT_P, e.P_diag), (K.OUT_SLIP, e.slip),
                                 (K.OUT_SIGMU, e.sigma_mu)))
    assert loop.counters == est.counters


def test_self_check_falls_back_when_the_loop_differs(monkeypatch):
    """Batch replay trusts the compiled loop for a machine only after a short drive of it equals
    Estimator.step; a loop that differs (here: one estimate perturbed) makes it run the Python estimator."""
    from tractionecu.estimation import compiled_loop
    from tractionecu.pipeline.batch import loop_choice

    est = Estimator(VehicleParams())
    monkeypatch.setattr(compiled_loop, "_CHECKED", {})
    assert CompiledLoop.self_check(est) == (True, 0.0)
    assert loop_choice(est, None) == "compiled"
    orig = CompiledLoop.step_block

    def perturbed(self, IN):
        out = orig(self, IN)
        out[-1, K.OUT_MU] += 1e-6
        return out

    monkeypatch.setattr(compiled_loop, "_CHECKED", {})
    monkeypatch.setattr(CompiledLoop, "step_block", perturbed)
    ok, diff = CompiledLoop.self_check(est)
    assert not ok and diff > 1e-7
    assert "self-check" in loop_choice(est, None)


def test_kernel_constants_are_the_estimators():
    """The compiled loop's copies of the estimator's status bits, curvature bounds and the averaged slip's
    steadiness time (_loop_kernel's module comment says why they are copies) equal estimator.py's."""
    from tractionecu.estimation import estimator as E
    names = ("WHEEL_TIMEOUT", "GPS_TIMEOUT", "TORQUE_TIMEOUT", "AXLE_TIMEOUT", "DRAFT_TIMEOUT", "NOT_CONVERGED",
             "INPUT_REJECTED", "MEAS_GATED", "COV_REPAIRED", "FILTER_LOST", "STANDSTILL", "UNVERIFIED",
             "MACHINE_UNSUPPORTED", "SLIP_UNCERTAIN", "SLIP_AVERAGED", "INVALID_MASK", "KAPPA_NOISE_MIN", "KAPPA_MAX",
             "SLIP_STEADY_S")
    assert {n: getattr(K, n) for n in names} == {n: getattr(E, n) for n in names}


def test_slip_at_the_clipped_curvature_as_the_python_estimator():
    """A 3 m circle after a straight (the curvature input clipped at KAPPA_MAX): the slip flagged not supported
    and held in the compiled loop as in the step path, step by step."""
    from test_kinematics import _turning

    from tractionecu.estimation.estimator import KAPPA_MAX, SLIP_UNCERTAIN

    run = synth_run(seed=2, duration=14.0)
    steps = _turning(run, 1 / 3.0, t_from=6.0)
    est = Estimator(VehicleParams())
    loop = CompiledLoop(Estimator(VehicleParams()))
    IN = CompiledLoop.inputs_from_steps(steps)
    clipped = 0
    for k, (t, inputs, meas) in enumerate(steps):
        e = est.step(t, inputs, meas)
        row = loop.step_block(IN[k:k + 1])[0]
        assert row[K.OUT_STATUS] == e.status, f"status at step {k}"
        _assert_vectors(row, k, ((K.OUT_MU, e.mu), (K.OUT_SLIP, e.slip), (K.OUT_P, e.P_diag)))
        if abs(e.kappa) >= KAPPA_MAX:
            clipped += 1
            assert e.status & SLIP_UNCERTAIN
    assert clipped > 300
    assert loop.counters == est.counters
