"""Map exports: GeoTIFF, ISO 11783-10 logged data and grid, PNG (paper Fig. 7 style), GeoJSON.

The exporters stay in one module: each is one function of a few dozen lines
over the same helpers (layer choice, filled grids, soil classes) and the one
dispatch :func:`export`; the ISO 11783-10 writers are in
:mod:`~tractionecu.mapping.iso11783`.

Every exporter takes a :class:`~tractionecu.mapping.store.MapStore` or a map
directory.  GeoTIFF and GeoJSON need ``rasterio`` and the PNG needs
``matplotlib``; they are imported inside the functions, and a missing one
raises :class:`MissingExtraError` naming ``pip install 'tractionecu[maps]'``.
The ISO-XML writer uses only the standard library and numpy.

What is exported (unless ``filled=False``): the paper's fill of the cell
means over the data extent grown by ε_low, i.e. the map a consumer would use.

GeoTIFF
    One float32 band per layer (band description = layer name, band unit
    "1" and tags ``units``/``long_name``: all layers are dimensionless), NaN = no data,
    north-up, CRS = the map's UTM zone (EPSG:326zz/327zz), pixel size = map
    resolution, deflate-compressed.
ISO 11783-10 (:mod:`~tractionecu.mapping.iso11783`)
    ``isoxml``: the measured samples as logged data, a completed task with a
    device description declaring every DDI (units, scale) and a binary time
    log of the 10 Hz track with each sample's stored layer values.
    ``isoxml-grid``: the (filled) map as a type-2 grid, no-data cells marked.
PNG
    Like the paper's Fig. 7: the filled map of one layer semi-transparent in
    the background, measured cells opaque on top, estimated soil boundaries
    (classification by nearest typical ``a``), optional true boundaries, the
    vehicle track in black, a legend of the soil classes and a colour bar.
GeoJSON (RFC 7946, WGS84 lon/lat)
    One Polygon feature per connected soil zone (classified filled ``a``)
    with the zone's soil name, typical ``a``, area [m²] and mean of every
    layer; one LineString feature for the vehicle track; with
    ``include_cells`` one Point per measured cell with its means and counts.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tractionecu.errors import TractionEcuError

from .fill import DEFAULT_EPS_M
from .iso11783 import ISO_DDI, ISO_DDI_COVERAGE, ISO_DESIGNATOR, ISO_SCALE, export_isoxml_log, latlon_grid_spec
from .iso11783 import export_isoxml_grid as _iso_grid
from .soil import classify_by_a, natural_classes
from .store import ESTIMATE_LEVELS, LayerGrid, MapStore, open_store
from .tiles import atomic_write_bytes

GEOTIFF_UNIT = "1"
"""Unit of every GeoTIFF band (all layers are dimensionless; "1" as in UDUNITS/CF)."""

FORMATS = ("geotiff", "isoxml", "isoxml-grid", "png", "geojson")



class MissingExtraError(TractionEcuError, ImportError):
    """An optional dependency of an export is not installed."""


def _require(module: str, what: str) -> Any:
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as e:
        raise MissingExtraError(
            f"{what} needs the '{module.split('.')[0]}' package: pip install 'tractionecu[maps]' ({e})"
        ) from None


# ------------------------------------------------------------------ helpers
def _layers(store: MapStore, layers: Sequence[str] | None) -> list[str]:
    """The requested layers, or by default every layer that holds data."""
    if layers is None:
        names = [n for n in store.layers if store.extent([n]) is not None]
        if not names:
            raise ValueError(f"{store.directory}: the map holds no data")
        return names
    names = list(layers)
    if not names:
        raise KeyError(f"no layer named; layers are {list(store.layers)}")
    for n in names:
        if n not in store.layers:
            raise KeyError(f"unknown map layer {n!r}; layers are {list(store.layers)}")
    if len(set(names)) < len(names):
        raise KeyError(f"a layer named twice in {','.join(names)}: each is one band and one logged value")
    return names


def _grids(store: MapStore, layers: Sequence[str], filled: bool,
           fill_kwargs: Mapping[str, Any] | None) -> tuple[dict[str, LayerGrid], tuple[int, int, int, int]]:
    fk = dict(fill_kwargs or {})
    ext = store.padded_extent(max(fk.get("eps_m", DEFAULT_EPS_M)) if filled else 0.0)
    if ext is None:
        raise ValueError(f"{store.directory}: the map holds no data")
    out = {}
    for n in layers:
        out[n] = store.filled_grid(n, ext, **fk) if filled else store.grid(n, ext)
    return out, ext


def _soil_classes(store: MapStore, soil_classes: Mapping[str, float] | None, ga: LayerGrid) -> dict[str, float]:
    if soil_classes:
        return {str(k): float(getattr(v, "a_typical", v)) for k, v in soil_classes.items()}
    if store.soil_classes:
        return dict(store.soil_classes)
    # up to three classes, fewer where they lie within the spread of a's samples in one cell (the measured
    # cells' median standard deviation): a field of one soil is one class, not three of its noise
    sd = np.sqrt(ga.var[(ga.count >= 2) & np.isfinite(ga.var)])
    centres = natural_classes(ga.mean, 3, spread=float(np.median(sd)) if sd.size else math.nan)
    return {f"a≈{c:.2f}": float(c) for c in centres}


# ------------------------------------------------------------------ GeoTIFF
def export_geotiff(store_or_dir: MapStore | os.PathLike[str] | str, out_path: os.PathLike[str] | str, *,
                   layers: Sequence[str] | None = None, filled: bool = True,
                   fill_kwargs: Mapping[str, Any] | None = None) -> Path:
    """Write a multi-band GeoTIFF (one band per layer) with the map's CRS."""
    rasterio = _require("rasterio", "GeoTIFF export")
    from rasterio.io import MemoryFile
    from rasterio.transform import from_origin

    store = open_store(store_or_dir)
    names = _layers(store, layers)
    grids, (col0, row0, cols, rows) = _grids(store, names, filled, fill_kwargs)
    res = store.resolution_m
    west = store.frame.easting0 + col0 * res
    north = store.frame.northing0 + (row0 + rows) * res
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    profile = dict(driver="GTiff", width=cols, height=rows, count=len(names), dtype="float32",
                   crs=store.frame.crs, transform=from_origin(west, north, res, res), nodata=float("nan"),
                   compress="deflate", predictor=3)
    if rows >= 256 and cols >= 256:
        profile.update(tiled=True, blockxsize=256, blockysize=256)
    # made in memory and written with the one atomic write: GDAL only prints a failed write (a full disk) and
    # the file it closed, empty, was moved over the earlier map.tif, the export saying it was written
    with MemoryFile() as mem:
        with mem.open(**profile) as dst:
            for b, n in enumerate(names, start=1):
                dst.write(grids[n].mean[::-1].astype(np.float32), b)
                dst.set_band_description(b, n)
                dst.set_band_unit(b, GEOTIFF_UNIT)
                dst.update_tags(b, units=GEOTIFF_UNIT, long_name=ISO_DESIGNATOR.get(n, n))
            dst.update_tags(source="tractionecu", content="paper fill of cell means" if filled else "cell means",
                            units="dimensionless", origin_lat=str(store.frame.origin_lat),
                            origin_lon=str(store.frame.origin_lon),
                            estimate_levels=",".join(sorted(store.estimate_levels)) or "unknown")
        data = mem.read()
    atomic_write_bytes(out, data)
    return out


