"""Bus-rate benchmark: the estimator with its inputs at the rates real buses send them.

Run from the repository root::

    python benchmarks/bus_rates.py [--seed 7] [--duration S] [--jitter-s J] [--json OUT.json]

For each rate pair — wheel speeds and drive torques (``SensorSpec.wheel_rate_hz``),
front-axle load and draft (``SensorSpec.loadpin_rate_hz``) — the project's
simulator writes a ``paper-three-soils`` recording with those sensor figures
(everything else as the scenario; ``--jitter-s`` sets ``can_jitter_s``, the
frames' arrival delay, uniform in [0, J]), and the recording is replayed at
the default 100 Hz with its own ``vehicle.toml``, as ``tractionecu replay``
does.  Truth model: the project's simulator (it shares the filter's
equations).  One line per rate pair:

``valid_in_work``
    share of estimator steps with ``valid`` while the implement is in work
    (``truth.csv`` column ``work``);
``timeout_in_work``
    share of those steps with any timeout bit (0x01–0x10);
``mu_err``
    μ mean absolute relative error (the scorecard's ``mu_mean_abs_rel_error``);
``nis95``
    share of updates with NIS inside its two-sided 95 % χ² interval;

and the ratio of ``mu_err`` and of ``valid_in_work`` to those of the 100 Hz
baseline measured in the same run.  Issue 13's target: wheel and torque data
at 20 Hz with draft at 10 Hz, valid ≥ 95 % of work time and μ error ≤ 1.5 %.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tractionecu.config import SensorSpec, replace  # noqa: E402
from tractionecu.evaluation.scoring import read_truth, scorecard  # noqa: E402
from tractionecu.pipeline.replay import replay  # noqa: E402
from tractionecu.recording.reader import read_recording  # noqa: E402
from tractionecu.sim import scenarios  # noqa: E402
from tractionecu.sim.simulator import simulate  # noqa: E402
from tractionecu.sim.writer import write_recording  # noqa: E402

RATES = ((100.0, 50.0), (50.0, 50.0), (20.0, 10.0), (10.0, 10.0))
"""(wheel and torque, axle load and draft) rates [Hz]; the first is the baseline (the SensorSpec defaults)."""

TIMEOUT_BITS = 0x1F


def measure(rec_dir: Path, wheel_hz: float, pin_hz: float, seed: int, duration: float | None,
            jitter_s: float) -> dict[str, float]:
    """Simulate, write, replay and score one rate pair (module doc)."""
    sensors = replace(SensorSpec(), wheel_rate_hz=wheel_hz, loadpin_rate_hz=pin_hz, can_jitter_s=jitter_s)
    scn = scenarios.get("paper-three-soils", seed=seed, duration_s=duration, sensors=sensors)
    write_recording(scn, simulate(scn), rec_dir)
    res = replay(read_recording(rec_dir))
    arr = res.arrays
    truth = read_truth(rec_dir / "truth.csv", rec_dir / "truth.toml")
    sc = scorecard(arr, truth)
    head = (rec_dir / "truth.csv").read_text(encoding="utf-8").split("\n", 1)[0].split(",")
    work_t = np.loadtxt(rec_dir / "truth.csv", delimiter=",", skiprows=1, usecols=[head.index("work")]) > 0.5
    k = np.clip(np.searchsorted(truth.t, arr["t"] + 1e-9, side="right") - 1, 0, len(truth.t) - 1)
    work = work_t[k]
    return {"wheel_hz": wheel_hz, "pin_hz": pin_hz,
            "valid_in_work": float(np.mean(arr["valid"][work])),
            "timeout_in_work": float(np.mean((arr["status"][work] & TIMEOUT_BITS) != 0)),
            "mu_err": float(sc.get("mu_mean_abs_rel_error", np.nan)),
            "nis95": float(sc.get("nis_within_95", np.nan))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--duration", type=float, default=None, help="stop each run after this many seconds [s]")
    ap.add_argument("--jitter-s", type=float, default=SensorSpec().can_jitter_s,
                    help="CAN arrival jitter, uniform in [0, J] [s] (default: the SensorSpec figure)")
    ap.add_argument("--json", default=None, help="also write the figures to this JSON file")
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bus_rates_") as tmp:
        for wheel_hz, pin_hz in RATES:
            rows.append(measure(Path(tmp) / f"w{wheel_hz:g}_p{pin_hz:g}", wheel_hz, pin_hz, args.seed,
                                args.duration, args.jitter_s))
    base = rows[0]
    print(f"paper-three-soils seed {args.seed}, CAN jitter 0–{args.jitter_s * 1e3:g} ms, estimator at 100 Hz")
    for r in rows:
        r["mu_err_ratio"] = r["mu_err"] / base["mu_err"]
        r["valid_ratio"] = r["valid_in_work"] / base["valid_in_work"]
        print(f"wheel+torque {r['wheel_hz']:>5g} Hz, axle+draft {r['pin_hz']:>4g} Hz: "
              f"valid_in_work {r['valid_in_work'] * 100:6.2f} %  timeout_in_work {r['timeout_in_work'] * 100:5.2f} %  "
              f"mu_err {r['mu_err'] * 100:5.2f} %  nis95 {r['nis95'] * 100:5.1f} %  "
              f"(vs 100 Hz: mu_err x{r['mu_err_ratio']:.2f}, valid x{r['valid_ratio']:.3f})")
    if args.json:
        Path(args.json).write_text(json.dumps({"seed": args.seed, "jitter_s": args.jitter_s, "rows": rows}, indent=2)
                                   + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
