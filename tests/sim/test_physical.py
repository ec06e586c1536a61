"""Physical truth model: its physics against hand calculations, and what it writes on the bus."""

import csv
import hashlib
import math
import tomllib
from collections import defaultdict

import numpy as np
import pytest

from tractionecu.bus import j1939
from tractionecu.bus.candump import read_candump
from tractionecu.config import G, SensorSpec, VehicleParams
from tractionecu.model.mucurve import SOIL_CLASSES
from tractionecu.recording.reader import read_recording
from tractionecu.sim import scenarios
from tractionecu.sim import tyre as ty
from tractionecu.sim.physical import HitchSpec, axle_loads, wheel_speed_ratios
from tractionecu.sim.sensors import ToothedPickup, draw_biases, pickup_speeds
from tractionecu.sim.simulator import ImplementSpec, simulate
from tractionecu.sim.writer import write_recording

P = VehicleParams()


# ---- tyre–soil: Brixius at known points ---------------------------------------------------------------
def test_brixius_gross_traction_and_motion_resistance_at_known_points():
    # GT(B_n = 50, s = 0.1) = 0.88 (1 − e^−5)(1 − e^−0.75) + 0.04, MR = 1/50 + 0.04 + 0.05/√50 (by hand).
    assert ty.gross_traction_ratio(0.1, 50.0) == pytest.approx(0.501189, abs=1e-6)
    assert ty.motion_resistance_ratio(0.1, 50.0) == pytest.approx(0.067071, abs=1e-6)
    assert ty.gross_traction_ratio(0.0, 50.0) == pytest.approx(0.04)
    # At full slip GT tends to 0.88 (1 − e^{−0.1 B_n}) + 0.04.
    assert ty.gross_traction_ratio(1.0, 30.0) == pytest.approx(0.88 * (1 - math.exp(-3.0)) * (1 - math.exp(-7.5)) + 0.04)


def test_mobility_number_from_cone_index_and_tyre_by_hand():
    # CI 1 MPa, 540/65R34 (b 0.54 m, d 1.6 m, h 0.351 m), W = 18 kN, k_z = 1e5 + 1.6 × 1.6e5 = 356 kN/m.
    delta = 18000.0 / 356000.0
    hand = (1e6 * 0.54 * 1.6 / 18000.0) * (1 + 5 * delta / 0.351) / (1 + 3 * 0.54 / 1.6)
    assert hand == pytest.approx(41.03, abs=0.01)
    assert float(ty.mobility_number(1e6, 18000.0, 0.54, 0.8, ty.TyreSpec(), 1.6e5)) == pytest.approx(hand, rel=1e-12)


def test_off_class_soils_fit_no_class():
    """The peaked and sigmoid soils leave a clear residual against every class of the filter."""
    for soil in scenarios.OFF_CLASS_SOILS:
        s = np.linspace(0.0, 0.4, 81)
        mu = ty.paper_mu(s, soil, P.mass_kg * G / 4, P.tyre_width_m, P.r0_m, ty.TyreSpec(), P.tyre_pressure_pa, P.rho_t)
        best = 1.0
        for cls in SOIL_CLASSES.values():
            g = cls.g(s)
            a = float(np.dot(g, mu) / np.dot(g, g))
            r2 = 1 - np.sum((mu - a * g) ** 2) / np.sum((mu - mu.mean()) ** 2)
            best = min(best, 1 - r2)
        assert best > 0.01, soil.name


# ---- load transfer ----------------------------------------------------------------------------------
def test_axle_loads_match_a_static_hand_calculation():
    # 6300 kg, L 2.5 m, CG 1.0 m ahead of the rear axle, 10 kN draft at 0.5 m, drawbar 1 m behind, 8° pull.
    fzf, fzr = axle_loads(P, HitchSpec(), P.mass_kg, 10000.0, 0.0, 0.0)
    tb = math.tan(math.radians(8.0))
    hand_f = (6300 * 9.81 * 1.0 - 10000 * (0.5 + 1.0 * tb)) / 2.5
    assert fzf == pytest.approx(hand_f, rel=1e-12)
    assert hand_f == pytest.approx(22159.0, abs=1.0)
    assert fzf + fzr == pytest.approx(6300 * 9.81 + 10000 * tb)
    # Acceleration and grade move load rearwards by m (a + g sin θ) h_cg / L.
    f2, _ = axle_loads(P, HitchSpec(), P.mass_kg, 0.0, 0.5, 0.0)
    f0, _ = axle_loads(P, HitchSpec(), P.mass_kg, 0.0, 0.0, 0.0)
    assert f0 - f2 == pytest.approx(6300 * 0.5 * 1.0 / 2.5)


