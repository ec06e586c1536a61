"""Kinematics in turns, the course-against-heading direction, standstill and inputs slower than the step.

Fast and seeded: closed forms of the wheel-speed factors, the compiled model
in a turn against plain RK4, the curvature filter on a synthetic circle, the
estimator on the synthetic truth loop driven round a circle (each wheel at
its own ground speed), a short ``s-curves-30m`` recording of the physical
truth model, and a standstill whose covariance must keep growing.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from est_synth import synth_run

from tractionecu.config import VehicleParams
from tractionecu.estimation.estimator import (INVALID_MASK, KAPPA_MAX, SLIP_AVERAGED, SLIP_UNCERTAIN, STANDSTILL,
                                              Estimator, EstimatorConfig)
from tractionecu.estimation.kinematics import SLIP_DIFF_MAX, CurvatureFilter
from tractionecu.model.vehicle import (FilterModel, JIT, rk4, wheel_speed_factor_slopes, wheel_speed_factors)

VEH = VehicleParams()
B, L = VEH.track_width_m, VEH.wheelbase_m


# ----------------------------------------------------------------------------- geometry
def test_wheel_speed_factors_are_the_radii_of_a_circle():
    R = 30.0                                   # left turn of 30 m radius round the rear-axle centre
    k = wheel_speed_factors(1.0 / R, B, L)
    # each wheel's distance from the turn centre over R
    assert k[2] == pytest.approx((R - B / 2) / R) and k[3] == pytest.approx((R + B / 2) / R)
    assert k[0] == pytest.approx(math.hypot(R - B / 2, L) / R) and k[1] == pytest.approx(math.hypot(R + B / 2, L) / R)
    assert k[1] > k[3] > 1.0 > k[0] > k[2]    # outer faster, front on the larger radius
    np.testing.assert_allclose(wheel_speed_factors(-1.0 / R, B, L), k[[1, 0, 3, 2]])   # the mirror turn
    np.testing.assert_array_equal(wheel_speed_factors(0.0, B, L), np.ones(4))
    # the slopes are the derivative
    h = 1e-6
    num = (wheel_speed_factors(1 / R + h, B, L) - wheel_speed_factors(1 / R - h, B, L)) / (2 * h)
    np.testing.assert_allclose(wheel_speed_factor_slopes(1 / R, B, L), num, rtol=1e-6)


def _turn_states(rng, k):
    x = rng.normal([3, 3, 3, 3, 2.3, .3, .3, .3, .3, .06], [0.05, 0.05, 0.05, 0.05, 0.05, .05, .05, .05, .05, .01],
                   size=(21, 10))
    kap = [1 / 30.0, -1 / 30.0, 0.2, 0.0][k % 4]
    u = np.array([3000.0, 3100.0, 4000.0, 4100.0, 24000.0, 15000.0, kap])
    return x, u


@pytest.mark.skipif(not JIT, reason="compiled core not in use")
def test_compiled_step_in_a_turn_is_bitwise_rk4():
    model = FilterModel(VEH)
    rng = np.random.default_rng(3)
    for k in range(40):
        x, u = _turn_states(rng, k)
        fz, r_d = model.loads(u, x[:, 4])               # each state's loads at its own speed, held over the step
        ref = rk4(lambda y: model.rhs(y, u, fz, r_d), x, 0.01)
        assert np.array_equal(model.step(x, u, 0.01), ref)


def test_curvature_enters_the_longitudinal_balance():
    """Front forces act along the steered wheels: v̇ is lower in a turn by Σ F_h,front (1 − cos δ)/m."""
    model = FilterModel(VEH)
    x = np.array([3, 3, 3, 3, 2.3, .3, .3, .3, .3, .06])
    u0 = np.array([3000.0, 3000.0, 4000.0, 4000.0, 24000.0, 15000.0])
    u1 = np.append(u0, 1 / 30.0)
    fz, r_d = model.loads(u0)                            # the axle split: the steering term alone
    d0, d1 = model.rhs(x, u0), model.rhs(x, u1, fz, r_d)
    c = model.front_cosines(1 / 30.0)
    assert d1[4] - d0[4] == pytest.approx(-(0.3 * fz[0] * ((1 - c[0]) + (1 - c[1]))) / VEH.mass_kg, rel=1e-9)
    np.testing.assert_array_equal(d1[:4], d0[:4])
    np.testing.assert_array_equal(model.rhs(x, np.append(u0, 0.0)), d0)      # κ = 0 is the paper's model


# ----------------------------------------------------------------------------- curvature filter
def _circle(cf: CurvatureFilter, kappa: float, v: float, slip_diff: float, course_sigma: float, seconds: float,
            rng, gnss: bool = True, direction: float = 1.0) -> None:
    """Drive cf round a circle: rear wheels at 100 Hz with a slip difference, GNSS course at 10 Hz."""
    r = 0.78
    psi = 0.3                                            # heading, counter-clockwise from east
    for k in range(int(seconds * 100)):
        t = k * 0.01
        psi += v * kappa * 0.01
        v_rl, v_rr = v * (1 - kappa * B / 2), v * (1 + kappa * B / 2)
        w_rl = v_rl / (r * (1 - 0.05))
        w_rr = v_rr / (r * (1 - 0.05 - slip_diff))
        cf.wheels(t, w_rl + 1e-3 * rng.standard_normal(), w_rr + 1e-3 * rng.standard_normal(), 1e-6, 1e-6, v)
        if gnss and k % 10 == 9:
            course = math.degrees(math.pi / 2 - psi) + (180.0 if direction < 0 else 0.0)
            cf.course(t, course + math.degrees(course_sigma) * rng.standard_normal(), abs(v), direction)


def _course_turns_wheels_do_not(cf: CurvatureFilter, legs, rng) -> list[float]:
    """Drive cf along ``legs`` of (seconds, v [m/s], course rate [rad/s]) with equal rear wheel speeds (the
    wheels show no turn) at 100 Hz and a GNSS course turning at the leg's rate at 10 Hz; β after each step."""
    psi, t = 0.0, 0.0
    beta = []
    for seconds, v, rate in legs:
        for k in range(int(seconds * 100)):
            t += 0.01
            psi += rate * 0.01
            w = v / 0.78
            cf.wheels(t, w + 1e-3 * rng.standard_normal(), w + 1e-3 * rng.standard_normal(), 1e-6, 1e-6, v)
            if k % 10 == 9:
                course = math.degrees(math.pi / 2 - psi) + (180.0 if v < 0 else 0.0)
                cf.course(t, course + 0.5 * rng.standard_normal(), abs(v), math.copysign(1.0, v))
            beta.append(cf.beta)
    return beta


