"""A replay's map against the simulated field it was driven on.

A simulated recording's ``truth.toml`` holds the field's soil regions
(``[[soils]]`` with name, class, ``a``, ``ρ_s`` and polygon in the field's
local frame, and ``[field]`` with its origin).  :func:`field_from_truth`
rebuilds them as a :class:`~tractionecu.sim.field.Field`;
:func:`score_replay_map` scores the map a replay wrote
(:func:`tractionecu.mapping.from_replay.write_replay_map`) against it with
:func:`~tractionecu.evaluation.map_score.map_scorecard` and writes
``map_scorecard.json``.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from ..sim.field import Field, SoilRegion
from .map_score import map_scorecard, write_map_scorecard


def field_from_truth(path: str | Path) -> Field | None:
    """Rebuild the simulated field's soil regions from ``truth.toml`` (None if it has none)."""
    data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    soils = data.get("soils")
    fld = data.get("field", {})
    if not soils or "origin_lat" not in fld:
        return None
    regions = [SoilRegion(s["name"], s["soil_class"], float(s["a"]), float(s["rho_s"]),
                          tuple((float(x), float(y)) for x, y in s.get("polygon", []))) for s in soils]
    return Field(regions, origin_lat=float(fld["origin_lat"]), origin_lon=float(fld["origin_lon"]))


def score_map(map_dir: Path, fld: Field, track_latlon: np.ndarray) -> dict[str, Any]:
    """Map scorecard against the field's true soils (classification by nearest true a)."""
    reg_a = np.array([r.a for r in fld.regions])
    reg_rho = np.array([r.rho_s for r in fld.regions])

    def soil_fn(lat, lon):
        return fld.soil_index(*fld.to_xy(lat, lon))

    def values_fn(lat, lon):
        k = soil_fn(lat, lon)
        return {"a": reg_a[k], "rho_s": reg_rho[k]}

    return map_scorecard(map_dir, soil_fn, values_fn, soil_a={i: float(a) for i, a in enumerate(reg_a)},
                         track_latlon=track_latlon, truth_frame="latlon")


def score_replay_map(out: Path, rec: Any, map_dir: Path) -> dict[str, Any] | None:
    """Score ``map_dir`` against ``rec``'s ``truth.toml`` and write ``out/map_scorecard.json``.

    The track is the recording's GNSS fixes with a finite position.  Returns
    the scorecard, or None when the recording has no ``truth.toml`` or it
    holds no field.
    """
    if rec.truth_toml_path is None:
        return None
    fld = field_from_truth(rec.truth_toml_path)
    if fld is None:
        return None
    gps = rec.gps
    ok = np.isfinite(gps.lat) & np.isfinite(gps.lon)
    card = score_map(Path(map_dir), fld, np.column_stack([gps.lat[ok], gps.lon[ok]]))
    write_map_scorecard(out, card)
    return card
