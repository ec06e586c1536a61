"""Uncertainty and radius-calibration figures: does the reported 2σ hold the truth with biased sensors?

Run from the repository root::

    python benchmarks/uncertainty.py --json OUT.json [--seeds 0 1 2]

``benchmarks/estimator.py`` adds the same figures to its own (:func:`figures`).

Figures (printed and written as JSON keys):

``biased_mu_within_2sigma`` / ``biased_rho_within_2sigma``
    share of valid samples (and wheels) whose true μ (ρ_s) lies within the
    reported 2σ (``Estimate.sigma_mu``, ``sigma_rho_s``), over the
    ``biased-sensors`` scenario (physical truth model, sensor gains, offsets
    and GNSS latency drawn inside the configured tolerances), all seeds
    pooled; ``*_filter_only`` the same with the filter's own √P.
``biased_mu_error`` / ``biased_rho_error``
    μ mean absolute relative error and ρ_s mean absolute error there.
``physical_mu_within_2sigma`` / ``physical_mu_error``
    the same on ``physical-three-soils`` (same truth model, no biases): what
    is not due to the sensor errors.
``matched_mu_within_2sigma`` / ``matched_rho_within_2sigma`` / ``matched_mu_error``
    ``biased-sensors`` (the same sensor errors) with the three model
    differences that the filter's model has no term for taken away, as
    ``benchmarks/truth_gap.py`` variant D does (no hub reduction losses, a
    level line of pull, the filter's rolling radius); the tyre–soil law,
    relaxation, turns, toothed pickups and the GNSS latency stay: the
    coverage of the sensor errors on a truth model that is not the filter.
``paper_biased_mu_within_2sigma``, ``paper_biased_rho_within_2sigma``, ``paper_biased_mu_error``
    ``paper-three-soils`` (the project's simulator) with the sensor errors
    of :func:`tractionecu.evaluation.coverage.biased_trace` and 60 ms of
    GNSS latency.
``radius_scale_front`` / ``radius_scale_rear`` / ``radius_halfwidth_*``
    the self-calibrated rolling-radius scale and its 95 % half-width at the
    end of a run with tyres rolling 2 % larger than nominal
    (:func:`tractionecu.evaluation.coverage.radius_scenario`; true scale 1.02);
``radius_slip_mae_uncalibrated`` / ``radius_slip_mae_calibrated``
    the per-wheel slip mean absolute error in work without and with the
    calibration (``radius_mu_error_*`` the μ error).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tractionecu.estimation.calibration import CalibrationConfig  # noqa: E402
from tractionecu.estimation.estimator import EstimatorConfig  # noqa: E402
from tractionecu.evaluation.coverage import biased_trace, coverage, radius_scenario, work_errors  # noqa: E402
from tractionecu.evaluation.scoring import read_truth  # noqa: E402
from tractionecu.pipeline.replay import replay  # noqa: E402
from tractionecu.recording.reader import read_recording  # noqa: E402
from tractionecu.sim import scenarios  # noqa: E402
from tractionecu.sim.simulator import simulate  # noqa: E402
from tractionecu.sim.writer import write_recording  # noqa: E402


def _pooled(cards: list[dict[str, Any]]) -> dict[str, float]:
    """Sample-weighted means of the coverage figures over runs."""
    n = np.array([c["samples"] for c in cards], dtype=float)
    keys = ("mu_within_2sigma", "mu_within_2sigma_filter_only", "rho_within_2sigma", "rho_within_2sigma_filter_only",
            "mu_mean_abs_rel_error", "rho_s_mean_abs_error")
    return {k: float(np.sum(n * np.array([c[k] for c in cards])) / n.sum()) for k in keys}


def _run(work: Path, name: str, seed: int, bias_paper: bool = False, matched: bool = False) -> dict[str, Any]:
    out = work / f"{name}-{seed}{'-biased' if bias_paper else ''}{'-matched' if matched else ''}"
    scn = scenarios.get(name, seed=seed, **({"effects": {"gps_latency": {"tau_s": 0.06}}} if bias_paper else {}))
    if matched:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from truth_gap import variants

        scn = dataclasses.replace(scn, physical=variants(scn)[-1][1])
    tr = simulate(scn)
    if bias_paper:
        tr, _ = biased_trace(tr, scn.sensors, np.random.default_rng(seed + 77))
    write_recording(scn, tr, out)
    rec = read_recording(out)
    card = coverage(replay(rec).arrays, read_truth(rec.truth_csv_path, rec.truth_toml_path))
    print(f"  {out.name}: μ within 2σ {card['mu_within_2sigma']:.3f} (filter's own σ "
          f"{card['mu_within_2sigma_filter_only']:.3f}), ρ_s {card['rho_within_2sigma']:.3f}, "
          f"μ error {card['mu_mean_abs_rel_error']:.4f}, ρ_s error {card['rho_s_mean_abs_error']:.4f}", flush=True)
    return card


def figures(work: Path, seeds: list[int]) -> dict[str, float]:
    """The uncertainty and calibration figures (module doc), simulating into ``work``."""
    fig: dict[str, float] = {}
    if "biased-sensors" in scenarios.SCENARIOS:
        for name, tag in (("biased-sensors", "biased"), ("physical-three-soils", "physical")):
            p = _pooled([_run(work, name, s) for s in seeds])
            fig[f"{tag}_mu_within_2sigma"] = p["mu_within_2sigma"]
            fig[f"{tag}_mu_within_2sigma_filter_only"] = p["mu_within_2sigma_filter_only"]
            fig[f"{tag}_rho_within_2sigma"] = p["rho_within_2sigma"]
            fig[f"{tag}_rho_within_2sigma_filter_only"] = p["rho_within_2sigma_filter_only"]
            fig[f"{tag}_mu_error"] = p["mu_mean_abs_rel_error"]
            fig[f"{tag}_rho_error"] = p["rho_s_mean_abs_error"]
        p = _pooled([_run(work, "biased-sensors", s, matched=True) for s in seeds])
        fig["matched_mu_within_2sigma"] = p["mu_within_2sigma"]
        fig["matched_mu_within_2sigma_filter_only"] = p["mu_within_2sigma_filter_only"]
        fig["matched_rho_within_2sigma"] = p["rho_within_2sigma"]
        fig["matched_rho_within_2sigma_filter_only"] = p["rho_within_2sigma_filter_only"]
        fig["matched_mu_error"] = p["mu_mean_abs_rel_error"]
        fig["matched_rho_error"] = p["rho_s_mean_abs_error"]
    p = _pooled([_run(work, "paper-three-soils", s, bias_paper=True) for s in seeds[:1]])
    fig["paper_biased_mu_within_2sigma"] = p["mu_within_2sigma"]
    fig["paper_biased_mu_within_2sigma_filter_only"] = p["mu_within_2sigma_filter_only"]
    fig["paper_biased_rho_within_2sigma"] = p["rho_within_2sigma"]
    fig["paper_biased_mu_error"] = p["mu_mean_abs_rel_error"]
    # rolling radius: tyres 2 % larger than nominal
    scn = radius_scenario(0.02, seed=seeds[0])
    write_recording(scn, simulate(scn), work / "radius")
    rec = read_recording(work / "radius")
    truth = read_truth(rec.truth_csv_path, rec.truth_toml_path)
    for on, tag in ((False, "uncalibrated"), (True, "calibrated")):
        a = replay(rec, cfg=EstimatorConfig(calibration=CalibrationConfig(enabled=on))).arrays
        w = work_errors(a, truth)
        fig[f"radius_slip_mae_{tag}"] = w["slip_mae"]
        fig[f"radius_mu_error_{tag}"] = w["mu_rel_error"]
        if on:
            for i, axle in enumerate(("front", "rear")):
                fig[f"radius_scale_{axle}"] = float(a["radius_scale"][-1, i])
                fig[f"radius_halfwidth_{axle}"] = float(a["radius_halfwidth"][-1, i])
    return fig


TARGETS = {"biased_mu_within_2sigma": (">=", 0.90), "biased_mu_error": ("<=", 0.03),
           "matched_mu_within_2sigma": (">=", 0.90), "matched_mu_error": ("<=", 0.03)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", required=True, help="write the figures to this JSON file")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="simulation seeds (default 0 1 2)")
    ap.add_argument("--keep", default=None, help="keep the recordings in this directory")
    args = ap.parse_args(argv)
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="tecu-unc-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        fig = figures(work, args.seeds)
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    for k, v in fig.items():
        tgt = TARGETS.get(k)
        mark = ""
        if tgt:
            ok = v >= tgt[1] if tgt[0] == ">=" else v <= tgt[1]
            mark = f"   (target {tgt[0]} {tgt[1]:g}: {'met' if ok else 'NOT met'})"
        print(f"{k:44s} {v:.6g}{mark}")
    Path(args.json).write_text(json.dumps(fig, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
