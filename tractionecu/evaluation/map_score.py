"""Map accuracy against a known (simulated) field: ``map_scorecard``.

Scored cells are the cells of the filled map (the paper's fill of the cell
means) that hold a value *and* lie within ``radius_m`` (default ε_low = 10 m)
Manhattan distance of the vehicle track — the cells the map claims to know.
For those cells:

* ``map_soil_accuracy`` — fraction whose soil class is right.  A cell's class
  is the soil whose typical ``a`` is nearest to the cell's filled ``a``
  (:func:`~tractionecu.mapping.soil.classify_by_a`); the truth is
  ``truth_soil_fn`` at the cell centre;
* ``map_a_rmse`` / ``map_rho_s_rmse`` — RMSE [-] of the filled ``a`` / ``ρ_s``
  against ``truth_values_fn`` at the cell centre.

Also returned: ``map_cells_scored``, ``map_cells_measured``,
``map_a_rmse_measured`` / ``map_rho_s_rmse_measured`` (cells with samples,
unfilled means), ``map_radius_m``, ``map_resolution_m``.  Undefined metrics
(no scored cell) are ``None``.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from ..mapping.fill import DEFAULT_EPS_M, DEFAULT_WEIGHTS, EPS_LOW_M
from ..mapping.soil import classify_by_a, soil_a_table
from ..mapping.store import LayerGrid, MapStore, open_store
from ..mapping.tiles import atomic_write_bytes

SCORECARD_NAME = "map_scorecard.json"

TruthFn = Callable[[NDArray[np.float64], NDArray[np.float64]], Any]


def track_mask(grid_shape: tuple[int, int], x0: float, y0: float, res: float,
               track_xy: ArrayLike, max_gap_m: float = 20.0) -> NDArray[np.bool_]:
    """Cells crossed by the track polyline (segments longer than ``max_gap_m`` [m]
    are treated as a GNSS gap and not drawn)."""
    h, w = grid_shape
    mask = np.zeros((h, w), dtype=bool)
    xy = np.asarray(track_xy, dtype=np.float64).reshape(-1, 2)
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    if len(xy) == 0 or h == 0 or w == 0:
        return mask
    p = xy
    if len(xy) > 1:
        seg = np.diff(xy, axis=0)
        length = np.hypot(seg[:, 0], seg[:, 1])
        use = (length > 0.5 * res) & (length <= max_gap_m)
        n = np.where(use, np.ceil(length / (0.5 * res)), 0).astype(np.int64)
        k = np.repeat(np.arange(len(seg)), n)
        j = np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n) + 1
        f = (j / np.repeat(n, n))[:, None]
        p = np.vstack([xy, xy[k] + f * seg[k]])
    col = np.floor((p[:, 0] - x0) / res).astype(np.int64)
    row = np.floor((p[:, 1] - y0) / res).astype(np.int64)
    ok = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    mask[row[ok], col[ok]] = True
    return mask


def _truth_at(fn: TruthFn, store: MapStore, x: NDArray[np.float64], y: NDArray[np.float64], frame: str) -> Any:
    if frame == "latlon":
        lat, lon = store.to_latlon(x, y)
        return fn(np.asarray(lat), np.asarray(lon))
    if frame == "local":
        return fn(x, y)
    raise ValueError(f"truth_frame must be 'latlon' or 'local', got {frame!r}")


def _rmse(err: NDArray[np.float64]) -> float | None:
    err = err[np.isfinite(err)]
    return float(np.sqrt(np.mean(err * err))) if err.size else None


def map_scorecard(store_or_dir: MapStore | os.PathLike[str] | str,
                  truth_soil_fn: TruthFn,
                  truth_values_fn: TruthFn,
                  track_xy: ArrayLike | None = None,
                  *,
                  soil_a: Mapping[Any, Any],
                  track_latlon: ArrayLike | None = None,
                  truth_frame: str = "latlon",
                  radius_m: float = EPS_LOW_M,
                  eps_m: Sequence[float] = DEFAULT_EPS_M,
                  weights: Sequence[float] = DEFAULT_WEIGHTS) -> dict[str, Any]:
    """Score a map against the true field.

    Parameters
    ----------
    store_or_dir:
        A :class:`MapStore` or a map directory (or a replay output holding
        ``map/``).
    truth_soil_fn:
        ``f(p, q) -> soil ids`` for arrays of cell centres; ids are compared
        with the keys of ``soil_a``.
    truth_values_fn:
        ``f(p, q) -> {"a": array, "rho_s": array}`` (true values [-]); a
        2-tuple ``(a, rho_s)`` is accepted too.
    track_xy:
        (N, 2) vehicle positions in the map's local frame [m].  Or give
        ``track_latlon`` ((N, 2) lat, lon [deg]).  If neither is given the
        track recorded in the store is used.
    soil_a:
        ``{soil id: typical a}`` (or ``{id: SoilClass}``) — the classes.
    truth_frame:
        ``"latlon"``: the truth functions take (lat [deg], lon [deg]) — use this
        when the simulator has its own metric frame; ``"local"``: they take the
        map's local (x [m], y [m]).
    radius_m:
        Scored cells lie within this Manhattan distance [m] of the track.
    """
    store = open_store(store_or_dir)
    keys, typical = soil_a_table(soil_a)
    res = store.resolution_m
    ext = store.padded_extent(max(eps_m), ["a"])
    card: dict[str, Any] = {
        "map_soil_accuracy": None, "map_a_rmse": None, "map_rho_s_rmse": None,
        "map_cells_scored": 0, "map_cells_measured": 0,
        "map_a_rmse_measured": None, "map_rho_s_rmse_measured": None,
        "map_radius_m": float(radius_m), "map_resolution_m": res,
    }
    if ext is None:
        return card
    ga: LayerGrid = store.filled_grid("a", ext, eps_m=eps_m, weights=weights)
    graw = store.grid("a", ext)
    grho = store.filled_grid("rho_s", ext, eps_m=eps_m, weights=weights) if "rho_s" in store.layers else None
    grho_raw = store.grid("rho_s", ext) if grho is not None else None

    if track_xy is None and track_latlon is not None:
        ll = np.asarray(track_latlon, dtype=np.float64).reshape(-1, 2)
        tx, ty = store.to_local(ll[:, 0], ll[:, 1])
        track_xy = np.column_stack([tx, ty])
    if track_xy is None:
        track_xy = store.track()[:, 1:3]
    tmask = track_mask(ga.shape, ga.x0, ga.y0, res, track_xy)
    if tmask.any():
        dist = ndimage.distance_transform_cdt(~tmask, metric="taxicab")
        near = dist <= int(math.floor(radius_m / res * (1 + 1e-9)))
    else:
        near = np.zeros(ga.shape, dtype=bool)
    scored = near & np.isfinite(ga.mean)
    card["map_cells_scored"] = int(scored.sum())
    measured = graw.count > 0
    card["map_cells_measured"] = int(measured.sum())
    x, y = ga.centres()

    def truth_values(sel: NDArray[np.bool_]) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
        tv = _truth_at(truth_values_fn, store, x[sel], y[sel], truth_frame)
        if isinstance(tv, Mapping):
            ta = np.asarray(tv["a"], dtype=np.float64)
            tr = tv.get("rho_s")
        else:
            ta, tr = np.asarray(tv[0], dtype=np.float64), tv[1]
        return np.broadcast_to(ta, (int(sel.sum()),)), (
            None if tr is None else np.broadcast_to(np.asarray(tr, dtype=np.float64), (int(sel.sum()),)))

    if scored.any():
        cls = classify_by_a(ga.mean[scored], typical)
        pred = np.asarray(keys)[cls]
        true_ids = np.broadcast_to(np.asarray(_truth_at(truth_soil_fn, store, x[scored], y[scored], truth_frame)),
                                   pred.shape)
        numeric = "iufb"
        if pred.dtype.kind == true_ids.dtype.kind or (pred.dtype.kind in numeric and true_ids.dtype.kind in numeric):
            right = pred == true_ids
        else:  # e.g. names vs integer ids: never equal
            right = np.zeros(pred.shape, dtype=bool)
        card["map_soil_accuracy"] = float(np.mean(right))
        ta, tr = truth_values(scored)
        card["map_a_rmse"] = _rmse(ga.mean[scored] - ta)
        if grho is not None and tr is not None:
            card["map_rho_s_rmse"] = _rmse(grho.mean[scored] - tr)
    if measured.any():
        ta, tr = truth_values(measured)
        card["map_a_rmse_measured"] = _rmse(graw.mean[measured] - ta)
        if grho_raw is not None and tr is not None:
            m2 = grho_raw.count[measured] > 0
            card["map_rho_s_rmse_measured"] = _rmse((grho_raw.mean[measured] - tr)[m2])
    return card


def write_map_scorecard(out_dir: os.PathLike[str] | str, card: Mapping[str, Any]) -> Path:
    """Write ``card`` as ``out_dir/map_scorecard.json`` (atomically); returns the path."""
    path = Path(out_dir) / SCORECARD_NAME
    atomic_write_bytes(path, (json.dumps(dict(card), indent=2, sort_keys=True, allow_nan=False) + "\n").encode())
    return path


__all__ = ["SCORECARD_NAME", "map_scorecard", "track_mask", "write_map_scorecard"]
