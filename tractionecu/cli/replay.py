"""``tractionecu replay REC --out RUN [--rate 100] [--plot]``: run the estimator over a recording.

The recording is decoded (CAN through the DBC, NMEA with UTC alignment) and
the estimator is stepped on a fixed grid of ``rate`` Hz.  The grid's phase
follows the wheel-speed frames (grid time = frame time + ``GRID_MARGIN_S``)
so that every frame of one drive-train burst arrives in the step it belongs
to.  Inputs are held (zero-order hold inside the estimator); a measurement
or input is passed to the estimator only on the step at which a NEW sample
arrived.

Outputs in RUN:

* ``estimates.csv`` — one row per step (columns in :data:`CSV_COLUMNS`);
* ``scorecard.json`` — when the recording has ``truth.csv``
  (see :mod:`tractionecu.estimation.scoring`), also printed as a table;
* ``config.toml`` — the resolved vehicle, sensor and estimator configuration;
* with ``--plot``: ``fig6_mu_rho.png`` (true and estimated μ per wheel and
  ρ_s over time, paper Fig. 6) and ``fig5_mu_curves.png`` (identified
  against true μ(s) per soil, paper Fig. 5).

Exit codes: 0 ok, 1 the recording or configuration cannot be read (the
message names the file or key), 3 ``--plot`` without matplotlib.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import tomllib
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..config import VehicleParams, load_vehicle, to_toml
from ..errors import ConfigError
from ..estimation.estimator import Estimate, Estimator, EstimatorConfig
from ..model.vehicle import N_STATE, STATE_NAMES, WHEELS
from ..recording.reader import Recording, read_recording
from ..sim.sensors import SensorSpec

_BATCH = 2048
"""Estimates kept before they are copied into the result arrays (bounded memory, bulk copies)."""

GRID_MARGIN_S = 0.0015
"""Grid time after the wheel-speed frame time [s]: covers CAN arrival jitter and the spread of one burst."""

CSV_COLUMNS = tuple(["t"] + [f"mu_{w}" for w in WHEELS] + ["rho_s", "a", "soil_class"] + [f"slip_{w}" for w in WHEELS]
               + ["v"] + [f"omega_{w}" for w in WHEELS] + [f"var_{n}" for n in STATE_NAMES]
               + ["nis", "nis_dof", "adapt", "status", "valid"])


def add_subparser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="run the estimator over a recording; score it against truth if present")
    p.add_argument("recording", metavar="REC", help="recording directory")
    p.add_argument("--out", required=True, metavar="RUN", help="output directory")
    p.add_argument("--rate", type=float, default=100.0, help="estimator rate [Hz] (default: %(default)s)")
    p.add_argument("--plot", action="store_true", help="also write the paper's Fig. 5 and Fig. 6 as PNG")
    p.add_argument("--no-map", action="store_true", help="do not write map tiles (RUN/map) and map_scorecard.json")
    p.add_argument("--config", metavar="TOML", default=None,
                   help="estimator configuration ([estimator] table, optional [estimator.fuzzy])")
    p.add_argument("--classes", default=None, metavar="A,B,...",
                   help="surface classes to fit (overrides the configuration), e.g. stubble,grassland,tilled,road")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    cfg = load_config(args.config) if args.config else EstimatorConfig()
    if args.classes:
        from ..config import replace
        cfg = replace(cfg, soil_classes=tuple(c.strip() for c in args.classes.split(",") if c.strip()))
    if not args.rate > 0:
        raise ConfigError(f"--rate: must be > 0, got {args.rate}")
    if args.plot:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            print("tractionecu replay: --plot needs matplotlib (pip install 'tractionecu[maps]')", file=sys.stderr)
            return 3
    res = replay(args.recording, args.out, rate_hz=args.rate, plot=args.plot, cfg=cfg, write_map=not args.no_map)
    print(format_summary(res))
    return 0


def load_config(path: str | Path) -> EstimatorConfig:
    """Read an estimator TOML file (``[estimator]`` table or keys at top level)."""
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise ConfigError(f"{p}: configuration file not found") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read: {exc}") from exc
    except ValueError as exc:  # TOMLDecodeError, or an integer literal beyond Python's 4300-digit limit
        raise ConfigError(f"{p}: not valid TOML: {exc}") from exc
    return EstimatorConfig.from_mapping(data.get("estimator", data))


# ----------------------------------------------------------------------------- streams
def _arrivals(src_t: np.ndarray, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the latest sample at or before each grid time and whether it is new at that step."""
    idx = np.searchsorted(src_t, grid, side="right") - 1
    prev = np.concatenate([[-1], idx[:-1]])
    return idx, (idx >= 0) & (idx != prev)


