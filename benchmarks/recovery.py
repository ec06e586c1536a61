"""Never stay diverged: the estimator after faults and reverses, against the clean drive of the same run.

Run from the repository root::

    python benchmarks/recovery.py --json OUT.json [--seed 1] [--keep DIR]

Truth model: the project's own simulator (``tractionecu/sim``).  Cases:

``clean``
    ``paper-three-soils``, 150 s (the baseline of the ratios);
``wheel_burst``, ``gnss_step``, ``gap``
    the same recording with one fault 60 s in (``tractionecu.evaluation.faults``):
    2 s of wheel speeds 1.6× too high; the GNSS speed 1 m/s too high for 3 s;
    no CAN frame and no GNSS epoch for 5 s while the machine works;
``headland_reverse``
    the ``headland-reverse`` scenario in full: four passes joined by
    three-point turns with 12 m straight back at 1 m/s (negative wheel speeds
    and torques, WBSD "reverse", unsigned GNSS speed with the course turned).

Figures per case (printed, and written as JSON):

``valid_in_work``
    share of estimates marked valid while the implement is in work;
``back_after_fault_s``
    time from the fault's end to the first valid estimate (faults only);
``mu_err_in_work``
    mean over the wheels of |μ̂ − μ|/|μ|, over valid estimates in work from
    10 s after the fault's end (the whole run for the others);
``rho_mae``
    mean |ρ̂_s − ρ_s| over valid estimates;
``valid_wrong_sign``
    valid estimates whose speed has the wrong sign (true |v| > 0.05 m/s);
``lost``
    times the estimator declared itself lost.

Each case's ``valid_in_work`` and ``mu_err_in_work`` are also printed as a
ratio to the clean case's.  Targets (issue "Never stay diverged"): valid
again within 5 s of normal driving; μ within 1 % 10 s after; over the
reversing recording valid ≥ 90 % of work time, ρ_s error ≤ 0.01, no valid
estimate with the wrong sign of v.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tractionecu.evaluation.faults import cut, rewrite_can, shift_gnss_speed  # noqa: E402
from tractionecu.evaluation.scoring import read_truth  # noqa: E402
from tractionecu.pipeline.replay import replay  # noqa: E402
from tractionecu.recording.reader import read_recording  # noqa: E402
from tractionecu.sim import scenarios  # noqa: E402
from tractionecu.sim.simulator import simulate  # noqa: E402
from tractionecu.sim.writer import write_recording  # noqa: E402

FAULT_AT_S = 60.0


def figures(rec_dir: Path, fault_end: float | None) -> dict:
    rec = read_recording(rec_dir)
    res = replay(rec)
    a = res.arrays
    tr = read_truth(rec.truth_csv_path, rec.truth_toml_path)
    work_col = np.genfromtxt(rec.truth_csv_path, delimiter=",", names=True, usecols=("t", "work"))["work"]
    k = np.clip(np.searchsorted(tr.t, a["t"] + 1e-9, side="right") - 1, 0, len(tr.t) - 1)
    t, valid, work, v_true, mu = a["t"], a["valid"], work_col[k] > 0.5, tr.v[k], tr.mu[k]
    err = np.mean(np.abs(a["mu"] - mu), axis=1) / np.maximum(np.mean(np.abs(mu), axis=1), 0.05)
    late = valid & work & (t >= (fault_end + 10.0 if fault_end is not None else -np.inf))
    out = {
        "valid_in_work": float(valid[work].mean()),
        "mu_err_in_work": float(err[late].mean()),
        "rho_mae": float(np.mean(np.abs(a["rho_s"] - tr.rho_s[k])[valid])),
        "valid_wrong_sign": int(np.sum(valid & (np.sign(a["v"]) != np.sign(v_true)) & (np.abs(v_true) > 0.05))),
        "lost": int(res.counters["lost"]),
    }
    if fault_end is not None:
        back = t[(t >= fault_end) & valid]
        out["back_after_fault_s"] = float(back[0] - fault_end) if back.size else float("nan")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", required=True, help="write the figures to this JSON file")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--keep", default=None, help="keep the recordings in this directory")
    args = ap.parse_args(argv)
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="tecu-recovery-"))
    work.mkdir(parents=True, exist_ok=True)
    wall = time.perf_counter()
    base = work / "clean"
    scn = scenarios.get("paper-three-soils", seed=args.seed, duration_s=150.0)
    write_recording(scn, simulate(scn), base)
    f0 = float(read_recording(base).signals["WheelSpeed_FL"].t[0]) + FAULT_AT_S

    def burst(t: float, name: str, values: dict) -> dict:
        if name == "TECU_WheelSpeeds" and f0 <= t < f0 + 2.0:
            return {k: (x * 1.6 if k.startswith("WheelSpeed") else x) for k, x in values.items()}
        return values

    cases: dict[str, tuple[Path, float | None]] = {
        "clean": (base, None),
        "wheel_burst": (rewrite_can(base, work / "wheel_burst", burst), f0 + 2.0),
        "gnss_step": (shift_gnss_speed(base, work / "gnss_step", f0, f0 + 3.0, 1.0), f0 + 3.0),
        "gap": (cut(base, work / "gap", f0, f0 + 5.0), f0 + 5.0),
    }
    rev = work / "headland_reverse"
    scn = scenarios.get("headland-reverse", seed=args.seed)
    write_recording(scn, simulate(scn), rev)
    cases["headland_reverse"] = (rev, None)
    out = {name: figures(path, end) for name, (path, end) in cases.items()}
    ref = out["clean"]
    print(f"{'case':18s} {'valid_in_work':>13s} {'(x clean)':>9s} {'mu_err':>8s} {'(x clean)':>9s} "
          f"{'rho_mae':>8s} {'back_s':>7s} {'wrong_sign':>10s} {'lost':>4s}")
    for name, f in out.items():
        f["valid_in_work_ratio_to_clean"] = f["valid_in_work"] / ref["valid_in_work"]
        f["mu_err_ratio_to_clean"] = f["mu_err_in_work"] / ref["mu_err_in_work"]
        back = f.get("back_after_fault_s")
        print(f"{name:18s} {f['valid_in_work']:13.4f} {f['valid_in_work_ratio_to_clean']:9.3f} "
              f"{f['mu_err_in_work']:8.4f} {f['mu_err_ratio_to_clean']:9.3f} {f['rho_mae']:8.4f} "
              f"{'-' if back is None else f'{back:.2f}':>7s} {f['valid_wrong_sign']:10d} {f['lost']:4d}")
    out["seed"] = args.seed
    out["wall_seconds"] = time.perf_counter() - wall
    Path(args.json).write_text(json.dumps(out, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