# ------------------------------------------------------------------ ISO-XML
def export_isoxml(store_or_dir: MapStore | os.PathLike[str] | str, out_dir: os.PathLike[str] | str, *,
                  layers: Sequence[str] | None = None, task_name: str = "Ground condition log",
                  **_unused: Any) -> Path:
    """Write the map's logged data as ISO 11783-10 (``TASKDATA.XML``, ``TLG00001.XML``,
    ``TLG00001.BIN``; :func:`~tractionecu.mapping.iso11783.export_isoxml_log`) into
    ``out_dir``; returns the path of ``TASKDATA.XML``.  ``filled``/``fill_kwargs``
    are accepted and ignored: a time log holds samples, not cells."""
    store = open_store(store_or_dir)
    return export_isoxml_log(store, out_dir, _layers(store, layers), task_name=task_name)


def export_isoxml_grid(store_or_dir: MapStore | os.PathLike[str] | str, out_dir: os.PathLike[str] | str, *,
                       layers: Sequence[str] | None = None, filled: bool = True,
                       fill_kwargs: Mapping[str, Any] | None = None,
                       task_name: str = "Ground condition map") -> Path:
    """Write ``TASKDATA.XML`` + ``GRD00001.BIN`` (grid type 2, no-data cells marked;
    :func:`~tractionecu.mapping.iso11783.export_isoxml_grid`) into ``out_dir``;
    returns the path of ``TASKDATA.XML``."""
    store = open_store(store_or_dir)
    names = _layers(store, layers)
    grids, _ = _grids(store, names, filled, fill_kwargs)
    return _iso_grid(store, grids, out_dir, names, task_name=task_name)