@pytest.mark.parametrize("v", [2.5, -1.0])
def test_curvature_from_wheels_and_course_removes_the_slip_difference(v):
    rng = np.random.default_rng(5)
    cf = CurvatureFilter(B, 0.05)
    kappa = 1 / 30.0
    _circle(cf, kappa, v, 0.01, 0.05 / abs(v), 60.0, rng, direction=math.copysign(1.0, v))
    k, var = cf.curvature(v, 0.2)
    # the wheels alone read κ + Δs/b (0.0056 1/m too much); the course removes that bias
    assert abs(cf.kappa_w - kappa) > 0.004
    assert abs(k - kappa) < 0.0015 and abs(k - kappa) < 3.0 * math.sqrt(var)
    assert math.sqrt(var) < 0.006


def test_curvature_without_gnss_uses_the_wheels_and_says_so():
    rng = np.random.default_rng(6)
    cf = CurvatureFilter(B, 0.05)
    _circle(cf, 1 / 30.0, 2.5, 0.0, 0.02, 30.0, rng, gnss=False)
    k, var = cf.curvature(2.5, 0.2)
    assert abs(k - 1 / 30.0) < 0.0005          # equal slips: the wheel ratio is the curvature
    # the bias is not checked: σ is the slip difference's whole stationary spread, SLIP_DIFF_MAX over b
    assert math.sqrt(var) >= SLIP_DIFF_MAX / B
    assert cf.curvature(0.05, 0.2) == (0.0, math.inf)            # at standstill κ = ψ̇/v is not defined


def test_an_unknown_speed_moves_no_heading():
    # regression: a hub recording without GNSS and without the axle load has no speed for the rolling
    # radius (v None); the filter raised TypeError on abs(None) in its prediction
    cf = CurvatureFilter(B, 0.05)
    cf.wheels(0.0, 10.0, 10.2, 1e-4, 1e-4, None)
    cf.wheels(0.01, 10.0, 10.2, 1e-4, 1e-4, math.nan)
    cf.wheels(0.02, 10.0, 10.2, 1e-4, 1e-4, None)
    assert cf.v == 0.0 and cf.beta == 0.0
    assert cf.kappa_w == pytest.approx(2.0 / B * 0.2 / 20.2, rel=0.05)


def test_the_bias_grows_back_to_its_spread_when_the_course_is_lost():
    """With the course the bias is known to well inside its stationary spread; once the course is lost
    its σ grows again, with the distance travelled, towards that spread and never beyond it."""
    rng = np.random.default_rng(9)
    cf = CurvatureFilter(B, 0.05)
    _circle(cf, 1 / 30.0, 2.5, 0.005, 0.02, 60.0, rng)
    sd = [math.sqrt(cf.P[2])]
    assert sd[0] < 0.6 * SLIP_DIFF_MAX / B
    for _ in range(4):
        _circle(cf, 1 / 30.0, 2.5, 0.005, 0.02, 10.0, rng, gnss=False)
        sd.append(math.sqrt(cf.P[2]))
    assert all(b > a for a, b in zip(sd, sd[1:]))
    assert sd[-1] <= SLIP_DIFF_MAX / B


