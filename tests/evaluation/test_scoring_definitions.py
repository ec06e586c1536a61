"""The scorecard compares the estimator's quantities with the truth's in the same (the paper's) terms."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from tractionecu.evaluation.coverage import coverage
from tractionecu.evaluation.scoring import read_truth, scorecard

WHEELS = ("FL", "FR", "RL", "RR")


def _write_truth(tmp_path, *, physical: bool, n: int = 200, pull_deg: float = 8.0, weight: float = 61803.0):
    rng = np.random.default_rng(3)
    t = 1000.0 + 0.01 * np.arange(1, n + 1)
    fdx = np.where(np.arange(n) < n // 2, 0.0, 17000.0)
    fz_sum = weight + fdx * math.tan(math.radians(pull_deg))
    fz = np.column_stack([0.18 * fz_sum, 0.18 * fz_sum, 0.32 * fz_sum, 0.32 * fz_sum])
    rho = 0.06 + 0.002 * rng.standard_normal(n)
    mu = np.column_stack([np.full(n, 0.4), np.full(n, 0.4), np.full(n, 0.3), np.full(n, 0.3)])
    head = (["t"] + [f"mu_{w}" for w in WHEELS] + ["rho_s", "a", "soil_id", "soil_name"] + [f"slip_{w}" for w in WHEELS]
            + ["v", "fdx"] + ([f"fz_{w}" for w in WHEELS] if physical else []))
    lines = [",".join(head)]
    for i in range(n):
        row = ([f"{t[i]:.3f}"] + [f"{x:.5f}" for x in mu[i]] + [f"{rho[i]:.6f}", "0.8", "0", "firm"]
               + ["0.08"] * 4 + ["2.5", f"{fdx[i]:.1f}"] + ([f"{x:.1f}" for x in fz[i]] if physical else []))
        lines.append(",".join(row))
    (tmp_path / "truth.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    toml = ['[[soils]]', 'name = "firm"', 'soil_class = "stubble"', 'a = 0.8', 'rho_s = 0.06', '']
    if physical:
        toml += ["[physical.hitch]", f"pull_angle_deg = {pull_deg}", ""]
    (tmp_path / "truth.toml").write_text("\n".join(toml), encoding="utf-8")
    return t, mu, rho, fdx, fz_sum, weight


def _estimates(t, mu, rho, mu_offset=0.0):
    n = len(t)
    return {"t": t + 0.002, "mu": mu + mu_offset, "rho_s": rho, "a": np.full(n, 0.8), "soil_class": ["stubble"] * n,
            "nis": np.full(n, 2.0), "nis_dof": np.full(n, 5), "valid": np.ones(n, bool),
            "sigma_mu": np.full((n, 4), 0.01), "sigma_rho_s": np.full(n, 0.002), "P_diag": np.full((n, 10), 1e-4)}


def test_physical_rho_s_is_turned_into_eq8_terms(tmp_path):
    """truth.csv's ρ_s of the physical truth is per unit of wheel load (Σρ_i F_z,i / ΣF_z, and ΣF_z carries the pull's
    vertical part F_dx tan β); eq. 8's is per unit of weight: the scorecard compares the estimate with the latter."""
    t, mu, rho, fdx, fz_sum, weight = _write_truth(tmp_path, physical=True)
    tr = read_truth(tmp_path / "truth.csv", tmp_path / "truth.toml")
    want = np.round(rho, 6) * fz_sum / weight
    assert tr.rho_s_paper == pytest.approx(want, rel=2e-5)
    assert np.all(tr.rho_s_paper[fdx > 0] > tr.rho_s[fdx > 0] * 1.03)        # 17 kN at 8°: 3.9 % more load
    assert tr.rho_s_paper[fdx == 0] == pytest.approx(tr.rho_s[fdx == 0], rel=2e-5)
    # an estimator that gets eq. 8's ρ_s exactly scores ~0, not the definition's difference
    sc = scorecard(_estimates(t, mu, want), tr)
    assert sc["rho_s_mean_abs_error"] < 1e-6
    assert coverage(_estimates(t, mu, want), tr)["rho_within_2sigma"] == 1.0


