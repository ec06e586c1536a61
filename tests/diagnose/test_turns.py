"""The diagnosis's nominal model in turns: path curvature, lateral load transfer, per-wheel ground speeds."""

from __future__ import annotations

import numpy as np
import pytest

from tractionecu.config import G, VehicleParams
from tractionecu.diagnose.data import Frame
from tractionecu.diagnose.features import (lateral_load_transfer, path_curvature, turn_speed, turn_threshold,
                                           wheel_state)
from tractionecu.model.vehicle import FilterModel, rolling_radius, wheel_loads, wheel_speed_factors

RATE = 10.0


def _veh() -> VehicleParams:
    return VehicleParams(front_roll_share=0.4)


def _path(kappa_turn: float = 0.2, v: float = 2.0, n: int = 600, turn=(200, 350), ramp: int = 20):
    """Curvature (straight, a ramp into a steady arc, a ramp out, straight) and speed per row."""
    k = np.zeros(n)
    a, b = turn
    k[a:b] = kappa_turn
    k[a:a + ramp] = np.linspace(0.0, kappa_turn, ramp)
    k[b - ramp:b] = np.linspace(kappa_turn, 0.0, ramp)
    return k, np.full(n, float(v))


def _frame(kappa, v, *, slip=(0.05, 0.05, 0.05, 0.05), wheels_follow_path=True, course=True, seed=0) -> Frame:
    """A recording of the turn: wheel speeds from each wheel's ground speed k_i(κ)·v, its loaded radius (the
    lateral load transfer at v² κ) and its slip; GNSS course from the heading ψ̇ = κ v (turned by π in reverse)."""
    veh = _veh()
    n = kappa.size
    t = np.arange(n) / RATE
    fzf = np.full(n, veh.static_front_load_n())
    fz = wheel_loads(fzf, veh)
    kk = kappa if wheels_follow_path else np.zeros(n)
    fz = FilterModel(veh).lateral_loads(fz, v, kk)
    r = rolling_radius(fz, veh)
    ground = wheel_speed_factors(kk, veh.track_width_m, veh.wheelbase_m) * v[:, None]
    omega = ground / (r * (1.0 - np.asarray(slip)[None, :]))
    psi = np.cumsum(kappa * v) / RATE
    heading = psi + np.where(v < 0, np.pi, 0.0)
    rng = np.random.default_rng(seed)
    fr = Frame(t=t, t0_epoch=0.0, rate_hz=RATE, vehicle=veh)
    fr.omega = omega
    fr.md = np.full((n, 4), 1000.0) * np.sign(v)[:, None] + rng.normal(0.0, 1.0, (n, 4))
    fr.fzf = fzf
    fr.v_gps = np.abs(v)
    fr.heading = heading if course else None
    return fr


def _with_turns(fr: Frame) -> Frame:
    """What features.compute() sets before the first wheel state."""
    kappa, known, _turn = path_curvature(fr)
    fr.kappa, fr.kappa_known = kappa, known
    fr.lat_accel = turn_speed(fr) ** 2 * kappa
    return fr