def test_a_course_the_wheels_do_not_follow_bends_no_wheel_for_long():
    """Wheels that show no turn while the course turns (the paper truth's turns: every wheel at v): no slip
    difference explains a 9 m radius, so the bias may not take it up.  With a random-walk bias it did
    (|β| ≈ 0.11 1/m, 20 σ of its spread, after a quarter circle) and bent the wheels' ground speeds by ±10 %
    long after the turn; the bounded bias stays within a few σ of its spread."""
    rng = np.random.default_rng(10)
    cf = CurvatureFilter(B, 0.05)
    beta = _course_turns_wheels_do_not(cf, [(20.0, 2.5, 0.0), (13.0, 1.2, 1.2 / 9.0)], rng)
    assert np.max(np.abs(beta)) < 4.0 * SLIP_DIFF_MAX / B


def test_standstill_forgets_the_slip_difference():
    """At standstill there is no slip and so no slip difference: β returns to 0 with its stationary variance
    (the heading is kept); moving off, the curvature is the wheels' again."""
    rng = np.random.default_rng(11)
    cf = CurvatureFilter(B, 0.05)
    _circle(cf, 1 / 30.0, 2.5, 0.01, 0.02, 60.0, rng)
    h = cf.h
    assert abs(cf.beta) > 0.5 * SLIP_DIFF_MAX / B and cf.P[2] < (SLIP_DIFF_MAX / B) ** 2
    cf.standstill()
    assert cf.beta == 0.0 and cf.P[1] == 0.0 and cf.P[2] == pytest.approx((SLIP_DIFF_MAX / B) ** 2)
    assert cf.h == h
    assert cf.curvature(1.0, 0.2)[0] == cf.kappa_w


def test_course_against_heading_tells_the_direction():
    rng = np.random.default_rng(7)
    cf = CurvatureFilter(B, 0.05)
    _circle(cf, 0.0, 2.5, 0.0, 0.02, 10.0, rng)                 # heading known from the forward course
    heading_course = math.degrees(math.pi / 2 - 0.3)
    assert cf.course_direction(heading_course + 3.0, 1.0) == 1.0
    assert cf.course_direction(heading_course + 183.0, 1.0) == -1.0
    assert cf.course_direction(heading_course + 90.0, 1.0) == 0.0
    assert CurvatureFilter(B, 0.05).course_direction(heading_course, 1.0) == 0.0     # no heading yet


def test_s_curve_transitions_leave_no_bias():
    """Arcs of 30 m radius turning alternately left and right, joined by 1 s clothoids, with equal slips on
    both wheels and the true course: there is no slip difference to find.  The heading integrates the
    unfiltered wheel curvature, so the low pass's lag in the transitions is no heading error that the
    course would explain as a bias (integrating the low-passed term gave a mean |β| of 0.0013 1/m and a
    curvature error of 0.0021 1/m here; the arcs' own curvature was then wrong between transitions)."""
    rng = np.random.default_rng(12)
    cf = CurvatureFilter(B, 0.05)
    v, r, dt = 2.5, 0.78, 0.01
    psi = t = kap = 0.0
    errs, betas = [], []
    for n in range(12):
        sgn = 1.0 if n % 2 == 0 else -1.0
        for kind, steps in (("ramp", 100), ("hold", int(12.0 / v / dt))):
            k0 = kap
            for i in range(steps):
                t += dt
                kap = k0 + (sgn / 30.0 - k0) * (i + 1) / steps if kind == "ramp" else sgn / 30.0
                psi += v * kap * dt
                wl, wr = v * (1 - kap * B / 2) / r, v * (1 + kap * B / 2) / r
                cf.wheels(t, wl * (1 + 1e-3 * rng.standard_normal()), wr * (1 + 1e-3 * rng.standard_normal()),
                          1e-5, 1e-5, v)
                if int(round(t / dt)) % 10 == 0:
                    cf.course(t, math.degrees(math.pi / 2 - psi), v, 1.0)
                if t > 20.0:
                    errs.append(cf.curvature(v, 0.2)[0] - kap)
                    betas.append(cf.beta)
    assert np.mean(np.abs(betas)) < 3e-4
    assert np.mean(np.abs(errs)) < 1e-3