# ------------------------------------------------------------------ PNG
def _track_xy(store: MapStore, max_gap_m: float = 20.0) -> NDArray[np.float64]:
    """Track as an (N, 2) polyline with NaN rows at gaps (for plotting)."""
    tr = store.track()
    if len(tr) == 0:
        return np.zeros((0, 2))
    xy = tr[:, 1:3]
    gap = np.hypot(*np.diff(xy, axis=0).T) > max_gap_m
    if gap.any():
        xy = np.insert(xy, np.flatnonzero(gap) + 1, np.nan, axis=0)
    return xy


def export_png(store_or_dir: MapStore | os.PathLike[str] | str, out_path: os.PathLike[str] | str, *,
               layer: str = "a", soil_classes: Mapping[str, float] | None = None,
               truth_soil_fn: Callable[[Any, Any], Any] | None = None, truth_frame: str = "latlon",
               fill_kwargs: Mapping[str, Any] | None = None, dpi: int = 150,
               title: str | None = None) -> Path:
    """Render the map like the paper's Fig. 7 (see module docstring).

    ``truth_soil_fn(p, q) -> soil ids`` (lat/lon or local x/y per
    ``truth_frame``) adds the true soil boundaries as dashed lines.
    """
    _require("matplotlib", "PNG export")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    store = open_store(store_or_dir)
    names = _layers(store, [layer] + (["a"] if layer != "a" else []))
    grids, _ = _grids(store, names, True, fill_kwargs)
    g = grids[layer]
    ga = grids["a"]
    raw = store.grid(layer, (int(round(g.x0 / g.res)), int(round(g.y0 / g.res)), g.shape[1], g.shape[0]))
    classes = _soil_classes(store, soil_classes, ga)
    cnames = list(classes)
    ca = np.array([classes[n] for n in cnames])
    h, w = g.shape
    extent = (g.x0, g.x0 + w * g.res, g.y0, g.y0 + h * g.res)

    vals = np.concatenate([g.mean[np.isfinite(g.mean)], raw.mean[np.isfinite(raw.mean)]])
    if layer == "a" and len(ca):
        vals = np.concatenate([vals, ca])
    lo, hi = (float(np.min(vals)), float(np.max(vals))) if vals.size else (0.0, 1.0)
    if hi - lo < 1e-9:
        lo, hi = lo - 0.05, hi + 0.05
    norm = Normalize(lo, hi)
    cmap = "viridis"

    aspect = (extent[3] - extent[2]) / max(extent[1] - extent[0], 1e-9)
    ax_w = 6.0
    ax_h = float(np.clip(ax_w * aspect, 2.5, 9.0))
    fig = Figure(figsize=(ax_w + 4.2, ax_h + 1.4), dpi=dpi)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    ax.imshow(np.ma.masked_invalid(g.mean), origin="lower", extent=extent, cmap=cmap, norm=norm,
              alpha=0.35, interpolation="nearest")
    im = ax.imshow(np.ma.masked_invalid(raw.mean), origin="lower", extent=extent, cmap=cmap, norm=norm,
                   interpolation="nearest")
    x, y = g.centres()
    handles: list[Any] = []
    cls = classify_by_a(ga.mean, ca).astype(float)
    cls[cls < 0] = np.nan
    if len(ca) > 1 and np.isfinite(cls).any() and np.nanmin(cls) != np.nanmax(cls):
        # outline each class separately, so that a boundary between classes
        # that are not neighbours in a is drawn once, where it is
        inside = np.isfinite(cls)
        for k in np.unique(cls[inside]).astype(int):
            ind = np.where(inside, (cls == k).astype(float), np.nan)
            ax.contour(x, y, np.ma.masked_invalid(ind), levels=[0.5], colors="crimson", linewidths=1.2)
        handles.append(Line2D([], [], color="crimson", lw=1.2, label="soil boundary (map)"))
    if truth_soil_fn is not None:
        if truth_frame == "latlon":
            la, lo_ = store.to_latlon(x, y)
            tid = np.asarray(truth_soil_fn(la, lo_))
        else:
            tid = np.asarray(truth_soil_fn(x, y))
        uniq = np.unique(tid)
        if len(uniq) > 1:
            for u in uniq:
                ax.contour(x, y, (tid == u).astype(float), levels=[0.5], colors="dodgerblue", linewidths=1.2)
            handles.append(Line2D([], [], color="dodgerblue", lw=1.2, label="soil boundary (true)"))
    txy = _track_xy(store)
    if len(txy):
        ax.plot(txy[:, 0], txy[:, 1], color="black", lw=0.5)
        handles.append(Line2D([], [], color="black", lw=0.8, label="vehicle track"))
    cm = im.get_cmap()
    if layer == "a":
        for n, a in sorted(zip(cnames, ca), key=lambda p: -p[1]):
            handles.append(Patch(facecolor=cm(norm(a)), edgecolor="0.3", label=f"{n} (a = {a:.2f})"))
    handles.append(Patch(facecolor=cm(0.5), alpha=0.35, edgecolor="0.3", label="filled (transparent)"))
    handles.append(Patch(facecolor=cm(0.5), edgecolor="0.3", label="measured cells (opaque)"))
    fig_w, fig_h = fig.get_size_inches()
    ax.set_position((0.9 / fig_w, 0.8 / fig_h, ax_w / fig_w, ax_h / fig_h))
    cax = fig.add_axes(((ax_w + 1.05) / fig_w, 0.8 / fig_h, 0.18 / fig_w, ax_h / fig_h))
    fig.legend(handles=handles, loc="upper left", bbox_to_anchor=((ax_w + 1.9) / fig_w, (ax_h + 0.8) / fig_h),
               fontsize=8, framealpha=0.9)
    cb = fig.colorbar(im, cax=cax)
    cb.set_label(f"{layer} [-]")
    ax.set_xlabel("x east [m]")
    ax.set_ylabel("y north [m]")
    ax.set_aspect("equal")
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_title(title or f"Ground condition map: {layer}  ({store.frame.crs}, {store.resolution_m:g} m cells)",
                 fontsize=10)
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp.{os.getpid()}")
    try:
        fig.savefig(tmp, format="png", bbox_inches="tight", pad_inches=0.15)
        os.replace(tmp, out)
    finally:
        if tmp.exists():
            tmp.unlink()
    return out


