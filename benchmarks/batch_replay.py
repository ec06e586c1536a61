"""Batch replay against the step path, in one run: speed per core (CPU time) and the largest difference.

On one simulated ``paper-three-soils`` recording (``--seed``, ``--duration``; kept in ``--work``), best
of ``--repeat`` rounds, the two paths alternating within each round, timed by ``time.process_time``
(CPU seconds of this process: the machine's other jobs inflate it far less than wall time; the load
average is printed beside):

* ``engine``: the recording decoded once in memory, then :func:`tractionecu.pipeline.replay.replay`
  (the step path's loop and sink) against :func:`tractionecu.pipeline.batch.replay_batch`;
* ``path``: from the recording's path: :func:`~tractionecu.pipeline.rundir.replay_to_dir` on the step path
  (``compiled=False``: streamed decoding, ``Estimator.step`` at 100 Hz, ``estimates.csv``, the map) against
  :func:`~tractionecu.pipeline.batch.replay_batch_rows` (decoding, the loop, the 1 Hz rows and the map's
  steps) and the map;
* ``fleet task``: :func:`tractionecu.fleet.tasks.replay_task` without and with ``batch`` (Parquet, the
  farm-frame map), when pyarrow is installed: without, the task writes ``estimates.csv`` as ``tractionecu
  replay`` does (through the compiled loop where it covers the machine) and its Parquet from that text.

Real time per core = the recording's span / CPU seconds.  The equality line is the batch path's
contract: the largest absolute difference over every estimate column between the two ``engine`` runs
(target 1e-9).

The batch path's estimator loop is the compiled one (:mod:`tractionecu.estimation.compiled_loop`) where it
covers the machine, else the step path's Python estimator; the ``loop`` line says which ran and why.
``where the time goes`` is an instrumented batch run (the best of ``--repeat``): the CPU time per step in the compiled
loop, in each return to Python (the μ(s) curve's segment close and once-a-second fit ("curvefit"; its update itself
runs compiled in the loop), the curve's slope for an averaged slip, the radius calibration, the general update,
the filter's initialisation), and around it (the blocks' step arguments, the sink), and how often each return
happened.

``--config TOML`` runs every path with that estimator configuration (the fleet's ``--config``): with
``smoother_lag_s = 0.0`` the figures of the filter without the fixed-lag smoother.

    python benchmarks/batch_replay.py [--duration 60] [--seed 0] [--repeat 3] [--work DIR] [--json OUT] [--config TOML]
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

from _common import load_line as _load, simulate_recording as _simulate   # benchmarks/_common.py

TARGET_X = 1000.0
TARGET_DIFF = 1e-9


def _cpu(fn: Callable[[], Any]) -> tuple[float, float, Any]:
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return time.process_time() - c0, time.perf_counter() - w0, out


def measure(path: Path, repeat: int = 3, fleet: bool = True, cfg: Any = None) -> dict[str, Any]:
    """The figures of the module doc on the recording at ``path`` (a directory with can.log), every path run with
    the estimator configuration ``cfg`` (None: the default)."""
    from tractionecu.estimation import _kernels
    from tractionecu.pipeline.batch import max_differences, replay_batch, replay_batch_rows
    from tractionecu.mapping.from_replay import write_replay_map
    from tractionecu.pipeline.replay import replay
    from tractionecu.pipeline.rundir import replay_to_dir
    from tractionecu.recording.reader import read_recording

    _kernels.warm_up()
    scratch = Path(tempfile.mkdtemp(prefix="batch_bench_"))
    rec = read_recording(path)
    step_res = replay(rec, cfg=cfg)                         # also warms both paths' first-use costs
    span = step_res.sim_seconds
    batch_res = replay_batch(rec, cfg=cfg)
    diff = max_differences(step_res.arrays, batch_res.arrays)

    def path_step() -> Any:
        return replay_to_dir(path, scratch / "step", keep_arrays=False, compiled=False, cfg=cfg)

    def path_batch() -> Any:
        b = replay_batch_rows(path, cfg=cfg)
        write_replay_map(scratch / "batch", b["recording"], b["map"], gps_mask=b["gps_mask"])
        return b

    cases: dict[str, tuple[Callable[[], Any], Callable[[], Any]]] = {
        "engine": (lambda: replay(rec, cfg=cfg), lambda: replay_batch(rec, cfg=cfg)),
        "path": (path_step, path_batch),
    }
    if fleet:
        try:
            import pyarrow  # noqa: F401

            from tractionecu.fleet.tasks import replay_task

            ref = {"path": str(path), "machine": "m", "date": "2026-07-01", "field": "f"}

            def task(batch: bool) -> Callable[[], Any]:
                def run() -> Any:
                    d = Path(tempfile.mkdtemp(dir=scratch))
                    (d / "task").mkdir()
                    return replay_task(ref, "k", "0" * 64, d / "task", d, {
                        "rate_hz": 100.0, "estimate_rate_hz": 1.0, "origin": [52.0, 13.0], "batch": batch,
                        **({} if cfg is None else {"estimator": cfg.to_toml()})})
                return run

            cases["fleet task"] = (task(False), task(True))
        except ImportError:
            pass
    out: dict[str, Any] = {"recording": str(path), "span_s": span, "steps": step_res.steps,
                           "max_abs_diff": max(diff.values()), "diff_per_column": diff, "cases": {},
                           "loop": getattr(batch_res, "loop", "python"), "repeat": repeat}
    for name, (fs, fb) in cases.items():
        best = {"step": (float("inf"), 0.0), "batch": (float("inf"), 0.0)}
        load0 = _load()
        for _ in range(repeat):
            for kind, fn in (("step", fs), ("batch", fb)):
                cpu, wall, _ = _cpu(fn)
                if cpu < best[kind][0]:
                    best[kind] = (cpu, wall)
        out["cases"][name] = {k: {"cpu_s": c, "wall_s": w, "x_per_core": span / c} for k, (c, w) in best.items()}
        out["cases"][name]["load_before"] = load0
        out["cases"][name]["load_after"] = _load()
    shutil.rmtree(scratch, ignore_errors=True)
    if out["loop"] == "compiled":
        out["breakdown"] = breakdown(rec, repeat, cfg)
    try:
        out["filter_core_floor"] = filter_core_floor(rec, repeat)
    except ImportError:                                       # without numba there is no compiled core
        pass
    return out


def breakdown(rec: Any, repeat: int = 3, cfg: Any = None) -> dict[str, Any]:
    """CPU time per step of an instrumented :func:`~tractionecu.pipeline.batch.replay_batch` of ``rec`` (the run
    of smallest total of ``repeat``), split into the compiled loop, each kind of return to Python (with its
    count) and the rest (module doc)."""
    best: dict[str, Any] = {}
    for _ in range(repeat):
        b = _breakdown_once(rec, cfg)
        if not best or b["total_us"] < best["total_us"]:
            best = b
    return best


def _breakdown_once(rec: Any, cfg: Any = None) -> dict[str, Any]:
    from tractionecu.estimation import compiled_loop as cl
    from tractionecu.pipeline.batch import replay_batch

    acc: dict[str, list[float]] = {}
    names = ["step_block", "block_inputs", "arrays"] + [n for n in vars(cl.CompiledLoop) if n.startswith("_ev_")]
    saved = {n: vars(cl.CompiledLoop)[n] for n in names}

    def timed(name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        def wrapper(*args: Any, **kw: Any) -> Any:
            c0 = time.process_time()
            try:
                return fn(*args, **kw)
            finally:
                a = acc.setdefault(name, [0, 0.0])
                a[0] += 1
                a[1] += time.process_time() - c0
        return wrapper

    for n, f in saved.items():
        fn = f.__func__ if isinstance(f, (staticmethod, classmethod)) else f
        w = timed(n, fn)
        setattr(cl.CompiledLoop, n, staticmethod(w) if isinstance(f, staticmethod) else w)
    try:
        c0 = time.process_time()
        res = replay_batch(rec, cfg=cfg)
        total = time.process_time() - c0
    finally:
        for n, f in saved.items():
            setattr(cl.CompiledLoop, n, f)
    steps = res.steps
    events = {n[4:]: acc.get(n, [0, 0.0]) for n in names if n.startswith("_ev_")}
    in_python = sum(v[1] for v in events.values())
    loop = acc.get("step_block", [0, 0.0])[1]
    return {"steps": steps, "total_us": 1e6 * total / steps, "compiled_us": 1e6 * (loop - in_python) / steps,
            "events": {k: {"count": int(c), "us_per_step": 1e6 * t / steps} for k, (c, t) in events.items() if c},
            "around_us": 1e6 * (total - loop) / steps}


def filter_core_floor(rec: Any, repeat: int = 3) -> dict[str, Any]:
    """CPU time per step of the compiled filter core alone, called from one compiled loop: the bound of any
    batch loop that keeps this filter.

    The step path's filter calls are recorded on ``rec`` (every predict's x, P, u, dt, Q and every fast
    update's x, P, z, R and first state), then a numba loop calls the same compiled kernels
    (``_kernels.predict_model``: sigma points, RK4 of FilterModel over the 21 points, mean and covariance;
    ``_kernels.update_block``) on those arguments, step after step, with no Python in between.  Nothing
    else of the estimator runs (noise model, supervisor, curve, calibration, bookkeeping): the figure is
    a floor, not a replay.
    """
    import numpy as np
    from numba import njit

    from tractionecu.estimation import _kernels, ukf
    from tractionecu.pipeline.replay import replay

    preds: list[tuple] = []
    upds: list[tuple] = []
    models: list[Any] = []
    orig_p, orig_u = ukf.UnscentedFilter.predict, ukf.UnscentedFilter.update

    def predict(self, u, dt, Q):
        if self._model is not None:
            preds.append((self.x.copy(), self.P.copy(), np.asarray(u, dtype=float).copy(), float(dt),
                          np.array(Q, dtype=float), self._w.copy()))
            models.append(self._model)
        return orig_p(self, u, dt, Q)

    def update(self, z, idx, R):
        if idx.__class__ is slice:
            zz = np.asarray(z, dtype=float)
            upds.append((self.x.copy(), self.P.copy(), zz.copy(), np.asarray(R, dtype=float).copy(),
                         int(self.meas_index[idx][0]), self.gate_chi2, self.x_lo.copy(), self.x_hi.copy()))
        return orig_u(self, z, idx, R)

    ukf.UnscentedFilter.predict, ukf.UnscentedFilter.update = predict, update
    try:
        res = replay(rec)
    finally:
        ukf.UnscentedFilter.predict, ukf.UnscentedFilter.update = orig_p, orig_u
    n_p, n_u = len(preds), len(upds)
    PX = np.array([p[0] for p in preds])
    PP = np.array([p[1] for p in preds])
    PU = np.array([p[2] for p in preds])
    PD = np.array([p[3] for p in preds])
    PQ = np.array([p[4] for p in preds])
    W = preds[0][5]
    KC = models[0]._kc.copy()
    UX = np.array([u[0] for u in upds])
    UPm = np.array([u[1] for u in upds])
    UZ = np.zeros((n_u, 5))
    UR = np.zeros((n_u, 5))
    UM = np.array([u[2].size for u in upds], dtype=np.int64)
    UI = np.array([u[4] for u in upds], dtype=np.int64)
    for k, u in enumerate(upds):
        UZ[k, :u[2].size] = u[2]
        UR[k, :u[2].size] = u[3]
    gate, lo, hi = upds[0][5], upds[0][6], upds[0][7]
    pm, ub = _kernels.predict_model, _kernels.update_block

    @njit(cache=False)
    def loop(PX, PP, PU, PD, PQ, W, KC, UX, UPm, UZ, UR, UM, UI, gate, lo, hi):  # pragma: no cover - compiled
        n = PX.shape[1]
        sig = np.empty((2 * n + 1, n))
        xo = np.empty(n)
        Po = np.empty((n, n))
        xn = np.empty(n)
        Pn = np.empty((n, n))
        acc = 0.0
        for k in range(PX.shape[0]):
            acc += pm(PX[k], PP[k], PU[k], PD[k], PQ[k], W, KC, sig, xo, Po)
        for k in range(UX.shape[0]):
            m = UM[k]
            work = np.empty((n, m + 2))
            small = np.empty((2 * m + 1, m))
            code, nis, cl = ub(UX[k], UPm[k], UZ[k, :m], UR[k, :m], UI[k], gate, lo, hi, xn, Pn, work, small)
            acc += code
        return acc

    args = (PX, PP, PU, PD, PQ, W, KC, UX, UPm, UZ, UR, UM, UI, gate, lo, hi)
    loop(*args)                                              # compile
    best = float("inf")
    for _ in range(repeat):
        c0 = time.process_time()
        loop(*args)
        best = min(best, time.process_time() - c0)
    steps = res.steps
    return {"steps": steps, "predicts": n_p, "updates": n_u, "cpu_s": best, "us_per_step": 1e6 * best / steps,
            "x_per_core": res.sim_seconds / best}


def report(m: dict[str, Any]) -> list[str]:
    """The printed lines of :func:`measure`'s figures."""
    lines = []
    for name, c in m["cases"].items():
        s, b = c["step"], c["batch"]
        first = "estimates.csv path" if name == "fleet task" else "step path"
        lines.append(f"{name}: {first} {s['cpu_s']:.2f} s CPU ({s['x_per_core']:.0f}x real time per core; wall "
                     f"{s['wall_s']:.2f} s), batch {b['cpu_s']:.2f} s CPU ({b['x_per_core']:.0f}x; wall "
                     f"{b['wall_s']:.2f} s): batch / {first} {s['cpu_s'] / b['cpu_s']:.2f}; {c['load_before']} before, "
                     f"{c['load_after']} after")
    lines.append(f"batch path's estimator loop: {m.get('loop', 'python')}")
    bd = m.get("breakdown")
    if bd:
        ev = ", ".join(f"{k} {v['us_per_step']:.2f} ({v['count']} returns)" for k, v in
                       sorted(bd["events"].items(), key=lambda kv: -kv[1]["us_per_step"]))
        lines.append(f"where the time goes (instrumented batch run, best of {m.get('repeat', 1)}, us CPU per step): "
                     f"{bd['total_us']:.2f} in "
                     f"all = compiled loop {bd['compiled_us']:.2f} + returns to Python: {ev} + step arguments and "
                     f"sink {bd['around_us']:.2f}")
    worst = max(m["diff_per_column"].items(), key=lambda kv: kv[1])
    where = f"column {worst[0]}" if worst[1] > 0 else "every column equal"
    lines.append(f"batch vs step estimates, {m['steps']} steps, {len(m['diff_per_column'])} columns: max |diff| "
                 f"{m['max_abs_diff']:.3g} ({where}; target <= {TARGET_DIFF:g})")
    fl = m.get("filter_core_floor")
    if fl:
        lines.append(f"floor: the compiled filter core alone (predict with RK4 over the sigma points, block update) "
                     f"in one compiled loop over this recording's {fl['predicts']} predicts and {fl['updates']} "
                     f"updates: {fl['cpu_s']:.3f} s CPU, {fl['us_per_step']:.2f} us per step = "
                     f"{fl['x_per_core']:.0f}x real time per core")
    xe = m["cases"]["engine"]["batch"]["x_per_core"]
    x = m["cases"]["path"]["batch"]["x_per_core"]
    lines.append(f"batch replay >= {TARGET_X:.0f}x real time per core: {x:.0f}x from the recording's path "
                 f"({'met' if x >= TARGET_X else 'not met'}; step path {m['cases']['path']['step']['x_per_core']:.0f}x "
                 f"in the same run), {xe:.0f}x from the decoded recording (engine; "
                 f"{'met' if xe >= TARGET_X else 'not met'}; "
                 f"step path {m['cases']['engine']['step']['x_per_core']:.0f}x)")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=60.0, help="seconds of paper-three-soils")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=3, help="rounds (best CPU time of each path)")
    ap.add_argument("--work", type=Path, default=None, help="directory for the recording (kept, reused)")
    ap.add_argument("--no-fleet", action="store_true", help="skip the fleet task case")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--config", type=Path, default=None, metavar="TOML",
                    help="estimator configuration of every path ([estimator] table, as tractionecu replay and "
                         "fleet take it), e.g. smoother_lag_s = 0.0")
    a = ap.parse_args(argv)
    cfg = None
    if a.config is not None:
        from tractionecu.estimation.config import load_estimator_config

        cfg = load_estimator_config(a.config)
    work = a.work or Path(tempfile.mkdtemp(prefix="batch_replay_"))
    work.mkdir(parents=True, exist_ok=True)
    rec = work / f"paper-three-soils_s{a.seed}_{int(a.duration)}s"
    if not (rec / "can.log").is_file():
        _simulate(rec, a.seed, a.duration)
    print(f"batch replay benchmark: paper-three-soils seed {a.seed}, {a.duration:.0f} s; best CPU time of "
          f"{a.repeat}; {_load()}" + (f"; estimator configuration {a.config}" if cfg is not None else ""), flush=True)
    m = measure(rec, a.repeat, fleet=not a.no_fleet, cfg=cfg)
    for line in report(m):
        print(line, flush=True)
    print(_load())
    if a.json:
        a.json.write_text(json.dumps(m, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
