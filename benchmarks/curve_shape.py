"""μ(s) beyond one parameter: R² of the identified curve per soil, its path, and its cost.

Run from the repository root::

    python benchmarks/curve_shape.py --json OUT.json [--seeds 0 1] [--scenarios soils-off-class ...] [--keep DIR] [--load | --no-load]

``--load`` / ``--no-load``: the curve's load dependence on or off (``[estimator] curve_shape_load`` for the
replay, ``load`` for the pairs run); without either, the estimator's default (``EstimatorConfig``).

For each scenario and seed: simulate (``tractionecu simulate``; a recording already in ``--keep DIR`` is
reused), replay (in this process, as ``tractionecu replay`` does: :func:`chain_run`) and
print, per soil, the scorecard's R² of the identified μ(s) against the truth's curve (the class
curve for the paper truth model, the tabulated ``mu_curve`` of ``truth.toml`` for the physical one),
the curve path most samples reported (``class:<name>`` or ``shape:<form>``) and the slip span of
the soil's true slips (5–95 %).  ``range R2``: the same R² over the soil's own slip range only (the 5–95 %
interval of its true slips in work), where the curve rests on data; over [0, 0.4] the rest is the
curve's extrapolation.  ``soil#``: the estimator's soil number most of the soil's valid estimates
reported (soil segments whose slips at equal μ̂ do not differ are pooled into one soil,
:class:`~tractionecu.estimation.curve.ShapeIdentifier`) and its share.  The last line counts the soil runs
the issue's target applies to (span ≥ 0.04) and names those where the chain's R² is under 0.98.  Two rows
per soil:

``chain``
    the whole estimator: the curve fitted to the filter's own (μ̂, ŝ), as the scorecard scores it;
``pairs``
    the curve identification alone (:class:`~tractionecu.estimation.curve.CurveEstimator`, same
    settings) fed at 10 Hz with the truth's per-wheel (μ, s) plus a slip error of 0.009 (AR(1),
    0.5 s: the filter's slip error on straight passes, README) and 0.003 on μ, so that the
    identification is measured apart from the filter's own μ and slip errors; with the truth's
    wheel loads ``fz_*`` (the hub estimator passes its own), so that the load dependence can be fitted.

``exact`` (second table)
    the same identification fed with the truth's per-wheel (μ, s) as they are, no error added, with the
    load term as the run's and on: what the identification reaches when the pairs are exact, with the
    slips each soil's work covers and the truth's load dependence.  Beside it, per axle, the errors of the
    chain's pairs against the truth in work (:func:`~tractionecu.evaluation.curve_score.pair_errors`): the
    standard deviations of e_s and e_μ, their correlation, the correlation of e_s with the true slip and
    the slope of ŝ on s (1 and 0 for the classical errors the fit assumes).

Two definitions of the target are counted on the last lines, each stated: the issue's, R² over
s ∈ [0, 0.4] (the scorecard's), and R² over each soil's own slip range (5–95 % of its true slips in work),
where the curve rests on data.  Neither replaces the other.

Scoring load: the truth's tabulated ``mu_curve`` is μ(s) at the static mean wheel load m g/4, and the
identified curve is evaluated at the same load (its reference load m g/4 of ``vehicle.toml``; a curve
without a load dependence is one curve for every load).  ``front``/``rear``: the same curve at the
static front and rear wheel loads against the truth's ``mu_curve_front``/``mu_curve_rear``, as a check
that the load dependence, where identified, holds away from the reference load.

Cost: ``curve_us_per_step`` is the time of all curve updates of the ``pairs`` run (shape
identification on) divided by the number of 100 Hz estimator steps of the same duration, and
``curve_us_per_step_paper_path`` the same with the shape identification off.
"""

from __future__ import annotations

