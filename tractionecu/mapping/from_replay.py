"""Map a finished replay: estimates sampled at the GNSS epochs (10 Hz) into tiles.

The paper (section 4) stores p_soil = {a, p, α1, α2, ρ_s} at 10 Hz with the
GNSS position of the same instant.  Here each GNSS epoch takes the estimate
of the fixed-rate step at or just after it, and the values are combined over
a window centred on the epoch (:mod:`tractionecu.mapping.sampler`, the same
computation the service does online with a delay); the shape parameters p,
α1, α2 are those of the surface class the curve fit chose at that epoch.  Only estimates
marked valid with a clean status and a good fix reach the map (the store's
rules).

With a simulated recording, the truth's soil regions are rebuilt from
``truth.toml`` and the map is scored (``map_scorecard.json``).
"""

from __future__ import annotations

import shutil
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from ..sim.field import Field, SoilRegion
from .sampler import DEFAULT_HALF_WINDOW_S, centred_map_values
from .score import map_scorecard, write_map_scorecard
from .store import MapStore


def write_replay_map(out: Path, rec: Any, arrays: dict[str, Any], *, resolution_m: float | None = None,
                     half_window_s: float = DEFAULT_HALF_WINDOW_S) -> dict[str, Any]:
    """Write ``out/map`` from replay ``arrays`` (keys t, mu, rho_s, a, status, valid, soil_class).

    A previous map in ``out/map`` is replaced: a replay's map is a product of
    that replay alone.  Returns a summary with the sample counts and, with
    truth, the map scorecard.
    """
    gps = rec.gps
    summary: dict[str, Any] = {"map_dir": str(out / "map")}
    if len(gps) == 0:
        summary["map_samples"] = 0
        return summary
    map_dir = out / "map"
    if map_dir.exists():
        shutil.rmtree(map_dir)
    ok = np.isfinite(gps.lat) & np.isfinite(gps.lon)
    if not ok.any():
        summary["map_samples"] = 0
        return summary
    first = int(np.flatnonzero(ok)[0])
    kw = {} if resolution_m is None else {"resolution_m": resolution_m}
    store = MapStore(map_dir, float(gps.lat[first]), float(gps.lon[first]), **kw)
    t = np.asarray(arrays["t"], dtype=float)
    idx = np.searchsorted(t, gps.t - 1e-9)
    inside = (idx < t.size) & (gps.t >= t[0])
    idx = np.minimum(idx, t.size - 1)
    values = centred_map_values(gps.t, arrays["mu"][idx], arrays["slip"][idx], arrays["P_diag"][idx, 5:9],
                                arrays["v"][idx], arrays["rho_s"][idx],
                                np.asarray(arrays["soil_class"], dtype=object)[idx], half_window_s)
    accepted = store.add_many(gps.lat, gps.lon, values, gps.t, valid=arrays["valid"][idx] & inside,
                              status=arrays["status"][idx], fix_quality=gps.fix_quality, hdop=gps.hdop)
    store.close()
    summary["map_samples"] = int(accepted.sum())
    summary["map_epochs"] = int(len(gps))
    if rec.truth_toml_path is not None:
        fld = field_from_truth(rec.truth_toml_path)
        if fld is not None:
            card = score_map(map_dir, fld, np.column_stack([gps.lat[ok], gps.lon[ok]]))
            write_map_scorecard(out, card)
            summary["map_scorecard"] = card
    return summary


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