# ----------------------------------------------------------------------------- the estimator in a turn
def _turning(run, kappa_turn: float, course: bool = True, t_from: float = 0.0):
    """The synthetic straight run bent round a circle of curvature κ (from ``t_from`` [s] on, straight before):
    each wheel's speed scaled by its ground-speed factor (same slip per wheel) and by its axle's rolling radius
    over its own, the lateral load transfer's (δ_f, δ_r = λ_f, 1 − λ_f of m v² κ h_cg/b moved to the outer
    wheels, eq. 9), the GNSS course turning at v κ."""
    from tractionecu.model.vehicle import rolling_radius

    out = []
    fzf = VEH.static_front_load_n()
    psi = 0.0
    t_prev = 0.0
    vi = 0
    for t, inputs, meas in run.steps:
        kappa = kappa_turn if t >= t_from else 0.0
        k = wheel_speed_factors(kappa, B, L)
        while vi + 1 < len(run.t) and run.t[vi + 1] <= t:
            vi += 1
        psi += run.v[vi] * kappa * (t - t_prev)
        t_prev = t
        m = dict(meas)
        fzf = inputs.get("Fzf", fzf)                                  # the held front-axle load
        ff, fr = 0.5 * fzf, 0.5 * (VEH.weight_n - fzf)
        moment = VEH.mass_kg * run.v[vi] ** 2 * kappa * VEH.cg_height_m / B
        df, dr = VEH.front_roll_share * moment, (1.0 - VEH.front_roll_share) * moment
        axle = rolling_radius(np.array([ff, ff, fr, fr]), VEH)
        own = rolling_radius(np.array([ff - df, ff + df, fr - dr, fr + dr]), VEH)
        m["omega"] = np.asarray(meas["omega"]) * k * (axle / own)
        if course and "v" in meas:
            m["course"] = (90.0 - math.degrees(psi)) % 360.0
        out.append((t, inputs, m))
    return out


@pytest.fixture(scope="module")
def run20():
    return synth_run(seed=11, duration=20.0)


def test_per_wheel_slip_in_a_turn(run20):
    """Round a 30 m circle each wheel's slip is as accurate as on the straight (the truth's slip per
    wheel is the same in both runs); without the curvature the outer wheels read about ±κb/2 of slip
    too much or too little."""
    kappa = 1 / 30.0
    n0 = int(10.0 / 0.01)

    def slip_error(steps, no_curvature=False):
        est = Estimator(VEH)
        if no_curvature:
            est._kin.curvature = lambda v, m: (0.0, math.inf)          # type: ignore[method-assign]
        got = [est.step(*s) for s in steps]
        slip = np.array([e.slip for e in got[n0:]])
        return np.abs(slip - run20.slip[n0:len(got)]).mean(axis=0), np.array([e.kappa for e in got[n0:]])

    straight, _ = slip_error(run20.steps)
    turn, kap = slip_error(_turning(run20, kappa))
    assert abs(np.median(kap) - kappa) < 0.001
    assert (turn <= 1.05 * straight + 3e-4).all()
    flat, _ = slip_error(_turning(run20, kappa), no_curvature=True)
    assert (flat > straight + 0.01).all()


def test_slip_not_supported_where_the_curvature_is_clipped(run20):
    """Round a 3 m circle (κ = 0.33 1/m: a headland turn between passes 6 m apart) the curvature input is
    clipped at KAPPA_MAX, the wheels' ground speeds k_i(κ)·v of eq. 6 are not known, and a slip taken with the
    clipped κ is off by about 0.1 on the front wheels: every step at the clip is flagged SLIP_UNCERTAIN (never
    SLIP_AVERAGED) and holds the last supported slip of the straight before, and no (μ, s) pair of a clipped step
    goes to the μ(s) curve (regression: the curve's pairs were gated by the slip's σ alone there, and 92 of 119
    updates round such a circle took slips off by up to 0.18).  Round a 30 m circle nothing is clipped and the
    slip is reported as on the straight."""
    n0 = int(10.0 / 0.01)
    fed: list[float] = []

    def run(steps):
        est = Estimator(VEH)
        upd = est._curve.update

        def update(t, *args, **kw):
            fed.append(t)
            return upd(t, *args, **kw)

        est._curve.update = update                                 # type: ignore[method-assign]
        return [est.step(*s) for s in steps]

    tight = run(_turning(run20, 1 / 3.0, t_from=10.0))
    fed_t = set(fed)
    kap = np.array([e.kappa for e in tight])
    st = np.array([e.status for e in tight])
    slip = np.array([e.slip for e in tight])
    clipped = np.abs(kap) >= KAPPA_MAX
    assert not clipped[:n0].any() and clipped[n0:].mean() > 0.8
    assert (st[clipped] & SLIP_UNCERTAIN).all()
    assert not (st[clipped] & SLIP_AVERAGED).any()
    first = int(np.flatnonzero(clipped)[0])
    end = first + int(np.argmin(clipped[first:])) if not clipped[first:].all() else len(clipped)
    last = int(np.flatnonzero((st[:first] & SLIP_UNCERTAIN) == 0)[-1])
    assert end - first > 500 and first - last < 300
    assert (slip[first:end] == slip[last]).all()                   # the last supported slip, held
    t_steps = np.array([e.t for e in tight])
    assert len(fed_t & set(t_steps[~clipped])) > 20                # the curve is fed off the clip
    assert not fed_t & set(t_steps[clipped])                       # and never at it
    for steps in (run20.steps, _turning(run20, 1 / 30.0)):
        wide = run(steps)
        assert max(abs(e.kappa) for e in wide) < KAPPA_MAX
        assert not any(e.status & SLIP_UNCERTAIN for e in wide[n0:])


