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
