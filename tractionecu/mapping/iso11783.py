"""ISO 11783-10 (ISO-XML, version 4.3) exports of a map: logged data and a grid.

Logged data (:func:`export_isoxml_log`, format ``isoxml``)
    What the vehicle measured, as a task controller logs it:

    ``TASKDATA.XML``
        ``DVC`` "tractionecu" (the estimator as a device) with one ``DET``
        (type 1, device), a ``DPD`` for every DDI the log uses (trigger
        "time interval", a designator) and a ``DVP`` per layer giving offset
        0, scale, decimals and unit; one ``TSK`` with status 4 (completed)
        holding a ``TIM`` (start, stop, type 4 effective) and the ``TLG``
        ``TLG00001`` (type 1, binary), and a further ``TLG00002``, ... wherever the
        track's time runs back (a farm map's machines at the same hours), so that
        the time of every log runs forward.
    ``TLG00001.XML``
        The binary's header: ``TIM`` (A empty: start in the binary, D = 4)
        with ``PTN`` (A, B, D empty: north, east and status in the binary)
        and one ``DLV`` per DDI (B empty, C = ``DET-1``).
    ``TLG00001.BIN``
        One record per track sample (10 Hz, every position that passed the
        map's GNSS checks), little-endian: ms since midnight (uint32) and
        days since 1980-01-01 (uint16) UTC, north and east (int32,
        1e-7 deg), position status (uint8, 1 = GNSS fix: the track only holds
        positions that passed the fix check), number of DLVs (uint8), then
        per DLV its header index (uint8) and value (int32).

    DDIs:

    ========  ======  =====  ====  ===================================
    layer     DDI     scale  unit  meaning
    ========  ======  =====  ====  ===================================
    (state)   0x008D  1      n.a.  Actual Work State (standard, ISO 11783-11): 1 = sample accepted into the map
    a         0xE100  1e-4   -     μ(s) curve parameter a (proprietary)
    p         0xE101  1e-4   -     μ(s) curve parameter p (proprietary)
    alpha1    0xE102  1e-3   -     μ(s) curve parameter α1 (proprietary)
    alpha2    0xE103  1e-3   -     μ(s) curve parameter α2 (proprietary)
    rho_s     0xE104  1e-5   -     soil rolling resistance ρ_s (proprietary)
    mu        0xE105  1e-4   -     adhesion coefficient μ (proprietary)
    other     0xE110+ 1e-4   -     further layers (proprietary)
    coverage  0xE1FF  1      -     grid only: 0 no data, 1 filled, 2 measured
    ========  ======  =====  ====  ===================================

    ISO 11783-11 has no DDI for a traction or rolling-resistance
    coefficient, so the layers use the manufacturer-proprietary range
    (0xE000–0xFFFE), each declared by a DPD with a DVP.  All layers are
    dimensionless (unit designator "-").  The layer values of a sample are
    those the map stored for it (``track_values.log``); a sample that was
    not accepted carries the work state 0 and no layer value.  A map written
    before the values were logged gives a time log of positions and work
    state only.

    Time: a track time ≥ 315532800 (1980-01-01) is read as Unix time [s]
    UTC; a smaller one as seconds after the map's ``created_utc``.
Grid (:func:`export_isoxml_grid`, format ``isoxml-grid``)
    The (filled) map as a ``GRD`` of type 2 in a task of status 1 (planned),
    for terminals that take a map as a grid: ``TASKDATA.XML`` with the same
    ``DVC`` declaring the DDIs, a ``TZN`` (code 1) whose ``PDV`` are the layers
    and the coverage flag, and ``GRD00001.BIN`` (one little-endian int32 per
    PDV and cell, rows south to north, columns west to east).  Cells without
    data hold :data:`GRID_NO_DATA` (−2³¹) in every layer and coverage 0, never
    0.  The metric map is resampled (nearest cell) to a WGS84 grid of about
    the map resolution.
"""

from __future__ import annotations

import datetime as _dt
import math
import os
import struct
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .projection import meridian_radius, normal_radius
from .store import LayerGrid, MapStore
from .tiles import DirectoryLock, atomic_write_bytes, lock_directory

ISO_DDI = {"a": 0xE100, "p": 0xE101, "alpha1": 0xE102, "alpha2": 0xE103, "rho_s": 0xE104, "mu": 0xE105}
ISO_SCALE = {"a": 1e-4, "p": 1e-4, "alpha1": 1e-3, "alpha2": 1e-3, "rho_s": 1e-5, "mu": 1e-4}
ISO_DESIGNATOR = {"a": "mu(s) parameter a", "p": "mu(s) parameter p", "alpha1": "mu(s) parameter alpha1",
                  "alpha2": "mu(s) parameter alpha2", "rho_s": "soil rolling resistance",
                  "mu": "adhesion coefficient"}
