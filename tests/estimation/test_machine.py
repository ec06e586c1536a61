"""Machine-level estimator (tractionecu.estimation.machine) on synthetic engine-driven runs.

The plant here is a small two-axle model written for these tests (rigid MFWD with a front lead, per-wheel
μ_i = a·g(s_i), a droop-governed engine, draft), sampled at J1939 periods with noise: it checks the
estimator's bookkeeping and its machine-level claims, not the project's truth model (tractionecu.sim).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tractionecu.config import DrivetrainSpec, VehicleParams
from tractionecu.estimation.estimator import INPUT_REJECTED, NOT_CONVERGED, STATUS_NAMES, status_names
from tractionecu.estimation.machine import (DRAFT_NOT_SEPARATED, MACHINE_LEVEL, MACHINE_UNSUPPORTED, MachineEstimate,
                                            MachineEstimator)
from tractionecu.errors import EstimatorError
from tractionecu.estimation.machine_curve import D497, resolve_prior
from tractionecu.model.mucurve import SOIL_CLASSES
from tractionecu.model.vehicle import rolling_radius

STUBBLE = SOIL_CLASSES["stubble"]


def mech_vehicle(**dt) -> VehicleParams:
    spec = dict(kind="mechanical", final_drive_ratio=20.0, efficiency=0.88, front_lead=0.03)
    spec.update(dt)
    return VehicleParams(mass_kg=6300.0, drivetrain=DrivetrainSpec(**spec))


def plant(seconds: float = 60.0, *, a: float = 0.7, rho_s: float = 0.06, draft_n: float = 15000.0,
          eta_true: float = 0.88, lead: float = 0.03, gear: float = 4.0, seed: int = 1, mfwd: bool = True,
          pull_deg: float = 0.0, gear_fn=None, curve=STUBBLE):
    """Synthetic mechanical tractor at 1 kHz; returns the truth and the bus samples (t, key, value).
    ``pull_deg``: line of pull above the horizontal; its F_dx tan β (at the mean draft) loads the rear axle.
    ``gear_fn(t)``: a transmission ratio that varies (a CVT; slow, so the reflected inertia's rate term is
    left out), reported by ETC2 at its 0.001 resolution.  ``curve``: the wheels' μ(s) shape, μ_i = a·g(s_i)."""
    rng = np.random.default_rng(seed)
    veh = mech_vehicle()
    W = veh.weight_n
    i_f = veh.drivetrain.final_drive_ratio
    tref = 400.0
    fzf = 0.4 * W - draft_n * veh.hitch_height_m / veh.wheelbase_m
    fzr = W + draft_n * math.tan(math.radians(pull_deg)) - fzf
    rdf, rdr = rolling_radius(np.array([fzf / 2, fzr / 2]), veh).tolist()
    k = 1 + lead                           # the gears fix the front over rear angular speed ratio
    jw = veh.wheel_inertia_kgm2
    dt = 1e-3
    n = int(seconds / dt)
    w_set = 220.0                          # engine speed set point [rad/s] (2100 rpm)
    v, w = 0.5, 0.5 / rdr                  # start rolling
    truth = {"t": [], "mu": [], "rho_s": [], "v": [], "s_r": [], "s_f": []}
    bus = []
    i_tot = gear * i_f
    J = veh.drivetrain.engine_inertia_kgm2 * i_tot ** 2 + 2 * jw * ((1 + k * k) if mfwd else 1.0)
    t_next = {"eec1": 0.0, "etc2": 0.0, "ec1": 0.0, "ccvs": 0.0, "gbsd": 0.0, "hitch": 0.0, "gnss": 0.0}
    period = {"eec1": 0.02, "etc2": 0.1, "ec1": 1.0, "ccvs": 0.1, "gbsd": 0.1, "hitch": 0.1, "gnss": 0.1}
    for j in range(n):
        t = j * dt
        if gear_fn is not None:
            gear = float(gear_fn(t))
            i_tot = gear * i_f
            J = veh.drivetrain.engine_inertia_kgm2 * i_tot ** 2 + 2 * jw * ((1 + k * k) if mfwd else 1.0)
        dn = draft_n * (1.0 + 0.1 * math.sin(0.5 * t))
        we = w * i_tot
        pct = float(np.clip(100.0 * 0.08 * (w_set - we) + 40.0, 0.0, 100.0))   # droop governor
        M = pct / 100.0 * tref * i_tot * eta_true
        s_r = 1 - v / (rdr * w)
        s_f = 1 - v / (rdf * k * w)
        mu_r = a * float(curve.g(s_r))
        mu_f = a * float(curve.g(s_f))
        if mfwd:
            fh = mu_r * fzr + mu_f * fzf
            dw = (M - rdr * (mu_r + veh.rho_t) * fzr - k * rdf * (mu_f + veh.rho_t) * fzf) / J
        else:                                  # 2WD: the front wheels roll (F_h,f = −ρ_t F_zf)
            fh = mu_r * fzr - veh.rho_t * fzf
            dw = (M - rdr * (mu_r + veh.rho_t) * fzr) / J
        dv = (fh - dn - rho_s * W) / veh.mass_kg
        w += dt * dw
        v += dt * dv
        if j % 10 == 0:
            truth["t"].append(t)
            truth["mu"].append(fh / (fzf + fzr))
            truth["rho_s"].append(rho_s)
            truth["v"].append(v)
            truth["s_r"].append(s_r)
            truth["s_f"].append(s_f)
        for key in t_next:
            if t + 1e-9 < t_next[key]:
                continue
            t_next[key] += period[key]
            if key == "eec1":
                bus.append((t, "Te", round(pct + rng.normal(0, 1.0))))
                bus.append((t, "we", round(we * (1 + rng.normal(0, 0.001)) / (math.pi / 240)) * math.pi / 240))
            elif key == "etc2":
                bus.append((t, "gear", round(gear, 3)))
                bus.append((t, "cgear", 4.0))
            elif key == "ec1":
                bus.append((t, "Tref", tref))
            elif key == "ccvs":
                bus.append((t, "vwb", w * veh.r0_m * (1 + rng.normal(0, 0.003))))
            elif key == "gbsd":
                bus.append((t, "vr", v * (1 + rng.normal(0, 0.01))))
            elif key == "hitch":
                bus.append((t, "Fdx", round((dn + rng.normal(0, 300)) / 10) * 10))
            elif key == "gnss":
                bus.append((t, "v", v + rng.normal(0, 0.05)))
    return {k: np.array(x) for k, x in truth.items()}, bus


