"""The naming rules of the diagnosis (:mod:`tractionecu.diagnose.engine`), on synthetic fits.

Two rules decide whether a fault the augmentation added is *named*:

1. a fault whose estimate trades off (|correlation| ≥ ``TRADE_OFF_CORR`` in the joint fit) with a
   characteristic found at a healthy size is not separated from what every machine has: it is not
   named and the verdict is recomputed (the next named fault, else none);
2. a fault added by a step of the augmentation that another fault improves as much (within the
   margin max(DETECT_LLR, AMBIGUOUS_FRACTION · S)) is ambiguous between the two, unless a later step
   adds the rival in its own right (then both are present, neither is an alternative).

The recording, its channels and the numerical fits are replaced by small synthetic objects of the
types the engine consumes (:class:`FitResult` with a correlation matrix, held-out scores, the
stepwise steps); the naming logic itself runs unchanged.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from tractionecu.diagnose import engine
from tractionecu.diagnose import openworld
from tractionecu.diagnose.candidates import CANDIDATES
from tractionecu.diagnose.engine import DETECT_LLR, TRADE_OFF_CORR, CandidateResult
from tractionecu.diagnose.fit import FitResult, HeldOut


# --------------------------------------------------------------------------- synthetic objects
def _fit(effects: dict[str, dict[str, float]], corr: dict[tuple[str, str], float] | None = None) -> FitResult:
    """A fit of ``effects`` ({effect: {param: value}}) with unit standard errors, narrow intervals and
    the given correlations between parameters (keys ``effect.param``); every other pair uncorrelated."""
    names = tuple(f"{e}.{p}" for e, ps in effects.items() for p in ps)
    x = np.array([v for ps in effects.values() for v in ps.values()], dtype=float)
    cov = np.eye(len(names))
    for (a, b), r in (corr or {}).items():
        i, j = names.index(a), names.index(b)
        cov[i, j] = cov[j, i] = r
    ci = {e: {p: (v - 0.01, v + 0.01) for p, v in ps.items()} for e, ps in effects.items()}
    flat = {p: v for ps in effects.values() for p, v in ps.items()}
    return FitResult(candidate="+".join(effects), x=x, cov=cov, params=flat,
                     ci95={p: iv for c in ci.values() for p, iv in c.items()},
                     se={p: 1.0 for p in flat}, sse={}, n={}, cost=0.0, ok=True,
                     effects={e: dict(ps) for e, ps in effects.items()}, ci95_by=ci, at_bound={}, names=names)


# Values inside each library range, away from the value at which the effect vanishes.
VALUE = {"wheel_radius": {"epsilon": 0.03}, "drivetrain": {"eta": 0.90}, "relaxation": {"sigma_m": 0.8},
         "mass": {"delta_kg": 800.0, "front_share": 0.3}, "torque_gain": {"k_front": 1.0, "k_rear": 1.08},
         "gps_latency": {"tau_s": 0.3}, "draft_offset": {"b0_n": 900.0, "b1_npm": 0.0},
         "axle_load_offset": {"b0_n": 2500.0, "b1_npm": 0.0}}


def _values(*names: str, **override: dict[str, float]) -> dict[str, dict[str, float]]:
    return {n: {**VALUE[n], **override.get(n, {})} for n in names}


def _ho(name: str) -> HeldOut:
    return HeldOut(candidate=name, sse={}, n={}, resid={}, fold_params=[])


def _diagnose(monkeypatch, scores: dict[str, float], chosen: list[str], joint: FitResult, steps: list[dict],
              reaches_absence: frozenset[str] = frozenset(), rerun: tuple | None = None,
              open_world: dict | None = None, sensor_faults: tuple = ()):
    """Run :func:`engine.diagnose` with the candidates' single-step held-out ``scores``, and the
    augmentation's outcome (``chosen``, the joint fit, its ``steps``; ``rerun`` the same three when the
    augmentation is re-run without a withdrawn fault) given; everything that reads a
    recording or fits numerically is replaced, the verdict and naming logic run as in the engine."""
    frame = SimpleNamespace(source="synthetic", notes=[], fzf_modelled=False)
    feat = SimpleNamespace(notes=[], sensor_faults=[], frame=frame)
    monkeypatch.setattr(engine, "_data", SimpleNamespace(Frame=SimpleNamespace, load=lambda s, v: frame))
    monkeypatch.setattr(engine, "compute", lambda fr: feat)
    monkeypatch.setattr(engine, "build_channels", lambda f: [])
    monkeypatch.setattr(engine, "_testability",
                        lambda p, f: {n: "" if n in scores else "not in this case" for n in CANDIDATES})
    monkeypatch.setattr(engine, "held_out", lambda problem, name, **kw: _ho(str(name)))
    monkeypatch.setattr(engine, "score", lambda problem, null, ho: (scores[ho.candidate], {}))
    monkeypatch.setattr(engine, "fit", lambda problem, name, **kw: _fit(_values(name)))
    monkeypatch.setattr(engine, "_calibrate", lambda f, fp: None)
    monkeypatch.setattr(engine, "_excludes_null", lambda f, name=None: (name or f.candidate) not in reaches_absence)
    monkeypatch.setattr(engine, "_implausible_bound", lambda f, name: "")
    monkeypatch.setattr(engine, "_grade_check", lambda problem, feat, res: {})
    seen = {}

    def stepwise(problem, results, best, null, consistent=None, exclude=()):
        seen["first"] = best.name
        seen.setdefault("exclude", []).append(list(exclude))
        if exclude and rerun is not None:
            ch2, joint2, steps2 = rerun
            return list(ch2), joint2, _ho("+".join(ch2)), [dict(s) for s in steps2]
        kept = [c for c in chosen if c not in exclude]
        return kept, joint, _ho("+".join(kept)), [dict(s) for s in steps]

    monkeypatch.setattr(engine, "_stepwise", stepwise)
    monkeypatch.setattr(engine, "_statement",
                        lambda verdict, effect, ambiguous, *a, fitted=None: f"<{verdict} {effect} {'/'.join(ambiguous or [])}>"
                        + ("" if fitted is None else " fitted " + ", ".join(
                            f"{k} [{v['ci95'][0]}, {v['ci95'][1]}]" for k, v in fitted.items() if v.get("ci95"))))
    monkeypatch.setattr(openworld, "open_world", lambda d: dict(open_world or {}))
    feat.sensor_faults = list(sensor_faults)
    d = engine.diagnose(frame)
    return d, seen


def _effect(d, name: str) -> dict:
    return next(e for e in d.effects if e["name"] == name)


# --------------------------------------------------------------------------- rule 1: trade-off with a characteristic
def test_fault_trading_off_with_healthy_characteristic_is_not_named(monkeypatch):
    """A radius error whose ε correlates at −0.93 with a healthy drivetrain efficiency (η = 0.90) in the
    joint fit: the radius error was the verdict; it is not named, the verdict becomes none and the
    drivetrain is reported as consistent with it."""
    joint = _fit(_values("wheel_radius", "drivetrain"), {("wheel_radius.epsilon", "drivetrain.eta"): -0.93})
    steps = [{"step": 1, "added": "wheel_radius", "score": 60.0, "against": "nominal model"},
             {"step": 2, "added": "drivetrain", "score": 25.0, "against": "wheel_radius"}]
    d, seen = _diagnose(monkeypatch, {"wheel_radius": 60.0, "drivetrain": 20.0}, ["wheel_radius", "drivetrain"],
                        joint, steps)
    assert seen["first"] == "wheel_radius"          # the radius error led the augmentation
    wr, dt = _effect(d, "wheel_radius"), _effect(d, "drivetrain")
    assert dt["kind"] == "characteristic"
    assert wr["trades_off_with"] == [{"with": "drivetrain", "correlation": pytest.approx(-0.93)}]
    assert (d.verdict, d.effect) == ("none", None)
    assert wr["named"] is False
    assert wr["explained_by"][0]["with"] == "drivetrain"
    assert dt["consistent_with"] == ["wheel_radius"]
    assert d.statement.startswith("No fault named")
    assert any("wheel_radius trades off with drivetrain (correlation -0.93)" in n for n in d.notes)


def test_verdict_moves_to_the_next_named_fault(monkeypatch):
    """With a second, independent fault (a mass change) added later, the verdict is recomputed to it."""
    joint = _fit(_values("wheel_radius", "drivetrain", "mass"),
                 {("wheel_radius.epsilon", "drivetrain.eta"): 0.85, ("mass.delta_kg", "drivetrain.eta"): 0.1})
    steps = [{"step": 1, "added": "wheel_radius", "score": 60.0, "against": "nominal model"},
             {"step": 2, "added": "drivetrain", "score": 25.0, "against": "wheel_radius"},
             {"step": 3, "added": "mass", "score": 18.0, "against": "wheel_radius+drivetrain"}]
    d, _ = _diagnose(monkeypatch, {"wheel_radius": 60.0, "drivetrain": 20.0, "mass": 15.0},
                     ["wheel_radius", "drivetrain", "mass"], joint, steps)
    assert (d.verdict, d.effect) == ("effect", "mass")
    assert d.statement.startswith("<effect mass")
    assert _effect(d, "wheel_radius")["named"] is False
    assert _effect(d, "mass")["named"] is True


@pytest.mark.parametrize("corr, eta", [(-0.7, 0.90),    # below TRADE_OFF_CORR: separated
                                       (-0.93, 0.60)])  # η outside the healthy range: a fault, not a characteristic
def test_radius_error_stays_named_without_a_healthy_trade_off(monkeypatch, corr, eta):
    assert abs(corr) < TRADE_OFF_CORR or not 0.80 <= eta <= 1.0
    joint = _fit(_values("wheel_radius", "drivetrain", drivetrain={"eta": eta}),
                 {("wheel_radius.epsilon", "drivetrain.eta"): corr})
    steps = [{"step": 1, "added": "wheel_radius", "score": 60.0, "against": "nominal model"},
             {"step": 2, "added": "drivetrain", "score": 25.0, "against": "wheel_radius"}]
    d, _ = _diagnose(monkeypatch, {"wheel_radius": 60.0, "drivetrain": 20.0}, ["wheel_radius", "drivetrain"],
                     joint, steps)
    assert (d.verdict, d.effect) == ("effect", "wheel_radius")
    assert _effect(d, "wheel_radius")["named"] is True
    assert "explained_by" not in _effect(d, "wheel_radius")


# --------------------------------------------------------------------------- rule 2: a step tied with another fault
def _stepwise(monkeypatch, first: str, single: dict[str, float], trials: dict[tuple[str, ...], float],
              char_values: dict[str, dict[str, float]] | None = None):
    """Run :func:`engine._stepwise` from ``first`` with held-out improvements ``trials`` per tried model
    (tuple of effect names, missing → 0) instead of fitting; the joint fits carry :data:`VALUE`
    (``char_values`` overrides, e.g. an unhealthy characteristic)."""
    monkeypatch.setattr(engine, "_white", lambda problem, ho: False)
    # These synthetic steps carry no per-channel gains: the separation rule (rule 5) is tested on its own.
    monkeypatch.setattr(engine, "_unseparated", lambda name, per: "")
    monkeypatch.setattr(engine, "held_out", lambda problem, names, **kw: _ho("+".join(names)))
    monkeypatch.setattr(engine, "score",
                        lambda problem, cur, ho: (trials.get(tuple(ho.candidate.split("+")), 0.0), {}))
    monkeypatch.setattr(engine, "fit",
                        lambda problem, joint, **kw: _fit(_values(*joint.names, **(char_values or {}))))
    monkeypatch.setattr(engine, "_calibrate", lambda f, fp: None)
    monkeypatch.setattr(engine, "_excludes_null", lambda f, name=None: True)
    monkeypatch.setattr(engine, "_implausible_bound", lambda f, name: "")
    results = [CandidateResult(n, True, "", s, {}, _fit(_values(n)), _ho(n), s >= DETECT_LLR)
               for n, s in sorted(single.items(), key=lambda kv: -kv[1])]
    firstr = next(r for r in results if r.name == first)
    chosen, _, _, steps = engine._stepwise(SimpleNamespace(), results, firstr, _ho("null"), {})
    return chosen, {s["added"]: s for s in steps if "added" in s}


def test_step_tied_with_another_fault_records_the_rival(monkeypatch):
    """Step 2 adds a mass change (+40); a torque-sensor gain improves it by +33 (within the margin
    max(10, 0.2·40) = 10), a healthy-sized relaxation by +34 and a GNSS latency by +20 (outside).
    Only the fault within the margin is a rival: not the characteristic, not the far one."""
    single = {"wheel_radius": 60.0, "mass": 40.0, "torque_gain": 38.0, "relaxation": 30.0, "gps_latency": 12.0}
    trials = {("wheel_radius", "mass"): 40.0, ("wheel_radius", "torque_gain"): 33.0,
              ("wheel_radius", "relaxation"): 34.0, ("wheel_radius", "gps_latency"): 20.0}
    # The relaxation fits at 5 m (beyond a healthy tyre): it is not taken in place of the fault.
    chosen, steps = _stepwise(monkeypatch, "wheel_radius", single, trials, {"relaxation": {"sigma_m": 5.0}})
    assert chosen == ["wheel_radius", "mass"]
    assert steps["mass"]["ambiguous_with"] == ["torque_gain"]
    assert "ambiguous_with" not in steps["wheel_radius"]


def test_rival_below_detection_but_within_margin_is_a_rival(monkeypatch):
    """A step of +15 and a rival of +7: the rival is within the margin (10) though below DETECT_LLR
    on its own; the step cannot be told from it."""
    single = {"wheel_radius": 60.0, "mass": 40.0, "torque_gain": 38.0}
    trials = {("wheel_radius", "mass"): 15.0, ("wheel_radius", "torque_gain"): 7.0}
    chosen, steps = _stepwise(monkeypatch, "wheel_radius", single, trials)
    assert chosen == ["wheel_radius", "mass"]
    assert steps["mass"]["ambiguous_with"] == ["torque_gain"]


def test_step_clear_of_every_rival_is_not_ambiguous(monkeypatch):
    single = {"wheel_radius": 60.0, "mass": 40.0, "torque_gain": 38.0}
    trials = {("wheel_radius", "mass"): 40.0, ("wheel_radius", "torque_gain"): 29.0}
    chosen, steps = _stepwise(monkeypatch, "wheel_radius", single, trials)
    assert chosen == ["wheel_radius", "mass"]
    assert "ambiguous_with" not in steps["mass"]


_AMB_STEPS = [{"step": 1, "added": "drivetrain", "score": 80.0, "against": "nominal model"},
              {"step": 2, "added": "mass", "score": 40.0, "against": "drivetrain", "ambiguous_with": ["torque_gain"]}]


def test_first_fault_tied_with_a_rival_makes_the_verdict_ambiguous(monkeypatch):
    """A healthy drivetrain leads; the first fault (a mass change) was added by a step that a torque
    gain improved as much: the verdict is ambiguous between them, with the shared structure stated."""
    joint = _fit(_values("drivetrain", "mass"))
    d, _ = _diagnose(monkeypatch, {"drivetrain": 80.0, "mass": 50.0, "torque_gain": 45.0},
                     ["drivetrain", "mass"], joint, _AMB_STEPS)
    assert (d.verdict, d.effect) == ("ambiguous", None)
    assert d.ambiguous_between == ["mass", "torque_gain"]
    assert "torque-sensor gain on one axle and a mass on that axle" in d.statement
    m = _effect(d, "mass")
    assert (m["named"], m["ambiguous"], m["ambiguous_with"]) == (False, True, ["torque_gain"])
    tg = _effect(d, "torque_gain")               # the rival is listed, unnamed
    assert (tg["named"], tg["ambiguous"]) == (False, True)


def test_ambiguous_without_mass_and_torque_gain_has_no_shared_structure_sentence(monkeypatch):
    steps = [dict(_AMB_STEPS[0]), {**_AMB_STEPS[1], "ambiguous_with": ["gps_latency"]}]
    d, _ = _diagnose(monkeypatch, {"drivetrain": 80.0, "mass": 50.0, "gps_latency": 45.0},
                     ["drivetrain", "mass"], _fit(_values("drivetrain", "mass")), steps)
    assert (d.verdict, d.ambiguous_between) == ("ambiguous", ["mass", "gps_latency"])
    assert d.statement.startswith("<ambiguous None mass/gps_latency>")
    assert "torque-sensor gain" not in d.statement


def test_rival_added_by_a_later_step_is_present_not_an_alternative(monkeypatch):
    """The torque gain that tied with the mass step is added by step 3 in its own right: both are
    faults of this machine, the mass is named and the verdict stays the mass."""
    steps = _AMB_STEPS + [{"step": 3, "added": "torque_gain", "score": 22.0, "against": "drivetrain+mass"}]
    joint = _fit(_values("drivetrain", "mass", "torque_gain"))
    d, _ = _diagnose(monkeypatch, {"drivetrain": 80.0, "mass": 50.0, "torque_gain": 45.0},
                     ["drivetrain", "mass", "torque_gain"], joint, steps)
    assert (d.verdict, d.effect) == ("effect", "mass")
    m, tg = _effect(d, "mass"), _effect(d, "torque_gain")
    assert m["named"] is True and "ambiguous_with" not in m and not m.get("ambiguous")
    assert tg["named"] is True and not tg.get("ambiguous")
    assert "Several effects at once" in d.statement


# --------------------------------------------------------------------------- rule 3: backward pass
def _prune(monkeypatch, first: str, loglik: dict[tuple[str, ...], float], corr=None):
    """Run :func:`engine._stepwise` from ``first`` where the held-out log-likelihood of each model (a
    tuple of effect names in the order fitted; the null is ()) is ``loglik`` (missing → 0), so that a
    score is the difference of two models' values; joint fits carry ``corr`` between parameters."""
    def key(names):
        names = (names,) if isinstance(names, str) else tuple(names)
        return tuple(sorted(names))

    ll = {key(k): v for k, v in loglik.items()}
    monkeypatch.setattr(engine, "_white", lambda problem, ho: False)
    monkeypatch.setattr(engine, "_unseparated", lambda name, per: "")
    monkeypatch.setattr(engine, "held_out",
                        lambda problem, names, **kw: _ho("+".join(key(names))))
    monkeypatch.setattr(engine, "score", lambda problem, ref, ho: (
        ll.get(key(ho.candidate.split("+")), 0.0) - ll.get(key(ref.candidate.split("+")), 0.0), {}))

    def fit(problem, joint, **kw):
        names = joint.names
        return _fit(_values(*names), {k: v for k, v in (corr or {}).items()
                                      if all(p.split(".")[0] in names for p in k)})

    monkeypatch.setattr(engine, "fit", fit)
    monkeypatch.setattr(engine, "_calibrate", lambda f, fp: None)
    monkeypatch.setattr(engine, "_excludes_null", lambda f, name=None: True)
    monkeypatch.setattr(engine, "_implausible_bound", lambda f, name: "")
    singles = {k[0]: v for k, v in ll.items() if len(k) == 1}
    results = [CandidateResult(n, True, "", s, {}, _fit(_values(n)), _ho(n), s >= DETECT_LLR)
               for n, s in sorted(singles.items(), key=lambda kv: -kv[1])]
    firstr = next(r for r in results if r.name == first)
    chosen, jf, _, steps = engine._stepwise(SimpleNamespace(), results, firstr, _ho(""), {})
    return chosen, jf, steps


