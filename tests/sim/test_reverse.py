"""Reversing in the simulator: signed truth, sensors in reverse, stops at cusps, unchanged forward plans."""

import csv
import math

import numpy as np
import pytest

from tractionecu.cli.main import build_parser
from tractionecu.config import G, VehicleParams
from tractionecu.model.mucurve import SOIL_CLASSES
from tractionecu.model.vehicle import WHEELS, rolling_radius, slip, wheel_loads
from tractionecu.recording.reader import read_recording
from tractionecu.sim import scenarios
from tractionecu.sim.field import Field
from tractionecu.sim.plan import DS, Plan, back_and_forth
from tractionecu.sim.simulator import (V_SLIP_MIN, V_STANDSTILL, Scenario, _implicit_step, _slip_and_partials,
                                       simulate)
from tractionecu.sim.writer import FORWARD, REVERSE, write_recording

P = VehicleParams()
REV = 12.0
V_REV = 1.0


def _short_plan(reverse: float = REV) -> Plan:
    """Two 30 m passes joined by one headland turn."""
    return back_and_forth(0.0, 0.0, 30.0, 2, 6.0, v_work=2.0, v_turn=1.2, lead_in=5.0,
                          reverse_at_headland=reverse, v_reverse=V_REV)


@pytest.fixture(scope="module")
def rev(tmp_path_factory):
    out = tmp_path_factory.mktemp("rev")
    scn = Scenario("reverse-test", Field(list(scenarios.PAPER_SOILS)), _short_plan(), seed=3)
    tr = simulate(scn)
    write_recording(scn, tr, out)
    return scn, tr, read_recording(out)


def _index(scn, tr, t):
    return np.clip(np.round((t - scn.start_epoch) / scn.control_dt).astype(int) - 1, 0, len(tr.t) - 1)


def _angle_diff_deg(a, b):
    return np.abs((a - b + 180.0) % 360.0 - 180.0)


def _steady(tr, sign):
    """Samples moving steadily in the direction ``sign`` (+1 / -1) with that direction selected."""
    return (tr.direction == sign) & (sign * tr.v > 0.5)


# ---- plan ------------------------------------------------------------------------------------------


def test_headland_turn_reverses_straight_back_and_keeps_the_pass_layout():
    plan = _short_plan()
    flat = _short_plan(0.0)
    assert len(plan.cusps) == 2                      # forwards -> reverse -> forwards
    back = plan.direction < 0
    i = np.flatnonzero(back)
    assert np.all(np.diff(i) == 1)                   # one reverse leg
    assert len(i) * DS == pytest.approx(REV, abs=DS)
    assert np.all(plan.v_target[back] == V_REV) and not plan.work[back].any()
    # Straight, heading constant, positions moving against the heading.
    h = plan.heading[i[0]]
    assert np.ptp(plan.heading[back]) == 0.0
    step = np.stack([np.diff(plan.x[i]), np.diff(plan.y[i])], axis=1)
    assert np.allclose(step, -DS * np.array([math.cos(h), math.sin(h)]), atol=1e-9)
    # The passes lie where the semicircle plan puts them.
    for p in (plan, flat):
        assert p.work.any()
    assert np.allclose(plan.x[plan.work], flat.x[flat.work]) and np.allclose(plan.y[plan.work], flat.y[flat.work])
    assert np.allclose(plan.heading[plan.work], flat.heading[flat.work])


def test_the_path_is_continuous():
    plan = _short_plan()
    gaps = np.hypot(np.diff(plan.x), np.diff(plan.y))
    assert gaps.max() <= DS + 1e-9
    dh = np.abs(np.angle(np.exp(1j * np.diff(plan.heading))))
    assert dh.max() < 0.02


# ---- truth ----------------------------------------------------------------------------------------


def test_reverse_leg_in_the_truth(rev):
    scn, tr, _ = rev
    back = tr.direction < 0
    assert back.any()
    assert np.all(tr.v[_steady(tr, -1)] < 0.0)
    assert tr.v.min() == pytest.approx(-V_REV, abs=0.06)
    # 12 m travelled backwards, straight along the heading.
    assert -np.sum(tr.v[back]) * scn.control_dt == pytest.approx(REV, abs=0.05)
    i = np.flatnonzero(back)
    assert np.hypot(tr.x[i[-1]] - tr.x[i[0]], tr.y[i[-1]] - tr.y[i[0]]) == pytest.approx(REV, abs=DS)


