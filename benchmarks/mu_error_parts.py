"""What the μ error of one replay is made of: work and headland, wheel, soil, frequency band, and the
estimate's response to the truth's own μ variation.

Run from the repository root::

    python benchmarks/mu_error_parts.py [--scenario physical-declared-exact] [--seed 0]
                                        [--wheel-hz 20 --pin-hz 10] [--json OUT.json]

The scenario is simulated with ``--seed`` (``--wheel-hz`` / ``--pin-hz`` set the simulator's
``SensorSpec.wheel_rate_hz`` / ``loadpin_rate_hz``, as the bus rows of ``benchmarks/estimator.py``) and
replayed at 100 Hz on its own ``vehicle.toml``, as ``tractionecu replay`` does.  The total is the
scorecard's ``mu_mean_abs_rel_error`` (every step after the first convergence, per wheel, where the true
|μ| ≥ 0.05); each part below is given as its own mean and as its **contribution** to that total (the sum
of its absolute relative errors over the total's count: the contributions of a partition add up to the
total).  Printed:

``parts``
    work (implement in work, ``truth.csv`` ``work``) and not in work (headland turns, transport), the
    latter split into straight and turning (|curvature| ≥ 0.001 1/m; the paper truth writes no curvature,
    its steps all count as straight); the turning steps (in work or not) on the turn's outer and on its inner
    wheels, which the lateral load transfer loads and unloads; valid and not valid steps; per
    wheel; per soil in work.
``blocks``
    the mean absolute relative error in work after averaging the signed error over blocks of 10 ms to 2 s
    (what is left at each time scale: a ring averages out in blocks longer than its period, a bias does
    not).
``bands``
    share of the variance of the signed error in work per frequency band (periodogram over the steps in
    work, per wheel, summed).
``response``
    the estimate against the truth's own μ in work (Welch cross-spectrum, 5.12 s segments), per wheel
    and frequency: the gain |H| and phase of μ̂ over μ (1 and 0 at a perfect estimate; a phase near ±π
    at a frequency means the estimate there moves against the truth and adds to the error), the truth's
    spectral density and the error's.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.signal import csd, welch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tractionecu.config import SensorSpec, replace  # noqa: E402
from tractionecu.evaluation.scoring import read_truth, scorecard  # noqa: E402
from tractionecu.pipeline.replay import replay  # noqa: E402
from tractionecu.recording.reader import read_recording  # noqa: E402
from tractionecu.sim import scenarios  # noqa: E402
from tractionecu.sim.simulator import simulate  # noqa: E402
from tractionecu.sim.writer import write_recording  # noqa: E402

BLOCKS_S = (0.01, 0.05, 0.1, 0.25, 0.5, 1.0, 2.0)
BANDS_HZ = ((0.0, 0.5), (0.5, 1.0), (1.0, 2.0), (2.0, 3.0), (3.0, 5.0), (5.0, 7.0), (7.0, 10.0), (10.0, 20.0),
            (20.0, 50.0))
RESPONSE_HZ = (1.0, 2.0, 3.0, 4.0, 5.0, 5.5, 6.0, 6.5, 7.0, 8.0)
STEP_S = 0.01


def _truth_columns(rec_dir: Path, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The named ``truth.csv`` columns that the recording has (the paper truth writes no ``curvature``)."""
    head = (rec_dir / "truth.csv").read_text(encoding="utf-8").split("\n", 1)[0].split(",")
    have = [n for n in names if n in head]
    cols = np.loadtxt(rec_dir / "truth.csv", delimiter=",", skiprows=1, usecols=[head.index(n) for n in have],
                      ndmin=2)
    return {n: cols[:, j] for j, n in enumerate(have)}


