"""Service configuration: defaults, the shipped example, errors that name the key."""

from __future__ import annotations

import math
import tomllib
from dataclasses import fields
from pathlib import Path

import pytest

from tractionecu.errors import ConfigError
from tractionecu.service.config import (
    ServiceConfig,
    default_name,
    from_dict,
    load_config,
    to_toml,
    with_overrides,
)

REPO = Path(__file__).resolve().parents[2]


def test_defaults() -> None:
    cfg = ServiceConfig()
    assert (cfg.can.interface, cfg.can.channel) == ("socketcan", "can0")
    assert cfg.can.kernel_timestamps
    assert cfg.estimation.rate_hz == 100.0 and cfg.broadcast.rate_hz == 10.0
    name = cfg.broadcast.name_value()
    assert name == default_name()
    assert name.industry_group == 2 and name.arbitrary_address_capable


def test_example_config_is_the_defaults() -> None:
    cfg = load_config(REPO / "systemd" / "tractionecu.toml")
    assert to_toml(cfg) == to_toml(ServiceConfig())


def test_resolved_toml_round_trips() -> None:
    cfg = with_overrides(ServiceConfig(), can={"interface": "virtual", "channel": "x", "options": {"bitrate": 250000}},
                         map={"origin_lat": 47.5, "origin_lon": -110.5})
    again = from_dict(tomllib.loads(to_toml(cfg)))
    assert to_toml(again) == to_toml(cfg)
    assert again.can.options == {"bitrate": 250000}


def test_state_dir_resolution(tmp_path: Path) -> None:
    cfg = ServiceConfig()
    assert cfg.state_dir({}) == Path("tractionecu-state")
    assert cfg.state_dir({"STATE_DIRECTORY": "/var/lib/tractionecu:/var/lib/other"}) == Path("/var/lib/tractionecu")
    assert cfg.map_dir({"STATE_DIRECTORY": "/var/lib/tractionecu"}) == Path("/var/lib/tractionecu/map")
    cfg2 = with_overrides(cfg, service={"state_dir": str(tmp_path)})
    assert cfg2.state_dir({"STATE_DIRECTORY": "/elsewhere"}) == tmp_path


@pytest.mark.parametrize(
    "data, key",
    [
        ({"can": {"interface": "nosuchbus"}}, "can.interface"),
        ({"can": {"bogus": 1}}, "can.bogus"),
        ({"can": {"rx_queue_frames": 1}}, "can.rx_queue_frames"),
        ({"can": {"rx_queue_frames": 100.5}}, "can.rx_queue_frames"),
        ({"can": {"timestamps": "gps"}}, "can.timestamps"),
        ({"can": {"reopen_min_s": 5.0, "reopen_max_s": 1.0}}, "can.reopen_max_s"),
        ({"can": {"options": {"channel": "can1"}}}, "can.options.channel"),
        ({"gps": {"baudrate": "fast"}}, "gps.baudrate"),
        ({"gps": {"source": "usb"}}, "gps.source"),
        ({"gps": {"max_hdop": 0.0}}, "gps.max_hdop"),
        ({"estimation": {"rate_hz": 0}}, "estimation.rate_hz"),
        ({"estimation": {"lag_s": float("inf")}}, "estimation.lag_s"),
        ({"broadcast": {"rate_hz": 30.0}}, "broadcast.rate_hz"),
        ({"broadcast": {"name": "zz"}}, "broadcast.name"),
        ({"broadcast": {"name": "0x1000000000000000"}}, "broadcast.name"),  # industry group 1
        ({"broadcast": {"preferred_address": 254}}, "broadcast.preferred_address"),
        ({"broadcast": {"enabled": 1}}, "broadcast.enabled"),
        ({"map": {"origin_lat": 47.0}}, "map.origin_lat"),
        ({"map": {"origin_lat": 95.0, "origin_lon": 1.0}}, "map.origin_lat"),
        ({"map": {"rate_hz": 3.0}}, "map.rate_hz"),
        ({"service": {"status_interval_s": -1.0}}, "service.status_interval_s"),
        ({"nonsense": {}}, "nonsense"),
        ({"can": "socketcan"}, "can"),
    ],
)
def test_errors_name_the_key(data: dict, key: str) -> None:
    with pytest.raises(ConfigError) as ei:
        from_dict(data)
    assert str(ei.value).startswith(key), str(ei.value)


