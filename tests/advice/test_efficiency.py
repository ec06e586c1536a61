"""Traction efficiency (paper eq. 7), the optimal slip and its interval, and the bus message."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from tractionecu.advice import efficiency as eff
from tractionecu.advice.bus import MESSAGE, efficiency_frame
from tractionecu.advice.engine import AdviceEngine
from tractionecu.bus.dbc import default_codec
from tractionecu.config import VehicleParams
from tractionecu.model.mucurve import SOIL_CLASSES
from tractionecu.model.vehicle import traction_efficiency

STUBBLE = SOIL_CLASSES["stubble"]


def curve(a: float, sigma_a: float = 0.0) -> eff.CurveParams:
    return eff.CurveParams(a, STUBBLE.p, STUBBLE.alpha1, STUBBLE.alpha2, sigma_a=sigma_a, class_name="stubble")


def test_eta_is_paper_eq7() -> None:
    # η = κ/(κ + ρ)(1 − s), κ = μ − ρ_s, ρ = ρ_s + ρ_t: the per-wheel form and the model's function agree
    mu, s, rho_s, rho_t = 0.45, 0.08, 0.07, 0.015
    want = float(traction_efficiency(mu - rho_s, rho_s + rho_t, s))
    assert float(eff.eta_wheels([mu], [s], rho_s, rho_t)[0]) == pytest.approx(want)
    # the machine's η of four equal wheels is the wheel's η
    assert eff.eta_machine([mu] * 4, [s] * 4, [1e4] * 4, rho_s, rho_t) == pytest.approx(want)


def test_machine_eta_is_power_ratio() -> None:
    # Σ pull·v / Σ wheel power, with wheel power (μ + ρ_t) F_z · v/(1 − s)
    mu = np.array([0.40, 0.42, 0.50, 0.52])
    s = np.array([0.06, 0.07, 0.09, 0.10])
    fz = np.array([12e3, 12e3, 19e3, 19e3])
    rho_s, rho_t, v = 0.06, 0.015, 2.5
    p_out = float(np.sum((mu - rho_s) * fz)) * v
    p_in = float(np.sum((mu + rho_t) * fz * v / (1 - s)))
    assert eff.eta_machine(mu, s, fz, rho_s, rho_t) == pytest.approx(p_out / p_in)


@pytest.mark.parametrize("a,rho_s", [(0.82, 0.05), (0.70, 0.07), (0.58, 0.10), (0.45, 0.12)])
def test_optimum_matches_a_dense_search(a: float, rho_s: float) -> None:
    s = np.linspace(0, 0.6, 600001)
    e = eff.eta_curve(s, curve(a), rho_s, 0.015)
    k = int(np.nanargmax(e))
    s_star, e_star = eff.optimum(curve(a), rho_s, 0.015)
    assert s_star == pytest.approx(s[k], abs=2e-4)
    assert e_star == pytest.approx(e[k], abs=1e-6)


def test_softer_soil_moves_the_optimum_up() -> None:
    # more soil resistance and less adhesion: the best slip is higher, the best efficiency lower
    s1, e1 = eff.optimum(curve(0.82), 0.05, 0.015)
    s2, e2 = eff.optimum(curve(0.58), 0.10, 0.015)
    assert s2 > s1 + 0.02 and e2 < e1 - 0.1


def test_interval_grows_with_the_parameter_uncertainty() -> None:
    _, _, ss0, _ = eff.optimum_with_interval(curve(0.7, 0.0), 0.07, 0.015, 0.0)
    _, _, ss1, se1 = eff.optimum_with_interval(curve(0.7, 0.02), 0.07, 0.015, 0.0)
    _, _, ss2, _ = eff.optimum_with_interval(curve(0.7, 0.02), 0.07, 0.015, 0.005 ** 2)
    assert ss0 == 0.0 and 0 < ss1 < ss2 and se1 > 0
    # the delta method against the spread of s* over sampled a
    rng = np.random.default_rng(1)
    samples = [eff.optimum(curve(a), 0.07, 0.015)[0] for a in rng.normal(0.7, 0.02, 400)]
    assert float(np.std(samples)) == pytest.approx(ss1, rel=0.15)


def test_a_covariance_of_the_full_shape_is_used() -> None:
    # a covariance over (a, p, α1, α2), as a curve fit beyond a provides it, widens the interval
    cov = np.diag([0.02 ** 2, 0.05 ** 2, 3.0 ** 2, 0.5 ** 2])
    c = eff.CurveParams(0.7, STUBBLE.p, STUBBLE.alpha1, STUBBLE.alpha2, cov=cov, names=("a", "p", "alpha1", "alpha2"))
    _, _, ss_full, _ = eff.optimum_with_interval(c, 0.07, 0.015, 0.0)
    _, _, ss_a, _ = eff.optimum_with_interval(curve(0.7, 0.02), 0.07, 0.015, 0.0)
    assert ss_full > ss_a
    est = SimpleNamespace(curve=SimpleNamespace(a=0.7, p=STUBBLE.p, alpha1=STUBBLE.alpha1, alpha2=STUBBLE.alpha2,
                                                cov=cov, names=("a", "p", "alpha1", "alpha2")), soil_class="stubble")
    got = eff.curve_of(est)
    assert got is not None and got.covariance()[1].shape == (4, 4)


def estimate(t: float, slip: float, a: float = 0.7, rho_s: float = 0.07, status: int = 0, v: float = 2.5,
             sv: float = 0.02) -> SimpleNamespace:
    mu = float(STUBBLE.mu(slip, a))
    P = np.full(10, 1e-5)
    P[4] = sv ** 2
    P[9] = 0.004 ** 2
    return SimpleNamespace(t=t, mu=np.full(4, mu), slip=np.full(4, slip), rho_s=rho_s, v=v, P_diag=P, a=a,
                           soil_class="stubble", status=status, valid=status == 0)


def test_tracker_reports_the_optimum_with_an_interval() -> None:
    trk = eff.EfficiencyTracker(eff.efficiency_config_for(VehicleParams()))
    rep = trk.update(estimate(0.0, 0.08))
    s_true, e_true = eff.optimum(curve(0.7), 0.07, 0.015)
    assert rep.flags == 0 and rep.s_star_valid and rep.eta_valid
    assert rep.s_star == pytest.approx(s_true, abs=1e-6)
    assert rep.s_star_lo < rep.s_star < rep.s_star_hi
    assert rep.eta == pytest.approx(float(eff.eta_curve(0.08, curve(0.7), 0.07, 0.015)), abs=1e-9)
    assert rep.eta_lost >= 0 and rep.eta_star == pytest.approx(e_true)
    assert rep.pull_at_s_star_n == pytest.approx((float(STUBBLE.mu(s_true, 0.7)) - 0.07) * VehicleParams().weight_n)


def test_low_slip_says_so_instead_of_a_number() -> None:
    # at 0.5 % slip g(s) → 0: a is undetermined, s* is not given, and the flags say why
    trk = eff.EfficiencyTracker(eff.efficiency_config_for(VehicleParams()))
    for k in range(20):
        rep = trk.update(estimate(0.1 * k, 0.005))
    assert not rep.s_star_valid and math.isnan(rep.s_star)
    assert rep.flags & eff.LOW_EXCITATION
    assert "slip too low to identify the curve" in rep.reasons()


def test_invalid_estimate_and_unknown_curve() -> None:
    trk = eff.EfficiencyTracker()
    rep = trk.update(estimate(0.0, 0.08, status=0x20))
    assert rep.flags & eff.ESTIMATE_INVALID and math.isnan(rep.eta) and math.isnan(rep.s_star)
    rep = trk.update(estimate(0.1, 0.08, a=math.nan))
    assert rep.flags & eff.CURVE_NOT_IDENTIFIED
    rep = trk.update(estimate(0.2, 0.08, v=0.0))
    assert rep.flags & eff.NOT_PULLING and not rep.slip_ok


def test_a_slip_the_estimator_does_not_support_gives_no_efficiency() -> None:
    # status 0x2000: the slip's own σ is over its bound and the estimator holds an old value; η (eq. 7,
    # factor 1 − s) and the excitation of the curve must not rest on it.  0x1000: machine-level μ not
    # supported (gear shift).
    trk = eff.EfficiencyTracker(eff.efficiency_config_for(VehicleParams()))
    rep = trk.update(estimate(0.0, 0.08, status=0x2000))
    assert rep.flags & eff.ESTIMATE_INVALID and not rep.eta_valid and not rep.slip_ok
    assert not rep.flags & eff.LOW_EXCITATION          # no supported slip yet: the estimate's flag says why
    rep = trk.update(estimate(0.05, 0.005))             # the first supported slip is low: the 0.08 did not count
    assert rep.flags & eff.LOW_EXCITATION
    rep = trk.update(estimate(0.1, 0.08, status=0x1000))
    assert rep.flags & eff.ESTIMATE_INVALID and not rep.eta_valid


def test_start_up_does_not_read_as_low_slip() -> None:
    """Every run's first status lines said "slip too low to identify the curve" (at a slip of 0.55 too):
    the excitation window started at −∞.  Before the first supported slip, the estimate's flags say why."""
    trk = eff.EfficiencyTracker(eff.efficiency_config_for(VehicleParams()))
    rep = trk.update(estimate(0.0, 0.55, status=0x2000))    # start-up: the slip not yet supported
    assert not rep.flags & eff.LOW_EXCITATION and "slip too low" not in rep.reasons()
    rep = trk.update(estimate(0.1, 0.08))
    assert not rep.flags & eff.LOW_EXCITATION


