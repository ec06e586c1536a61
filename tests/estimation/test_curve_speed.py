"""The μ(s) curve update is pinned float for float.

:meth:`CurveEstimator.update` with one class runs compiled (:mod:`tractionecu.estimation._curve_kernel`: the
forgetting, the wheels' pairs, g(ŝ), the a sums, the shape identification's change test, binning and history),
the same function for the step path and for batch replay's compiled loop.  End to end: short seeded recordings of
five scenarios are simulated and replayed on the step path; every estimate column, every curve state the updates
returned (a, class, per-class a and evidence, pairs used, var a, path, segment, soil, slip span and range, the
fitted shape's parameters and covariance) and the update inputs are hashed (exact bytes of every float) and
compared with ``tests/data/curve_speed/reference.json`` (the README there says how it was made and checked).

If only the ``inputs`` hash differs, the estimator upstream of the curve changed, not the curve: the reference
hashes must then be made again (README there).
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tractionecu.estimation import curve as curve_mod
from tractionecu.estimation import estimator as estimator_mod

REFERENCE = Path(__file__).resolve().parents[1] / "data" / "curve_speed" / "reference.json"

CASES = {                      # scenario: simulated duration [s] (seed 0)
    "paper-three-soils": 90.0,
    "physical-three-soils": 90.0,
    "two-soils-tilled": 60.0,
    "soils-off-class": 60.0,
    "headland-reverse": 60.0,
}


def _canon(x: Any) -> str:
    """Exact text of a value: floats as hex, arrays as dtype, shape and bytes."""
    if isinstance(x, float):
        return x.hex()
    if isinstance(x, np.ndarray):
        return f"{x.dtype}{x.shape}" + np.ascontiguousarray(x).tobytes().hex()
    if isinstance(x, np.generic):
        return _canon(x.item())
    if isinstance(x, (tuple, list)):
        return "(" + ",".join(_canon(y) for y in x) + ")"
    if isinstance(x, dict):
        return "{" + ",".join(f"{k}:{_canon(v)}" for k, v in sorted(x.items())) + "}"
    if x is None or isinstance(x, (bool, int, str)):
        return repr(x)
    if dataclasses_fields := getattr(x, "__dataclass_fields__", None):
        return type(x).__name__ + _canon({k: getattr(x, k) for k in dataclasses_fields})
    raise TypeError(f"no exact text for {type(x).__name__}")


def _state_text(cs: Any) -> str:
    """A curve state's fields and its identified curve (a·g_class(s) or the fitted shape)."""
    c = cs.curve
    curve = None if c is None else (c.form, c.theta, np.asarray(c.cov), c.path, c.s_range, c.load_q)
    return _canon({"a": cs.a, "class_index": cs.class_index, "class_name": cs.class_name,
                   "a_per_class": cs.a_per_class, "nll_per_class": cs.nll_per_class, "n_used": cs.n_used,
                   "var_a": cs.var_a, "curve_path": cs.curve_path, "segment": cs.segment,
                   "slip_span": cs.slip_span, "soil": cs.soil, "s_range": cs.s_range, "curve": curve})


def _sha(parts: list[str]) -> str:
    h = hashlib.sha256()
    for p in parts:
        h.update(p.encode())
        h.update(b"\n")
    return h.hexdigest()