INPUTS = {"Te", "Tref", "gear", "Fzf", "Fdx"}


def run(est, bus, rate=100.0, drop=()):
    """Step ``est`` on a 100 Hz grid with the latest new sample of each key (the pipeline's rule)."""
    out = []
    bus = [b for b in bus if b[1] not in drop]
    j = 0
    t_end = bus[-1][0]
    for k in range(int(t_end * rate)):
        t = (k + 1) / rate
        inputs, meas = {}, {}
        while j < len(bus) and bus[j][0] <= t:
            _, key, val = bus[j]
            (inputs if key in INPUTS else meas)[key] = val
            j += 1
        out.append(est.step(t, inputs, meas))
    return out


def _truth_at(truth, t):
    i = np.clip(np.searchsorted(truth["t"], t, side="right") - 1, 0, len(truth["t"]) - 1)
    return i


@pytest.fixture(scope="module")
def synthetic():
    return plant()


def test_machine_level_mu_and_rho_s_on_a_synthetic_run(synthetic) -> None:
    truth, bus = synthetic
    est = MachineEstimator(mech_vehicle())
    out = run(est, bus)
    assert all(isinstance(e, MachineEstimate) for e in out)
    late = [e for e in out if e.t > 20.0]
    assert np.mean([e.valid for e in late]) > 0.99, {n for e in late for n in status_names(e.status)}
    i = _truth_at(truth, np.array([e.t for e in late]))
    mu = np.array([e.mu[0] for e in late])
    rel = np.abs(mu - truth["mu"][i]) / truth["mu"][i]
    assert rel.mean() < 0.03
    rho = np.array([e.rho_s for e in late])
    assert np.abs(rho - truth["rho_s"][i]).mean() < 0.015
    for e in late[::100]:
        assert e.status & MACHINE_LEVEL and not e.status & DRAFT_NOT_SEPARATED
        assert np.all(e.mu == e.mu[0])                           # one μ for the machine, on every wheel
        assert e.slip[0] == e.slip[1] and e.slip[2] == e.slip[3]  # slip per axle
    a = late[-1].a
    assert abs(a - 0.7) / 0.7 < 0.05