@pytest.fixture(scope="module")
def straight_run():
    scn = scenarios.get("paper-straight", truth="physical", duration_s=60.0)
    scn.implement = ImplementSpec(draft_cv=0.0)
    return scn, simulate(scn)


def test_simulated_front_load_is_the_hand_calculation_at_steady_pull(straight_run):
    scn, tr = straight_run
    k = np.flatnonzero(tr.work)[-500:]                       # steady cruise with the implement in work
    assert np.ptp(tr.v[k]) < 0.05
    hand = np.array([axle_loads(scn.vehicle, scn.physical.hitch, scn.vehicle.mass_kg, f, 0.0, 0.0)[0] for f in tr.fdx[k]])
    assert np.allclose(tr.fzf[k], hand, rtol=0.005)
    assert tr.fzf[k].mean() < scn.vehicle.static_front_load_n() - 1000.0


def test_mu_and_rho_in_the_paper_split_close_the_speed_equation(straight_run):
    """Σ(μ − ρ_s) F_z = F_dx at steady cruise: the truth's μ and ρ_s carry the whole force balance."""
    scn, tr = straight_run
    k = np.flatnonzero(tr.work)[-300:]
    net = (tr.mu[k] * tr.fz[k]).sum(axis=1) - tr.rho_s[k] * tr.fz[k].sum(axis=1)
    air = 0.5 * 1.2 * scn.vehicle.cd_area_m2 * tr.v[k] ** 2
    assert np.mean(net) == pytest.approx(np.mean(tr.fdx[k] + air), rel=0.01)


# ---- turning kinematics -----------------------------------------------------------------------------
def test_wheel_speed_ratios_ackermann():
    g = wheel_speed_ratios(1 / 30.0, 1.8, 2.5)
    assert g[3] / g[2] == pytest.approx(1.03 / 0.97)
    assert g[0] == pytest.approx(math.hypot(0.97, 2.5 / 30))
    assert g[0] > g[2] and g[1] > g[3]                      # front wheels on the larger radius


@pytest.fixture(scope="module")
def circle_run():
    scn = scenarios.get("circles-30m", duration_s=70.0)
    return scn, simulate(scn)


def test_outer_wheels_faster_by_the_geometric_ratio_in_a_circle(circle_run):
    scn, tr = circle_run
    w = scn.vehicle.track_width_m
    k = np.flatnonzero((np.abs(tr.curvature - 1 / 30.0) < 1e-4) & tr.work)
    assert len(k) > 500
    ratio = (1 + w / 60.0) / (1 - w / 60.0)
    assert np.allclose(tr.v_wheel[k, 3] / tr.v_wheel[k, 2], ratio, rtol=1e-9)
    # The wheels themselves turn faster on the outside by that ratio, within the slips' difference.
    r = ty.rolling_radius(tr.fz[k], scn.vehicle.r0_m, ty.TyreSpec(), scn.vehicle.tyre_pressure_pa)
    om = (r[:, 3] * tr.omega[k, 3]) / (r[:, 2] * tr.omega[k, 2])
    assert np.median(om) == pytest.approx(ratio, rel=0.005)
    # Lateral load transfer: the axles' outer-minus-inner load differences times half the track balance the
    # roll moment m v² κ h_cg (statics of the rigid body), shared by the axles as their loads (the loads of a
    # step are set from the speed at its start, the previous sample).
    m, h = scn.vehicle.mass_kg, scn.vehicle.cg_height_m
    hand = m * tr.v[k - 1] ** 2 / 30.0 * h
    got = ((tr.fz[k, 1] - tr.fz[k, 0]) + (tr.fz[k, 3] - tr.fz[k, 2])) * w / 2
    assert np.allclose(got, hand, rtol=1e-6)
    share_f = (tr.fz[k, 0] + tr.fz[k, 1]) / tr.fz[k].sum(axis=1)
    assert np.allclose((tr.fz[k, 1] - tr.fz[k, 0]) * w / 2, share_f * hand, rtol=1e-6)
    # Slip is against each wheel's own ground speed: it stays near the straight-line value on both sides.
    assert abs(np.median(tr.slip[k, 3]) - np.median(tr.slip[k, 2])) < 0.01


# ---- mechanical drive-line and its J1939 messages -----------------------------------------------------
@pytest.fixture(scope="module")
def mech(tmp_path_factory):
    out = tmp_path_factory.mktemp("mech")
    scn = scenarios.get("mechanical-three-soils", duration_s=40.0)
    tr = simulate(scn)
    write_recording(scn, tr, out)
    return scn, tr, out


