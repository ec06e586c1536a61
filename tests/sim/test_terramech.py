"""The Bekker / Janosi–Hanamoto tyre–soil model of the physical truth against hand calculations."""

import hashlib
import math
import tomllib

import numpy as np
import pytest

from tractionecu.config import G
from tractionecu.model.mucurve import CURVE_SHAPES
from tractionecu.sim import _physical_kernel as K
from tractionecu.sim import scenarios
from tractionecu.sim import terramech as tm
from tractionecu.sim import tyre as ty
from tractionecu.sim.physical import simulate_physical
from tractionecu.sim.simulator import simulate
from tractionecu.sim.writer import write_recording

TYRE = ty.TyreSpec()
VEH = scenarios.MECH_TRACTOR
RUBICON = tm.WONG_AGRICULTURAL["rubicon-sandy-loam"]()


def test_wheel_terms_by_hand_for_rubicon_sandy_loam():
    # 540/65R34 (b 0.54 m, D 1.6 m) at 1.6 bar, k_z = 1e5 + 1.6 × 1.6e5 = 356 kN/m, W = 21 kN.
    w, b, d = 21000.0, 0.54, 1.6
    delta = w / 356000.0
    l = 2 * math.sqrt(d * delta - delta ** 2)
    p = w / (b * l)
    k = 6.9e3 / b + 752e3                                   # k_c/b + k_phi [N/m^(n+2)]
    z0 = (p / k) ** (1 / 0.66)
    rc = b * k * z0 ** 1.66 / 1.66
    assert l == pytest.approx(0.6031, abs=1e-4)
    assert p == pytest.approx(64.48e3, rel=1e-3)
    assert z0 == pytest.approx(0.0236, abs=2e-4)
    tmax, j0, rho_c = tm.wheel_terms(RUBICON, w, b, 0.8, TYRE, 1.6e5)
    assert float(tmax) == pytest.approx(3.7e3 / p + math.tan(math.radians(29.8)), rel=1e-12)
    assert float(j0) == pytest.approx(0.025 / l, rel=1e-12)
    assert float(rho_c) == pytest.approx(rc / w, rel=1e-12)
    assert 0.6 < float(tmax) < 0.66 and 0.02 < float(rho_c) < 0.03


def test_janosi_shape_is_the_shear_stress_integrated_over_the_patch():
    """F/F_max = (1/l) ∫₀ˡ (1 − e^{−i x/K}) dx (uniform pressure, j = i x), integrated numerically."""
    l, kk = 0.6, 0.025
    x = np.linspace(0.0, l, 200001)
    for i in (0.005, 0.03, 0.1, 0.3):
        tau = 1 - np.exp(-i * x / kk)
        integral = np.sum(0.5 * (tau[1:] + tau[:-1]) * np.diff(x)) / l
        assert float(tm.janosi_shape(i, kk / l)) == pytest.approx(integral, rel=1e-6)
    assert float(tm.janosi_shape(-0.1, 0.04)) == -float(tm.janosi_shape(0.1, 0.04))
    assert float(tm.janosi_shape(0.0, 0.04)) == 0.0


def test_kernel_law_3_is_the_module_shape_and_its_slope():
    j0 = 0.04
    for s in (-0.2, -1e-10, 0.0, 1e-10, 2e-5, 4e-5, 1e-3, 0.05, 0.3, 1.0):
        assert K.shape(s, tm.LAW_JANOSI, j0) == pytest.approx(float(tm.janosi_shape(s, j0)), rel=1e-9, abs=1e-15)
        h = 1e-7
        num = (float(tm.janosi_shape(abs(s) + h, j0)) - float(tm.janosi_shape(abs(s) + 0.0, j0))) / h
        assert K.shape_slope(s, tm.LAW_JANOSI, j0) == pytest.approx(num, rel=1e-4, abs=1e-4)
    # The series and the closed form meet at x = 1e-3 (no step in the slope the relaxation length uses).
    assert K.janosi_slope(1e-3 - 1e-12) == pytest.approx(K.janosi_slope(1e-3 + 1e-12), rel=1e-9)


def test_heavier_wheel_longer_patch_steeper_rise():
    """The load enters through the patch: a heavier wheel rises faster in slip (j0 = K/l smaller)."""
    light, heavy = 12000.0, 27000.0
    _, j_l, r_l = tm.wheel_terms(RUBICON, light, 0.54, 0.8, TYRE, 1.6e5)
    _, j_h, r_h = tm.wheel_terms(RUBICON, heavy, 0.54, 0.8, TYRE, 1.6e5)
    assert j_h < j_l
    assert float(tm.janosi_shape(0.05, j_h)) > float(tm.janosi_shape(0.05, j_l))