import argparse
import collections
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tractionecu.estimation.curve import CurveEstimator  # noqa: E402
from tractionecu.estimation.config import EstimatorConfig  # noqa: E402
from tractionecu.estimation.estimator import SLIP_AVERAGED, SLIP_UNCERTAIN  # noqa: E402
from tractionecu.evaluation.curve_score import identified_curve, pair_errors, r_squared_over, true_curve  # noqa: E402
from tractionecu.config import G, load_vehicle  # noqa: E402
from tractionecu.evaluation.scoring import R2_TARGET_SLIP_SPAN, S_GRID, read_truth, r_squared, scorecard  # noqa: E402
from tractionecu.evaluation.scoring import slip_spans as scoring_slip_spans  # noqa: E402
from tractionecu.pipeline.replay import replay  # noqa: E402
from tractionecu.recording.reader import read_recording  # noqa: E402

TARGET_R2, TARGET_SPAN = 0.98, R2_TARGET_SLIP_SPAN
"""Issue 13's target: R² of the identified μ(s) ≥ 0.98 on every soil whose slip span is ≥ 0.04."""
SLIP_SIGMA = 0.009
SLIP_CORR_S = 0.5


def pairs_run(rec: Path, seed: int, shape: bool = True, load: bool = False,
              exact: bool = False) -> tuple[dict[str, dict], float, float]:
    """The identification alone on the truth's pairs: per soil {r2, range_r2, path}, curve seconds, run seconds.
    ``exact``: the truth's pairs as they are (no slip or μ error added)."""
    tr = read_truth(rec / "truth.csv", rec / "truth.toml")
    fz = truth_loads(rec)
    veh = load_vehicle(rec / "vehicle.toml")
    fz_ref = veh.mass_kg * G / 4.0
    rng = np.random.default_rng(seed)
    ce = CurveEstimator(["stubble"], tau_s=3.0, shape=shape, fz_ref_n=fz_ref, load=load)
    tc = -math.inf
    e = 0.0
    states: dict[str, list] = collections.defaultdict(list)
    spent = 0.0
    for i in range(len(tr.t)):
        if tr.t[i] - tc < 0.1 - 1e-9 or abs(tr.v[i]) < 0.5:
            continue
        dt = 0.1 if tc == -math.inf else float(tr.t[i] - tc)
        tc = float(tr.t[i])
        e = e * math.exp(-dt / SLIP_CORR_S) + math.sqrt(1 - math.exp(-2 * dt / SLIP_CORR_S)) * SLIP_SIGMA * rng.standard_normal()
        mu = tr.mu[i] + (0.0 if exact else 0.003 * rng.standard_normal(4))
        s = tr.slip[i] + (0.0 if exact else e)
        t0 = time.perf_counter()
        st = ce.update(tc, mu, s, np.full(4, 0.005), np.full(4, SLIP_SIGMA), None if fz is None else fz[i])
        spent += time.perf_counter() - t0
        states[tr.soil_name[i]].append(st)
    out = {}
    ranges = slip_spans(rec, ranges=True)
    for name, sts in states.items():
        a = np.array([x.a for x in sts])
        idx = np.flatnonzero(np.isfinite(a))
        if not idx.size:
            continue
        cur, info = identified_curve(idx, a, [x.class_name for x in sts], [x.curve for x in sts], S_GRID)
        y = true_curve(tr.soils[name], S_GRID)
        lo, hi = ranges.get(name, (math.nan, math.nan))
        out[name] = {"r2": r_squared(cur, y), "range_r2": r_squared_over(cur, y, S_GRID, lo, hi),
                     "path": info["curve_path"],
                     "shape_share": float(np.mean([x.curve_path.startswith("shape:") for x in sts])),
                     **axle_r2(rec, name, idx, sts, veh)}
    return out, spent, float(tr.t[-1] - tr.t[0])