def test_s_curves_physical_left_right_slip_difference(make_recording):
    """On the physical truth model's S-curves (30 m radius) the left-right slip difference of each axle
    (free of the rolling-radius error, which is the same on both sides) follows the truth."""
    from tractionecu.evaluation.scoring import read_truth
    from tractionecu.pipeline.replay import replay
    from tractionecu.recording.reader import read_recording

    rec_dir = make_recording("s-curves-30m", 2, 60.0)
    res = replay(read_recording(rec_dir))
    a = res.arrays
    tr = read_truth(rec_dir / "truth.csv")
    k = np.clip(np.searchsorted(tr.t, a["t"] + 1e-9, side="right") - 1, 0, len(tr.t) - 1)
    m = a["valid"] & (np.abs(tr.v[k]) > 1.0)
    assert m.sum() > 2000
    se, st = a["slip"][m], tr.slip[k][m]
    for i, j in ((0, 1), (2, 3)):
        assert np.mean(np.abs((se[:, j] - se[:, i]) - (st[:, j] - st[:, i]))) < 0.008


# ----------------------------------------------------------------------------- standstill
def test_standstill_holds_flags_and_the_covariance_keeps_growing(run20):
    """At v = 0 the data cannot support ρ_s or slip: STANDSTILL, not valid, the last moving values held,
    and the filter's variance of ρ_s and of μ grows step after step."""
    est = Estimator(VEH)
    for s in run20.steps:
        e = est.step(*s)
    assert e.valid
    t0, last_in, last_meas = run20.steps[-1]
    om, md = np.asarray(last_meas["omega"]), np.asarray(last_in["Md"])
    v0 = float(run20.v[-1])
    fzf = VEH.static_front_load_n()
    held = None
    p_rho = []
    for k in range(1, 1301):                       # 3 s braking to a stop, then 10 s standing
        t = t0 + 0.01 * k
        f = max(0.0, 1.0 - k / 300.0)
        meas = {"omega": om * f}
        if k % 10 == 0:
            meas["v"] = v0 * f
        e = est.step(t, {"Md": md * f, "Fzf": fzf, "Fdx": 15000.0 * f}, meas)
        if k <= 300:
            continue
        assert e.status & STANDSTILL and not e.valid
        if held is None:
            held = (e.rho_s, e.slip.copy())
        assert e.rho_s == held[0] and np.array_equal(e.slip, held[1])
        p_rho.append(e.P_diag[9])
        assert est._kin.beta == 0.0 and est._kin.P[2] == est._kin.var_beta     # no slip difference standing
    p_rho = np.array(p_rho)
    # the variance of ρ_s grows on every step, past the convergence bound: after 10 s standing the filter
    # itself no longer claims to know ρ_s
    assert (np.diff(p_rho) > 0).all() and p_rho[-1] > EstimatorConfig().conv_sigma_rho ** 2


def test_creeping_slip_is_flagged_held_and_not_fed_to_the_curve(run20):
    """Slowing from 2.4 m/s to a creep of 0.5 m/s: the filter's σ_v over |v| becomes a slip uncertainty
    above ``slip_sigma_max``; slip is then flagged (0x2000), held at the last supported value, and no
    (μ, s) pair reaches the curve; at work speed the bit is clear.  The bit alone does not invalidate the
    estimate (μ and ρ_s do not rest on the slip)."""
    assert SLIP_UNCERTAIN & INVALID_MASK == 0
    est = Estimator(VEH)
    for s in run20.steps:
        e = est.step(*s)
    assert not e.status & SLIP_UNCERTAIN and e.valid
    sig_work = math.sqrt(e.P_diag[4]) / abs(e.v)
    assert sig_work < EstimatorConfig().slip_sigma_max
    calls = []
    update = est._curve.update
    est._curve.update = lambda *a, **k: calls.append(a[0]) or update(*a, **k)      # type: ignore[method-assign]
    t0, last_in, last_meas = run20.steps[-1]
    om, md = np.asarray(last_meas["omega"]), np.asarray(last_in["Md"])
    v0 = float(run20.v[-1])
    fzf = VEH.static_front_load_n()
    flagged = []
    held = None
    for k in range(1, 801):                        # 3 s slowing to a fifth, then 5 s creeping
        t = t0 + 0.01 * k
        f = max(0.2, 1.0 - 0.8 * k / 300.0)
        meas = {"omega": om * f}
        if k % 10 == 0:
            meas["v"] = v0 * f
        e = est.step(t, {"Md": md * f, "Fzf": fzf, "Fdx": 15000.0 * f}, meas)
        if k > 300:
            assert not e.status & STANDSTILL
            assert e.status & SLIP_UNCERTAIN
            if held is None:
                held = e.slip.copy()
                t_flag = t
            assert np.array_equal(e.slip, held)
            flagged.append(e)
    assert not [c for c in calls if c >= t_flag]
    # the bit follows the filter's own σ of v: at a fifth of the speed σ_v/|v| is far above the bound
    assert all(math.sqrt(e.P_diag[4]) / abs(e.v) > EstimatorConfig().slip_sigma_max for e in flagged)