# ------------------------------------------------------------------ GeoJSON
def _ring_ccw(ring: list[list[float]], ccw: bool) -> list[list[float]]:
    a = np.asarray(ring)
    area2 = float(np.sum(a[:-1, 0] * a[1:, 1] - a[1:, 0] * a[:-1, 1]))
    return ring if (area2 > 0) == ccw else ring[::-1]


def export_geojson(store_or_dir: MapStore | os.PathLike[str] | str, out_path: os.PathLike[str] | str, *,
                   soil_classes: Mapping[str, float] | None = None, include_cells: bool = False,
                   fill_kwargs: Mapping[str, Any] | None = None, decimals: int = 8) -> Path:
    """Write soil zones, the track (and optionally measured cells) as GeoJSON."""
    _require("rasterio", "GeoJSON export")
    from rasterio import features
    from rasterio.transform import Affine

    store = open_store(store_or_dir)
    names = list(store.layers)
    grids, (col0, row0, cols, rows) = _grids(store, names, True, fill_kwargs)
    ga = grids["a"] if "a" in grids else grids[names[0]]
    classes = _soil_classes(store, soil_classes, ga)
    cnames = list(classes)
    ca = np.array([classes[n] for n in cnames])
    cls = classify_by_a(ga.mean, ca).astype(np.int32)
    res = store.resolution_m
    # pixel (col, row) -> local metres, rows growing northwards
    transform = Affine(res, 0.0, ga.x0, 0.0, res, ga.y0)
    feats: list[dict[str, Any]] = []

    def ll(coords: Sequence[Sequence[float]]) -> list[list[float]]:
        c = np.asarray(coords, dtype=np.float64)
        lat, lon = store.to_latlon(c[:, 0], c[:, 1])
        return [[round(float(a), decimals), round(float(b), decimals)] for a, b in zip(lon, lat)]

    # one label per 4-connected zone of equal class, so that every polygon of
    # features.shapes maps to exactly one zone
    from scipy import ndimage

    comp = np.zeros(cls.shape, dtype=np.int32)
    comp_class = [-1]
    for k in range(len(ca)):
        lab, n = ndimage.label(cls == k)
        if n:
            comp[lab > 0] = lab[lab > 0] + (len(comp_class) - 1)
            comp_class.extend([k] * n)
    ncomp = len(comp_class)
    area = np.bincount(comp.ravel(), minlength=ncomp) * (res * res)
    means: dict[str, NDArray[np.float64]] = {}
    for n in names:
        v = grids[n].mean.ravel()
        ok = np.isfinite(v)
        cnt = np.bincount(comp.ravel()[ok], minlength=ncomp)
        tot = np.bincount(comp.ravel()[ok], weights=v[ok], minlength=ncomp)
        with np.errstate(invalid="ignore", divide="ignore"):
            means[n] = np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan)
    for geom, value in features.shapes(comp, mask=comp > 0, transform=transform, connectivity=4):
        z = int(value)
        k = comp_class[z]
        rings = [_ring_ccw(ll(r), ccw=(i == 0)) for i, r in enumerate(geom["coordinates"])]
        props: dict[str, Any] = {"kind": "soil_zone", "soil": cnames[k], "a_typical": float(ca[k]),
                                 "area_m2": float(area[z])}
        for n in names:
            props[f"{n}_mean"] = None if not np.isfinite(means[n][z]) else float(means[n][z])
        feats.append({"type": "Feature", "geometry": {"type": "Polygon", "coordinates": rings},
                      "properties": props})
    txy = store.track()
    if len(txy) >= 2:
        # one line per stretch driven: broken where consecutive positions lie more than 20 m apart or the time
        # runs back (a farm map's tracks of several machines, one after the other: a straight 1.1 km segment
        # joined two fields)
        step = np.hypot(*np.diff(txy[:, 1:3], axis=0).T)
        cut = np.flatnonzero((step > 20.0) | (np.diff(txy[:, 0]) < 0.0)) + 1
        parts = [p for p in np.split(txy, cut) if len(p) >= 2]
        if parts:
            geom = ({"type": "LineString", "coordinates": ll(parts[0][:, 1:3])} if len(parts) == 1 else
                    {"type": "MultiLineString", "coordinates": [ll(p[:, 1:3]) for p in parts]})
            feats.append({"type": "Feature", "geometry": geom,
                          "properties": {"kind": "track", "t_start_s": float(txy[:, 0].min()),
                                         "t_end_s": float(txy[:, 0].max())}})
    if include_cells:
        raw = {n: store.grid(n, (col0, row0, cols, rows)) for n in names}
        any_count = np.zeros((rows, cols), dtype=bool)
        for g in raw.values():
            any_count |= g.count > 0
        rr, cc = np.nonzero(any_count)
        xs = ga.x0 + (cc + 0.5) * res
        ys = ga.y0 + (rr + 0.5) * res
        coords = ll(np.column_stack([xs, ys])) if len(xs) else []
        for k in range(len(rr)):
            props = {"kind": "cell"}
            for n in names:
                c = int(raw[n].count[rr[k], cc[k]])
                props[f"{n}_count"] = c
                props[f"{n}_mean"] = float(raw[n].mean[rr[k], cc[k]]) if c else None
            feats.append({"type": "Feature", "geometry": {"type": "Point", "coordinates": coords[k]},
                          "properties": props})
    doc = {"type": "FeatureCollection",
           "name": "tractionecu ground condition map",
           # which estimator made the map: "machine" means one μ for all four wheels, not per-wheel precision
           "estimate_levels": {lv: ESTIMATE_LEVELS[lv] for lv in sorted(store.estimate_levels)},
           "features": feats}
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out, json.dumps(doc, allow_nan=False, separators=(",", ":")).encode("utf-8"))
    return out


