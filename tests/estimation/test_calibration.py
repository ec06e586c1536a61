"""Rolling-radius self-calibration (estimation/calibration.py): the regression, its tests, and a recording."""

from __future__ import annotations

import math
import numpy as np
import pytest

from tractionecu.estimation.calibration import CalibrationConfig, RadiusCalibration, slip_at
from tractionecu.estimation.config import EstimatorConfig
from tractionecu.model.mucurve import SOIL_CLASSES

STUBBLE = SOIL_CLASSES["stubble"]
RD = 0.78


def test_slip_at_inverts_the_curve():
    for cls in SOIL_CLASSES.values():
        for mu in (0.0, 0.02, 0.08, 0.15, 0.4):
            s = slip_at(mu, 0.7, cls.p, cls.alpha1, cls.alpha2)
            assert 0.7 * float(cls.g(s)) == pytest.approx(mu, abs=1e-9)
    assert math.isnan(slip_at(0.69, 0.7, STUBBLE.p, STUBBLE.alpha1, STUBBLE.alpha2))


def _push(cal, k_true, n, rng, mu_lo=0.04, mu_hi=0.12, v=3.0, turn=0.0, accel=0.0, t0=0.0):
    """n GNSS epochs at 10 Hz of a machine whose tyres roll k_true × r_d, on stubble with a = 0.7."""
    for j in range(n):
        mu = rng.uniform(mu_lo, mu_hi)
        s = slip_at(mu, 0.7, STUBBLE.p, STUBBLE.alpha1, STUBBLE.alpha2)
        w = v / (k_true * RD * (1.0 - s))
        om = [w * (1 + turn), w * (1 - turn), w * (1 + turn), w * (1 - turn)]
        om = [x * (1.0 + 0.002 * rng.standard_normal()) for x in om]
        cal.push(t0 + 0.1 * j, v + 0.05 * rng.standard_normal(), om, RD, RD, [mu] * 4, accel, True, 0.7, "stubble")


def test_scale_recovered_within_its_interval_and_applied():
    rng = np.random.default_rng(1)
    cal = RadiusCalibration()
    _push(cal, 1.02, 400, rng)
    f, r = cal.state()
    for ax in (f, r):
        assert ax.blocks == 40
        assert abs(ax.scale - 1.02) <= ax.halfwidth < 0.005
        assert ax.applied == ax.scale
    assert cal.applied == (f.scale, r.scale) and cal.version >= 1
    s = cal.summary()
    assert s["front"]["applied"] and s["rear"]["blocks"] == 40


def test_not_applied_before_enough_blocks_and_samples_that_fail_are_skipped():
    rng = np.random.default_rng(2)
    cal = RadiusCalibration(CalibrationConfig(min_blocks=20))
    _push(cal, 1.02, 150, rng)                               # 15 blocks
    assert cal.state()[0].blocks == 15 and cal.applied == (1.0, 1.0)
    n = cal.samples
    _push(cal, 1.02, 50, rng, turn=0.05, t0=100.0)           # curving: left/right differ by 10 %
    _push(cal, 1.02, 50, rng, accel=0.3, t0=200.0)           # accelerating (GNSS latency)
    _push(cal, 1.02, 50, rng, mu_lo=0.3, mu_hi=0.4, t0=300.0)  # in work: the curve's slip is not small
    _push(cal, 1.02, 50, rng, v=0.5, t0=400.0)               # too slow
    assert cal.samples == n and cal.rejected == 200 and cal.state()[0].blocks == 15


def test_outliers_do_not_move_the_scale():
    rng = np.random.default_rng(3)
    cal = RadiusCalibration()
    _push(cal, 0.98, 300, rng)
    _push(cal, 0.90, 10, rng, t0=30.0)                      # one block of nonsense (a slipping stretch)
    _push(cal, 0.98, 300, rng, t0=31.0)
    f = cal.state()[0]
    assert abs(f.scale - 0.98) <= f.halfwidth < 0.005


def test_recording_with_a_radius_error(tmp_path):
    """+2 % rolling radius: the scale is found within its interval, applied, and slip and μ errors in work fall."""
    from tractionecu.evaluation.coverage import radius_scenario, work_errors
    from tractionecu.evaluation.scoring import read_truth
    from tractionecu.pipeline.replay import replay
    from tractionecu.recording.reader import read_recording
    from tractionecu.sim.simulator import simulate
    from tractionecu.sim.writer import write_recording

    scn = radius_scenario(0.02, seed=5)
    write_recording(scn, simulate(scn), tmp_path / "rec")
    rec = read_recording(tmp_path / "rec")
    truth = read_truth(rec.truth_csv_path, rec.truth_toml_path)
    errs = {}
    for on in (True, False):
        cfg = EstimatorConfig(calibration=CalibrationConfig(enabled=on))
        a = replay(rec, cfg=cfg).arrays
        w = work_errors(a, truth)
        assert w["work_samples"] > 1000
        errs[on] = (w["slip_mae"], w["mu_rel_error"])
        k = np.clip(np.searchsorted(truth.t, a["t"] + 1e-9, side="right") - 1, 0, len(truth.t) - 1)
        work_start = int(np.argmax(a["valid"] & (truth.mu[k].mean(axis=1) > 0.2)))
        if on:
            scale, hw, applied = a["radius_scale"][-1], a["radius_halfwidth"][-1], a["radius_applied"][-1]
            assert (np.abs(scale - 1.02) <= hw).all() and (hw <= 0.005).all()
            assert np.array_equal(applied, scale)
            # applied before the work began
            first = int(np.argmax(a["radius_applied"][:, 0] != 1.0))
            assert 0 < first < work_start
        else:
            assert np.isnan(a["radius_scale"][-1]).all() and (a["radius_applied"][-1] == 1.0).all()
    print(f"slip MAE in work: {errs[False][0]:.4f} uncalibrated, {errs[True][0]:.4f} calibrated; "
          f"μ error {errs[False][1]:.4f} -> {errs[True][1]:.4f}")
    assert errs[True][0] < 0.6 * errs[False][0]
    assert errs[True][1] < errs[False][1]
