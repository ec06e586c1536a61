"""Sensor faults of the effect library: formulas, the wheel-speed hold check, the recording-level
injectors, and the engine-level terms of the reduced (1 Hz) diagnosis, on small seeded inputs."""

import math

import numpy as np
import pytest

from tractionecu.config import VehicleParams
from tractionecu.diagnose.candidates import CANDIDATES, DETECTORS
from tractionecu.diagnose.data import Frame
from tractionecu.diagnose.features import modelled_front_load, wheel_speed_faults
from tractionecu.model import effects as fx


def test_every_sensor_fault_has_a_formula_a_signature_and_a_test_path():
    for name, e in fx.SENSOR_FAULTS.items():
        assert e.formula and e.signature and e.doc
        assert name in CANDIDATES or name in DETECTORS
    for name, e in fx.ENGINE_TERMS.items():
        assert e.formula and e.signature


def test_torque_fault_is_undone_exactly():
    m = np.array([[100.0, 200.0, 300.0, 400.0]])
    k = np.array([0.05, 0.05, -0.07, -0.07])
    b = np.array([10.0, 10.0, -20.0, -20.0])
    meas = (1 + k) * m + b
    assert np.allclose(fx.torque_true(meas, k, b), m)


def test_tyre_pressure_moves_radius_and_rolling_resistance_together():
    eps, rho = fx.tyre_pressure_terms(1.0)
    assert eps == 0.0 and rho == 1.0
    eps, rho = fx.tyre_pressure_terms(0.5)     # half the rated pressure
    # The stiffness falls to c + (1 − c)/2 of the rated one (the carcass keeps its share), the deflection
    # rises by its inverse, and the rolling radius falls by a third of that rise.
    c = fx.TYRE_CARCASS_SHARE
    assert eps == pytest.approx(-fx.TYRE_DEFLECTION_RATIO / 3.0 * (1.0 / (c + (1.0 - c) * 0.5) - 1.0))
    assert -fx.TYRE_DEFLECTION_RATIO / 3.0 < eps < 0.0    # less than a third of the rated deflection
    assert rho == pytest.approx(2.0 ** fx.TYRE_RR_PRESSURE_EXPONENT)
    eps, rho = fx.tyre_pressure_terms(1.25)
    assert eps > 0 and rho < 1


def test_tyre_pressure_interval_carries_the_tyre_laws_uncertainty():
    from tractionecu.diagnose.intervals import tyre_law_extension

    for p in (0.5, 0.75, 1.3):
        assert fx.tyre_pressure_from_radius(fx.tyre_pressure_terms(p)[0]) == pytest.approx(p)
    lo, hi = fx.tyre_pressure_law_range(0.7, 0.85)
    assert lo < 0.7 and hi > 0.85
    # the ends are pressures that give the fitted radius terms under the range's corners
    eps_hi = fx.tyre_pressure_terms(0.85)[0]
    assert hi == pytest.approx(max(fx.tyre_pressure_from_radius(eps_hi, d, c)
                                   for d in fx.TYRE_DEFLECTION_RATIO_RANGE for c in fx.TYRE_CARCASS_SHARE_RANGE))
    assert tyre_law_extension("tyre_pressure", "p_ratio", (0.7, 0.85), 0.3, 2.0) == pytest.approx((lo, hi))
    assert tyre_law_extension("tyre_pressure", "p_ratio", (0.35, 0.85), 0.3, 2.0)[0] == 0.3   # clipped to the bound
    assert tyre_law_extension("wheel_radius", "epsilon", (-0.01, 0.0)) == (-0.01, 0.0)
    # a radius gain no finite pressure gives under some corner of the law: the upper end goes to the bound
    assert fx.tyre_pressure_from_radius(fx.TYRE_DEFLECTION_RATIO / 3.0) == float("inf")
    assert tyre_law_extension("tyre_pressure", "p_ratio", (1.0, 1.99), 0.3, 2.0)[1] == 2.0


def test_offset_drift_and_clock_shift():
    t = np.array([0.0, 60.0, 120.0])
    assert np.allclose(fx.offset_drift(t, 100.0, 50.0), [100.0, 150.0, 200.0])
    assert np.allclose(fx.clock_shift_s(t, 0.1, 1000.0), [0.1, 0.16, 0.22])


def _frame(n=300, rate=10.0, seed=4):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    om = 3.0 + 0.3 * np.sin(t / 5.0)[:, None] + rng.normal(0, 0.01, (n, 4))
    return Frame(t=t, t0_epoch=0.0, rate_hz=rate, vehicle=VehicleParams(), omega=om,
                 md=np.full((n, 4), 500.0), v_gps=np.full(n, 2.4))


