"""Each effect switch changes the signals it should and no others."""

import numpy as np
import pytest

from tractionecu.errors import ConfigError
from tractionecu.model.effects import EFFECT_NAMES, EFFECTS, parse_effect_arg
from tractionecu.sim import scenarios
from tractionecu.sim.simulator import simulate
from tractionecu.sim.terrain import Terrain

DUR = 25.0


def _run(effects):
    scn = scenarios.get("paper-three-soils", seed=2, duration_s=DUR, effects=effects)
    if "grade" in effects:
        scn.field.terrain = Terrain.henrys_field()
        scn.field.terrain_offset = (300.0, 300.0)
    return simulate(scn)


@pytest.fixture(scope="module")
def base():
    return _run({})


# signal -> which effects may change it (TruthTrace fields)
CHANGES = {
    "grade": {"omega", "v", "md", "mu", "slip", "alt", "theta"},
    "load_transfer": {"omega", "v", "md", "mu", "slip", "fz", "fzf"},
    "gps_latency": set(),  # only the GNSS channel (checked in the recording test below)
    "wheel_radius": {"omega", "v", "md", "mu", "slip"},
    "relaxation": {"omega", "v", "md", "mu", "slip"},
    "draft_speed": {"omega", "v", "md", "mu", "slip", "fdx"},
    "drivetrain": {"omega", "v", "md", "mu", "slip"},
    "mass": {"omega", "v", "md", "mu", "slip", "fz", "fzf"},
    "aero": {"omega", "v", "md", "mu", "slip"},
}
SIGNALS = ("omega", "v", "md", "fz", "fzf", "fdx", "mu", "slip", "alt", "theta")


def test_every_effect_is_covered():
    assert set(CHANGES) == set(EFFECT_NAMES) == set(EFFECTS)


@pytest.mark.parametrize("name", [n for n in EFFECT_NAMES if n != "gps_latency"])
def test_effect_changes_only_its_signals(base, name):
    tr = _run({name: EFFECTS[name].defaults()})
    n = min(len(tr.t), len(base.t))
    # The implement is lowered at a place on the path, so an effect that moves the vehicle
    # shifts when the draft ramps in; compare the draft where both runs are fully in work.
    both = tr.work[:n] & base.work[:n]
    changed = {s for s in SIGNALS if s != "fdx" and not np.array_equal(getattr(tr, s)[:n], getattr(base, s)[:n])}
    if not np.array_equal(tr.fdx[:n][both], base.fdx[:n][both]):
        changed.add("fdx")
    assert changed, f"{name} changed nothing"
    assert changed <= CHANGES[name], f"{name} changed {changed - CHANGES[name]}"
    # The effect's own signature signal must have changed.
    must = {"grade": "theta", "load_transfer": "fzf", "wheel_radius": "omega", "relaxation": "mu",
            "draft_speed": "fdx", "drivetrain": "md", "mass": "fzf", "aero": "v"}[name]
    assert must in changed


def test_gps_latency_touches_only_the_gnss_channel(tmp_path):
    from tractionecu.sim.writer import write_recording
    for tag, eff in (("a", {}), ("b", {"gps_latency": {"tau_s": 0.3}})):
        scn = scenarios.get("paper-three-soils", seed=2, duration_s=DUR, effects=eff)
        write_recording(scn, simulate(scn), tmp_path / tag)
    can_a = [ln for ln in (tmp_path / "a" / "can.log").read_text().splitlines() if "FE49" not in ln.split()[2][:6]]
    can_b = [ln for ln in (tmp_path / "b" / "can.log").read_text().splitlines() if "FE49" not in ln.split()[2][:6]]
    assert can_a == can_b  # every frame but GBSD (ground speed from the GNSS) identical
    assert (tmp_path / "a" / "gps.nmea").read_text() != (tmp_path / "b" / "gps.nmea").read_text()


def test_effect_arguments():
    assert parse_effect_arg("gps_latency=0.2") == ("gps_latency", {"tau_s": 0.2})
    assert parse_effect_arg("mass:delta_kg=800,front_share=0.5")[1] == {"delta_kg": 800.0, "front_share": 0.5}
    assert parse_effect_arg("grade")[1] == {"scale": 1.0}
    for bad in ("gravity", "mass:weight=3", "gps_latency=fast", "gps_latency=99"):
        with pytest.raises(ConfigError):
            parse_effect_arg(bad)