def test_turn_loads_and_slips_follow_the_formulas():
    kappa, v = _path()
    fr = _with_turns(_frame(kappa, v))
    veh = fr.vehicle
    steady = slice(230, 320)
    # κ from the rear wheels equals the path's (equal slips on both rear wheels), and is a turn.
    np.testing.assert_allclose(fr.kappa[steady], 0.2, rtol=1e-9)   # radii from the loads: iterated
    assert np.all(fr.kappa_known)
    ws = wheel_state(fr, np.zeros((fr.n, 4)), v)
    # Loads: F_z,FL/FR = F_zf/2 ∓ δ_f, F_z,RL/RR = F_zr/2 ∓ δ_r, δ = λ m v² κ h_cg / b.
    lam, m, h, b = 0.4, veh.mass_kg, veh.cg_height_m, veh.track_width_m
    d_all = m * v[steady] ** 2 * 0.2 * h / b
    ff = 0.5 * fr.fzf[steady]
    fr_ = 0.5 * (veh.weight_n - fr.fzf[steady])
    np.testing.assert_allclose(ws.fz[steady, 0], ff - lam * d_all, rtol=1e-12)
    np.testing.assert_allclose(ws.fz[steady, 1], ff + lam * d_all, rtol=1e-12)
    np.testing.assert_allclose(ws.fz[steady, 2], fr_ - (1 - lam) * d_all, rtol=1e-12)
    np.testing.assert_allclose(ws.fz[steady, 3], fr_ + (1 - lam) * d_all, rtol=1e-12)
    assert np.all(ws.fz[steady, 1] - ws.fz[steady, 0] > 1000.0)          # a real shift, not a rounding
    # The moments balance: (δ_f + δ_r) b = m a_y h_cg.
    dsum = 0.5 * (ws.fz[steady, 1] - ws.fz[steady, 0] + ws.fz[steady, 3] - ws.fz[steady, 2])
    np.testing.assert_allclose(dsum * b, m * v[steady] ** 2 * 0.2 * h, rtol=1e-9)
    # Slip of every wheel against its own ground speed: the 0.05 it was made with, in the turn and out of it.
    np.testing.assert_allclose(ws.slip, 0.05, atol=1e-9)
    # Without the turn terms (the old nominal model) the rear wheels' slips in the arc are off by ∓κb/2.
    fr0 = _frame(kappa, v)
    ws0 = wheel_state(fr0, np.zeros((fr.n, 4)), v)
    assert np.max(np.abs(ws0.slip[steady, 2:] - 0.05)) > 0.1


def test_the_estimators_lateral_loads_are_the_same_formula():
    veh = _veh()
    rng = np.random.default_rng(3)
    n = 200
    fzf = rng.uniform(15e3, 30e3, n)
    v = rng.uniform(-6.0, 6.0, n)
    kappa = rng.uniform(-0.5, 0.5, n)          # includes a_y large enough for the 0.9 clip
    fz = wheel_loads(fzf, veh)
    ours = lateral_load_transfer(fz, v * v * kappa, veh, veh.mass_kg)
    theirs = FilterModel(veh).lateral_loads(fz, v, kappa)
    np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=1e-9)
    assert np.any(np.abs(ours[:, 1] - ours[:, 0]) >= 0.9 * fz[:, 0] * 2 - 1e-6)   # the clip was reached


def test_a_straight_recording_gives_the_same_wheel_state_bit_for_bit():
    n = 400
    kappa, v = np.zeros(n), np.full(n, 2.5)
    # A rear slip difference of 0.01 (soil under one track): the wheel ratio reads 0.0056 1/m, but the
    # course is straight, so it is no turn.
    fr = _with_turns(_frame(kappa, v, slip=(0.06, 0.06, 0.05, 0.06)))
    assert np.all(fr.kappa == 0.0) and np.all(fr.lat_accel == 0.0)
    ws = wheel_state(fr, np.zeros((n, 4)), v, delta_m=300.0, eps_r=0.01)
    old = _frame(kappa, v, slip=(0.06, 0.06, 0.05, 0.06))      # no curvature on the frame: the old model
    assert old.kappa is None
    ws_old = wheel_state(old, np.zeros((n, 4)), v, delta_m=300.0, eps_r=0.01)
    for name in ("fz", "r", "fh", "mu", "slip"):
        assert np.array_equal(getattr(ws, name), getattr(ws_old, name)), name


def test_paper_truth_turn_whose_wheels_roll_at_v_keeps_the_straight_model():
    """The paper's straight-line simulator driven round a headland: the course turns, the wheels do not."""
    kappa, v = _path(kappa_turn=0.3)
    fr = _with_turns(_frame(kappa, v, wheels_follow_path=False))
    assert np.all(fr.kappa == 0.0)
    old = _frame(kappa, v, wheels_follow_path=False)
    ws, ws_old = wheel_state(fr, np.zeros((fr.n, 4)), v), wheel_state(old, np.zeros((fr.n, 4)), v)
    assert np.array_equal(ws.slip, ws_old.slip) and np.array_equal(ws.fz, ws_old.fz)


