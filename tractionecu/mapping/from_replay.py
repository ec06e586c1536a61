"""Map a finished replay: estimates sampled at the GNSS epochs (10 Hz) into tiles.

The paper (section 4) stores p_soil = {a, p, α1, α2, ρ_s} at 10 Hz with the
GNSS position of the same instant.  Here each GNSS epoch takes the estimate
of the fixed-rate step at or just after it, and the values are combined over
a window centred on the epoch (:mod:`tractionecu.mapping.sampler`, the same
computation the service does online with a delay); the shape parameters p,
α1, α2 are those of the surface class the curve fit chose at that epoch.  Only estimates
marked valid with a clean status and a good fix reach the map (the store's
rules).

Scoring the map against a simulated field's truth is not done here: see
:mod:`tractionecu.evaluation.map_truth`.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError
from ..gnss.fix import fix_accepted
from .sampler import DEFAULT_HALF_WINDOW_S, STATUS_NO_PAIR, centred_map_values
from .store import STATUS_FILTER_LOST, MapStore, lock_map
from .tiles import MANIFEST_NAME


REFUSED_WORDS = {
    "invalid": "no valid estimate, or the GNSS gate refused the epoch",
    "status": "estimate flagged",
    "fix": "fix quality",
    "hdop": "HDOP",
    "position": "no position",
    "range": "beyond the map's range",
    "value": "no finite value",
    "no_layer": "no layer",
}
"""What each of the map store's rejection reasons means for a replay's GNSS epoch."""


def check_map_dir(map_dir: Path) -> None:
    """Refuse a ``map`` directory a replay may not replace: one that holds files but no map manifest, or a map
    another process has open for writing (:class:`~.tiles.MapStoreError`).

    Every map store writes its manifest when it is created, so a replay's map, even one cut short, has one;
    a directory without it is the owner's own (field boundaries, notes) and is never deleted.
    """
    d = Path(map_dir)
    if d.is_dir() and not (d / MANIFEST_NAME).exists() and any(d.iterdir()):
        raise ConfigError(f"{d}: exists and is not a map a replay wrote (no {MANIFEST_NAME}); a replay replaces "
                          "its own map there and would delete these files: move them or choose another --out")
    if d.exists() and not d.is_dir():
        raise ConfigError(f"{d}: exists and is not a directory; a replay writes its map there: move it or choose "
                          "another --out")
    if (d / MANIFEST_NAME).exists():
        lock_map(d).close()          # a map open for writing (a service's, its map.directory there) is not replaced


ORIGIN_FIXES = 25
"""A replay's map origin is the median of this many of its first mappable fixes (2.5 s at 10 Hz)."""


def replay_origin(gps: Any, gps_mask: np.ndarray | None = None) -> tuple[float, float]:
    """(lat, lon) [deg] of a replay's map origin: the median of its first :data:`ORIGIN_FIXES` fixes that
    the map could hold (a measured position: :func:`~tractionecu.gnss.fix.fix_accepted`, accepted by the
    replay's GNSS gate ``gps_mask``), so that a dead-reckoned, unfixed or single glitched first fix tens of
    kilometres off does not put the rest of the recording beyond the map's range.  Without such a fix,
    the first finite position (the map then holds nothing anyway)."""
    ok = np.isfinite(gps.lat) & np.isfinite(gps.lon)
    good = ok & np.asarray(fix_accepted(np.asarray(gps.fix_quality, dtype=float), 1), dtype=bool)
    if gps_mask is not None:
        good &= np.asarray(gps_mask, dtype=bool)
    idx = np.flatnonzero(good)[:ORIGIN_FIXES]
    if idx.size == 0:
        idx = np.flatnonzero(ok)[:1]
    return float(np.median(gps.lat[idx])), float(np.median(gps.lon[idx]))