ISO_UNIT = "-"
"""Unit designator of every layer: all are dimensionless."""
ISO_DDI_OTHER_START = 0xE110
ISO_DDI_COVERAGE = 0xE1FF
DDI_ACTUAL_WORK_STATE = 0x008D
"""ISO 11783-11 DDI 141, Actual Work State."""
ISO_GRID_FILENAME = "GRD00001"
GRID_NO_DATA = -2**31
"""Value of every layer in a grid cell without data."""
DET_ID = "DET-1"
DEVICE_CLIENT_NAME = "A000000000000001"
"""The device's ISO NAME (hex, most significant byte first): self-configurable,
industry group 2 (agricultural), identity number 1, all other fields 0."""
ISO_EPOCH = _dt.datetime(1980, 1, 1, tzinfo=_dt.timezone.utc)
_UNIX_1980 = 315532800.0


def iso_table(layers: Sequence[str]) -> list[tuple[str, int, float]]:
    """(layer, DDI, scale) of every layer, in order."""
    table = []
    other = ISO_DDI_OTHER_START
    for n in layers:
        if n in ISO_DDI:
            table.append((n, ISO_DDI[n], ISO_SCALE[n]))
        else:
            table.append((n, other, 1e-4))
            other += 1
    return table


def _xs_decimal(x: float) -> str:
    """``x`` as an ``xs:decimal`` (the type of DVP and VPN's scale ``C``): no exponent (``repr`` gives
    ``1e-05`` for ρ_s's scale, which a terminal validating against the ISO 11783-10 schema refuses)."""
    from decimal import Decimal

    text = format(Decimal(repr(float(x))), "f")
    return text.rstrip("0").rstrip(".") if "." in text else text


def _decimals(scale: float) -> int:
    return max(0, int(round(-math.log10(scale))))


def _root() -> ET.Element:
    return ET.Element("ISO11783_TaskData", {
        "VersionMajor": "4", "VersionMinor": "3",
        "ManagementSoftwareManufacturer": "tractionecu", "ManagementSoftwareVersion": _version(),
        "DataTransferOrigin": "2",
    })


def _device(root: ET.Element, entries: Sequence[tuple[int, str, float | None, str]]) -> None:
    """DVC with one DET referring to a DPD per (DDI, designator, scale or None, unit)."""
    dvc = ET.SubElement(root, "DVC", {"A": "DVC-1", "B": "tractionecu", "C": _version()[:32],
                                      "D": DEVICE_CLIENT_NAME, "E": "1",
                                      "F": "54454355303031", "G": "FF00000000656E"})
    det = ET.SubElement(dvc, "DET", {"A": DET_ID, "B": "1", "C": "1", "D": "ground estimator", "E": "0",
                                     "F": "0"})
    dvps = []
    for k, (ddi, designator, scale, unit) in enumerate(entries):
        attrs = {"A": str(10 + k), "B": f"{ddi:04X}", "C": "1", "D": "1", "E": designator[:32]}
        if scale is not None:
            attrs["F"] = str(100 + k)
            dvps.append({"A": str(100 + k), "B": "0", "C": _xs_decimal(scale), "D": str(_decimals(scale)),
                         "E": unit})
        ET.SubElement(det, "DOR", {"A": str(10 + k)})
        ET.SubElement(dvc, "DPD", attrs)
    for attrs in dvps:
        ET.SubElement(dvc, "DVP", attrs)


def _layer_entries(table: Sequence[tuple[str, int, float]]) -> list[tuple[int, str, float | None, str]]:
    return [(ddi, ISO_DESIGNATOR.get(n, n), scale, ISO_UNIT) for n, ddi, scale in table]


def _xml_bytes(root: ET.Element) -> bytes:
    ET.indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8") + b"\n"


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("tractionecu")
    except Exception:
        return "0.1.0"


def _quantise(v: NDArray[np.float64], scale: float) -> NDArray[np.int64]:
    """Raw int32 values of ``v`` (0 where ``v`` is NaN: callers leave those out)."""
    q = np.clip(np.rint(np.where(np.isfinite(v), v, 0.0) / scale), -2**31 + 1, 2**31 - 1)
    return q.astype(np.int64)


EXPORT_LOCK_WAIT_S = 30.0
"""How long an export waits for another one writing into the same TASKDATA directory [s]."""


