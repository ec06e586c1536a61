"""A mechanical tractor's recording through replay: the machine-level estimator, end to end (fast).

``tractionecu simulate --scenario mechanical-three-soils`` (J1939 EEC1, EC1 by BAM, ETC2, CCVS1, EBC2,
WBSD, GBSD, hitch, GNSS) for a short stretch, then ``tractionecu replay``: the vehicle's
``[drivetrain] kind = "mechanical"`` selects the machine-level estimator, whose status says so, and the
estimates are scored against the truth's ΣF_h/ΣF_z.  The accuracy bounds here are loose (a 40 s run,
first convergence included); the targets are measured on the whole scenarios (README).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from tractionecu.evaluation.replay import read_scorecard
from tractionecu.cli.main import main
from tractionecu.estimation.estimator import DRAFT_NOT_SEPARATED, MACHINE_LEVEL
from tractionecu.sim import scenarios


def _simulate(name: str, out: Path, seconds: float = 40.0) -> None:
    assert main(["simulate", "--scenario", name, "--out", str(out), "--duration", str(seconds)]) == 0


def _estimates(run: Path) -> dict[str, np.ndarray]:
    head = (run / "estimates.csv").read_text(encoding="utf-8").splitlines()[0].split(",")
    cols = [i for i, h in enumerate(head) if h not in ("soil_class", "curve_path")]
    data = np.genfromtxt(run / "estimates.csv", delimiter=",", skip_header=1, usecols=cols)
    return {head[i]: data[:, j] for j, i in enumerate(cols)}


def test_mechanical_recording_replays_at_machine_level(tmp_path: Path, capsys) -> None:
    rec, run = tmp_path / "rec", tmp_path / "run"
    _simulate("mechanical-three-soils", rec)
    assert main(["replay", str(rec), "--out", str(run), "--no-map"]) == 0
    out = capsys.readouterr().out
    assert "mu_mean_abs_rel_error[machine]" in out
    e = _estimates(run)
    status = e["status"].astype(np.int64)
    assert np.all(status & MACHINE_LEVEL) and not np.any(status & DRAFT_NOT_SEPARATED)
    assert np.all(e["mu_FL"][np.isfinite(e["mu_FL"])] == e["mu_RR"][np.isfinite(e["mu_RR"])])
    assert e["valid"].mean() > 0.5
    sc = read_scorecard(run / "scorecard.json")
    assert sc["level"] == "machine"
    assert sc["mu_mean_abs_rel_error"] < 0.25 and sc["rho_s_mean_abs_error"] < 0.06
    # the errors are over the valid estimates, with their share and the all-steps figure beside them
    assert 0.0 < sc["valid_fraction"] <= 1.0 and "valid estimates" in sc["mu_population"]
    assert math.isfinite(sc["mu_mean_abs_rel_error_all"]) and "valid_fraction" in out and "curve_path[" in out


def test_the_recording_declares_what_an_owner_knows_never_the_exact_truth(tmp_path: Path) -> None:
    """vehicle.toml of a mechanical run: line of pull, SPN 514 friction (engine + accessories) and the
    calibrated rear rolling radius, each off the truth by an error inside its stated tolerance."""
    from tractionecu.config import load_vehicle
    from tractionecu.sim import physwriter
    from tractionecu.sim.physical import axle_loads
    from tractionecu.sim.tyre import rolling_radius

    rec = tmp_path / "rec"
    _simulate("mechanical-three-soils", rec, 2.0)
    veh = load_vehicle(rec / "vehicle.toml")
    scn = scenarios.SCENARIOS["mechanical-three-soils"]
    scn = scn() if callable(scn) else scn
    ps = scn.physical
    eng = ps.drivetrain.mech.engine
    friction = 100.0 * (eng.friction_nm + eng.aux_torque_nm) / eng.reference_torque_nm
    r_true = float(rolling_radius(0.5 * axle_loads(scn.vehicle, ps.hitch, scn.vehicle.mass_kg, 0, 0, 0)[1],
                                  scn.vehicle.r0_m, ps.tyre, scn.vehicle.tyre_pressure_pa))
    dt = veh.drivetrain
    for got, true, tol in ((dt.engine_friction_percent, friction, physwriter.DECLARED_FRICTION_TOL_PCT + 0.005),
                           (veh.pull_angle_deg, ps.hitch.pull_angle_deg, physwriter.DECLARED_PULL_ANGLE_TOL_DEG + 0.005),
                           (dt.rolling_radius_m / r_true - 1.0, 0.0, physwriter.DECLARED_RADIUS_TOL_REL + 1e-4)):
        assert got != true and abs(got - true) <= tol


def test_without_a_draft_sensor_no_rho_s_is_reported(tmp_path: Path) -> None:
    rec, run = tmp_path / "rec", tmp_path / "run"
    _simulate("mechanical-no-draft", rec, 20.0)
    assert main(["replay", str(rec), "--out", str(run)]) == 0           # the map too: no ρ_s to map
    e = _estimates(run)
    status = e["status"].astype(np.int64)
    assert np.all(status & DRAFT_NOT_SEPARATED) and np.all(status & MACHINE_LEVEL)
    assert not np.isfinite(e["rho_s"]).any()
    sc = read_scorecard(run / "scorecard.json")
    assert sc["rho_s_reported_fraction"] == 0.0 and math.isnan(sc["rho_s_mean_abs_error"])


# ----------------------------------------------------------------------------- recordings not seen before
REPO = Path(__file__).resolve().parents[2]
JD_EXCERPT = REPO / "tests" / "data" / "candump" / "jd5055e_excerpt.log"
PGN_EEC1, PGN_EBC2, PGN_WBSD, PGN_EC1, PGN_TP_CM, PGN_TP_DT = 61444, 65215, 65096, 65251, 60416, 60160


def _pgn(line: str) -> int:
    cid = int(line.split()[2].split("#")[0], 16)
    pf = (cid >> 16) & 0xFF
    return (cid >> 8) & (0x3FF00 if pf < 240 else 0x3FFFF)


def _t(line: str) -> float:
    return float(line[1:line.index(")")])


def _variant(src: Path, dst: Path, lines: list[str]) -> Path:
    """A copy of recording ``src`` whose can.log holds ``lines``."""
    import shutil

    shutil.copytree(src, dst)
    (dst / "can.log").write_text("\n".join(lines) + "\n", encoding="utf-8")
    return dst


def _eec1_at_10ms(lines: list[str]) -> list[str]:
    """EEC1 every 10 ms from a 20 ms one: a frame between each pair, percent torque (byte 3) and engine speed
    (bytes 4-5) half-way between its neighbours' raw values."""
    out, prev = [], None
    for ln in lines:
        if _pgn(ln) == PGN_EEC1:
            t, data = _t(ln), bytes.fromhex(ln.split("#")[1])
            if prev is not None and 0.015 < t - prev[0] < 0.025:
                mid = bytearray(prev[1])
                mid[2] = (prev[1][2] + data[2]) // 2
                sp = (int.from_bytes(prev[1][3:5], "little") + int.from_bytes(data[3:5], "little")) // 2
                mid[3:5] = sp.to_bytes(2, "little")
                out.append(f"({0.5 * (prev[0] + t):.6f}) can0 {ln.split()[2].split('#')[0]}#{mid.hex().upper()}")
            prev = (t, data)
        out.append(ln)
    return sorted(out, key=_t)