def test_front_slip_at_the_geared_angular_ratio(synthetic) -> None:
    """Regression: the MFWD gears fix the front over rear angular speed ratio at 1 + λ whatever the loads, so
    the lighter front axle, on its larger rolling radius, slips more than the rear by more than λ.  The
    estimator once took the ratio as (1 + λ) r_r/r_f of the loaded radii and reported the front slip
    low by about r_f/r_r − 1 (here 2.6 %; 1.2 % on mechanical-three-soils), which moved the machine's μ(s)
    pair to a lower slip."""
    truth, bus = synthetic
    late = [e for e in run(MachineEstimator(mech_vehicle()), bus) if e.t > 20.0]
    i = _truth_at(truth, np.array([e.t for e in late]))
    err_f = np.array([e.slip[0] for e in late]) - truth["s_f"][i]
    err_r = np.array([e.slip[2] for e in late]) - truth["s_r"][i]
    veh = mech_vehicle()
    fzf = 0.4 * veh.weight_n - 15000.0 * veh.hitch_height_m / veh.wheelbase_m
    rdf, rdr = rolling_radius(np.array([fzf / 2, (veh.weight_n - fzf) / 2]), veh).tolist()
    assert rdf / rdr - 1.0 > 0.02                                # the offset the old ratio would leave
    assert abs(err_f.mean()) < 0.003 and abs(err_r.mean()) < 0.003
    assert abs(err_f.mean() - err_r.mean()) < 0.002            # front and rear slip on one footing


def test_without_draft_the_sum_is_estimated_and_no_rho_s_is_reported(synthetic) -> None:
    truth, bus = synthetic
    est = MachineEstimator(mech_vehicle(), draft=False)
    out = run(est, bus, drop={"Fdx"})
    late = [e for e in out if e.t > 20.0]
    assert late and all(e.status & DRAFT_NOT_SEPARATED for e in late)
    assert all(math.isnan(e.rho_s) and math.isnan(e.P_diag[9]) for e in out)
    i = _truth_at(truth, np.array([e.t for e in late]))
    total = np.array([e.resistance for e in late])
    veh = mech_vehicle()
    dn = 15000.0 * (1 + 0.1 * np.sin(0.5 * truth["t"][i]))
    assert np.abs(total - (truth["rho_s"][i] + dn / veh.weight_n)).mean() < 0.02
    assert "rho_s_and_draft_not_separated" in status_names(late[-1].status)
    assert STATUS_NAMES[MACHINE_LEVEL] == "machine_level"


def test_learnt_gear_ratio_without_etc2(synthetic) -> None:
    truth, bus = synthetic
    est = MachineEstimator(mech_vehicle(gear_ratio="learnt"))
    out = run(est, bus, drop={"gear"})
    late = [e for e in out if e.t > 20.0]
    assert abs(late[-1].total_ratio - 80.0) / 80.0 < 0.02
    i = _truth_at(truth, np.array([e.t for e in late]))
    mu = np.array([e.mu[0] for e in late])
    assert (np.abs(mu - truth["mu"][i]) / truth["mu"][i]).mean() < 0.04


def test_without_etc2_the_bus_profile_learns_the_ratio(synthetic) -> None:
    """gear_ratio = "bus" but no ETC2 on the bus (or its ratio "not available"): the ratio is learnt from engine
    speed over wheel speed, as with gear_ratio = "learnt", also when CCVS1 is not sent in the step of an EEC1
    (the latest engine speed within PAIR_S is paired with it)."""
    truth, bus = synthetic
    no_gear = [x for x in bus if x[1] != "gear"]
    shifted = sorted(((t + 0.005 if k == "vwb" else t), k, v) for t, k, v in no_gear)   # CCVS1 not beside EEC1
    for name, b in (("absent", no_gear),
                    ("not available", [(t, k, math.nan if k == "gear" else v) for t, k, v in bus]),
                    ("CCVS1 out of phase with EEC1", shifted)):
        est = MachineEstimator(mech_vehicle())
        late = [e for e in run(est, b) if e.t > 20.0]
        assert abs(late[-1].total_ratio - 80.0) / 80.0 < 0.02, name
        i = _truth_at(truth, np.array([e.t for e in late]))
        mu = np.array([e.mu[0] for e in late])
        assert (np.abs(mu - truth["mu"][i]) / truth["mu"][i]).mean() < 0.04, name
        assert np.mean([e.valid for e in late]) > 0.95, name