def test_driving_in_reverse_slips_positive_and_pulls_backwards(rev):
    _, tr, _ = rev
    s = _steady(tr, -1)
    assert s.sum() > 500
    assert np.all(tr.md[s] < 0.0) and np.all(tr.omega[s] < 0.0)
    # Eq. 6: the wheels turn faster than the ground passes: positive slip, as forwards ...
    assert np.all(tr.slip[s] > 0.0)
    # ... and the traction force points backwards, against the rolling resistance.
    assert np.all(tr.mu[s] < 0.0)
    r_nom = rolling_radius(tr.fz[s], P)
    assert np.all(r_nom * np.abs(tr.omega[s]) > np.abs(tr.v[s])[:, None])


@pytest.mark.parametrize("s_star", [0.04, 0.10])
def test_reverse_steady_state_slip_equals_analytic_solution(s_star):
    """The forward steady-state test mirrored: torques and external force reversed, start backwards.

    M_i = −r_i F_z,i (μ* + ρ_t) and an external force −F_dx (resisting the backward motion) must
    settle at eq. 6 slip s* > 0 with v < 0 and traction −μ*.
    """
    c = SOIL_CLASSES["stubble"]
    a, rho_s = 0.7, 0.07
    fz = wheel_loads(P.static_front_load_n(), P)
    r = rolling_radius(fz, P)
    mu_star = float(c.mu(s_star, a))
    md = -r * fz * (mu_star + P.rho_t)
    fdx = mu_star * fz.sum() - rho_s * P.mass_kg * G
    v = -2.0
    omega = np.full(4, v / r[0])
    s_dyn = np.zeros(4)
    z = [np.full(4, x) for x in (c.p, c.alpha1, c.alpha2)]
    for _ in range(4000):  # 20 s at 5 ms
        omega, v, s_dyn, _ = _implicit_step(omega, v, s_dyn, 0.005, md, fz, r, np.full(4, a), *z,
                                            np.full(4, rho_s), P.rho_t, P.wheel_inertia_kgm2, P.mass_kg, -fdx, None)
    assert v < 0.0 and np.all(omega < 0.0)
    assert slip(omega, v, r) == pytest.approx(np.full(4, s_star), abs=1e-6)
    sigma = _slip_and_partials(omega, v, r)[0]
    assert sigma == pytest.approx(np.full(4, -s_star), abs=1e-6)


def test_forward_slip_is_eq6_exactly():
    rng = np.random.default_rng(0)
    r = rolling_radius(wheel_loads(P.static_front_load_n(), P), P)
    for _ in range(50):
        v = float(rng.uniform(0.2, 4.0))
        omega = v / r * rng.uniform(0.8, 1.3, 4)
        assert np.array_equal(_slip_and_partials(omega, v, r)[0], slip(omega, v, r))
        assert np.array_equal(_slip_and_partials(-omega, -v, r)[0], -slip(omega, v, r))


@pytest.mark.parametrize("v,omega_scale", [
    (1.5, [1.1, 0.9, 1.0, 1.2]),            # forwards, eq. 6
    (-1.5, [1.1, 0.9, 1.0, 1.2]),           # reverse, eq. 6 mirrored
    (0.03, [1.7, 0.5, -1.0, 2.6]),          # near standstill, regularised
    (0.5, [0.6, -0.3, 0.1, 1.3]),           # a wheel turning against the motion
    (-0.3, [1.4, 0.7, 0.05, -0.2]),
])
def test_signed_slip_partials_match_finite_differences(v, omega_scale):
    r = rolling_radius(wheel_loads(P.static_front_load_n(), P), P)
    omega = v / r * np.array(omega_scale) if abs(v) >= V_SLIP_MIN else np.array(omega_scale) * 0.05 / r
    s, ds_dw, ds_dv = _slip_and_partials(omega, v, r)
    assert np.all(np.abs(s) <= 1.0)
    eps = 1e-7
    for i in range(4):
        dw = np.zeros(4)
        dw[i] = eps
        fd = (_slip_and_partials(omega + dw, v, r)[0][i] - _slip_and_partials(omega - dw, v, r)[0][i]) / (2 * eps)
        assert ds_dw[i] == pytest.approx(fd, rel=1e-5, abs=1e-6)
    fd_v = (_slip_and_partials(omega, v + eps, r)[0] - _slip_and_partials(omega, v - eps, r)[0]) / (2 * eps)
    assert ds_dv == pytest.approx(fd_v, rel=1e-5, abs=1e-6)