def write_replay_map(out: Path, rec: Any, arrays: dict[str, Any], *, resolution_m: float | None = None,
                     half_window_s: float = DEFAULT_HALF_WINDOW_S,
                     gps_mask: np.ndarray | None = None, origin: tuple[float, float] | None = None,
                     store: MapStore | None = None) -> dict[str, Any]:
    """Write ``out/map`` from replay ``arrays`` (keys t, mu, rho_s, a, status, valid, soil_class).

    A previous map in ``out/map`` is replaced: a replay's map is a product of
    that replay alone.  ``origin`` (lat, lon [deg]) fixes the map's origin
    (default: the recording's first fix); with ``store`` the samples are added
    to that open store instead (``out`` unused, the caller closes it): a farm
    map in one frame fed by several replays in sequence.  ``gps_mask`` (one bool per GNSS epoch of ``rec``) keeps
    the epochs the replay's GNSS gate accepted; the others are not mapped.
    Returns a summary: ``map_dir``, ``map_samples`` (estimates stored) and,
    when tiles were written, ``map_epochs`` (GNSS epochs of the recording) and ``map_refused`` (the epochs
    not mapped, by the map store's reason: :data:`REFUSED_WORDS`).
    """
    gps = rec.gps
    summary: dict[str, Any] = {"map_dir": str(out / "map")}
    map_dir = out / "map"
    if store is None and map_dir.exists():          # also when this replay maps nothing: never another's map
        check_map_dir(map_dir)
        # under the map's lock: a service writing it (its map.directory there) had its map deleted and went on
        # writing its tiles, in its own frame, into the map the replay made in its place
        lock = lock_map(map_dir) if (map_dir / MANIFEST_NAME).exists() else None
        try:
            shutil.rmtree(map_dir)
        finally:
            if lock is not None:
                lock.close()
    if len(gps) == 0:
        summary["map_samples"] = 0
        return summary
    ok = np.isfinite(gps.lat) & np.isfinite(gps.lon)
    if not ok.any():
        summary["map_samples"] = 0
        return summary
    kw = {} if resolution_m is None else {"resolution_m": resolution_m}
    own = store is None
    if store is None:
        lat0, lon0 = replay_origin(gps, gps_mask) if origin is None else origin
        store = MapStore(map_dir, float(lat0), float(lon0), **kw)
    t = np.asarray(arrays["t"], dtype=float)
    idx = np.searchsorted(t, gps.t - 1e-9)
    inside = (idx < t.size) & (gps.t >= t[0])
    idx = np.minimum(idx, t.size - 1)
    # Estimates of a lost filter (status FILTER_LOST) take no part in any window.
    lost = (np.asarray(arrays["status"])[idx] & STATUS_FILTER_LOST) != 0
    # A slip its own σ does not support (status 0x2000, held by the estimator) or one averaged over the
    # last metres of travel (0x10000) makes no (μ, s) pair.
    held = (np.asarray(arrays["status"])[idx] & STATUS_NO_PAIR) != 0
    values = centred_map_values(gps.t, np.where(lost[:, None], np.nan, arrays["mu"][idx]),
                                np.where(held[:, None], np.nan, arrays["slip"][idx]),
                                arrays["P_diag"][idx, 5:9], arrays["v"][idx],
                                np.where(lost, np.nan, arrays["rho_s"][idx]),
                                np.asarray(arrays["soil_class"], dtype=object)[idx], half_window_s,
                                curves=None if "curve" not in arrays else [arrays["curve"][i] for i in idx.tolist()])
    # A layer the estimator never reports (ρ_s of a machine without a draft sensor: ρ_s and the draft are
    # not separable) is not offered; a NaN of a layer at one epoch leaves only that layer (the store's rule).
    values = {k: v for k, v in values.items() if np.isfinite(np.asarray(v, dtype=float)).any()}
    offered = arrays["valid"][idx] & inside
    if gps_mask is not None:
        offered &= np.asarray(gps_mask, dtype=bool)
    before = {k: v for k, v in store.stats.items() if k.startswith("rejected_")}
    accepted = store.add_many(gps.lat, gps.lon, values, gps.t, valid=offered,
                              status=arrays["status"][idx], fix_quality=gps.fix_quality, hdop=gps.hdop)
    summary["map_refused"] = {k[len("rejected_"):]: int(v - before.get(k, 0)) for k, v in store.stats.items()
                              if k.startswith("rejected_") and v - before.get(k, 0) > 0}
    if own:
        store.close()
    else:
        summary["map_dir"] = str(store.directory)
    summary["map_samples"] = int(accepted.sum())
    summary["map_epochs"] = int(len(gps))
    return summary