def _export_lock(out: Path) -> DirectoryLock:
    """The TASKDATA directory's lock while its files are written: two exports into one directory (the default
    ``DIR/export/TASKDATA`` of one map) interleaved their files, and one's TASKDATA.XML named time logs of the
    length of the other's, or one the other had removed as an earlier export's."""
    return lock_directory(out, "another export is writing into this directory", wait_s=EXPORT_LOCK_WAIT_S)


# ------------------------------------------------------------------ logged data
def track_utc(store: MapStore, t: NDArray[np.float64]) -> NDArray[np.float64]:
    """Track times [s] as Unix time UTC (see the module docstring)."""
    t = np.asarray(t, dtype=np.float64)
    if t.size and float(np.nanmin(t)) >= _UNIX_1980:
        return t
    created = _dt.datetime.fromisoformat(str(store.manifest["created_utc"]))
    if created.tzinfo is None:
        created = created.replace(tzinfo=_dt.timezone.utc)
    return t + created.timestamp()


def _sample_values(store: MapStore, track: NDArray[np.float64], names: Sequence[str]) -> NDArray[np.float64]:
    """(N, len(names)) values the map stored for each track sample (NaN: none)."""
    out = np.full((len(track), len(names)), np.nan)
    vals = store.track_values()
    if not len(vals) or not len(track):
        return out
    cols = [1 + store.layers.index(n) for n in names]
    acc = np.flatnonzero(track[:, 3] != 0)
    if acc.size == len(vals) and np.array_equal(track[acc, 0], vals[:, 0]):
        # the values log holds one row per accepted track sample, in the same order (a farm map's logs are
        # its inputs' logs one after the other): matched by position.  Matched by time alone, two machines
        # working at the same clock times took each other's values (12 of 900 'a' values right).
        out[acc] = vals[:, cols]
        return out
    row_of = {float(t): k for k, t in enumerate(vals[:, 0])}   # a log the position cannot match (repaired)
    for i in acc:
        k = row_of.get(float(track[i, 0]))
        if k is not None:
            out[i] = vals[k, cols]
    return out


def export_isoxml_log(store: MapStore, out_dir: os.PathLike[str] | str, names: Sequence[str], *,
                      task_name: str = "Ground condition log") -> Path:
    """Write ``TASKDATA.XML``, ``TLG00001.XML`` and ``TLG00001.BIN`` (logged data,
    see the module docstring) for ``names`` into ``out_dir``; returns ``TASKDATA.XML``."""
    track = store.track()
    if not len(track):
        raise ValueError(f"{store.directory}: the map has no track to log")
    table = iso_table(names)
    values = _sample_values(store, track, names)
    utc = track_utc(store, track[:, 0])
    lat, lon = store.to_latlon(track[:, 1], track[:, 2])
    days = np.floor((utc - _UNIX_1980) / 86400.0)
    ms = np.rint((utc - _UNIX_1980 - days * 86400.0) * 1000.0)
    wrap = ms >= 86_400_000
    days[wrap] += 1
    ms[wrap] -= 86_400_000
    north = np.rint(np.asarray(lat) * 1e7).astype(np.int64)
    east = np.rint(np.asarray(lon) * 1e7).astype(np.int64)
    quant = [_quantise(values[:, k], scale) for k, (_, _, scale) in enumerate(table)]
    head = struct.Struct("<IHiiBB")
    dlv = struct.Struct("<Bi")
    # one time log per stretch whose time runs forward: a farm map's track is its machines' tracks one after
    # the other, and a time log whose time runs back (two machines at the same hours) is not a time log
    cuts = np.flatnonzero(np.diff(utc) < 0.0) + 1
    bufs = []
    for seg in np.split(np.arange(len(track)), cuts):
        buf = bytearray()
        for i in seg:
            ok = [k for k in range(len(table)) if np.isfinite(values[i, k])]
            buf += head.pack(int(ms[i]), int(days[i]), int(north[i]), int(east[i]), 1, 1 + len(ok))
            buf += dlv.pack(0, 1 if track[i, 3] else 0)
            for k in ok:
                buf += dlv.pack(1 + k, int(quant[k][i]))
        bufs.append(bytes(buf))

    tim = ET.Element("TIM", {"A": "", "D": "4"})
    ET.SubElement(tim, "PTN", {"A": "", "B": "", "D": ""})
    ET.SubElement(tim, "DLV", {"A": f"{DDI_ACTUAL_WORK_STATE:04X}", "B": "", "C": DET_ID})
    for _, ddi, _ in table:
        ET.SubElement(tim, "DLV", {"A": f"{ddi:04X}", "B": "", "C": DET_ID})

    def stamp(u: float) -> str:
        return _dt.datetime.fromtimestamp(u, _dt.timezone.utc).replace(tzinfo=None).isoformat(timespec="milliseconds")

    root = _root()
    _device(root, [(DDI_ACTUAL_WORK_STATE, "work state (mapped)", None, "")] + _layer_entries(table))
    tsk = ET.SubElement(root, "TSK", {"A": "TSK1", "B": task_name, "G": "4"})
    ET.SubElement(tsk, "TIM", {"A": stamp(float(np.min(utc))), "B": stamp(float(np.max(utc))), "D": "4"})
    logs = [f"TLG{k:05d}" for k in range(1, len(bufs) + 1)]          # TLG00001, TLG00002, ...
    for name, buf in zip(logs, bufs):
        ET.SubElement(tsk, "TLG", {"A": name, "B": str(len(buf)), "C": "1"})

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with _export_lock(out):
        for name, buf in zip(logs, bufs):
            atomic_write_bytes(out / f"{name}.BIN", buf)
            atomic_write_bytes(out / f"{name}.XML", _xml_bytes(tim))
        atomic_write_bytes(out / "TASKDATA.XML", _xml_bytes(root))
        for f in out.glob("TLG[0-9][0-9][0-9][0-9][0-9].*"):      # an earlier export's further time logs
            if f.stem not in logs and f.suffix in (".BIN", ".XML"):
                f.unlink(missing_ok=True)
    return out / "TASKDATA.XML"