def test_a_fault_a_later_addition_explains_is_dropped(monkeypatch):
    """A front mass enters first (+40: it takes up the level of the measured front-axle load), an
    axle-load offset next (+30 beside it); without the mass the offset alone keeps all but 4 of the
    held-out log-likelihood, without the offset the mass loses 30: the mass is dropped, the offset
    stays, named alone (its removal costs more than the detection threshold: not ambiguous)."""
    chosen, jf, steps = _prune(monkeypatch, "mass",
                               {("mass",): 40.0, ("axle_load_offset",): 66.0, ("mass", "axle_load_offset"): 70.0},
                               {("mass.delta_kg", "axle_load_offset.b0_n"): 0.95})
    assert chosen == ["axle_load_offset"]
    removed = next(s for s in steps if s.get("removed"))
    assert removed["removed"] == "mass" and removed["score"] == pytest.approx(4.0)
    assert "ambiguous_with" not in removed
    assert not any(s.get("ambiguous_with") for s in steps if s.get("added") == "axle_load_offset")
    assert jf.effects.keys() == {"axle_load_offset"}


_THREE = {("mass",): 40.0, ("axle_load_offset",): 30.0, ("gps_latency",): 20.0,
          ("mass", "axle_load_offset"): 52.0, ("mass", "gps_latency"): 84.0, ("axle_load_offset", "gps_latency"): 85.0,
          ("mass", "axle_load_offset", "gps_latency"): 90.0}