def chain_run(rec: Path, load: bool = False) -> tuple[dict, dict[str, dict]]:
    """The whole estimator on ``rec`` (replay in this process): its scorecard and, per soil, the R² over the
    soil's own slip range (``range_r2``, :func:`slip_spans`) and the estimator's soil number (``soil_no``,
    ``soil_share``)."""
    soils_no: list[int] = []
    res = replay(read_recording(rec), cfg=EstimatorConfig(curve_shape_load=load),
                 on_estimate=lambda e: soils_no.append(-1 if e.curve_state is None else e.curve_state.soil))
    a = res.arrays
    tr = read_truth(rec / "truth.csv", rec / "truth.toml")
    card = scorecard(a, tr)
    k = np.clip(np.searchsorted(tr.t, a["t"] + 1e-9, side="right") - 1, 0, len(tr.t) - 1)
    names = np.array(tr.soil_name, dtype=object)[k]
    valid = np.asarray(a["valid"], dtype=bool) & np.isfinite(a["a"])
    valid[:int(np.argmax(valid))] = False
    ranges = slip_spans(rec, ranges=True)
    sno = np.array(soils_no[:len(k)])
    out = {}
    for name in sorted(set(tr.soil_name)):
        idx = np.flatnonzero(valid & (names == name))
        if not idx.size:
            continue
        cur, _ = identified_curve(idx, a["a"], a["soil_class"], a.get("curve"), S_GRID)
        lo, hi = ranges.get(name, (math.nan, math.nan))
        cnt = collections.Counter(sno[idx].tolist())
        no, n_no = cnt.most_common(1)[0]
        out[name] = {"range_r2": r_squared_over(cur, true_curve(tr.soils[name], S_GRID), S_GRID, lo, hi),
                     "slip_range": [lo, hi], "soil_no": int(no), "soil_share": n_no / idx.size}
        # the errors of the pairs the curve is fitted to, per axle: valid estimates whose slip is supported
        # (neither held nor averaged: SLIP_UNCERTAIN, SLIP_AVERAGED), in work (|μ| ≥ 0.15 on every wheel)
        held = (np.asarray(a["status"]) & (SLIP_UNCERTAIN | SLIP_AVERAGED)) != 0
        work = idx[np.all(np.abs(tr.mu[k[idx]]) >= 0.15, axis=1) & (np.abs(tr.v[k[idx]]) >= 0.5) & ~held[idx]]
        # (signed in the direction of the true force: a slip under traction that reads negative stays negative)
        sgn = np.sign(tr.mu[k[work]])
        for axle, cols in (("front", [0, 1]), ("rear", [2, 3])):
            out[name][f"errors_{axle}"] = pair_errors(
                (sgn * a["mu"][work])[:, cols], (sgn * a["slip"][work])[:, cols],
                (sgn * tr.mu[k[work]])[:, cols], (sgn * tr.slip[k[work]])[:, cols])
    return card, out


def truth_loads(rec: Path) -> np.ndarray | None:
    """The truth's wheel loads fz_FL..fz_RR [N] (n, 4), None for a truth without them."""
    with open(rec / "truth.csv", encoding="utf-8") as fh:
        head = fh.readline().strip().split(",")
    cols = [f"fz_{w}" for w in ("FL", "FR", "RL", "RR")]
    if not all(c in head for c in cols):
        return None
    return np.loadtxt(rec / "truth.csv", delimiter=",", skiprows=1, usecols=[head.index(c) for c in cols], ndmin=2)


def axle_r2(rec: Path, name: str, idx: np.ndarray, sts: list, veh) -> dict[str, float]:
    """R² of the soil's identified curves at the static front / rear wheel loads against the truth's
    ``mu_curve_front`` / ``mu_curve_rear`` (mean over the shape-path samples; {} without them)."""
    import tomllib
    soils = {s["name"]: s for s in tomllib.loads((rec / "truth.toml").read_text(encoding="utf-8")).get("soils", [])}
    info = soils.get(name, {})
    curves = [sts[j].curve for j in idx.tolist() if sts[j].curve is not None and sts[j].curve_path.startswith("shape:")]
    if "mu_curve_front" not in info or len(curves) * 2 < len(idx):
        return {}
    out = {}
    ff = veh.static_front_fraction
    for key, fz in (("front", ff * veh.mass_kg * G / 2.0), ("rear", (1.0 - ff) * veh.mass_kg * G / 2.0)):
        mean = np.mean([c.mu(S_GRID, np.full_like(S_GRID, fz)) for c in curves], axis=0)
        true = np.interp(S_GRID, info["mu_curve_s"], info[f"mu_curve_{key}"])
        out[f"r2_{key}"] = r_squared(mean, true)
    return out