# ------------------------------------------------------------------ grid
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
    if float(lon.max()) - float(lon.min()) > 180.0:
        # a field across the 180th meridian: the ISO 11783-10 grid runs east from its minimum east position in
        # −180…180°, so it would span the globe (a Fiji field asked for 153 GiB)
        raise ValueError("the map crosses the 180th meridian: an ISO 11783-10 grid cannot hold it (GRD runs east "
                         "from a minimum east position in -180..180 deg); export it as geotiff in its UTM frame")
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


def export_isoxml_grid(store: MapStore, grids: Mapping[str, LayerGrid], out_dir: os.PathLike[str] | str,
                       names: Sequence[str], *, task_name: str = "Ground condition map") -> Path:
    """Write ``TASKDATA.XML`` + ``GRD00001.BIN`` (grid type 2, see the module
    docstring) of ``grids`` into ``out_dir``; returns ``TASKDATA.XML``."""
    ref = grids[names[0]]
    finite = np.zeros(ref.shape, dtype=bool)
    for g in grids.values():
        finite |= np.isfinite(g.mean)
    if not finite.any():
        raise ValueError(f"{store.directory}: the map holds no data")
    spec = latlon_grid_spec(store, ref, finite)
    row, col, inside = _sample_nearest(store, ref, spec)
    table = iso_table(names)
    cells = np.zeros((spec["rows"], spec["cols"], len(table) + 1), dtype="<i4")
    has_any = np.zeros((spec["rows"], spec["cols"]), dtype=bool)
    measured = np.zeros_like(has_any)
    for k, (n, _, scale) in enumerate(table):
        g = grids[n]
        v = np.where(inside, g.mean[row, col], np.nan)
        ok = np.isfinite(v)
        q = np.full(v.shape, GRID_NO_DATA, dtype=np.int64)
        q[ok] = _quantise(v[ok], scale)
        cells[:, :, k] = q.astype("<i4")
        has_any |= ok
        measured |= inside & (g.count[row, col] > 0)
    cells[:, :, -1] = np.where(measured, 2, np.where(has_any, 1, 0))
    payload = cells.tobytes(order="C")

    root = _root()
    _device(root, _layer_entries(table) + [(ISO_DDI_COVERAGE, "coverage 0 none 1 filled 2 measured", 1.0, "")])
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
        ET.SubElement(root, "VPN", {"A": f"VPN{k}", "B": "0", "C": _xs_decimal(scale), "D": str(_decimals(scale)),
                                    "E": ISO_UNIT})
    ET.SubElement(root, "VPN", {"A": f"VPN{len(table) + 1}", "B": "0", "C": "1.0", "D": "0", "E": ""})

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with _export_lock(out):
        atomic_write_bytes(out / f"{ISO_GRID_FILENAME}.BIN", payload)
        atomic_write_bytes(out / "TASKDATA.XML", _xml_bytes(root))
    return out / "TASKDATA.XML"


__all__ = [
    "DDI_ACTUAL_WORK_STATE",
    "GRID_NO_DATA",
    "ISO_DDI",
    "ISO_DDI_COVERAGE",
    "ISO_SCALE",
    "export_isoxml_grid",
    "export_isoxml_log",
    "iso_table",
    "latlon_grid_spec",
    "track_utc",
]