"""Three faults in the joint model; with the latency in it either the mass or the axle-load offset alone
keeps nearly everything: removing the mass costs 5, the offset 6 (fold fits differ from the forward
step's, where the offset had entered before the latency)."""


def _backward(monkeypatch, corr):
    """:func:`engine._prune` on the three-fault model of :data:`_THREE` (held-out log-likelihoods as in
    :func:`_prune`)."""
    _prune(monkeypatch, "mass", _THREE, corr)          # installs the synthetic fits and scores
    names = ("mass", "axle_load_offset", "gps_latency")
    joint = engine.fit(None, SimpleNamespace(names=names))
    steps = [{"step": k + 1, "added": n, "score": 10.0, "against": "+".join(names[:k])} for k, n in enumerate(names)]
    results = [CandidateResult(n, True, "", _THREE[(n,)], {}, _fit(_values(n)), _ho(n), True) for n in names]
    chosen, _, _ = engine._prune(SimpleNamespace(), results, list(names), joint, _ho("+".join(sorted(names))), steps)
    return chosen, steps


def test_two_faults_either_of_which_the_data_need_are_ambiguous_with_their_correlation(monkeypatch):
    """Both removals cheaper than the detection threshold and the two estimates correlate at 0.95: the
    cheaper (the mass) is dropped, the one kept is ambiguous with it, with the correlation."""
    chosen, steps = _backward(monkeypatch, {("mass.delta_kg", "axle_load_offset.b0_n"): 0.95})
    assert chosen == ["axle_load_offset", "gps_latency"]
    removed = next(s for s in steps if s.get("removed"))
    assert (removed["removed"], removed["score"]) == ("mass", pytest.approx(5.0))
    assert removed["ambiguous_with"] == "axle_load_offset"
    kept = next(s for s in steps if s.get("added") == "axle_load_offset")
    assert kept["ambiguous_with"] == ["mass"]
    assert kept["trade_off"] == {"mass": pytest.approx(0.95)}
    assert "ambiguous_with" not in next(s for s in steps if s.get("added") == "gps_latency")


