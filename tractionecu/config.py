"""Typed, frozen configuration with units, loaded from and saved to TOML.

Every config table of the package is a frozen dataclass declared with the
helpers here, and read, checked and written by the same few functions:

- :func:`setting` declares a key: default, doc line with the unit, range
  [lo, hi] and whether NaN is allowed; :func:`section` declares a nested table
  of another such dataclass, :func:`table` a free table passed through as is.
- :func:`validate` (called by each ``__post_init__``) checks types and ranges;
  a :class:`~tractionecu.errors.ConfigError` always names the key as
  ``section.key``.
- :func:`from_mapping` builds a dataclass from a TOML table (unknown keys
  named, integers taken for floats, nested sections) and remembers which keys
  the table set (:func:`given_keys`).
- :func:`to_toml` writes a dataclass back (each key with its doc line);
  reading the text with :func:`from_mapping` gives an equal object.
- :func:`load_toml` reads a file, with errors that name the file.

Sensor figures and their precedence
-----------------------------------
:class:`SensorSpec` holds the figures of the machine's sensors (rates, noise,
resolution); the estimator takes its measurement noise R and the input part
of Q from them, the simulator its noise.  They are configuration:

1. a ``[sensors]`` table in the vehicle file (``vehicle.toml``, beside
   ``[vehicle]`` or beside top-level vehicle keys; :func:`load_sensors`);
2. the service config's ``[sensors]`` table: a key set there overrides the
   same key of the vehicle file (:func:`resolve_sensors`);
3. a key set in neither takes the documented default of :class:`SensorSpec`.

The machine's own bus messages
------------------------------
A ``[signals]`` table in the vehicle file maps the owner's DBC signals onto
the contract names, with an optional scale (:func:`signal_map`); the DBC
files themselves are given with ``--dbc`` to ``replay``, ``inspect`` and
``diagnose``.  The recording reader applies it
(:func:`tractionecu.recording.reader.read_recording`).

The drivetrain
--------------
A ``[drivetrain]`` table (top level, or ``[vehicle.drivetrain]``) says what
drives the wheels (:class:`DrivetrainSpec`): ``kind = "hub"`` (per-wheel
drive torques, the paper's tractor and the default), ``"mechanical"`` or
``"power-split"`` (one engine: EEC1 torque, the gear ratio, final drive,
front-axle lead, efficiency), how the wheel speeds come and whether the
front-axle load is measured.  The pipeline picks the estimator from it and
from the signals a recording carries (:mod:`tractionecu.pipeline.signals`).

Vehicle defaults
----------------
The paper's case study (Kobelski et al. 2020, section 5) gives: 80 kW total
drive-train power, 6300 kg unloaded mass including four wheels of 160 kg each,
and ρ_t = 0.015 (Schreiber & Kutzbach 2007).  Where the paper is silent the
defaults are assumptions, each with its source:

- ``r0_m = 0.80``: unloaded wheel radius of a 80 kW tractor's 540/65R34-class
  rear tyre (rolling circumference ≈ 5.0 m, tyre data books of Michelin /
  Continental agricultural tyres); also the figure in the project's physics
  notes.  The paper's tractor has four equal wheels, so one radius is used.
- ``tyre_width_m = 0.54``: section width b_t of the 540/65R34 tyre.
- ``tyre_pressure_pa = 1.6e5``: 1.6 bar, a typical field inflation pressure
  for that tyre at 2–3 t load (manufacturers' load/inflation tables).  The
  Guskov (1988) formula, as printed in the paper, has the factor 10^5 that
  converts bar to Pa; with p_t in Pa the formula reads
  Δr = F_z / (2π p_t √(b_t r0 / 2)).
- ``wheel_inertia_kgm2 = 60``: tyre and rim of 160 kg with a radius of
  gyration of ≈ 0.6 r0 give ≈ 37 kg·m²; the reflected rotor inertia of a
  wheel-hub drive (≈ 0.06 kg·m² rotor through a 1:25 planetary reduction,
  ≈ 37 kg·m²) is of the same order; 60 kg·m² is a round figure in between
  (Osinenko et al. 2014 use a lumped wheel-plus-drive inertia of this order).
- ``wheelbase_m = 2.5``, ``cg_height_m = 1.0``, ``hitch_height_m = 0.5``:
  the project's physics notes for this tractor class (ASABE D497 tractor
  examples of 75–90 kW have 2.4–2.6 m wheelbase).
- ``static_front_fraction = 0.40``: ballasting recommendation 40/60 front/rear
  for MFWD tractors in draft work (ASABE EP496 / manufacturers' ballast guides).
- ``front_roll_share = 0.25``: most tractors' front axle pivots about a
  longitudinal pin (oscillating front axle), so it carries no roll moment about
  the pin; the only left–right load difference at the front comes from its
  lateral tyre force F_yf acting at the pin height h_p below the pin: with
  the outer front wheel at F_zf/2 + δ_f and the inner at F_zf/2 − δ_f, the
  moments about the pin give δ_f b = F_yf h_p.  In a steady turn F_yf ≈ m a_y × the front axle's
  static load share, so the front's part of the roll moment m a_y h_cg is
  (static front share) × h_p/h_cg ≈ 0.4 × 0.6 m / 1.0 m ≈ 0.25 (pin at about
  the front wheel centre's height); the rear axle, rigidly in the chassis,
  takes the rest (model doc "Lateral load transfer" in
  :mod:`tractionecu.model.vehicle`).
- ``cd_area_m2 = 4.5``: C_d ≈ 0.9 × frontal area ≈ 5 m²; about 17 N at
  2.5 m/s, matching the physics notes' "≈ 20 N, negligible in the field".
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import math
import numbers
import re
import tomllib
from contextlib import contextmanager
from dataclasses import MISSING, dataclass, fields
from pathlib import Path
from typing import Any, Iterator, Mapping

from .errors import ConfigError

G = 9.81
"""Gravitational acceleration [m/s²]."""


# ----------------------------------------------------------------------------- declaring keys
def setting(default: Any, doc: str, lo: float | None = None, hi: float | None = None, *,
            nan_ok: bool = False) -> Any:
    """A config key: ``default``, ``doc`` (one line with the unit), allowed range [lo, hi].

    The default's type is the key's type (bool, int, float, str, or a tuple of
    one of them).  ``nan_ok`` lets a float be NaN (e.g. "not set").
    """
    md: dict[str, Any] = {"doc": doc}
    if lo is not None:
        md["lo"] = lo
    if hi is not None:
        md["hi"] = hi
    if nan_ok:
        md["nan_ok"] = True
    return dataclasses.field(default=default, metadata=md)


def section(cls: type, doc: str, *, partial: bool = False) -> Any:
    """A nested table ``[outer.name]`` holding dataclass ``cls`` (its defaults when absent).

    ``partial``: the keys a file did not set are resolved elsewhere (see
    :func:`given_keys`); :func:`to_toml` writes them as comments.
    """
    md: dict[str, Any] = {"doc": doc, "section": cls}
    if partial:
        md["partial"] = True
    return dataclasses.field(default_factory=cls, metadata=md)


def table(doc: str) -> Any:
    """A free table of keys passed through unchecked (e.g. driver options); empty by default."""
    return dataclasses.field(default_factory=dict, metadata={"doc": doc, "table": True})


# ----------------------------------------------------------------------------- checking
def _key(section_name: str, name: str) -> str:
    return f"{section_name}.{name}" if section_name else name


_LIST_OF = {str: "strings", int: "integers", float: "numbers", bool: "true/false values"}


def validate(obj: Any, section_name: str) -> None:
    """Type and range checks of every key from the field declarations; errors name ``section.key``.

    Normalises in place: a list for a tuple key becomes a tuple, a free table a dict.
    """
    for f in fields(obj):
        v = getattr(obj, f.name)
        key = _key(section_name, f.name)
        md = f.metadata
        d = f.default
        if "section" in md:
            if not isinstance(v, md["section"]):
                raise ConfigError(f"{key}: expected a table ({md['section'].__name__}), got {v!r}")
        elif md.get("table"):
            if not isinstance(v, Mapping):
                raise ConfigError(f"{key}: expected a table, got {v!r}")
            object.__setattr__(obj, f.name, dict(v))
        elif isinstance(d, bool):
            if not isinstance(v, bool):
                raise ConfigError(f"{key}: expected true or false, got {v!r}")
        elif isinstance(d, (int, float)):
            if isinstance(v, numbers.Real) and not isinstance(v, (bool, int, float)):
                # a numpy scalar (a value read from an array) is the number it holds
                v = int(v) if isinstance(v, numbers.Integral) else float(v)
                object.__setattr__(obj, f.name, v)
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ConfigError(f"{key}: expected a number, got {v!r}")
            if isinstance(d, int) and not isinstance(v, int):
                raise ConfigError(f"{key}: expected an integer, got {v!r}")
            if md.get("nan_ok") and isinstance(v, float) and math.isnan(v):
                continue
            if isinstance(v, float) and not math.isfinite(v):
                raise ConfigError(f"{key}: expected a finite number, got {v!r}")
            lo, hi = md.get("lo"), md.get("hi")
            if (lo is not None and v < lo) or (hi is not None and v > hi):
                raise ConfigError(f"{key} = {v!r} is outside [{lo}, {hi}] ({md['doc']})")
        elif isinstance(d, str):
            if not isinstance(v, str):
                raise ConfigError(f"{key}: expected a string, got {v!r}")
        elif isinstance(d, tuple):
            item = type(d[0]) if d else object
            if not isinstance(v, (list, tuple)) or not all(
                    isinstance(x, item) and (item is bool or not isinstance(x, bool)) for x in v):
                raise ConfigError(f"{key}: expected a list of {_LIST_OF.get(item, 'values')}, got {v!r}")
            object.__setattr__(obj, f.name, tuple(v))


# ----------------------------------------------------------------------------- reading
_GIVEN = "_config_given_keys"


def from_mapping(cls: type, data: Any, section_name: str) -> Any:
    """Build dataclass ``cls`` from the TOML table ``data`` named ``section_name`` ("" = the file).

    Unknown keys are named; an integer is taken for a float key; a nested
    :func:`section` is built from its sub-table.  Values are checked by the
    dataclass (:func:`validate`).  The keys ``data`` set are remembered
    (:func:`given_keys`).
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f"{section_name or 'config'}: expected a table, got {type(data).__name__}")
    known = {f.name: f for f in fields(cls) if f.init}
    unknown = sorted((k for k in data if k not in known), key=str)
    if unknown:
        what = "key" if section_name else "table"
        raise ConfigError(f"{_key(section_name, str(unknown[0]))}: unknown {what} (known: {', '.join(sorted(known))})")
    kw: dict[str, Any] = {}
    for name, f in known.items():
        if name not in data:
            continue
        v = data[name]
        key = _key(section_name, name)
        if "section" in f.metadata:
            v = from_mapping(f.metadata["section"], v, key)
        elif isinstance(f.default, float) and isinstance(v, int) and not isinstance(v, bool):
            try:
                v = float(v)
            except OverflowError:
                raise ConfigError(f"{key}: {v.bit_length()}-bit integer is out of range") from None
        kw[name] = v
    try:
        obj = cls(**kw)
    except TypeError as exc:  # pragma: no cover - defensive
        raise ConfigError(f"{section_name or 'config'}: {exc}") from exc
    object.__setattr__(obj, _GIVEN, frozenset(kw))
    return obj