def test_hub_vehicle_is_refused_and_bad_input_is_counted() -> None:
    with pytest.raises(EstimatorError, match="hub"):
        MachineEstimator(VehicleParams())
    est = MachineEstimator(mech_vehicle())
    e = est.step(0.0, {"Te": float("nan"), "Tref": -3.0, "gear": None}, {"we": -1.0, "v": float("inf")})
    assert not e.valid and est.counters["rejected_inputs"] == 1 and est.counters["rejected_measurements"] == 2


def test_declared_line_of_pull_and_calibrated_radius_set_the_loads() -> None:
    import dataclasses

    veh = dataclasses.replace(mech_vehicle(rolling_radius_m=0.78), pull_angle_deg=8.0)
    est = MachineEstimator(veh)
    est._in["Fdx"] = 20000.0
    fzf, fzr, rdf, rdr = est.loads()
    assert fzf + fzr == pytest.approx(veh.weight_n + 20000.0 * math.tan(math.radians(8.0)))
    est._in["Fdx"] = 0.0
    _, fzr0, _, rdr0 = est.loads()
    assert fzr0 == pytest.approx(0.6 * veh.weight_n) and rdr0 == pytest.approx(0.78)
    assert rdr < rdr0                                 # more load in work: eq. 9's change from the static load


def test_power_split_runs_the_machine_level_estimator_on_the_reported_ratio(synthetic) -> None:
    truth, bus = synthetic
    est = MachineEstimator(mech_vehicle(kind="power-split"))
    late = [e for e in run(est, bus) if e.t > 20.0]
    i = _truth_at(truth, np.array([e.t for e in late]))
    mu = np.array([e.mu[0] for e in late])
    assert late[-1].status & MACHINE_LEVEL and late[-1].total_ratio == pytest.approx(80.0)
    assert (np.abs(mu - truth["mu"][i]) / truth["mu"][i]).mean() < 0.03


def test_power_split_ratio_changes_are_not_gear_shifts() -> None:
    """A CVT's reported ratio changes every ETC2 frame (here a sweep of ±10 % over 20 s): that is no torque
    interruption, so μ stays supported; engine speed off the reported ratio (a slipping clutch) still is not."""
    truth, bus = plant(60.0, gear_fn=lambda t: 4.0 * (1.0 + 0.1 * math.sin(2 * math.pi * t / 20.0)), seed=7)
    est = MachineEstimator(mech_vehicle(kind="power-split"))
    out = run(est, _edit(bus, "we", 40.0, 40.5, lambda t, v: v * 1.10))
    late = [e for e in out if 20.0 < e.t < 39.9 or e.t > 43.0]
    assert np.mean([not e.status & MACHINE_UNSUPPORTED for e in late]) > 0.99
    i = _truth_at(truth, np.array([e.t for e in late]))
    mu = np.array([e.mu[0] for e in late])
    assert (np.abs(mu - truth["mu"][i]) / truth["mu"][i]).mean() < 0.04
    assert _unsupported(out, 40.11, 40.4 + est.validity.shift_hold_s - 0.05) == 1.0
    mech = [e for e in run(MachineEstimator(mech_vehicle()), bus) if e.t > 20.0]   # a gearbox: every change a shift
    assert np.mean([bool(e.status & MACHINE_UNSUPPORTED) for e in mech]) > 0.9


def _edit(bus, key, t0, t1, fn):
    return [(t, k, fn(t, v) if k == key and t0 <= t < t1 else v) for t, k, v in bus]


def _unsupported(out, t0, t1):
    sel = [e for e in out if t0 <= e.t < t1]
    return np.mean([bool(e.status & MACHINE_UNSUPPORTED) and not e.valid for e in sel])


def test_shift_and_clutch_slip_mark_mu_unsupported(synthetic) -> None:
    """An ETC2 gear change, or engine speed off the reported ratio (a slipping clutch), makes the μ
    not valid for shift_hold_s; before and after, the run stays valid."""
    truth, bus = synthetic
    bus = _edit(bus, "cgear", 30.0, 30.25, lambda t, v: 5.0)             # a gear reported and back again
    bus = _edit(bus, "we", 40.0, 40.5, lambda t, v: v * 1.10)            # engine 10 % over the wheels
    apart = sorted(((t + 0.005 if k == "vwb" else t), k, v) for t, k, v in bus)   # CCVS1 not in an EEC1's step
    for b in (bus, apart):
        est = MachineEstimator(mech_vehicle())
        hold = est.validity.shift_hold_s
        out = run(est, b)
        assert _unsupported(out, 30.05, 30.25 + hold - 0.05) == 1.0
        assert _unsupported(out, 40.11, 40.4 + hold - 0.05) == 1.0     # CCVS1 samples at 40.1 .. 40.4 s
        assert _unsupported(out, 21.0, 29.9) == 0.0 and _unsupported(out, 33.0, 39.9) == 0.0
        assert np.mean([e.valid for e in out if 43.0 < e.t < 60.0]) > 0.99
        assert est.counters["unsupported_steps"] > 0
    assert "machine_mu_unsupported" in status_names(MACHINE_UNSUPPORTED)


