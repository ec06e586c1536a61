"""Diagnosis end to end on short simulated recordings with a concealed effect (the CI subset).

Each recording is simulated from :mod:`tractionecu.evaluation.suite`, written like a logger
would (``can.log``, ``gps.nmea``, ``vehicle.toml``) and diagnosed blind; the truth the case
knows is used only to score.
"""

import dataclasses
import json
import math
import shutil
import struct

import numpy as np
import pytest

from tractionecu.cli.main import main
from tractionecu.diagnose.engine import diagnose
from tractionecu.evaluation.suite import all_cases, export_engine_csv, score_case, write_case
from tractionecu.model.effects import EFFECTS

CASES = {c.name: c for c in all_cases()}


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    root = tmp_path_factory.mktemp("diag")
    cache = {}

    def get(name):
        if name not in cache:
            cache[name] = write_case(CASES[name], root / name)
        return cache[name]

    return get


def _png_size(path):
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", f"{path.name} is not a PNG"
    w, h = struct.unpack(">II", data[16:24])
    return w, h


def test_cli_names_a_concealed_grade_and_shows_the_fit_improve(recordings, tmp_path):
    rec = recordings("grade_henrys_fast")
    out = tmp_path / "report"
    assert main(["diagnose", str(rec), "--out", str(out)]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["verdict"] == "effect" and rep["effect"] == "grade"
    scale = rep["parameters"]["scale"]
    assert scale["ci95"][0] <= 1.0 <= scale["ci95"][1]  # the real relief, unscaled
    assert 0.7 < scale["value"] < 1.3
    speed = rep["signals"]["speed"]
    assert speed["rmse_after"] < 0.6 * speed["rmse_before"]  # held-out fit of the speed equation improves
    assert speed["nis_coverage_after"] > speed["nis_coverage_before"] + 0.2  # residuals move back to the noise level
    assert rep["candidates"][0]["name"] == "grade"
    for key in ("verdict", "effect", "candidates", "parameters", "signals"):
        assert key in rep
    for png in ("residual_before_after.png", "residual_map.png", "ranking.png"):
        w, h = _png_size(out / png)
        assert w > 300 and h > 200
    md = (out / "report.md").read_text()
    assert "grade" in md and "F_grade = m g sin θ" in md
    # The second view ran: the estimator's ρ_s track follows the slope.
    est = rep["estimator"]
    assert est["track_correlation"]["rho_s vs sin θ (grade)"] > 0.5


@pytest.mark.parametrize("name", ["load_transfer_fast", "relaxation_fast", "null_fast", "confounded_grade_one_direction"])
def test_fast_case_verdict(recordings, name):
    case = CASES[name]
    d = diagnose(recordings(name))
    row = score_case(case, d)
    assert row["correct"], row
    if name == "load_transfer_fast":
        # Load transfer is what every tractor has: part of the nominal model, not a fault; its heights
        # are reported as the nominal model's, with intervals that hold the truth.
        assert d.verdict == "none" and row["reported"] == []
        assert row["covered"]["load_transfer.h_hitch_m"] and row["covered"]["load_transfer.h_cg_m"], row["fitted"]


@pytest.mark.parametrize("name", ["null_lt_fast", "phys_null_short", "phys_wheel_dropout_short",
                                  "phys_null_reverse"])
def test_realistic_plant(recordings, name):
    """Healthy recordings of a realistic plant (the paper's model with load transfer on; the independent
    physical truth model, also reversing at a headland) name no fault; a 3-s wheel-speed dropout is found by
    the data check, located, and names nothing else."""
    case = CASES[name]
    d = diagnose(recordings(name))
    row = score_case(case, d)
    assert row["correct"], row
    rep = json.loads(json.dumps(d.effects, default=float))
    assert any(e["kind"] == "nominal" and e["name"] == "load_transfer" for e in rep)
    if name == "phys_null_reverse":
        # Regressions: (1) the GNSS speed carries no sign and the motion resistance turns with the travel;
        # taken as forward, the reverse legs broke the speed equation's nominal model (physical-headland-reverse
        # seed 5: R² 0.35, 1.9 kN RMS held out, and a mass of +3.8 t named).  (2) A clock shift that explains 0.4 % of the
        # GNSS speed's mismatch (f² 0.008) was added at the augmentation's second step, past the relevance
        # rule that kept it from being named alone.
        from tractionecu.diagnose.report import to_json

        sig = to_json(d)["signals"]["speed"]
        assert sig["r2_before"] > 0.9, sig
        assert d.verdict == "none", d.statement
        # (3) The slip of eq. 6 is positive where a wheel drives, also in reverse, while the torque balance's
        # adhesion carries the force's sign: the slip channel inverted μ(s) at −|μ| there and predicted a
        # negative slip on every reverse row (+0.017 m/s mean residual on them, none on the forward rows).
        ch = d.problem.channels["slip"]
        rows = np.ones(ch.m, dtype=bool)
        y, p = ch.parts({}, rows)
        assert ch.sg is not None
        mu_dir = ch.sg * ch.wc.get({}).mu[ch.ti, ch.wi]       # the adhesion along the wheel's rotation
        drive = (ch.sg < 0.0) & (mu_dir > 0.05)
        assert drive.sum() > 100
        assert np.mean(y[drive] / ch.wv[drive]) > 0.0 and np.mean(p[drive] / ch.wv[drive]) > 0.0
    if name == "phys_wheel_dropout_short":
        hold = [e for e in rep if e["name"] == "wheel_speed_hold"]
        assert len(hold) == 1 and hold[0]["parameters"]["wheel"]["value"] == "RL"
        assert abs(hold[0]["parameters"]["t0_s"]["value"] - 40.0) < 1.0
        assert abs(hold[0]["parameters"]["duration_s"]["value"] - 3.0) < 0.5
    if name == "confounded_grade_one_direction":
        assert d.ambiguous_between[0] == "grade"


def test_diagnosis_never_reads_the_truth(recordings, tmp_path):
    """Truth files replaced by garbage (and then removed) change nothing in the diagnosis."""
    src = recordings("load_transfer_fast")
    a = tmp_path / "a"
    shutil.copytree(src, a)
    (a / "truth.csv").write_text("garbage,that,would,break,a,reader\n1,2\n")
    (a / "truth.toml").write_text("this is = not [toml\n")
    b = tmp_path / "b"
    shutil.copytree(src, b)
    (b / "truth.csv").unlink()
    (b / "truth.toml").unlink()
    da, db = diagnose(a), diagnose(b)
    assert (da.verdict, da.effect) == (db.verdict, db.effect)
    # Every reported effect (here the nominal model's load-transfer heights) and every score agree.
    assert json.dumps(da.effects, default=float) == json.dumps(db.effects, default=float)
    assert any(e["kind"] == "nominal" for e in da.effects)
    assert [c.score for c in da.candidates] == [c.score for c in db.candidates]


def test_one_hertz_engine_export_reports_slip_and_what_cannot_be_tested(recordings, tmp_path):
    """A J1939-style 1 Hz CSV (engine percent torque, engine speed, CCVS, GNSS; no wheels, no draft)."""
    rec = recordings("null_fast")
    csv_path = export_engine_csv(rec, tmp_path / "export.csv", gear_ratio=60.0, reference_torque_nm=450.0)
    head = csv_path.read_text().splitlines()[0]
    assert "EEC1_ActualEnginePercentTorque" in head and "WheelSpeed" not in head and "Draft" not in head
    out = tmp_path / "rep"
    assert main(["diagnose", str(csv_path), "--out", str(out), "--csv-mapping", "j1939",
                 "--reference-torque", "450", "--vehicle", str(rec / "vehicle.toml")]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["verdict"] == "none"  # nothing from the library is concealed here
    sm = rep["slip_model"]
    assert sm["detected"] and sm["score"] > 10
    assert sm["a"]["ci95"][0] > 0.0
    assert "slip under load" in rep["statement"]
    g = rep["signals"]["ground_speed"]
    assert g["rmse_after"] < 0.7 * g["rmse_before"]
    untestable = {c["name"]: c["reason"] for c in rep["candidates"] if not c["testable"]}
    # nothing in the library can be told apart with these signals; each says why
    assert set(untestable) == set(EFFECTS) and all(untestable.values())
    assert "axles" in untestable["wheel_radius"]
    assert math.isfinite(sm["epsilon"]["value"])  # the offset is still fitted, as a nuisance of the slip model
    for png in ("residual_before_after.png", "residual_map.png", "ranking.png"):
        _png_size(out / png)


def test_real_engine_export_of_a_standing_machine_says_why_nothing_can_be_diagnosed(tmp_path):
    """A real CANedge log (J1939 engine bus + GNSS, engine idling, machine standing), exported at 1 Hz:
    diagnosis runs through the CSV importer and says, in the user's terms, why there is nothing to test
    (it said "fewer than 30 usable samples" of a file with 128)."""
    from pathlib import Path

    csv_path = Path(__file__).resolve().parents[1] / "data" / "csv" / "css_engine_gnss_1hz.csv"
    out = tmp_path / "rep"
    assert main(["diagnose", str(csv_path), "--out", str(out), "--csv-mapping", "j1939",
                 "--reference-torque", "1500", "--time-offset", "1635188454"]) == 4
    rep = json.loads((out / "report.json").read_text())
    assert rep["verdict"] == "untestable" and rep["effect"] is None    # a standing machine is not "healthy"
    assert "0 of 128 samples usable" in rep["statement"]
    assert "does not drive" in rep["statement"] and "wheel-based speed at most 0.00 m/s" in rep["statement"]
    assert "GNSS speed at most 0.92 m/s" in rep["statement"]
    assert all(not c["testable"] and c["reason"] for c in rep["candidates"])
    assert "does not drive" in (out / "report.md").read_text()
    # the full analysis' keys, empty (a tool reading `effects` found none in an engine-level report)
    assert rep["effects"] == [] and rep["steps"] == [] and rep["open_world"] is None


def test_an_export_takes_the_reference_torque_the_vehicle_file_declares(tmp_path):
    """A 1 Hz export carries no EC1: without --reference-torque the vehicle file's [drivetrain]
    engine_reference_torque_nm (SPN 544 from the data sheet) converts the percent torque."""
    from tractionecu.config import VehicleParams, save_vehicle
    from tractionecu.diagnose import diagnose_path
    from tractionecu.errors import ConfigError

    csv_path = tmp_path / "export.csv"
    csv_path.write_text("Time [s],EEC1 SPN190 Engine Speed [rpm],EEC1 SPN513 Actual Engine - Percent Torque [%],"
                        "CCVS1 SPN84 Wheel-Based Vehicle Speed [km/h],GNSS Speed [km/h]\n"
                        + "".join(f"{k},800,12,0,0\n" for k in range(30)))
    bare = tmp_path / "bare.toml"
    save_vehicle(VehicleParams(), bare)
    with pytest.raises(ConfigError, match="engine_reference_torque_nm"):
        diagnose_path(csv_path, tmp_path / "r0", vehicle=bare, csv_mapping="auto")
    veh = VehicleParams()
    declared = tmp_path / "vehicle.toml"
    save_vehicle(dataclasses.replace(veh, drivetrain=dataclasses.replace(veh.drivetrain,
                                                                         engine_reference_torque_nm=450.0)),
                 declared)
    rep = diagnose_path(csv_path, tmp_path / "r1", vehicle=declared, csv_mapping="auto")
    assert (tmp_path / "r1" / "report.json").is_file() and rep["verdict"] == "untestable"   # standing


def test_slip_channel_carries_a_clock_running_ahead(recordings, tmp_path):
    """A CAN clock 0.3 s ahead of GNSS time is a GNSS *lead* of the wheel data, which no latency τ ≥ 0
    describes.  Regression: the clock skew acted on the GNSS-speed channel only, where the spline takes up
    almost all of it (phys_clock_skew: 0.5 % of that channel's mismatch, not named); the slip, formed from
    the CAN wheel speeds and the GNSS-fitted speed, carries it as it carries a latency."""
    from tractionecu.diagnose import data as _data
    from tractionecu.diagnose.channels import build_channels
    from tractionecu.diagnose.features import compute
    from tractionecu.evaluation import faults as F

    def slip_sse(rec):
        feat = compute(_data.load(rec, None))
        ch = next(c for c in build_channels(feat) if c.name == "slip")
        rows = np.ones(ch.m, dtype=bool)
        out = {}
        for off in (-0.3, 0.0, 0.3):
            eff = {"clock_skew": {"offset_s": off, "rate_ppm": 0.0}} if off else {}
            y, p = ch.parts(eff, rows)
            out[off] = float(np.sum((y - p) ** 2))
        return out

    healthy = slip_sse(recordings("null_fast"))
    skewed = slip_sse(F.clock_skew(recordings("null_fast"), tmp_path / "skew", 0.3))
    assert healthy[0.0] < min(healthy[-0.3], healthy[0.3]), healthy
    assert skewed[0.3] < min(skewed[0.0], skewed[-0.3]), skewed


def test_an_engine_level_export_with_a_draft_does_not_call_it_absent():
    """A mechanical export carrying 'RHS SPN1879 Rear Draft [N]' was diagnosed with "no draft" in its
    statement and "no draft signal" as every candidate's reason, while its note read work from that draft."""
    from tractionecu.diagnose.reduced import DRAFT_NOT_USED, _reason

    assert _reason("mass", False).startswith("no draft signal")
    assert _reason("mass", True).startswith(DRAFT_NOT_USED)
    assert _reason("load_transfer", True) == "no axle-load signal; " + DRAFT_NOT_USED
    assert "no draft" not in _reason("draft_speed", True)
