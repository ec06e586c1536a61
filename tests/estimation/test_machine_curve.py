"""The machine-level μ(s) prior (estimation/machine_curve.py): its class by name and its class index on the bus.

The estimator's curve identification holds one class, the prior; its own index (0) is no index a receiver can
read (the bus's SoilClassIndex maps indices through the configured ``soil_classes``).  The estimates carry the
prior's index there, or its fixed code when it is none of them (model.mucurve.class_index)."""

from __future__ import annotations

import pytest
from test_machine import mech_vehicle, plant, run   # the synthetic mechanical plant of test_machine.py

from tractionecu.estimation.config import EstimatorConfig
from tractionecu.estimation.machine import MachineEstimator
from tractionecu.estimation.machine_curve import D497, MACHINE_PRIORS, machine_curve_estimator, resolve_prior
from tractionecu.model.mucurve import CLASS_CODES, CURVE_SHAPES, SOIL_CLASSES, curve_class


def test_the_prior_names_stay_importable_and_are_the_registry_s():
    assert D497 is CURVE_SHAPES["d497"] is curve_class("d497") is resolve_prior("d497")
    assert MACHINE_PRIORS["d497"] is D497 and "d497" not in SOIL_CLASSES


@pytest.mark.parametrize("prior, classes, index", [
    ("d497", ("stubble",), CLASS_CODES["d497"]),
    ("d497", ("tilled", "stubble"), CLASS_CODES["d497"]),
    ("tilled", ("stubble", "tilled"), 1),
    ("tilled", ("stubble",), CLASS_CODES["tilled"]),
    ("stubble", ("stubble",), 0),
])
def test_the_curve_states_carry_the_prior_s_bus_index(prior, classes, index):
    cfg = EstimatorConfig(soil_classes=classes)
    ce = machine_curve_estimator(cfg, resolve_prior(prior))
    assert [c.name for c in ce.classes] == [prior]
    assert ce.state().class_index == index
    st = ce.update(0.0, [0.4, 0.4], [0.08, 0.08], [0.01, 0.01])
    assert st.class_index == index and st.class_name == prior
    assert machine_curve_estimator(cfg, None).state().class_index == 0      # no prior: the configured list's


def test_machine_estimates_with_the_d497_prior_carry_its_code_not_stubble_s_index():
    """Before, SoilClassIndex was 0 here, which a receiver reads as soil_classes[0] = "stubble"."""
    _, bus = plant(25.0, a=0.8, curve=D497, seed=5)
    out = run(MachineEstimator(mech_vehicle(), EstimatorConfig(machine_curve_prior="d497")), bus)
    late = [e for e in out if e.t > 15.0 and e.valid]
    assert late and all(e.soil_class == "d497" and e.soil_class_index == CLASS_CODES["d497"] for e in late)
    tilled = run(MachineEstimator(mech_vehicle(), EstimatorConfig(soil_classes=("stubble", "tilled"),
                                                                  machine_curve_prior="tilled")), bus[:5000])
    assert {(e.soil_class, e.soil_class_index) for e in tilled} == {("tilled", 1)}
    dflt = run(MachineEstimator(mech_vehicle()), bus[:5000])
    assert {(e.soil_class, e.soil_class_index) for e in dflt} == {("stubble", 0)}


def test_a_prior_of_its_own_has_no_bus_index():
    """A SoilClass given directly that is in neither registry: index -1 (the bus sends "not available")."""
    from tractionecu.model.mucurve import SoilClass

    own = SoilClass("own", p=1.0, alpha1=-6.0, alpha2=-6.0, a_typical=0.7, rho_s_typical=0.06)
    ce = machine_curve_estimator(EstimatorConfig(), own)
    assert ce.state().class_index == -1 and ce.state().class_name == "own"
