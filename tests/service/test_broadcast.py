"""The estimate frames carry every status bit: bits 0–15 in EstimateStatus, bits 16–23 in EstimateStatusExt."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from tractionecu.bus.dbc import default_codec
from tractionecu.estimation.estimator import NOT_CONVERGED, SLIP_AVERAGED, SLIP_UNCERTAIN
from tractionecu.service.broadcast import NO_DATA_STATUS, estimate_frames, no_estimate_frames


def _soil(frames, codec):
    for can_id, data in frames:
        name, vals = codec.decode(can_id, data)
        if name == "TECU_EstSoil":
            return vals
    raise AssertionError("no TECU_EstSoil frame")


@pytest.mark.parametrize("status", [0, NOT_CONVERGED, SLIP_UNCERTAIN, SLIP_AVERAGED | NOT_CONVERGED])
def test_status_bits_above_16_reach_the_bus(status):
    codec = default_codec()
    est = SimpleNamespace(mu=[0.5] * 4, slip=[0.05] * 4, rho_s=0.06, a=0.8, status=status, soil_class_index=1)
    vals = _soil(estimate_frames(codec, est, sa=0x80, priority=6), codec)
    assert int(vals["EstimateStatus"]) == status & 0xFFFF
    assert int(vals["EstimateStatusExt"]) == status >> 16
    assert int(vals["EstimateStatus"]) | int(vals["EstimateStatusExt"]) << 16 == status


def test_no_estimate_frames_clear_the_extended_bits():
    codec = default_codec()
    vals = _soil(no_estimate_frames(codec, sa=0x80, priority=6), codec)
    assert int(vals["EstimateStatus"]) == NO_DATA_STATUS & 0xFFFF
    assert int(vals["EstimateStatusExt"]) == NO_DATA_STATUS >> 16


@pytest.mark.parametrize("soil_class, index, sent", [
    ("stubble", 0, 0),          # the configured classes' index, as the estimate carries it
    ("tilled", 1, 1),
    ("tilled", 202, 202),       # a surface class outside the configured list: its fixed code
    ("d497", 204, 204),
    ("d497", 0, 204),           # an estimate that carries its one-class list's index: never read as stubble
])
def test_soil_class_index_never_names_another_class(soil_class, index, sent):
    """SoilClassIndex: below 200 an index in the configured estimator.soil_classes; a curve shape that is no
    surface class (model.mucurve.CURVE_SHAPES, the machine-level prior d497) goes out as its code 200 + k."""
    from tractionecu.model.mucurve import CLASS_CODES

    codec = default_codec()
    est = SimpleNamespace(mu=[0.5] * 4, slip=[0.05] * 4, rho_s=0.06, a=0.8, status=0, soil_class=soil_class,
                          soil_class_index=index)
    got = int(_soil(estimate_frames(codec, est, sa=0x80, priority=6), codec)["SoilClassIndex"])
    assert got == sent
    if got >= 200:
        assert {c: n for n, c in CLASS_CODES.items()}[got] == soil_class


@pytest.mark.parametrize("index", [None, math.nan, -1, 255])
def test_soil_class_index_not_available_without_an_index(index):
    """No index, or one of no class (-1: a machine prior given as a class of its own), is "not available",
    never clipped into the range (-1 would go out as 0)."""
    codec = default_codec()
    est = SimpleNamespace(mu=[0.5] * 4, slip=[0.05] * 4, rho_s=0.06, a=0.8, status=0, soil_class="own",
                          soil_class_index=index)
    assert np.isnan(_soil(estimate_frames(codec, est, sa=0x80, priority=6), codec)["SoilClassIndex"])


def test_map_layers_of_a_curve_shape_outside_the_surface_classes():
    """service/mapwriter.layer_values: the class shape of d497 (it gave no p, α1, α2 with SOIL_CLASSES only)."""
    from tractionecu.service.mapwriter import layer_values

    est = SimpleNamespace(mu=[0.5] * 4, rho_s=0.06, a=0.8, soil_class="d497")
    assert layer_values(est) == {"mu": 0.5, "rho_s": 0.06, "a": 0.8, "p": 1.0, "alpha1": -7.5, "alpha2": -7.5}
    est.soil_class = "loam"
    assert layer_values(est) == {"mu": 0.5, "rho_s": 0.06, "a": 0.8}