def test_faults_that_do_not_trade_off_are_not_ambiguous_when_dropped(monkeypatch):
    """The same held-out figures without a correlation between the two: the mass was simply not needed."""
    chosen, steps = _backward(monkeypatch, {("mass.delta_kg", "axle_load_offset.b0_n"): 0.3})
    assert chosen == ["axle_load_offset", "gps_latency"]
    assert not any(s.get("ambiguous_with") for s in steps)


def test_faults_each_needed_beside_the_other_both_stay(monkeypatch):
    chosen, _, steps = _prune(monkeypatch, "mass",
                              {("mass",): 40.0, ("axle_load_offset",): 30.0, ("mass", "axle_load_offset"): 70.0})
    assert chosen == ["mass", "axle_load_offset"]
    assert not any(s.get("removed") for s in steps)


def test_a_healthy_characteristic_is_never_dropped(monkeypatch):
    """A healthy drivetrain (η 0.90) whose removal would cost nothing stays: it is the machine's."""
    chosen, _, steps = _prune(monkeypatch, "mass",
                              {("mass",): 40.0, ("drivetrain",): 5.0, ("mass", "drivetrain"): 52.0})
    assert chosen == ["mass", "drivetrain"]


# --------------------------------------------------------------------------- rule 4: the reported interval
def test_a_fault_whose_reported_interval_reaches_its_absence_is_not_named(monkeypatch):
    """A healthy relaxation leads; a rear mass was added by the augmentation (held-out +10.2, its sandwich
    interval clear of zero), but the interval it is reported with (profile likelihood, block jackknife)
    reaches Δm = 0: it is not named, the verdict is none and a note says why."""
    joint = _fit(_values("relaxation", "mass"))
    steps = [{"step": 1, "added": "relaxation", "score": 276.0, "against": "nominal model"},
             {"step": 2, "added": "mass", "score": 10.2, "against": "relaxation"}]
    d, _ = _diagnose(monkeypatch, {"relaxation": 276.0, "mass": 10.1}, ["relaxation", "mass"], joint, steps,
                     reaches_absence=frozenset({"mass"}))
    m = _effect(d, "mass")
    assert (m["named"], m["not_significant"]) == (False, True)
    assert _effect(d, "relaxation")["kind"] == "characteristic"
    assert (d.verdict, d.effect) == ("none", None)
    assert any(n.startswith("mass: held-out score 10.2") and "reaches the value at which it vanishes" in n
               for n in d.notes)


