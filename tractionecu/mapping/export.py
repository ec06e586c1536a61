"""Map exports: GeoTIFF, ISO 11783-10 grid, PNG (paper Fig. 7 style), GeoJSON.

The four exporters stay in one module (over 500 lines): each is one function
of a few dozen lines over the same helpers (layer choice, filled grids, soil
classes) and the one dispatch :func:`export`.

Every exporter takes a :class:`~tractionecu.mapping.store.MapStore` or a map
directory.  GeoTIFF and GeoJSON need ``rasterio`` and the PNG needs
``matplotlib``; they are imported inside the functions, and a missing one
raises :class:`MissingExtraError` naming ``pip install 'tractionecu[maps]'``.
The ISO-XML writer uses only the standard library and numpy.

What is exported (unless ``filled=False``): the paper's fill of the cell
means over the data extent grown by ε_low, i.e. the map a consumer would use.

GeoTIFF
    One float32 band per layer (band description = layer name), NaN = no data,
    north-up, CRS = the map's UTM zone (EPSG:326zz/327zz), pixel size = map
    resolution, deflate-compressed.
ISO 11783-10
    ``TASKDATA.XML`` (version 4.3) with one task (TSK) holding a treatment zone
    (TZN code 1) whose process data variables (PDV) are the layers plus a
    coverage flag, and a grid (GRD) of type 2 referring to it, and
    ``GRD00001.BIN``.  By default only layers holding data are written (also
    for GeoTIFF).  ISO grids are in WGS84 degrees, so the metric map is
    resampled (nearest cell) to a lat/lon grid of about the map resolution.
    Each cell holds one little-endian int32 per PDV in TZN order, rows from
    south to north, columns west to east.  Layers carry manufacturer-
    proprietary DDIs with a value presentation (VPN) giving the scale:

    ========  =====  ======
    layer     DDI    scale
    ========  =====  ======
    a         E100   1e-4
    p         E101   1e-4
    alpha1    E102   1e-3
    alpha2    E103   1e-3
    rho_s     E104   1e-5
    mu        E105   1e-4
    other     E110+  1e-4
    coverage  E1FF   1      (0 no data, 1 filled, 2 measured)
    ========  =====  ======

    Grid type 2 has no "no data" value: cells without data carry 0 in every
    layer and coverage 0.  All layers are dimensionless (unit designator "-").
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
import xml.etree.ElementTree as ET
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tractionecu.errors import TractionEcuError

from .fill import DEFAULT_EPS_M
from .projection import meridian_radius, normal_radius
from .soil import classify_by_a, natural_classes
from .store import LayerGrid, MapStore, open_store
from .tiles import atomic_write_bytes

FORMATS = ("geotiff", "isoxml", "png", "geojson")

ISO_DDI = {"a": 0xE100, "p": 0xE101, "alpha1": 0xE102, "alpha2": 0xE103, "rho_s": 0xE104, "mu": 0xE105}
ISO_SCALE = {"a": 1e-4, "p": 1e-4, "alpha1": 1e-3, "alpha2": 1e-3, "rho_s": 1e-5, "mu": 1e-4}
ISO_DDI_OTHER_START = 0xE110
ISO_DDI_COVERAGE = 0xE1FF
ISO_GRID_FILENAME = "GRD00001"


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
    for n in names:
        if n not in store.layers:
            raise KeyError(f"unknown map layer {n!r}; layers are {list(store.layers)}")
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


def _soil_classes(store: MapStore, soil_classes: Mapping[str, float] | None,
                  a_values: NDArray[np.float64]) -> dict[str, float]:
    if soil_classes:
        return {str(k): float(getattr(v, "a_typical", v)) for k, v in soil_classes.items()}
    if store.soil_classes:
        return dict(store.soil_classes)
    centres = natural_classes(a_values, 3)
    return {f"a≈{c:.2f}": float(c) for c in centres}


def _iso_table(layers: Sequence[str]) -> list[tuple[str, int, float]]:
    table = []
    other = ISO_DDI_OTHER_START
    for n in layers:
        if n in ISO_DDI:
            table.append((n, ISO_DDI[n], ISO_SCALE[n]))
        else:
            table.append((n, other, 1e-4))
            other += 1
    return table


# ------------------------------------------------------------------ GeoTIFF
def export_geotiff(store_or_dir: MapStore | os.PathLike[str] | str, out_path: os.PathLike[str] | str, *,
                   layers: Sequence[str] | None = None, filled: bool = True,
                   fill_kwargs: Mapping[str, Any] | None = None) -> Path:
    """Write a multi-band GeoTIFF (one band per layer) with the map's CRS."""
    rasterio = _require("rasterio", "GeoTIFF export")
    from rasterio.transform import from_origin

    store = open_store(store_or_dir)
    names = _layers(store, layers)
    grids, (col0, row0, cols, rows) = _grids(store, names, filled, fill_kwargs)
    res = store.resolution_m
    west = store.frame.easting0 + col0 * res
    north = store.frame.northing0 + (row0 + rows) * res
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp.{os.getpid()}")
    profile = dict(driver="GTiff", width=cols, height=rows, count=len(names), dtype="float32",
                   crs=store.frame.crs, transform=from_origin(west, north, res, res), nodata=float("nan"),
                   compress="deflate", predictor=3)
    if rows >= 256 and cols >= 256:
        profile.update(tiled=True, blockxsize=256, blockysize=256)
    try:
        with rasterio.open(tmp, "w", **profile) as dst:
            for b, n in enumerate(names, start=1):
                dst.write(grids[n].mean[::-1].astype(np.float32), b)
                dst.set_band_description(b, n)
            dst.update_tags(source="tractionecu", content="paper fill of cell means" if filled else "cell means",
                            units="dimensionless", origin_lat=str(store.frame.origin_lat),
                            origin_lon=str(store.frame.origin_lon))
        os.replace(tmp, out)
    finally:
        if tmp.exists():
            tmp.unlink()
    return out