def test_the_message_decodes_back() -> None:
    codec = default_codec()
    trk = eff.EfficiencyTracker(eff.efficiency_config_for(VehicleParams()))
    rep = trk.update(estimate(0.0, 0.08))
    cid, data = efficiency_frame(codec, rep, sa=0x90, priority=6)
    name, vals = codec.decode(cid, data)
    assert name == MESSAGE and codec.message(MESSAGE).pgn == 0xFF23 and cid & 0xFF == 0x90
    assert vals["OptimalSlip"] == pytest.approx(rep.s_star, abs=0.5e-4)
    assert vals["TractionEfficiency"] == pytest.approx(rep.eta, abs=0.5e-4)
    assert vals["TractionEfficiencyAtOptimum"] == pytest.approx(rep.eta_star, abs=0.5e-4)
    assert vals["EfficiencyValidity"] == 0
    assert vals["OptimalSlipHalfWidth"] == pytest.approx((rep.s_star_hi - rep.s_star_lo) / 2, abs=0.5e-3)
    # invalid values go out as "not available", the flags say why
    rep = trk.update(estimate(0.1, 0.08, status=0x20))
    _, vals = codec.decode(*efficiency_frame(codec, rep, sa=0x90, priority=6))
    assert vals["EfficiencyValidity"] == eff.ESTIMATE_INVALID
    assert all(math.isnan(vals[k]) for k in ("OptimalSlip", "TractionEfficiency", "TractionEfficiencyAtOptimum"))
    _, vals = codec.decode(*efficiency_frame(codec, None, sa=0x90, priority=6))
    assert int(vals["EfficiencyValidity"]) & eff.CURVE_NOT_IDENTIFIED


