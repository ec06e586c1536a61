"""The declarative config base, the sensor figures as configuration, and TOML round trips."""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from tractionecu.config import (
    SensorSpec,
    VehicleParams,
    from_mapping,
    given_keys,
    load_sensors,
    load_toml,
    load_vehicle,
    resolve_sensors,
    save_vehicle,
    to_toml,
)
from tractionecu.errors import ConfigError
from tractionecu.estimation.estimator import Estimator, EstimatorConfig, load_estimator_config
from tractionecu.estimation.supervisor import FuzzyConfig

FIGURES = {"wheel_speed_sigma_rel": 0.004, "gps_speed_sigma": 0.1, "torque_quant": 1.0, "gps_nsat": 12}
"""Sensor figures other than the defaults."""


def _toml_table(name: str, values: dict) -> str:
    return f"[{name}]\n" + "".join(f"{k} = {v!r}\n" for k, v in values.items())


@pytest.fixture
def vehicle_file(tmp_path: Path) -> Path:
    p = tmp_path / "vehicle.toml"
    p.write_text(_toml_table("vehicle", {"mass_kg": 7000.0}) + "\n" + _toml_table("sensors", FIGURES), encoding="utf-8")
    return p


# ----------------------------------------------------------------------------- [sensors] in the vehicle file
def test_sensors_of_the_vehicle_file_reach_the_estimator(vehicle_file: Path) -> None:
    vehicle = load_vehicle(vehicle_file)
    sensors = load_sensors(vehicle_file)
    assert vehicle == VehicleParams(mass_kg=7000.0)
    assert sensors == SensorSpec(**FIGURES)
    assert given_keys(sensors) == set(FIGURES)
    est = Estimator(vehicle, sensors=sensors)
    assert est.sensors == SensorSpec(**FIGURES)
    assert est._r_v == pytest.approx(0.1 ** 2)
    assert est._R_list([10.0])[0] == pytest.approx((0.005 + 0.004 * 10.0) ** 2 + 0.001 ** 2 / 12)


def test_sensors_beside_top_level_vehicle_keys(tmp_path: Path) -> None:
    p = tmp_path / "vehicle.toml"
    p.write_text("mass_kg = 6500\nr0_m = 0.9\n\n" + _toml_table("sensors", {"gps_rate_hz": 5.0}), encoding="utf-8")
    assert load_vehicle(p) == VehicleParams(mass_kg=6500.0, r0_m=0.9)
    assert load_sensors(p) == SensorSpec(gps_rate_hz=5.0)


def test_no_sensors_table_gives_the_documented_defaults(tmp_path: Path) -> None:
    p = tmp_path / "vehicle.toml"
    save_vehicle(VehicleParams(), p)
    assert "[sensors]" not in p.read_text(encoding="utf-8")
    assert load_sensors(p) == SensorSpec()
    assert resolve_sensors(None, {}) == SensorSpec()
    assert resolve_sensors(p, None) == SensorSpec()


def test_save_vehicle_writes_sensors_that_read_back_equal(tmp_path: Path) -> None:
    p = tmp_path / "vehicle.toml"
    save_vehicle(VehicleParams(wheelbase_m=2.7), p, SensorSpec(**FIGURES))
    assert load_vehicle(p) == VehicleParams(wheelbase_m=2.7)
    assert load_sensors(p) == SensorSpec(**FIGURES)


@pytest.mark.parametrize("table, key", [
    ({"wheel_rate_hz": 0.0}, "sensors.wheel_rate_hz"),
    ({"gps_speed_sigma": -0.1}, "sensors.gps_speed_sigma"),
    ({"torque_quant": "2 N m"}, "sensors.torque_quant"),
    ({"gps_nsat": 12.5}, "sensors.gps_nsat"),
    ({"axle_sigma_n": math.inf}, "sensors.axle_sigma_n"),
    ({"wheel_speed_sigma": 0.1}, "sensors.wheel_speed_sigma"),   # unknown key
])
def test_bad_sensor_figure_names_the_key(tmp_path: Path, table: dict, key: str) -> None:
    p = tmp_path / "vehicle.toml"
    p.write_text(_toml_table("vehicle", {"mass_kg": 7000.0}) + _toml_table("sensors", table),
                 encoding="utf-8")
    load_vehicle(p)  # the vehicle part is fine
    with pytest.raises(ConfigError) as ei:
        load_sensors(p)
    assert str(ei.value).startswith(f"{p}: {key}"), str(ei.value)     # the file, then the key
    with pytest.raises(ConfigError) as ei:
        from_mapping(SensorSpec, table, "sensors")
    assert str(ei.value).startswith(key), str(ei.value)