# ------------------------------------------------------------------ ISO-XML
def latlon_grid_spec(store: MapStore, grid: LayerGrid, finite: NDArray[np.bool_]) -> dict[str, Any]:
    """WGS84 grid covering the finite cells of ``grid``: min north/east [deg],
    cell north/east size [deg] (≈ the map resolution), rows, columns."""
    rows_any = np.flatnonzero(finite.any(axis=1))
    cols_any = np.flatnonzero(finite.any(axis=0))
    res = grid.res
    xa, xb = grid.x0 + cols_any[0] * res, grid.x0 + (cols_any[-1] + 1) * res
    ya, yb = grid.y0 + rows_any[0] * res, grid.y0 + (rows_any[-1] + 1) * res
    # boundary of the metric box, densely sampled, in lat/lon
    t = np.linspace(0.0, 1.0, 65)
    bx = np.concatenate([xa + (xb - xa) * t, np.full_like(t, xb), xb - (xb - xa) * t, np.full_like(t, xa)])
    by = np.concatenate([np.full_like(t, ya), ya + (yb - ya) * t, np.full_like(t, yb), yb - (yb - ya) * t])
    lat, lon = store.to_latlon(bx, by)
    lat_c = float(np.mean(lat))
    dlat = math.degrees(res / meridian_radius(lat_c))
    dlon = math.degrees(res / (normal_radius(lat_c) * math.cos(math.radians(lat_c))))
    lat0 = math.floor(float(lat.min()) * 1e9) / 1e9
    lon0 = math.floor(float(lon.min()) * 1e9) / 1e9
    nrows = int(math.ceil((float(lat.max()) - lat0) / dlat))
    ncols = int(math.ceil((float(lon.max()) - lon0) / dlon))
    return {"min_north": lat0, "min_east": lon0, "cell_north": dlat, "cell_east": dlon,
            "rows": max(nrows, 1), "cols": max(ncols, 1)}


def _sample_nearest(store: MapStore, grid: LayerGrid, spec: Mapping[str, Any]) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.bool_]]:
    """Indices into ``grid`` of the cell nearest each lat/lon grid cell centre."""
    lat = spec["min_north"] + (np.arange(spec["rows"]) + 0.5) * spec["cell_north"]
    lon = spec["min_east"] + (np.arange(spec["cols"]) + 0.5) * spec["cell_east"]
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    x, y = store.to_local(la, lo)
    col = np.floor((x - grid.x0) / grid.res).astype(np.intp)
    row = np.floor((y - grid.y0) / grid.res).astype(np.intp)
    h, w = grid.shape
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    return np.clip(row, 0, h - 1), np.clip(col, 0, w - 1), inside