def test_a_withdrawn_fault_is_left_out_of_a_rerun_augmentation(monkeypatch):
    """A front mass entered at step 3 on the level of the front-axle load and kept the axle-load offset
    (the same constant on the pin) out of the model; its reported interval reaches Δm = 0.  The
    augmentation is re-run without it: the offset it blocked is added and named beside the GNSS latency,
    and the mass stays in the report as withdrawn, not named."""
    joint = _fit(_values("relaxation", "mass", "gps_latency"))
    steps = [{"step": 1, "added": "relaxation", "score": 232.7, "against": "nominal model"},
             {"step": 2, "added": "mass", "score": 96.7, "against": "relaxation"},
             {"step": 3, "added": "gps_latency", "score": 60.7, "against": "relaxation+mass"}]
    joint2 = _fit(_values("relaxation", "gps_latency", "axle_load_offset"))
    steps2 = [{"step": 1, "added": "relaxation", "score": 232.7, "against": "nominal model"},
              {"step": 2, "added": "gps_latency", "score": 150.0, "against": "relaxation"},
              {"step": 3, "added": "axle_load_offset", "score": 72.0, "against": "relaxation+gps_latency"}]
    d, seen = _diagnose(monkeypatch, {"relaxation": 232.7, "mass": 138.0, "gps_latency": 188.5,
                                      "axle_load_offset": 72.0},
                        ["relaxation", "mass", "gps_latency"], joint, steps, reaches_absence=frozenset({"mass"}),
                        rerun=(["relaxation", "gps_latency", "axle_load_offset"], joint2, steps2))
    assert seen["exclude"] == [[], ["mass"]]
    assert (d.verdict, d.effect) == ("effect", "gps_latency")
    assert _effect(d, "gps_latency")["named"] and _effect(d, "axle_load_offset")["named"]
    m = _effect(d, "mass")
    assert (m["named"], m["not_significant"], m["withdrawn"]) == (False, True, True)
    assert any(s.get("withdrawn") == "mass" for s in d.steps)
    assert any(n.startswith("mass: held-out score 96.7") and "re-run without it" in n for n in d.notes)