def test_paper_truth_rho_s_is_unchanged(tmp_path):
    t, mu, rho, *_ = _write_truth(tmp_path, physical=False)
    tr = read_truth(tmp_path / "truth.csv", tmp_path / "truth.toml")
    assert tr.rho_s_eq8 is None and tr.rho_s_paper is tr.rho_s


def test_signed_mu_bias_is_reported(tmp_path):
    t, mu, rho, *_ = _write_truth(tmp_path, physical=False)
    tr = read_truth(tmp_path / "truth.csv", tmp_path / "truth.toml")
    sc = scorecard(_estimates(t, mu, rho, mu_offset=np.array([0.004, 0.004, -0.003, -0.003])), tr)
    assert sc["mu_mean_bias"] == pytest.approx([0.004, 0.004, -0.003, -0.003], abs=1e-9)
    assert sc["mu_mean_rel_bias"] == pytest.approx((0.004 / 0.4 - 0.003 / 0.3) / 2, abs=1e-9)
    assert sc["mu_mean_abs_rel_error"] == pytest.approx((0.004 / 0.4 + 0.003 / 0.3) / 2, abs=1e-9)


def test_the_curve_target_states_the_soils_slip_span(tmp_path):
    """A 12-s start on the HENRYS slope printed "r2_mu_curve[stubble] 0.3213 ... >= 0.98": the soil's true slips in
    work spanned 0.030, below the 0.04 from which issue 13's R² target holds, and nothing said so."""
    from tractionecu.cli.replay import format_summary
    from tractionecu.evaluation.scoring import R2_TARGET_SLIP_SPAN, slip_spans

    t, mu, rho, *_ = _write_truth(tmp_path, physical=False)
    tr = read_truth(tmp_path / "truth.csv", tmp_path / "truth.toml")
    assert slip_spans(tr) == {"firm": pytest.approx(0.0)}               # every true slip is 0.08
    tr.slip[:, :] = np.linspace(0.02, 0.12, len(t))[:, None]             # 5–95 %: 0.025 .. 0.115
    assert slip_spans(tr)["firm"] == pytest.approx(0.09, abs=1e-3)
    assert slip_spans(tr, ranges=True)["firm"] == pytest.approx((0.025, 0.115), abs=1e-3)
    res = {"steps": len(t), "sim_seconds": 2.0, "wall_seconds": 0.1, "realtime_factor": 20.0}
    sc = scorecard(_estimates(t, mu, rho), tr)
    assert sc["slip_span"]["firm"] == pytest.approx(0.09, abs=1e-3)
    line = next(x for x in format_summary({**res, "scorecard": sc}).splitlines() if x.startswith("r2_mu_curve"))
    assert line.endswith(">= 0.98 (true slips span 0.090)")
    tr.slip[:, :] = 0.08
    sc = scorecard(_estimates(t, mu, rho), tr)
    line = next(x for x in format_summary({**res, "scorecard": sc}).splitlines() if x.startswith("r2_mu_curve"))
    assert line.endswith(f"n/a: true slips span 0.000 < {R2_TARGET_SLIP_SPAN}")


def test_a_scorecard_without_rho_s_prints_no_nan(tmp_path):
    """A mechanical machine without a draft sensor reports no ρ_s (issue 14): the replay table printed
    "rho_s_mean_abs_error nan", and an empty map "map_soil_accuracy n/a %"."""
    from tractionecu.cli.replay import format_summary

    t, mu, rho, *_ = _write_truth(tmp_path, physical=False)
    tr = read_truth(tmp_path / "truth.csv", tmp_path / "truth.toml")
    sc = scorecard(_estimates(t, mu, np.full(len(t), np.nan)), tr)
    assert math.isnan(sc["rho_s_mean_abs_error"])
    res = {"steps": len(t), "sim_seconds": 2.0, "wall_seconds": 0.1, "realtime_factor": 20.0, "scorecard": sc,
           "map_scorecard": {"map_soil_accuracy": None, "map_a_rmse": None, "map_rho_s_rmse": None}}
    text = format_summary(res)
    assert "nan" not in text and "n/a %" not in text
    assert re.search(r"^rho_s_mean_abs_error +n/a: no rho_s reported", text, re.M)