def test_the_identified_mucurve_of_any_form_is_used() -> None:
    from tractionecu.model.mucurve import MuCurve

    # the class path without var(a) yet: a from the curve, σ(a) left to the estimate
    est = SimpleNamespace(curve=MuCurve.from_class(STUBBLE, 0.7), soil_class="stubble", a=0.7)
    c = eff.curve_of(est)
    assert c is not None and c.cov is None and c.mu(0.08) == pytest.approx(float(STUBBLE.mu(0.08, 0.7)))
    # a fitted eq. 14 shape with its covariance: s* and its interval from all four parameters
    theta = (0.7, STUBBLE.p, STUBBLE.alpha1, STUBBLE.alpha2)
    cov = np.diag([0.01 ** 2, 0.02 ** 2, 2.0 ** 2, 0.3 ** 2])
    est = SimpleNamespace(curve=MuCurve("eq14", theta, cov, "shape:eq14"), soil_class="stubble", a=0.7)
    c = eff.curve_of(est)
    s0, e0, ss, _ = eff.optimum_with_interval(c, 0.07, 0.015, 0.0)
    assert (s0, e0) == pytest.approx(eff.optimum(curve(0.7), 0.07, 0.015), abs=1e-9)
    assert 0 < ss < 0.05
    # a shape whose covariance is not known: no interval, so no s*
    est = SimpleNamespace(curve=MuCurve("eq14", theta, np.full((4, 4), np.nan), "shape:eq14"), soil_class="x", a=0.7)
    assert math.isinf(eff.optimum_with_interval(eff.curve_of(est), 0.07, 0.015, 0.0)[2])


