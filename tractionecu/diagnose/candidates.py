"""Candidate explanations: the effect library's effects, with what diagnosis fits of each.

Every candidate uses the parameters and bounds of its
:class:`~tractionecu.model.effects.EffectDef`; the terms are the library's own
functions, applied inside the channels (:mod:`.channels`).  Some parameters
cannot be told apart from the nominal model's free parameters with forward
driving only; they are held at a stated value and the report says why.

Each fitted parameter has a *negligible* half-width around its null value:
an effect counts as found only when a parameter's 95 % interval lies outside
it.  The sizes: grade scale 0.1 (a tenth of the relief); hitch 0.05 m and
centre of gravity 0.1 m; GNSS latency 0.02 s (a fifth of a 10 Hz epoch);
radius error 0.3 % (0.3 slip points, against optimum slips of 6–12 %);
relaxation length 0.1 m (a time constant under 40 ms at 2.5 m/s, within the
50 ms inverter response); draft coefficient 0.005 s²/m² (under 2 % of draft
across field speeds); drivetrain efficiency 1 %; mass 50 kg; drag area
10 m² (under 40 N at 2.5 m/s).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..model.effects import EFFECTS, LIBRARY


@dataclass(frozen=True)
class FitParam:
    """One fitted parameter: bounds and unit from the library, its null value (effect absent)
    and the grid searched for a starting point."""

    name: str
    null: float
    starts: tuple[float, ...]
    """Grid of starting values (the search picks the best, then refines)."""
    lo: float
    hi: float
    unit: str
    negligible: float = 0.0
    """Half-width around the null value within which the effect is physically negligible."""


def _fp(effect: str, name: str, null: float, starts: tuple[float, ...], negligible: float = 0.0) -> FitParam:
    spec = {p.name: p for p in LIBRARY[effect].params}[name]
    return FitParam(name, null, starts, spec.lo, spec.hi, spec.unit, negligible)


@dataclass(frozen=True)
class Candidate:
    name: str
    fitted: tuple[FitParam, ...]
    fixed: dict[str, float] = field(default_factory=dict)
    fixed_reason: str = ""
    plain: str = ""
    """The effect in plain words, for the verdict."""

    @property
    def formula(self) -> str:
        return LIBRARY[self.name].formula

    @property
    def names(self) -> tuple[str, ...]:
        return (self.name,)

    def effects(self, x) -> dict[str, dict[str, float]]:
        """``{effect: parameters}`` for fitted values ``x``."""
        return {self.name: self.params(x)}

    def params(self, x) -> dict[str, float]:
        """Full parameter dict of the effect for fitted values ``x``."""
        out = dict(LIBRARY[self.name].defaults())
        out.update(self.fixed)
        for fp, v in zip(self.fitted, x):
            out[fp.name] = float(v)
        return out


CANDIDATES: dict[str, Candidate] = {
    c.name: c
    for c in (
        Candidate("grade", (_fp("grade", "scale", 0.0, (0.0, 0.5, 1.0, 2.0), 0.1),),
                  plain="field grade: the slope component of weight, F = m g sin θ"),
        Candidate("load_transfer", (_fp("load_transfer", "h_hitch_m", 0.0, (0.0, 0.5, 1.0), 0.05), _fp("load_transfer", "h_cg_m", 0.0, (0.0, 1.0), 0.1)),
                  plain="longitudinal load transfer: pull, acceleration and slope move load from the front to the rear axle"),
        Candidate("gps_latency", (_fp("gps_latency", "tau_s", 0.0, (0.0, 0.03, 0.07, 0.12, 0.2, 0.3, 0.45, 0.7, 1.0, 1.5, 2.0), 0.02),),
                  plain="GNSS speed latency: the receiver reports the speed τ late"),
        Candidate("wheel_radius", (_fp("wheel_radius", "epsilon", 0.0, (-0.1, -0.06, -0.035, -0.02, -0.01, -0.004, 0.0, 0.004, 0.01, 0.02, 0.035, 0.06, 0.1), 0.003),),
                  plain="rolling-radius error: the true radius is (1 + ε) times the nominal formula"),
        Candidate("relaxation", (_fp("relaxation", "sigma_m", 0.01, (0.01, 0.05, 0.15, 0.3, 0.5, 0.8, 1.2, 1.8, 2.7, 4.0, 5.0), 0.09),),
                  plain="tyre relaxation: the traction force follows slip with the lag σ/v"),
        Candidate("draft_speed", (_fp("draft_speed", "c_s2pm2", 0.0, (0.0, 0.02, 0.05, 0.1, 0.2, 0.4), 0.005),), fixed={"v_ref_mps": 2.5},
                  fixed_reason="v_ref is a reference point, not a separate parameter: D_0 and v_ref trade off; "
                               "c is reported at v_ref = 2.5 m/s",
                  plain="draft depends on speed (ASABE D497 quadratic term)"),
        Candidate("drivetrain", (_fp("drivetrain", "eta", 1.0, (0.6, 0.8, 0.9, 0.95, 1.0), 0.01),), fixed={"loss_nm": 0.0},
                  fixed_reason="a constant loss torque acts like soil rolling resistance in forward driving "
                               "and is not separable from ρ_s; it is held at 0",
                  plain="drivetrain losses between the measured drive torque and the wheel"),
        Candidate("mass", (_fp("mass", "delta_kg", 0.0, (-1500.0, -500.0, 0.0, 500.0, 1500.0, 3000.0), 50.0), _fp("mass", "front_share", 0.5, (0.0, 0.5, 1.0))),
                  plain="the vehicle mass differs from nominal (ballast)"),
        Candidate("aero", (_fp("aero", "cd_area_m2", 0.0, (0.0, 2.0, 5.0, 15.0, 50.0), 10.0),),
                  plain="aerodynamic drag"),
        # Sensor faults (model.effects.SENSOR_FAULTS).  Negligible bands: torque gain 1 % (the
        # class of a calibrated strain-gauge shaft sensor), torque offset 20 N·m (≈ 13 N of force at
        # 1.6 m radius... per wheel), draft offset 200 N and drift 50 N/min, axle-load offset 300 N
        # and drift 100 N/min (≈ 0.5 % of a 60 kN axle), clock 0.02 s and 50 ppm, pressure ratio 0.05.
        Candidate("torque_gain", (_fp("torque_gain", "k_front", 0.0, (-0.1, 0.0, 0.1), 0.01),
                                  _fp("torque_gain", "k_rear", 0.0, (-0.1, 0.0, 0.1), 0.01)),
                  plain="drive-torque sensor gain error (per axle)"),
        Candidate("torque_offset", (_fp("torque_offset", "b_front_nm", 0.0, (-300.0, 0.0, 300.0), 20.0),
                                    _fp("torque_offset", "b_rear_nm", 0.0, (-300.0, 0.0, 300.0), 20.0)),
                  plain="drive-torque sensor offset (per axle)"),
        Candidate("draft_offset", (_fp("draft_offset", "b0_n", 0.0, (-2000.0, 0.0, 2000.0), 200.0),
                                   _fp("draft_offset", "b1_npm", 0.0, (-300.0, 0.0, 300.0), 50.0)),
                  plain="draft sensor offset and drift"),
        Candidate("axle_load_offset", (_fp("axle_load_offset", "b0_n", 0.0, (-3000.0, 0.0, 3000.0), 300.0),
                                       _fp("axle_load_offset", "b1_npm", 0.0, (-500.0, 0.0, 500.0), 100.0)),
                  plain="front-axle load sensor offset and drift"),
        Candidate("clock_skew", (_fp("clock_skew", "offset_s", 0.0, (-0.3, -0.1, 0.0, 0.1, 0.3), 0.02),
                                 _fp("clock_skew", "rate_ppm", 0.0, (-500.0, 0.0, 500.0), 50.0)),
                  plain="CAN logger clock apart from GNSS time (offset and rate)"),
        Candidate("tyre_pressure", (_fp("tyre_pressure", "p_ratio", 1.0, (0.5, 0.7, 0.85, 1.0, 1.2, 1.5), 0.05),),
                  plain="tyre inflation pressure off the rated one (radius and rolling resistance together)"),
    )
}

NOMINAL = frozenset({"load_transfer"})
"""Library effects every tractor has: part of the nominal model (fitted as a nuisance, reported, never a fault)."""
DETECTORS = frozenset({"wheel_speed_hold"})
"""Sensor faults found by a data check (:func:`~.features.wheel_speed_faults`), not by a fit."""

assert set(CANDIDATES) | DETECTORS == set(LIBRARY), "every library effect is a candidate or a detector"