@pytest.fixture(scope="module")
def mech40(tmp_path_factory) -> Path:
    rec = tmp_path_factory.mktemp("mech") / "rec"
    _simulate("mechanical-three-soils", rec, 40.0)
    return rec


def _replay_scorecard(rec: Path, run: Path) -> dict:
    assert main(["replay", str(rec), "--out", str(run), "--no-map"]) == 0
    sc = read_scorecard(run / "scorecard.json")
    assert sc["level"] == "machine"
    return sc


def test_eec1_at_10_ms_and_ccvs1_only_replay_like_the_recording(mech40: Path, tmp_path: Path) -> None:
    """The simulator sends EEC1 every 20 ms with EBC2 and WBSD beside CCVS1; a tractor may send EEC1 every
    10 ms (J1939-71 allows 10-20 ms) or one wheel-based speed only (CCVS1): both run at machine level with
    the original's accuracy (the 40 s run's loose bounds)."""
    lines = (mech40 / "can.log").read_text(encoding="utf-8").splitlines()
    ref = _replay_scorecard(mech40, tmp_path / "run0")
    fast = _eec1_at_10ms(lines)
    assert sum(_pgn(x) == PGN_EEC1 for x in fast) > 1.9 * sum(_pgn(x) == PGN_EEC1 for x in lines)
    for name, var in (("eec1-10ms", fast), ("ccvs1-only", [x for x in lines if _pgn(x) not in (PGN_EBC2, PGN_WBSD)])):
        sc = _replay_scorecard(_variant(mech40, tmp_path / name, var), tmp_path / f"run-{name}")
        assert sc["valid_fraction"] > 0.5, name
        assert sc["mu_mean_abs_rel_error"] < max(0.08, 1.5 * ref["mu_mean_abs_rel_error"]), (name, sc, ref)
        assert sc["rho_s_mean_abs_error"] < 0.03, name