def test_a_curve_shape_outside_the_surface_classes_has_its_curve_and_optimum() -> None:
    """An estimate of the machine-level estimator's ``d497`` prior without a reported curve: its class shape
    comes from model.mucurve.curve_class (it gave no curve, so no η(s) and no s*, with SOIL_CLASSES only)."""
    from tractionecu.model.mucurve import CURVE_SHAPES

    d497 = CURVE_SHAPES["d497"]
    got = eff.curve_of(SimpleNamespace(a=0.8, soil_class="d497"), sigma_a=0.01)
    assert got is not None and (got.p, got.alpha1, got.alpha2, got.class_name) == (1.0, -7.5, -7.5, "d497")
    s = np.linspace(0.0, 0.4, 41)
    assert np.allclose(got.mu(s), d497.mu(s, 0.8))
    s_star, e_star = eff.true_optimum(0.8, 0.06, 0.015, "d497")
    # η(s) = (0.8 g(s) - ρ_s)/(0.8 g(s) + ρ_t)(1 - s) on a fine grid: the same maximum
    fine = np.linspace(0.001, 0.5, 50000)
    mu = d497.mu(fine, 0.8)
    eta = (mu - 0.06) / (mu + 0.015) * (1 - fine)
    assert s_star == pytest.approx(fine[np.argmax(eta)], abs=2e-4) and e_star == pytest.approx(eta.max(), abs=1e-6)
    assert eff.curve_of(SimpleNamespace(a=0.8, soil_class="loam")) is None
    with pytest.raises(KeyError, match="loam"):
        eff.true_optimum(0.8, 0.06, 0.015, "loam")


def test_a_machine_without_a_draft_sensor_is_told_apart_from_an_invalid_estimate() -> None:
    """A mechanical tractor without a draft sensor reports no ρ_s by design (status 0x8000, machine level 0x4000);
    its estimate is valid, but the service's status line said "s* - (estimate not valid)" all the way."""
    from tractionecu.advice.engine import AdviceEngine

    trk = eff.EfficiencyTracker(eff.efficiency_config_for(VehicleParams()))
    est = estimate(0.0, 0.08, rho_s=math.nan, status=0xC000)
    est.valid = True
    rep = trk.update(est)
    assert rep.flags & eff.NO_RHO_S and not rep.flags & eff.ESTIMATE_INVALID
    assert not rep.eta_valid and not rep.s_star_valid and rep.slip_ok
    _, vals = default_codec().decode(*efficiency_frame(default_codec(), rep, sa=0x90, priority=6))
    assert int(vals["EfficiencyValidity"]) & eff.NO_RHO_S and math.isnan(vals["TractionEfficiency"])
    eng = AdviceEngine(VehicleParams())
    eng.feed(est)
    assert "no rho_s without a draft sensor" in eng.status_text() and "estimate not valid" not in eng.status_text()
    # a ρ_s missing for any other reason still makes the estimate unusable
    rep = trk.update(estimate(0.1, 0.08, rho_s=math.nan))
    assert rep.flags & eff.ESTIMATE_INVALID and not rep.flags & eff.NO_RHO_S