def test_name_accepts_integer_and_hex() -> None:
    hexname = "0xA000FF007D001092"
    a = from_dict({"broadcast": {"name": hexname}}).broadcast.name_value()
    b = from_dict({"broadcast": {"name": 0x2000FF007D001092}}).broadcast.name_value()
    assert a.identity_number == b.identity_number == 4242
    assert a.arbitrary_address_capable and not b.arbitrary_address_capable


def test_file_errors_name_the_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[can\n")
    with pytest.raises(ConfigError, match="bad.toml: not valid TOML"):
        load_config(bad)
    wrong = tmp_path / "wrong.toml"
    wrong.write_text('[gps]\nport = 5\n')
    with pytest.raises(ConfigError, match=r"wrong.toml: gps.port"):
        load_config(wrong)


def test_the_estimation_timeouts_reach_the_estimator() -> None:
    """[estimation] wheel_speed_timeout_s and its four siblings were read and written to the resolved
    configuration, but the estimator kept its 0.05/0.5/0.05/0.1/0.1 s."""
    from tractionecu.service.config import from_dict
    from tractionecu.service.loop import default_estimator_factory, estimator_machine, service_estimator_config

    cfg = from_dict({"estimation": {"wheel_speed_timeout_s": 0.5, "ground_speed_timeout_s": 5.0,
                                    "torque_timeout_s": 0.5, "axle_load_timeout_s": 1.0, "draft_timeout_s": 1.0}})
    est = default_estimator_factory(*estimator_machine(cfg), cfg=service_estimator_config(cfg))
    assert est._rates.timeout_s == {"Md": 0.5, "Fzf": 1.0, "Fdx": 1.0, "omega": 0.5, "v": 5.0}


def test_a_one_sided_slip_band_must_still_run_upwards_and_a_kpa_pressure_is_named() -> None:
    """slip_max = 0.05 alone made an MFWD's band 8 %–5 % ("slip 6.5 % above the 8 %–5 % band": add ballast);
    tyre_pressure_min_pa = 80 (meant as kPa) advised "the tyre's minimum for the present load 0.00 bar"."""
    from tractionecu.service.config import from_dict

    with pytest.raises(ConfigError, match=r"advice.slip_max = 0.05: the band with the mfwd axle type's other end "
                                          r"is 0.08–0.05"):
        from_dict({"advice": {"axle_type": "mfwd", "slip_max": 0.05}})
    assert from_dict({"advice": {"axle_type": "mfwd", "slip_max": 0.15}}).advice.slip_max == 0.15
    with pytest.raises(ConfigError, match=r"advice.tyre_pressure_min_pa = 80: .* the key is in Pa \(80 kPa = 80000"):
        from_dict({"advice": {"tyre_pressure_min_pa": 80}})
    assert from_dict({"advice": {"tyre_pressure_min_pa": 80000}}).advice.tyre_pressure_min_pa == 80000
    adv = from_dict({"advice": {"max_mass_kg": 11500.0, "ballast_kg": 400.0, "axle_type": "4wd",
                                "max_front_axle_kg": 5000.0, "max_rear_axle_kg": 7500.0}}).advice
    assert adv.max_mass_kg == 11500.0
    # the service's advice gets every key of [advice] the advice's settings have (one had been left out)
    st = adv.settings()
    assert (st.max_mass_kg, st.ballast_kg, st.axle_type) == (11500.0, 400.0, "4wd")
    assert (st.max_front_axle_kg, st.max_rear_axle_kg) == (5000.0, 7500.0)
    shared = {f.name for f in fields(type(st))} & {f.name for f in fields(adv)}
    assert shared >= {"axle_type", "slip_min", "slip_max", "distance_m", "eta_loss", "eta_minutes",
                      "tyre_pressure_min_pa", "ballast_kg", "max_mass_kg", "max_front_axle_kg", "max_rear_axle_kg"}
    assert math.isnan(from_dict({}).advice.max_mass_kg)
    with pytest.raises(ConfigError, match="advice.max_mass_kg"):
        from_dict({"advice": {"max_mass_kg": -1.0}})