def test_eec1_thinned_to_100_ms_keeps_the_drive_speed_timeout_off(mech40: Path, tmp_path: Path) -> None:
    """A logger that keeps every 5th EEC1 frame (100 ms): the drive speed's one period tracker took samples
    from the engine speed and from CCVS1/WBSD, which land a step apart, read them as a 10 ms stream, and the
    timeout (at its floor) tripped between two 10 Hz samples: wheel_speed_timeout on 32 % of the steps.  The
    period now follows one source (the engine speed, where it is the drive speed)."""
    from tractionecu.estimation.estimator import WHEEL_TIMEOUT

    lines = (mech40 / "can.log").read_text(encoding="utf-8").splitlines()
    k = [0]

    def keep(ln: str) -> bool:
        if _pgn(ln) != PGN_EEC1:
            return True
        k[0] += 1
        return k[0] % 5 == 1                          # the frames just before CCVS1 and WBSD

    rec = _variant(mech40, tmp_path / "eec1-100ms", [x for x in lines if keep(x)])
    _replay_scorecard(rec, tmp_path / "run")
    st = _estimates(tmp_path / "run")["status"].astype(int)
    assert np.mean((st & WHEEL_TIMEOUT) != 0) < 0.03


def test_without_ec1_replay_names_the_reference_torque_or_takes_the_declared_one(mech40: Path, tmp_path: Path,
                                                                                   capsys) -> None:
    """No EC1 on the bus (a capture started after its 5 s broadcast): replay says what is missing for the
    profile it runs; the reference torque declared in [drivetrain] engine_reference_torque_nm runs it."""
    lines = [x for x in (mech40 / "can.log").read_text(encoding="utf-8").splitlines()
             if _pgn(x) not in (PGN_EC1, PGN_TP_CM, PGN_TP_DT)]
    rec = _variant(mech40, tmp_path / "no-ec1", lines)
    assert main(["replay", str(rec), "--out", str(tmp_path / "run"), "--no-map"]) == 4
    err = capsys.readouterr().err
    assert "not replayed: profile mechanical (the one the estimator runs, vehicle.toml" in err and "Traceback" not in err
    assert "missing: EngineReferenceTorque" in err
    from tractionecu.pipeline.replay import MissingSignals, replay

    with pytest.raises(MissingSignals, match="the estimator's mechanical profile needs them") as e:   # said "hub"
        replay(rec)
    assert e.value.profile == "mechanical" and e.value.missing == ["EngineReferenceTorque"]
    scn = scenarios.SCENARIOS["mechanical-three-soils"]
    scn = scn() if callable(scn) else scn
    tref = scn.physical.drivetrain.mech.engine.reference_torque_nm                  # the engine's data sheet
    toml = (rec / "vehicle.toml").read_text(encoding="utf-8")
    assert "engine_reference_torque_nm = 0.0\n" in toml                  # written, not declared
    (rec / "vehicle.toml").write_text(toml.replace("engine_reference_torque_nm = 0.0\n",
                                                   f"engine_reference_torque_nm = {tref}\n"), encoding="utf-8")
    assert main(["inspect", str(rec)]) == 0
    assert "engine reference torque  vehicle.toml" in capsys.readouterr().out
    sc = _replay_scorecard(rec, tmp_path / "run-declared")
    assert sc["valid_fraction"] > 0.5 and sc["mu_mean_abs_rel_error"] < 0.25