GRID_MAX_GAP_S = 2.0
"""Wheel-speed gaps longer than this [s] are left out of the replay grid."""


def build_grid(rec: Recording, rate_hz: float) -> np.ndarray:
    """Fixed-rate grid [s] phased to the wheel-speed frames (see module doc)."""
    ws = rec.signals.get("WheelSpeed_FL")
    if ws is None or len(ws) == 0:
        raise ConfigError("recording has no WheelSpeed_FL signal (TECU_WheelSpeeds)")
    t0 = float(ws.t[0]) + GRID_MARGIN_S
    t1 = float(rec.t_end)
    # Gaps in the wheel-speed stream longer than GRID_MAX_GAP_S (logger paused, a clock jump
    # in the capture) get no grid steps: the grid covers the spans that hold data, so a jump
    # of years cannot ask for an absurd number of steps; the estimator restarts after a gap.
    gaps = np.flatnonzero(np.diff(ws.t) > GRID_MAX_GAP_S)
    if gaps.size == 0:
        n = int(math.floor((t1 - t0) * rate_hz + 1e-9)) + 1
        return t0 + np.arange(max(n, 0)) / rate_hz
    starts = np.concatenate([[t0], ws.t[gaps + 1] + GRID_MARGIN_S])
    ends = np.concatenate([ws.t[gaps], [t1]])
    parts = []
    for a, b in zip(starts, ends):
        n = int(math.floor((float(b) - float(a)) * rate_hz + 1e-9)) + 1
        if n > 0:
            parts.append(float(a) + np.arange(n) / rate_hz)
    return np.concatenate(parts) if parts else np.empty(0)


def _group(rec: Recording, names: list[str], grid: np.ndarray) -> tuple[np.ndarray | None, np.ndarray]:
    """Values (n, k) at their arrival steps and the new-sample flags of a group of signals of one message."""
    series = [rec.signals.get(n) for n in names]
    if any(s is None or len(s) == 0 for s in series):
        return None, np.zeros(grid.size, dtype=bool)
    idx, new = _arrivals(series[0].t, grid)  # type: ignore[union-attr]
    safe = np.maximum(idx, 0)
    vals = np.column_stack([s.value[safe] for s in series])  # type: ignore[union-attr]
    return vals, new