def test_unknown_key_is_named_with_the_known_ones() -> None:
    with pytest.raises(ConfigError, match=r"^sensors\.gps_rate: unknown key \(known: .*gps_rate_hz"):
        from_mapping(SensorSpec, {"gps_rate": 10.0}, "sensors")
    with pytest.raises(ConfigError, match=r"^vehicle\.mass: unknown key"):
        from_mapping(VehicleParams, {"mass": 1.0}, "vehicle")


@pytest.mark.parametrize("text, named", [
    ("[vehicle]\nmass_kg = 6500\n[sensorz]\ngps_rate_hz = 10\n", "sensorz"),          # a table's typo
    ("mass_kg = 99999999\n[vehicle]\nmass_kg = 6500\n", "mass_kg"),                   # a key above [vehicle]
])
def test_a_vehicle_file_with_a_vehicle_table_refuses_what_it_would_ignore(tmp_path: Path, text, named) -> None:
    """Beside [vehicle], a misspelt table or a top-level key was dropped without a word."""
    p = tmp_path / "vehicle.toml"
    p.write_text(text, encoding="utf-8")
    for load in (load_vehicle, load_sensors):
        with pytest.raises(ConfigError, match=rf"^{p}: {named}: unknown in a vehicle file with a \[vehicle\] table"):
            load(p)


def test_sensors_not_a_table(tmp_path: Path) -> None:
    p = tmp_path / "vehicle.toml"
    p.write_text("mass_kg = 6500\nsensors = 3\n", encoding="utf-8")
    assert load_vehicle(p) == VehicleParams(mass_kg=6500.0)
    with pytest.raises(ConfigError, match=r"vehicle\.toml: sensors: expected a table"):
        load_sensors(p)


# ----------------------------------------------------------------------------- precedence
def test_overrides_win_over_the_vehicle_file_which_wins_over_the_defaults(vehicle_file: Path) -> None:
    s = resolve_sensors(vehicle_file, {"gps_speed_sigma": 0.02, "wheel_rate_hz": 50})
    assert s.gps_speed_sigma == 0.02                      # service over vehicle file
    assert s.wheel_speed_sigma_rel == 0.004               # vehicle file over default
    assert s.wheel_rate_hz == 50.0 and isinstance(s.wheel_rate_hz, float)  # service over default
    assert s.draft_sigma_n == SensorSpec().draft_sigma_n  # default
    # an override equal to the default still wins over the vehicle file
    assert resolve_sensors(vehicle_file, {"gps_speed_sigma": 0.05}).gps_speed_sigma == 0.05


def test_bad_override_names_the_key(vehicle_file: Path) -> None:
    with pytest.raises(ConfigError, match=r"^sensors\.gps_rate_hz = -1\.0 is outside"):
        resolve_sensors(vehicle_file, {"gps_rate_hz": -1.0})


# ----------------------------------------------------------------------------- base
def test_validate_types_and_ranges() -> None:
    with pytest.raises(ConfigError, match=r"^vehicle\.mass_kg: expected a number, got True"):
        VehicleParams(mass_kg=True)
    with pytest.raises(ConfigError, match=r"^vehicle\.mass_kg = 1\.0 is outside \[100\.0, 100000\.0\] \(total vehicle mass"):
        VehicleParams(mass_kg=1.0)
    with pytest.raises(ConfigError, match=r"^estimator\.input_noise: expected true or false"):
        EstimatorConfig(input_noise=1)
    with pytest.raises(ConfigError, match=r"^estimator\.fuzzy\.grid_points: expected an integer"):
        EstimatorConfig.from_mapping({"fuzzy": {"grid_points": 50.5}})
    with pytest.raises(ConfigError, match=r"^estimator\.soil_classes: expected a list of strings"):
        EstimatorConfig.from_mapping({"soil_classes": ["stubble", 3]})
    with pytest.raises(ConfigError, match=r"^estimator\.fuzzy: expected a table"):
        EstimatorConfig.from_mapping({"fuzzy": 3})
    with pytest.raises(ConfigError, match=r"^vehicle\.mass_kg: \d+-bit integer is out of range"):
        from_mapping(VehicleParams, {"mass_kg": 10 ** 400}, "vehicle")
    assert EstimatorConfig.from_mapping({"soil_classes": ["stubble", "tilled"]}).soil_classes == ("stubble", "tilled")