def test_jd5055e_capture_with_a_mechanical_vehicle_replays_with_no_motion(tmp_path: Path, capsys) -> None:
    """The real John Deere 5055E capture (stationary; ETC2's ratio and GBSD not available) with
    [drivetrain] kind = "mechanical" and the ratio learnt: inspect names the profile replay runs, replay runs
    the machine-level estimator, reports no motion and claims no valid estimate."""
    import shutil

    rec = tmp_path / "jd"
    rec.mkdir()
    shutil.copy(JD_EXCERPT, rec / "can.log")
    (rec / "vehicle.toml").write_text('[vehicle]\nmass_kg = 2900.0\n[vehicle.drivetrain]\nkind = "mechanical"\n'
                                      'gear_ratio = "learnt"\n', encoding="utf-8")
    assert main(["inspect", str(rec)]) == 0
    out = capsys.readouterr().out
    assert 'replay runs mechanical (vehicle.toml: [drivetrain] kind = "mechanical")' in out
    # the learnt ratio meets the gear-ratio need (replay said "missing gear ratio ... flags those steps")
    assert "mechanical (replay runs this one): 4 of 6 found" in out and "replay of profile mechanical: runs" in out
    assert "gear ratio               learnt from engine speed over wheel speed" in out
    run = tmp_path / "run"
    assert main(["replay", str(rec), "--out", str(run), "--no-map"]) == 0
    cap = capsys.readouterr()
    assert "motion: no motion" in cap.out and "Traceback" not in cap.err
    assert "gear ratio" not in cap.out
    e = _estimates(run)
    assert len(e["valid"]) > 0 and not e["valid"].any()
    assert np.all(e["status"].astype(np.int64) & MACHINE_LEVEL)


def test_machine_curve_prior_from_the_configuration(mech40: Path, tmp_path: Path) -> None:
    """``[estimator] machine_curve_prior = "d497"`` through ``replay --config``, map on: the machine's curve is
    reported and scored on the D497 shape (estimation/machine_curve.py), μ and ρ_s as without it."""
    cfg = tmp_path / "prior.toml"
    cfg.write_text('[estimator]\nmachine_curve_prior = "d497"\n', encoding="utf-8")
    run = tmp_path / "run-d497"
    assert main(["replay", str(mech40), "--out", str(run), "--config", str(cfg)]) == 0
    sc = read_scorecard(run / "scorecard.json")
    ref = _replay_scorecard(mech40, tmp_path / "run-default")
    paths = {c["curve_path"] for c in sc["curves"].values()}
    assert paths == {"class:d497"}, sc["curves"]
    assert {c["curve_path"] for c in ref["curves"].values()} == {"class:stubble"}
    assert sc["mu_mean_abs_rel_error"] == ref["mu_mean_abs_rel_error"]
    assert sc["rho_s_mean_abs_error"] == ref["rho_s_mean_abs_error"]
    assert "class:d497" in (run / "estimates.csv").read_text(encoding="utf-8")
    # the map's a layer is a = mu/g_d497(s) wherever mu is mapped (it was NaN, and no epoch was mapped)
    from tractionecu.mapping.store import MapStore

    store = MapStore.open(run / "map")
    ext = store.extent(["mu"])
    mu, a, p = (store.grid(n, ext) for n in ("mu", "a", "p"))
    has = mu.count > 0
    assert has.sum() > 50 and np.all(a.count[has] > 0) and np.isfinite(a.mean[has]).all()
    assert 0.5 < float(np.median(a.mean[has])) < 1.0                      # an asymptotic adhesion
    assert np.allclose(p.mean[has], 1.0)                                  # the D497 shape: p = 1