def _same(a: Any, b: Any) -> bool:
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


def given_keys(obj: Any) -> frozenset[str]:
    """The keys set explicitly: those of the table ``obj`` was read from (:func:`from_mapping`);
    for an object built in code, the keys whose value differs from the default."""
    given = obj.__dict__.get(_GIVEN)
    if given is not None:
        return given
    out = set()
    for f in fields(obj):
        d = f.default if f.default is not MISSING else f.default_factory()  # type: ignore[misc]
        if not _same(getattr(obj, f.name), d):
            out.add(f.name)
    return frozenset(out)


def load_toml(path: str | Path, what: str) -> dict[str, Any]:
    """Parse a TOML file; errors name the file: '<what> file not found', 'cannot read', 'not valid TOML'."""
    p = Path(path)
    try:
        return tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{p}: {what} file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read: {exc}") from None
    except ValueError as exc:  # TOMLDecodeError, or an integer literal beyond Python's 4300-digit limit
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None


# ----------------------------------------------------------------------------- writing
_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def toml_key(k: str) -> str:
    """A TOML key: bare when it can be, else a quoted string."""
    return k if _BARE_KEY.fullmatch(k) else toml_value(k)


def toml_value(v: Any) -> str:
    """A TOML value that reads back as ``v`` (bool, int, float incl. nan/inf, str, list, table, date/time)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)  # 'nan', 'inf', '-inf' are TOML too
    if isinstance(v, str):  # control characters escaped; a lone surrogate (not text TOML can hold) becomes U+FFFD
        out = v.replace("\\", "\\\\").replace('"', '\\"')
        out = re.sub(r"[\x00-\x1f\x7f]", lambda m: f"\\u{ord(m.group()):04X}", out)
        return '"' + re.sub(r"[\ud800-\udfff]", "\\\\uFFFD", out) + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{" + ", ".join(f"{toml_key(str(k))} = {toml_value(x)}" for k, x in v.items()) + "}"
    if isinstance(v, (_dt.datetime, _dt.date, _dt.time)):
        return v.isoformat()
    raise ConfigError(f"cannot write {type(v).__name__} to TOML")


def to_toml(obj: Any, section_name: str | None = None) -> str:
    """TOML text of dataclass ``obj``, each key after its doc line; nested sections and
    non-empty free tables follow as ``[section.name]`` tables.  Without ``section_name``
    the keys are written at the top level."""
    lines: list[str] = []
    _write_table(obj, section_name or "", lines, None)
    return "\n".join(lines) + "\n"


def _write_table(obj: Any, name: str, out: list[str], given: frozenset[str] | None) -> None:
    if name:
        out.append(f"[{name}]")
    subs = []
    for f in fields(obj):
        v = getattr(obj, f.name)
        if "section" in f.metadata or f.metadata.get("table"):
            subs.append((f, v))
            continue
        doc = f.metadata.get("doc")
        if doc:
            out.append(f"# {doc}")
        line = f"{toml_key(f.name)} = {toml_value(v)}"
        out.append(line if given is None or f.name in given else "# " + line)
    for f, v in subs:
        sub = _key(name, f.name)
        if f.metadata.get("table"):
            if v:
                out += ["", f"[{sub}]"] + [f"{toml_key(str(k))} = {toml_value(x)}" for k, x in v.items()]
            continue
        if out:
            out.append("")
        if f.metadata.get("partial"):
            out.append(f"# {f.metadata['doc']}")
        _write_table(v, sub, out, given_keys(v) if f.metadata.get("partial") else None)


def replace(obj: Any, **changes: Any) -> Any:
    """``dataclasses.replace`` that re-validates."""
    return dataclasses.replace(obj, **changes)


# ----------------------------------------------------------------------------- drivetrain
DRIVETRAIN_KINDS = ("hub", "mechanical", "power-split")
"""``[drivetrain] kind``: per-wheel drives; engine, gearbox and axles; a power-split (CVT) transmission."""

WHEEL_SPEED_SOURCES = ("auto", "per-wheel", "per-axle", "machine")
"""``[drivetrain] wheel_speeds``: how the bus gives the wheel speeds (``auto``: the best the recording has)."""

LOAD_SENSING = ("front-axle", "none")
"""``[drivetrain] load_sensing``: front-axle load pins, or none (rear load from the mass and the draft)."""

GEAR_RATIO_SOURCES = ("bus", "learnt")
"""``[drivetrain] gear_ratio``: ETC2's actual gear ratio (SPN 526), or learnt from engine speed over wheel speed."""

