"""Smoother-lag benchmark: the delivered μ and ρ_s error against the fixed-lag smoother's lag.

Run from the repository root::

    python benchmarks/smoother_lag.py [--seed 0] [--lags 0 0.05 0.1 0.2 0.4] [--duration S] [--json OUT.json]

Each case is simulated once and replayed once per lag (``[estimator] smoother_lag_s``; everything else the
default configuration and the recording's own ``vehicle.toml``, as ``tractionecu replay`` does).  Cases:

``paper-three-soils``
    the project's simulator (it shares the filter's equations), GNSS at 10 Hz;
``paper-three-soils gnss 20 Hz`` / ``gnss 5 Hz``
    the same with ``SensorSpec.gps_rate_hz`` 20 and 5: whether the lag that pays follows the GNSS period;
``physical-three-soils`` / ``physical-declared-exact``
    the physical truth (tyre relaxation, the hub's carcass, load transfer), with the declared figures off
    inside their tolerances / exact;
``mechanical-three-soils`` / ``mechanical-bekker-soils``
    the machine-level estimator of a mechanical tractor on the Brixius and the Bekker truths (its wheel
    speeds from CCVS1, WBSD and EBC2 every 100 ms).

Per case and lag: ``mu_err`` (the scorecard's ``mu_mean_abs_rel_error``; the machine level's over its valid
estimates against ΣF_h/ΣF_z, as ``tractionecu replay`` scores it), ``rho_err`` (``rho_s_mean_abs_error``), the replay's CPU time (the step path), and the ratio of each to the filter alone
(lag 0, the baseline) measured in the same run.  The rule that holds a lag of at least two wheel-speed
periods (``smoother.MIN_WHEEL_PERIODS``) is off here, so that each lag is the one asked: the figures are
what the rule is chosen from (the hub's 100 Hz wheel speeds keep the configured 0.05 s, the machine level's
10 Hz ones take 0.2 s).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tractionecu.config import SensorSpec, replace  # noqa: E402
from tractionecu.estimation import smoother  # noqa: E402
from tractionecu.estimation.config import EstimatorConfig  # noqa: E402
from tractionecu.evaluation.machine_score import is_machine_level, machine_scorecard  # noqa: E402
from tractionecu.evaluation.scoring import read_truth, scorecard  # noqa: E402
from tractionecu.pipeline.replay import machine_of, replay  # noqa: E402
from tractionecu.recording.reader import read_recording  # noqa: E402
from tractionecu.sim import scenarios  # noqa: E402
from tractionecu.sim.simulator import simulate  # noqa: E402
from tractionecu.sim.writer import write_recording  # noqa: E402

CASES = (("paper-three-soils", None), ("paper-three-soils", 20.0), ("paper-three-soils", 5.0),
         ("physical-three-soils", None), ("physical-declared-exact", None), ("mechanical-three-soils", None), ("mechanical-bekker-soils", None))
"""(scenario, GNSS rate [Hz] or None for the scenario's own)."""


def case_name(scenario: str, gps_hz: float | None) -> str:
    return scenario if gps_hz is None else f"{scenario} gnss {gps_hz:g} Hz"


def measure(rec_dir: Path, lags: list[float]) -> list[dict[str, float]]:
    """Replay one recording once per lag and score it."""
    rec = read_recording(rec_dir)
    truth = read_truth(rec_dir / "truth.csv", rec_dir / "truth.toml")
    rows = []
    for lag in lags:
        c0 = time.process_time()
        res = replay(rec, cfg=EstimatorConfig(smoother_lag_s=lag))
        cpu = time.process_time() - c0
        if is_machine_level(res.arrays):     # one μ for the machine: against ΣF_h/ΣF_z, as tractionecu replay
            sc = machine_scorecard(res.arrays, truth, rec.truth_csv_path, machine_of(rec)[0].mass_kg)
        else:
            sc = scorecard(res.arrays, truth)
        rows.append({"lag_s": lag, "mu_err": float(sc["mu_mean_abs_rel_error"]),
                     "rho_err": float(sc["rho_s_mean_abs_error"]), "cpu_s": cpu})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--lags", type=float, nargs="+", default=[0.0, 0.05, 0.1, 0.2, 0.4],
                    help="lags [s]; the first is the baseline the ratios are taken against")
    ap.add_argument("--duration", type=float, default=None, help="stop each simulation after this many seconds [s]")
    ap.add_argument("--json", default=None, help="also write the figures to this JSON file")
    args = ap.parse_args(argv)
    smoother.MIN_WHEEL_PERIODS = 0          # each lag as asked (module doc)
    out: dict[str, list[dict[str, float]]] = {}
    with tempfile.TemporaryDirectory(prefix="smoother_lag_") as tmp:
        for scenario, gps_hz in CASES:
            name = case_name(scenario, gps_hz)
            kw = {} if gps_hz is None else {"sensors": replace(SensorSpec(), gps_rate_hz=gps_hz)}
            scn = scenarios.get(scenario, seed=args.seed, duration_s=args.duration, **kw)
            rec_dir = Path(tmp) / name.replace(" ", "_")
            write_recording(scn, simulate(scn), rec_dir)
            out[name] = rows = measure(rec_dir, args.lags)
            base = rows[0]
            for r in rows:
                r["mu_err_ratio"] = r["mu_err"] / base["mu_err"]
                r["rho_err_ratio"] = r["rho_err"] / base["rho_err"]
                r["cpu_ratio"] = r["cpu_s"] / base["cpu_s"]
                print(f"{name:36s} lag {r['lag_s']:4.2f} s: mu_err {r['mu_err'] * 100:6.3f} %  "
                      f"rho_err {r['rho_err']:.5f}  replay CPU {r['cpu_s']:6.2f} s  (vs lag {base['lag_s']:g}: "
                      f"mu_err x{r['mu_err_ratio']:.3f}, rho_err x{r['rho_err_ratio']:.3f}, "
                      f"CPU x{r['cpu_ratio']:.2f})", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps({"seed": args.seed, "cases": out}, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
