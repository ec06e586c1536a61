"""The ends of a recording, its gaps, and recordings shorter than two held-out blocks.

Regressions found by diagnosing short healthy recordings as a user would:

* the front-axle load channel smoothed the load and its regressors with a moving average that counted the
  rows past either end (and every missing row) as zeros: the last row of a 40-s ``physical-declared-exact``
  recording read −4.9 kN against the load transfer, and the channel's RMS was 520–692 N (217 N on a 414-s
  recording) against a noise of 50–84 N, reported as "Unexplained mismatch in the front-axle load";
* a recording shorter than 80 s fell into a single held-out fold (blocks of 40 s), so each fit "on the other
  fold" had no rows: the generic model's held-out reduction was NaN, with numpy warnings.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from tractionecu.diagnose.features import FOLD_BLOCK_S, held_out_folds, moving_mean


def test_moving_mean_does_not_pull_ends_and_gaps_towards_zero():
    x = np.full(50, 20000.0)
    x[20:23] = np.nan                                     # a gap: three rows without a sample
    m = moving_mean(x, 10)
    assert np.allclose(m, 20000.0)                        # the ends and the rows around the gap included
    y = np.arange(30, dtype=float)
    assert np.allclose(moving_mean(y, 5)[2:-2], y[2:-2])  # inside: the centred mean of a line is the line
    assert moving_mean(y, 5)[0] == pytest.approx(1.0)     # first row: the mean of rows 0..2
    assert np.isnan(moving_mean(np.full(5, np.nan), 3)).all()
    sparse = np.full(20, np.nan)
    sparse[::4] = 1.0                                     # one sample in four rows
    m = moving_mean(sparse, 8, min_count=2)               # windows of 8 rows hold 1 or 2 samples
    assert np.array_equal(np.isfinite(m), np.isfinite(moving_mean(sparse, 8)) & (np.convolve(
        np.isfinite(sparse), np.ones(8), mode="same") >= 2))
    assert np.allclose(m[np.isfinite(m)], 1.0)


def test_a_recording_shorter_than_two_blocks_gets_both_folds():
    for span in (10.0, 40.0, 79.0):
        t = np.arange(0.0, span, 0.1)
        f = held_out_folds(t)
        assert set(np.unique(f)) == {0, 1}
        assert 0.4 < f.mean() < 0.6
    t = np.arange(0.0, 414.0, 0.1)                        # a long recording keeps its 40-s blocks
    assert np.array_equal(held_out_folds(t), np.floor(t / FOLD_BLOCK_S).astype(np.int64) % 2)


def test_a_short_healthy_recording_has_no_unexplained_front_load(make_recording):
    from tractionecu.diagnose.engine import diagnose
    from tractionecu.diagnose.locate import per_time

    rec = make_recording("physical-declared-exact", 0, 40.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)    # "Mean of empty slice" on the empty fold
        d = diagnose(rec)
    assert set(np.unique(d.features.fold)) == {0, 1}
    ho = d.joint_heldout or (d.winner.heldout if d.winner is not None else d.null_heldout)
    idx, rt = per_time(d.problem.channels["front_load"], ho.resid["front_load"])
    t = d.features.frame.t[idx]
    edge = (t < t[0] + 1.0) | (t > t[-1] - 1.0)
    # the rows within a second of either end are no worse than the rest (they were 10–100× worse)
    assert np.sqrt(np.mean(rt[edge] ** 2)) < 2.0 * np.sqrt(np.mean(rt[~edge] ** 2))
    ow = d.open_world
    assert not ow["channels"]["front_load"]["structured"]
    assert "front-axle load" not in ow.get("statement", "")
    sse = d.null_heldout.sse
    assert all(math.isfinite(float(v)) for v in (sse.values() if isinstance(sse, dict) else [sse]))
    assert math.isfinite(ow.get("heldout_rmse_reduction", 0.0))


def test_a_recording_too_short_for_a_held_out_test_names_nothing(make_recording):
    """A 3-s start from rest (paper truth, healthy) was diagnosed "effect: axle_load_offset", held-out score 11.1:
    its four held-out blocks of 0.75 s were shorter than the 5-s window the draft channel averages its speed
    over, so the folds were not held out from each other."""
    from tractionecu.diagnose.engine import MIN_DRIVING_S, diagnose

    d = diagnose(make_recording("paper-straight", 3, 3.0))
    assert d.verdict == "untestable" and d.effect is None        # not a healthy machine's "none"
    assert not any(e["named"] for e in d.effects)
    assert d.statement.startswith("Cannot diagnose: the recording holds ")
    assert f"at least {MIN_DRIVING_S:.0f} s" in d.statement
    assert not any(c.testable for c in d.candidates)
    assert not any(e["name"] == "load_transfer" for e in d.effects)   # no heights fitted to 2.5 s of driving


def test_the_report_of_a_recording_without_channels_is_written(make_recording, tmp_path):
    """A 2-s ``henrys-slope`` start (1.2 s of driving) left no channel to test, and ``tractionecu diagnose``
    stopped with a traceback drawing the residual figure with zero rows (report.json was already written)."""
    import json

    from tractionecu.cli.main import main
    from tractionecu.diagnose.engine import diagnose

    rec = make_recording("henrys-slope", 3, 2.0)
    assert not diagnose(rec).problem.channels                     # the case: nothing to plot
    assert main(["diagnose", str(rec), "--out", str(tmp_path / "d"), "--no-estimator"]) == 4
    rep = json.loads((tmp_path / "d" / "report.json").read_text())
    assert rep["verdict"] == "untestable" and rep["statement"].startswith("Cannot diagnose")
    for png in ("residual_before_after.png", "residual_map.png", "ranking.png"):
        assert (tmp_path / "d" / png).stat().st_size > 1000


def test_a_mechanical_recording_without_draft_gets_the_engine_level_analysis(make_recording, tmp_path):
    """A mechanical tractor's bus recording without draft or axle-load sensing left the full analysis no
    channel: "Cannot diagnose: no signal in this recording carries its signature", though it carries what the
    engine-level analysis of a 1 Hz export needs (EEC1 percent torque with EC1's reference, engine speed,
    a wheel-based speed, GNSS)."""
    import json

    from tractionecu.diagnose import diagnose_path
    from tractionecu.diagnose.data import load

    rec = make_recording("mechanical-no-draft", 11, 45.0)
    fr = load(rec)
    assert fr.md is None and not fr.has("fdx") and not fr.has("fzf")   # hitch status sends draft "not available"
    # the engine torque is EEC1's percent less the declared friction percent (basic friction and accessories,
    # SPN 514) of EC1's reference torque: the simulator's engine torque less its accessories' torque, within
    # the declared friction's tolerance (1 % of the reference) and EEC1's 1 %/bit
    import tomllib

    truth = np.genfromtxt(rec / "truth.csv", delimiter=",", names=True)
    eng = tomllib.loads((rec / "truth.toml").read_text())["physical"]["drivetrain"]["mech"]["engine"]
    te_true = np.interp(fr.t + fr.t0_epoch, truth["t"], truth["engine_torque_nm"]) - eng["aux_torque_nm"]
    ok = np.isfinite(fr.engine_torque) & (te_true > 100.0)
    assert ok.sum() > 200
    assert abs(np.median(fr.engine_torque[ok] - te_true[ok])) < 0.015 * eng["reference_torque_nm"]
    rep = diagnose_path(rec, tmp_path / "d", estimator=False)
    assert any(n.startswith("engine-level analysis") for n in rep["notes"])
    assert not rep["statement"].startswith("Cannot diagnose") and rep["verdict"] == "none"
    assert rep["slip_model"]["detected"]                              # wheel slip under load, from GNSS vs wheels
    assert json.loads((tmp_path / "d" / "report.json").read_text())["slip_model"]["a"]["value"] > 0


def _nmea(body: str) -> str:
    c = 0
    for ch in body:
        c ^= ord(ch)
    return f"${body}*{c:02X}"


def test_gnss_epochs_the_gate_refuses_are_not_used(make_recording, tmp_path):
    """A receiver that marks 1 s in every 5 s invalid (RMC status V, GGA quality 0, speed 0): replay's gate
    refused those epochs, diagnosis used their speed of 0 and reported an unexplained GNSS-speed mismatch
    of 0.785 m/s RMS, 13.7 times its noise."""
    import shutil

    from tractionecu.diagnose import data as ddata

    src = make_recording("paper-three-soils", 2, 60.0)
    rec = tmp_path / "rec"
    shutil.copytree(src, rec)
    out = []
    for ln in (rec / "gps.nmea").read_text().splitlines():
        body = ln[1:ln.index("*")] if ln.startswith("$") and "*" in ln else ""
        f = body.split(",")
        if body and f[0][2:] in ("RMC", "GGA", "VTG") and f[1 if f[0][2:] != "VTG" else 0]:
            sec = None if f[0][2:] == "VTG" else float(f[1][4:])
            if f[0][2:] != "VTG" and int(sec) % 5 == 0:
                if f[0][2:] == "RMC":
                    f[2], f[7] = "V", "0.000"
                else:
                    f[6] = "0"
                ln = _nmea(",".join(f))
        out.append(ln)
    (rec / "gps.nmea").write_text("\n".join(out) + "\n")
    clean, bad = ddata.load(src), ddata.load(rec)
    assert any("GNSS epochs refused by the GNSS gate (invalid" in n for n in bad.notes)
    both = np.isfinite(clean.v_gps) & np.isfinite(bad.v_gps)
    assert np.isnan(bad.v_gps).sum() > 0.15 * bad.v_gps.size       # the refused fifth is left out
    assert np.max(np.abs(clean.v_gps[both] - bad.v_gps[both])) < 1e-9


def test_without_gnss_the_radar_stands_in_and_no_clock_skew_is_tested(make_recording, tmp_path):
    """Without gps.nmea the radar speed (GBSD) silently became 'GNSS speed' and the CAN-to-GNSS clock skew
    was scored against a speed on the CAN clock."""
    import shutil

    from tractionecu.diagnose.engine import diagnose

    rec = tmp_path / "rec"
    shutil.copytree(make_recording("paper-three-soils", 2, 60.0), rec)
    (rec / "gps.nmea").unlink()
    d = diagnose(rec)
    assert d.features.frame.v_gps_source == "radar"
    assert any("radar's ground speed (GBSD) stands in" in n for n in d.notes)
    cs = d.candidate("clock_skew")
    assert cs is not None and not cs.testable and "no GNSS" in cs.reason


def test_a_can_clock_moved_onto_gnss_time_is_said_in_the_notes(make_recording, tmp_path):
    """A capture whose CAN clock ran an hour behind the GNSS log: the reader found the offset and moved every
    CAN time by +3600 s, replay and inspect said so, diagnosis said nothing (its notes held only the altitude
    range), while it tests a CAN-to-GNSS clock skew on those times."""
    import shutil

    from tractionecu.diagnose import data as ddata

    src = make_recording("paper-three-soils", 2, 60.0)
    rec = tmp_path / "rec"
    shutil.copytree(src, rec)
    lines = (src / "can.log").read_text().splitlines()
    with open(rec / "can.log", "w") as f:
        for ln in lines:
            t = float(ln[1:ln.index(")")])
            f.write(f"({t - 3600.0:.6f}){ln[ln.index(')') + 1:]}\n")
    assert not any(n.startswith("clock:") for n in ddata.load(src).notes)
    notes = ddata.load(rec).notes
    clock = [n for n in notes if n.startswith("clock:")]
    assert len(clock) == 1 and "CAN clock offset +3599.9" in clock[0] and clock[0].endswith("applied")


def _without_draft(src, dst):
    """A copy of recording ``src`` whose capture lost its rear hitch status (PGN 65093, the draft)."""
    import shutil

    shutil.copytree(src, dst)
    lines = (src / "can.log").read_text().splitlines(keepends=True)
    kept = [ln for ln in lines if " 0CFE4582#" not in ln]
    assert len(kept) < len(lines)
    (dst / "can.log").write_text("".join(kept))
    return dst


def test_a_hub_recording_without_its_draft_is_diagnosed_not_a_traceback(make_recording, tmp_path):
    """A hub tractor's capture without the rear hitch status (the draft message not logged) ended in
    "TypeError: unsupported operand type(s) for -: 'float' and 'NoneType'" in the force balance."""
    from tractionecu.diagnose.engine import diagnose

    rec = _without_draft(make_recording("paper-three-soils", 2, 60.0), tmp_path / "rec")
    d = diagnose(rec)
    assert d.features.frame.fdx is None
    assert d.verdict in ("none", "effect", "ambiguous", "unexplained", "untestable")


def test_a_recording_replay_refuses_keeps_its_diagnosis(make_recording, tmp_path):
    """The estimator view (a second view, replay's estimator over the recording) raised replay's "the
    recording has no DraftForce" after every fit was done: exit 1, no report.json, the diagnosis lost."""
    import json

    from tractionecu.diagnose import diagnose_path

    rec = _without_draft(make_recording("paper-three-soils", 2, 60.0), tmp_path / "rec")
    rep = diagnose_path(rec, tmp_path / "out")
    assert rep["estimator"] == {"skipped": "not run: replay needs DraftForce, which this recording lacks"}
    assert "estimator view not run: replay needs DraftForce, which this recording lacks" in rep["notes"]
    assert json.loads((tmp_path / "out" / "report.json").read_text())["verdict"] == rep["verdict"]


def test_without_a_draft_signal_the_unknown_pull_is_named_as_no_fault(make_recording, tmp_path):
    """A healthy hub tractor whose hitch status was not logged: the pull, taken as zero, was taken up as
    faults, "effect: drivetrain" with η = 0.5 at its lower bound and a mass of +2140 kg (120 s of
    paper-three-soils), and on this 60-s recording, through the force-integrated ground speed the slip is
    taken against, "effect: relaxation", σ = 3.6 m.  The channels whose equation holds the pull are not
    built, and the ground speed is the spline through the GNSS speed; the slip's channels are tested."""
    from tractionecu.diagnose.engine import diagnose

    rec = _without_draft(make_recording("paper-three-soils", 2, 60.0), tmp_path / "rec")
    d = diagnose(rec)
    assert {"speed", "gps_speed", "front_load", "draft"}.isdisjoint(d.problem.channels)
    assert "slip" in d.problem.channels and d.features.v_int is not None and not d.features.v_int.any()
    assert any(n.startswith("no draft signal: the pull is unknown") for n in d.notes)
    assert d.verdict == "none" and not [e for e in d.effects if e.get("named")]


def test_without_gnss_positions_the_one_soil_is_said(make_recording, tmp_path):
    """Without its GNSS log a healthy recording of three soils came out "unexplained" (a slow resistive force,
    the soils' change) with nothing saying the field had no cells."""
    import shutil

    from tractionecu.diagnose.engine import diagnose

    rec = tmp_path / "rec"
    shutil.copytree(make_recording("paper-three-soils", 2, 60.0), rec)
    (rec / "gps.nmea").unlink()
    d = diagnose(rec)
    assert d.features.n_cells == 1
    assert any(n.startswith("no GNSS positions: the soil is taken as one for the whole recording") for n in d.notes)


def test_the_reference_torque_given_stands_in_for_a_missing_ec1_on_the_bus(make_recording, tmp_path):
    """``diagnose --reference-torque`` was read for a CSV export only: a mechanical capture without EC1 (its
    5 s broadcast before the logger started) came out "untestable", the option ignored."""
    import shutil
    import tomllib

    from tractionecu.diagnose import diagnose_path

    src = make_recording("mechanical-no-draft", 11, 45.0)
    rec = tmp_path / "no-ec1"
    shutil.copytree(src, rec)
    lines = (src / "can.log").read_text().splitlines(keepends=True)
    kept = [ln for ln in lines if not any(f" {i}#" in ln for i in ("1CEBFF00", "1CECFF00"))]   # EC1 over BAM
    assert len(kept) < len(lines)
    (rec / "can.log").write_text("".join(kept))
    assert diagnose_path(rec, tmp_path / "d0", estimator=False)["verdict"] == "untestable"
    tref = tomllib.loads((src / "truth.toml").read_text())["physical"]["drivetrain"]["mech"]["engine"][
        "reference_torque_nm"]
    rep = diagnose_path(rec, tmp_path / "d", reference_torque_nm=tref, estimator=False)
    assert rep["verdict"] == "none" and rep["slip_model"]["detected"]
    assert f"engine reference torque {tref:g} N·m as given (the bus sends no EC1)" in rep["notes"]