FRONT_DRIVE = ("engaged", "disengaged", "auto")
"""``[drivetrain] front_drive``: the mechanical front-wheel drive (MFWD) clutch."""


MAX_DEFLECTION = 0.3
"""Largest tyre deflection the model takes, as a share of the unloaded radius r0 [-]
(:func:`tractionecu.model.vehicle.rolling_radius`); a declared rolling radius or wheel-speed radius must lie
within this share of r0 (:class:`VehicleParams`)."""

HUB_EFFICIENCY = 0.96
"""Default torque efficiency of a hub reduction, motor to wheel [-] (DrivetrainSpec doc)."""
HUB_EFFICIENCY_TOL = 0.02
"""Default relative standard uncertainty of the hub reduction's efficiency [-] (DrivetrainSpec doc)."""


@dataclass(frozen=True)
class DrivetrainSpec:
    """What drives the wheels and what the bus says about it (``[drivetrain]`` of ``vehicle.toml``).

    ``hub`` is the paper's tractor: one drive torque per wheel.  ``mechanical``
    and ``power-split`` have one engine: the drive torque at the wheels is
    T_e·i·η, T_e the engine torque (J1939 EEC1 actual percent torque, SPN 513,
    less the nominal friction percent torque, times the EC1 reference torque,
    SPN 544), i = i_g·i_f the total ratio (ETC2 actual gear ratio, SPN 526,
    or the ratio a CVT reports, times the final drive) and η the drivetrain
    efficiency.  The estimator that runs on such a machine is
    :mod:`tractionecu.estimation.machine`.

    Hub drive: the reported motor torque reaches the wheel through the hub
    reduction, M_wheel = η·M_motor driving (M_motor/η braking).  Not given,
    η = 1 with tolerance 0: the paper's machine, whose reported drive torque
    is the wheel's (every ``VehicleParams()`` of the paper's scenarios).  A
    machine with a hub reduction declares its η: :data:`HUB_EFFICIENCY`
    0.96 is two planetary stages at 0.98 each, the middle of the 0.97-0.99
    per planetary stage of Naunheimer et al. 2011 ("Automotive
    Transmissions", 2nd ed.); their range 0.94-0.98 gives
    :data:`HUB_EFFICIENCY_TOL` 0.02 (1σ, relative; it also covers the
    bearings' and seals' losses that the stage figures leave out).

    Defaults where a machine's figures are not given: the efficiency 0.88 is
    the middle of the 0.85-0.90 transmission efficiency of tractor gearboxes
    (ASABE D497.7 section 4.1.1 for gear transmissions); a front-axle lead of
    1-5 % is what MFWD tractors are built with (ASABE D497 / manufacturers);
    an engine flywheel with crankshaft of a 4-cylinder 3-4.5 l tractor diesel
    has 1.5-3 kg·m² (2.0 here, an assumption).
    """

    kind: str = setting("hub", "hub | mechanical | power-split (see DRIVETRAIN_KINDS)")
    final_drive_ratio: float = setting(0.0, "transmission output to rear wheel speed ratio i_f [-]; "
                                       "0: not known (needed with gear_ratio = 'bus')", 0.0, 200.0)
    gear_ratio: str = setting("bus", "bus (ETC2 actual gear ratio, SPN 526) | learnt (engine speed over wheel speed)")
    efficiency: float = setting(math.nan, "drivetrain efficiency engine (hub: motor) to wheels η [-]; "
                                "not given: the kind's default (hub 1.0, else 0.88)", 0.3, 1.0, nan_ok=True)
    efficiency_tolerance: float = setting(math.nan, "relative uncertainty of η [-] (1σ): it bounds how well μ "
                                          "is known; not given: the kind's default (hub 0, else 0.03)", 0.0, 0.5,
                                          nan_ok=True)
    hub_drag_nms: float = setting(0.0, "hub drive: the hub reduction's no-load loss as a drag torque at the wheel "
                                  "per unit wheel speed c [N·m per rad/s] (oil churning, seals, bearings; the "
                                  "motor torque that turns a lifted wheel at a steady speed, over that speed): "
                                  "M_wheel = η M_motor − c ω; 0: not known, none taken off", 0.0, 1000.0)
    hub_stiffness_nmprad: float = setting(0.0, "hub drive: torsional stiffness k between motor and wheel, at the "
                                          "wheel [N·m/rad] (gear meshes, planet carrier, hub and rim: the "
                                          "reduction's data sheet or a run-up test); > 0 with "
                                          "hub_motor_inertia_kgm2: the hub estimator's two-inertia hub; 0: "
                                          "not known, one lumped inertia", 0.0, 1e9)
    hub_damping_nmsprad: float = setting(0.0, "hub drive: torsional damping c between motor and wheel, at the "
                                         "wheel [N·m·s/rad]; used with hub_stiffness_nmprad", 0.0, 1e7)
    hub_motor_inertia_kgm2: float = setting(0.0, "hub drive: the motor side's inertia (rotor and first stage) "
                                            "reflected to the wheel, J_m [kg·m²] (rotor inertia from the motor's "
                                            "data sheet times the ratio squared); the wheel side is "
                                            "wheel_inertia_kgm2 − J_m; used with hub_stiffness_nmprad", 0.0, 5000.0)
    front_drive: str = setting("engaged", "MFWD clutch: engaged | disengaged (a disengaged front axle rolls) | "
                               "auto (from the bus: engaged while EBC2's front-axle speed keeps the coupling's "
                               "ratio to the rear wheels, rolling when it falls below it by the lead)")
    front_lead: float = setting(0.02, "front-axle lead: front over rear wheel circumferential speed, minus 1 [-] "
                                "(1-5 % on MFWD tractors)", -0.1, 0.2)
    engine_friction_percent: float = setting(0.0, "nominal friction percent torque (J1939 EEC3 SPN 514) taken "
                                             "off EEC1's indicated percent torque [%]", 0.0, 50.0)
    engine_reference_torque_nm: float = setting(0.0, "engine reference torque T_ref (J1939 SPN 544) [N·m] as the "
                                                "engine's data sheet gives it, used while the bus has sent no EC1 "
                                                "(a capture started after its 5 s broadcast, or an ECU that sends "
                                                "it only on request); 0: from EC1 only", 0.0, 64255.0)
    engine_inertia_kgm2: float = setting(2.0, "engine flywheel and crankshaft inertia J_e [kg·m²] "
                                         "(reflected to the wheels by the total ratio squared)", 0.0, 100.0)
    wheel_speeds: str = setting("auto", "auto | per-wheel | per-axle (EBC2 front-axle and relative speeds) | "
                                "machine (one wheel-based speed: EBC2 is not used)")
    wheel_speed_radius_m: float = setting(0.0, "radius the tractor converts wheel speed to its wheel-based "
                                          "speed with (CCVS1 / WBSD) [m]; 0: r0_m", 0.0, 2.5)
    rolling_radius_m: float = setting(0.0, "effective rolling radius of the rear wheels at their static load, from "
                                      "the tractor's wheel-speed distance calibration (a measured 100 m driven "
                                      "with the implement raised) [m]; 0: eq. 9 from r0_m and the tyre data", 0.0, 2.5)
    load_sensing: str = setting("none", "front-axle (load pins) | none (loads from the mass, the static front "
                                "share and the draft); engine-driven kinds: the hub estimator always takes its "
                                "loads from the front-axle pins")
    draft_sensing: bool = setting(True, "the hitch measures the draft (ISO 11783-7 rear hitch status); false: "
                                  "ρ_s and the draft are estimated as their sum, ρ_s is not reported")

    def __post_init__(self) -> None:
        hub = self.kind == "hub"
        if isinstance(self.efficiency, float) and math.isnan(self.efficiency):
            object.__setattr__(self, "efficiency", 1.0 if hub else 0.88)
        if isinstance(self.efficiency_tolerance, float) and math.isnan(self.efficiency_tolerance):
            object.__setattr__(self, "efficiency_tolerance", 0.0 if hub else 0.03)
        validate(self, "drivetrain")
        for key, allowed in (("kind", DRIVETRAIN_KINDS), ("wheel_speeds", WHEEL_SPEED_SOURCES),
                             ("load_sensing", LOAD_SENSING), ("gear_ratio", GEAR_RATIO_SOURCES),
                             ("front_drive", FRONT_DRIVE)):
            if getattr(self, key) not in allowed:
                raise ConfigError(f"drivetrain.{key}: {getattr(self, key)!r} is not one of {', '.join(allowed)}")
        if self.kind != "hub" and self.gear_ratio == "bus" and not self.final_drive_ratio >= 1.0:
            if self.final_drive_ratio > 0.0:
                # 0.5 was told "needed", as if it had not been given
                raise ConfigError(f"drivetrain.final_drive_ratio = {self.final_drive_ratio!r} is below 1: it is the "
                                  "transmission output's speed over the rear wheels' (a reduction, 1 or more; "
                                  "0: not known)")
            raise ConfigError(f"drivetrain.final_drive_ratio: needed for kind = {self.kind!r} with gear_ratio = "
                              "'bus' (the wheel torque is the engine torque times gear and final drive ratios)")

    @property
    def engine_driven(self) -> bool:
        """True for one engine through a transmission (mechanical, power-split)."""
        return self.kind != "hub"


