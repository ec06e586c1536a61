"""MapStore: 10 Hz accumulation into on-disk tiles, the API the estimator,
replay and service call.

The module stays whole (over 500 lines) because all of it works on one set of
resident tiles under one lock: accumulation, the atomic flush, eviction and
the read-back that merges memory and disk; the track log
(:mod:`~tractionecu.mapping.track`) and the file formats
(:mod:`~tractionecu.mapping.tiles`) are apart.

::

    from tractionecu.mapping.store import MapStore
    store = MapStore(directory, origin_lat, origin_lon)        # new map, or resume a matching one
    store = MapStore.open(directory)                           # resume from manifest.json
    ok = store.add(lat_deg, lon_deg, {"a": 0.71, "rho_s": 0.06, "mu": 0.4}, t,
                   valid=e.valid, status=e.status, fix_quality=gga_quality, hdop=hdop)  # False if rejected
    n = store.flush()                                          # dirty tiles written atomically
    mean, x0, y0, res = store.mean_grid("a")                  # NaN where empty
    store.close()

Threading: :meth:`add` (data thread) and :meth:`flush` (worker thread) may
run concurrently; a lock guards the in-memory tiles, and the compression and
disk writes of :meth:`flush` happen outside it.

Grid convention of the returned arrays: ``array[row, col]``, row 0 at the
south (``y0``), col 0 at the west (``x0``); cell [row, col] covers
x ∈ [x0 + col·res, x0 + (col+1)·res), y ∈ [y0 + row·res, y0 + (row+1)·res)
in the local frame of :class:`~tractionecu.mapping.projection.FieldFrame`
[m].  Flip rows (``array[::-1]``) for a north-up image.

Default resolution 0.5 m: the innermost fill band (ε_high = 1.5 m) then
spans three cells, so the fill resolves the paper's 1.5/5/10 m bands; the
cell is about one tyre contact-patch long, and finer cells would resolve
nothing that the GNSS error (0.02 m RTK … ~0.5 m SBAS) and the distance
travelled within the estimator's settling time do not already blur; a
100 ha field is 4·10⁶ cells.  Default tile 64 × 64 cells (32 m): one flush
typically rewrites one or two tiles of 0.49 MB raw (six layers × 4096 cells
× 20 B), zlib-compressed on disk; at most ``max_resident_tiles`` clean tiles
(default 256 ≈ 126 MB) stay in memory.
"""

from __future__ import annotations

import collections
import datetime as _dt
import logging
import math
import os
import threading
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tractionecu.errors import ConfigError

from ..gnss.fix import fix_accepted
from .fill import DEFAULT_EPS_M, DEFAULT_WEIGHTS, EPS_LOW_M, paper_fill
from .grid import LAYERS, TileStats
from .projection import FieldFrame
from .tiles import (
    LOCK_NAME,
    MANIFEST_FORMAT,
    MANIFEST_NAME,
    MANIFEST_VERSION,
    TILES_DIRNAME,
    TRACK_NAME,
    CorruptTileError,
    MapStoreError,
    encode_tile,
    fsync_dir,
    iter_tile_files,
    read_manifest,
    read_tile,
    remove_stray_temporaries,
    atomic_write_bytes,
    tile_filename,
    write_manifest,
)
from .track import TrackLog

log = logging.getLogger(__name__)

DEFAULT_RESOLUTION_M = 0.5
DEFAULT_TILE_CELLS = 64
STATUS_FILTER_LOST = 0x200
"""EstimateStatus bit of a filter that lost the vehicle (DBC ``EstimateStatus``)."""
STATUS_STANDSTILL = 0x400
"""EstimateStatus bit of a standstill, where ρ_s and slip are not supported by the data."""
STATUS_MACHINE_UNSUPPORTED = 0x1000
"""EstimateStatus bit of a machine-level μ the bus does not support now (shift, front axle decoupled, low torque)."""
STATUS_MACHINE_LEVEL = 0x4000
"""EstimateStatus bit of the machine-level estimator: one μ for the machine, the same on all four wheels."""
ESTIMATE_LEVELS = {"wheel": "per-wheel μ (hub drive: a torque and a speed per wheel)",
                   "machine": "one μ for the machine, the same on all four wheels (engine-level data: no per-wheel "
                              "precision)"}
"""The manifest's ``estimate_levels``: which estimator levels the accepted samples came from."""
DEFAULT_REJECT_STATUS_MASK = 0x17F | STATUS_FILTER_LOST | STATUS_STANDSTILL | STATUS_MACHINE_UNSUPPORTED
"""EstimateStatus bits that make :meth:`MapStore.add` reject a sample: sensor
timeouts (0x01–0x10), not converged (0x20), input rejected (0x40),
covariance repaired (0x100), filter lost (0x200) and standstill (0x400); a
NIS-gated measurement (0x80) alone does not."""
DEFAULT_MAX_TRACK_PENDING = 360_000
"""Track records kept in memory while they cannot be written (10 h at 10 Hz, 11.5 MB)."""
DEFAULT_MIN_FLUSH_INTERVAL_S = 0.1
"""Flushes closer together than this are skipped (≤ 10 writes per second)."""


