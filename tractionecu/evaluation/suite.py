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

from ..model.effects import EFFECTS, validate_params
from ..sim.field import Field, SoilRegion
from ..sim.plan import DS, Plan, back_and_forth, straight
from ..sim.simulator import ImplementSpec, Scenario, simulate
from ..sim.terrain import Terrain
from ..sim.writer import write_recording


@dataclass
class Fault:
    """A fault written into the recording after simulation (:mod:`.faults`): a library sensor fault
    (``name`` in ``SENSOR_FAULTS`` with its true ``params``) or an out-of-library one (``name``
    starting ``outside:``, described in words)."""

    name: str
    params: dict[str, float]
    apply: Callable[[Path, Path], Path]


@dataclass
class Case:
    """One suite recording: how to build it and what is concealed in it."""

    name: str
    kind: str
    """"effect", "null", "confounded", "nominal" (only what every tractor has: load transfer, whose
    heights are scored), "characteristic" (tyre relaxation or drivetrain efficiency at a healthy size:
    reported as the machine's, not as a fault) or "outside" (an effect outside the library)."""
    effect: str | None
    params: dict[str, float] = field(default_factory=dict)
    build: Callable[[], Scenario] | None = None
    fast: bool = False
    """Part of the quick subset that runs in CI."""
    full: bool = True
    """Part of the full suite (short CI-only cases are not)."""
    note: str = ""
    truth_model: str = "paper"
    """Which simulator made the recording: ``paper`` (the paper's model with library effects switched
    on), ``physical`` (the independent truth model, ``tractionecu.sim.physical``, hub drive) or
    ``physical-mech`` (the same truth model with the mechanical MFWD drive-line)."""
    extra: dict[str, dict[str, float]] = field(default_factory=dict)
    """Further concealed effects of the paper truth model (several effects at once)."""
    faults: tuple[Fault, ...] = ()
    vehicle_edit: dict[str, float] = field(default_factory=dict)
    """Entries of ``vehicle.toml`` changed after writing: the file then disagrees with the machine
    (a mass error is the file's mass below the truth's)."""

    def scenario(self) -> Scenario:
        assert self.build is not None
        scn = self.build()
        if self.truth_model == "paper":
            effs = {}
            if self.effect is not None and self.kind != "outside" and self.effect in EFFECTS:
                effs[self.effect] = validate_params(self.effect, self.params)
            for k, v in self.extra.items():
                effs[k] = validate_params(k, v)
            if effs:
                scn.effects = effs
            if "grade" in effs:
                scn.field.relief_scale = float(effs["grade"].get("scale", 1.0))
        return scn

    def concealed(self) -> dict[str, dict[str, float]]:
        """Every library effect or fault concealed in the recording, with its true parameters
        (load transfer is part of the nominal model and not listed)."""
        out: dict[str, dict[str, float]] = {}
        if self.effect is not None and self.kind in ("effect", "confounded", "characteristic"):
            out[self.effect] = dict(self.params)
        for k, v in self.extra.items():
            if k != "load_transfer":
                out[k] = dict(v)
        for f in self.faults:
            if not f.name.startswith("outside:"):
                out[f.name] = dict(f.params)
        return out


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

    def add(name, kind, effect, params, build, fast=False, note="", full=True, **kw):
        C.append(Case(name, kind, effect, params, build, fast=fast, full=full, note=note, **kw))

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
    add("load_transfer_a", "nominal", "load_transfer", {"h_hitch_m": 0.5, "h_cg_m": 1.0},
        lambda: Scenario("load_transfer_a", Field(_soil("stubble", 0.75, 0.06)), _work(240.0, 3, 2.5), seed=201))
    add("load_transfer_b", "nominal", "load_transfer", {"h_hitch_m": 0.7, "h_cg_m": 1.2},
        lambda: Scenario("load_transfer_b", Field(_soil("grassland", 0.68, 0.05)), _work(240.0, 3, 2.2), seed=202,
                         implement=ImplementSpec(draft_n=21000.0)), fast=False)
    add("load_transfer_fast", "nominal", "load_transfer", {"h_hitch_m": 0.4, "h_cg_m": 0.9},
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
    add("relaxation_a", "characteristic", "relaxation", {"sigma_m": 0.8},
        lambda: Scenario("relaxation_a", Field(_soil("stubble", 0.72, 0.07)), _work(200.0, 3, 2.5), seed=501))
    add("relaxation_b", "characteristic", "relaxation", {"sigma_m": 0.5},
        lambda: Scenario("relaxation_b", Field(_soil("tilled", 0.60, 0.12)), _work(200.0, 3, 1.8, 1.0), seed=502))
    add("relaxation_fast", "characteristic", "relaxation", {"sigma_m": 0.6},
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
    _realistic_cases(add)
    return C


LT = {"load_transfer": {"h_hitch_m": 0.6, "h_cg_m": 1.1}}
"""Load transfer of a real tractor (switched on in every paper-truth recording of a realistic plant)."""


def _phys(seed: int, **phys):
    """``physical-three-soils`` of the independent truth model (tractionecu.sim.physical)."""
    def build():
        from ..sim.scenarios import physical_three_soils

        return physical_three_soils(seed=seed, **({"physical": _phys_spec(**phys)} if phys else {}))
    return build


def _phys_spec(**phys):
    from ..sim.physical import PhysicalSpec
    from ..sim.scenarios import PHYSICAL_THREE_SOILS

    return PhysicalSpec(PHYSICAL_THREE_SOILS, **phys)


def _phys_reverse(seed: int):
    """``physical-headland-reverse``: the physical truth with a three-point turn at every headland."""
    def build():
        from ..sim.scenarios import physical_headland_reverse

        return physical_headland_reverse(seed=seed)
    return build


def _phys_pressure(seed: int, p_true_pa: float, p_declared_pa: float):
    """``physical-three-soils`` with the tyres at ``p_true_pa`` while the vehicle file declares
    ``p_declared_pa`` (and its rear radius was calibrated there)."""
    def build():
        from ..config import VehicleParams
        from ..sim.scenarios import physical_three_soils

        return physical_three_soils(seed=seed, vehicle=VehicleParams(tyre_pressure_pa=p_true_pa),
                                    physical=_phys_spec(declared_tyre_pressure_pa=p_declared_pa))
    return build


def _mech(seed: int):
    """``mechanical-three-soils`` of the independent truth model with the mechanical drive-line."""
    def build():
        from ..sim.scenarios import mechanical_three_soils

        return mechanical_three_soils(seed=seed)
    return build


def _phys_short(seed: int):
    """A shorter physical-truth recording (two 110-m passes) for the CI subset."""
    def build():
        from ..sim.scenarios import physical_three_soils

        scn = physical_three_soils(seed=seed)
        return replace(scn, name="physical-short", plan=_work(110.0, 2, 2.4))
    return build


def _realistic_cases(add) -> None:
    """Recordings of a realistic plant: the independent truth model (``physical``) and the paper's
    model with load transfer always on; several effects per recording, sensor faults written into the
    recording as the faulty sensor would (:mod:`.faults`), and effects outside the library."""
    from . import faults as F

    both = {"FL": 0.0, "FR": 0.0}
    # Nulls of the realistic plant.
    add("phys_null_a", "null", None, {}, _phys(1101), truth_model="physical")
    add("phys_null_b", "null", None, {}, _phys(1102), truth_model="physical")
    add("phys_null_short", "null", None, {}, _phys_short(1103), truth_model="physical", fast=True, full=False)
    add("phys_null_c", "null", None, {}, _phys(1104), truth_model="physical")
    # A healthy machine that reverses at every headland (three-point turns: quarter circle, stop, 12 m back
    # at 1 m/s, stop): everyday driving the forward-only nulls do not have.
    add("phys_null_reverse", "null", None, {}, _phys_reverse(1105), truth_model="physical", fast=True)
    # The mechanical MFWD tractor of the physical truth model (engine, powershift, front-axle lead,
    # drive-line losses; J1939 engine-level signals, no per-wheel torque, no axle-load pin).
    add("mech_null_a", "null", None, {}, _mech(1111), truth_model="physical-mech")
    add("mech_null_b", "null", None, {}, _mech(1112), truth_model="physical-mech")
    # Sensor faults on the physical truth.
    add("phys_torque_rear_low", "effect", None, {}, _phys(1201), truth_model="physical",
        faults=(Fault("torque_gain", {"k_front": 0.0, "k_rear": -0.07},
                      lambda a, b: F.torque_gain(a, b, {"RL": -0.07, "RR": -0.07, **both})),),
        note="rear torque reads 7 % low")
    add("phys_draft_drift", "effect", None, {}, _phys(1202), truth_model="physical",
        faults=(Fault("draft_offset", {"b0_n": 0.0, "b1_npm": 300.0}, lambda a, b: F.draft_offset(a, b, 0.0, 300.0)),),
        note="draft reading drifts 0 → 2 kN")
    add("phys_wheel_dropout", "effect", None, {}, _phys(1203), truth_model="physical",
        faults=(Fault("wheel_speed_hold", {"t0_s": 150.0, "duration_s": 3.0},
                      lambda a, b: F.wheel_speed_hold(a, b, "RL", 150.0, 3.0, "dropout")),),
        note="RL wheel speed reads 0 for 3 s")
    add("phys_wheel_dropout_short", "effect", None, {}, _phys_short(1213), truth_model="physical", fast=True,
        full=False, faults=(Fault("wheel_speed_hold", {"t0_s": 40.0, "duration_s": 3.0},
                                  lambda a, b: F.wheel_speed_hold(a, b, "RL", 40.0, 3.0, "dropout")),))
    # The library's remaining recording-level sensor faults on the physical truth, one recording each, sizes
    # fixed before their first diagnosis: a drive-torque zero offset of 2 % of a 10 kN·m range on the rear
    # axle; a CAN logger whose clock runs 0.3 s ahead of GNSS time and gains 100 ppm (a cheap RTC across
    # temperature); tyres let down to 1.2 bar while the vehicle file (and the rear radius's calibration run)
    # says 1.6 bar.  A logger clock *behind* GNSS time is, to the data, a GNSS latency of the same size
    # (the gps_latency cases).
    add("phys_torque_offset", "effect", None, {}, _phys(1204), truth_model="physical",
        faults=(Fault("torque_offset", {"b_front_nm": 0.0, "b_rear_nm": 200.0},
                      lambda a, b: F.torque_offset(a, b, {"RL": 200.0, "RR": 200.0})),),
        note="rear drive torques read 200 N·m high")
    # The same fault on a machine that reverses at every headland: a torque offset keeps its sign in reverse,
    # while the tyre's zero-slip traction ratio and the motion resistance turn with the travel.
    add("phys_torque_offset_reverse", "effect", None, {}, _phys_reverse(1207), truth_model="physical",
        faults=(Fault("torque_offset", {"b_front_nm": 0.0, "b_rear_nm": 200.0},
                      lambda a, b: F.torque_offset(a, b, {"RL": 200.0, "RR": 200.0})),),
        note="rear drive torques read 200 N·m high, reversing headlands")
    add("phys_clock_skew", "effect", None, {}, _phys(1205), truth_model="physical",
        faults=(Fault("clock_skew", {"offset_s": 0.3, "rate_ppm": 100.0},
                      lambda a, b: F.clock_skew(a, b, 0.3, 100.0)),),
        note="CAN clock 0.3 s ahead of GNSS, +100 ppm")
    add("phys_tyre_pressure", "effect", "tyre_pressure", {"p_ratio": 0.75}, _phys_pressure(1206, 1.2e5, 1.6e5),
        truth_model="physical", note="tyres at 1.2 bar, the file says 1.6 bar")
    # Several at once on the physical truth: a GNSS latency (receiver) and an axle-load offset.
    add("phys_latency_axle", "effect", "gps_latency", {"tau_s": 0.3}, _phys(1301, gnss_latency_s=0.3),
        truth_model="physical",
        faults=(Fault("axle_load_offset", {"b0_n": 2500.0, "b1_npm": 0.0},
                      lambda a, b: F.axle_load_offset(a, b, 2500.0)),),
        note="GNSS latency 0.3 s + axle-load offset 2.5 kN")
    # The file's mass below the machine's (ballast the file does not know) with a draft drift.
    add("phys_mass_drift", "effect", "mass", {"delta_kg": 800.0, "front_share": 0.4}, _phys(1302),
        truth_model="physical",
        vehicle_edit={"mass_kg": 6300.0 - 800.0},
        faults=(Fault("draft_offset", {"b0_n": 0.0, "b1_npm": 200.0}, lambda a, b: F.draft_offset(a, b, 0.0, 200.0)),),
        note="vehicle file 800 kg light + draft drift")
    # Outside the library.
    add("phys_one_wheel_gain", "outside", None, {}, _phys(1401), truth_model="physical",
        faults=(Fault("outside:torque gain on FL only (+10 %)", {}, lambda a, b: F.torque_gain(a, b, {"FL": 0.10})),),
        note="FL torque +10 % (one wheel)")
    add("phys_draft_step", "outside", None, {}, _phys(1402), truth_model="physical",
        faults=(Fault("outside:draft offset stepping to 1.5 kN at t = 200 s", {},
                      lambda a, b: F.signal_offset(a, b, "RearHitchStatus", "DraftForce",
                                                   lambda t: 1500.0 if t >= 200.0 else 0.0)),),
        note="draft offset steps 0 → 1.5 kN")
    # Several effects at once on the paper's model with load transfer on (realistic plant).
    add("multi_grade_latency", "effect", "grade", {"scale": 1.0},
        lambda: Scenario("multi_grade_latency", Field(_soil("stubble", 0.72, 0.07), **_henrys((300.0, 300.0))),
                         _north_south(_work(260.0, 4, 2.5)), seed=1501),
        extra={"gps_latency": {"tau_s": 0.3}, **LT})
    add("multi_mass_radius", "effect", "mass", {"delta_kg": 700.0, "front_share": 1.0},
        lambda: Scenario("multi_mass_radius", Field(_soil("stubble", 0.74, 0.07)), _work(220.0, 4, 2.5), seed=1502),
        extra={"wheel_radius": {"epsilon": -0.02}, **LT})
    add("multi_drivetrain_lt", "characteristic", "drivetrain", {"eta": 0.88, "loss_nm": 0.0},
        lambda: Scenario("multi_drivetrain_lt", Field(_soil("grassland", 0.70, 0.05)), _work(220.0, 4, 2.5),
                         seed=1503), extra=dict(LT))
    add("multi_relaxation_lt", "characteristic", "relaxation", {"sigma_m": 0.6},
        lambda: Scenario("multi_relaxation_lt", Field(_soil("stubble", 0.72, 0.07)), _work(200.0, 3, 2.2),
                         seed=1504), extra=dict(LT))
    add("null_lt_fast", "null", None, {},
        lambda: Scenario("null_lt_fast", Field(_soil("stubble", 0.74, 0.07)), _work(120.0, 2, 2.4), seed=1505),
        extra=dict(LT), fast=True, full=False)


def _three_soils(seed: int) -> Scenario:
    from ..sim.scenarios import paper_three_soils
    return paper_three_soils(seed=seed)


def cases() -> list[Case]:
    """The full suite."""
    return [c for c in all_cases() if c.full]


def fast_cases() -> list[Case]:
    """The quick subset run in CI."""
    return [c for c in all_cases() if c.fast]


def write_case(case: Case, out: str | Path, seed_offset: int = 0) -> Path:
    """Simulate ``case``, write its recording directory and apply its recording-level faults and
    vehicle-file edits; returns the path.  ``seed_offset`` is added to the scenario's seed: the same
    case with other noise, sensor draws and disturbances (recordings the diagnosis was never run on)."""
    import shutil

    out = Path(out)
    scn = case.scenario()
    if seed_offset:
        scn = replace(scn, seed=scn.seed + int(seed_offset))
    tr = simulate(scn)
    if not case.faults:
        write_recording(scn, tr, out)
    else:
        stage = out.with_name(out.name + ".stage")
        if stage.exists():
            shutil.rmtree(stage)
        write_recording(scn, tr, stage)
        for k, f in enumerate(case.faults):
            nxt = out if k == len(case.faults) - 1 else out.with_name(f"{out.name}.stage{k}")
            f.apply(stage, nxt)
            shutil.rmtree(stage)
            stage = nxt
    if case.vehicle_edit:
        _edit_vehicle(out / "vehicle.toml", case.vehicle_edit)
    return out


def _edit_vehicle(path: Path, edits: dict[str, float]) -> None:
    import re

    text = path.read_text(encoding="utf-8")
    for k, v in edits.items():
        text, n = re.subn(rf"(?m)^(\s*{re.escape(k)}\s*=\s*)[^\n#]+", rf"\g<1>{v!r}", text)
        if n != 1:
            raise ValueError(f"{path}: no single entry {k!r} to edit")
    path.write_text(text, encoding="utf-8")


# --------------------------------------------------------------------------- scoring
def _reported(d) -> list[str]:
    """Library effects the diagnosis reports, in rank order: named effects and faults, then ambiguous
    ones, then the machine's characteristics (healthy relaxation, drivetrain efficiency)."""
    named = [e["name"] for e in d.effects if e["kind"] in ("effect", "sensor_fault") and e.get("named")
             and not e.get("ambiguous")]
    amb = [e["name"] for e in d.effects if e["kind"] in ("effect", "sensor_fault") and e.get("ambiguous")]
    chars = [e["name"] for e in d.effects if e["kind"] == "characteristic"]
    out = []
    for n in named + amb + chars:
        if n not in out:
            out.append(n)
    return out


def _fit_of(d, name: str):
    """(parameters, 95 % intervals, at-bound flags) of ``name``: from the joint fit when it was chosen,
    else from its own single fit."""
    jf = d.joint
    if jf is not None and name in jf.effects and name in jf.ci95_by:
        return jf.effects[name], jf.ci95_by[name], jf.at_bound.get(name, {})
    cr = d.candidate(name)
    if cr is None or cr.fit is None:
        return None
    return cr.fit.params, cr.fit.ci95, cr.fit.at_bound.get(name, {})


def score_case(case: Case, d, seed_offset: int = 0) -> dict:
    """Compare one diagnosis (:class:`~tractionecu.diagnose.engine.Diagnosis`) of ``case`` (written with
    ``seed_offset``) with the concealed truth.

    - ``correct``: nulls and nominal cases: verdict ``none`` (no effect or fault named);
      confounded: verdict ``ambiguous``; effect cases: every concealed effect is among the reported
      effects (named, or listed as ambiguous) and ranked above every reported effect that is absent;
      outside cases: no library effect named (the mismatch is located instead: ``located``);
    - ``top1``: single-effect cases: verdict ``effect`` naming the concealed effect;
    - ``covered``: per true parameter of a concealed effect (``effect.param``), whether its 95 %
      interval holds the true value (nominal cases: the load-transfer heights);
    - ``rmse_reduction``: 1 − RMSE_after/RMSE_before on held-out data of the final model (the joint
      fit, else the winner, else -- nothing fitted -- the nominal model itself, which reduces nothing:
      0), on the channel where the reduction is largest among those the concealed effects act on.
    """
    conc = case.concealed()
    rep = _reported(d)
    # What the plant has against the nominal model without any concealed effect (the physical truth
    # model's rolling radius): reported at its true size, it is neither a false alarm nor an absent effect.
    plant = {}
    for key, (lo_t, hi_t) in inherent(case, seed_offset).items():
        name, par = key.split(".", 1)
        got = _fit_of(d, name) if name in rep else None
        if got is not None and par in got[1]:
            lo, hi = got[1][par]
            plant[name] = {"parameter": par, "value": float(got[0][par]), "ci95": [float(lo), float(hi)],
                           "plant_range": [lo_t, hi_t], "agrees": bool(lo <= hi_t and hi >= lo_t)}
    rep_eval = [n for n in rep if not (n in plant and plant[n]["agrees"] and n not in conc)]
    faults = [n for n in rep_eval if not any(e["name"] == n and e["kind"] == "characteristic" for e in d.effects)]
    row: dict = {"case": case.name, "kind": case.kind, "truth_model": case.truth_model,
                 "truth": "+".join(conc) or (case.note or None), "truth_params": conc,
                 "verdict": d.verdict, "effect": d.effect, "ambiguous_between": list(d.ambiguous_between),
                 "reported": rep, "plant": plant}
    if case.kind in ("null", "nominal"):
        row["correct"] = (d.verdict == "none" or d.effect in plant and plant[d.effect]["agrees"]) and not faults
    elif case.kind == "confounded":
        row["correct"] = d.verdict == "ambiguous"
    elif case.kind == "outside":
        row["correct"] = not any(e.get("named") and not e.get("ambiguous") for e in d.effects
                                 if e["kind"] in ("effect", "sensor_fault") and e["name"] != "wheel_speed_hold")
        row["located"] = bool(d.open_world.get("structure_remains"))
        row["open_world"] = {k: d.open_world.get(k) for k in ("channel", "term_order", "heldout_rmse_reduction",
                                                              "where")}
    elif case.kind == "characteristic":
        # A healthy-size characteristic (relaxation, drivetrain efficiency): reported as the machine's,
        # no fault named.
        row["correct"] = d.verdict == "none" and not faults and all(n in rep for n in conc)
    else:
        absent = [i for i, n in enumerate(rep_eval) if n not in conc]
        found = [rep_eval.index(n) if n in rep_eval else None for n in conc]
        row["correct"] = all(i is not None for i in found) and (not absent or max(found) < min(absent))
    if len(conc) == 1 and case.kind == "effect":
        row["top1"] = d.verdict == "effect" and d.effect == next(iter(conc))
    top = [c for c in d.candidates if c.testable]
    row["ranking"] = [(c.name, round(float(c.score), 2)) for c in top[:4]]
    cov, fitted = {}, {}
    if case.kind == "nominal":
        nom = next((e for e in d.effects if e["kind"] == "nominal"), None)
        for k, tv in case.params.items():
            if nom is None or k not in nom["parameters"] or not nom["parameters"][k].get("ci95"):
                cov[f"load_transfer.{k}"] = False
                continue
            p = nom["parameters"][k]
            lo, hi = p["ci95"]
            fitted[f"load_transfer.{k}"] = {"value": p["value"], "ci95": [lo, hi], "true": tv, "at_bound": ""}
            cov[f"load_transfer.{k}"] = bool(lo <= tv <= hi)
    for name, tp in conc.items():
        got = _fit_of(d, name) if name in _candidates() else None
        for k, tv in tp.items():
            if name == "wheel_speed_hold" or k not in {p.name for p in _candidates()[name].fitted}:
                continue   # held parameters (v_ref, a loss torque) have no interval
            key = f"{name}.{k}"
            if got is None or k not in got[1]:
                cov[key] = False
                continue
            lo, hi = got[1][k]
            ident = _identified(name, k, lo, hi)
            fitted[key] = {"value": float(got[0][k]), "ci95": [float(lo), float(hi)], "true": float(tv),
                           "at_bound": got[2].get(k, ""), "identified": ident}
            # An interval spanning (nearly) the whole range of the parameter says nothing: it does not
            # count as holding the truth.
            cov[key] = bool(ident and lo <= tv <= hi)
    row["covered"] = cov
    row["fitted"] = fitted
    final = d.joint_heldout or (d.winner.heldout if d.winner is not None else None)
    if final is None:
        # Nothing fitted (the effect missed, or only listed as ambiguous): the final model is the nominal one
        # and its held-out RMSE the null's.  Left out, a missed effect dropped out of the median instead of
        # counting as the 0 it reduced.
        final = d.null_heldout
    best, best_red = None, None
    if final is not None and conc:
        for ch in d.problem.channels.values():
            n0 = d.null_heldout.sse[ch.name]
            n1 = final.sse[ch.name]
            if n0 > 0 and any(n in ch.effects for n in conc):
                red = 1.0 - math.sqrt(n1 / n0)
                if best_red is None or red > best_red:
                    best, best_red = ch.name, red
    row["affected_signal"] = best
    row["rmse_reduction"] = best_red
    return row


def _identified(name: str, k: str, lo: float, hi: float) -> bool:
    from ..diagnose.engine import identified

    return identified(name, k, float(lo), float(hi))


def inherent(case: Case, seed_offset: int = 0) -> dict[str, tuple[float, float]]:
    """Deviations the plant of a case has from the nominal model with nothing concealed, as
    ``{"effect.param": (low, high)}``: for the independent truth model, the rolling radius, whose
    tyre deflects under load by its own law (``sim.tyre.rolling_radius``) while the nominal model uses
    the radius of the vehicle file the recording carries (``sim.physwriter``: eq. 9 through the rear radius
    its owner calibrated, off the truth's inside its tolerance, drawn per seed, hence ``seed_offset`` as
    :func:`write_case` takes it); the range is r_truth/r_nominal − 1 over the static front and rear wheel
    loads, at the tyre pressure the file declares.  The paper truth model has none."""
    if case.truth_model == "paper":
        return {}
    from ..config import G
    from ..model.vehicle import rolling_radius
    from ..sim import tyre as ty
    from ..sim.physwriter import _declared_vehicle

    scn = case.scenario()
    if seed_offset:
        scn = replace(scn, seed=scn.seed + int(seed_offset))
    tyre = scn.physical.tyre if scn.physical is not None else ty.TyreSpec()
    # The file as written, before any edit of the case (a concealed mass error is the case's effect, not the
    # plant's); at the pressure it declares: a concealed pressure error is the case's effect too.
    veh = _declared_vehicle(scn) if scn.physical is not None else scn.vehicle
    f = veh.static_front_fraction
    p = veh.tyre_pressure_pa
    eps = []
    for fz in (f * veh.mass_kg * G / 2, (1 - f) * veh.mass_kg * G / 2):
        rt = float(ty.rolling_radius(np.array([fz]), veh.r0_m, tyre, p)[0])
        rn = float(rolling_radius(np.array([fz]), veh)[0])
        eps.append(rt / rn - 1.0)
    return {"wheel_radius.epsilon": (min(eps), max(eps))}


def _candidates():
    from ..diagnose.candidates import CANDIDATES

    return CANDIDATES


def summarize(rows: list[dict]) -> dict:
    """Suite figures from scored rows (see :func:`score_case`), with coverage per effect."""
    eff = [r for r in rows if r["kind"] in ("effect", "characteristic")]
    nulls = [r for r in rows if r["kind"] in ("null", "nominal")]
    conf = [r for r in rows if r["kind"] == "confounded"]
    outside = [r for r in rows if r["kind"] == "outside"]
    pairs = [ok for r in rows for ok in r.get("covered", {}).values()]
    per_effect: dict[str, list[bool]] = {}
    for r in rows:
        for k, ok in r.get("covered", {}).items():
            per_effect.setdefault(k.split(".")[0], []).append(ok)
    top1 = [r["top1"] for r in eff if "top1" in r]
    red = [r["rmse_reduction"] for r in eff if r.get("rmse_reduction") is not None]
    return {
        "n_effect_cases": len(eff),
        "named_above_absent": float(np.mean([r["correct"] for r in eff])) if eff else None,
        "top1_accuracy_single": float(np.mean(top1)) if top1 else None,
        "ci_coverage": float(np.mean(pairs)) if pairs else None,
        "n_ci_parameters": len(pairs),
        "ci_coverage_per_effect": {k: f"{sum(v)}/{len(v)}" for k, v in sorted(per_effect.items())},
        "median_heldout_rmse_reduction": float(np.median(red)) if red else None,
        "null_false_alarms": int(sum(not r["correct"] for r in nulls)),
        "n_null_cases": len(nulls),
        "confounded_as_ambiguous": bool(conf) and all(r["correct"] for r in conf),
        "n_confounded_cases": len(conf),
        "outside_no_library_name": f"{sum(r['correct'] for r in outside)}/{len(outside)}",
        "outside_located": f"{sum(r.get('located', False) for r in outside)}/{len(outside)}",
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
