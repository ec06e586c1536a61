"""Vehicle model against hand calculation (paper eqs. 2, 6, 8, 9)."""

import math

import numpy as np
import pytest

from tractionecu.config import G, VehicleParams, load_vehicle, save_vehicle
from tractionecu.errors import ConfigError
from tractionecu.model.vehicle import (FilterModel, rolling_radius, slip, traction_efficiency, tyre_deflection,
                                       wheel_loads)

P = VehicleParams()


def test_guskov_deflection_by_hand():
    # Δr = F_z / (2π p_t sqrt(b r0 / 2)) = 15000 / (2π·1.6e5·sqrt(0.27·0.8)) = 0.032104 m
    k = 2 * math.pi * 1.6e5 * math.sqrt(0.54 / 2 * 0.80)
    assert tyre_deflection(15000.0, P) == pytest.approx(15000.0 / k, rel=1e-12)
    assert 15000.0 / k == pytest.approx(0.032104, abs=1e-6)
    assert rolling_radius(15000.0, P) == pytest.approx(0.80 - 0.032104, abs=1e-6)


def test_wheel_loads_split_front_measured_rear_by_difference():
    fz = wheel_loads(24000.0, P)
    assert fz.tolist() == pytest.approx([12000, 12000, (P.mass_kg * G - 24000) / 2, (P.mass_kg * G - 24000) / 2])
    assert fz.sum() == pytest.approx(P.mass_kg * G)


@pytest.mark.parametrize("omega,v,r,expected", [
    (3.0, 2.16, 0.8, 0.1),              # driving branch: 1 - 2.16/2.4
    (3.0, 2.64, 0.8, -1 + 2.4 / 2.64),  # braking branch
    (0.0, 2.0, 0.8, -1.0),              # locked wheel
    (3.0, 0.0, 0.8, 1.0),               # spinning on the spot
    (0.0, 0.0, 0.8, 0.0),               # standstill
    (-3.0, -2.16, 0.8, 0.1),            # reverse driving: magnitudes
])
def test_two_branch_slip(omega, v, r, expected):
    assert float(slip(omega, v, r)) == pytest.approx(expected, abs=1e-12)


def test_slip_is_vectorised_over_sigma_points():
    om = np.full((21, 4), 3.0)
    s = slip(om, np.full((21, 1), 2.16), np.full(4, 0.8))
    assert s.shape == (21, 4) and np.allclose(s, 0.1)


def test_traction_efficiency():
    # κ = 0.3, ρ = 0.1, s = 0.1: η = 0.3/0.4·0.9 = 0.675
    assert float(traction_efficiency(0.3, 0.1, 0.1)) == pytest.approx(0.675)


def test_filter_rk4_matches_closed_form_when_mu_constant():
    """With μ, ρ_s and inputs held, ω̇ and v̇ are constant, so RK4 must equal Euler exactly."""
    m = FilterModel(P)
    fzf = P.static_front_load_n()
    u = np.array([3000.0, 3000.0, 4000.0, 4000.0, fzf, 15000.0])
    x = np.array([3.0, 3.0, 3.0, 3.0, 2.3, 0.3, 0.31, 0.32, 0.33, 0.06])
    fz = wheel_loads(fzf, P)
    r = rolling_radius(fz, P)
    dt = 0.01
    om_dot = (u[:4] - r * x[5:9] * fz - r * P.rho_t * fz) / P.wheel_inertia_kgm2
    v_dot = ((x[5:9] * fz).sum() - u[5] - x[9] * P.mass_kg * G) / P.mass_kg
    nx = m.step(x[None, :], u, dt)[0]
    assert nx[:4] == pytest.approx(x[:4] + dt * om_dot, rel=1e-12)
    assert nx[4] == pytest.approx(x[4] + dt * v_dot, rel=1e-12)
    assert nx[5:] == pytest.approx(x[5:])


def test_filter_step_many_states_equals_one_by_one():
    m = FilterModel(P)
    rng = np.random.default_rng(3)
    X = rng.normal([3, 3, 3, 3, 2.3, .3, .3, .3, .3, .06], 0.05, size=(21, 10))
    u = np.array([3000.0, 3000.0, 4000.0, 4000.0, 24000.0, 15000.0])
    batch = m.step(X, u, 0.01)
    single = np.array([m.step(X[i], u, 0.01) for i in range(21)])
    assert np.array_equal(batch, single)


def test_vehicle_toml_round_trip(tmp_path):
    p = VehicleParams(mass_kg=7000.0, r0_m=0.85)
    save_vehicle(p, tmp_path / "vehicle.toml")
    assert load_vehicle(tmp_path / "vehicle.toml") == p


@pytest.mark.parametrize("text,key", [
    ("[vehicle]\nmass_kg = -5\n", "vehicle.mass_kg"),
    ("[vehicle]\nmass_kg = 'heavy'\n", "vehicle.mass_kg"),
    ("[vehicle]\nmas_kg = 6300\n", "vehicle.mas_kg"),
    ("[vehicle]\nr0_m = nan\n", "vehicle.r0_m"),
])
def test_bad_vehicle_config_names_the_key(tmp_path, text, key):
    f = tmp_path / "vehicle.toml"
    f.write_text(text)
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        load_vehicle(f)