# ----------------------------------------------------------------------------- replay
def replay(recording_path: str | Path, out_dir: str | Path, rate_hz: float = 100.0, plot: bool = False,
           on_estimate: Callable[[Estimate], None] | None = None, cfg: EstimatorConfig | None = None,
           sensors: SensorSpec | None = None, write_map: bool = True) -> dict[str, Any]:
    """Run the estimator over a recording and write the outputs (module doc).

    ``on_estimate`` is called with every :class:`Estimate` in time order (the
    map writer hooks in here).  Returns a summary dict: ``steps``,
    ``sim_seconds``, ``wall_seconds``, ``realtime_factor``, ``counters``, the
    output paths and, with truth, ``scorecard``.
    """
    wall0 = time.perf_counter()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rec = read_recording(recording_path)
    read_s = time.perf_counter() - wall0
    vehicle = load_vehicle(rec.vehicle_toml_path) if rec.vehicle_toml_path else VehicleParams()
    cfg = cfg or EstimatorConfig()
    sensors = sensors or SensorSpec()
    est = Estimator(vehicle, cfg, sensors)

    grid = build_grid(rec, rate_hz)
    n = grid.size
    md, new_md = _group(rec, [f"DriveTorque_{w}" for w in WHEELS], grid)
    om, new_om = _group(rec, [f"WheelSpeed_{w}" for w in WHEELS], grid)
    fzf, new_fzf = _group(rec, ["FrontAxleLoad"], grid)
    fdx, new_fdx = _group(rec, ["DraftForce"], grid)
    if len(rec.gps):
        gi, new_v = _arrivals(rec.gps.t, grid)
        vg = rec.gps.speed[np.maximum(gi, 0)]
    else:
        new_v, vg = np.zeros(n, dtype=bool), np.zeros(n)

    md_l = md if md is not None else None
    fz_l = fzf[:, 0].tolist() if fzf is not None else None
    fd_l = fdx[:, 0].tolist() if fdx is not None else None
    vg_l = vg.tolist()
    t_l = grid.tolist()
    new_md_l, new_om_l, new_fz_l, new_fd_l, new_v_l = (a.tolist() for a in (new_md, new_om, new_fzf, new_fdx, new_v))
    res = {k: np.empty(n) for k in ("rho_s", "a", "v", "nis", "adapt")}
    res_mu = np.empty((n, 4))
    res_slip = np.empty((n, 4))
    res_om = np.empty((n, 4))
    res_var = np.empty((n, N_STATE))
    res_dof = np.empty(n, dtype=np.int64)
    res_status = np.empty(n, dtype=np.int64)
    res_valid = np.empty(n, dtype=bool)
    res_cls: list[str] = []

    def flush(batch: list[Estimate], k0: int) -> None:
        """Copy a batch of estimates into the result arrays (rows k0..), field by field."""
        k1 = k0 + len(batch)
        for name, arr in res.items():
            arr[k0:k1] = [getattr(e, name) for e in batch]
        for name, arr in (("mu", res_mu), ("slip", res_slip), ("omega", res_om), ("P_diag", res_var)):
            arr[k0:k1] = [getattr(e, name) for e in batch]
        res_dof[k0:k1] = [e.nis_dof for e in batch]
        res_status[k0:k1] = [e.status for e in batch]
        res_valid[k0:k1] = [e.valid for e in batch]
        res_cls.extend(e.soil_class for e in batch)

    step = est.step
    batch: list[Estimate] = []
    keep = batch.append
    k0 = 0
    wall_loop = time.perf_counter()
    for k in range(n):
        inp: dict[str, Any] = {}
        if new_md_l[k]:
            inp["Md"] = md_l[k]  # type: ignore[index]
        if new_fz_l[k]:
            inp["Fzf"] = fz_l[k]  # type: ignore[index]
        if new_fd_l[k]:
            inp["Fdx"] = fd_l[k]  # type: ignore[index]
        meas: dict[str, Any] = {}
        if new_om_l[k]:
            meas["omega"] = om[k]  # type: ignore[index]
        if new_v_l[k]:
            meas["v"] = vg_l[k]
        e = step(t_l[k], inp, meas)
        keep(e)
        if on_estimate is not None:
            on_estimate(e)
        if len(batch) == _BATCH:
            flush(batch, k0)
            k0 += _BATCH
            batch.clear()
    flush(batch, k0)
    loop_s = time.perf_counter() - wall_loop

    arrays = {"t": grid, "mu": res_mu, "slip": res_slip, "omega": res_om, "P_diag": res_var, "nis_dof": res_dof,
              "status": res_status, "valid": res_valid, "soil_class": res_cls, **res}
    csv_path = out / "estimates.csv"
    t_w = time.perf_counter()
    write_estimates_csv(csv_path, arrays)
    cfg_path = out / "config.toml"
    cfg_path.write_text("# Resolved configuration of this replay (SI units)\n" + to_toml(vehicle, "vehicle") + "\n"
                        + to_toml(sensors, "sensors") + "\n" + cfg.to_toml()
                        + f"\n[replay]\nrate_hz = {float(rate_hz)!r}\ngrid_margin_s = {GRID_MARGIN_S!r}\n",
                        encoding="utf-8")
    if write_map:
        from ..mapping.from_replay import write_replay_map
        summary_map = write_replay_map(out, rec, arrays)
    else:
        summary_map = {}

    sim_s = float(grid[-1] - grid[0]) if n > 1 else 0.0
    write_s = time.perf_counter() - t_w
    summary: dict[str, Any] = {"recording": str(recording_path), "steps": int(n), "rate_hz": float(rate_hz),
                               "sim_seconds": sim_s, "read_seconds": read_s, "loop_seconds": loop_s,
                               "write_seconds": write_s, "counters": dict(est.counters),
                               "estimates_csv": str(csv_path), "config": str(cfg_path), **summary_map}
    if rec.truth_csv_path is not None:
        from ..estimation.scoring import read_truth, scorecard
        truth = read_truth(rec.truth_csv_path, rec.truth_toml_path)
        sc = scorecard(arrays, truth)
        summary["scorecard"] = sc
        if plot:
            summary["plots"] = plot_run(out, arrays, truth, sc)
    elif plot:
        summary["plots"] = plot_run(out, arrays, None, None)
    wall = time.perf_counter() - wall0
    summary["wall_seconds"] = wall
    summary["realtime_factor"] = sim_s / wall if wall > 0 else math.inf
    if "scorecard" in summary:
        sc_out = dict(summary["scorecard"])
        sc_out["realtime_factor"] = summary["realtime_factor"]
        (out / "scorecard.json").write_text(json.dumps(sc_out, indent=2, sort_keys=True) + "\n", encoding="utf-8")
        summary["scorecard_json"] = str(out / "scorecard.json")
    return summary