def _creep(est, run, f_of_k, n, rng, t0=None, gnss_sigma=0.05):
    """Continue ``run``'s last step with wheel speeds, torques and draft scaled by f_of_k(k) for n steps of
    10 ms, GNSS speed at 10 Hz with seeded white noise of gnss_sigma [m/s]: the measurements' slip stays
    that of the last step.  Returns the estimates."""
    t_last, last_in, last_meas = run.steps[-1]
    t0 = t_last if t0 is None else t0
    om, md = np.asarray(last_meas["omega"]), np.asarray(last_in["Md"])
    v0 = float(run.v[-1])
    fzf = VEH.static_front_load_n()
    out = []
    for k in range(1, n + 1):
        f = f_of_k(k)
        meas = {"omega": om * f}
        if k % 10 == 0:
            meas["v"] = abs(v0 * f + gnss_sigma * rng.standard_normal())
        out.append(est.step(t0 + 0.01 * k, {"Md": md * f, "Fzf": fzf, "Fdx": 15000.0 * f}, meas))
    return out


def test_slip_at_1_mps_is_reported_averaged_over_distance_once_its_sigma_allows(run20):
    """At 1 m/s the filter's σ_v over |v| (≈ 0.024) is above ``slip_sigma_max`` on every step, but the slip
    over the last metres is supported once enough metres have passed: the σ of a mean of the speed error,
    correlated over ``slip_avg_corr_s`` (1 s), falls below the bound after ≈ 7 s.  Those steps carry
    SLIP_AVERAGED (not SLIP_UNCERTAIN) and the average, within 0.01 of the truth's slip (the measurements'
    slip is held at the last work step's); a standstill ends the stretch (nothing new valid there), and
    after it the average needs its metres again."""
    from tractionecu.estimation.estimator import SLIP_AVERAGED
    cfg = EstimatorConfig()
    assert SLIP_AVERAGED & INVALID_MASK == 0 and SLIP_AVERAGED != SLIP_UNCERTAIN
    est = Estimator(VEH)
    for s in run20.steps:
        e = est.step(*s)
    truth = run20.slip[-1]
    rng = np.random.default_rng(5)
    f1 = 0.4                                   # ≈ 1 m/s
    es = _creep(est, run20, lambda k: max(f1, 1.0 - (1.0 - f1) * k / 200.0), 1600, rng)   # 2 s slowing, 14 s at 1 m/s
    avg = [e for e in es if e.status & SLIP_AVERAGED]
    assert len(avg) > 300
    for e in es:
        if e.status & SLIP_AVERAGED:
            assert not e.status & (SLIP_UNCERTAIN | STANDSTILL)
        else:
            assert e.status & SLIP_UNCERTAIN or abs(e.v) > 1.5        # per-step slip supported only at speed
    # at 1 m/s not before the metres are there: the mean over T s has σ·√c(T), c(7 s) ≈ 0.26 → 0.012
    t_slow = min(e.t for e in es if abs(e.v) < 1.2)
    slow = [e for e in avg if e.t > t_slow]
    assert len(slow) > 300 and min(e.t for e in slow) - t_slow > 5.0
    err = np.array([np.abs(e.slip - truth) for e in slow])
    assert err.mean() <= 0.01 and err.max() <= 3.0 * cfg.slip_sigma_max
    length, sig = est.slip_window
    assert 0.0 < length <= cfg.slip_avg_max_m and sig <= cfg.slip_sigma_max
    # stop: standstill ends the stretch; nothing averaged or valid there
    t1 = es[-1].t
    stop = _creep(est, run20, lambda k: f1 * max(0.0, 1.0 - k / 100.0), 200, rng, t0=t1)
    still = [e for e in stop if e.status & STANDSTILL]
    assert len(still) > 50 and not any(e.status & SLIP_AVERAGED or e.valid for e in still)
    # moving again: the first 3 s have too few metres for the average (σ·√c(3 s) ≈ 0.016 > 0.0125)
    again = _creep(est, run20, lambda k: f1, 300, rng, t0=stop[-1].t)
    assert not any(e.status & SLIP_AVERAGED for e in again)