def test_missing_vehicle_file_is_a_clear_error(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_vehicle(tmp_path / "nope.toml")


# ---- lateral load transfer in turns (model doc "Lateral load transfer") --------------------------------
def test_lateral_load_transfer_balances_the_roll_moment_by_hand():
    """κ > 0 (left turn): the right wheels gain what the left lose; (δ_f + δ_r) b = m v²κ h_cg, the front's share
    λ_f; each axle keeps its load; each wheel's radius follows its own load (eq. 9)."""
    veh = VehicleParams(front_roll_share=0.3)
    model = FilterModel(veh)
    v, kap = 2.5, 1 / 8.0
    u = np.array([0.0, 0.0, 0.0, 0.0, 24000.0, 0.0, kap])
    fz, rd = model.loads(u, v)
    ff, fr = 12000.0, (veh.weight_n - 24000.0) / 2
    moment = veh.mass_kg * v * v * kap * veh.cg_height_m          # m a_y h_cg [N·m]
    df, dr = 0.3 * moment / veh.track_width_m, 0.7 * moment / veh.track_width_m
    assert fz.tolist() == pytest.approx([ff - df, ff + df, fr - dr, fr + dr], rel=1e-12)
    assert ((fz[1] - fz[0]) / 2 + (fz[3] - fz[2]) / 2) * veh.track_width_m == pytest.approx(moment, rel=1e-12)
    assert fz[0] + fz[1] == pytest.approx(24000.0, rel=1e-12) and fz[2] + fz[3] == pytest.approx(2 * fr, rel=1e-12)
    np.testing.assert_allclose(rd, rolling_radius(fz, veh), rtol=0, atol=0)
    assert rd[1] < rd[0] and rd[3] < rd[2]                            # the loaded outer wheels roll smaller
    # the same turn to the right, or in reverse (v < 0, same κ: the same circle), mirrors / repeats it
    np.testing.assert_allclose(model.loads(np.append(u[:6], -kap), v)[0], fz[[1, 0, 3, 2]], rtol=1e-12)
    np.testing.assert_allclose(model.loads(u, -v)[0], fz, rtol=0, atol=0)
    # straight, or without a speed: the axle split
    assert model.loads(np.append(u[:6], 0.0), v)[0].tolist() == [ff, ff, fr, fr]
    assert model.loads(u)[0].tolist() == [ff, ff, fr, fr]


def test_lateral_load_transfer_keeps_a_tenth_on_the_inner_wheel():
    model = FilterModel(VehicleParams(front_roll_share=1.0))
    fz, _ = model.loads(np.array([0.0, 0.0, 0.0, 0.0, 24000.0, 0.0, 0.25]), 6.0)   # 9 m/s² sideways
    assert fz[0] == pytest.approx(0.1 * 12000.0) and fz[1] == pytest.approx(1.9 * 12000.0)


def test_the_turns_loads_move_the_wheel_dynamics_as_eq_2_says():
    """ω̇_i of the model in a turn is eq. 2 with each wheel's own load and radius; the compiled step equals
    rk4 of that right-hand side bit for bit; v̇ (eq. 8) sums the four forces."""
    veh = VehicleParams()
    model = FilterModel(veh)
    x = np.array([[3.1, 3.3, 3.0, 3.2, 2.4, 0.30, 0.32, 0.35, 0.37, 0.06]])
    u = np.array([2500.0, 2600.0, 3300.0, 3400.0, 24000.0, 9000.0, 1 / 12.0])
    fz, rd = model.loads(u, x[:, 4])
    d = model.rhs(x, u)
    mu = x[0, 5:9]
    np.testing.assert_allclose(d[0, :4], (u[:4] - rd[0] * mu * fz[0] - rd[0] * veh.rho_t * fz[0]) / veh.wheel_inertia_kgm2,
                               rtol=1e-12)
    c = model.front_cosines(u[6])
    fx = mu[0] * fz[0, 0] * c[0] + mu[1] * fz[0, 1] * c[1] + mu[2] * fz[0, 2] + mu[3] * fz[0, 3]
    assert d[0, 4] == pytest.approx((fx - u[5] - x[0, 9] * veh.mass_kg * G) / veh.mass_kg, rel=1e-12)
    from tractionecu.model.vehicle import rk4
    np.testing.assert_array_equal(model.step(x, u, 0.01), rk4(lambda y: model.rhs(y, u, fz, rd), x, 0.01))


def test_front_roll_share_is_a_checked_vehicle_key(tmp_path):
    p = tmp_path / "vehicle.toml"
    save_vehicle(VehicleParams(front_roll_share=0.4), p)
    assert load_vehicle(p).front_roll_share == 0.4
    p.write_text(p.read_text().replace("front_roll_share = 0.4", "front_roll_share = 1.5"))
    with pytest.raises(ConfigError, match="front_roll_share"):
        load_vehicle(p)