@dataclass
class LayerGrid:
    """Dense per-cell statistics of one layer over a rectangular extent.

    ``mean``/``var`` are NaN where ``count`` is 0 (``var`` also where
    count < 2).  ``x0``, ``y0`` [m] are the local coordinates of the south-west
    corner of cell [0, 0]; ``res`` [m] the cell size; rows grow northwards.
    """

    layer: str
    mean: NDArray[np.float64]
    count: NDArray[np.uint32]
    var: NDArray[np.float64]
    x0: float
    y0: float
    res: float

    @property
    def shape(self) -> tuple[int, int]:
        return self.mean.shape  # type: ignore[return-value]

    def centres(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Local (x, y) [m] of every cell centre, each shaped like ``mean``."""
        h, w = self.mean.shape
        x = self.x0 + (np.arange(w) + 0.5) * self.res
        y = self.y0 + (np.arange(h) + 0.5) * self.res
        return np.meshgrid(x, y)


class _Tile:
    __slots__ = ("stats", "version", "saved_version")

    def __init__(self, stats: TileStats, saved: bool) -> None:
        self.stats = stats
        self.version = 0
        self.saved_version = 0 if saved else -1

    @property
    def dirty(self) -> bool:
        return self.version != self.saved_version


def lock_map(directory: Path) -> Any:
    """Advisory exclusive lock so that only one writer uses a map directory (close the returned file to release
    it); :class:`MapStoreError` if another process has the map open for writing."""
    f = open(directory / LOCK_NAME, "a+b")
    try:
        import fcntl
    except ImportError:  # pragma: no cover - non-POSIX
        return f
    try:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        f.close()
        raise MapStoreError(f"{directory}: map is open for writing by another process") from None
    return f


DEFAULT_MAX_RANGE_M = 50_000.0
"""A map covers one farm: positions farther than this from its origin on either axis [m] are refused as GNSS
glitches (a far-off tile would also stretch every export's grid over the gap)."""


class MapStore:
    """Tiled, persistent per-cell running statistics of the map layers.

    Parameters
    ----------
    directory:
        Map directory (created if missing).  If it already holds a map with the
        same origin/resolution/tile size/layers, that map is resumed; a
        different one raises :class:`~tractionecu.errors.ConfigError`.
    origin_lat, origin_lon:
        Fixed field origin [deg WGS84]; fixes the UTM zone and local (0, 0).
    resolution_m:
        Cell size [m] (default 0.5).
    tile_cells:
        Cells per tile side (default 64).
    layers:
        Layer names (default :data:`~tractionecu.mapping.grid.LAYERS`).
    soil_classes:
        Optional {soil name: typical a [-]}, stored in the manifest and used by
        the exports to classify and outline soils.
    min_fix_quality:
        Least accurate GGA fix quality accepted when :meth:`add` is given one
        (1 = autonomous GNSS, 2 = DGPS/SBAS, 5 = RTK float, 4 = RTK fixed, in that order; dead reckoning,
        manual input and simulation, 6–8, never: :mod:`tractionecu.gnss.fix`).
    max_hdop:
        Highest accepted HDOP [-] when :meth:`add` is given one.
    reject_status_mask:
        EstimateStatus bits that reject a sample passed with ``status``
        (default :data:`DEFAULT_REJECT_STATUS_MASK`).
    max_range_m:
        Positions farther than this from the origin (either axis) [m] are
        rejected as GNSS glitches.
    min_flush_interval_s:
        :meth:`flush` calls closer together than this [s] write nothing.
    max_resident_tiles:
        Clean tiles beyond this many are dropped from memory (LRU) and
        re-read from disk when touched again; dirty tiles are never dropped.
    max_track_pending:
        Track records not yet written (a full disk keeps them) are held up to
        this many; beyond it the oldest tenth is dropped and counted as
        ``track_dropped``.
    read_only:
        Open an existing map for reading (exports); no lock, no writes.
    """

    def __init__(self, directory: os.PathLike[str] | str, origin_lat: float, origin_lon: float, *,
                 resolution_m: float = DEFAULT_RESOLUTION_M, tile_cells: int = DEFAULT_TILE_CELLS,
                 layers: Sequence[str] = LAYERS, soil_classes: Mapping[str, float] | None = None,
                 min_fix_quality: int = 1, max_hdop: float = 5.0, max_range_m: float = DEFAULT_MAX_RANGE_M,
                 reject_status_mask: int = DEFAULT_REJECT_STATUS_MASK,
                 min_flush_interval_s: float = DEFAULT_MIN_FLUSH_INTERVAL_S,
                 max_resident_tiles: int = 256, max_track_pending: int = DEFAULT_MAX_TRACK_PENDING,
                 read_only: bool = False) -> None:
        self.directory = Path(directory)
        if not (math.isfinite(resolution_m) and resolution_m > 0):
            raise ConfigError(f"resolution_m must be > 0, got {resolution_m}")
        if int(tile_cells) < 1:
            raise ConfigError(f"tile_cells must be ≥ 1, got {tile_cells}")
        layers = tuple(str(x) for x in layers)
        if not layers or len(set(layers)) != len(layers):
            raise ConfigError(f"layers must be non-empty and unique, got {layers}")
        try:
            self.frame = FieldFrame(float(origin_lat), float(origin_lon))
        except ValueError as e:
            raise ConfigError(f"origin_lat/origin_lon: {e}") from None
        self.resolution_m = float(resolution_m)
        self.tile_cells = int(tile_cells)
        self.layers = layers
        self._layer_index = {name: i for i, name in enumerate(layers)}
        self.soil_classes: dict[str, float] | None = (
            {str(k): float(v) for k, v in soil_classes.items()} if soil_classes else None)
        self.min_fix_quality = int(min_fix_quality)
        self.max_hdop = float(max_hdop)
        self.max_range_m = float(max_range_m)
        self.reject_status_mask = int(reject_status_mask)
        self.min_flush_interval_s = float(min_flush_interval_s)
        self.max_resident_tiles = int(max_resident_tiles)
        self.read_only = bool(read_only)
        self.estimate_levels: set[str] = set()
        """Levels (:data:`ESTIMATE_LEVELS`) of the accepted samples that carried a status, this map's whole life."""
        self._levels_written: set[str] = set()

        self._lock = threading.Lock()
        self._flush_lock = threading.Lock()
        self._tiles: collections.OrderedDict[tuple[int, int], _Tile] = collections.OrderedDict()
        self._on_disk: set[tuple[int, int]] = set()
        self._last_flush = -math.inf
        self._lockf: Any = None
        self._closed = False
        self.corrupt_tiles: list[tuple[Path, str]] = []
        """(path, reason) of every tile found damaged; the file is renamed to ``*.corrupt``."""
        self.stats: collections.Counter[str] = collections.Counter()
        """Counters: ``accepted`` and ``rejected_<reason>`` samples, ``tiles_written``, ..."""
        self.removed_temporaries: list[Path] = []
        self._track = TrackLog(self.directory / TRACK_NAME, max_track_pending, self.stats, self._lock,
                               n_layers=len(layers))

        self._created_utc = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
        manifest = self._manifest_dict()
        existing = (self.directory / MANIFEST_NAME).exists()
        if read_only:
            if not existing:
                raise MapStoreError(f"{self.directory}: no map manifest")
        else:
            (self.directory / TILES_DIRNAME).mkdir(parents=True, exist_ok=True)
            self._lockf = lock_map(self.directory)
        try:
            if existing:
                old = read_manifest(self.directory)
                self._check_manifest(old, manifest)
                self._created_utc = str(old.get("created_utc", self._created_utc))
                self.estimate_levels = {str(x) for x in old.get("estimate_levels", ()) if str(x) in ESTIMATE_LEVELS}
                self._levels_written = set(self.estimate_levels)
                if soil_classes is None:
                    sc = old.get("soil_classes")
                    self.soil_classes = {str(k): float(v) for k, v in sc.items()} if sc else None
                elif not read_only and self.soil_classes != old.get("soil_classes"):
                    write_manifest(self.directory, self._manifest_dict())
            else:
                write_manifest(self.directory, manifest)
                fsync_dir(self.directory)
            if not read_only:
                self.removed_temporaries = remove_stray_temporaries(self.directory)
                self._track.repair()
            self._load_existing()
        except BaseException:
            self._release_lock()
            raise

    # ------------------------------------------------------------ lifecycle
    @classmethod
    def open(cls, directory: os.PathLike[str] | str, *, read_only: bool = False, **kwargs: Any) -> MapStore:
        """Resume the map in ``directory`` with the parameters of its manifest."""
        m = read_manifest(Path(directory))
        try:
            return cls(directory, float(m["origin_lat"]), float(m["origin_lon"]),
                       resolution_m=float(m["resolution_m"]), tile_cells=int(m["tile_cells"]),
                       layers=tuple(m["layers"]), read_only=read_only, **kwargs)
        except KeyError as e:
            raise MapStoreError(f"{Path(directory) / MANIFEST_NAME}: missing key {e}") from None

    def close(self) -> None:
        """Write everything still dirty (ignoring the rate limit) and release the lock."""
        if self._closed:
            return
        try:
            if not self.read_only:
                self.flush(force=True)
        finally:
            self._closed = True
            self._release_lock()

    def _release_lock(self) -> None:
        if self._lockf is not None:
            self._lockf.close()
            self._lockf = None

    def __enter__(self) -> MapStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:  # last resort; close() is the contract
        try:
            self._release_lock()
        except Exception:
            pass

    # ------------------------------------------------------------ manifest
    def _manifest_dict(self) -> dict[str, Any]:
        f = self.frame
        return {
            "format": MANIFEST_FORMAT,
            "version": MANIFEST_VERSION,
            "origin_lat": f.origin_lat,
            "origin_lon": f.origin_lon,
            "crs": f.crs,
            "utm_zone": f.zone,
            "utm_south": bool(f.south),
            "origin_easting_m": f.easting0,
            "origin_northing_m": f.northing0,
            "resolution_m": self.resolution_m,
            "tile_cells": self.tile_cells,
            "layers": list(self.layers),
            "soil_classes": self.soil_classes,
            "estimate_levels": sorted(self.estimate_levels),
            "created_utc": self._created_utc,
        }

    def _check_manifest(self, old: Mapping[str, Any], new: Mapping[str, Any]) -> None:
        for key in ("origin_lat", "origin_lon", "resolution_m"):
            if not math.isclose(float(old.get(key, math.nan)), float(new[key]), rel_tol=0, abs_tol=1e-12):
                raise ConfigError(f"{key}: map in {self.directory} has {old.get(key)}, requested {new[key]}")
        for key in ("tile_cells", "layers", "crs"):
            if old.get(key) != new[key]:
                raise ConfigError(f"{key}: map in {self.directory} has {old.get(key)}, requested {new[key]}")

    @property
    def manifest(self) -> dict[str, Any]:
        return self._manifest_dict()

    # ------------------------------------------------------------ loading
    def _quarantine(self, path: Path, reason: str) -> None:
        self.corrupt_tiles.append((path, reason))
        self.stats["corrupt_tiles"] += 1
        log.warning("map tile %s is corrupt (%s); it is set aside and the tile restarts empty", path, reason)
        if self.read_only:
            return
        target = path.with_name(path.name + ".corrupt")
        k = 1
        while target.exists():
            target = path.with_name(f"{path.name}.corrupt{k}")
            k += 1
        try:
            os.replace(path, target)
            fsync_dir(path.parent)
        except OSError as e:  # pragma: no cover - best effort
            log.warning("could not set aside %s: %s", path, e)

    def _read_checked(self, key: tuple[int, int], path: Path) -> TileStats | None:
        try:
            tx, ty, stats = read_tile(path)
        except CorruptTileError as e:
            self._quarantine(path, e.reason)
            return None
        if (tx, ty) != key or stats.cells != self.tile_cells or stats.layers != self.layers:
            self._quarantine(path, f"header says tile {(tx, ty)}, {stats.cells} cells, layers "
                                   f"{list(stats.layers)}; expected {key}, {self.tile_cells}, {list(self.layers)}")
            return None
        return stats

    def _load_existing(self) -> None:
        for key, path in iter_tile_files(self.directory):
            stats = self._read_checked(key, path)
            if stats is None:
                continue
            self._on_disk.add(key)
            if len(self._tiles) < self.max_resident_tiles:
                self._tiles[key] = _Tile(stats, saved=True)

    def _tile(self, key: tuple[int, int]) -> _Tile:
        """Resident tile for ``key`` (loaded or created); caller holds the lock."""
        t = self._tiles.get(key)
        if t is not None:
            self._tiles.move_to_end(key)
            return t
        stats = None
        if key in self._on_disk:
            stats = self._read_checked(key, self.directory / TILES_DIRNAME / tile_filename(*key))
            if stats is None:
                self._on_disk.discard(key)
        t = _Tile(stats if stats is not None else TileStats(self.layers, self.tile_cells), saved=stats is not None)
        self._tiles[key] = t
        self._evict()
        return t

    def _evict(self) -> None:
        excess = len(self._tiles) - self.max_resident_tiles
        if excess <= 0:
            return
        for key in list(self._tiles)[:-1]:
            if excess <= 0:
                break
            if not self._tiles[key].dirty and key in self._on_disk:
                del self._tiles[key]
                excess -= 1

    # ------------------------------------------------------------ accumulate
    def to_local(self, lat_deg: Any, lon_deg: Any) -> tuple[Any, Any]:
        """(lat, lon) [deg] → local (x, y) [m]."""
        return self.frame.to_local(lat_deg, lon_deg)

    def to_latlon(self, x: Any, y: Any) -> tuple[Any, Any]:
        """Local (x, y) [m] → (lat, lon) [deg]."""
        return self.frame.to_latlon(x, y)

    # ------------------------------------------------------------ rejection rules
    # The one statement of the rules of add() and add_many(): (reason, good) pairs,
    # ``good`` true for a sample that passes, computed alike from Python numbers
    # (add) and numpy arrays (add_many).  They apply in this order, the GNSS rules
    # first, then the range of the projected position (samples passing those go on
    # the track), then the estimate; the first rule a sample fails names its
    # rejection, counted as ``stats["rejected_" + reason]``.
    def _gnss_rules(self, lat: Any, lon: Any, t: Any, fix_quality: Any, hdop: Any) -> tuple[tuple[str, Any], ...]:
        return (("position", (abs(lat) <= 90.0) & (abs(lon) <= 180.0) & (abs(t) < math.inf)),
                ("fix", fix_quality is None or fix_accepted(fix_quality, self.min_fix_quality)),
                # an HDOP not given (NaN: an epoch without GGA) is no reason to refuse, as for the gate
                ("hdop", hdop is None or np.logical_not(np.greater(hdop, self.max_hdop))))

    def _range_rule(self, x: Any, y: Any) -> tuple[str, Any]:
        return "range", (abs(x) <= self.max_range_m) & (abs(y) <= self.max_range_m)

    def _estimate_rules(self, valid: Any, status: Any, layer_values: Sequence[Any]) -> list[tuple[str, Any]]:
        """``layer_values``: the values of the known layers."""
        rules = [("invalid", valid), ("status", status is None or (status & self.reject_status_mask) == 0),
                 ("no_layer", len(layer_values) > 0)]
        if layer_values:
            # Each layer is its own mean: a NaN `a` (its window not full yet) leaves μ and ρ_s of the same
            # sample to their layers, as the service's map writer does; only a sample with no finite layer
            # value is refused.
            finite = abs(layer_values[0]) < math.inf
            for v in layer_values[1:]:
                finite = finite | (abs(v) < math.inf)
            rules.append(("value", finite))
        return rules

    def _reject(self, reason: str) -> bool:
        self.stats["rejected_" + reason] += 1
        return False

    def add(self, lat_deg: float, lon_deg: float, values: Mapping[str, float], t: float, *,
            valid: bool = True, status: int | None = None, fix_quality: int | None = None,
            hdop: float | None = None) -> bool:
        """Accumulate one sample (meant for 10 Hz).  Returns False if rejected.

        ``values`` maps layer names to values; unknown names are ignored, missing
        layers are simply not updated.  Rejected (with ``stats['rejected_…']``):
        ``valid`` false (estimator not converged / status not OK), ``status``
        (the estimator's EstimateStatus bitfield) with a bit of
        ``reject_status_mask`` set, fix quality
        below ``min_fix_quality``, HDOP above ``max_hdop``, non-finite or
        out-of-range position or time, no finite layer value (a non-finite
        value of one layer leaves that layer alone), no known
        layer, position farther than ``max_range_m`` from the origin.  The track
        records every sample whose position passed the GNSS checks.
        """
        if self.read_only or self._closed:
            raise MapStoreError(f"{self.directory}: map is {'read-only' if self.read_only else 'closed'}")
        try:
            lat = float(lat_deg)
            lon = float(lon_deg)
            tt = float(t)
        except (TypeError, ValueError):
            return self._reject("position")
        fq = None if fix_quality is None else float(fix_quality)
        hd = None if hdop is None else float(hdop)
        for reason, good in self._gnss_rules(lat, lon, tt, fq, hd):
            if not good:
                return self._reject(reason)
        x, y = self.frame.to_local(lat, lon)
        reason, good = self._range_rule(x, y)
        if not good:
            return self._reject(reason)
        pairs: list[tuple[int, float]] = []
        for name, v in values.items():
            li = self._layer_index.get(name)
            if li is not None:
                try:
                    pairs.append((li, float(v)))
                except (TypeError, ValueError):
                    pairs.append((li, math.nan))
        ok = True
        for reason, good in self._estimate_rules(bool(valid), None if status is None else int(status),
                                                 [v for _, v in pairs]):
            if not good:
                ok = False
                break
        col = math.floor(x / self.resolution_m)
        row = math.floor(y / self.resolution_m)
        n = self.tile_cells
        row_values = [math.nan] * len(self.layers)
        for li, v in pairs:
            row_values[li] = v
        with self._lock:
            self._track.append(tt, x, y, ok, row_values)
            if not ok:
                self.stats["rejected_" + reason] += 1
                return False
            tile = self._tile((col // n, row // n))
            tile.stats.add(row % n, col % n, [(li, v) for li, v in pairs if math.isfinite(v)])
            tile.version += 1
            self.stats["accepted"] += 1
            if status is not None:
                self.estimate_levels.add("machine" if int(status) & STATUS_MACHINE_LEVEL else "wheel")
        return True

    def add_many(self, lat_deg: ArrayLike, lon_deg: ArrayLike, values: Mapping[str, ArrayLike], t: ArrayLike, *,
                 valid: ArrayLike | None = None, status: ArrayLike | None = None,
                 fix_quality: ArrayLike | None = None, hdop: ArrayLike | None = None) -> NDArray[np.bool_]:
        """Vectorised :meth:`add` for a batch (e.g. a whole replay): same rules,
        same statistics and track, in sample order; returns the accepted mask.

        Every argument is an array of one length N (or broadcasts to it);
        ``values`` maps layer names to arrays.
        """
        if self.read_only or self._closed:
            raise MapStoreError(f"{self.directory}: map is {'read-only' if self.read_only else 'closed'}")
        lat = np.asarray(lat_deg, dtype=np.float64).ravel()
        n = lat.size
        lon = np.broadcast_to(np.asarray(lon_deg, dtype=np.float64).ravel(), (n,))
        tt = np.broadcast_to(np.asarray(t, dtype=np.float64).ravel(), (n,))
        reason = np.full(n, "", dtype=object)

        def apply(rules: Iterable[tuple[str, Any]]) -> None:
            for why, good in rules:
                reason[np.logical_not(good) & (reason == "")] = why

        fq = None if fix_quality is None else np.broadcast_to(np.asarray(fix_quality), (n,))
        hd = None if hdop is None else np.broadcast_to(np.asarray(hdop, dtype=np.float64), (n,))
        apply(self._gnss_rules(lat, lon, tt, fq, hd))
        pos_ok = reason == ""
        x = np.full(n, np.nan)
        y = np.full(n, np.nan)
        if pos_ok.any():
            x[pos_ok], y[pos_ok] = self.frame.to_local(lat[pos_ok], lon[pos_ok])
        apply([self._range_rule(x, y)])
        on_track = reason == ""
        layer_vals: list[tuple[int, NDArray[np.float64]]] = []
        for name, v in values.items():
            li = self._layer_index.get(name)
            if li is not None:
                layer_vals.append((li, np.broadcast_to(np.asarray(v, dtype=np.float64).ravel(), (n,))))
        apply(self._estimate_rules(True if valid is None else np.broadcast_to(np.asarray(valid, dtype=bool), (n,)),
                                   None if status is None else np.broadcast_to(np.asarray(status, dtype=np.int64), (n,)),
                                   [arr for _, arr in layer_vals]))
        ok = reason == ""
        col = np.zeros(n, dtype=np.int64)
        row = np.zeros(n, dtype=np.int64)
        col[ok] = np.floor(x[ok] / self.resolution_m).astype(np.int64)
        row[ok] = np.floor(y[ok] / self.resolution_m).astype(np.int64)
        nt = self.tile_cells
        idx = np.flatnonzero(ok)
        keys = np.stack([col[idx] // nt, row[idx] // nt], axis=1) if idx.size else np.zeros((0, 2), np.int64)
        uniq, inv = np.unique(keys, axis=0, return_inverse=True) if idx.size else (keys, np.zeros(0, np.int64))
        inv = np.asarray(inv).ravel()
        track = np.column_stack([tt[on_track], x[on_track], y[on_track], ok[on_track]]).astype(np.float64)
        sample_values = np.full((idx.size, 1 + len(self.layers)), np.nan)
        sample_values[:, 0] = tt[idx]
        for li, arr in layer_vals:
            sample_values[:, 1 + li] = arr[idx]
        with self._lock:
            self._track.append_rows(track, sample_values)
            for k, (tx, ty) in enumerate(uniq.tolist()):
                sel = idx[inv == k]
                tile = self._tile((int(tx), int(ty)))
                r, c = row[sel] % nt, col[sel] % nt
                for li, arr in layer_vals:
                    fin = np.isfinite(arr[sel])
                    if fin.any():
                        tile.stats.merge_batch(li, r[fin], c[fin], arr[sel][fin])
                tile.version += 1
            self.stats["accepted"] += int(ok.sum())
            for why, cnt in collections.Counter(reason[~ok].tolist()).items():
                self.stats["rejected_" + why] += cnt
            if status is not None and ok.any():
                machine = (np.broadcast_to(np.asarray(status, dtype=np.int64), (n,))[ok] & STATUS_MACHINE_LEVEL) != 0
                if machine.any():
                    self.estimate_levels.add("machine")
                if not machine.all():
                    self.estimate_levels.add("wheel")
        return ok

    # ------------------------------------------------------------ flush
    def dirty_tiles(self) -> list[tuple[int, int]]:
        with self._lock:
            return [k for k, t in self._tiles.items() if t.dirty]

    def _recreate_if_removed(self) -> None:
        """The map directory was removed while the map was open (its manifest is gone): make it again with the
        manifest and write every tile held in memory anew (the tiles held only on disk are lost with it, and
        counted); without this every later flush failed and the samples held in memory were lost at shutdown."""
        if (self.directory / MANIFEST_NAME).exists():
            return
        (self.directory / TILES_DIRNAME).mkdir(parents=True, exist_ok=True)
        with self._lock:
            levels = set(self.estimate_levels)
        write_manifest(self.directory, {**self._manifest_dict(), "estimate_levels": sorted(levels)})
        self._levels_written = levels
        with self._lock:
            lost = len(self._on_disk - set(self._tiles))
            for tile in self._tiles.values():
                tile.saved_version = -1
            self._on_disk.clear()
        self.stats["recreated"] += 1
        self.stats["tiles_lost_with_directory"] += lost
        log.warning("map %s: the map directory was removed while the map was open: made again, the %d tile(s) "
                    "in memory written anew, %d held only on disk lost with it", self.directory, len(self._tiles),
                    lost)

    def flush(self, *, force: bool = False) -> int:
        """Write the dirty tiles (and new track records) atomically.

        Returns the number of tiles written.  Calls less than
        ``min_flush_interval_s`` after the previous flush return 0 without
        writing unless ``force``.  Safe to call from a worker thread while
        :meth:`add` runs.  On an I/O error the tiles stay dirty and
        :class:`~tractionecu.mapping.tiles.MapStoreError` is raised.
        """
        if self.read_only:
            return 0
        with self._flush_lock:
            now = time.monotonic()
            if not force and now - self._last_flush < self.min_flush_interval_s:
                return 0
            self._last_flush = now
            try:
                self._recreate_if_removed()
            except OSError as e:
                raise MapStoreError(f"{self.directory}: the map directory was removed and cannot be made "
                                    f"again: {e}") from e
            with self._lock:
                todo = [(k, t, t.version, t.stats.copy()) for k, t in self._tiles.items() if t.dirty]
                track = self._track.take()
            written = 0
            errors: list[str] = []
            tdir = self.directory / TILES_DIRNAME
            for key, tile, version, snap in todo:
                try:
                    atomic_write_bytes(tdir / tile_filename(*key), encode_tile(key[0], key[1], snap))
                except OSError as e:
                    errors.append(f"{tile_filename(*key)}: {e}")
                    continue
                written += 1
                with self._lock:
                    tile.saved_version = max(tile.saved_version, version)
                    self._on_disk.add(key)
            failed, unwritten = self._track.write(track)
            if failed:
                errors += failed
                with self._lock:
                    self._track.put_back(unwritten)
            with self._lock:
                levels = set(self.estimate_levels)
            if levels != self._levels_written:              # the manifest says which levels the map holds
                try:
                    write_manifest(self.directory, {**self._manifest_dict(), "estimate_levels": sorted(levels)})
                    self._levels_written = levels
                except OSError as e:
                    errors.append(f"{MANIFEST_NAME}: {e}")
            self.stats["tiles_written"] += written
            self.stats["flushes"] += 1
            if errors:
                raise MapStoreError(f"{self.directory}: flush failed: " + "; ".join(errors))
            return written

    # ------------------------------------------------------------ read back
    def tile_keys(self) -> list[tuple[int, int]]:
        """Keys (TX, TY) of every tile in memory or on disk."""
        with self._lock:
            return sorted(set(self._tiles) | self._on_disk)

    def _snapshot(self, li: int) -> dict[tuple[int, int], tuple[NDArray[Any], NDArray[Any], NDArray[Any]]]:
        """(count, mean, m2) of layer ``li`` for every tile, copied."""
        out = {}
        with self._lock:
            resident = {k: (t.stats.count[li].copy(), t.stats.mean[li].copy(), t.stats.m2[li].copy())
                        for k, t in self._tiles.items()}
            disk_only = sorted(self._on_disk - set(self._tiles))
        out.update(resident)
        for key in disk_only:
            try:
                _, _, st = read_tile(self.directory / TILES_DIRNAME / tile_filename(*key))
            except CorruptTileError as e:
                self.corrupt_tiles.append((e.path, e.reason))
                log.warning("%s", e)
                continue
            if st.layers != self.layers or st.cells != self.tile_cells:
                continue
            out[key] = (st.count[li], st.mean[li], st.m2[li])
        return out

    def extent(self, layers: Iterable[str] | None = None) -> tuple[int, int, int, int] | None:
        """(col0, row0, cols, rows) of the cells holding data in any of ``layers``."""
        names = tuple(layers) if layers is not None else self.layers
        lo_c = lo_r = math.inf
        hi_c = hi_r = -math.inf
        n = self.tile_cells
        for name in names:
            for (tx, ty), (cnt, _, _) in self._snapshot(self._layer_idx(name)).items():
                occ = cnt > 0
                if not occ.any():
                    continue
                rows = np.flatnonzero(occ.any(axis=1))
                cols = np.flatnonzero(occ.any(axis=0))
                lo_c = min(lo_c, tx * n + cols[0])
                hi_c = max(hi_c, tx * n + cols[-1])
                lo_r = min(lo_r, ty * n + rows[0])
                hi_r = max(hi_r, ty * n + rows[-1])
        if lo_c == math.inf:
            return None
        return int(lo_c), int(lo_r), int(hi_c - lo_c + 1), int(hi_r - lo_r + 1)

    def _layer_idx(self, layer: str) -> int:
        try:
            return self._layer_index[layer]
        except KeyError:
            raise KeyError(f"unknown map layer {layer!r}; layers are {list(self.layers)}") from None

    def grid(self, layer: str, extent: tuple[int, int, int, int] | None = None) -> LayerGrid:
        """Dense :class:`LayerGrid` of ``layer`` over ``extent`` (default: cells
        with data in this layer; a 0 × 0 grid if there are none)."""
        li = self._layer_idx(layer)
        snap = self._snapshot(li)
        if extent is None:
            extent = self.extent([layer]) or (0, 0, 0, 0)
        col0, row0, cols, rows = extent
        n = self.tile_cells
        count = np.zeros((rows, cols), np.uint32)
        mean = np.full((rows, cols), np.nan)
        m2 = np.zeros((rows, cols))
        for (tx, ty), (cnt, mu, mm) in snap.items():
            # overlap of this tile with the extent, in global cell indices
            c_lo, c_hi = max(tx * n, col0), min(tx * n + n, col0 + cols)
            r_lo, r_hi = max(ty * n, row0), min(ty * n + n, row0 + rows)
            if c_lo >= c_hi or r_lo >= r_hi:
                continue
            src = (slice(r_lo - ty * n, r_hi - ty * n), slice(c_lo - tx * n, c_hi - tx * n))
            dst = (slice(r_lo - row0, r_hi - row0), slice(c_lo - col0, c_hi - col0))
            c = cnt[src]
            count[dst] = c
            mean[dst] = np.where(c > 0, mu[src], np.nan)
            m2[dst] = mm[src]
        var = np.full((rows, cols), np.nan)
        ok = count >= 2
        var[ok] = m2[ok] / (count[ok] - 1.0)
        res = self.resolution_m
        return LayerGrid(layer, mean, count, var, col0 * res, row0 * res, res)

    def padded_extent(self, pad_m: float = EPS_LOW_M,
                      layers: Iterable[str] | None = None) -> tuple[int, int, int, int] | None:
        """:meth:`extent` grown by ``pad_m`` [m] on every side (room for the fill)."""
        ext = self.extent(layers)
        if ext is None:
            return None
        p = int(math.floor(pad_m / self.resolution_m * (1 + 1e-9)))
        col0, row0, cols, rows = ext
        return col0 - p, row0 - p, cols + 2 * p, rows + 2 * p

    def filled_grid(self, layer: str, extent: tuple[int, int, int, int] | None = None, *,
                    eps_m: Sequence[float] = DEFAULT_EPS_M, weights: Sequence[float] = DEFAULT_WEIGHTS,
                    preserve_measured: bool = False) -> LayerGrid:
        """:class:`LayerGrid` whose ``mean`` is the paper's fill of the cell means
        (:func:`~tractionecu.mapping.fill.paper_fill`); ``count``/``var`` stay the
        measured ones.  The default extent is the data extent grown by ε_low so
        that the fill can reach beyond the outermost measured cells."""
        if extent is None:
            extent = self.padded_extent(max(eps_m), [layer]) or (0, 0, 0, 0)
        g = self.grid(layer, extent)
        g.mean = paper_fill(g.mean, self.resolution_m, eps_m=eps_m, weights=weights,
                            preserve_measured=preserve_measured)
        return g

    def mean_grid(self, layer: str) -> tuple[NDArray[np.float64], float, float, float]:
        """(mean array, x0 [m], y0 [m], res [m]) over the cells with data in
        ``layer``; NaN where empty.  See the module docstring for orientation."""
        g = self.grid(layer)
        return g.mean, g.x0, g.y0, g.res

    def curve_paths(self, extent: tuple[int, int, int, int] | None = None, *,
                    classes: Mapping[str, Any] | None = None, tol: float = 1e-6) -> NDArray[np.object_]:
        """Per cell, how its μ(s) curve was identified: ``"class:<name>"`` where every sample
        mapped to it carried that class's fixed shape (p, α1, α2 of the paper's one-parameter path,
        eq. 18), ``"shape"`` where the cell's shape parameters are none of the classes' (the shape
        identified from the data, :mod:`tractionecu.estimation.curve`, or samples of several paths
        averaged), ``""`` where the cell has no shape sample.

        Derived from the ``p``, ``alpha1``, ``alpha2`` layers (means and variances), so maps
        written before the shape path read back as class cells.  ``classes`` maps names to
        objects with ``p``, ``alpha1``, ``alpha2`` (default: the built-in surface classes and curve shapes); the
        grid is that of :meth:`grid` over ``extent`` (default: the cells with a ``p`` sample).
        """
        from ..model.mucurve import CURVE_SHAPES, SOIL_CLASSES
        classes = {**SOIL_CLASSES, **CURVE_SHAPES} if classes is None else classes
        names = ("p", "alpha1", "alpha2")
        if any(n not in self._layer_index for n in names):
            raise KeyError(f"curve_paths needs the layers {names}; this map has {list(self.layers)}")
        if extent is None:
            extent = self.extent(["p"]) or (0, 0, 0, 0)
        grids = [self.grid(n, extent) for n in names]
        out = np.full(grids[0].mean.shape, "", dtype=object)
        has = grids[0].count > 0
        out[has] = "shape"
        for name, c in classes.items():
            ref = (float(c.p), float(c.alpha1), float(c.alpha2))
            same = has.copy()
            for g, v in zip(grids, ref):
                spread = np.where(g.count >= 2, np.nan_to_num(g.var, nan=0.0), 0.0)
                same &= (np.abs(g.mean - v) <= tol * max(1.0, abs(v))) & (spread <= (tol * max(1.0, abs(v))) ** 2)
            out[same] = f"class:{name}"
        return out

    def track(self) -> NDArray[np.float64]:
        """Vehicle track so far: (N, 4) array of t [s], x [m], y [m], accepted flag."""
        return self._track.read()

    def track_values(self) -> NDArray[np.float64]:
        """Layer values of every sample accepted into the map: (N, 1 + layers) array
        of t [s] and one column per layer (manifest order, NaN where the sample had
        none).  Empty for maps written before the values were logged."""
        return self._track.read_values()


def open_store(store_or_dir: MapStore | os.PathLike[str] | str) -> MapStore:
    """A :class:`MapStore` as given, or the map in a directory opened read-only.

    A directory without ``manifest.json`` but with a ``map/`` sub-directory
    holding one (a replay output directory) is accepted too.
    """
    if isinstance(store_or_dir, MapStore):
        return store_or_dir
    d = Path(store_or_dir)
    if not d.exists():
        raise MapStoreError(f"{d}: no such directory")
    if not (d / MANIFEST_NAME).exists() and (d / "map" / MANIFEST_NAME).exists():
        d = d / "map"
    elif not (d / MANIFEST_NAME).exists() and (d / "estimates.csv").exists():
        raise MapStoreError(f"{d}: a replay's output without a map (replayed with --no-map, or the recording has "
                            "no GNSS position): nothing to export")
    return MapStore.open(d, read_only=True)


__all__ = ["DEFAULT_MAX_RANGE_M", "CorruptTileError", "LayerGrid", "MapStore", "MapStoreError", "lock_map",
           "open_store"]