def test_low_net_torque_marks_mu_unsupported(synthetic) -> None:
    truth, bus = synthetic
    est = MachineEstimator(mech_vehicle())
    out = run(est, _edit(bus, "Te", 45.0, 50.0, lambda t, v: est.validity.min_net_torque_pct - 2.0))
    assert _unsupported(out, 45.1, 50.0) == 1.0 and _unsupported(out, 25.0, 44.9) == 0.0


def test_tight_turn_and_decoupled_front_axle_mark_mu_unsupported(synthetic) -> None:
    """EBC2: rear wheels apart by a turn whose front-axle path exceeds the rear's by more than
    max_front_path_excess; then the front axle slower than the coupling's ratio (an MFWD disengaged)."""
    truth, bus = synthetic
    veh = mech_vehicle()
    lk = 0.3                                             # L·κ: front path √(1 + 0.09) − 1 = 4.4 % longer
    ebc2 = []
    for t, k, v in bus:
        if k != "vwb":
            continue
        vfa = v * 1.03                                     # engaged: the front axle at the lead
        if 45.0 <= t < 55.0:
            vfa *= 0.95                                    # rolling front axle
        d = 0.5 * lk / veh.wheelbase_m * veh.track_width_m * v if 35.0 <= t < 38.0 else 0.0
        ebc2 += [(t, "vfa", vfa), (t, "rel_r", np.array([v + d - vfa, v - d - vfa]))]
    out = run(MachineEstimator(veh), sorted(bus + ebc2, key=lambda b: b[0]))
    assert _unsupported(out, 35.05, 38.9) == 1.0
    assert _unsupported(out, 25.0, 34.9) == 0.0 and _unsupported(out, 40.0, 44.9) == 0.0
    assert _unsupported(out, 48.0, 55.0) > 0.9                 # after the 3 s smoothing has seen it


def test_gnss_course_noise_is_no_turn_and_a_course_turn_still_is(synthetic) -> None:
    """The GNSS course carries its Doppler noise, σ_v/|v| per epoch (1.1° at 2.5 m/s with the receiver's
    0.05 m/s), more than a 17 m radius turns it in 0.1 s: a rate from two epochs held almost every step of
    a straight pass unsupported (0.13 % valid on a recording of an independent simulator). The window's
    slope, tested beyond its own noise, leaves the straight pass valid and still finds a tight turn."""
    truth, bus = synthetic
    rng = np.random.default_rng(5)
    veh = mech_vehicle()
    rate = 0.3                                            # [rad/s] at ~2 m/s: L·κ ≈ 0.35, beyond the 1 % excess
    course = []
    for t, k, v in bus:
        if k != "v":
            continue
        heading = 90.0 + (math.degrees(rate * (min(t, 38.0) - 35.0)) if t >= 35.0 else 0.0)
        noise = math.degrees(0.05 / max(abs(v), 0.5)) * rng.standard_normal()
        course.append((t, "course", (heading + noise) % 360.0))
    out = run(MachineEstimator(veh), sorted(bus + course, key=lambda b: b[0]))
    assert _unsupported(out, 20.0, 34.9) == 0.0 and _unsupported(out, 40.5, 60.0) == 0.0
    assert np.mean([e.valid for e in out if 20.0 < e.t < 34.9]) > 0.99
    assert _unsupported(out, 35.6, 38.9) == 1.0             # found within half the 1 s window, held 1 s after


def test_two_wheel_drive_front_rolls_and_the_rear_carries_the_torque() -> None:
    """MFWD declared disengaged (2WD): the plant's front wheels roll, the rear carries every N·m; the
    machine μ = ΣF_h/ΣF_z and the rear axle's μ(s) (a) come out right."""
    truth, bus = plant(50.0, mfwd=False, seed=3)
    est = MachineEstimator(mech_vehicle(front_drive="disengaged"))
    late = [e for e in run(est, bus) if e.t > 20.0]
    assert np.mean([e.valid for e in late]) > 0.99
    i = _truth_at(truth, np.array([e.t for e in late]))
    mu = np.array([e.mu[0] for e in late])
    assert (np.abs(mu - truth["mu"][i]) / truth["mu"][i]).mean() < 0.03
    assert all(math.isnan(e.slip[0]) for e in late)               # the front axle's slip is not modelled
    assert abs(late[-1].a - 0.7) / 0.7 < 0.05