def slip_spans(rec: Path, ranges: bool = False) -> dict[str, Any]:
    """:func:`tractionecu.evaluation.scoring.slip_spans` of the recording's truth."""
    return scoring_slip_spans(read_truth(rec / "truth.csv", rec / "truth.toml"), ranges)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, required=True)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--scenarios", nargs="+", default=["soils-off-class", "physical-three-soils", "paper-three-soils"])
    ap.add_argument("--keep", type=Path, default=None, help="keep (and reuse) the simulated recordings here")
    ap.add_argument("--load", action=argparse.BooleanOptionalAction, default=None,
                    help="the curve's load dependence on / off (chain and pairs; default: the estimator's default)")
    args = ap.parse_args(argv)
    load = EstimatorConfig().curve_shape_load if args.load is None else bool(args.load)
    print(f"curve load term: {'on' if load else 'off'}")
    work = args.keep or Path(tempfile.mkdtemp(prefix="curve_shape_"))
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    cost = {"curve_s_shape": 0.0, "curve_s_paper": 0.0, "run_s": 0.0}
    print(f"{'scenario':22s} {'seed':>4s} {'soil':16s} {'span':>6s} {'s 5-95%':>12s} {'chain R2':>9s} {'range R2':>9s} {'soil#':>9s} "
          f"{'chain path':20s} {'pairs R2':>9s} {'pairs path':20s} {'front':>6s} {'rear':>6s}")
    for scn in args.scenarios:
        for seed in args.seeds:
            rec = work / f"rec_{scn}_{seed}"
            py = [sys.executable, "-m", "tractionecu"]
            if not (rec / "truth.csv").exists():
                subprocess.run(py + ["simulate", "--scenario", scn, "--seed", str(seed), "--out", str(rec)],
                               check=True, capture_output=True)
            card, per_soil = chain_run(rec, load=load)
            spans = slip_spans(rec)
            pairs, spent, dur = pairs_run(rec, seed, load=load)
            _, spent0, _ = pairs_run(rec, seed, shape=False)
            exact, _, _ = pairs_run(rec, seed, load=load, exact=True)
            exact_load, _, _ = pairs_run(rec, seed, load=True, exact=True)
            cost["curve_s_shape"] += spent
            cost["curve_s_paper"] += spent0
            cost["run_s"] += dur
            for soil, r2 in card["r2_mu_curve"].items():
                row = {"scenario": scn, "seed": seed, "soil": soil, "slip_span": spans.get(soil, math.nan),
                       "chain_r2": r2, "chain_path": card["curves"].get(soil, {}).get("curve_path", ""),
                       **{f"chain_{k}": v for k, v in per_soil.get(soil, {}).items()},
                       "pairs_r2": pairs.get(soil, {}).get("r2", math.nan),
                       "pairs_path": pairs.get(soil, {}).get("path", ""),
                       "pairs_r2_front": pairs.get(soil, {}).get("r2_front", math.nan),
                       "pairs_r2_rear": pairs.get(soil, {}).get("r2_rear", math.nan),
                       "exact_r2": exact.get(soil, {}).get("r2", math.nan),
                       "exact_range_r2": exact.get(soil, {}).get("range_r2", math.nan),
                       "exact_path": exact.get(soil, {}).get("path", ""),
                       "exact_load_r2": exact_load.get(soil, {}).get("r2", math.nan),
                       "exact_load_range_r2": exact_load.get(soil, {}).get("range_r2", math.nan),
                       "exact_load_path": exact_load.get(soil, {}).get("path", ""),
                       "mu_mean_abs_rel_error": card.get("mu_mean_abs_rel_error", math.nan)}
                # issue 13's target: R² ≥ 0.98 where the soil's slip span is ≥ 0.04 (over [0, 0.4], the
                # scorecard's figure; the range R² beside it says how much of that is extrapolation)
                row["target_applies"] = bool(row["slip_span"] >= TARGET_SPAN)
                row["target_met"] = bool(row["target_applies"] and r2 >= TARGET_R2)
                # the same threshold over the soil's own slip range (5-95 % of its true slips): a second
                # definition, reported beside the issue's, never instead of it
                row["target_met_range"] = bool(row["target_applies"] and row.get("chain_range_r2", math.nan) >= TARGET_R2)
                rows.append(row)
                sno = f"{row.get('chain_soil_no', -1)} ({row.get('chain_soil_share', math.nan) * 100:.0f}%)"
                lo, hi = row.get("chain_slip_range", (math.nan, math.nan))
                print(f"{scn:22s} {seed:4d} {soil:16s} {row['slip_span']:6.3f} {f'{lo:.3f}-{hi:.3f}':>12s} {r2:9.4f} "
                      f"{row.get('chain_range_r2', math.nan):9.4f} {sno:>9s} {row['chain_path']:20s} "
                      f"{row['pairs_r2']:9.4f} {row['pairs_path']:20s} {row['pairs_r2_front']:6.3f} "
                      f"{row['pairs_r2_rear']:6.3f}")
    print("\nThe identification on the truth's exact per-wheel pairs (no slip or μ error; soil segments from the"
          " identification's own change test, as in the chain), load term as the run's / on, R2 over [0, 0.4] and over the soil's slip range;"
          "\nthe errors of the chain's pairs per axle in work: sd of e_s and e_mu, corr(e_mu, e_s), corr(e_s, s), gain of s-hat on s")
    print(f"{'scenario':22s} {'seed':>4s} {'soil':16s} {'exact R2':>9s} {'range':>7s} {'exact+load':>10s} {'range':>7s} "
          f"{'exact path, run / load on':34s} {'axle':5s} {'sd e_s':>7s} {'sd e_mu':>7s} {'c(mu,s)':>7s} {'c(s,s)':>7s} {'s gain':>6s}")
    for row in rows:
        for axle in ("front", "rear"):
            er = row.get(f"chain_errors_{axle}", {})
            head = (f"{row['scenario']:22s} {row['seed']:4d} {row['soil']:16s} {row['exact_r2']:9.4f} {row['exact_range_r2']:7.4f} "
                    f"{row['exact_load_r2']:10.4f} {row['exact_load_range_r2']:7.4f} "
                    f"{row['exact_path'] + ' / ' + row['exact_load_path']:34s}" if axle == "front" else " " * 113)
            print(f"{head} {axle:5s} {er.get('s_sd', math.nan):7.4f} {er.get('mu_sd', math.nan):7.4f} "
                  f"{er.get('corr_mu_s', math.nan):+7.2f} {er.get('corr_s_true', math.nan):+7.2f} {er.get('s_gain', math.nan):6.2f}")
    app = [r for r in rows if r["target_applies"]]
    print(f"R2 >= {TARGET_R2} where the slip span >= {TARGET_SPAN}: {sum(r['target_met'] for r in app)} of {len(app)} "
          f"soil runs; not met: " + (", ".join(f"{r['scenario']}/{r['seed']}/{r['soil']} {r['chain_r2']:.3f}"
                                                for r in app if not r["target_met"]) or "none"))
    print(f"  over each soil's own slip range (5-95 % of its true slips): {sum(r['target_met_range'] for r in app)} of "
          f"{len(app)}; on the truth's exact pairs, over [0, 0.4]: {sum(r['exact_r2'] >= TARGET_R2 for r in app)} of "
          f"{len(app)} (load term on: {sum(r['exact_load_r2'] >= TARGET_R2 for r in app)})")
    steps = cost["run_s"] * 100.0
    figures = {"curve_us_per_step": cost["curve_s_shape"] / steps * 1e6,
               "curve_us_per_step_paper_path": cost["curve_s_paper"] / steps * 1e6, "load": load, "rows": rows}
    print(f"curve_us_per_step {figures['curve_us_per_step']:.2f} (paper path only: "
          f"{figures['curve_us_per_step_paper_path']:.2f})")
    args.json.write_text(json.dumps(figures, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