@pytest.mark.parametrize("kind", ["hold", "dropout", "missing", "sign flip"])
def test_wheel_speed_hold_is_found_located_and_repaired(kind):
    fr = _frame()
    truth = fr.omega.copy()
    a, b = 100, 130                                   # 3 s on RL
    if kind == "hold":
        fr.omega[a:b, 2] = fr.omega[a - 1, 2]
    elif kind == "dropout":
        fr.omega[a:b, 2] = 0.0
    elif kind == "sign flip":                         # a sign lost in the sensor or its decoding: never mentioned
        fr.omega[a:b, 2] = -fr.omega[a:b, 2]
    else:
        fr.omega[a:b, 2] = np.nan
    faults, bad = wheel_speed_faults(fr)
    assert len(faults) == 1
    f = faults[0]
    assert f["wheel"] == "RL" and f["kind"] == kind
    assert f["t0_s"] == pytest.approx(fr.t[a - (1 if kind == "hold" else 0)], abs=0.11)
    assert f["duration_s"] == pytest.approx(3.0, abs=0.2)
    assert bad[a:b].all() and not bad[:a - 1].any() and not bad[b + 1:].any()
    # Repaired from the other rear wheel: within its noise of the truth.
    assert np.max(np.abs(fr.omega[a:b, 2] - truth[a:b, 2])) < 0.1


def test_a_healthy_frame_has_no_wheel_speed_fault():
    faults, bad = wheel_speed_faults(_frame(seed=5))
    assert faults == [] and not bad.any()
    rev = _frame(seed=6)
    rev.omega *= -1.0                                 # reversing: all four wheels turn backwards together
    faults, bad = wheel_speed_faults(rev)
    assert faults == [] and not bad.any()


def test_front_load_is_modelled_from_the_vehicle_file_without_a_pin():
    fr = _frame()
    fr.fdx = np.full(fr.n, 20000.0)
    veh = fr.vehicle
    fz = modelled_front_load(fr)
    # Constant speed: only the pull transfers load, F_dx h_hitch / L.
    expect = veh.static_front_load_n() - 20000.0 * veh.hitch_height_m / veh.wheelbase_m
    assert np.allclose(fz[20:-20], expect, rtol=1e-6)


def test_reduced_diagnosis_names_a_zero_slip_offset_and_brings_a_into_range():
    """A 1 Hz engine-level export whose traction ratio carries 0.3 that never reaches the soil (rolling
    resistance, transmission losses, PTO and hydraulics): without the offset term `a` lands near
    the unphysical values of real exports; with it, in range, and the term is named."""
    from tractionecu.diagnose.reduced import diagnose_reduced
    from tractionecu.model.mucurve import SOIL_CLASSES

    rng = np.random.default_rng(7)
    n = 900
    t = np.arange(n, dtype=float)
    veh = VehicleParams()
    mg = veh.mass_kg * 9.81
    a_true, mu0 = 0.7, 0.3
    mu_soil = np.clip(0.35 + 0.2 * np.sin(t / 37.0) + 0.1 * np.sin(t / 11.0), 0.02, 0.62)
    s = np.interp(mu_soil / a_true, SOIL_CLASSES["stubble"].g(np.linspace(0, 0.6, 601)), np.linspace(0, 0.6, 601))
    vw = 2.0 + 0.8 * np.sin(t / 53.0) ** 2
    vg = vw * (1 - s) + rng.normal(0, 0.02, n)
    power = (mu_soil + mu0) * mg * vw
    omega_e = 2 * math.pi * 1800 / 60 * np.ones(n)
    fr = Frame(t=t, t0_epoch=0.0, rate_hz=1.0, vehicle=veh, v_gps=vg, v_wheel_bus=vw,
               engine_torque=power / omega_e, engine_speed=omega_e)
    rep = diagnose_reduced(fr)
    sm = rep["slip_model"]
    assert sm["detected"]
    assert "zero_slip_offset" in sm["terms"]
    lo, hi = sm["terms"]["zero_slip_offset"]["ci95"]
    assert lo < mu0 < hi
    assert 0.3 <= sm["a"]["value"] <= 1.1 and sm["a"]["ci95"][0] < a_true < sm["a"]["ci95"][1]
    assert any(e["name"] == "zero_slip_offset" and e["named"] for e in rep["effects"])
    assert "zero-slip" in rep["statement"].lower() or "zero_slip_offset" in rep["statement"]
    assert rep["steps"] == [] and rep["open_world"] is None       # the full analysis' keys, empty


def test_the_reports_tyre_note_gives_the_radius_the_data_measure_and_the_laws_ranges():
    from tractionecu.diagnose.engine import tyre_law_note

    note = tyre_law_note(0.75)
    assert f"ε = {fx.tyre_pressure_terms(0.75)[0]:+.4f}" in note
    assert "0.04–0.06" in note and "0.10–0.35" in note