def test_a_first_fault_whose_interval_reaches_absence_does_not_rerun(monkeypatch):
    joint = _fit(_values("mass", "gps_latency"))
    steps = [{"step": 1, "added": "mass", "score": 30.0, "against": "nominal model"},
             {"step": 2, "added": "gps_latency", "score": 25.0, "against": "mass"}]
    d, seen = _diagnose(monkeypatch, {"mass": 30.0, "gps_latency": 20.0}, ["mass", "gps_latency"], joint, steps,
                        reaches_absence=frozenset({"mass"}))
    assert seen["exclude"] == [[]]


def test_the_verdict_moves_past_a_fault_whose_interval_reaches_absence(monkeypatch):
    joint = _fit(_values("mass", "gps_latency"))
    steps = [{"step": 1, "added": "mass", "score": 30.0, "against": "nominal model"},
             {"step": 2, "added": "gps_latency", "score": 25.0, "against": "mass"}]
    d, _ = _diagnose(monkeypatch, {"mass": 30.0, "gps_latency": 20.0}, ["mass", "gps_latency"], joint, steps,
                     reaches_absence=frozenset({"mass"}))
    assert (d.verdict, d.effect) == ("effect", "gps_latency")
    assert _effect(d, "gps_latency")["named"] is True


# --------------------------------------------------------------------------- rule 5: a contradicting signal
def test_an_effect_that_worsens_a_signal_it_acts_on_is_contradicted():
    assert engine._contradicted({"speed": 30.7, "gps_speed": 2.3, "front_load": 116.4}) == ""
    why = engine._contradicted({"speed": -15.1, "gps_speed": 27.2})
    assert why.startswith("contradicted by the speed channel") and "15.1" in why
    assert engine._contradicted({"speed": -DETECT_LLR + 0.1, "gps_speed": 27.2}) == ""