def test_averaging_off_and_work_speed_are_unchanged(run20):
    """``slip_avg_max_m = 0`` switches the average off (the slip is held and flagged as before); at work
    speed, where each step's slip is supported, the estimates are the same to the bit with it on or off."""
    from tractionecu.estimation.estimator import SLIP_AVERAGED
    on, off = Estimator(VEH), Estimator(VEH, EstimatorConfig(slip_avg_max_m=0.0))
    for s in run20.steps:
        a, b = on.step(*s), off.step(*s)
        assert a.status == b.status
        for x, y in ((a.slip, b.slip), (a.mu, b.mu), (a.v, b.v), (a.rho_s, b.rho_s), (a.P_diag, b.P_diag)):
            assert np.array_equal(x, y, equal_nan=True)
    es = _creep(off, run20, lambda k: 0.4, 1500, np.random.default_rng(5))
    assert not any(e.status & SLIP_AVERAGED for e in es) and all(e.status & SLIP_UNCERTAIN for e in es[100:])


def test_a_flagged_slip_makes_no_map_pair():
    """The map's centred window takes (μ, s) pairs for its a; a slip flagged 0x2000 is a held value, so its
    sample gives no pair (weight 0), online (CentredSampler) as in replay (centred_map_values)."""
    from types import SimpleNamespace

    from tractionecu.mapping.sampler import CentredSampler, centred_map_values

    def est(status):
        return SimpleNamespace(mu=np.full(4, 0.4), slip=np.full(4, 0.08), P_diag=np.full(10, 1e-4), v=2.0,
                               valid=True, status=status, soil_class="stubble", rho_s=0.06, curve=None)

    for status, paired in ((0, True), (SLIP_UNCERTAIN, False)):
        smp = CentredSampler()
        smp.push(0.0, 47.0, 8.0, 4, 0.8, est(status))
        assert (smp._hist[-1][1] > 0).all() == paired
    n = 50
    t = np.arange(n) * 0.1
    held = np.arange(n) >= 25
    slip = np.where(held[:, None], np.nan, 0.08) * np.ones((n, 4))
    vals = centred_map_values(t, np.full((n, 4), 0.4), slip, np.full((n, 4), 1e-4), np.full(n, 2.0),
                              np.full(n, 0.06), ["stubble"] * n, half_window_s=1.0)
    assert np.isfinite(vals["a"][:10]).all() and np.isnan(vals["a"][-10:]).all()


# ----------------------------------------------------------------------------- inputs slower than the step
def _subsample(run, every: int):
    """Wheel speeds and torques only every ``every`` steps (a slower bus), the rest as recorded."""
    out = []
    for k, (t, inputs, meas) in enumerate(run.steps):
        i, m = dict(inputs), dict(meas)
        if k % every:
            i.pop("Md", None)
            m.pop("omega", None)
        out.append((t, i, m))
    return out


def test_first_order_hold_follows_the_torque_at_20_hz(run20):
    """With wheel and torque samples at 20 Hz, the first-order hold of the inputs gives μ closer to the
    truth than holding each sample (the estimate lagged the torque by more than a period)."""
    steps = _subsample(run20, 5)
    errs = []
    for foh in (True, False):
        est = Estimator(VEH)
        if not foh:
            est._first_order_hold = lambda *a: None                   # type: ignore[method-assign]
        mu = np.array([est.step(*s).mu for s in steps])
        errs.append(np.nanmean(np.abs(mu[1000:] - run20.mu[1000:len(mu)])))
    assert errs[0] < 0.95 * errs[1]


def test_every_sample_every_step_is_unchanged_by_the_hold(run20):
    """Inputs on every step: the first-order hold changes nothing (the paper's replay stays as it was)."""
    est, ref = Estimator(VEH), Estimator(VEH)
    ref._first_order_hold = lambda *a: None                            # type: ignore[method-assign]
    steps = [(t, {"Md": i["Md"], "Fzf": VEH.static_front_load_n(), "Fdx": 15000.0}, m)
             for t, i, m in run20.steps[:600]]
    for s in steps:
        a, b = est.step(*s), ref.step(*s)
        assert np.array_equal(a.mu, b.mu, equal_nan=True)


def test_curvature_is_zero_on_a_straight_line(run20):
    est = Estimator(VEH, EstimatorConfig())
    kap = [est.step(*s).kappa for s in run20.steps]
    assert np.max(np.abs(kap[300:])) < 0.01