def test_machine_curve_prior_on_the_bus(mech40: Path) -> None:
    """The broadcast of a replay's estimates with the d497 prior: SoilClassIndex is d497's code (204), which a
    receiver cannot map through the configured soil_classes; it was 0, which reads as soil_classes[0], stubble."""
    from tractionecu.bus.dbc import default_codec
    from tractionecu.estimation.config import EstimatorConfig
    from tractionecu.model.mucurve import CLASS_CODES
    from tractionecu.pipeline.replay import replay_streamed
    from tractionecu.service.broadcast import estimate_frames

    codec = default_codec()
    sent: list[tuple[str, float]] = []
    n = [0]

    def on_estimate(e) -> None:
        n[0] += 1
        if n[0] % 100 == 0:                            # one estimate a second (100 Hz steps) to the bus
            for can_id, data in estimate_frames(codec, e, sa=0x90, priority=6):
                name, vals = codec.decode(can_id, data)
                if name == "TECU_EstSoil":
                    sent.append((e.soil_class, vals["SoilClassIndex"]))

    replay_streamed(mech40, cfg=EstimatorConfig(machine_curve_prior="d497"), on_estimate=on_estimate)
    assert len(sent) > 20 and {c for c, _ in sent} == {"d497"}
    assert {int(i) for _, i in sent} == {CLASS_CODES["d497"]}


def test_a_bekker_soil_recording_replays_and_scores_against_its_own_curve(tmp_path: Path) -> None:
    """mechanical-bekker-soils (Bekker / Janosi-Hanamoto tyre-soil truth, no Brixius term) replays at machine
    level, and its curve is scored against the soil's tabulated Janosi curve, not a class: d497's curve, fitted
    at the same working point, extrapolates far above it (the prior is not the truth's family here)."""
    rec = tmp_path / "rec"
    _simulate("mechanical-bekker-soils", rec)
    cards = {}
    for prior in ("", "d497"):
        cfg = tmp_path / f"prior{prior}.toml"
        cfg.write_text(f'[estimator]\nmachine_curve_prior = "{prior}"\n', encoding="utf-8")
        run = tmp_path / f"run{prior}"
        assert main(["replay", str(rec), "--out", str(run), "--no-map", "--config", str(cfg)]) == 0
        cards[prior] = read_scorecard(run / "scorecard.json")
    default, d497 = cards[""], cards["d497"]
    assert default["level"] == "machine" and default["mu_mean_abs_rel_error"] < 0.25
    assert default["mu_mean_abs_rel_error"] == d497["mu_mean_abs_rel_error"]
    soils = [n for n, c in default["curves"].items() if math.isfinite(default["r2_mu_curve"].get(n, math.nan))]
    assert soils
    import tomllib

    from tractionecu.model.mucurve import curve_class
    truth = {s["name"]: s for s in tomllib.loads((rec / "truth.toml").read_text(encoding="utf-8"))["soils"]}
    for n in soils:
        assert default["curves"][n]["curve_path"] == "class:stubble"
        assert d497["curves"][n]["curve_path"] == "class:d497"
        assert truth[n]["traction_model"] == "bekker-janosi-hanamoto" and truth[n]["mu_curve_s"][20] == 0.4
        # at s = 0.4 the D497 curve through the working point lies > 0.2 above the soil's Janosi curve
        over = d497["curves"][n]["a_identified"] * float(curve_class("d497").g(0.4)) - truth[n]["mu_curve"][20]
        assert over > 0.2 and d497["r2_mu_curve"][n] < default["r2_mu_curve"][n]


def test_inspect_does_not_advise_declaring_what_a_broken_vehicle_file_declares(mech40: Path, tmp_path: Path,
                                                                               capsys) -> None:
    """A vehicle file that declares kind = "mechanical" but does not load (here: a front_drive value it does
    not know) was reported, and then inspect advised 'declare [drivetrain] kind = "mechanical" ... to run it'."""
    import shutil

    rec = tmp_path / "rec"
    shutil.copytree(mech40, rec)
    text = (rec / "vehicle.toml").read_text(encoding="utf-8")
    assert 'front_drive = "engaged"' in text
    (rec / "vehicle.toml").write_text(text.replace('front_drive = "engaged"', 'front_drive = "on"'), encoding="utf-8")
    assert main(["inspect", str(rec)]) == 0
    out = capsys.readouterr().out
    assert "vehicle.toml does not load" in out and "front_drive" in out
    assert "declare [drivetrain]" not in out and "once vehicle.toml loads (above)" in out