def test_bekker_soils_are_not_the_d497_family():
    """The scenario's soils leave a clear residual against D497's slip term (the machine prior's shape)."""
    d497 = CURVE_SHAPES["d497"]
    s = np.linspace(0.0, 0.4, 401)
    worst = 1.0
    for soil in scenarios.BEKKER_THREE_SOILS:
        mu = ty.paper_mu(s, soil, VEH.mass_kg * G / 4, VEH.tyre_width_m, VEH.r0_m, TYRE, VEH.tyre_pressure_pa,
                         VEH.rho_t)
        g = d497.g(s)
        a = float(g @ mu / (g @ g))
        worst = min(worst, 1 - np.sum((mu - a * g) ** 2) / np.sum((mu - mu.mean()) ** 2))
    assert worst < 0.9


@pytest.fixture(scope="module")
def bekker_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bekker")
    scn = scenarios.get("mechanical-bekker-soils", duration_s=40.0)
    tr = simulate(scn)
    write_recording(scn, tr, out)
    return scn, tr, out


def test_truth_mu_is_the_janosi_curve_at_the_wheels_relaxed_slip(bekker_run):
    """In steady work on one soil the truth's μ_i is T_max f(s/j0) + ρ_t,tyre − ρ_t,declared under each
    wheel's load at its own slip: on the mean over 4 s (the force follows the slip's ≈ 1 Hz drive-line
    oscillation through its relaxation length, so sample by sample they differ by the lag)."""
    scn, tr, _ = bekker_run
    k = np.flatnonzero(tr.work)[-400:]
    sid = int(tr.soil_wheel[k[0], 0])
    assert np.all(tr.soil_wheel[k] == sid)
    soil = scn.physical.soils[sid]
    for i in range(4):
        tmax, j0, _ = tm.wheel_terms(soil, tr.fz[k, i], VEH.tyre_width_m, VEH.r0_m, TYRE, VEH.tyre_pressure_pa)
        hand = tmax * tm.janosi_shape(tr.slip[k, i], j0) + TYRE.rho_t - VEH.rho_t
        assert np.mean(tr.mu[k, i]) == pytest.approx(np.mean(hand), abs=0.005), i


def test_truth_rho_s_is_bekkers_compaction_resistance(bekker_run):
    scn, tr, _ = bekker_run
    k = np.flatnonzero(tr.work)[-400:]
    sid = int(tr.soil_wheel[k[0], 0])
    assert np.all(tr.soil_wheel[k] == sid)
    soil = scn.physical.soils[sid]
    _, _, rho_c = tm.wheel_terms(soil, tr.fz[k], VEH.tyre_width_m, VEH.r0_m, TYRE, VEH.tyre_pressure_pa)
    hand = np.sum((rho_c + TYRE.rho_t - VEH.rho_t) * tr.fz[k], axis=1) / tr.fz[k].sum(axis=1)
    assert np.allclose(tr.rho_s[k], hand, rtol=1e-9)


def test_truth_toml_names_the_model_and_its_parameters(bekker_run):
    _, _, out = bekker_run
    t = tomllib.loads((out / "truth.toml").read_text())
    names = [s["name"] for s in t["soils"]]
    assert names == ["upland-sandy-loam", "north-gower-clayey-loam", "rubicon-sandy-loam"]
    for s in t["soils"]:
        assert s["traction_model"] == tm.TRACTION_MODEL and s["law"] == "janosi"
        assert "cone_index_pa" not in s and s["shear_k_m"] > 0 and len(s["mu_curve"]) == len(s["mu_curve_s"])
        assert s["mu_curve"][0] == pytest.approx(TYRE.rho_t - VEH.rho_t)


def test_mixed_brixius_and_bekker_soils_are_refused():
    scn = scenarios.get("mechanical-bekker-soils", duration_s=1.0)
    mixed = (scenarios.PHYSICAL_THREE_SOILS[0],) + scenarios.BEKKER_THREE_SOILS[1:]
    from dataclasses import replace
    scn = replace(scn, physical=replace(scn.physical, soils=mixed))
    with pytest.raises(ValueError, match="Brixius and Bekker"):
        simulate_physical(scn)


MECH_40S_SHA256 = {
    "can.log": "328215d127446a78b35ab72db7d7ba75437cdb7e143c57f74f274ba9818d711d",
    "truth.csv": "82d26a635d3c772e92b05c6a8e826f60c99fa7c55e56776171172e2e79f38d14",
}
"""mechanical-three-soils, seed 0, 40 s, written before the Bekker soils existed."""


def test_brixius_mechanical_recording_byte_identical(tmp_path):
    scn = scenarios.get("mechanical-three-soils", duration_s=40.0)
    write_recording(scn, simulate(scn), tmp_path)
    got = {n: hashlib.sha256((tmp_path / n).read_bytes()).hexdigest() for n in MECH_40S_SHA256}
    assert got == MECH_40S_SHA256