# ----------------------------------------------------------------------------- vehicle
@dataclass(frozen=True)
class VehicleParams:
    """Nominal vehicle parameters, as a user knows them from the spec sheet."""

    mass_kg: float = setting(6300.0, "total vehicle mass m incl. wheels [kg]", 100.0, 100000.0)
    wheel_mass_kg: float = setting(160.0, "mass of one wheel m_w [kg]", 1.0, 5000.0)
    rated_power_w: float = setting(80e3, "total drive-train power [W]", 1e3, 1e6)
    r0_m: float = setting(0.80, "unloaded wheel radius r0 [m]", 0.1, 2.5)
    tyre_width_m: float = setting(0.54, "tyre section width b_t [m]", 0.05, 1.5)
    tyre_pressure_pa: float = setting(1.6e5, "tyre inflation pressure p_t [Pa]", 2e4, 1e6)
    wheel_inertia_kgm2: float = setting(60.0, "wheel + reflected drive inertia J_w [kg·m²]", 0.1, 5000.0)
    rho_t: float = setting(0.015, "tyre-deformation rolling resistance coefficient ρ_t [-]", 0.0, 0.2)
    tyre_carcass_stiffness_npm: float = setting(0.0, "longitudinal stiffness c_x of the tyre carcass between rim "
                                                "and contact patch [N/m] (tyre test data, Pacejka 2006 ch. 7: the "
                                                "slip stiffness over c_x is the relaxation length); > 0: the hub "
                                                "estimator's μ follows slip changes through the carcass (transient "
                                                "slip); 0: the paper's random-walk μ", 0.0, 1e8)
    wheelbase_m: float = setting(2.5, "wheelbase L [m]", 0.5, 6.0)
    cg_height_m: float = setting(1.0, "centre-of-gravity height h_cg [m]", 0.1, 4.0)
    hitch_height_m: float = setting(0.5, "drawbar / hitch height h_hitch [m]", 0.0, 2.0)
    static_front_fraction: float = setting(0.40, "static share of weight on the front axle [-]", 0.05, 0.95)
    track_width_m: float = setting(1.8, "track width, wheel centre to wheel centre [m]", 0.5, 5.0)
    front_roll_share: float = setting(0.25, "share of the roll moment m a_y h_cg of a turn that the front axle's "
                                      "left–right load difference carries [-] (the rear axle carries the rest): "
                                      "0.25 for a pivoting (oscillating) front axle, which takes only its lateral "
                                      "force times the pivot height; a suspended or rigid chassis shares it by "
                                      "its axles' roll stiffness (model doc \"Lateral load transfer\")", 0.0, 1.0)
    cd_area_m2: float = setting(4.5, "drag area C_d·A [m²]", 0.0, 50.0)
    max_wheel_torque_nm: float = setting(9000.0, "torque limit of one wheel drive [N·m]", 10.0, 1e5)
    pull_angle_deg: float = setting(0.0, "line of pull above the horizontal at the hitch β [deg]: the draft adds "
                                    "F_dx·tan β to the wheel loads (ASABE D497.7 4.1.4); used by the "
                                    "hub and the machine-level estimators", -30.0, 45.0)
    pull_angle_tol_deg: float = setting(0.0, "bound of the error of pull_angle_deg [deg] (rectangular, standard "
                                        "uncertainty bound/√3 as the sensor tolerances; 0: taken as exact): "
                                        "enters the hub estimator's reported σ of the rear μ", 0.0, 30.0)
    drivetrain: DrivetrainSpec = section(DrivetrainSpec, "what drives the wheels and what the bus says about it "
                                                         "(also a top-level [drivetrain] table)")

    def __post_init__(self) -> None:
        validate(self, "vehicle")
        dt = self.drivetrain
        lo, hi = (1.0 - MAX_DEFLECTION) * self.r0_m, (1.0 + MAX_DEFLECTION) * self.r0_m
        for key in ("rolling_radius_m", "wheel_speed_radius_m"):
            r = getattr(dt, key)
            if r > 0.0 and not lo <= r <= hi:
                # a diameter given for the radius, or another tyre's: 0.4 m with r0 0.8 m was taken as 0.56 m (the
                # deflection limit), 1.52 m halved every slip's wheel speed, without a word
                raise ConfigError(f"drivetrain.{key} = {r!r} is outside [{lo:.4g}, {hi:.4g}] m, r0_m = {self.r0_m!r} "
                                  f"± {MAX_DEFLECTION:.0%} (the radius, not the diameter, of the tyre of r0_m)")
        if dt.hub_stiffness_nmprad > 0.0 or dt.hub_motor_inertia_kgm2 > 0.0 or dt.hub_damping_nmsprad > 0.0:
            if dt.engine_driven:
                raise ConfigError(f"drivetrain.hub_stiffness_nmprad: a two-inertia hub is declared for kind = "
                                  f"{dt.kind!r}; it belongs to a hub drive (kind = 'hub')")
            if not dt.hub_stiffness_nmprad > 0.0:
                raise ConfigError("drivetrain.hub_stiffness_nmprad: must be > 0 when hub_motor_inertia_kgm2 or "
                                  "hub_damping_nmsprad is given (the two-inertia hub needs its stiffness)")
            if not 0.0 < dt.hub_motor_inertia_kgm2 < self.wheel_inertia_kgm2:
                raise ConfigError(f"drivetrain.hub_motor_inertia_kgm2: {dt.hub_motor_inertia_kgm2!r} must lie "
                                  f"between 0 and wheel_inertia_kgm2 ({self.wheel_inertia_kgm2!r}, motor and "
                                  "wheel together), exclusive, when hub_stiffness_nmprad is given")

    @property
    def hub_two_inertia(self) -> tuple[float, float, float, float] | None:
        """(k [N·m/rad], c [N·m·s/rad], J_m, J_w [kg·m²]) of a declared two-inertia hub (motor side J_m,
        wheel side J_w = wheel_inertia_kgm2 − J_m), None when not declared."""
        dt = self.drivetrain
        if not dt.hub_stiffness_nmprad > 0.0 or dt.engine_driven:
            return None
        jm = dt.hub_motor_inertia_kgm2
        return (dt.hub_stiffness_nmprad, dt.hub_damping_nmsprad, jm, self.wheel_inertia_kgm2 - jm)

    # ---- derived quantities -------------------------------------------------
    @property
    def weight_n(self) -> float:
        """Total weight m·g [N]."""
        return self.mass_kg * G

    def static_front_load_n(self) -> float:
        """Static front-axle ground reaction F_zf [N]."""
        return self.static_front_fraction * self.weight_n