def test_not_available_values_are_missing_samples_not_rejected_inputs() -> None:
    """J1939 "not available" / "error" decode as NaN: no sample (counted), the held value stays until its
    stream times out, the step is not predict-only; a draft without a draft sensor is not read at all."""
    est = MachineEstimator(mech_vehicle())
    est.step(0.0, {"Te": 40.0, "Tref": 400.0, "gear": 4.0, "Fdx": 15000.0}, {"we": 200.0})
    e = est.step(0.01, {"Te": math.nan, "gear": math.nan}, {"we": math.nan, "vwb": math.nan})
    assert not e.status & INPUT_REJECTED and est.counters["rejected_inputs"] == 0
    assert est.counters["not_available"] == 4 and est.counters["rejected_measurements"] == 0
    assert est._in["Te"] == 40.0 and est._in["gear"] == 4.0
    nod = MachineEstimator(mech_vehicle(), draft=False)
    e = nod.step(0.0, {"Te": 40.0, "Tref": 400.0, "gear": 4.0, "Fdx": math.nan}, {"we": 200.0})
    assert not e.status & INPUT_REJECTED and nod.counters["not_available"] == 0 and math.isnan(nod._in["Fdx"])


def test_convergence_enters_below_the_bound_and_leaves_beyond_the_efficiency_tolerance() -> None:
    """Entry at P_μ ≤ c²; once converged the estimate stays so up to c² + (σ_η/η·μ)² (the declared
    efficiency's share of μ's uncertainty) and leaves beyond it; then it re-enters only below c² again."""
    import dataclasses

    from tractionecu.estimation.config import EstimatorConfig

    est = MachineEstimator(mech_vehicle(efficiency_tolerance=0.03), dataclasses.replace(EstimatorConfig(),
                                                                                      conv_exit_factor=1.0))
    est.t_init = 0.0
    c2 = est.cfg.conv_sigma_mu ** 2
    mu = 0.4
    band = c2 + (0.03 * mu) ** 2
    seq = [(1.2 * c2, False), (0.9 * c2, True), (0.99 * band, True), (0.5 * band, True), (1.01 * band, False),
           (0.99 * band, False), (1.01 * c2, False), (0.99 * c2, True)]
    for k, (pmu, conv) in enumerate(seq):
        assert est._converged(2.0 + k, pmu, 0.0, mu) is conv, (k, pmu / c2)
    assert est._converged(0.5, 0.0, 0.0, mu) is False               # never before conv_min_s
    assert est._converged(3.0, 0.0, 2 * est.cfg.conv_sigma_rho ** 2 + 1.0, mu) is False   # ρ alike
    # the hub's conv_exit_factor is honoured: the wider of the two exit bounds applies
    hub = MachineEstimator(mech_vehicle(efficiency_tolerance=0.03))
    hub.t_init = 0.0
    f2 = hub.cfg.conv_exit_factor ** 2
    assert hub._converged(2.0, 0.9 * c2, 0.0, 0.1) and hub._converged(3.0, 0.99 * f2 * c2, 0.0, 0.1)
    assert not hub._converged(4.0, 1.01 * f2 * c2, 0.0, 0.1)
    assert hub._converged(5.0, 0.9 * c2, 0.0, 1.0) and hub._converged(6.0, 0.99 * (c2 + 0.03 ** 2), 0.0, 1.0)


def test_the_status_does_not_flicker_in_steady_work(synthetic) -> None:
    """After the first convergence a steady run stays converged: not_converged changes state at most once."""
    truth, bus = synthetic
    out = run(MachineEstimator(mech_vehicle()), bus)
    nc = np.array([bool(e.status & NOT_CONVERGED) for e in out])
    after = nc[int(np.argmin(nc)):]
    assert not after[0] and np.count_nonzero(np.diff(after.astype(int))) <= 1


