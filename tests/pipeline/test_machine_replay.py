"""A mechanical tractor's recording through replay: the machine-level estimator, end to end (fast).

``tractionecu simulate --scenario mechanical-three-soils`` (J1939 EEC1, EC1 by BAM, ETC2, CCVS1, EBC2,
WBSD, GBSD, hitch, GNSS) for a short stretch, then ``tractionecu replay``: the vehicle's
``[drivetrain] kind = "mechanical"`` selects the machine-level estimator, whose status says so, and the
estimates are scored against the truth's ΣF_h/ΣF_z.  The accuracy bounds here are loose (a 40 s run,
first convergence included); the targets are measured on the whole scenarios (README).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

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
    sc = json.loads((run / "scorecard.json").read_text(encoding="utf-8"))
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
    sc = json.loads((run / "scorecard.json").read_text(encoding="utf-8"))
    assert sc["rho_s_reported_fraction"] == 0.0 and math.isnan(sc["rho_s_mean_abs_error"])