def write_estimates_csv(path: Path, arrays: dict[str, Any]) -> None:
    """Write ``estimates.csv`` (columns :data:`CSV_COLUMNS`)."""
    left = np.column_stack([arrays["t"], arrays["mu"], arrays["rho_s"], arrays["a"]]).tolist()
    right = np.column_stack([arrays["slip"], arrays["v"], arrays["omega"], arrays["P_diag"], arrays["nis"],
                             arrays["nis_dof"], arrays["adapt"], arrays["status"], arrays["valid"]]).tolist()
    fl = "%.3f" + ",%.6g" * 6 + ",%s,"
    fr = ",".join(["%.6g"] * 20) + ",%d,%.4g,%d,%d"
    cls = arrays["soil_class"]
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(",".join(CSV_COLUMNS) + "\n")
        fh.write("\n".join([fl % (*a, c) + fr % tuple(b) for a, c, b in zip(left, cls, right)]))
        fh.write("\n")


# ----------------------------------------------------------------------------- output
def format_summary(res: dict[str, Any]) -> str:
    """The scorecard (if any) and run figures as a plain-text table."""
    lines = [f"replay: {res['steps']} steps, {res['sim_seconds']:.1f} s simulated in {res['wall_seconds']:.2f} s "
             f"({res['realtime_factor']:.0f}x real time)"]
    sc = res.get("scorecard")
    if sc:
        if "error" in sc:
            lines.append(f"scorecard: {sc['error']}")
        else:
            rows = [("mu_mean_abs_rel_error", f"{sc['mu_mean_abs_rel_error'] * 100:.2f} %", "<= 2 %"),
                    ("mu_mean_abs_error", f"{sc['mu_mean_abs_error']:.4f}", ""),
                    ("rho_s_mean_abs_error", f"{sc['rho_s_mean_abs_error']:.4f}", ""),
                    ("reconvergence_s", f"{sc['reconvergence_s']:.2f} s", "<= 2 s"),
                    ("nis_within_95", f"{sc['nis_within_95'] * 100:.1f} %", "~95 %"),
                    ("t_first_convergence_s", f"{sc['t_first_convergence_s']:.2f} s", "")]
            for name, r2 in sc["r2_mu_curve"].items():
                c = sc["curves"].get(name, {})
                extra = f" (a {c.get('a_identified', float('nan')):.3f} vs {c.get('a_true', float('nan')):.3f})" if c else ""
                rows.append((f"r2_mu_curve[{name}]", f"{r2:.4f}{extra}", ">= 0.98"))
            w = max(len(r[0]) for r in rows)
            w2 = max(len(r[1]) for r in rows)
            lines.append(f"{'metric':<{w}}  {'value':<{w2}}  target")
            lines += [f"{a:<{w}}  {b:<{w2}}  {c}" for a, b, c in rows]
    msc = res.get("map_scorecard")
    if msc:
        lines.append(f"{'map_soil_accuracy':<22}  {msc['map_soil_accuracy'] * 100:.1f} %  (target >= 95 %)")
        lines.append(f"{'map_a_rmse':<22}  {msc['map_a_rmse']:.4f}")
        lines.append(f"{'map_rho_s_rmse':<22}  {msc['map_rho_s_rmse']:.4f}")
    if "map_samples" in res:
        lines.append(f"map: {res['map_samples']} of {res.get('map_epochs', 0)} GNSS epochs mapped -> {res['map_dir']}")
    for k in ("estimates_csv", "scorecard_json", "config"):
        if k in res:
            lines.append(f"{k}: {res[k]}")
    for p in res.get("plots", []):
        lines.append(f"plot: {p}")
    return "\n".join(lines)