def replay_hashes(scenario: str, duration_s: float, out_dir: Path, curve_cls: type | None = None,
                  monkeypatch: Any = None) -> dict[str, Any]:
    """Simulate ``scenario`` (seed 0, ``duration_s``) into ``out_dir``, replay it on the step path with
    ``curve_cls`` as the estimator's curve identification (None: today's), and hash what came out."""
    from tractionecu.pipeline.replay import replay
    from tractionecu.recording.reader import read_recording
    from tractionecu.sim import scenarios
    from tractionecu.sim.simulator import simulate
    from tractionecu.sim.writer import write_recording

    scn = scenarios.get(scenario, seed=0, duration_s=duration_s)
    write_recording(scn, simulate(scn), out_dir)
    base = curve_cls or curve_mod.CurveEstimator
    inputs: list[str] = []
    states: list[str] = []
    seen = {"segments": 0, "fitted": 0}

    class Recorded(base):                                     # type: ignore[misc, valid-type]
        def update(self, t, mu, s, sigma_mu, sigma_s=None, fz=None, mu_bin=None):  # noqa: ANN001, ANN201
            inputs.append(_canon([t, mu, s, sigma_mu, sigma_s, fz, mu_bin]))
            cs = super().update(t, mu, s, sigma_mu, sigma_s, fz, mu_bin)
            states.append(_state_text(cs))
            seen["segments"] = max(seen["segments"], cs.segment)
            seen["fitted"] += int(cs.shape_curve is not None or cs.var_a == cs.var_a)
            return cs

    patch = monkeypatch or pytest.MonkeyPatch()
    patch.setattr(estimator_mod, "CurveEstimator", Recorded)
    try:
        res = replay(read_recording(out_dir))
    finally:
        if monkeypatch is None:
            patch.undo()
    cols = {}
    for name, v in sorted(res.arrays.items()):
        if name == "curve":                                    # the identified curves: in the states
            continue
        cols[name] = _sha([_canon(v if isinstance(v, np.ndarray) else list(v))])
    return {"duration_s": duration_s, "updates": len(states), "inputs": _sha(inputs), "curve": _sha(states),
            "columns": cols, **seen}