def export_isoxml(store_or_dir: MapStore | os.PathLike[str] | str, out_dir: os.PathLike[str] | str, *,
                  layers: Sequence[str] | None = None, filled: bool = True,
                  fill_kwargs: Mapping[str, Any] | None = None, task_name: str = "Ground condition map") -> Path:
    """Write ``TASKDATA.XML`` + ``GRD00001.BIN`` (grid type 2) into ``out_dir``;
    returns the path of ``TASKDATA.XML``."""
    store = open_store(store_or_dir)
    names = _layers(store, layers)
    grids, _ = _grids(store, names, filled, fill_kwargs)
    ref = grids[names[0]]
    finite = np.zeros(ref.shape, dtype=bool)
    for g in grids.values():
        finite |= np.isfinite(g.mean)
    if not finite.any():
        raise ValueError(f"{store.directory}: the map holds no data")
    spec = latlon_grid_spec(store, ref, finite)
    row, col, inside = _sample_nearest(store, ref, spec)
    table = _iso_table(names)
    cells = np.zeros((spec["rows"], spec["cols"], len(table) + 1), dtype="<i4")
    has_any = np.zeros((spec["rows"], spec["cols"]), dtype=bool)
    measured = np.zeros_like(has_any)
    for k, (n, _, scale) in enumerate(table):
        g = grids[n]
        v = np.where(inside, g.mean[row, col], np.nan)
        ok = np.isfinite(v)
        q = np.zeros(v.shape)
        q[ok] = np.rint(v[ok] / scale)
        cells[:, :, k] = np.clip(q, -2**31, 2**31 - 1).astype("<i4")
        has_any |= ok
        measured |= inside & (g.count[row, col] > 0)
    cells[:, :, -1] = np.where(measured, 2, np.where(has_any, 1, 0))
    payload = cells.tobytes(order="C")

    root = ET.Element("ISO11783_TaskData", {
        "VersionMajor": "4", "VersionMinor": "3",
        "ManagementSoftwareManufacturer": "tractionecu", "ManagementSoftwareVersion": _version(),
        "DataTransferOrigin": "2",
    })
    tsk = ET.SubElement(root, "TSK", {"A": "TSK1", "B": task_name, "G": "1"})
    tzn = ET.SubElement(tsk, "TZN", {"A": "1", "B": "ground condition"})
    for k, (n, ddi, _) in enumerate(table, start=1):
        ET.SubElement(tzn, "PDV", {"A": f"{ddi:04X}", "B": "0", "E": f"VPN{k}"})
    ET.SubElement(tzn, "PDV", {"A": f"{ISO_DDI_COVERAGE:04X}", "B": "0", "E": f"VPN{len(table) + 1}"})
    ET.SubElement(tsk, "GRD", {
        "A": f"{spec['min_north']:.9f}", "B": f"{spec['min_east']:.9f}",
        "C": repr(float(spec["cell_north"])), "D": repr(float(spec["cell_east"])),
        "E": str(spec["cols"]), "F": str(spec["rows"]), "G": ISO_GRID_FILENAME,
        "H": str(len(payload)), "I": "2", "J": "1",
    })
    for k, (n, _, scale) in enumerate(table, start=1):
        decimals = max(0, int(round(-math.log10(scale))))
        ET.SubElement(root, "VPN", {"A": f"VPN{k}", "B": "0", "C": repr(float(scale)), "D": str(decimals),
                                    "E": "-"})
    ET.SubElement(root, "VPN", {"A": f"VPN{len(table) + 1}", "B": "0", "C": "1.0", "D": "0", "E": "-"})
    ET.indent(root)
    xml = b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8") + b"\n"

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out / f"{ISO_GRID_FILENAME}.BIN", payload)
    atomic_write_bytes(out / "TASKDATA.XML", xml)
    return out / "TASKDATA.XML"


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("tractionecu")
    except Exception:
        return "0.1.0"


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
    classes = _soil_classes(store, soil_classes, ga.mean)
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
    classes = _soil_classes(store, soil_classes, ga.mean)
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
        feats.append({"type": "Feature", "geometry": {"type": "LineString", "coordinates": ll(txy[:, 1:3])},
                      "properties": {"kind": "track", "t_start_s": float(txy[0, 0]), "t_end_s": float(txy[-1, 0])}})
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
           "features": feats}
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out, json.dumps(doc, allow_nan=False, separators=(",", ":")).encode("utf-8"))
    return out


EXPORTERS: dict[str, Callable[..., Path]] = {
    "geotiff": export_geotiff,
    "isoxml": export_isoxml,
    "png": export_png,
    "geojson": export_geojson,
}

DEFAULT_OUT = {"geotiff": "map.tif", "isoxml": "TASKDATA", "png": "map.png", "geojson": "map.geojson"}


def export(store_or_dir: MapStore | os.PathLike[str] | str, fmt: str, out: os.PathLike[str] | str,
           **kwargs: Any) -> Path:
    """Dispatch to the exporter of ``fmt`` (one of :data:`FORMATS`)."""
    try:
        fn = EXPORTERS[fmt]
    except KeyError:
        raise ValueError(f"unknown map format {fmt!r}; choose from {', '.join(FORMATS)}") from None
    return fn(store_or_dir, out, **kwargs)


__all__ = [
    "DEFAULT_OUT",
    "EXPORTERS",
    "FORMATS",
    "MissingExtraError",
    "export",
    "export_geojson",
    "export_geotiff",
    "export_isoxml",
    "export_png",
    "latlon_grid_spec",
]
