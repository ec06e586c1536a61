"""What every tractor has is not a fault: the nominal model's rolling-resistance terms, the
parsimony rule for the machine's characteristics, fits on a bound, and uninformative intervals."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from tractionecu.config import VehicleParams
from tractionecu.diagnose.channels import (MU0_RANGE, SLIP_RESISTANCE_MAX, SlipChannel, _CurveInverse,
                                          _rho_and_slip_fit)
from tractionecu.diagnose.data import Frame
from tractionecu.diagnose.engine import _implausible_bound, identified
from tractionecu.diagnose.fit import FitResult
from tractionecu.model.mucurve import SOIL_CLASSES


def test_rho_per_cell_and_one_slip_coefficient_are_least_squares_within_the_physical_range():
    rng = np.random.default_rng(3)
    n = 600
    group = np.repeat([0, 1, 2], n // 3)
    mg = 60000.0
    xs = rng.uniform(0.0, 6000.0, n)               # Σ F_z |s| [N]
    rho = np.array([0.05, 0.08, 0.06])
    for k_true in (0.07, -0.2, 0.6):
        y = rho[group] * mg + k_true * xs + rng.normal(0, 5.0, n)
        fit = _rho_and_slip_fit(y, mg, xs, group, 3)
        A = np.column_stack([(group == g).astype(float) for g in range(3)] + [xs])
        b, *_ = np.linalg.lstsq(A, y, rcond=None)
        k_hat = np.clip(b[3], 0.0, SLIP_RESISTANCE_MAX)
        assert k_hat == pytest.approx(min(max(k_true, 0.0), SLIP_RESISTANCE_MAX), abs=2e-3)
        if 0.0 < b[3] < SLIP_RESISTANCE_MAX:
            assert np.allclose(fit, A @ b, rtol=1e-9, atol=1e-6)
        else:
            # On a bound, ρ per cell is the least squares given that k.
            for g in range(3):
                m = group == g
                assert np.mean(fit[m] - k_hat * xs[m]) == pytest.approx(np.mean(y[m] - k_hat * xs[m]), rel=1e-9)


def test_slip_channel_fits_the_zero_slip_traction_ratio_per_axle():
    """μ = a g(s) + μ_0 per axle (a real tyre's hysteresis loss differs from the declared ρ_t): the
    nominal fit recovers a per cell and μ_0 per axle from noiseless slip."""
    cls = SOIL_CLASSES["stubble"]
    inv = _CurveInverse(cls)
    rng = np.random.default_rng(5)
    n = 4000
    cell = rng.integers(0, 6, n)                   # 3 field cells × 2 axles (cell % 2 = axle)
    a_true = np.array([0.7, 0.65, 0.6, 0.58, 0.8, 0.72])
    mu0_true = np.array([0.02, 0.035])
    s = rng.uniform(0.0, 0.2, n)
    mu = a_true[cell] * cls.g(s) + mu0_true[cell % 2]
    ch = SimpleNamespace(ncell=6)
    a, m0 = SlipChannel._gauss_newton_a(ch, inv, mu, np.ones(n), None, s, np.ones(n), cell,
                                        np.full(6, 0.7), iters=30)
    assert np.allclose(a, a_true, atol=2e-3)
    assert np.allclose(m0, mu0_true, atol=1e-3)
    assert MU0_RANGE[0] < 0 < 0.04 < MU0_RANGE[1]   # Brixius' 0.04 against a declared ρ_t of 0 still fits


def test_an_interval_spanning_its_range_is_not_identified():
    assert not identified("torque_gain", "k_rear", -0.3, 0.3)
    assert not identified("torque_gain", "k_rear", -0.28, 0.29)
    assert identified("torque_gain", "k_rear", -0.1, -0.05)
    assert not identified("torque_gain", "k_rear", math.nan, 0.1)


def _fit(name, params, at_bound):
    return FitResult(name, np.zeros(0), np.zeros((0, 0)), params, {}, {}, {}, {}, 0.0, True,
                     effects={name: params}, at_bound={name: at_bound})


def test_a_fit_on_a_bound_is_implausible_unless_the_bound_is_where_the_effect_vanishes():
    assert _implausible_bound(_fit("wheel_radius", {"epsilon": 0.1}, {"epsilon": "upper"}), "wheel_radius")
    assert _implausible_bound(_fit("torque_gain", {"k_front": 0.3, "k_rear": 0.0}, {"k_front": "upper"}),
                              "torque_gain")
    # η = 1 and σ at its floor are the effects' absence; a front-axle share of 1 is front ballast.
    assert not _implausible_bound(_fit("drivetrain", {"eta": 1.0}, {"eta": "upper"}), "drivetrain")
    assert not _implausible_bound(_fit("mass", {"delta_kg": 700.0, "front_share": 1.0},
                                       {"front_share": "upper"}), "mass")
    assert not _implausible_bound(_fit("wheel_radius", {"epsilon": 0.02}, {}), "wheel_radius")


def test_reduced_diagnosis_flags_a_term_on_its_bound_and_does_not_name_it():
    """An engine-level export whose offset lies beyond the zero-slip term's range: the fit ends on the
    bound, which is reported as a missing term, not as an estimate."""
    from tractionecu.diagnose.reduced import TERM_BOUNDS, diagnose_reduced

    rng = np.random.default_rng(11)
    n = 900
    t = np.arange(n, dtype=float)
    veh = VehicleParams()
    mg = veh.mass_kg * 9.81
    mu0 = TERM_BOUNDS["mu0"][1] + 0.4               # beyond the range
    mu_soil = np.clip(0.35 + 0.2 * np.sin(t / 37.0) + 0.1 * np.sin(t / 11.0), 0.02, 0.62)
    grid = np.linspace(0, 0.6, 601)
    s = np.interp(mu_soil / 0.7, SOIL_CLASSES["stubble"].g(grid), grid)
    vw = 2.0 + 0.8 * np.sin(t / 53.0) ** 2
    vg = vw * (1 - s) + rng.normal(0, 0.02, n)
    omega_e = np.full(n, 2 * math.pi * 30.0)
    fr = Frame(t=t, t0_epoch=0.0, rate_hz=1.0, vehicle=veh, v_gps=vg, v_wheel_bus=vw,
               engine_torque=(mu_soil + mu0) * mg * vw / omega_e, engine_speed=omega_e)
    rep = diagnose_reduced(fr)
    sm = rep["slip_model"]
    if "mu0" in sm["at_bound"]:
        assert sm["at_bound"]["mu0"] == "upper"
        assert not sm["plausible"] and "bound" in rep["statement"]
        assert not any(e["name"] == "zero_slip_offset" and e["named"] for e in rep["effects"])
    else:
        # The offset was taken up by another term: then that term is flagged or a is implausible.
        assert not sm["plausible"]


def _slip_stub(shift_fl: float, seed: int = 2):
    """A diagnosis stand-in with a slip channel of four wheels over 2000 straight samples; FL's
    residual is shifted by ``shift_fl`` slip points (its torque reads high against FR's)."""
    from tractionecu.diagnose.fit import HeldOut

    rng = np.random.default_rng(seed)
    n = 2000
    ti = np.repeat(np.arange(n), 4)
    wi = np.tile(np.arange(4), n)
    wv = np.full(ti.size, 2.5)
    e = np.repeat(rng.normal(0, 0.004, n), 4) + rng.normal(0, 0.003, ti.size)   # common + own noise [-]
    e = e + np.where(wi == 0, shift_fl, 0.0)
    frame = SimpleNamespace(n=n, heading=np.zeros(n), dt=0.1)
    ch = SimpleNamespace(ti=ti, wi=wi, wv=wv)
    ho = HeldOut("x", {}, {}, {"slip": e * wv})
    return SimpleNamespace(problem=SimpleNamespace(channels={"slip": ch}), features=SimpleNamespace(frame=frame)), ho


def test_one_wheel_disagreeing_with_its_partner_is_located():
    from tractionecu.diagnose.openworld import wheel_asymmetry

    d, ho = _slip_stub(-0.01)
    a = wheel_asymmetry(d, ho)
    assert a is not None and a["axle"] == "front" and a["wheels"] == ("FL", "FR")
    assert a["mean_slip_diff"] == pytest.approx(-0.01, abs=0.001)
    d, ho = _slip_stub(0.0)
    assert wheel_asymmetry(d, ho) is None


def _slip_parts_stub(mu, y, cell, cls):
    """A slip channel on given adhesion ratios and slips (one soil class; ``eff['gain']`` scales μ)."""
    ch = SlipChannel.__new__(SlipChannel)
    ch.ncell, ch.y, ch.cell, ch.wv = 6, y, cell, np.ones(y.size)
    ch.inv = {cls.name: _CurveInverse(cls)}
    ch._frozen, ch.soil = False, cls
    ch._inputs = lambda eff: (mu * eff.get("gain", {}).get("k", 1.0), np.ones(y.size), None)
    ch._a_start = {cls.name: np.full(6, 0.7)}
    return ch


def test_slip_channel_fit_does_not_depend_on_the_previous_call():
    """Regression: the a and μ_0 solution of the previous call is a warm start only; after a call far
    away (μ_0 driven to a bound) the fit of the true inputs equals the one from the grid start (the
    cost depended on the order of a fault's grid points, and a radius error of -0.015 was fitted as
    +0.004)."""
    cls = SOIL_CLASSES["stubble"]
    rng = np.random.default_rng(7)
    n = 4000
    cell = rng.integers(0, 6, n)
    a_true = np.array([0.7, 0.65, 0.6, 0.58, 0.8, 0.72])
    s = rng.uniform(0.0, 0.2, n)
    mu = a_true[cell] * cls.g(s) + np.array([0.01, 0.02])[cell % 2]
    rows = np.ones(n, dtype=bool)
    fresh = _slip_parts_stub(mu, s, cell, cls)
    y0, p0 = fresh.parts({}, rows)
    used = _slip_parts_stub(mu, s, cell, cls)
    used.parts({"gain": {"k": 3.0}}, rows)        # far away: μ_0 on its bound, a at its clip
    y1, p1 = used.parts({}, rows)
    assert np.sum((y1 - p1) ** 2) <= np.sum((y0 - p0) ** 2) * (1 + 1e-6)
    assert np.allclose(used.mu0, fresh.mu0, atol=1e-3)


def test_reduced_diagnosis_reads_an_unphysical_a_as_a_over_the_power_share_at_the_wheels():
    """An engine-level export where only 40 % of the engine power reaches the wheels (the rest drives the
    PTO): the slip follows μ_engine by the curve with a replaced by a/φ, so a = 0.7 fits as about 1.75.
    The report says the fit gives a/φ and which shares φ a physical a would mean (here it holds 0.4)."""
    from tractionecu.diagnose.reduced import A_PLAUSIBLE, diagnose_reduced

    rng = np.random.default_rng(5)
    n = 900
    t = np.arange(n, dtype=float)
    veh = VehicleParams()
    mg = veh.mass_kg * 9.81
    a_true, share = 0.7, 0.4
    mu_soil = np.clip(0.30 + 0.15 * np.sin(t / 37.0) + 0.08 * np.sin(t / 11.0), 0.02, 0.55)
    grid = np.linspace(0, 0.6, 601)
    s = np.interp(mu_soil / a_true, SOIL_CLASSES["stubble"].g(grid), grid)
    vw = 2.0 + 0.8 * np.sin(t / 53.0) ** 2
    vg = vw * (1 - s) + rng.normal(0, 0.02, n)
    omega_e = np.full(n, 2 * math.pi * 30.0)
    fr = Frame(t=t, t0_epoch=0.0, rate_hz=1.0, vehicle=veh, v_gps=vg, v_wheel_bus=vw,
               engine_torque=mu_soil * mg * vw / share / omega_e, engine_speed=omega_e)
    rep = diagnose_reduced(fr)
    sm = rep["slip_model"]
    assert sm["a"]["value"] > A_PLAUSIBLE[1] and not sm["plausible"]
    lo, hi = sm["power_share_if_a_physical"]
    assert lo <= share <= hi
    assert "a/φ" in rep["statement"]


def test_every_term_that_changes_the_wheel_loads_acts_on_the_slip_channel():
    """The slip channel forms μ = F_x/F_z and the loaded radius from the wheel loads, the rear ones being
    the weight less the front pin's reading: a term that changes them (a mass the vehicle file lacks, an
    axle-load offset) must be in the channel's effects, or a fit of it leaves the slip channel on loads
    short by that much (a rolling-radius error beside a front mass took up Δm g on the rear)."""
    from tractionecu.diagnose.channels import SLIP_EFFECTS, wheel_kwargs
    from tractionecu.diagnose.features import wheel_state
    from tractionecu.model.effects import LIBRARY

    veh = VehicleParams()
    n = 20
    fr = Frame(t=np.arange(n) * 0.1, t0_epoch=0.0, rate_hz=10.0, vehicle=veh)
    fr.omega = np.full((n, 4), 5.0)
    fr.md = np.full((n, 4), 800.0)
    fr.fzf = np.full(n, 0.4 * veh.mass_kg * 9.81)
    base = wheel_state(fr, np.zeros((n, 4)), None)
    changes_loads = set()
    for name, d in LIBRARY.items():
        # Every parameter away from its absence: the library default, or the range's upper end.
        eff = {name: {p.name: (p.default if p.default not in (0.0, 1.0) else p.hi) for p in d.params}}
        try:
            kw = wheel_kwargs(eff, fr)
        except KeyError:
            continue
        ws = wheel_state(fr, np.zeros((n, 4)), None, **kw)
        if not np.allclose(ws.fz, base.fz):
            changes_loads.add(name)
    assert {"mass", "axle_load_offset"} <= changes_loads
    assert changes_loads <= SLIP_EFFECTS


def test_a_missing_raw_wheel_speed_is_interpolated_not_read_as_standstill():
    """A raw window without a sample (time stamps on the windows' edges) is NaN; read as 0 rad/s it made
    a slip of −0.9 that smoothing and the relaxation filter spread into valid rows (a relaxation length
    of 1.05 m fitted for 0.6 m).  It is interpolated in time from its neighbours, per wheel."""
    from tractionecu.diagnose.channels import fill_missing_raw

    t = np.arange(10) * 0.01
    x = np.column_stack([2.0 + t, 3.0 - t, np.full(10, np.nan), 1.0 + t])
    x[4, 0] = np.nan
    x[[0, 9], 3] = np.nan
    out = fill_missing_raw(t, x)
    assert out[4, 0] == pytest.approx(2.04)
    assert out[0, 3] == pytest.approx(1.01) and out[9, 3] == pytest.approx(1.08)   # held at the ends
    assert np.all(out[:, 2] == 0.0)                                                  # no sample at all
    assert np.isnan(x[4, 0])                                                         # input unchanged
    clean = np.ones((5, 4))
    assert fill_missing_raw(t[:5], clean) is clean


def test_the_nominal_wheel_torque_goes_through_the_hub_drives_declared_efficiency_and_drag():
    """The estimator drives its wheels with η M (M/η braking) less the declared drag c ω; the diagnosis's
    nominal model takes the same wheel torque.  Left at the motor torque, a machine declaring η = 0.934 read
    its wheel forces 7 % high, a pull-dependent error that the speed equation put into the mass's
    acceleration regressor.  A fitted drivetrain effect's η replaces the declared one; a machine declaring
    η = 1 and no drag, and an engine-driven one, keep the recorded torque bit for bit."""
    import dataclasses

    from tractionecu.diagnose.channels import wheel_kwargs
    from tractionecu.diagnose.features import declared_wheel_torque, wheel_state

    base = VehicleParams()
    hub = dataclasses.replace(base, drivetrain=dataclasses.replace(base.drivetrain, efficiency=0.9, hub_drag_nms=4.0))
    md = np.array([[800.0, -600.0, 0.0, 500.0]])
    om = np.array([[5.0, 5.0, 5.0, -5.0]])
    out = declared_wheel_torque(md, om, hub)
    assert out[0, 0] == pytest.approx(0.9 * 800.0 - 20.0)          # driving: η M − c ω
    assert out[0, 1] == pytest.approx(-600.0 / 0.9 - 20.0)         # braking: M/η − c ω
    assert out[0, 2] == pytest.approx(-20.0)
    assert out[0, 3] == pytest.approx(500.0 / 0.9 + 20.0)          # reversing while braking
    assert declared_wheel_torque(md, om, base) is md
    mech = dataclasses.replace(base, drivetrain=dataclasses.replace(base.drivetrain, kind="mechanical", efficiency=0.88,
                                                                            final_drive_ratio=20.0))
    assert declared_wheel_torque(md, om, mech) is md

    n = 20
    frames = []
    for veh in (base, hub):
        fr = Frame(t=np.arange(n) * 0.1, t0_epoch=0.0, rate_hz=10.0, vehicle=veh)
        fr.omega = np.full((n, 4), 5.0)
        fr.md = np.full((n, 4), 800.0)
        fr.fzf = np.full(n, 0.4 * veh.mass_kg * 9.81)
        frames.append(fr)
    ws0, ws1 = (wheel_state(fr, np.zeros((n, 4)), None) for fr in frames)
    r = ws0.r
    assert np.allclose(ws1.fh - ws0.fh, (0.9 * 800.0 - 20.0 - 800.0) / r)
    # The drivetrain effect: its η replaces the declared one (absolute), its loss replaces the drag.
    kw = wheel_kwargs({"drivetrain": {"eta": 0.95, "loss_nm": 0.0}}, frames[1])
    ws2 = wheel_state(frames[1], np.zeros((n, 4)), None, **kw)
    assert np.allclose(ws2.fh, wheel_state(frames[0], np.zeros((n, 4)), None, **kw).fh)
    assert np.allclose(ws2.fh - ws0.fh, (0.95 - 1.0) * 800.0 / r)


def test_the_relaxations_mu_rate_takes_the_wheel_torque_of_the_fitted_effects(make_recording):
    """The relaxation's lead μ̇ σ/|v| is taken from μ at the bin edges, whose torque must be the bin means' own: a
    fitted drivetrain's η (and a torque sensor's gain) scale it there as in :func:`wheel_state` (it was taken
    through the declared reduction whatever the effects said)."""
    from tractionecu.diagnose import channels, data, features

    rec = make_recording("paper-three-soils", 7, 60.0)
    feat = features.compute(data.load(rec))
    slip = next(c for c in channels.build_channels(feat) if isinstance(c, SlipChannel))
    fr = feat.frame
    assert fr.md_edge is not None
    ws = slip.wc.get({})
    base = slip._mu_dot(ws, {})
    rf = ws.r * ws.fz
    rf_e = np.concatenate([rf[:1], 0.5 * (rf[1:] + rf[:-1]), rf[-1:]])
    md_e = np.nan_to_num(fr.md_edge)
    om = np.nan_to_num(fr.omega)
    om_e = np.concatenate([om[:1], om])                    # the wheel speed at each edge, as _mu_dot takes it
    for eff, factor in (({"drivetrain": {"eta": 0.8, "loss_nm": 0.0}}, 0.8),
                        ({"torque_gain": {"k_front": 0.1, "k_rear": 0.1}}, None)):
        got = slip._mu_dot(ws, eff)
        kw = channels.wheel_kwargs(eff, fr)
        m_eff = features.wheel_torque(md_e, om_e, fr.vehicle, **kw)
        if factor is not None:
            np.testing.assert_allclose(m_eff, factor * md_e)
        expect = np.diff((m_eff - md_e) / rf_e, axis=0) / fr.dt
        np.testing.assert_allclose(got - base, expect, atol=1e-9 * float(np.abs(base).max()))
        assert np.abs(expect).max() > 1e-3 * np.abs(base).max()