def test_without_draft_the_loads_carry_the_draft_the_sum_implies() -> None:
    """No draft sensor, a line of pull of 10°: the rear axle carries F_dx tan β the bus does not report.
    The draft implied by the resistance sum (less the soil class's typical ρ_s) loads the wheels; taking it
    as 0 made μ = ΣF_h/ΣF_z read F_dx tan β / ΣF_z (about 4 %) high."""
    import dataclasses

    truth, bus = plant(60.0, pull_deg=10.0, seed=5)
    veh = dataclasses.replace(mech_vehicle(), pull_angle_deg=10.0)
    est = MachineEstimator(veh, draft=False)
    late = [e for e in run(est, bus, drop={"Fdx"}) if e.t > 20.0]
    i = _truth_at(truth, np.array([e.t for e in late]))
    mu = np.array([e.mu[0] for e in late])
    bias = np.mean((mu - truth["mu"][i]) / truth["mu"][i])
    assert abs(bias) < 0.015, bias
    assert est._fdx_est == pytest.approx(15000.0, rel=0.15)
    fzf, fzr, _, _ = est.loads()
    assert fzf + fzr == pytest.approx(veh.weight_n + est._fdx_est * math.tan(math.radians(10.0)))
    assert all(math.isnan(e.rho_s) for e in late)                       # ρ_s still never reported


def test_declared_reference_torque_stands_in_until_ec1_arrives(synthetic) -> None:
    """[drivetrain] engine_reference_torque_nm: the wheel torque is known without EC1; EC1's value, once sent,
    is the ECU's own and replaces it (also after a reset)."""
    truth, bus = synthetic
    est = MachineEstimator(mech_vehicle(engine_reference_torque_nm=400.0))
    late = [e for e in run(est, bus, drop={"Tref"}) if e.t > 20.0]
    assert np.mean([e.valid for e in late]) > 0.99
    i = _truth_at(truth, np.array([e.t for e in late]))
    assert (np.abs(np.array([e.mu[0] for e in late]) - truth["mu"][i]) / truth["mu"][i]).mean() < 0.03
    est.step(61.0, {"Tref": 410.0}, {})
    assert est._in["Tref"] == 410.0
    est.reset()
    assert est._in["Tref"] == 400.0
    assert math.isnan(MachineEstimator(mech_vehicle())._in["Tref"])


def _with_ebc2(bus, truth, veh, rolling):
    """EBC2 beside CCVS1: the front-axle speed at the coupling's lead (engaged), or at the ground speed when
    ``rolling(t)`` (the front axle disengaged); the rear wheels at the wheel-based speed."""
    out = []
    for t, k, v in bus:
        if k != "vwb":
            continue
        vfa = truth["v"][_truth_at(truth, t)] if rolling(t) else v * 1.03
        out += [(t, "vfa", vfa), (t, "rel_r", np.array([v - vfa, v - vfa]))]
    return sorted(bus + out, key=lambda b: b[0])


def test_mfwd_state_from_the_bus() -> None:
    """front_drive = "auto": a tractor driven in 2WD is recognised from EBC2 (the front axle rolls at the ground
    speed, below the coupling's ratio by λ + s_r) and estimated with the rolling front axle; a 4WD one stays
    engaged; the change is held unsupported like a shift."""
    truth, bus = plant(50.0, mfwd=False, seed=3)
    est = MachineEstimator(mech_vehicle(front_drive="auto"))
    out = run(est, _with_ebc2(bus, truth, mech_vehicle(), lambda t: True))
    late = [e for e in out if e.t > 20.0]
    assert all(not e.front_engaged for e in late) and est.counters["mfwd_changes"] == 1
    assert np.mean([e.valid for e in late]) > 0.99
    i = _truth_at(truth, np.array([e.t for e in late]))
    mu = np.array([e.mu[0] for e in late])
    assert (np.abs(mu - truth["mu"][i]) / truth["mu"][i]).mean() < 0.03
    assert abs(late[-1].a - 0.7) / 0.7 < 0.05                        # the rear axle's μ(s), as declared 2WD
    truth4, bus4 = plant(40.0, seed=3)
    est4 = MachineEstimator(mech_vehicle(front_drive="auto"))
    late4 = [e for e in run(est4, _with_ebc2(bus4, truth4, mech_vehicle(), lambda t: False)) if e.t > 20.0]
    assert all(e.front_engaged for e in late4) and est4.counters["mfwd_changes"] == 0
    assert np.mean([e.valid for e in late4]) > 0.99