def test_signed_slip_is_continuous_across_regimes():
    r = rolling_radius(wheel_loads(P.static_front_load_n(), P), P)
    # Through standstill and through a wheel reversing its rotation, σ has no jump.
    for v in np.linspace(-0.3, 0.3, 601):
        a = _slip_and_partials(np.full(4, 0.2 / r[0]), v, r)[0]
        b = _slip_and_partials(np.full(4, 0.2 / r[0]), v + 1e-6, r)[0]
        assert np.max(np.abs(a - b)) < 1e-3
    for w in np.linspace(-0.5, 0.5, 1001):
        a = _slip_and_partials(np.full(4, w), 0.4, r)[0]
        b = _slip_and_partials(np.full(4, w + 1e-6), 0.4, r)[0]
        assert np.max(np.abs(a - b)) < 1e-3


def test_the_machine_stops_before_it_changes_direction(rev):
    scn, tr, _ = rev
    ctl = scn.controller
    sw = np.flatnonzero(np.diff(tr.direction) != 0) + 1
    assert len(sw) == 2
    # Never moving against the selected direction, and standing still at each change.
    assert np.all(tr.direction * tr.v > -V_STANDSTILL)
    dwell = int(round(ctl.shuttle_dwell_s / scn.control_dt))
    for k in sw:
        assert np.all(np.abs(tr.v[k - dwell:k + 1]) < V_STANDSTILL)
    # No instant reversal: from 0.5 m/s one way to 0.5 m/s the other takes at least 1 m/s / accel_max.
    for k in sw:
        before = np.flatnonzero(np.abs(tr.v[:k]) > 0.5)[-1]
        after = k + np.flatnonzero(np.abs(tr.v[k:]) > 0.5)[0]
        assert tr.v[before] * tr.v[after] < 0.0
        assert (after - before) * scn.control_dt >= 1.0 / ctl.accel_max
    # The direction changes at the plan's cusps.
    plan = scn.plan
    for k, c in zip(sw, plan.cusps):
        i = int(round(c / DS))
        assert tr.x[k] == pytest.approx(plan.x[i], abs=DS) and tr.y[k] == pytest.approx(plan.y[i], abs=DS)


# ---- sensors ----------------------------------------------------------------------------------------


def test_hub_drives_report_negative_speeds_and_torques_in_reverse(rev):
    scn, tr, rec = rev
    for name in ("WheelSpeed", "DriveTorque"):
        for w in WHEELS:
            s = rec.signals[f"{name}_{w}"]
            k = _index(scn, tr, s.t)
            assert np.all(s.value[_steady(tr, -1)[k]] < 0.0), (name, w)
            assert np.all(s.value[_steady(tr, +1)[k]] > 0.0), (name, w)


def test_wbsd_and_gbsd_say_reverse_while_reversing(rev):
    scn, tr, rec = rev
    # GBSD leaves the navigation ECU 30 ms after its GNSS epoch.
    for sig, lag in (("WheelBasedMachineDirection", 0.0), ("GroundBasedMachineDirection", 0.03)):
        s = rec.signals[sig]
        k = _index(scn, tr, s.t - lag)
        want = np.where(tr.direction[k] < 0, REVERSE, FORWARD)
        assert np.array_equal(s.value.astype(int), want), sig
        assert (s.value == REVERSE).any() and (s.value == FORWARD).any()
    assert (REVERSE, FORWARD) == (0, 1)          # ISO 11783-7 SPN 1864 / 1861, dbc VAL_
    for sig in ("WheelBasedMachineSpeed", "GroundBasedMachineSpeed"):
        assert np.all(rec.signals[sig].value >= 0.0)