# ----------------------------------------------------------------------------- sensors
@dataclass(frozen=True)
class SensorSpec:
    """Rates [Hz], noise standard deviations and resolution of the machine's sensors.

    The defaults are documented figures of real tractor hardware, each with
    its source; the estimator's R and input noise come from here, never from
    the truth, and the simulator adds the same noise.
    """

    wheel_rate_hz: float = setting(100.0, "wheel speed and drive torque frame rate [Hz]; 10 ms is the usual drive-train PGN period (ISO 11783-7 / J1939-71 engine and transmission speed PGNs are 10–20 ms)", 1.0, 1000.0)
    wheel_speed_sigma_rel: float = setting(0.002, "wheel-speed noise, relative [-]: period-measured 60-tooth pulse rings / hub-motor resolvers give 0.1–0.5 % speed ripple", 0.0, 0.5)
    wheel_speed_sigma_abs: float = setting(0.005, "wheel-speed noise floor [rad/s]", 0.0, 10.0)
    wheel_speed_quant: float = setting(0.001, "wheel-speed resolution [rad/s] (the DBC's 0.001 rad/s/bit)", 1e-6, 1.0)
    torque_sigma_rel: float = setting(0.01, "drive-torque noise, relative [-]: inverter torque estimates from phase currents, 1 % ripple (current-sensor noise of Hall/shunt sensors ≈ 0.5–1 % FS)", 0.0, 0.5)
    torque_sigma_abs: float = setting(5.0, "drive-torque noise floor [N·m]", 0.0, 1e4)
    torque_quant: float = setting(2.0, "drive-torque resolution [N·m] (DBC 2 N·m/bit)", 1e-3, 1e3)
    loadpin_rate_hz: float = setting(50.0, "load-pin sample rate [Hz]: strain-gauge/magnetoelastic hitch pins with CAN output run at 10–100 Hz; ISO 11783-7 hitch status is sent every 100 ms, 50 Hz here", 1.0, 1000.0)
    draft_sigma_n: float = setting(300.0, "draft load-pin noise [N]: ±0.3 % of a 100 kN full scale (typical strain-gauge load-pin accuracy 0.25–1 % FS)", 0.0, 1e5)
    draft_quant_n: float = setting(10.0, "draft resolution [N] (ISO 11783-7 rear draft 10 N/bit)", 1e-3, 1e4)
    axle_sigma_n: float = setting(300.0, "front-axle load-pin noise [N]: ±0.3 % of 100 kN FS", 0.0, 1e5)
    axle_quant_n: float = setting(5.0, "front-axle load resolution [N] (DBC 5 N/bit)", 1e-3, 1e4)
    gps_rate_hz: float = setting(10.0, "GNSS epoch rate [Hz]: agricultural receivers output 10 Hz (u-blox ZED-F9P: up to 20 Hz RTK)", 0.1, 100.0)
    gps_speed_sigma: float = setting(0.05, "GNSS Doppler speed noise [m/s] (ZED-F9P datasheet: velocity accuracy 0.05 m/s)", 0.0, 10.0)
    gps_pos_sigma: float = setting(0.30, "GNSS horizontal position noise [m], slowly varying (SBAS/DGPS: 0.3–0.6 m CEP; ZED-F9P with SBAS 1.0 m CEP, RTK 0.01 m)", 0.0, 100.0)
    gps_pos_tau_s: float = setting(30.0, "correlation time of the position error [s] (multipath/ionosphere residuals vary over tens of seconds)", 0.1, 1e5)
    gps_alt_sigma: float = setting(0.5, "GNSS altitude noise [m] (vertical error ≈ 1.5–2× horizontal)", 0.0, 100.0)
    gps_fix_quality: int = setting(2, "GGA fix quality [-]: 2 = DGPS/SBAS (4 = RTK fixed)", 1, 8)
    gps_hdop: float = setting(0.9, "typical HDOP [-] in open field with 15–20 satellites (GPS+Galileo+GLONASS)", 0.1, 99.0)
    gps_nsat: int = setting(16, "satellites used [-]", 4, 99)
    can_jitter_s: float = setting(0.0003, "CAN reception timestamp jitter [s]: arbitration delay of a 250 kbit/s bus at 30–50 % load is up to a few frame times (≈ 0.5 ms per 8-byte frame)", 0.0, 0.1)
    # Tolerances: bounds of the systematic errors (gain, zero offset, latency) that noise figures do not
    # describe.  A calibration leaves them inside these bounds; the data cannot identify them, so the
    # estimator adds them to the uncertainty it reports (estimation/uncertainty.py), treating each bound
    # ±b as a rectangular distribution of standard uncertainty b/√3 (GUM, JCGM 100:2008, 4.3.7).
    torque_gain_tol_rel: float = setting(0.02, "drive-torque gain tolerance, ± relative [-]: inverter torque estimates from phase currents and a motor model (flux linkage and inductances drift with temperature) differ from a torque transducer by a few per cent of reading (Aarniovuori et al., 'Induction motor torque estimation accuracy using motor terminal variables', Lappeenranta University of Technology); 2 % for a calibrated drive", 0.0, 0.5)
    torque_offset_tol_nm: float = setting(20.0, "drive-torque zero offset tolerance, ± [N·m]: phase-current sensor offsets of 0.1–0.3 % of full scale (closed-loop Hall sensors) at a 9 kN·m wheel-drive range", 0.0, 1e4)
    axle_offset_tol_n: float = setting(300.0, "front-axle load-pin zero offset tolerance, ± [N]: temperature effect on zero ≈ 0.01 % FS/K of strain-gauge load pins (HBM: < 0.05 %/10 K) over a 30 K range on a 100 kN pin", 0.0, 1e5)
    axle_gain_tol_rel: float = setting(0.005, "front-axle load-pin gain tolerance, ± relative [-]: sensitivity tolerance and temperature effect on span of calibrated load pins (0.2–0.5 % of reading)", 0.0, 0.5)
    draft_offset_tol_n: float = setting(300.0, "draft load-pin zero offset tolerance, ± [N] (as axle_offset_tol_n: 0.3 % FS of a 100 kN pin over 30 K)", 0.0, 1e5)
    draft_gain_tol_rel: float = setting(0.005, "draft load-pin gain tolerance, ± relative [-] (as axle_gain_tol_rel)", 0.0, 0.5)
    gps_latency_tol_s: float = setting(0.1, "GNSS speed latency bound [s]: the solution of an epoch leaves the receiver 20–100 ms later (computation, then a GGA+RMC+VTG set takes ≈ 20 ms at 115 200 baud) and loggers stamp it on arrival", 0.0, 2.0)
    rolling_radius_tol_rel: float = setting(0.03, "rolling-radius tolerance of the tyre, ± relative [-]: ETRTO / TRA dimension tolerance of ±3 % on an agricultural tyre's overall diameter, before wear and pressure; narrowed by self-calibration (estimation/calibration.py)", 0.0, 0.3)

    def __post_init__(self) -> None:
        validate(self, "sensors")


