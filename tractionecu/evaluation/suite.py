"""Concealed-effect recordings that prove diagnosis: one effect on, diagnosis not told.

Each case builds a :class:`~tractionecu.sim.simulator.Scenario` from the
simulator's primitives (field, soils, terrain, plan, implement) with exactly
one effect of the library switched on at a realistic size, or none (nulls),
or an effect on a recording that cannot separate it (confounded).  Seeds,
speeds, soils and effect sizes vary between cases.  The truth a case knows
(``effect``, ``params``) is for scoring only and never reaches diagnosis,
which reads the written recording like any other.

Sizes (physics notes, ``shared/design/physics.md``): grades of the real
HENRYS relief (1–4 %), hitch 0.4–0.7 m and centre of gravity 0.9–1.2 m high,
GNSS latency 0.15 s (Doppler) to 0.4 s (position-difference speed),
rolling-radius errors of −1.5 % and +2 %, relaxation lengths 0.5–0.8 m,
ASABE D497 speed coefficients 0.04–0.08 s²/m², front ballast 600–900 kg.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from ..model.effects import validate_params
from ..sim.field import Field, SoilRegion
from ..sim.plan import DS, Plan, back_and_forth, straight
from ..sim.simulator import ImplementSpec, Scenario, simulate
from ..sim.terrain import Terrain
from ..sim.writer import write_recording


@dataclass
class Case:
    """One suite recording: how to build it and what is concealed in it."""

    name: str
    kind: str
    """"effect", "null" or "confounded"."""
    effect: str | None
    params: dict[str, float] = field(default_factory=dict)
    build: Callable[[], Scenario] | None = None
    fast: bool = False
    """Part of the quick subset that runs in CI."""
    full: bool = True
    """Part of the full suite (short CI-only cases are not)."""
    note: str = ""

    def scenario(self) -> Scenario:
        assert self.build is not None
        scn = self.build()
        if self.effect is not None:
            scn.effects = {self.effect: validate_params(self.effect, self.params)}
            if self.effect == "grade":
                scn.field.relief_scale = float(self.params.get("scale", 1.0))
        return scn


# --------------------------------------------------------------------------- building blocks
def _soil(cls: str, a: float, rho: float) -> list[SoilRegion]:
    return [SoilRegion(cls, cls, a=a, rho_s=rho)]


def _north_south(plan: Plan) -> Plan:
    """Turn a plan along ±x into one along ±y (passes across the HENRYS contour lines)."""
    return replace(plan, x=plan.y.copy(), y=plan.x.copy(), heading=(math.pi / 2 - plan.heading))


def _henrys(offset: tuple[float, float]) -> dict:
    return {"terrain": Terrain.henrys_field(), "terrain_offset": offset}


def _speed_steps(plan: Plan, speeds: tuple[float, ...], pass_length: float) -> Plan:
    """Change the working speed along each pass: the pass is split into equal parts at ``speeds``.

    Turns keep their speed.  Operators change speed within a pass (gear/throttle changes), and this
    is what lets a speed-dependent draft show against a draft level that is free per pass.
    """
    v = plan.v_target.copy()
    work_speed = float(np.max(v))
    on_pass = v >= work_speed - 1e-9
    d_in = np.zeros(v.size)
    acc = 0.0
    for k in range(v.size):
        acc = acc + DS if on_pass[k] else 0.0
        d_in[k] = acc
    part = np.minimum((d_in / (pass_length / len(speeds))).astype(int), len(speeds) - 1)
    v = np.where(on_pass, np.asarray(speeds)[part], v)
    return replace(plan, v_target=v)


def _plane(slope: float) -> Terrain:
    """A uniform incline rising ``slope`` [-] to the north (synthetic terrain)."""
    y = np.arange(0.0, 1000.0 + 1e-9, 10.0)
    h = np.repeat((slope * y)[:, None], 3, axis=1)
    return Terrain(h, -1000.0, -100.0, 10.0, f"plane {slope * 100:.1f} % north")


def _work(pass_m: float, n: int, v: float, vturn: float = 1.2) -> Plan:
    return back_and_forth(0.0, 0.0, pass_m, n, 6.0, v_work=v, v_turn=vturn)


# --------------------------------------------------------------------------- cases
def all_cases() -> list[Case]:
    """Every case, full suite and CI-only (see module doc)."""
    C: list[Case] = []

    def add(name, kind, effect, params, build, fast=False, note="", full=True):
        C.append(Case(name, kind, effect, params, build, fast=fast, full=full, note=note))

    # grade: the real HENRYS relief, passes across the contour lines in both directions.
    add("grade_henrys_a", "effect", "grade", {"scale": 1.0},
        lambda: Scenario("grade_henrys_a", Field(_soil("stubble", 0.72, 0.07), **_henrys((300.0, 300.0))),
                         _north_south(_work(260.0, 4, 2.5)), seed=101))
    add("grade_henrys_b", "effect", "grade", {"scale": 1.0},
        lambda: Scenario("grade_henrys_b", Field(_soil("tilled", 0.62, 0.11), **_henrys((650.0, 100.0))),
                         _north_south(_work(240.0, 4, 2.0, 1.0)), seed=102,
                         implement=ImplementSpec(draft_n=15000.0)))
    add("grade_henrys_fast", "effect", "grade", {"scale": 1.0},
        lambda: Scenario("grade_henrys_fast", Field(_soil("grassland", 0.70, 0.05), **_henrys((650.0, 100.0))),
                         _north_south(_work(230.0, 2, 2.5)), seed=103), fast=True, full=False)
    # load transfer
    add("load_transfer_a", "effect", "load_transfer", {"h_hitch_m": 0.5, "h_cg_m": 1.0},
        lambda: Scenario("load_transfer_a", Field(_soil("stubble", 0.75, 0.06)), _work(240.0, 3, 2.5), seed=201))
    add("load_transfer_b", "effect", "load_transfer", {"h_hitch_m": 0.7, "h_cg_m": 1.2},
        lambda: Scenario("load_transfer_b", Field(_soil("grassland", 0.68, 0.05)), _work(240.0, 3, 2.2), seed=202,
                         implement=ImplementSpec(draft_n=21000.0)), fast=False)
    add("load_transfer_fast", "effect", "load_transfer", {"h_hitch_m": 0.4, "h_cg_m": 0.9},
        lambda: Scenario("load_transfer_fast", Field(_soil("tilled", 0.60, 0.12)), _work(110.0, 2, 2.3), seed=203),
        fast=True, full=False)
    # GNSS latency
    add("gps_latency_a", "effect", "gps_latency", {"tau_s": 0.15},
        lambda: Scenario("gps_latency_a", Field(_soil("stubble", 0.72, 0.07)), _work(200.0, 4, 2.5), seed=301))
    add("gps_latency_b", "effect", "gps_latency", {"tau_s": 0.4},
        lambda: Scenario("gps_latency_b", Field(_soil("tilled", 0.62, 0.11)), _work(200.0, 4, 3.0, 1.5), seed=302))
    # rolling radius
    add("wheel_radius_a", "effect", "wheel_radius", {"epsilon": 0.02},
        lambda: Scenario("wheel_radius_a", Field(_soil("stubble", 0.78, 0.06)), _work(220.0, 4, 2.5), seed=401))
    add("wheel_radius_b", "effect", "wheel_radius", {"epsilon": -0.015},
        lambda: Scenario("wheel_radius_b", Field(_soil("grassland", 0.70, 0.05)), _work(220.0, 4, 2.8, 1.4),
                         seed=402))
    # relaxation
    add("relaxation_a", "effect", "relaxation", {"sigma_m": 0.8},
        lambda: Scenario("relaxation_a", Field(_soil("stubble", 0.72, 0.07)), _work(200.0, 3, 2.5), seed=501))
    add("relaxation_b", "effect", "relaxation", {"sigma_m": 0.5},
        lambda: Scenario("relaxation_b", Field(_soil("tilled", 0.60, 0.12)), _work(200.0, 3, 1.8, 1.0), seed=502))
    add("relaxation_fast", "effect", "relaxation", {"sigma_m": 0.6},
        lambda: Scenario("relaxation_fast", Field(_soil("grassland", 0.70, 0.05)), _work(100.0, 2, 2.2), seed=503),
        fast=True, full=False)
    # speed-dependent draft: the operator changes speed within each pass
    add("draft_speed_a", "effect", "draft_speed", {"c_s2pm2": 0.04, "v_ref_mps": 2.5},
        lambda: Scenario("draft_speed_a", Field(_soil("stubble", 0.75, 0.06)),
                         _speed_steps(_work(240.0, 3, 3.0), (2.0, 3.0, 2.5), 240.0), seed=601))
    add("draft_speed_b", "effect", "draft_speed", {"c_s2pm2": 0.08, "v_ref_mps": 2.5},
        lambda: Scenario("draft_speed_b", Field(_soil("tilled", 0.62, 0.11)),
                         _speed_steps(_work(240.0, 3, 2.8), (2.8, 1.8, 2.4), 240.0), seed=602,
                         implement=ImplementSpec(draft_n=14000.0)))
    # mass / ballast
    add("mass_a", "effect", "mass", {"delta_kg": 800.0, "front_share": 1.0},
        lambda: Scenario("mass_a", Field(_soil("stubble", 0.72, 0.07)), _work(200.0, 4, 2.5), seed=701))
    add("mass_b", "effect", "mass", {"delta_kg": 600.0, "front_share": 0.6},
        lambda: Scenario("mass_b", Field(_soil("grassland", 0.70, 0.05)), _work(200.0, 4, 2.2, 1.0), seed=702))
    # nulls
    add("null_henrys_geometry", "null", None, {},
        lambda: Scenario("null_henrys_geometry", Field(_soil("stubble", 0.72, 0.07)),
                         _north_south(_work(260.0, 4, 2.5)), seed=801))
    add("null_fast", "null", None, {},
        lambda: Scenario("null_fast", Field(_soil("stubble", 0.74, 0.07)), _work(120.0, 2, 2.4), seed=804),
        fast=True, full=False)
    add("null_three_soils", "null", None, {},
        lambda: _three_soils(seed=802))
    add("null_tilled_grass", "null", None, {},
        lambda: Scenario("null_tilled_grass",
                         Field([SoilRegion("grassland", "grassland", a=0.70, rho_s=0.05),
                                SoilRegion("tilled", "tilled", a=0.62, rho_s=0.11,
                                           polygon=((120.0, -20.0), (400.0, -20.0), (400.0, 60.0), (120.0, 60.0)))]),
                         _work(240.0, 3, 2.0, 1.0), seed=803, implement=ImplementSpec(draft_n=19000.0)))
    # confounded: a uniform 3 % incline driven in one direction only; grade and a constant
    # resistance (soil ρ_s or a constant draft) are the same force there.
    add("confounded_grade_one_direction", "confounded", "grade", {"scale": 1.0},
        lambda: Scenario("confounded_grade_one_direction",
                         Field(_soil("stubble", 0.72, 0.07), terrain=_plane(0.03)),
                         straight(0.0, 0.0, math.pi / 2, 300.0, 2.5), seed=901),
        fast=True, note="uniform 3 % incline, one pass direction")
    return C


def _three_soils(seed: int) -> Scenario:
    from ..sim.scenarios import paper_three_soils
    return paper_three_soils(seed=seed)


def cases() -> list[Case]:
    """The full suite."""
    return [c for c in all_cases() if c.full]


def fast_cases() -> list[Case]:
    """The quick subset run in CI."""
    return [c for c in all_cases() if c.fast]


def write_case(case: Case, out: str | Path) -> Path:
    """Simulate ``case`` and write its recording directory; returns the path."""
    out = Path(out)
    scn = case.scenario()
    tr = simulate(scn)
    write_recording(scn, tr, out)
    return out


# --------------------------------------------------------------------------- scoring
def score_case(case: Case, d) -> dict:
    """Compare one diagnosis (:class:`~tractionecu.diagnose.engine.Diagnosis`) with the concealed truth.

    - ``correct``: effect cases: verdict ``effect`` naming the concealed effect; nulls: verdict
      ``none``; confounded: verdict ``ambiguous``;
    - ``covered``: per fitted parameter of the concealed effect's candidate (fitted in every
      diagnosis), whether its 95 % interval holds the true value;
    - ``rmse_reduction``: 1 − RMSE_after/RMSE_before on held-out data of the concealed effect's
      candidate, on its affected signal: the channel, among those the effect acts on, where the
      reduction is largest.
    """
    row: dict = {"case": case.name, "kind": case.kind, "truth": case.effect, "truth_params": dict(case.params),
                 "verdict": d.verdict, "effect": d.effect, "ambiguous_between": list(d.ambiguous_between)}
    if case.kind == "null":
        row["correct"] = d.verdict == "none"
    elif case.kind == "confounded":
        row["correct"] = d.verdict == "ambiguous"
    else:
        row["correct"] = d.verdict == "effect" and d.effect == case.effect
    top = [c for c in d.candidates if c.testable]
    row["ranking"] = [(c.name, round(float(c.score), 2)) for c in top[:4]]
    if case.effect is None:
        return row
    cr = d.candidate(case.effect)
    if cr is None or cr.fit is None:
        row["covered"] = {k: False for k in case.params if k != "v_ref_mps"}
        row["fitted"] = {}
        row["rmse_reduction"] = None
        row["affected_signal"] = None
        return row
    cov, fitted = {}, {}
    for k, (lo, hi) in cr.fit.ci95.items():
        if k not in case.params:
            continue
        tv = float(case.params[k])
        fitted[k] = {"value": float(cr.fit.params[k]), "ci95": [float(lo), float(hi)], "true": tv}
        cov[k] = bool(lo <= tv <= hi)
    row["covered"] = cov
    row["fitted"] = fitted
    best, best_red = None, None
    for ch in d.problem.channels.values():
        if case.effect not in ch.effects or cr.heldout is None:
            continue
        n0 = d.null_heldout.sse[ch.name]
        n1 = cr.heldout.sse[ch.name]
        if n0 > 0:
            red = 1.0 - math.sqrt(n1 / n0)
            if best_red is None or red > best_red:
                best, best_red = ch.name, red
    row["affected_signal"] = best
    row["rmse_reduction"] = best_red
    row["score"] = float(cr.score)
    return row


def summarize(rows: list[dict]) -> dict:
    """Suite figures from scored rows (see :func:`score_case`)."""
    eff = [r for r in rows if r["kind"] == "effect"]
    nulls = [r for r in rows if r["kind"] == "null"]
    conf = [r for r in rows if r["kind"] == "confounded"]
    pairs = [ok for r in eff for ok in r.get("covered", {}).values()]
    prim = []
    for r in eff:
        cov = r.get("covered", {})
        if cov:
            first = next(iter(cov))
            prim.append(cov[first])
    red = [r["rmse_reduction"] for r in eff if r.get("rmse_reduction") is not None]
    return {
        "n_effect_cases": len(eff),
        "top1_accuracy": float(np.mean([r["correct"] for r in eff])) if eff else None,
        "ci_coverage": float(np.mean(pairs)) if pairs else None,
        "ci_coverage_primary": float(np.mean(prim)) if prim else None,
        "n_ci_parameters": len(pairs),
        "median_heldout_rmse_reduction": float(np.median(red)) if red else None,
        "null_false_alarms": int(sum(not r["correct"] for r in nulls)),
        "n_null_cases": len(nulls),
        "confounded_as_ambiguous": bool(conf) and all(r["correct"] for r in conf),
        "n_confounded_cases": len(conf),
    }


# --------------------------------------------------------------------------- rough exports
def export_engine_csv(recording: str | Path, path: str | Path, *, gear_ratio: float = 60.0,
                      reference_torque_nm: float = 450.0, rate_hz: float = 1.0) -> Path:
    """Write a J1939-style decoded export of a recording, as a CAN logger's 1 Hz CSV would hold it.

    The simulated tractor drives its wheels directly; the export pretends one engine drives all
    four wheels through a fixed ratio ``gear_ratio`` [-] without loss:
    engine speed ω_e = i ω̄_wheel, engine torque T_e = Σ M_i / i, written as percent of
    ``reference_torque_nm`` (EEC1 SPN 513, 1 % resolution) and rpm (SPN 190, 0.125 rpm);
    wheel-based speed from WBSD in km/h (CCVS SPN 84, 1/256 km/h); GNSS speed in km/h, position
    and altitude from the NMEA fixes.  Each column holds the latest value at each export tick
    (a logger's sample-and-hold); there is no per-wheel signal and no draft.  Time column
    ``timestamps`` in seconds since the start.
    """
    import csv

    from ..model.vehicle import WHEELS
    from ..recording.reader import read_recording

    rec = read_recording(recording)
    tab = rec.table(rate_hz)
    t = tab.t - tab.t[0]
    om = np.mean([tab[f"WheelSpeed_{w}"] for w in WHEELS], axis=0)
    md = np.sum([tab[f"DriveTorque_{w}"] for w in WHEELS], axis=0)
    eng_speed_rpm = np.round(gear_ratio * om * 60.0 / (2 * math.pi) / 0.125) * 0.125
    torque_pct = np.round(md / gear_ratio / reference_torque_nm * 100.0)
    ccvs_kmh = np.round(tab["WheelBasedMachineSpeed"] * 3.6 * 256.0) / 256.0
    gnss_kmh = tab["gps_speed"] * 3.6
    out = Path(path)
    with open(out, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["timestamps", "EEC1_ActualEnginePercentTorque", "EEC1_EngineSpeed", "CCVS1_WheelBasedVehicleSpeed",
                    "GNSS_Speed", "Latitude", "Longitude", "gnss_altitude_Altitude"])
        for k in range(t.size):
            vals = [torque_pct[k], eng_speed_rpm[k], ccvs_kmh[k], gnss_kmh[k], tab["gps_lat"][k], tab["gps_lon"][k],
                    tab["gps_alt"][k]]
            if not all(np.isfinite(vals)):
                continue
            w.writerow([f"{t[k]:.3f}", f"{vals[0]:.0f}", f"{vals[1]:.3f}", f"{vals[2]:.4f}", f"{vals[3]:.3f}",
                        f"{vals[4]:.8f}", f"{vals[5]:.8f}", f"{vals[6]:.2f}"])
    return out