def test_gear_changes_happen(mech):
    scn, tr, out = mech
    gears = np.unique(tr.gear)
    assert len(gears) >= 4 and gears.min() == 1                 # accelerating from rest through the gears
    assert np.all(np.diff(tr.gear)[np.diff(tr.gear) != 0] != 0)
    ratio = np.asarray(scn.physical.drivetrain.mech.gears)[tr.gear - 1]
    assert np.allclose(tr.gear_ratio, ratio)
    # Engine speed is the wheel-side node speed times gear and final drive: within the governor's range.
    rpm = tr.engine_speed * 60 / (2 * np.pi)
    assert rpm[tr.work].min() > 1200 and rpm.max() < 2400


def test_mfwd_front_lead_makes_front_wheels_slip_more(mech):
    _, tr, _ = mech
    k = tr.work & tr.mfwd
    assert k.sum() > 500
    assert np.mean(tr.slip[k, :2]) > np.mean(tr.slip[k, 2:]) + 0.01


def test_j1939_periods_in_the_written_capture(mech):
    scn, tr, out = mech
    times = defaultdict(list)
    for f in read_candump(out / "can.log"):
        times[j1939.pgn_of(f.can_id)].append(f.t)
    period = {pgn: float(np.median(np.diff(t))) for pgn, t in times.items() if len(t) > 2}
    expect = {61444: 0.02, 61445: 0.1, 65265: 0.1, 65215: 0.1, 65096: 0.1, 65097: 0.1, 65093: 0.1}
    for pgn, p in expect.items():
        assert period[pgn] == pytest.approx(p, abs=0.002), pgn
    # EC1 by BAM every 5 s: a TP.CM announcing PGN 65251 and its TP.DT packets.
    cm = [f for f in read_candump(out / "can.log") if j1939.pgn_of(f.can_id) == 60416]
    assert len(cm) >= 7 and all(c.data[0] == 32 and int.from_bytes(c.data[5:8], "little") == 65251 for c in cm)
    assert np.median(np.diff([c.t for c in cm])) == pytest.approx(5.0, abs=0.01)
    # None of the hub drive's proprietary messages.
    assert not {65296, 65297, 65298} & set(times)
    rec = read_recording(out)
    assert np.nanmax(rec.signals["EngineReferenceTorque"].value) == scn.physical.drivetrain.mech.engine.reference_torque_nm
    pct = rec.signals["ActualEnginePercentTorque"]
    assert np.nanmedian(pct.value) > 20.0
    with open(out / "export_1hz.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == pytest.approx(40, abs=1)
    assert "EEC1 SPN190 Engine Speed [rpm]" in rows[0]
    truth = tomllib.loads((out / "truth.toml").read_text())
    assert truth["truth_model"] == "physical" and truth["drivetrain"] == "mechanical"


# ---- sensors --------------------------------------------------------------------------------------------
def test_bias_draws_within_tolerance():
    spec = SensorSpec()
    for seed in range(200):
        b = draw_biases(spec, np.random.default_rng(seed))
        assert max(abs(x) for x in b.torque_gain) <= spec.torque_gain_tol_rel
        assert max(abs(x) for x in b.torque_offset_nm) <= spec.torque_offset_tol_nm
        assert abs(b.axle_offset_n) <= spec.axle_offset_tol_n and abs(b.draft_offset_n) <= spec.draft_offset_tol_n
        assert abs(b.axle_gain) <= spec.axle_gain_tol_rel and abs(b.draft_gain) <= spec.draft_gain_tol_rel
        assert 0.05 <= b.gnss_latency_s <= spec.gps_latency_tol_s


def test_biased_recording_carries_its_drawn_gains(tmp_path):
    scn = scenarios.get("biased-sensors", seed=3, duration_s=30.0)
    tr = simulate(scn)
    write_recording(scn, tr, tmp_path)
    b = tomllib.loads((tmp_path / "truth.toml").read_text())["biases"]
    assert any(abs(g) > 1e-4 for g in b["torque_gain"]) and 0.05 <= b["gnss_latency_s"] <= 0.1
    rec = read_recording(tmp_path)
    s = rec.signals["DriveTorque_RL"]
    k = np.clip(np.round((s.t - scn.start_epoch) / scn.control_dt).astype(int) - 1, 0, len(tr.t) - 1)
    big = np.abs(tr.md[k, 2]) > 2000
    ratio = np.median((s.value[big] - b["torque_offset_nm"][2]) / tr.md[k, 2][big])
    assert ratio == pytest.approx(1 + b["torque_gain"][2], abs=0.002)


def test_toothed_pickup_error_repeats_once_per_revolution():
    t = np.arange(0, 20.0, 0.001)
    omega = np.full(len(t), 2 * np.pi)                       # one revolution per second
    ft = np.arange(1.0, 20.0, 0.01)
    pk = ToothedPickup()
    m = pickup_speeds(t, omega, ft, 0.01, pk, 25.0, np.random.default_rng(1))
    err = m / omega[0] - 1
    # Almost no bias: at this speed every 10 ms window holds 15 teeth and the tooth gap between two
    # windows is never measured, so one window's pitch error (0.005 × √2 / 15 ≈ 5e-4) can remain.
    assert abs(err.mean()) < 1e-3
    assert 5e-4 < err.std() < 5e-3                           # 0.1–0.5 % ripple (SensorSpec's figure)
    lag = 100                                                 # one wheel revolution = 100 frames
    c = np.corrcoef(err[:-lag], err[lag:])[0, 1]
    assert c > 0.9                                            # coloured: the same pattern every revolution
    # At standstill the speed reads zero after the time-out.
    om2 = np.where(t < 10, 2 * np.pi, 0.0)
    m2 = pickup_speeds(t, om2, ft, 0.01, pk, 25.0, np.random.default_rng(1))
    assert np.all(m2[ft > 10.0 + pk.timeout_s + 0.05] == 0.0)


def test_hub_recording_wheel_speeds_follow_the_motor_shafts(tmp_path):
    scn = scenarios.get("physical-three-soils", duration_s=20.0)
    tr = simulate(scn)
    write_recording(scn, tr, tmp_path)
    rec = read_recording(tmp_path)
    s = rec.signals["WheelSpeed_FL"]
    k = np.clip(np.round((s.t - scn.start_epoch) / scn.control_dt).astype(int) - 1, 0, len(tr.t) - 1)
    fast = tr.omega_sensor[k, 0] > 2.0
    rel = s.value[fast] / tr.omega_sensor[k, 0][fast] - 1
    assert abs(np.median(rel)) < 0.003 and np.std(rel) < 0.01
    assert "FrontAxleLoad" in rec.signals and "DraftForce" in rec.signals


# ---- the paper's scenario unchanged ------------------------------------------------------------------
PAPER_20S_SHA256 = {
    # Written by the simulator before the physical truth model was added (same seed and duration).
    "can.log": "71b3d261a9cdc804c23e01f47f8fb3f0b978d29f927065ebd841dead0d8599a1",
    "gps.nmea": "13949eee849e2a62a186a787842d88457a1ac98c1d16c85f2286348ef2d5ee12",
    "truth.csv": "c010a683600a0eb9d2ac9a09ec41814fc33670866b3ecd12f46c5ae9d076c696",
}


def test_paper_scenario_byte_identical(tmp_path):
    """paper-three-soils writes the same bytes as before the physical model existed (20 s, seed 0)."""
    scn = scenarios.get("paper-three-soils", duration_s=20.0)
    assert scn.truth == "paper" and scn.physical is None
    write_recording(scn, simulate(scn), tmp_path)
    got = {n: hashlib.sha256((tmp_path / n).read_bytes()).hexdigest() for n in PAPER_20S_SHA256}
    assert got == PAPER_20S_SHA256


def test_s_curve_and_circle_plans_have_30m_radius():
    from tractionecu.sim.physical import _path_curvature
    from tractionecu.sim.plan import circles, s_curves
    p = s_curves(0.0, 0.0, 240.0, 3, 12.0, radius=30.0, v_work=2.5, v_turn=1.2)
    k = _path_curvature(p)[p.work]
    assert np.median(np.abs(k)) == pytest.approx(1 / 30.0, rel=0.01)
    assert (k > 0.02).mean() > 0.3 and (k < -0.02).mean() > 0.3        # left and right arcs alternate
    sign_changes = np.count_nonzero(np.diff(np.sign(k[np.abs(k) > 0.02])) != 0)
    assert sign_changes >= 20
    c = circles(0.0, 0.0, 30.0, 2, v_work=2.5)
    kc = _path_curvature(c)
    assert np.sum(np.abs(kc - 1 / 30) < 1e-3) * 0.05 == pytest.approx(2 * np.pi * 30, rel=0.01)
    assert np.sum(np.abs(kc + 1 / 30) < 1e-3) * 0.05 == pytest.approx(2 * np.pi * 30, rel=0.01)
