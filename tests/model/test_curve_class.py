"""One lookup of a μ(s) class by name for every consumer: surface classes and curve shapes that are none."""

import re

import numpy as np
import pytest

from tractionecu.bus.dbc import default_dbc_path
from tractionecu.model.mucurve import CLASS_CODES, CURVE_SHAPES, SOIL_CLASSES, class_index, curve_class


def test_curve_class_knows_both_registries_and_nothing_else():
    for name, cls in SOIL_CLASSES.items():
        assert curve_class(name) is cls
    d497 = curve_class("d497")
    assert d497 is CURVE_SHAPES["d497"]
    assert (d497.p, d497.alpha1, d497.alpha2) == (1.0, -7.5, -7.5)
    s = np.linspace(0.0, 0.4, 9)
    assert np.allclose(d497.g(s), -np.expm1(-7.5 * s))          # the D497.7 slip term 1 - exp(-7.5 s)
    assert curve_class("") is None and curve_class("clay") is None and curve_class("D497") is None


def test_the_surface_registry_stays_surface_classes_only():
    """The simulator writes its truth against SOIL_CLASSES and soil_classes chooses from it: d497 is not there."""
    assert "d497" not in SOIL_CLASSES
    assert not set(SOIL_CLASSES) & set(CURVE_SHAPES)


def test_every_named_class_has_its_own_bus_code():
    names = [*SOIL_CLASSES, *CURVE_SHAPES]
    assert sorted(CLASS_CODES) == sorted(names)
    codes = list(CLASS_CODES.values())
    assert len(set(codes)) == len(codes) and all(200 <= c <= 254 for c in codes)


@pytest.mark.parametrize("name, configured, expected", [
    ("stubble", ("stubble",), 0),
    ("tilled", ("stubble", "tilled"), 1),
    ("tilled", ("stubble",), 202),        # a surface class outside the configured list: its code
    ("d497", ("stubble",), 204),          # never a configured class
    ("d497", ("stubble", "grassland", "tilled", "road"), 204),
    ("clay", ("stubble",), None),
])
def test_class_index_is_the_configured_index_else_the_fixed_code(name, configured, expected):
    assert class_index(name, configured) == expected


def test_the_dbc_comment_lists_every_code():
    text = default_dbc_path().read_text(encoding="utf-8")
    line = next(ln for ln in text.splitlines() if ln.startswith("CM_ SG_") and " SoilClassIndex " in ln)
    for name, code in CLASS_CODES.items():
        assert re.search(rf"\b{code} {name}\b", line), (name, code, line)
    assert "255 not available" in line
