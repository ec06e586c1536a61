"""Typed, frozen configuration with units, loaded from and saved to TOML.

Every field carries its unit in the name or in the doc line.  Values are
validated on construction; a :class:`~tractionecu.errors.ConfigError` always
names the offending key.

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
- ``cd_area_m2 = 4.5``: C_d ≈ 0.9 × frontal area ≈ 5 m²; about 17 N at
  2.5 m/s, matching the physics notes' "≈ 20 N, negligible in the field".
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Mapping

from .errors import ConfigError

G = 9.81
"""Gravitational acceleration [m/s²]."""


@dataclass(frozen=True)
class VehicleParams:
    """Nominal vehicle parameters, as a user knows them from the spec sheet."""

    mass_kg: float = field(default=6300.0, metadata={"doc": "total vehicle mass m incl. wheels [kg]", "lo": 100.0, "hi": 100000.0})
    wheel_mass_kg: float = field(default=160.0, metadata={"doc": "mass of one wheel m_w [kg]", "lo": 1.0, "hi": 5000.0})
    rated_power_w: float = field(default=80e3, metadata={"doc": "total drive-train power [W]", "lo": 1e3, "hi": 1e6})
    r0_m: float = field(default=0.80, metadata={"doc": "unloaded wheel radius r0 [m]", "lo": 0.1, "hi": 2.5})
    tyre_width_m: float = field(default=0.54, metadata={"doc": "tyre section width b_t [m]", "lo": 0.05, "hi": 1.5})
    tyre_pressure_pa: float = field(default=1.6e5, metadata={"doc": "tyre inflation pressure p_t [Pa]", "lo": 2e4, "hi": 1e6})
    wheel_inertia_kgm2: float = field(default=60.0, metadata={"doc": "wheel + reflected drive inertia J_w [kg·m²]", "lo": 0.1, "hi": 5000.0})
    rho_t: float = field(default=0.015, metadata={"doc": "tyre-deformation rolling resistance coefficient ρ_t [-]", "lo": 0.0, "hi": 0.2})
    wheelbase_m: float = field(default=2.5, metadata={"doc": "wheelbase L [m]", "lo": 0.5, "hi": 6.0})
    cg_height_m: float = field(default=1.0, metadata={"doc": "centre-of-gravity height h_cg [m]", "lo": 0.1, "hi": 4.0})
    hitch_height_m: float = field(default=0.5, metadata={"doc": "drawbar / hitch height h_hitch [m]", "lo": 0.0, "hi": 2.0})
    static_front_fraction: float = field(default=0.40, metadata={"doc": "static share of weight on the front axle [-]", "lo": 0.05, "hi": 0.95})
    track_width_m: float = field(default=1.8, metadata={"doc": "track width, wheel centre to wheel centre [m]", "lo": 0.5, "hi": 5.0})
    cd_area_m2: float = field(default=4.5, metadata={"doc": "drag area C_d·A [m²]", "lo": 0.0, "hi": 50.0})
    max_wheel_torque_nm: float = field(default=9000.0, metadata={"doc": "torque limit of one wheel drive [N·m]", "lo": 10.0, "hi": 1e5})

    def __post_init__(self) -> None:
        _validate(self, "vehicle")

    # ---- derived quantities -------------------------------------------------
    @property
    def weight_n(self) -> float:
        """Total weight m·g [N]."""
        return self.mass_kg * G

    def static_front_load_n(self) -> float:
        """Static front-axle ground reaction F_zf [N]."""
        return self.static_front_fraction * self.weight_n


def _validate(obj: Any, section: str) -> None:
    for f in fields(obj):
        v = getattr(obj, f.name)
        lo, hi = f.metadata.get("lo"), f.metadata.get("hi")
        if lo is None and hi is None:
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)) or isinstance(v, float) and not math.isfinite(v):
            raise ConfigError(f"{section}.{f.name}: expected a finite number, got {v!r}")
        if lo is not None and v < lo or hi is not None and v > hi:
            raise ConfigError(f"{section}.{f.name} = {v!r} is outside [{lo}, {hi}] ({f.metadata.get('doc', '')})")


def from_mapping(cls: type, data: Mapping[str, Any], section: str) -> Any:
    """Build dataclass ``cls`` from a TOML table, naming unknown or bad keys."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{section}: expected a table, got {type(data).__name__}")
    known = {f.name: f for f in fields(cls)}
    unknown = sorted(set(data) - set(known))
    if unknown:
        raise ConfigError(f"{section}.{unknown[0]}: unknown key (known: {', '.join(sorted(known))})")
    kwargs = {}
    for k, v in data.items():
        default = known[k].default
        numeric = isinstance(default, (int, float)) and not isinstance(default, bool)
        if numeric and (isinstance(v, bool) or not isinstance(v, (int, float))):
            raise ConfigError(f"{section}.{k}: expected a number, got {v!r}")
        if isinstance(default, bool) and not isinstance(v, bool):
            raise ConfigError(f"{section}.{k}: expected true or false, got {v!r}")
        if isinstance(default, int) and not isinstance(default, bool) and not isinstance(v, int):
            raise ConfigError(f"{section}.{k}: expected an integer, got {v!r}")
        if isinstance(default, float) and isinstance(v, int):
            try:
                v = float(v)
            except OverflowError:
                raise ConfigError(f"{section}.{k}: {len(str(v))}-digit integer is out of range") from None
        kwargs[k] = v
    try:
        return cls(**kwargs)
    except TypeError as exc:  # pragma: no cover - defensive
        raise ConfigError(f"{section}: {exc}") from exc


def load_vehicle(path: str | Path) -> VehicleParams:
    """Load ``vehicle.toml`` (keys at top level or under ``[vehicle]``)."""
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise ConfigError(f"{p}: vehicle file not found") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: cannot read: {exc}") from exc
    except ValueError as exc:  # TOMLDecodeError, or an integer literal beyond Python's 4300-digit limit
        raise ConfigError(f"{p}: not valid TOML: {exc}") from exc
    table = data.get("vehicle", data)
    return from_mapping(VehicleParams, table, "vehicle")


def to_toml(obj: Any, section: str | None = None) -> str:
    """Serialise a flat dataclass to TOML with the doc line of each field as a comment."""
    lines = [f"[{section}]"] if section else []
    for f in fields(obj):
        v = getattr(obj, f.name)
        doc = f.metadata.get("doc")
        if doc:
            lines.append(f"# {doc}")
        lines.append(f"{f.name} = {_toml_value(v)}")
    return "\n".join(lines) + "\n"


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def save_vehicle(params: VehicleParams, path: str | Path) -> None:
    """Write ``vehicle.toml``."""
    Path(path).write_text("# Nominal vehicle parameters (SI units)\n" + to_toml(params, "vehicle"), encoding="utf-8")


def replace(obj: Any, **changes: Any) -> Any:
    """``dataclasses.replace`` that re-validates."""
    return dataclasses.replace(obj, **changes)