def test_curve_prior_d497_is_the_brixius_slip_term_and_unknown_priors_are_refused() -> None:
    s = np.linspace(0.0, 0.5, 51)
    assert np.allclose(D497.g(s), 1.0 - np.exp(-7.5 * s))            # ASABE D497.7 GT's slip term
    assert resolve_prior("d497") is D497 and resolve_prior("tilled") is SOIL_CLASSES["tilled"]
    assert resolve_prior(None) is None
    with pytest.raises(ValueError, match="d497"):
        resolve_prior("loam")
    from tractionecu.errors import ConfigError
    from tractionecu.estimation.config import EstimatorConfig

    est = MachineEstimator(mech_vehicle(), EstimatorConfig(machine_curve_prior="d497"))   # [estimator] key
    assert est._curve.classes == [D497]
    assert MachineEstimator(mech_vehicle())._curve.classes[0] is STUBBLE                  # default: soil_classes
    with pytest.raises(ConfigError, match="machine_curve_prior"):
        EstimatorConfig(machine_curve_prior="loam")


def test_curve_prior_fits_the_machine_pairs_with_its_shape_and_reports_it() -> None:
    """Wheels on the D497 shape: with ``curve_prior="d497"`` the machine's a comes out (the effective slip
    takes the prior's g), the reported curve is a·g_d497 on the class path, and the scorer's
    representative curve reads the shape from the reported curve although ``d497`` is no surface class."""
    from tractionecu.evaluation.curve_score import identified_curve

    truth, bus = plant(50.0, a=0.8, curve=D497, seed=5)
    out = run(MachineEstimator(mech_vehicle(), curve_prior="d497"), bus)
    late = [e for e in out if e.t > 20.0 and e.valid]
    assert len(late) > 2000
    assert abs(late[-1].a - 0.8) / 0.8 < 0.05
    assert late[-1].soil_class == "d497" and late[-1].curve_path == "class:d497"
    cur = late[-1].curve
    assert cur is not None and cur.soil_class is D497
    assert cur.mu(0.2) == pytest.approx(late[-1].a * (1 - math.exp(-1.5)))
    grid = np.linspace(0.0, 0.4, 41)
    idx = np.arange(len(late))
    rep, info = identified_curve(idx, np.array([e.a for e in late]), [e.soil_class for e in late],
                                 [e.curve for e in late], grid)
    assert info["curve_path"] == "class:d497"
    assert np.allclose(rep, np.mean([e.a for e in late]) * D497.g(grid))
    # the default prior is the configured class: the same bus fitted with stubble's shape
    dflt = [e for e in run(MachineEstimator(mech_vehicle()), bus) if e.t > 20.0 and e.valid]
    assert dflt[-1].soil_class == "stubble" and dflt[-1].curve.soil_class is STUBBLE


def test_no_curve_pair_while_the_engine_torque_is_missing(synthetic) -> None:
    """Ten seconds of EEC1 "not available" fed the curve the held μ beside the moving slip: an exp1 curve at
    its α1 bound, a = 0.28 below the μ it had been fed, for the rest of the run (1 of 8 outages)."""
    from tractionecu.estimation.machine import TORQUE_TIMEOUT

    truth, bus = synthetic
    bus = [b for b in bus if not (b[1] == "Te" and 20.0 <= b[0] < 30.0)]
    est = MachineEstimator(mech_vehicle())
    fed = []
    update = est._curve.update

    def spy(t, *a, **k):
        fed.append(t)
        return update(t, *a, **k)

    est._curve.update = spy
    out = run(est, bus)
    timed_out = {round(e.t, 6) for e in out if e.status & TORQUE_TIMEOUT}
    assert len(timed_out) > 900                                   # the outage less the timeout
    assert fed and not timed_out & {round(t, 6) for t in fed}


def test_a_nan_time_is_refused_and_a_clock_stepped_back_restarts(synthetic) -> None:
    """As the hub estimator: a NaN time is a counted refusal, a clock stepped back starts again from the next
    data instead of freezing the filter with its holds and timeouts in the future."""
    truth, bus = synthetic
    est = MachineEstimator(mech_vehicle())
    first = [b for b in bus if b[0] < 30.0]
    out = run(est, first)
    e = est.step(math.nan, {}, {})
    assert not e.valid and est.counters["rejected_times"] == 1
    back = [(t - 10.0, k, v) for t, k, v in bus if t >= 30.0]
    out2 = run(est, back)
    assert est.counters["time_backwards"] == 1 and out[-1].valid
    assert np.mean([o.valid for o in out2 if o.t > 35.0]) > 0.9