def parts(rec_dir: Path) -> dict:
    """Replay ``rec_dir`` and decompose its μ error (module doc)."""
    res = replay(read_recording(rec_dir))
    a = res.arrays
    tr = read_truth(rec_dir / "truth.csv", rec_dir / "truth.toml")
    sc = scorecard(a, tr)
    cols = _truth_columns(rec_dir, ("work", "curvature"))
    k = np.clip(np.searchsorted(tr.t, a["t"] + 1e-9, side="right") - 1, 0, len(tr.t) - 1)
    valid = np.asarray(a["valid"], dtype=bool)
    i0 = int(np.argmax(valid))
    sl = slice(i0, None)
    mt, me = tr.mu[k][sl], a["mu"][sl]
    work = cols["work"][k][sl] > 0.5
    # turning: |curvature| ≥ 0.001 1/m (a truth without the column: every step counted straight)
    turn = np.abs(cols["curvature"][k][sl]) >= 1e-3 if "curvature" in cols else np.zeros(len(work), dtype=bool)
    big = np.abs(mt) >= 0.05
    rel = np.where(big, (me - mt) / np.maximum(np.abs(mt), 1e-12), np.nan)
    fin = np.isfinite(rel)
    n = int(fin.sum())
    out: dict = {"mu_err": float(sc["mu_mean_abs_rel_error"]), "mu_bias": float(sc["mu_mean_rel_bias"]),
                 "valid_work": float(valid[sl][work].mean()) if work.any() else float("nan")}

    def part(mask_steps: np.ndarray, wheel: int | None = None, wheels: np.ndarray | None = None) -> dict:
        m = np.broadcast_to(mask_steps[:, None], rel.shape) & fin
        if wheel is not None:
            keep = np.zeros(4, dtype=bool)
            keep[wheel] = True
            m = m & keep
        if wheels is not None:
            m = m & wheels
        e = rel[m]
        return {"share": float(m.sum() / n), "own": float(np.abs(e).mean()) if e.size else float("nan"),
                "signed": float(e.mean()) if e.size else float("nan"), "contribution": float(np.abs(e).sum() / n)}

    ones = np.ones(len(rel), dtype=bool)
    v = valid[sl]
    out["parts"] = {"work": part(work), "not in work": part(~work), "not in work, straight": part(~work & ~turn),
                    "not in work, turning": part(~work & turn), "valid": part(v), "not valid": part(~v)}
    if "curvature" in cols:
        # the turn's outer wheels (κ > 0, a left turn: the right wheels FR, RR) and inner wheels, where the
        # lateral load transfer moves the loads (docs/results/estimator.md, "Turns"); turning steps in and out of work
        left = (cols["curvature"][k][sl] > 0.0)[:, None]
        right_w = np.array([False, True, False, True])[None, :]
        outer = np.where(left, right_w, ~right_w)
        out["parts"]["turning, outer wheels"] = part(turn, wheels=outer)
        out["parts"]["turning, inner wheels"] = part(turn, wheels=~outer)
    for i, w in enumerate(("FL", "FR", "RL", "RR")):
        out["parts"][f"wheel {w}"] = part(ones, i)
        out["parts"][f"wheel {w} in work"] = part(work, i)
    soil = tr.soil_id[k][sl]
    for sid in np.unique(soil):
        name = tr.soil_name[int(np.flatnonzero(tr.soil_id == sid)[0])]
        out["parts"][f"soil {name} in work"] = part(work & (soil == sid))
    # time scales: block means of the signed error in work (steps in work, all four wheels finite)
    ew = rel[work & fin.all(axis=1)]
    out["blocks"] = {}
    for b in BLOCKS_S:
        nb = max(1, int(round(b / STEP_S)))
        q = len(ew) // nb
        out["blocks"][f"{b:g} s"] = float(np.abs(ew[:q * nb].reshape(q, nb, 4).mean(axis=1)).mean()) if q else float("nan")
    x = ew - ew.mean(axis=0)
    p = (np.abs(np.fft.rfft(x, axis=0)) ** 2).sum(axis=1)
    f = np.fft.rfftfreq(len(x), STEP_S)
    tot = p[1:].sum()
    out["bands"] = {f"{lo:g}-{hi:g} Hz": float(p[(f >= lo) & (f < hi) & (f > 0)].sum() / tot) for lo, hi in BANDS_HZ}
    # response of the estimate to the truth's μ in work
    w_all = work & fin.all(axis=1) & np.isfinite(me).all(axis=1)
    out["response"] = {}
    for i, w in enumerate(("FL", "FR", "RL", "RR")):
        xt, ye = mt[w_all, i], me[w_all, i]
        fr, pxy = csd(xt, ye, fs=1.0 / STEP_S, nperseg=512)
        _, pxx = welch(xt, fs=1.0 / STEP_S, nperseg=512)
        _, pee = welch(ye - xt, fs=1.0 / STEP_S, nperseg=512)
        h = pxy / pxx
        rows = []
        for fq in RESPONSE_HZ:
            j = int(np.argmin(np.abs(fr - fq)))
            rows.append({"f_hz": float(fr[j]), "gain": float(abs(h[j])), "phase_rad": float(np.angle(h[j])),
                         "psd_truth": float(pxx[j]), "psd_error": float(pee[j])})
        out["response"][w] = rows
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenario", default="physical-declared-exact")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--wheel-hz", type=float, default=None, help="wheel speed and torque frame rate [Hz]")
    ap.add_argument("--pin-hz", type=float, default=None, help="axle load and draft rate [Hz]")
    ap.add_argument("--recording", default=None, help="decompose this recording instead of simulating one")
    ap.add_argument("--json", default=None, help="also write the figures to this JSON file")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="mu_parts_") as tmp:
        if args.recording:
            rec_dir = Path(args.recording)
        else:
            changes = {}
            if args.wheel_hz:
                changes["wheel_rate_hz"] = args.wheel_hz
            if args.pin_hz:
                changes["loadpin_rate_hz"] = args.pin_hz
            kw = {"sensors": replace(SensorSpec(), **changes)} if changes else {}
            scn = scenarios.get(args.scenario, seed=args.seed, **kw)
            rec_dir = Path(tmp) / "rec"
            write_recording(scn, simulate(scn), rec_dir)
        r = parts(rec_dir)
    what = args.recording or f"{args.scenario} seed {args.seed}" + (
        f", wheel {args.wheel_hz:g} Hz, pins {args.pin_hz:g} Hz" if args.wheel_hz or args.pin_hz else "")
    print(f"{what}: mu_err {r['mu_err'] * 100:.3f} %  mu_bias {r['mu_bias'] * 100:+.3f} %  "
          f"valid_work {r['valid_work'] * 100:.2f} %")
    print(f"{'part':32s} {'share':>6s} {'own':>7s} {'signed':>8s} {'contribution':>12s}")
    for name, p in r["parts"].items():
        print(f"{name:32s} {p['share']:6.3f} {p['own'] * 100:6.2f}% {p['signed'] * 100:+7.2f}% {p['contribution'] * 100:11.3f}%")
    print("in work, signed error averaged over blocks: " + "  ".join(f"{k} {v * 100:.2f}%" for k, v in r["blocks"].items()))
    print("in work, variance share by band: " + "  ".join(f"{k} {v:.3f}" for k, v in r["bands"].items()))
    for w, rows in r["response"].items():
        print(f"response {w}: " + "  ".join(f"{q['f_hz']:.1f} Hz |H| {q['gain']:.2f} {q['phase_rad']:+.2f} rad" for q in rows))
    if args.json:
        Path(args.json).write_text(json.dumps({"what": what, **r}, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
