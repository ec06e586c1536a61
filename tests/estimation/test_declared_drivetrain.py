"""The hub estimator on the vehicle its owner declares: the hub reduction's efficiency, the line of pull and
the calibrated rolling radius (model doc "Declared drivetrain").

Fast and seeded: the filter model's rear load and radius law against their formulas, the input mapping of
the reported motor torque, the efficiency tolerance in the reported uncertainty, and a short recording of
the physical truth model (hub losses, pull angle, its own tyre radius) replayed with and without the
declared figures.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from tractionecu.config import DrivetrainSpec, VehicleParams
from tractionecu.estimation.estimator import Estimator
from tractionecu.estimation.uncertainty import SystematicUncertainty
from tractionecu.config import SensorSpec
from tractionecu.model.vehicle import FilterModel, N_STATE, rk4, rolling_radius

VEH = VehicleParams()


def _declared(veh: VehicleParams = VEH, **dt) -> VehicleParams:
    kw = {k: dt.pop(k) for k in ("pull_angle_deg",) if k in dt}
    return dataclasses.replace(veh, drivetrain=dataclasses.replace(veh.drivetrain, **dt), **kw)


def test_hub_defaults_are_the_papers_machine():
    d = DrivetrainSpec()
    assert d.efficiency == 1.0 and d.efficiency_tolerance == 0.0 and d.rolling_radius_m == 0.0
    m = DrivetrainSpec(kind="mechanical", final_drive_ratio=20.0)
    assert m.efficiency == 0.88 and m.efficiency_tolerance == 0.03


def test_pull_angle_loads_the_rear_axle_by_fdx_tan_beta():
    beta = 8.0
    veh = _declared(pull_angle_deg=beta)
    m0, m1 = FilterModel(VEH), FilterModel(veh)
    fzf, fdx = 24000.0, 15000.0
    ff0, fr0, _, _ = m0.load_floats(fzf, fdx)
    ff1, fr1, _, rdr1 = m1.load_floats(fzf, fdx)
    assert ff1 == ff0 == 0.5 * fzf
    assert fr0 == 0.5 * (VEH.weight_n - fzf)                   # β = 0: the paper's load, draft ignored
    assert fr1 == pytest.approx(0.5 * (VEH.weight_n - fzf + fdx * math.tan(math.radians(beta))), rel=1e-12)
    assert rdr1 == pytest.approx(float(rolling_radius(fr1, veh)), rel=1e-12)
    # the vectorised loads, the float path and the compiled step agree
    u = np.array([3000.0, 3000.0, 4000.0, 4000.0, fzf, fdx, 0.0])
    fz, rd = m1.loads(u)
    assert fz[2] == fr1 and fz[0] == ff1
    x = np.array([[3.2, 3.2, 3.3, 3.3, 2.5, 0.30, 0.30, 0.35, 0.35, 0.06]])
    ref = rk4(lambda y: m1.rhs(y, u, fz, rd), x, 0.01)
    np.testing.assert_allclose(m1.step(x, u, 0.01), ref, rtol=1e-12, atol=1e-12)
    # more rear load, the same torque: a smaller wheel acceleration than with β = 0
    assert m1.step(x, u, 0.01)[0, 2] < m0.step(x, u, 0.01)[0, 2]


def test_declared_rolling_radius_is_eq9_through_r0_and_the_calibration():
    r_cal = 0.781
    veh = _declared(rolling_radius_m=r_cal)
    f_s = 0.5 * (1.0 - veh.static_front_fraction) * veh.weight_n
    assert float(rolling_radius(f_s, veh)) == pytest.approx(r_cal, abs=1e-12)
    assert float(rolling_radius(0.0, veh)) == veh.r0_m
    assert float(rolling_radius(0.5 * f_s, veh)) == pytest.approx(veh.r0_m - 0.5 * (veh.r0_m - r_cal), abs=1e-12)
    m = FilterModel(veh)
    _, fr, _, rdr = m.load_floats(veh.weight_n - 2 * f_s)
    assert fr == pytest.approx(f_s) and rdr == pytest.approx(r_cal, abs=1e-12)


def _first_inputs(est: Estimator, md, direction: float = 1.0):
    est._dir = direction
    est.step(0.0, {"Md": md, "Fzf": 24000.0, "Fdx": 10000.0})
    return est._u[:4].copy()


def test_efficiency_maps_motor_to_wheel_torque_against_the_power_flow():
    eta = 0.95
    md = np.array([2000.0, 2000.0, -1000.0, 3000.0])
    base = _first_inputs(Estimator(VEH), md)
    np.testing.assert_array_equal(base, md)                    # η = 1: the reported torque as it is
    got = _first_inputs(Estimator(_declared(efficiency=eta)), md)
    np.testing.assert_allclose(got, [eta * 2000.0, eta * 2000.0, -1000.0 / eta, eta * 3000.0], rtol=1e-15)
    rev = _first_inputs(Estimator(_declared(efficiency=eta)), md, direction=-1.0)   # reversing: signs swap
    np.testing.assert_allclose(rev, [2000.0 / eta, 2000.0 / eta, -1000.0 * eta, 3000.0 / eta], rtol=1e-15)


def test_efficiency_tolerance_enters_the_systematic_uncertainty():
    args = ([3000.0] * 4, 24000.0, 10000.0, 0.77, 0.76, 0.01, 0.01)
    v0, r0 = SystematicUncertainty(SensorSpec(), VEH).variances(*args)
    v1, r1 = SystematicUncertainty(SensorSpec(), _declared(efficiency=0.95, efficiency_tolerance=0.02)).variances(*args)
    fz = (0.5 * 24000.0, 0.5 * (VEH.weight_n - 24000.0))
    for i in range(4):
        c = 3000.0 / ((0.77, 0.76)[i // 2] * fz[i // 2])
        assert v1[i] - v0[i] == pytest.approx((0.02 * c) ** 2, rel=1e-9)
    assert r1 > r0


def _mu_error(rec_dir, vehicle=None) -> float:
    from tractionecu.evaluation.scoring import read_truth
    from tractionecu.pipeline.replay import replay
    from tractionecu.recording.reader import read_recording

    res = replay(read_recording(rec_dir), vehicle=vehicle)
    a = res.arrays
    tr = read_truth(rec_dir / "truth.csv")
    k = np.clip(np.searchsorted(tr.t, a["t"] + 1e-9, side="right") - 1, 0, len(tr.t) - 1)
    m = a["valid"] & (np.abs(tr.v[k]) > 1.0) & (tr.mu[k].min(axis=1) > 0.05)
    assert m.sum() > 1000
    return float(np.mean(np.abs(a["mu"][m] - tr.mu[k][m]) / np.abs(tr.mu[k][m])))


def test_physical_recording_mu_error_falls_with_the_declared_figures(make_recording):
    from tractionecu.config import load_vehicle

    rec_dir = make_recording("physical-three-soils", 1, 60.0)
    declared = load_vehicle(rec_dir / "vehicle.toml")
    dt = declared.drivetrain
    truth_eta = 0.95                            # sim.drivetrain.HubDriveSpec: the declared figure is not it
    assert dt.efficiency != truth_eta and abs(dt.efficiency / truth_eta - 1.0) <= dt.efficiency_tolerance
    assert declared.pull_angle_deg != 0.0 and dt.rolling_radius_m > 0.0
    bare = _declared(declared, efficiency=1.0, efficiency_tolerance=0.0, rolling_radius_m=0.0, pull_angle_deg=0.0)
    e_bare = _mu_error(rec_dir, bare)
    e_decl = _mu_error(rec_dir)
    assert e_decl < 0.6 * e_bare, (e_decl, e_bare)


def test_pull_angle_tolerance_widens_the_rear_wheels_band_only():
    args = ([3000.0] * 4, 24000.0, 15000.0, 0.77, 0.76, 0.01, 0.01)
    veh = _declared(pull_angle_deg=8.0)
    v0, _ = SystematicUncertainty(SensorSpec(), veh).variances(*args)
    unc = SystematicUncertainty(SensorSpec(), dataclasses.replace(veh, pull_angle_tol_deg=2.0))
    v1, _ = unc.variances(*args)
    assert v1[:2] == v0[:2]
    fr = 0.5 * (veh.weight_n - 24000.0 + 15000.0 * math.tan(math.radians(8.0)))
    c = 3000.0 / (0.76 * fr)
    du = 0.5 * 15000.0 * math.radians(2.0) / math.sqrt(3.0) / math.cos(math.radians(8.0)) ** 2
    assert v1[2] - v0[2] == pytest.approx((c * du / fr) ** 2, rel=1e-9)