def test_reverse_turn_has_the_curvature_of_the_same_circle():
    kappa, v = _path(kappa_turn=0.15, v=-1.5)
    fr = _with_turns(_frame(kappa, v))
    np.testing.assert_allclose(fr.kappa[230:320], 0.15, rtol=1e-9)
    ws = wheel_state(fr, np.zeros((fr.n, 4)), v)
    np.testing.assert_allclose(ws.slip, 0.05, atol=1e-9)


def test_without_gnss_course_the_wheels_decide():
    kappa, v = _path(kappa_turn=0.2)
    fr = _with_turns(_frame(kappa, v, course=False))
    np.testing.assert_allclose(fr.kappa[230:320], 0.2, rtol=1e-9)
    assert np.all(fr.kappa[:150] == 0.0) and np.all(fr.kappa[420:] == 0.0)
    # Below the threshold (a slip difference of 0.03 over the track) the wheels alone are no turn.
    assert turn_threshold(fr.vehicle.track_width_m) == pytest.approx(0.03 / 1.8)


def test_standstill_and_missing_wheel_speeds_leave_the_curvature_undefined():
    kappa, v = _path(kappa_turn=0.2)
    v = v.copy()
    v[250:270] = 0.0                               # stands in the arc
    fr = _frame(kappa, v)
    fr.omega[250:270] = 0.0
    fr.omega[300:305, 2] = np.nan                  # RL sample lost
    fr = _with_turns(fr)
    assert not fr.kappa_known[250:270].any() and not fr.kappa_known[300:305].any()
    assert np.all(fr.kappa[250:270] == 0.0) and np.all(fr.kappa[300:305] == 0.0)
    assert np.all(np.isfinite(fr.kappa)) and np.all(np.isfinite(fr.lat_accel))
    np.testing.assert_allclose(fr.kappa[280:295], 0.2, rtol=1e-9)


def test_a_fitted_mass_shifts_with_the_turn():
    kappa, v = _path()
    fr = _with_turns(_frame(kappa, v))
    veh = fr.vehicle
    dm = 800.0
    ws = wheel_state(fr, np.zeros((fr.n, 4)), v, delta_m=dm)
    i = 280
    d_all = (veh.mass_kg + dm) * v[i] ** 2 * 0.2 * veh.cg_height_m / veh.track_width_m
    fr_ = 0.5 * ((veh.mass_kg + dm) * G - fr.fzf[i])
    assert ws.fz[i, 3] == pytest.approx(fr_ + 0.6 * d_all, rel=1e-9)


def test_the_wheels_drive_v_by_the_virtual_work_of_their_forces():
    """m v̇ = Σ k_i F_h,i − ...: wheel i moves k_i(κ) v, so its force does k_i F_h,i of work per unit of v."""
    kappa, v = _path()
    fr = _with_turns(_frame(kappa, v))
    veh = fr.vehicle
    ws = wheel_state(fr, np.zeros((fr.n, 4)), v)
    i = 280
    h = 0.5 * veh.track_width_m * fr.kappa[i]
    lk = veh.wheelbase_m * fr.kappa[i]
    k = (np.hypot(1 - h, lk), np.hypot(1 + h, lk), 1 - h, 1 + h)
    want = sum(k[j] * ws.fh[i, j] for j in range(4))
    assert ws.fx_sum[i] == pytest.approx(want, rel=1e-12)
    assert abs(want - np.sum(ws.fh[i])) > 0.05 * abs(np.sum(ws.fh[i]))   # the turn weighs the forces differently
    assert np.array_equal(ws.fx_sum[:150], np.nansum(ws.fh[:150], axis=1))   # straight: the plain sum