def test_given_keys() -> None:
    assert given_keys(from_mapping(SensorSpec, {"gps_hdop": 0.9}, "sensors")) == {"gps_hdop"}
    assert given_keys(SensorSpec(gps_hdop=1.2)) == {"gps_hdop"}   # built in code: what differs from the defaults
    assert given_keys(SensorSpec()) == set()


def test_load_toml_errors_name_the_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"missing\.toml: vehicle file not found"):
        load_vehicle(tmp_path / "missing.toml")
    with pytest.raises(ConfigError, match=r"missing\.toml: configuration file not found"):
        load_estimator_config(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[sensors\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"bad\.toml: not valid TOML"):
        load_sensors(bad)
    binary = tmp_path / "binary.toml"
    binary.write_bytes(b"\xff\xfe[x]")
    with pytest.raises(ConfigError, match=r"binary\.toml: cannot read"):
        load_toml(binary, "test")
    with pytest.raises(ConfigError, match=r": cannot read"):
        load_toml(tmp_path, "test")


def test_estimator_config_file(tmp_path: Path) -> None:
    p = tmp_path / "est.toml"
    p.write_text("[estimator]\nq_mu = 2e-3\nadapt_window = 50\n[estimator.fuzzy]\nfactor_max = 6\n", encoding="utf-8")
    cfg = load_estimator_config(p)
    assert cfg == EstimatorConfig(q_mu=2e-3, adapt_window=50, fuzzy=FuzzyConfig(factor_max=6.0))
    p.write_text("q_mu = 2e-3\n", encoding="utf-8")   # keys at the top level
    assert load_estimator_config(p) == EstimatorConfig(q_mu=2e-3)


@pytest.mark.parametrize("text, error", [
    ("[estimator]\nq_mu = -1\n", "estimator.q_mu = -1.0 is outside [0.0, 10.0]"),
    ("q_muu = 1e-3\n", "estimator.q_muu: unknown key"),
    ("[estimator.fuzzy]\nfoo = 1\n", "estimator.fuzzy.foo: unknown key"),
    ('[estimator]\nsoil_classes = ["stuble"]\n', "estimator.soil_classes: unknown class 'stuble'"),
])
def test_an_estimator_config_error_names_the_file(tmp_path: Path, text: str, error: str) -> None:
    """replay --config est.toml said "estimator.q_mu = -1.0 is outside ..." and no file, unlike the vehicle
    file's and the service config's errors."""
    p = tmp_path / "est.toml"
    p.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as ei:
        load_estimator_config(p)
    assert str(ei.value).startswith(f"{p}: {error}"), str(ei.value)


# ----------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("obj, section", [
    (VehicleParams(), "vehicle"),
    (VehicleParams(mass_kg=7200.0, r0_m=0.85, cd_area_m2=0.0), "vehicle"),
    (SensorSpec(), "sensors"),
    (SensorSpec(**FIGURES, can_jitter_s=0.0), "sensors"),
    (FuzzyConfig(factor_min=0.25, grid_points=51), "estimator.fuzzy"),
])
def test_flat_to_toml_reads_back_equal(obj: object, section: str) -> None:
    text = to_toml(obj, section)
    data = tomllib.loads(text)
    for part in section.split("."):
        data = data[part]
    assert from_mapping(type(obj), data, section) == obj
    assert from_mapping(type(obj), tomllib.loads(to_toml(obj)), section) == obj   # keys at the top level


def test_estimator_config_to_toml_reads_back_equal() -> None:
    cfg = EstimatorConfig(q_mu=3e-3, soil_classes=("stubble", "road"), adapt_window=50, input_noise=False,
                          fuzzy=FuzzyConfig(accel_high_mps2=0.4, grid_points=201))
    text = cfg.to_toml()
    assert "[estimator.fuzzy]" in text
    assert EstimatorConfig.from_mapping(tomllib.loads(text)["estimator"]) == cfg