def test_stepwise_does_not_add_a_fault_a_channel_contradicts(monkeypatch):
    """Step 2's best addition (a mass, +25 in all) lowers the speed channel by 15: it is not added; the next
    best (a GNSS latency, +12, no channel worse) is."""
    single = {"wheel_radius": 60.0, "mass": 30.0, "gps_latency": 15.0}
    per = {("wheel_radius", "mass"): (25.0, {"speed": -15.0, "gps_speed": 40.0}),
           ("wheel_radius", "gps_latency"): (12.0, {"gps_speed": 12.0})}
    _stepwise(monkeypatch, "wheel_radius", single, {})
    monkeypatch.setattr(engine, "score",
                        lambda problem, cur, ho: per.get(tuple(ho.candidate.split("+")), (0.0, {})))
    results = [CandidateResult(n, True, "", s, {}, _fit(_values(n)), _ho(n), s >= DETECT_LLR)
               for n, s in sorted(single.items(), key=lambda kv: -kv[1])]
    chosen, _, _, steps = engine._stepwise(SimpleNamespace(), results, results[0], _ho("null"), {})
    assert chosen == ["wheel_radius", "gps_latency"]
    assert any("best addition mass" in s.get("stopped", "") and "contradicted by the speed channel" in s["stopped"]
               for s in steps)


def test_a_mass_without_support_in_the_speed_equation_or_the_axle_load_is_not_separated():
    """The GNSS speed channel sees a mass only as the scale of the integrated force, as it sees a torque
    gain: a mass needs support where its inertia or static load acts."""
    assert engine._unseparated("mass", {"speed": -1.2, "gps_speed": 13.4}).startswith("no support where it is separable")
    assert engine._unseparated("mass", {"speed": 30.7, "gps_speed": 2.3, "front_load": 116.4}) == ""
    assert engine._unseparated("mass", {"speed": -3.0, "front_load": 40.0}) == ""
    assert engine._unseparated("gps_latency", {"gps_speed": 13.4}) == ""


def test_a_front_axle_load_offset_needs_support_on_the_pins_own_channel():
    """A front-axle load sensor's offset is an error of that reading: gains on the GNSS speed and slip channels,
    through the wheel loads it shifts, with the pin's own channel losing, are not its evidence (phys_mass_drift:
    +12.2 and +15.7 there, −1.6 on the front load, beside a mass moved wholly onto the front axle)."""
    why = engine._unseparated("axle_load_offset", {"gps_speed": 12.15, "slip": 15.73, "front_load": -1.56})
    assert why.startswith("no support where it is separable (front_load: -1.6 held out)")
    assert "wheel loads" in why
    assert engine._unseparated("axle_load_offset", {"front_load": 240.0, "slip": -0.5}) == ""
    assert "force-scale error" in engine._unseparated("mass", {"gps_speed": 13.4})


