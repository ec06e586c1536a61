"""Never stay diverged: the monitor, the estimator's recovery, and recordings with faults.

Each recording test runs a simulated three-soil drive with one fault and
checks that the estimate is valid again within 5 s of the fault's end and
within the accuracy target (μ mean relative error ≤ 1 %) 10–30 s after it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tractionecu.estimation.divergence import DivergenceMonitor
from tractionecu.estimation.estimator import FILTER_LOST, STANDSTILL, Estimator
from tractionecu.evaluation.faults import cut, rewrite_can, shift_gnss_speed
from tractionecu.evaluation.scoring import read_truth
from tractionecu.model.vehicle import IX_RHO, IX_V
from tractionecu.pipeline.gnss import GnssGate
from tractionecu.pipeline.replay import machine_of, recording_grid, replay
from tractionecu.pipeline.steps import vector_steps
from tractionecu.recording.reader import read_recording

FAULT_AT_S = 50.0
"""Fault start after the first wheel-speed frame [s] (the machine works on the first soil then)."""


# ----------------------------------------------------------------------------- the monitor alone
def _monitor() -> DivergenceMonitor:
    return DivergenceMonitor(lost_after_s=1.0, nis_alpha=1e-6, rho_max=0.5, min_speed_mps=0.2)


# (wheel speeds outside the gate?, ground speed outside the gate?); None: not in this update
W_OK, W_GATED, NONE = (False, None), (True, None), (None, None)
BOTH_OK, GROUND_GATED = (False, False), (False, True)


def test_monitor_declares_lost_after_a_channel_refused_for_1s_and_names_its_start():
    m = _monitor()
    assert m.update(0.00, *BOTH_OK, 3.0, 5, 2.5, 2.6, 0.05) is None
    for k in range(1, 100):
        # the ground speed refused at 10 Hz, the wheel speeds accepted at 100 Hz in between
        gated = GROUND_GATED if k % 10 == 0 else W_OK
        assert m.update(0.01 * k, *gated, 2.0, 4, 2.5, 2.6, 0.05) is None
    assert m.update(1.10, *GROUND_GATED, 2.0, 4, 2.5, 2.6, 0.05) == pytest.approx(0.10)


def test_monitor_an_accepted_update_ends_the_run_and_steps_without_update_do_not():
    m = _monitor()
    for k in range(50):
        assert m.update(0.01 * k, *W_GATED, np.nan, 0, 2.5, 2.6, 0.05) is None
    assert m.update(0.5, *W_OK, 4.0, 4, 2.5, 2.6, 0.05) is None            # accepted: run over
    for k in range(51, 149):
        assert m.update(0.01 * k, *NONE, np.nan, 0, 2.5, 2.6, 0.05) is None  # predict only
    assert m.update(1.49, *W_GATED, np.nan, 0, 2.5, 2.6, 0.05) is None


def test_monitor_nis_far_out_on_every_update():
    m = _monitor()
    for k in range(100):
        assert m.update(0.01 * k, *W_OK, 1e3, 4, 2.5, 2.6, 0.05) is None
    assert m.update(1.0, *W_OK, 1e3, 4, 2.5, 2.6, 0.05) == 0.0
    m = _monitor()
    for k in range(300):                                              # an ordinary 1-in-20 NIS excursion
        assert m.update(0.01 * k, *W_OK, 12.0 if k % 20 == 0 else 3.0, 4, 2.5, 2.6, 0.05) is None


def test_monitor_speed_envelope_and_rho_bound():
    m = _monitor()
    assert m.update(0.0, *BOTH_OK, 3.0, 5, -0.8, 1.0, 0.05) == 0.0          # vehicle backwards, wheels forwards
    assert m.update(0.0, *BOTH_OK, 3.0, 5, 0.1, -1.0, 0.05) is None          # below the speed threshold
    for k in range(100):
        assert m.update(0.01 * k, *BOTH_OK, 3.0, 5, 2.0, 2.1, 0.47) is None  # ρ_s near its bound...
    assert m.update(1.0, *BOTH_OK, 3.0, 5, 2.0, 2.1, 0.5) == 0.0             # ...for 1 s while moving
    m = _monitor()
    for k in range(300):                                                    # standing: ρ_s unobservable
        assert m.update(0.01 * k, *BOTH_OK, 3.0, 5, 0.0, 0.0, 0.5) is None


# ----------------------------------------------------------------------------- recordings
@pytest.fixture(scope="module")
def base(make_recording) -> Path:
    return make_recording("paper-three-soils", 1, 90.0)


def _t0(rec_dir: Path) -> float:
    return float(read_recording(rec_dir).signals["WheelSpeed_FL"].t[0])


def _mu_rel_error(rec, arrays) -> np.ndarray:
    """Per-step mean over the wheels of |μ̂ − μ| / |μ| against the truth."""
    tr = read_truth(rec.truth_csv_path, rec.truth_toml_path)
    k = np.clip(np.searchsorted(tr.t, arrays["t"] + 1e-9, side="right") - 1, 0, len(tr.t) - 1)
    mu = tr.mu[k]
    return np.mean(np.abs(arrays["mu"] - mu), axis=1) / np.maximum(np.mean(np.abs(mu), axis=1), 0.05)


def _check_recovery(rec_dir: Path, fault_end: float) -> dict:
    rec = read_recording(rec_dir)
    res = replay(rec)
    a = res.arrays
    t, valid = a["t"], a["valid"]
    after = t >= fault_end
    back = t[after & valid]
    assert back.size, "never valid again after the fault"
    assert back[0] - fault_end <= 5.0, f"valid again only {back[0] - fault_end:.2f} s after the fault"
    window = (t >= fault_end + 10.0) & (t < fault_end + 30.0)
    late = window & valid
    assert late.sum() >= 0.9 * window.sum(), "not valid 10–30 s after the fault"
    err = float(np.mean(_mu_rel_error(rec, a)[late]))
    assert err <= 0.01, f"μ error {err:.4f} 10–30 s after the fault"
    return {"back_s": float(back[0] - fault_end), "mu_err": err, "counters": res.counters}


def test_clean_recording_never_declares_the_filter_lost(base):
    res = replay(read_recording(base))
    assert res.counters["lost"] == 0
    assert not np.any(res.arrays["status"] & FILTER_LOST)


def test_recovers_from_a_2s_burst_of_wrong_wheel_speeds(base, tmp_path):
    f0 = _t0(base) + FAULT_AT_S

    def burst(t, name, values):
        if name == "TECU_WheelSpeeds" and f0 <= t < f0 + 2.0:
            return {k: (x * 1.6 if k.startswith("WheelSpeed") else x) for k, x in values.items()}
        return values

    _check_recovery(rewrite_can(base, tmp_path / "burst", burst), f0 + 2.0)


def test_recovers_from_a_1mps_gnss_speed_step(base, tmp_path):
    f0 = _t0(base) + FAULT_AT_S
    _check_recovery(shift_gnss_speed(base, tmp_path / "step", f0, f0 + 3.0, 1.0), f0 + 3.0)


def test_recovers_from_a_5s_data_gap_while_moving(base, tmp_path):
    f0 = _t0(base) + FAULT_AT_S
    out = _check_recovery(cut(base, tmp_path / "gap", f0, f0 + 5.0), f0 + 5.0)
    assert out["counters"]["gap_resets"] == 1


class _Kicked(Estimator):
    """The real estimator whose state is thrown off the vehicle once, at ``KICK_AT``, as a manoeuvre
    the model cannot follow or a sensor glitch would leave it: ``KICK`` is (state index, value)."""

    KICK_AT = np.inf
    KICK = (IX_V, -2.5)          # reversing at 2.5 m/s while the machine drives forwards

    def step(self, t, inputs=None, measurements=None):
        if t >= self.KICK_AT and self.ukf is not None and not getattr(self, "_kicked", False):
            self.ukf.x[self.KICK[0]] = self.KICK[1]
            self._kicked = True
        return super().step(t, inputs, measurements)


def test_a_filter_pushed_off_the_vehicle_is_declared_lost_and_recovers(base):
    rec = read_recording(base)
    vehicle, sensors = machine_of(rec)
    est = _Kicked(vehicle, sensors=sensors)
    grid = recording_grid(rec, 100.0)
    mask = GnssGate().track_mask(rec.gps)
    f0 = est.KICK_AT = float(grid[0]) + FAULT_AT_S
    out = [est.step(t, inputs, meas) for t, (inputs, meas)
           in zip(grid.tolist(), vector_steps(rec.signals, rec.gps.t[mask], rec.gps.speed[mask], grid))]
    lost = [e for e in out if not np.isnan(e.lost_since)]
    assert len(lost) == 1 and est.counters["lost"] == 1
    assert lost[0].t - f0 < 0.05 and lost[0].lost_since >= f0
    after = [e for e in out if e.t >= lost[0].t]
    assert after[0].status & FILTER_LOST and not after[0].valid
    first_valid = next(e for e in after if e.valid)
    assert first_valid.t - lost[0].t <= 5.0
    assert not first_valid.status & (FILTER_LOST | STANDSTILL)
    assert all(e.v > 0 for e in after if e.valid), "a valid estimate with the wrong sign of v"
    arrays = {"t": np.array([e.t for e in out]), "mu": np.array([e.mu for e in out])}
    err = _mu_rel_error(rec, arrays)
    late = (arrays["t"] >= lost[0].t + 10.0) & (arrays["t"] < lost[0].t + 30.0)
    assert float(np.mean(err[late])) <= 0.01


def test_replay_marks_the_lost_period_and_the_map_skips_it(base, tmp_path, monkeypatch):
    """ρ_s thrown to its bound: the filter slows to a crawl while the wheels turn at 2.5 m/s and the GNSS
    speed is refused (the behaviour seen after a reverse).  It is declared lost 1 s later, and the replay
    marks the lost period from its start: not valid, and no map sample comes from it."""
    import tractionecu.pipeline.rundir as pr
    from tractionecu.mapping.store import open_store

    f0 = _t0(base) + FAULT_AT_S
    monkeypatch.setattr(_Kicked, "KICK_AT", f0)
    monkeypatch.setattr(_Kicked, "KICK", (IX_RHO, 0.5))
    import tractionecu.estimation.estimator as est_mod
    monkeypatch.setattr(est_mod, "Estimator", _Kicked)       # replay builds it through pipeline.select
    seen = []
    summary, rec, res = pr.replay_to_dir(base, tmp_path / "run", on_estimate=seen.append)
    a = res.arrays
    assert res.counters["lost"] == 1
    detected = next(e for e in seen if not np.isnan(e.lost_since))
    assert detected.t - detected.lost_since >= 0.99            # found late...
    lost_rows = (a["status"] & FILTER_LOST) != 0
    t_lost = a["t"][lost_rows]
    assert t_lost[0] == pytest.approx(detected.lost_since)     # ...but marked from its start
    assert not np.any(a["valid"][lost_rows])
    assert any(e.valid for e in seen if detected.lost_since <= e.t < detected.t), \
        "the estimator had called part of the lost period valid (what the marking is for)"
    back = a["t"][(a["t"] > detected.t) & a["valid"]]
    assert back[0] - detected.t <= 5.0
    # the map accepted no sample from the lost period (the track log flags every offered sample)
    track = open_store(tmp_path / "run" / "map").track()
    accepted = track[track[:, 3] > 0, 0]
    assert accepted.size > 0.5 * summary["map_epochs"]
    assert not np.any((accepted >= t_lost[0]) & (accepted <= t_lost[-1]))


@pytest.fixture(scope="module")
def reversing(make_recording) -> Path:
    """The first pass, a three-point turn with 12 m straight back at 1 m/s, and the start of the second pass."""
    return make_recording("headland-reverse", 3, 180.0)


def test_reversing_at_a_headland(reversing):
    """Hub drives report negative wheel speeds and torques, GNSS speed is unsigned with the course turned."""
    rec = read_recording(reversing)
    res = replay(rec)
    a = res.arrays
    tr = read_truth(rec.truth_csv_path, rec.truth_toml_path)
    work_t = np.genfromtxt(rec.truth_csv_path, delimiter=",", names=True, usecols=("t", "work"))
    k = np.clip(np.searchsorted(tr.t, a["t"] + 1e-9, side="right") - 1, 0, len(tr.t) - 1)
    v_true, work, valid = tr.v[k], work_t["work"][k] > 0.5, a["valid"]
    rev = v_true < -0.5
    assert rev.sum() > 500, "the recording holds no reverse"
    # never valid with the wrong direction of travel; the reverse itself estimated with the right sign
    assert not np.any(valid & (np.sign(a["v"]) != np.sign(v_true)) & (np.abs(v_true) > 0.05))
    assert np.all(a["v"][rev & valid] < 0) and valid[rev].mean() > 0.8
    # work time: valid, and ρ_s where it is estimated
    assert valid[work].mean() >= 0.90
    assert np.mean(np.abs(a["rho_s"] - tr.rho_s[k])[valid]) <= 0.01
    # normal driving resumes when the machine is moving forwards again after the reverse
    t_resume = float(a["t"][np.flatnonzero(rev)[-1]])
    t_resume = float(a["t"][(a["t"] > t_resume) & (v_true > 0.5)][0])
    back = a["t"][(a["t"] >= t_resume) & valid]
    assert back[0] - t_resume <= 5.0
    # accuracy from 10 s on, judged in work: on the headland the implement is up and μ ≈ 0.1, where
    # 1 % is 0.001 (below what the force balance resolves; the clean drive shows the same there)
    late = (a["t"] >= t_resume + 10.0) & valid & work
    assert late.sum() > 1000
    assert float(np.mean(_mu_rel_error(rec, a)[late])) <= 0.01


def test_reversing_without_the_direction_bit_takes_the_wheels_rotation(reversing, tmp_path):
    """Without WBSD (SPN 1864) the sign of wheel rotation gives the direction: still no wrong-sign estimate."""
    rec = read_recording(rewrite_can(reversing, tmp_path / "no-wbsd", lambda t, n, v: None if n == "WBSD" else v))
    assert "WheelBasedMachineDirection" not in rec.signals
    a = replay(rec).arrays
    tr = read_truth(rec.truth_csv_path, rec.truth_toml_path)
    k = np.clip(np.searchsorted(tr.t, a["t"] + 1e-9, side="right") - 1, 0, len(tr.t) - 1)
    v_true = tr.v[k]
    assert not np.any(a["valid"] & (np.sign(a["v"]) != np.sign(v_true)) & (np.abs(v_true) > 0.05))
    assert np.all(a["v"][(v_true < -0.5) & a["valid"]] < 0)


def test_standstill_is_flagged_and_holds_rho_and_slip(reversing):
    """The machine stops for 1 s before each change of direction: there ρ_s and slip are the last
    values from moving, flagged 0x400 and not valid."""
    a = replay(read_recording(reversing)).arrays
    still = (a["status"] & STANDSTILL) != 0
    assert still.sum() > 100 and not np.any(a["valid"][still])
    starts = np.flatnonzero(np.diff(still.astype(int)) == 1) + 1
    held = 0
    for i in starts:
        if a["valid"][i - 1]:                 # entered from a valid moving estimate
            run = np.arange(i, i + int(np.argmin(still[i:])))
            assert np.all(a["rho_s"][run] == a["rho_s"][i - 1])
            assert np.all(a["slip"][run] == a["slip"][i - 1])
            held += 1
    assert held >= 1