def test_the_page_gets_no_slip_or_pull_the_estimate_does_not_support() -> None:
    """Reversing (slip not supported) and at standstill the page showed "slip now 1.3 %" and the pull frozen
    from the last supported step, as live values."""
    trk = eff.EfficiencyTracker(eff.efficiency_config_for(VehicleParams()))
    d = trk.update(estimate(0.0, 0.08)).as_dict()
    assert d["slip"] == pytest.approx(0.08) and d["slip_ok"] and d["pull_n"] > 0
    held = trk.update(estimate(0.1, 0.08, status=0x2000)).as_dict()         # slip not supported: held
    assert held["slip"] is None and held["slip_ok"] is False and held["pull_n"] is None
    still = trk.update(estimate(0.2, 0.08, status=0x400, v=0.0)).as_dict()   # standstill
    assert still["slip"] is None and still["pull_n"] is None


def test_a_curve_of_another_form_gets_its_own_optimum_at_once() -> None:
    """The estimator's curve became a fit whose parameters it gave as unknown (σ(p) = 161 on ``ballast-needed``):
    the class curve's s* was still sent as valid until the next once-a-second optimum."""
    eng = AdviceEngine(VehicleParams())
    for k in range(12):
        rep = eng.feed(estimate(0.1 * k, 0.12))
    assert rep.s_star_valid
    fit = estimate(1.25, 0.12)
    fit.curve = SimpleNamespace(a=0.706, p=-2.026, alpha1=-14.27, alpha2=-10.98, names=("a", "p", "alpha1", "alpha2"),
                                cov=np.diag([0.04, 161.0, 169.0, 71.0]) ** 2)
    rep = eng.feed(fit)                            # 0.25 s after the last optimum: the cheap path
    assert rep.flags & eff.INTERVAL_WIDE and not rep.s_star_valid and math.isnan(rep.s_star)


def test_a_front_drive_switched_off_gives_the_rear_axles_efficiency() -> None:
    """The machine-level estimator gives no front slip with the MFWD disengaged; the tracker read that as "not
    pulling", so a tractor working with its front drive off had no η, s* or advice.  The front wheels roll
    (F_h = −ρ_t F_z, no power), the rear wheels carry the machine's μ with the front's rolling loss."""
    veh = VehicleParams()
    cfg = eff.efficiency_config_for(veh)
    trk = eff.EfficiencyTracker(cfg)
    s_r, rho_s, W = 0.09, 0.07, cfg.weight_n
    fz = trk.wheel_loads(W * 0.3)                   # (the loads' split as the tracker takes it, at this pull)
    mu_r = float(STUBBLE.mu(s_r, 0.7))
    mu_m = (mu_r * fz[2:].sum() - cfg.rho_t * fz[:2].sum()) / W          # ΣF_h / ΣF_z
    est = estimate(0.0, s_r, rho_s=rho_s)
    est.mu, est.slip, est.front_engaged = np.full(4, mu_m), np.array([np.nan, np.nan, s_r, s_r]), False
    trk.wheel_loads = lambda pull: fz                # the split fixed, so that the expected values are exact
    rep = trk.update(est)
    assert not rep.flags & eff.NOT_PULLING and rep.slip_ok and rep.slip == pytest.approx(s_r)
    fzf, fzr = fz[:2].sum(), fz[2:].sum()
    eta_true = (mu_r * fzr - cfg.rho_t * fzf - rho_s * W) / ((mu_r + cfg.rho_t) * fzr / (1 - s_r))
    assert rep.eta == pytest.approx(eta_true, rel=1e-9) and math.isnan(rep.eta_front)
    assert rep.pull_n == pytest.approx(W * (mu_m - rho_s))
    rho_eff = (cfg.rho_t * fzf + rho_s * W) / fzr
    assert rep.s_star_valid and rep.s_star == pytest.approx(eff.optimum(curve(0.7), rho_eff, cfg.rho_t)[0], abs=1e-6)
    assert rep.s_star > eff.optimum(curve(0.7), rho_s, cfg.rho_t)[0]      # the rolling front asks for more slip