EXPORTERS: dict[str, Callable[..., Path]] = {
    "geotiff": export_geotiff,
    "isoxml": export_isoxml,
    "isoxml-grid": export_isoxml_grid,
    "png": export_png,
    "geojson": export_geojson,
}

DEFAULT_OUT = {"geotiff": "map.tif", "isoxml": "TASKDATA", "isoxml-grid": "TASKDATA_GRID", "png": "map.png", "geojson": "map.geojson"}


def export(store_or_dir: MapStore | os.PathLike[str] | str, fmt: str, out: os.PathLike[str] | str,
           **kwargs: Any) -> Path:
    """Dispatch to the exporter of ``fmt`` (one of :data:`FORMATS`).

    An existing ``out`` that is not a regular file or directory (a device, a pipe, a socket) is refused: the
    exporters write beside the target and rename over it, which replaced ``/dev/null`` with a GeoJSON file."""
    try:
        fn = EXPORTERS[fmt]
    except KeyError:
        raise ValueError(f"unknown map format {fmt!r}; choose from {', '.join(FORMATS)}") from None
    p = Path(out)
    if p.exists() and not (p.is_file() or p.is_dir()):
        raise ValueError(f"{p}: exists and is not a regular file or a directory; an export is written beside its "
                         "target and moved over it: give a file name")
    return fn(store_or_dir, out, **kwargs)


__all__ = [
    "DEFAULT_OUT",
    "EXPORTERS",
    "FORMATS",
    "ISO_DDI",
    "ISO_DDI_COVERAGE",
    "ISO_SCALE",
    "MissingExtraError",
    "export",
    "export_geojson",
    "export_geotiff",
    "export_isoxml",
    "export_isoxml_grid",
    "export_png",
    "latlon_grid_spec",
]
