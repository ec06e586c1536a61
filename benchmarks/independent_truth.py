"""The estimator on an independent truth model: recordings of a simulator that shares no code with the package.

Run from the repository root::

    python benchmarks/independent_truth.py --json OUT [--only straight,curves ...] [--keep DIR] [--seed N] [--variants]

Each case is simulated by ``benchmarks/independent_sim.py`` (its module doc: a tanh tyre curve, its own load
transfer, Ackermann wheel speeds, traction control, datasheet sensor noise), replayed as ``tractionecu replay``
replays it, and scored against that simulator's own truth (``independent_truth.csv``), which the replay never
reads.  Per case: valid share in work, the mean absolute relative μ error over the valid steps in work with
|μ| ≥ 0.05 (per wheel; machine level for the mechanical tractor: ΣF/ΣF_z), its signed part, the share of those
steps whose true μ lies within the reported 2σ, the ρ_s error and its 2σ coverage, the slip error where the slip
is supported (status 0x2000 clear), valid steps reversing with the wrong sign, and valid steps below 0.1 m/s.

Cases (``straight2`` etc. are the simulator's scenarios; sensor changes as stated):

========== ================================================================================================
straight   two soils, 160 s
curves     30 m arcs left then right, 120 s
reverse    forward, a stop, 1 m/s in reverse, forward again, 100 s
stops      two stops in work, 120 s
bus-20-10  ``straight`` with wheel and torque frames at 20 Hz, load pins at 10 Hz
biased     ``straight`` with every sensor error at its tolerance at once: torque gain ±2 %, offset ±20 N·m,
           axle-load offset −300 N, draft offset +300 N, hub efficiency 0.94 declared 0.96 ± 0.02
mechanical the mechanical tractor (EEC1, ETC2, CCVS1, EBC2, GBSD, hitch) on the two soils, 160 s
========== ================================================================================================

``--variants`` adds recordings no setting of the estimator was ever tried on (each with its own seed, the
``--seed`` option aside):

========================= ======================================================================================
stuck-mud                 firm soil, then mud (μ_max 0.50, s_c 0.20, ρ_s 0.12) under a 30 kN draft, 60 s
straight-seed7            ``straight`` with the simulator's seed 7
straight-usb-jitter       ``straight`` with the frames delivered in 8 ms USB batches, stamped on arrival
straight-gnss-latency-0.1 ``straight`` with the GNSS epochs 0.1 s late (not declared)
straight-no-tcs           ``straight`` without the drive's traction control
curves-seed5              ``curves`` with the simulator's seed 5
stops-seed3               ``stops`` with the simulator's seed 3
mechanical-seed7          ``mechanical`` with the simulator's seed 7
mechanical-usb-jitter     ``mechanical`` with the frames in 8 ms USB batches
mechanical-eta-0.86       ``mechanical`` with a drive line of efficiency 0.86 where the vehicle file declares
                          0.90 ± 0.03: outside the declared tolerance
========================= ======================================================================================
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import independent_sim as isim  # noqa: E402

from tractionecu.pipeline.rundir import replay_to_dir  # noqa: E402

WHEELS = ("FL", "FR", "RL", "RR")
SLIP_UNCERTAIN = 0x2000

CASES: dict[str, tuple[str, dict]] = {
    "straight": ("straight2", {}),
    "curves": ("curve30", {}),
    "reverse": ("reverse", {}),
    "stops": ("stops", {}),
    "bus-20-10": ("straight2", {"wheel_rate": 20.0, "load_rate": 10.0}),
    "biased": ("straight2", {"torque_gain": [1.02, 0.98, 0.98, 1.02], "torque_off": [-20.0, 20.0, 20.0, -20.0],
                             "axle_off": -300.0, "draft_off": 300.0, "eta_true": 0.94, "eta_decl": 0.96,
                             "eta_tol": 0.02}),
    "mechanical": ("mech2", {}),
}


VARIANTS: dict[str, tuple[str, dict]] = {
    "stuck-mud": ("stuck", {}),
    "straight-seed7": ("straight2", {"seed": 7}),
    "straight-usb-jitter": ("straight2", {"jitter": "usb"}),
    "straight-gnss-latency-0.1": ("straight2", {"gps_latency": 0.1}),
    "straight-no-tcs": ("straight2", {"tcs": False}),
    "curves-seed5": ("curve30", {"seed": 5}),
    "stops-seed3": ("stops", {"seed": 3}),
    "mechanical-seed7": ("mech2", {"seed": 7}),
    "mechanical-usb-jitter": ("mech2", {"jitter": "usb"}),
    "mechanical-eta-0.86": ("mech2", {"eta_true": 0.86}),
}


def score(rec: Path, run: Path, machine: bool) -> dict:
    """The case's figures (module doc) from ``independent_truth.csv`` and the replay's ``estimates.csv``."""
    import pandas as pd

    tr = np.genfromtxt(rec / "independent_truth.csv", delimiter=",", names=True)
    es = pd.read_csv(run / "estimates.csv")
    t = es["t"].to_numpy()

    def at(col: str) -> np.ndarray:
        return np.interp(t, tr["t"], tr[col])

    valid = es["valid"].to_numpy().astype(bool)
    status = es["status"].to_numpy().astype(np.int64)
    vt = at("v")
    work = (at("work") > 0.5) & (np.abs(vt) > 0.5)
    sel = valid & work
    out: dict = {"steps": int(t.size), "valid_work": float(valid[work].mean()) if work.any() else float("nan")}
    if machine:       # one μ for the machine: ΣF/ΣF_z of the truth against the reported (equal) wheels' μ
        f = sum(at(f"mu_{w}") * at(f"fz_{w}") for w in WHEELS) / sum(at(f"fz_{w}") for w in WHEELS)
        pairs = [(f, es["mu_RL"].to_numpy(), es["sigma_mu_RL"].to_numpy())]
    else:
        pairs = [(at(f"mu_{w}"), es[f"mu_{w}"].to_numpy(), es[f"sigma_mu_{w}"].to_numpy()) for w in WHEELS]
    err, bias, cover = [], [], []
    for mt, me, sg in pairs:
        big = sel & (np.abs(mt) >= 0.05)
        err.append(np.abs(me - mt)[big] / np.abs(mt[big]))
        bias.append((me - mt)[big] / np.abs(mt[big]))
        cover.append((np.abs(me - mt) <= 2.0 * sg)[big])
    err, bias, cover = (np.concatenate(x) for x in (err, bias, cover))
    out.update(mu_err=float(err.mean()) if err.size else float("nan"),
               mu_bias=float(bias.mean()) if bias.size else float("nan"),
               mu_cover=float(cover.mean()) if cover.size else float("nan"))
    rt, re_, srh = at("rho_s"), es["rho_s"].to_numpy(), es["sigma_rho_s"].to_numpy()
    ok = sel & np.isfinite(re_)
    out["rho_err"] = float(np.mean(np.abs(re_ - rt)[ok])) if ok.any() else float("nan")
    out["rho_cover"] = float(np.mean((np.abs(re_ - rt) <= 2.0 * srh)[ok])) if ok.any() else float("nan")
    sup = sel & ((status & SLIP_UNCERTAIN) == 0)
    slip = [np.abs(es[f"slip_{w}"].to_numpy() - at(f"slip_{w}"))[sup] for w in WHEELS] if not machine else []
    se = np.concatenate(slip) if slip else np.empty(0)
    out["slip_err"] = float(se.mean()) if se.size else float("nan")
    rev = valid & (vt < -0.5)
    out["rev_steps"] = int(rev.sum())
    out["rev_wrong_sign"] = int(np.sum(rev & (es["v"].to_numpy() > 0.0)))
    out["still_valid"] = int(np.sum(valid & (np.abs(vt) < 0.1)))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", required=True, help="write the figures here")
    ap.add_argument("--only", default="", help="comma-separated cases (default: all; module doc)")
    ap.add_argument("--keep", default=None, help="keep recordings and replays in this directory")
    ap.add_argument("--seed", type=int, default=0, help="the simulator's seed")
    ap.add_argument("--variants", action="store_true", help="also the variants never tried before (module doc)")
    args = ap.parse_args(argv)
    only = [c for c in args.only.split(",") if c]
    cases = {**CASES, **(VARIANTS if args.variants or any(c in VARIANTS for c in only) else {})}
    unknown = [c for c in only if c not in cases]
    if unknown:
        ap.error(f"unknown case(s) {', '.join(unknown)}; cases: {', '.join({**CASES, **VARIANTS})}")
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="tecu-indep-"))
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    print(f"{'case':25s} {'valid_work':>10s} {'mu_err':>7s} {'mu_bias':>8s} {'mu_2s':>6s} {'rho_err':>8s} "
          f"{'rho_2s':>6s} {'slip_err':>8s} {'rev_n':>6s} {'rev_wrong':>9s} {'still_valid':>11s}", flush=True)
    for name, (scenario, changes) in cases.items():
        if only and name not in only:
            continue
        cfg = {**isim.SCEN[scenario], "seed": args.seed, **changes}
        rec, run = work / f"rec-{name}", work / f"run-{name}"
        t0 = time.perf_counter()
        isim.run(dict(cfg), str(rec))
        replay_to_dir(str(rec), run, write_map=False)
        r = score(rec, run, machine=bool(cfg.get("mech")))
        r.update(case=name, scenario=scenario, changes=changes, seed=cfg["seed"], seconds=time.perf_counter() - t0)
        rows.append(r)
        print(f"{name:25s} {r['valid_work'] * 100:9.2f}% {r['mu_err'] * 100:6.2f}% {r['mu_bias'] * 100:+7.2f}% "
              f"{r['mu_cover'] * 100:5.1f}% {r['rho_err']:8.4f} {r['rho_cover'] * 100:5.1f}% {r['slip_err']:8.4f} "
              f"{r['rev_steps']:6d} {r['rev_wrong_sign']:9d} {r['still_valid']:11d}", flush=True)
    Path(args.json).write_text(json.dumps({"truth": "independent (benchmarks/independent_sim.py)", "rows": rows},
                                          indent=1, default=float) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