def test_gnss_speed_unsigned_and_course_turned_in_reverse(rev):
    scn, tr, rec = rev
    g = rec.gps
    k = _index(scn, tr, g.t)
    assert np.all(g.speed >= 0.0)
    back = _steady(tr, -1)[k]
    fwd = _steady(tr, +1)[k]
    assert back.sum() > 50
    sig = scn.sensors.gps_speed_sigma
    assert np.all(np.abs(g.speed[back] - np.abs(tr.v[k][back])) < 5 * sig + 0.001)
    body = (90.0 - np.degrees(tr.heading[k])) % 360.0
    assert np.all(_angle_diff_deg(g.course[back], body[back] + 180.0) <= 1.0)
    assert np.all(_angle_diff_deg(g.course[fwd], body[fwd]) <= 1.0)


def test_truth_csv_carries_signed_speed_and_direction(rev):
    _, tr, rec = rev
    with open(rec.truth_csv_path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    v = np.array([float(r["v"]) for r in rows])
    d = np.array([int(r["direction"]) for r in rows])
    assert np.array_equal(d, tr.direction)
    assert v.min() < -0.9 and np.allclose(v, tr.v, atol=1e-4)


# ---- forward plans and scenarios unchanged ---------------------------------------------------------


@pytest.mark.parametrize("name", [n for n in scenarios.SCENARIOS if "headland-reverse" not in n])
def test_existing_scenarios_drive_forwards_only(name):
    plan = scenarios.get(name).plan
    assert plan.direction.dtype == np.int8 and np.all(plan.direction == 1)
    assert len(plan.cusps) == 0


def test_default_back_and_forth_is_the_semicircle_plan():
    a = back_and_forth(0.0, 0.0, 240.0, 4, 6.0, v_work=2.5, v_turn=1.2)
    b = back_and_forth(0.0, 0.0, 240.0, 4, 6.0, v_work=2.5, v_turn=1.2, reverse_at_headland=0.0, v_reverse=0.7)
    for f in ("s", "x", "y", "heading", "v_target", "work", "direction"):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f


def test_forward_recordings_ignore_the_reverse_machinery(tmp_path):
    """A plan given its all-forward direction explicitly records byte for byte what the default plan does;
    the recording has no direction column and WBSD/GBSD say forward throughout."""
    a = scenarios.get("paper-three-soils", seed=5, duration_s=10.0)
    b = scenarios.get("paper-three-soils", seed=5, duration_s=10.0)
    p = b.plan
    b.plan = Plan(p.s, p.x, p.y, p.heading, p.v_target, p.work, np.ones(len(p.s), np.int8))
    ta, tb = simulate(a), simulate(b)
    assert np.all(ta.direction == 1) and np.all(ta.v > 0.0)
    write_recording(a, ta, tmp_path / "a")
    write_recording(b, tb, tmp_path / "b")
    for f in ("can.log", "gps.nmea", "truth.csv"):
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes()
    head = (tmp_path / "a" / "truth.csv").read_text().splitlines()[0].split(",")
    assert head[-1] == "work" and "direction" not in head
    rec = read_recording(tmp_path / "a")
    assert np.all(rec.signals["WheelBasedMachineDirection"].value == FORWARD)
    assert np.all(rec.signals["GroundBasedMachineDirection"].value == FORWARD)


# ---- registry ---------------------------------------------------------------------------------------


def test_headland_reverse_scenario_is_registered():
    assert "headland-reverse" in scenarios.SCENARIOS
    args = build_parser().parse_args(["simulate", "--scenario", "headland-reverse", "--out", "x"])
    assert args.scenario == "headland-reverse"
    scn = scenarios.get("headland-reverse", seed=4)
    assert scn.name == "headland-reverse" and scn.seed == 4
    three = scenarios.get("paper-three-soils")
    assert [r.name for r in scn.field.regions] == [r.name for r in three.field.regions]
    plan = scn.plan
    assert len(plan.cusps) == 2 * 3                   # three headlands, two cusps each
    back = plan.direction < 0
    assert np.sum(back) * DS == pytest.approx(3 * 12.0, abs=3 * DS)
    assert np.all(plan.v_target[back] == 1.0)
    assert np.allclose(plan.x[plan.work], three.plan.x[three.plan.work])
    assert np.allclose(plan.y[plan.work], three.plan.y[three.plan.work])