def test_a_heading_that_refuses_the_course_starts_again():
    """Wheels that show no turn while the course turns (a truth without Ackermann wheel speeds, or a
    wrong track width) push the bias far out and the heading away from the course; once the course is
    refused epoch after epoch the heading restarts from it, and on the straight that follows the
    curvature is back near zero."""
    rng = np.random.default_rng(8)
    cf = CurvatureFilter(B, 0.05)
    # a headland as in headland-reverse: quarter circle, 12 m back, quarter circle; twice
    legs = [(20.0, 2.5, 0.0)] + [(8.0, 1.2, math.pi / 16.0), (12.0, -1.0, 0.0), (8.0, 1.2, math.pi / 16.0),
                                 (20.0, 2.5, 0.0)] * 2
    _course_turns_wheels_do_not(cf, legs, rng)
    k_end, _ = cf.curvature(2.5, 0.2)
    assert abs(k_end) < 0.003


def test_straight_reverse_reads_no_curvature(make_recording, monkeypatch):
    """physical-headland-reverse: on the straight 12 m leg back after a three-point turn's quarter circle the
    curvature filter reads a straight path.  With the truth's steering smoothed across the cusp (its wheels'
    yaw 0.1 rad off its course over the turn) the filter took the disagreement up as a rear slip difference
    and read 0.006 1/m (1.5-4 σ_κ) on the straight leg, ±0.005 of left/right slip."""
    from tractionecu.evaluation.scoring import read_truth
    from tractionecu.pipeline.replay import replay
    from tractionecu.recording.reader import read_recording

    seen: list[tuple[float, float]] = []
    orig = CurvatureFilter.curvature

    def curvature(self, v, min_speed_mps):
        out = orig(self, v, min_speed_mps)
        seen.append((self._t, out[0]))
        return out

    monkeypatch.setattr(CurvatureFilter, "curvature", curvature)
    rec_dir = make_recording("physical-headland-reverse", 0, 135.0)
    replay(read_recording(rec_dir))
    tr = read_truth(rec_dir / "truth.csv")
    t, kap = np.array(seen).T
    k = np.clip(np.searchsorted(tr.t, t + 1e-9, side="right") - 1, 0, len(tr.t) - 1)
    head = (rec_dir / "truth.csv").read_text(encoding="utf-8").split("\n", 1)[0].split(",")
    kt = np.loadtxt(rec_dir / "truth.csv", delimiter=",", skiprows=1, usecols=[head.index("curvature")])[k]
    leg = (tr.v[k] < -0.8) & (kt == 0.0)
    assert leg.sum() > 500
    assert np.mean(np.abs(kap[leg])) < 0.002          # 0.0060 1/m with the cusp's yaw in the truth


def test_reversing_slip_is_averaged_only_in_steady_travel(make_recording):
    """physical-headland-reverse: a slip averaged over the last metres stands for the slip now only while the
    wheels roll steadily.  Where a leg starts or stops the truth's slip swings by 0.03-0.05 within a second
    while μ hardly moves, so the lag term does not see it (the averaged slips there were off by 0.018)."""
    from tractionecu.estimation.estimator import SLIP_AVERAGED
    from tractionecu.evaluation.scoring import read_truth
    from tractionecu.pipeline.replay import replay
    from tractionecu.recording.reader import read_recording

    rec_dir = make_recording("physical-headland-reverse", 0, 135.0)
    a = replay(read_recording(rec_dir)).arrays
    tr = read_truth(rec_dir / "truth.csv")
    k = np.clip(np.searchsorted(tr.t, a["t"] + 1e-9, side="right") - 1, 0, len(tr.t) - 1)
    avg = a["valid"] & ((a["status"] & SLIP_AVERAGED) != 0) & (tr.v[k] < -0.5)
    assert avg.sum() > 50
    accel = np.abs(np.gradient(tr.v, tr.t))[k]
    assert np.sum(avg & (accel > 0.05)) <= 0.02 * avg.sum()
    assert np.mean(np.abs(a["slip"][avg] - tr.slip[k][avg])) < 0.006


def test_slip_window_keeps_the_steadiness_look_back_when_trimmed(run20):
    """The averaged slip's window drops what no distance window reaches any more (past 4096 entries), but never
    the entries of the last SLIP_STEADY_S, which the steadiness test looks back over: at 12 m/s a second is more
    than ``slip_avg_max_m`` (10 m), and a trim by distance alone would leave the test a shorter look-back than
    the compiled loop's, which keeps the same rows."""
    from tractionecu.estimation.estimator import SLIP_STEADY_S

    est = Estimator(VEH)
    for s in run20.steps[:50]:
        est.step(*s)
    kw = np.ones(4)
    omega = np.full(4, 12.0 / 0.78)
    mu = np.full(4, 0.3)
    t0 = run20.steps[49][0]
    est._win_reset()
    lengths: list[int] = []
    for k in range(1, 6000):
        t = t0 + 0.01 * k
        est._slip_window(t, 12.0, kw, omega, mu, 1e-4, 0.0)
        if k > 110:
            assert est._win_t[0] <= t - SLIP_STEADY_S + 1e-9, f"step {k}"
        lengths.append(len(est._win_t))
    assert max(lengths) < 4300 and min(lengths[4100:]) < 200       # and it is still trimmed