def test_a_none_verdict_names_the_best_candidate_that_could_have_been_it():
    """Verdict none: the statement's best candidate is the best one that could have been the verdict, not a
    characteristic reported beside it (phys_torque_rear_low read "best candidate relaxation, held-out score
    267.8 < 10"); one over the threshold that was not named says why."""
    def cr(name, score, reason=""):
        return CandidateResult(name, True, reason, score, {}, None, None, False)

    results = [cr("relaxation", 267.8), cr("wheel_radius", 7.4), cr("drivetrain", 7.1)]
    text = engine._statement("none", None, [], results, None, None, None, {})
    assert "best candidate wheel_radius, held-out score 7.4 < 10" in text
    assert "relaxation" not in text
    results = [cr("relaxation", 267.8), cr("mass", 31.0, "contradicted by the speed channel"), cr("grade", 4.0)]
    text = engine._statement("none", None, [], results, None, None, None, {})
    assert "best candidate mass, held-out score 31.0, not named: contradicted by the speed channel" in text
    assert "No significant mismatch" in engine._statement("none", None, [], [cr("relaxation", 300.0)], None, None,
                                                          None, {})


# --------------------------------------------------------------------------- rule: identified, and the verdict agrees
def test_a_fault_none_of_whose_parameters_is_identified_is_not_named(monkeypatch):
    """A frozen draft reading was the headline "effect: drivetrain", η = 0.6 [0.5, 0.977]: an interval over
    nearly the library's whole range says nothing. It is not named; with structure left in the residuals
    the verdict is "unexplained", never the healthy machine's "none"."""
    joint = _fit(_values("drivetrain", drivetrain={"eta": 0.6}))
    joint.ci95_by["drivetrain"]["eta"] = (0.5, 0.977)
    steps = [{"step": 1, "added": "drivetrain", "score": 49.3, "against": "nominal model"}]
    d, _ = _diagnose(monkeypatch, {"drivetrain": 49.3}, ["drivetrain"], joint, steps)
    e = _effect(d, "drivetrain")
    assert e["kind"] == "effect" and (e["named"], e["not_identified"]) == (False, True)
    assert e["parameters"]["eta"]["identified"] is False
    assert (d.verdict, d.effect) == ("none", None)
    assert d.statement.startswith("No fault named: the best explanation, drivetrain, is not identified")
    assert any(n.startswith("drivetrain: held-out score 49.3, but no parameter is identified") for n in d.notes)
    d2, _ = _diagnose(monkeypatch, {"drivetrain": 49.3}, ["drivetrain"], joint, steps,
                      open_world={"structure_remains": True, "finding": True, "statement": "Unexplained mismatch in the x."})
    assert (d2.verdict, d2.effect) == ("unexplained", None)
    assert d2.statement.startswith("Mismatch that no library effect explains (below); no library effect named: "
                                   "the best explanation, drivetrain")


def test_the_statement_gives_the_reported_interval_of_the_named_fault(monkeypatch):
    """The statement took the candidate's own fit's interval, the effects list the joint fit's calibrated one
    (b_rear 383 [243, 523] against [68, 690] for a true 200): the statement now gives the list's."""
    joint = _fit(_values("gps_latency"))
    joint.ci95_by["gps_latency"]["tau_s"] = (0.12, 0.48)
    steps = [{"step": 1, "added": "gps_latency", "score": 40.0, "against": "nominal model"}]
    d, _ = _diagnose(monkeypatch, {"gps_latency": 40.0}, ["gps_latency"], joint, steps)
    assert (d.verdict, d.effect) == ("effect", "gps_latency")
    assert d.statement == "<effect gps_latency > fitted tau_s [0.12, 0.48]"


def test_a_sensor_fault_of_a_data_check_is_the_verdict_when_nothing_else_is_named(monkeypatch):
    """A wheel-speed hold found by the data check was in ``effects`` as named while the verdict said none."""
    fault = {"wheel": "RL", "kind": "hold", "t0_s": 60.0, "duration_s": 2.9}
    d, _ = _diagnose(monkeypatch, {"gps_latency": 3.0}, [], None, [], sensor_faults=(fault,))
    assert (d.verdict, d.effect) == ("effect", "wheel_speed_hold")
    assert d.statement.startswith("wheel-speed hold on RL: wheel_speed_hold (wheel = RL, t0_s = 60")