def test_service_config_to_toml_reads_back_equal() -> None:
    from tractionecu.service.config import ServiceConfig, from_dict, to_toml as service_toml, with_overrides

    cfg = with_overrides(ServiceConfig(), can={"interface": "virtual", "channel": "vcan0", "options": {"bitrate": 250000}},
                         gps={"source": "none"}, map={"origin_lat": 47.5, "origin_lon": -110.5},
                         advice={"slip_min": 0.08, "slip_max": 0.12, "ballast_kg": 250.0,
                                                 "max_mass_kg": 9000.0, "max_front_axle_kg": 4000.0,
                                                 "max_rear_axle_kg": 6000.0},
                         sensors={"gps_speed_sigma": 0.05, "torque_sigma_rel": 0.02},
                         broadcast={"name": "0xA000FF007D001092"}, service={"state_dir": "/tmp/x"})
    back = from_dict(tomllib.loads(service_toml(cfg)))
    assert back == cfg
    assert back.sensor_overrides() == {"gps_speed_sigma": 0.05, "torque_sigma_rel": 0.02}
    assert service_toml(back) == service_toml(cfg)
    defaults = from_dict(tomllib.loads(service_toml(ServiceConfig())))
    # NaN (map origin, advice slip band and ballast: not set) is never == NaN: compare the other tables and the text
    assert dataclasses.replace(defaults, map=ServiceConfig().map, advice=ServiceConfig().advice) == ServiceConfig()
    assert math.isnan(defaults.map.origin_lat) and math.isnan(defaults.map.origin_lon)
    assert math.isnan(defaults.advice.slip_min) and math.isnan(defaults.advice.slip_max)
    assert all(math.isnan(getattr(defaults.advice, k))
               for k in ("ballast_kg", "max_mass_kg", "max_front_axle_kg", "max_rear_axle_kg"))
    assert service_toml(defaults) == service_toml(ServiceConfig())
    assert defaults.sensor_overrides() == {}


def test_frozen_dataclasses() -> None:
    for obj in (VehicleParams(), SensorSpec(), EstimatorConfig()):
        assert dataclasses.is_dataclass(obj) and obj.__dataclass_params__.frozen