@pytest.mark.parametrize("scenario", sorted(CASES))
def test_replay_equals_reference(scenario: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    ref = json.loads(REFERENCE.read_text())[scenario]
    got = replay_hashes(scenario, CASES[scenario], tmp_path, monkeypatch=monkeypatch)
    assert got["duration_s"] == ref["duration_s"] and got["updates"] == ref["updates"] > 100
    assert (got["segments"], got["fitted"]) == (ref["segments"], ref["fitted"])
    assert got["inputs"] == ref["inputs"], "the curve's inputs changed: the estimator upstream, not the curve"
    assert got["curve"] == ref["curve"]
    assert got["columns"] == ref["columns"]


def test_fast_path_equals_general_path() -> None:
    """The one-class pass (:meth:`CurveEstimator._update_one`) against the general path of the same
    estimator (taken when the inputs are lists), on seeded pairs with the rare cases: a wheel below
    ``min_mu`` or ``min_slip``, opposite signs, NaN and inf, σ_μ below its floor, loads with a NaN."""
    rng = np.random.default_rng(3)
    fast = curve_mod.CurveEstimator(fz_ref_n=20000.0)
    slow = curve_mod.CurveEstimator(fz_ref_n=20000.0)
    n_fast = 0
    for i in range(3000):
        t = 0.1 * i
        soil = 1.0 + 0.6 * ((i // 700) % 2)                     # a soil change every 70 s
        s = np.abs(rng.normal(0.05 * soil, 0.02, 4))
        mu = 0.8 * (1.0 - np.exp(-12.0 * s / soil)) + rng.normal(0.0, 0.01, 4)
        if i % 17 == 0:
            mu[i % 4] = math.nan
        if i % 23 == 0:
            s[(i + 1) % 4] = -s[(i + 1) % 4]
        if i % 29 == 0:
            s[(i + 2) % 4] = 0.001
        if i % 31 == 0:
            mu[(i + 3) % 4] = 0.05
        if i % 37 == 0:
            s[i % 4] = math.inf
        sig_mu = np.full(4, 0.02 if i % 13 else 1e-8)
        sig_s = np.full(4, 0.01)
        fz = np.array([15000.0, 15000.0, 26000.0, math.nan if i % 11 == 0 else 26000.0])
        a = fast.update(t, mu, s, sig_mu, sig_s, fz)
        b = slow.update(t, mu.tolist(), s.tolist(), sig_mu.tolist(), sig_s, fz)    # lists: the general path
        n_fast += 1
        assert _state_text(a) == _state_text(b), i
        assert (a.shape_curve is None) == (b.shape_curve is None)
    assert slow.shape.segment == fast.shape.segment >= 1 and fast.shape.n_fits >= 1 and n_fast == 3000


def test_curve_state_is_the_dataclass() -> None:
    """The state built without ``__init__`` is a CurveState like one built with it (equal, replaceable,
    frozen, its curve made on demand)."""
    est = curve_mod.CurveEstimator()
    cs = est.update(0.0, np.array([0.4, 0.4, 0.5, 0.5]), np.array([0.05, 0.05, 0.08, 0.08]), np.full(4, 0.02))
    ref = curve_mod.CurveState(cs.a, cs.class_index, cs.class_name, cs.a_per_class, cs.nll_per_class, cs.n_used,
                               cs.shape_curve, cs.var_a, cs.curve_path, cs.segment, cs.slip_span, cs.soil,
                               cs.s_range)
    assert type(cs) is curve_mod.CurveState and _state_text(cs) == _state_text(ref)
    assert cs.curve is not None and cs.curve.a == cs.a
    with pytest.raises(AttributeError):
        cs.a = 1.0                                              # type: ignore[misc]
    import dataclasses
    assert dataclasses.replace(cs, class_index=7).class_index == 7


def test_kernel_constants_are_the_curve_modules() -> None:
    """numba freezes a global's value into the machine code it caches, keyed by the kernel's own file: the compiled
    update's copies of curve.py's bin layout (width, count, load groups, the change test's search order) must be
    curve.py's."""
    from tractionecu.estimation import _curve_kernel as CK

    assert CK.MU_BIN_WIDTH == curve_mod.MU_BIN_WIDTH and CK.N_BINS == curve_mod.PairBins.N_BINS
    assert (CK.LOAD_EDGE_LO, CK.LOAD_EDGE_HI) == curve_mod.LOAD_EDGES and CK.NEAR == curve_mod._NEAR


def test_history_ring_grows_without_changing_a_float() -> None:
    """The shape identification's history (the pairs of the last ``history_s``, for a new segment's take-over) is a
    ring that grows when an instant does not fit (high update rates, many pairs): 40 s at 100 Hz with soil changes,
    against the same run on a ring made large enough at the start, every state and the bins equal."""
    rng = np.random.default_rng(5)
    a = curve_mod.CurveEstimator(fz_ref_n=20000.0)
    b = curve_mod.CurveEstimator(fz_ref_n=20000.0)
    b.shape._HT = np.zeros((8192, 3))
    b.shape._HP = np.zeros((8192 * 4, 5))
    for i in range(4000):
        soil = 1.0 + 0.6 * ((i // 1000) % 2)
        s = np.abs(rng.normal(0.05 * soil, 0.02, 4))
        mu = 0.8 * (1.0 - np.exp(-12.0 * s / soil)) + rng.normal(0.0, 0.01, 4)
        args = (0.01 * i, mu, s, np.full(4, 0.02), np.full(4, 0.01), np.array([15000.0, 15000.0, 26000.0, 26000.0]))
        assert _state_text(a.update(*args)) == _state_text(b.update(*args)), i
    assert a.shape._HT.shape[0] > 256 and a.shape.segment == b.shape.segment >= 1
    assert _canon(a.shape.bins.arrays()) == _canon(b.shape.bins.arrays())
    assert _canon(a.shape.mature.arrays()) == _canon(b.shape.mature.arrays())


def test_batch_reports_the_shape_paths_a(make_recording) -> None:
    """Batch replay's ``a`` column is each step's :attr:`CurveState.a`, on the shape path the fitted shape's a, as
    on the step path (regression: the compiled loop's records gave the class's Σ w μ̂ / Σ w g(ŝ) there)."""
    from tractionecu.pipeline.batch import replay_batch
    from tractionecu.pipeline.replay import replay
    from tractionecu.recording.reader import read_recording

    rec = read_recording(make_recording("soils-off-class", 0, 120.0))
    step, batch = replay(rec), replay_batch(rec)
    paths = [c.path if c is not None else "" for c in step.arrays["curve"]]
    shape = np.array([p.startswith("shape:") for p in paths])
    assert shape.sum() > 1000 and batch.arrays["curve_path"] == paths
    a_step, a_batch = np.asarray(step.arrays["a"]), np.asarray(batch.arrays["a"])
    assert np.array_equal(a_step, a_batch, equal_nan=True)
    assert np.array_equal(a_step[shape], [c.a for c, s in zip(step.arrays["curve"], shape) if s])
