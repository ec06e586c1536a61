"""The service's ``[sensors]`` table: errors name the key, keys set here override the vehicle file's."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from tractionecu.config import SensorSpec, VehicleParams, save_vehicle
from tractionecu.errors import ConfigError
from tractionecu.service.config import ServiceConfig, from_dict, load_config, to_toml, with_overrides

REPO = Path(__file__).resolve().parents[2]
VEHICLE_FIGURES = SensorSpec(gps_speed_sigma=0.1, wheel_speed_sigma_rel=0.004, loadpin_rate_hz=20.0)


@pytest.fixture
def vehicle_file(tmp_path: Path) -> Path:
    p = tmp_path / "vehicle.toml"
    save_vehicle(VehicleParams(mass_kg=7000.0), p, VEHICLE_FIGURES)
    return p


@pytest.mark.parametrize("sensors, key", [
    ({"wheel_rate_hz": -5.0}, "sensors.wheel_rate_hz"),
    ({"gps_fix_quality": 2.0}, "sensors.gps_fix_quality"),
    ({"gps_speed_sigma": "low"}, "sensors.gps_speed_sigma"),
    ({"gps_speed_sigm": 0.1}, "sensors.gps_speed_sigm"),
])
def test_bad_sensors_key_is_named(sensors: dict, key: str) -> None:
    with pytest.raises(ConfigError) as ei:
        from_dict({"sensors": sensors})
    assert str(ei.value).startswith(key), str(ei.value)


def test_bad_sensors_key_in_a_file_names_file_and_key(tmp_path: Path) -> None:
    p = tmp_path / "service.toml"
    p.write_text("[sensors]\ntorque_quant = 0.0\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"service\.toml: sensors\.torque_quant = 0\.0 is outside"):
        load_config(p)


def test_service_keys_override_the_vehicle_file(tmp_path: Path, vehicle_file: Path) -> None:
    p = tmp_path / "service.toml"
    p.write_text(f'[estimation]\nvehicle = "{vehicle_file}"\n\n[sensors]\ngps_speed_sigma = 0.02\ngps_rate_hz = 5\n',
                 encoding="utf-8")
    cfg = load_config(p)
    assert cfg.sensor_overrides() == {"gps_rate_hz": 5.0, "gps_speed_sigma": 0.02}
    s = cfg.resolved_sensors()
    assert s.gps_speed_sigma == 0.02                 # service over vehicle file
    assert s.gps_rate_hz == 5.0                      # service over default
    assert s.wheel_speed_sigma_rel == 0.004 and s.loadpin_rate_hz == 20.0   # vehicle file over default
    assert s.torque_sigma_abs == SensorSpec().torque_sigma_abs            # default
    # the explicit keys survive with_overrides and a TOML round trip of the resolved config
    again = with_overrides(cfg, can={"channel": "vcan1"})
    assert again.sensor_overrides() == cfg.sensor_overrides() and again.resolved_sensors() == s
    back = from_dict(tomllib.loads(to_toml(cfg)))
    assert back.sensor_overrides() == cfg.sensor_overrides() and back.resolved_sensors() == s


def test_an_override_equal_to_the_default_still_wins(vehicle_file: Path) -> None:
    cfg = from_dict({"estimation": {"vehicle": str(vehicle_file)}, "sensors": {"gps_speed_sigma": 0.05}})
    assert cfg.resolved_sensors().gps_speed_sigma == 0.05


def test_without_a_vehicle_file_the_service_keys_and_defaults(tmp_path: Path) -> None:
    assert ServiceConfig().resolved_sensors() == SensorSpec()
    cfg = from_dict({"sensors": {"axle_sigma_n": 150}})
    assert cfg.resolved_sensors() == SensorSpec(axle_sigma_n=150.0)


def test_example_config_sets_no_sensor_figure() -> None:
    cfg = load_config(REPO / "systemd" / "tractionecu.toml")
    assert cfg.sensor_overrides() == {}
    text = (REPO / "systemd" / "tractionecu.toml").read_text(encoding="utf-8")
    for name in SensorSpec.__dataclass_fields__:
        assert f"# {name} = {getattr(SensorSpec(), name)!r}" in text, name


def test_the_resolved_sensors_reach_the_estimator(vehicle_file: Path) -> None:
    from tractionecu.estimation.estimator import Estimator

    cfg = from_dict({"estimation": {"vehicle": str(vehicle_file)}, "sensors": {"gps_speed_sigma": 0.02}})
    est = Estimator(VehicleParams(mass_kg=7000.0), sensors=cfg.resolved_sensors())
    assert est.sensors == SensorSpec(gps_speed_sigma=0.02, wheel_speed_sigma_rel=0.004, loadpin_rate_hz=20.0)
    assert est._r_v == pytest.approx(0.02 ** 2)