# ----------------------------------------------------------------------------- vehicle files
VEHICLE_FILE_TABLES = ("vehicle", "drivetrain", "sensors", "signals")
"""The tables of a vehicle file that has a ``[vehicle]`` table."""


def _vehicle_tables(data: Mapping[str, Any]) -> tuple[Any, Any]:
    """(vehicle table, sensors table) of a parsed vehicle file: ``[vehicle]`` or top-level keys, optional
    ``[sensors]`` (a ``[signals]`` table is :func:`load_signal_map`'s); a top-level ``[drivetrain]``
    is the vehicle's."""
    sensors = data.get("sensors", {})
    if "vehicle" in data:
        # beside [vehicle] only the file's other tables: a typo ([sensorz]) or a key above [vehicle] would
        # otherwise be dropped without a word (the keys inside each table are checked where they are read)
        extra = sorted(k for k in data if k not in VEHICLE_FILE_TABLES)
        if extra:
            raise ConfigError(f"{', '.join(extra)}: unknown in a vehicle file with a [vehicle] table (it holds only "
                              f"{', '.join('[' + t + ']' for t in VEHICLE_FILE_TABLES)}; keys go inside [vehicle])")
        veh = data["vehicle"]
        if "drivetrain" in data and isinstance(veh, Mapping):     # a top-level [drivetrain] beside [vehicle]
            if "drivetrain" in veh:
                raise ConfigError("drivetrain: given twice ([drivetrain] and [vehicle.drivetrain])")
            veh = {**veh, "drivetrain": data["drivetrain"]}
        return veh, sensors
    return {k: v for k, v in data.items() if k not in ("sensors", "signals")}, sensors


