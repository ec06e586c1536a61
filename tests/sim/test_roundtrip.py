"""Round trip: simulate → DBC encode → candump text → reader equals the truth within quantisation."""

import numpy as np
import pytest

from tractionecu.config import SensorSpec, load_sensors, load_vehicle
from tractionecu.model.vehicle import WHEELS
from tractionecu.recording.reader import read_recording
from tractionecu.sim import scenarios
from tractionecu.sim.field import EARTH_R
from tractionecu.sim.simulator import simulate
from tractionecu.sim.writer import write_recording

# Noise-free sensors whose own resolution equals the DBC's: what is left is DBC/NMEA quantisation.
EXACT = SensorSpec(wheel_speed_sigma_rel=0.0, wheel_speed_sigma_abs=0.0, torque_sigma_rel=0.0, torque_sigma_abs=0.0,
                   draft_sigma_n=0.0, axle_sigma_n=0.0, gps_speed_sigma=0.0, gps_pos_sigma=0.0, gps_alt_sigma=0.0,
                   can_jitter_s=0.0)


@pytest.fixture(scope="module")
def rt(tmp_path_factory):
    out = tmp_path_factory.mktemp("rec")
    scn = scenarios.get("paper-three-soils", seed=4, duration_s=30.0, sensors=EXACT)
    tr = simulate(scn)
    write_recording(scn, tr, out)
    return scn, tr, read_recording(out)


def _index(scn, tr, t):
    return np.clip(np.round((t - scn.start_epoch) / scn.control_dt).astype(int) - 1, 0, len(tr.t) - 1)


@pytest.mark.parametrize("sig,field,col,half_lsb", [
    *[(f"WheelSpeed_{w}", "omega", i, 0.0005 + 1e-9) for i, w in enumerate(WHEELS)],
    *[(f"DriveTorque_{w}", "md", i, 1.0 + 1e-9) for i, w in enumerate(WHEELS)],
    ("FrontAxleLoad", "fzf", None, 2.5 + 1e-6),
    ("DraftForce", "fdx", None, 5.0 + 1e-6),
])
def test_can_signals_equal_truth_within_dbc_quantisation(rt, sig, field, col, half_lsb):
    scn, tr, rec = rt
    s = rec.signals[sig]
    assert len(s) > 100
    k = _index(scn, tr, s.t)
    truth = getattr(tr, field)[k] if col is None else getattr(tr, field)[k, col]
    # Sensor quantisation (same step as the DBC) plus DBC rounding: at most one LSB in total.
    assert np.max(np.abs(s.value - truth)) <= 2 * half_lsb


def test_gps_equals_truth_within_nmea_resolution(rt):
    scn, tr, rec = rt
    g = rec.gps
    assert len(g) == 300
    k = _index(scn, tr, g.t)
    assert np.max(np.abs(g.speed - tr.v[k])) < 0.001          # knots with 3 decimals
    lat, lon = scn.field.to_latlon(tr.x[k], tr.y[k])
    assert np.max(np.abs(g.lat - lat)) * np.pi / 180 * EARTH_R < 0.02   # ddmm.mmmmm ≈ 1.9 cm
    assert np.all(g.fix_quality == 2)


def test_gps_aligned_to_can_time(rt):
    scn, tr, rec = rt
    # Epochs sit on whole 100 ms of UTC, on the same epoch scale as candump.
    frac = np.round((rec.gps.t - scn.start_epoch) * 10, 6)
    assert np.allclose(frac, np.round(frac))


def test_vehicle_file_carries_the_vehicle_and_the_sensor_figures(rt):
    scn, _, rec = rt
    assert load_vehicle(rec.vehicle_toml_path) == scn.vehicle
    assert load_sensors(rec.vehicle_toml_path) == EXACT