def plot_run(out: Path, arrays: dict[str, Any], truth: Any, sc: dict[str, Any] | None) -> list[str]:
    """Write the paper's Fig. 6 (μ per wheel and ρ_s over time) and Fig. 5 (μ(s) per soil) as PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..model.mucurve import SOIL_CLASSES
    from ..estimation.scoring import S_GRID

    t = arrays["t"]
    tr = t - t[0]
    paths = []
    fig, axes = plt.subplots(5, 1, figsize=(10, 11), sharex=True)
    if truth is not None:
        k = np.clip(np.searchsorted(truth.t, t + 1e-9, side="right") - 1, 0, len(truth.t) - 1)
    for i, w in enumerate(WHEELS):
        ax = axes[i]
        if truth is not None:
            ax.plot(tr, truth.mu[k, i], color="tab:brown", lw=1.0, label="true")
        ax.plot(tr, arrays["mu"][:, i], color="tab:blue", lw=0.8, label="AUKF-FS")
        ax.set_ylabel(f"μ {w} [-]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right")
    ax = axes[4]
    if truth is not None:
        ax.plot(tr, truth.rho_s[k], color="tab:brown", lw=1.0, label="true")
    ax.plot(tr, arrays["rho_s"], color="tab:blue", lw=0.8, label="AUKF-FS")
    ax.set_ylabel("ρ_s [-]")
    ax.set_xlabel("t [s]")
    ax.grid(alpha=0.3)
    fig.suptitle("Adhesion per wheel and soil rolling resistance (paper Fig. 6)")
    fig.tight_layout()
    p6 = out / "fig6_mu_rho.png"
    fig.savefig(p6, dpi=110)
    plt.close(fig)
    paths.append(str(p6))

    if sc and sc.get("curves"):
        fig, ax = plt.subplots(figsize=(7, 5))
        colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        for j, (name, c) in enumerate(sc["curves"].items()):
            col = colors[j % len(colors)]
            ax.plot(S_GRID, SOIL_CLASSES[c["class_true"]].mu(S_GRID, c["a_true"]), color=col, lw=2.5, alpha=0.45,
                    label=f"{name} true (a={c['a_true']:.2f})")
            ax.plot(S_GRID, SOIL_CLASSES[c["class_identified"]].mu(S_GRID, c["a_identified"]), color=col, lw=1.2,
                    ls="--", label=f"{name} identified (a={c['a_identified']:.3f}, R²={sc['r2_mu_curve'][name]:.4f})")
        ax.set_xlabel("slip s [-]")
        ax.set_ylabel("μ [-]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
        ax.set_title("Identified vs true μ(s) per soil (paper Fig. 5)")
        fig.tight_layout()
        p5 = out / "fig5_mu_curves.png"
        fig.savefig(p5, dpi=110)
        plt.close(fig)
        paths.append(str(p5))
    return paths