def load_vehicle(path: str | Path) -> VehicleParams:
    """Load ``vehicle.toml`` (keys at top level or under ``[vehicle]``; a ``[sensors]`` table is left to :func:`load_sensors`).
    A :class:`ConfigError` names the file."""
    data = load_toml(path, "vehicle")
    with _naming(path):
        veh = from_mapping(VehicleParams, _vehicle_tables(data)[0], "vehicle")
        _check_hub_sensing(veh.drivetrain)
        return veh


ENGINE_ONLY_KEYS = ("final_drive_ratio", "gear_ratio", "engine_inertia_kgm2", "front_lead", "front_drive",
                    "wheel_speeds", "wheel_speed_radius_m")
"""``[drivetrain]`` keys that only the machine-level estimator of an engine-driven kind reads (the engine's
reference and friction torques are not among them: diagnosis of an engine-level export reads them whatever the
kind)."""


def _check_hub_sensing(dt: DrivetrainSpec) -> None:
    """The hub estimator takes the draft from the hitch: a hub drive declared without it (``draft_sensing =
    false``) is an error, not a key read and ignored (such a machine replayed to no estimate at all).  Its wheel
    loads come from the front-axle pins whatever ``load_sensing`` says (a recording without them is refused by
    replay, :data:`~tractionecu.pipeline.signals.REPLAY_REQUIRED`).  A key of :data:`ENGINE_ONLY_KEYS` given
    away from its default on a hub drive is an error too: the file left out ``kind``."""
    if dt.kind != "hub":
        return
    defaults = DrivetrainSpec()
    engine = sorted(k for k in set(given_keys(dt)) & set(ENGINE_ONLY_KEYS)     # (a written file has them all,
                    if getattr(dt, k) != getattr(defaults, k))                 # at their defaults)
    if engine:
        # a vehicle file that forgot kind = "mechanical" ran the hub estimator, its ratios read and ignored
        raise ConfigError(f"drivetrain.{engine[0]}: a key of an engine-driven machine, given for kind = 'hub' "
                          f"(the default; {', '.join(engine)}): set kind = \"mechanical\" or \"power-split\", "
                          "or leave the key out")
    if "draft_sensing" in given_keys(dt) and not dt.draft_sensing:
        raise ConfigError("drivetrain.draft_sensing = false: the hub estimator needs the measured draft; a machine "
                          'without a draft sensor runs the machine-level estimator (kind = "mechanical" or '
                          '"power-split"), which estimates ρ_s and the draft as their sum')