def test_the_estimator_does_not_import_the_simulator() -> None:
    code = ("import sys, tractionecu.estimation.estimator, tractionecu.service.config; "
            "print(sorted(m for m in sys.modules if m.startswith('tractionecu.sim')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_a_vehicle_file_error_names_the_file(tmp_path: Path) -> None:
    """Replay reads a recording's vehicle.toml without the user naming it; its error said
    "drivetrain.final_drive_ratio: needed ..." and no file."""
    p = tmp_path / "vehicle.toml"
    p.write_text('[drivetrain]\nkind = "mechanical"\n', encoding="utf-8")
    with pytest.raises(ConfigError) as ei:
        load_vehicle(p)
    assert str(ei.value).startswith(f"{p}: drivetrain.final_drive_ratio: needed"), str(ei.value)


def test_a_final_drive_below_one_is_not_called_missing(tmp_path: Path) -> None:
    """final_drive_ratio = 0.5 was told "needed for kind = 'mechanical'", as if the key were not there."""
    p = tmp_path / "vehicle.toml"
    p.write_text('[drivetrain]\nkind = "mechanical"\nfinal_drive_ratio = 0.5\n', encoding="utf-8")
    with pytest.raises(ConfigError) as ei:
        load_vehicle(p)
    assert str(ei.value) == (f"{p}: drivetrain.final_drive_ratio = 0.5 is below 1: it is the transmission "
                             "output's speed over the rear wheels' (a reduction, 1 or more; 0: not known)")
    p.write_text('[drivetrain]\nkind = "mechanical"\nfinal_drive_ratio = 0.5\ngear_ratio = "learnt"\n')
    assert load_vehicle(p).drivetrain.final_drive_ratio == 0.5          # not used with a learnt ratio


def test_numpy_scalars_are_the_numbers_they_hold() -> None:
    """VehicleParams(mass_kg=np.int64(6300)) was refused: "expected a number, got np.int64(6300)"."""
    import numpy as np

    from tractionecu.config import VehicleParams

    v = VehicleParams(mass_kg=np.int64(6300), r0_m=np.float32(0.8))
    assert v.mass_kg == 6300 and type(v.mass_kg) is int and type(v.r0_m) is float


def test_keys_beside_the_estimator_table_are_an_error(tmp_path) -> None:
    """q_mu = 5.0 above [estimator] was dropped: the default 0.001 in force, nothing said."""
    import pytest

    from tractionecu.errors import ConfigError
    from tractionecu.estimation.config import load_estimator_config

    p = tmp_path / "est.toml"
    p.write_text("q_mu = 5.0\n[estimator]\nq_rho = 1e-5\n")
    with pytest.raises(ConfigError, match=r"q_mu beside the \[estimator\] table"):
        load_estimator_config(p)
    p.write_text("[estimator]\nq_mu = 5.0\n")
    assert load_estimator_config(p).q_mu == 5.0
    p.write_text("q_mu = 5.0\n")
    assert load_estimator_config(p).q_mu == 5.0


def test_a_hub_drive_without_a_draft_sensor_is_named(tmp_path) -> None:
    """A hub drive declared without a draft sensor was accepted and the key ignored; its replay ran to exit 0
    with no estimate."""
    from tractionecu.config import load_vehicle
    from tractionecu.errors import ConfigError

    p = tmp_path / "vehicle.toml"
    p.write_text('[vehicle]\nmass_kg = 6300.0\n[vehicle.drivetrain]\nkind = "hub"\ndraft_sensing = false\n')
    with pytest.raises(ConfigError, match="drivetrain.draft_sensing = false: the hub estimator needs the measured"):
        load_vehicle(p)
    p.write_text('[vehicle]\nmass_kg = 6300.0\n[vehicle.drivetrain]\nkind = "hub"\ndraft_sensing = true\n')
    assert load_vehicle(p).drivetrain.kind == "hub"


@pytest.mark.parametrize("key", ["rolling_radius_m", "wheel_speed_radius_m"])
@pytest.mark.parametrize("r, ok", [(0.4, False), (1.52, False), (0.55, False), (0.57, True), (0.777, True),
                                   (1.03, True), (1.05, False)])
def test_a_declared_radius_far_from_r0_is_named(tmp_path, key, r, ok) -> None:
    """rolling_radius_m = 0.4 with r0 0.8 m ran with 0.56 m (the model's 30 % deflection limit), the diameter
    1.52 m scaled every wheel speed: μ 40 % and 54 % off on replay, nothing said."""
    p = tmp_path / "vehicle.toml"
    dt = "" if key == "rolling_radius_m" else 'kind = "mechanical"\nfinal_drive_ratio = 28.0\n'
    p.write_text(f"[vehicle]\nr0_m = 0.8\n[vehicle.drivetrain]\n{dt}{key} = {r}\n")
    if ok:
        assert getattr(load_vehicle(p).drivetrain, key) == r
        return
    with pytest.raises(ConfigError) as ei:
        load_vehicle(p)
    assert str(ei.value) == (f"{p}: drivetrain.{key} = {r} is outside [0.56, 1.04] m, r0_m = 0.8 ± 30% "
                             "(the radius, not the diameter, of the tyre of r0_m)")


@pytest.mark.parametrize("key, value", [("final_drive_ratio", "28.0"), ("front_lead", "0.03"),
                                        ("gear_ratio", '"learnt"')])
def test_an_engine_key_on_a_hub_drive_is_named(tmp_path, key, value) -> None:
    """A vehicle file that left out kind = "mechanical" (the default is the paper's hub drive) gave its ratios
    and lead to the hub estimator, which reads none of them, without a word."""
    from tractionecu.config import load_vehicle
    from tractionecu.errors import ConfigError

    p = tmp_path / "vehicle.toml"
    p.write_text(f"[vehicle]\nmass_kg = 6300.0\n[vehicle.drivetrain]\n{key} = {value}\n")
    with pytest.raises(ConfigError, match=f"drivetrain.{key}: a key of an engine-driven machine, given for "
                                          "kind = 'hub'"):
        load_vehicle(p)
    ratio = "" if key == "final_drive_ratio" else "final_drive_ratio = 28.0\n"
    p.write_text(f'[vehicle]\nmass_kg = 6300.0\n[vehicle.drivetrain]\nkind = "mechanical"\n{ratio}{key} = {value}\n')
    assert load_vehicle(p).drivetrain.kind == "mechanical"
