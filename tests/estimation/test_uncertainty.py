"""Reported uncertainty: sensor tolerances propagated into σ_μ, σ_ρs (estimation/uncertainty.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from est_synth import synth_run

from tractionecu.config import G, SensorSpec, VehicleParams
from tractionecu.estimation.config import EstimatorConfig
from tractionecu.estimation.estimator import INVALID_MASK, STATUS_NAMES, UNVERIFIED, Estimator
from tractionecu.estimation.uncertainty import SystematicUncertainty

VEH = VehicleParams()
_NO_TOL = dict(torque_gain_tol_rel=0.0, torque_offset_tol_nm=0.0, axle_offset_tol_n=0.0, axle_gain_tol_rel=0.0,
               draft_offset_tol_n=0.0, draft_gain_tol_rel=0.0, gps_latency_tol_s=0.0, rolling_radius_tol_rel=0.0)


def test_status_bit_is_free_and_a_notice():
    assert UNVERIFIED == 0x800 and STATUS_NAMES[UNVERIFIED] == "unverified_assumptions"
    assert not UNVERIFIED & INVALID_MASK
    assert sum(1 for b in STATUS_NAMES if b & UNVERIFIED) == 1
    assert UNVERIFIED < 1 << 16                    # the DBC's EstimateStatus is 16 bits


def test_propagation_formulas():
    """Each tolerance alone gives the documented closed form (rectangular bound b: u = b/√3)."""
    md, fzf, fdx, rdf, rdr = [2000.0, 2000.0, 3000.0, 3000.0], 24000.0, 15000.0, 0.78, 0.77
    ff, fr = fzf / 2, (VEH.weight_n - fzf) / 2
    c = [md[0] / (rdf * ff), md[2] / (rdr * fr)]
    # torque gain: Δμ = δ c; Δρ_s = δ Σ|M/r| / (m g) (drives correlated)
    u = SystematicUncertainty(SensorSpec(**{**_NO_TOL, "torque_gain_tol_rel": 0.02}), VEH)
    vm, vr = u.variances(md, fzf, fdx, rdf, rdr, 0.0, 0.0)
    assert math.sqrt(vm[0]) == pytest.approx(c[0] * 0.02 / math.sqrt(3))
    assert math.sqrt(vm[3]) == pytest.approx(c[1] * 0.02 / math.sqrt(3))
    tot = 2 * md[0] / rdf + 2 * md[2] / rdr
    assert math.sqrt(vr) == pytest.approx(0.02 / math.sqrt(3) * tot / (VEH.mass_kg * G))
    # draft offset ΔF: ρ_s only, ΔF / (m g)
    u = SystematicUncertainty(SensorSpec(**{**_NO_TOL, "draft_offset_tol_n": 300.0}), VEH)
    vm, vr = u.variances(md, fzf, fdx, rdf, rdr, 0.0, 0.0)
    assert max(vm) == 0.0
    assert math.sqrt(vr) == pytest.approx(300.0 / math.sqrt(3) / (VEH.mass_kg * G))
    # axle-load offset: ±ΔF_zf/2 per wheel, Δμ = c ΔF_z / F_z; no effect on ρ_s (the loads sum to m g)
    u = SystematicUncertainty(SensorSpec(**{**_NO_TOL, "axle_offset_tol_n": 300.0}), VEH)
    vm, vr = u.variances(md, fzf, fdx, rdf, rdr, 0.0, 0.0)
    assert math.sqrt(vm[0]) == pytest.approx(c[0] * 150.0 / math.sqrt(3) / ff)
    assert math.sqrt(vm[2]) == pytest.approx(c[1] * 150.0 / math.sqrt(3) / fr)
    assert vr == 0.0
    # rolling radius (the uncertainty passed in, per axle)
    u = SystematicUncertainty(SensorSpec(**_NO_TOL), VEH)
    vm, vr = u.variances(md, fzf, fdx, rdf, rdr, 0.01, 0.0)
    assert math.sqrt(vm[1]) == pytest.approx(c[0] * 0.01) and vm[2] == 0.0
    assert math.sqrt(vr) == pytest.approx(0.01 * 2 * md[0] / rdf / (VEH.mass_kg * G))
    # GNSS latency: (τ a)²/3
    u = SystematicUncertainty(SensorSpec(**{**_NO_TOL, "gps_latency_tol_s": 0.1}), VEH)
    assert u.gnss_latency_var(0.3) == pytest.approx((0.1 * 0.3) ** 2 / 3)


def _biased(steps, gain=(0.02, 0.015, -0.01, 0.02), draft_offset=-250.0, axle_offset=250.0):
    out = []
    for t, inp, meas in steps:
        inp = dict(inp)
        inp["Md"] = np.asarray(inp["Md"]) * (1.0 + np.asarray(gain))
        if "Fdx" in inp:
            inp["Fdx"] = inp["Fdx"] + draft_offset
            inp["Fzf"] = inp["Fzf"] + axle_offset
        out.append((t, inp, meas))
    return out


@pytest.fixture(scope="module")
def biased_run():
    r = synth_run(seed=11, duration=20.0)
    return r, _biased(r.steps)


def _cover(est_list, r, sl):
    mu = np.array([e.mu for e in est_list])[sl]
    smu = np.array([e.sigma_mu for e in est_list])[sl]
    pmu = np.sqrt(np.array([e.P_diag[5:9] for e in est_list]))[sl]
    rho = np.array([e.rho_s for e in est_list])[sl]
    srho = np.array([e.sigma_rho_s for e in est_list])[sl]
    err = np.abs(mu - r.mu[sl])
    return (np.mean(err <= 2 * smu), np.mean(err <= 2 * pmu), np.mean(np.abs(rho - r.rho_s[sl]) <= 2 * srho))


def test_biased_sensors_are_covered_and_flagged(biased_run):
    r, steps = biased_run
    est = Estimator(VEH)
    out = [est.step(*s) for s in steps]
    sl = slice(500, None)
    valid = np.array([e.valid for e in out])[sl]
    assert valid.all()
    cov_mu, cov_filter, cov_rho = _cover(out, r, sl)
    print(f"coverage within 2σ: μ {cov_mu:.3f} (filter's own σ: {cov_filter:.3f}), ρ_s {cov_rho:.3f}")
    # the filter cannot see a constant gain or offset; the reported band holds the truth at the target rate
    assert cov_mu >= 0.9 and cov_rho >= 0.9
    assert cov_mu > cov_filter
    st = np.array([e.status for e in out])[sl]
    assert ((st & UNVERIFIED) != 0).mean() > 0.9


def test_reporting_leaves_the_filter_alone(biased_run):
    """Without the latency term (which is noise model), the systematic part changes only what is reported."""
    _, steps = biased_run
    sp = SensorSpec(gps_latency_tol_s=0.0)
    with_sys = Estimator(VEH, EstimatorConfig(), sp)
    plain = Estimator(VEH, EstimatorConfig(systematic_uncertainty=False), sp)
    a = [with_sys.step(*s) for s in steps]
    b = [plain.step(*s) for s in steps]
    assert np.array_equal(np.array([e.mu for e in a]), np.array([e.mu for e in b]), equal_nan=True)
    assert np.array_equal(np.array([e.P_diag for e in a]), np.array([e.P_diag for e in b]), equal_nan=True)
    f, e = b[-1], a[-1]
    assert np.allclose(f.sigma_mu, np.sqrt(f.P_diag[5:9])) and f.sigma_rho_s == pytest.approx(math.sqrt(f.P_diag[9]))
    assert (e.sigma_mu > f.sigma_mu).all() and e.sigma_rho_s > f.sigma_rho_s
    assert np.allclose(e.sigma_mu ** 2, e.P_diag[5:9] + e.sys_var[:4])
    assert not f.status & UNVERIFIED and e.status & UNVERIFIED


def test_sigma_before_convergence_is_nan():
    r = synth_run(seed=3, duration=0.5)
    est = Estimator(VEH)
    e = est.step(*r.steps[0])
    assert not e.valid and np.isnan(e.sigma_mu).all() and math.isnan(e.sigma_rho_s)