def load_sensors(path: str | Path) -> SensorSpec:
    """The ``[sensors]`` table of a vehicle file; the documented defaults for keys (or a table) it lacks."""
    data = load_toml(path, "vehicle")
    with _naming(path):
        return from_mapping(SensorSpec, _vehicle_tables(data)[1], "sensors")


@contextmanager
def _naming(path: str | Path) -> Iterator[None]:
    """A :class:`ConfigError` raised inside says which file it is about ("drivetrain.final_drive_ratio: needed
    ..." named no file, though a recording's vehicle.toml is read without the user naming it)."""
    try:
        yield
    except ConfigError as exc:
        if str(path) in str(exc):
            raise
        raise ConfigError(f"{path}: {exc}") from exc


def resolve_sensors(vehicle_path: str | Path | None, overrides: Mapping[str, Any] | None = None) -> SensorSpec:
    """The sensor figures of a machine (module doc): ``overrides`` (the service's ``[sensors]`` keys)
    over the vehicle file's ``[sensors]`` (none without ``vehicle_path``) over the defaults."""
    base = load_sensors(vehicle_path) if vehicle_path else SensorSpec()
    if not overrides:
        return base
    merged = {k: getattr(base, k) for k in given_keys(base)}
    merged.update(overrides)
    return from_mapping(SensorSpec, merged, "sensors")


def signal_map(data: Any, section_name: str = "signals") -> dict[str, tuple[str, float]]:
    """A ``[signals]`` table: contract name -> (``"Message.Signal"`` of a loaded DBC, scale).

    Each key is a contract signal name; its value is the source signal as a
    string, ``WheelSpeed_FL = "DriveCtrl_3.WhlSpdFL"``, or a table with an
    optional scale (contract value = source value × scale),
    ``WheelSpeed_FL = { signal = "DriveCtrl_3.WhlSpdFL", scale = 0.10472 }``.
    Only the form is checked here; whether the names exist is the codec's
    (:meth:`tractionecu.bus.dbc.Codec.resolve_mapping`).  Errors name the key.
    """
    if not isinstance(data, Mapping):
        raise ConfigError(f"{section_name}: expected a table, got {data!r}")
    out: dict[str, tuple[str, float]] = {}
    for name, v in data.items():
        key = _key(section_name, str(name))
        if isinstance(v, Mapping):
            unknown = sorted(str(k) for k in v if k not in ("signal", "scale"))
            if unknown:
                raise ConfigError(f"{key}.{unknown[0]}: unknown key (known: scale, signal)")
            if "signal" not in v:
                raise ConfigError(f"{key}: the table needs signal = \"Message.Signal\"")
            ref, scale = v["signal"], v.get("scale", 1.0)
        else:
            ref, scale = v, 1.0
        if not isinstance(ref, str) or not ref.strip():
            raise ConfigError(f"{key}: expected \"Message.Signal\" or {{ signal = ..., scale = ... }}, got {v!r}")
        if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not math.isfinite(scale) or scale == 0:
            raise ConfigError(f"{key}.scale: expected a finite, non-zero number, got {scale!r}")
        out[str(name)] = (ref.strip(), float(scale))
    return out


def load_signal_map(path: str | Path) -> dict[str, tuple[str, float]]:
    """The ``[signals]`` table of a vehicle file (:func:`signal_map`); empty without one.  Errors name the file."""
    data = load_toml(path, "vehicle")
    with _naming(path):
        return signal_map(data.get("signals", {}), "signals")


def save_vehicle(params: VehicleParams, path: str | Path, sensors: SensorSpec | None = None) -> None:
    """Write ``vehicle.toml``: ``[vehicle]`` and, when given, ``[sensors]``."""
    text = "# Nominal vehicle parameters (SI units)\n" + to_toml(params, "vehicle")
    if sensors is not None:
        text += "\n# Sensor figures: rates, noise (1σ) and resolution\n" + to_toml(sensors, "sensors")
    Path(path).write_text(text, encoding="utf-8")
