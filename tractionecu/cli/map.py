"""``tractionecu map`` — export and inspect ground-condition maps.

::

    tractionecu map export DIR --format geotiff|isoxml|isoxml-grid|png|geojson [--out PATH]
                               [--layers a,rho_s] [--raw] [--soil-classes NAME=A,...]
    tractionecu map info DIR

``DIR`` is a map directory (holding ``manifest.json``) or a replay output
directory holding ``map/``.  Default ``--out``: ``DIR/export/map.tif``,
``DIR/export/TASKDATA/`` (ISO 11783-10 logged data: task, device
description, binary time log), ``DIR/export/TASKDATA_GRID/`` (ISO 11783-10
grid), ``DIR/export/map.png``,
``DIR/export/map.geojson``.

Exit codes: 0 ok, 1 the map cannot be read or holds no data, 2 bad
arguments, 3 an optional dependency is missing (``pip install
'tractionecu[maps]'``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

EXIT_OK = 0
EXIT_MAP = 1
EXIT_USAGE = 2
EXIT_MISSING_EXTRA = 3

FORMATS = ("geotiff", "isoxml", "isoxml-grid", "png", "geojson")


def add_subparser(subparsers: Any) -> argparse.ArgumentParser:
    """Register ``map`` (with ``export`` and ``info``) on an argparse subparsers object."""
    p = subparsers.add_parser("map", help="export or inspect a ground-condition map",
                              description="Export or inspect a ground-condition map.")
    sub = p.add_subparsers(dest="map_command", metavar="{export,info}")
    sub.required = True
    e = sub.add_parser("export", help="write the map as GeoTIFF, ISO-XML, PNG or GeoJSON",
                       description="Write the map as GeoTIFF, ISO 11783-10 TASKDATA (isoxml: logged "
                                   "data with a time log; isoxml-grid: the map as a grid), PNG or GeoJSON.")
    e.add_argument("dir", type=Path, help="map directory or replay output directory")
    e.add_argument("--format", required=True, choices=FORMATS, dest="fmt", help="output format")
    e.add_argument("--out", type=Path, default=None,
                   help="output file (directory for isoxml, isoxml-grid; an existing directory for the other "
                        "formats gets map.tif, map.png or map.geojson inside); default DIR/export/...")
    e.add_argument("--layers", default=None,
                   help="comma-separated layers (geotiff, isoxml, isoxml-grid; png: the first one); "
                        "default all with data / a")
    e.add_argument("--raw", action="store_true", help="export the cell means without the fill (geotiff, isoxml-grid)")
    e.add_argument("--soil-classes", default=None,
                   help="NAME=A,... typical a per soil for classification (png, geojson); "
                        "default: from the manifest, else 3 natural classes")
    e.add_argument("--cells", action="store_true", help="geojson: also one point per measured cell")
    e.set_defaults(func=run)
    i = sub.add_parser("info", help="print manifest and statistics of a map")
    i.add_argument("dir", type=Path, help="map directory or replay output directory")
    i.set_defaults(func=run)
    p.set_defaults(func=run)
    return p


def _parse_classes(text: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        name, sep, val = part.rpartition("=")
        if not sep or not name:
            raise ValueError(f"--soil-classes: expected NAME=A, got {part!r}")
        try:
            a = float(val)
        except ValueError:
            raise ValueError(f"--soil-classes: class {name.strip()!r}: its a is not a number: {val.strip()!r}") from None
        if not math.isfinite(a):
            raise ValueError(f"--soil-classes: class {name.strip()!r}: its a must be finite, got {val.strip()!r}")
        out[name.strip()] = a
    if not out:
        raise ValueError("--soil-classes: no classes given")
    return out


def _default_out(directory: Path, fmt: str) -> Path:
    from tractionecu.mapping.export import DEFAULT_OUT

    return directory / "export" / DEFAULT_OUT[fmt]


def run(args: argparse.Namespace) -> int:
    """Handler for ``tractionecu map ...``; returns the exit code."""
    from tractionecu.errors import TractionEcuError
    from tractionecu.mapping.export import MissingExtraError, export
    from tractionecu.mapping.store import open_store

    cmd = getattr(args, "map_command", None)
    try:
        store = open_store(args.dir)
    except (TractionEcuError, OSError) as e:
        print(f"tractionecu map: {e}", file=sys.stderr)
        return EXIT_MAP
    if cmd == "info":
        info: dict[str, Any] = dict(store.manifest)
        info["directory"] = str(store.directory)
        info["tiles"] = len(store.tile_keys())
        ext = store.extent()
        info["extent_cells"] = None if ext is None else {"col0": ext[0], "row0": ext[1], "cols": ext[2],
                                                          "rows": ext[3]}
        info["track_points"] = int(len(store.track()))
        info["corrupt_tiles"] = [{"path": str(p), "reason": r} for p, r in store.corrupt_tiles]
        print(json.dumps(info, indent=2, sort_keys=True))
        return EXIT_OK
    if cmd != "export":
        print("tractionecu map: choose a command: export, info", file=sys.stderr)
        return EXIT_USAGE

    kwargs: dict[str, Any] = {}
    layers = [s.strip() for s in args.layers.split(",") if s.strip()] if args.layers is not None else None
    if layers is not None and not layers:
        print(f"tractionecu map export: --layers {args.layers!r}: no layer named", file=sys.stderr)
        return EXIT_USAGE
    try:
        if args.fmt in ("geotiff", "isoxml-grid"):
            kwargs["layers"] = layers
            kwargs["filled"] = not args.raw
        elif args.fmt == "isoxml":
            kwargs["layers"] = layers
        elif args.fmt == "png":
            if layers:
                kwargs["layer"] = layers[0]
        if args.soil_classes and args.fmt in ("png", "geojson"):
            kwargs["soil_classes"] = _parse_classes(args.soil_classes)
        if args.fmt == "geojson":
            kwargs["include_cells"] = bool(args.cells)
    except ValueError as e:
        print(f"tractionecu map export: {e}", file=sys.stderr)
        return EXIT_USAGE
    out = args.out if args.out is not None else _default_out(Path(args.dir), args.fmt)
    if args.fmt in ("geotiff", "png", "geojson") and Path(out).is_dir():   # a file format into a directory:
        from tractionecu.mapping.export import DEFAULT_OUT                 # its default name there

        out = Path(out) / DEFAULT_OUT[args.fmt]
    try:
        path = export(store, args.fmt, out, **kwargs)
    except MissingExtraError as e:
        print(f"tractionecu map export: {e}", file=sys.stderr)
        return EXIT_MISSING_EXTRA
    except KeyError as e:
        print(f"tractionecu map export: {e.args[0] if e.args else e}", file=sys.stderr)
        return EXIT_USAGE
    except (TractionEcuError, OSError, ValueError) as e:
        print(f"tractionecu map export: {e}", file=sys.stderr)
        return EXIT_MAP
    except MemoryError:
        # the raster formats are one grid over the map's whole extent: fields kilometres apart make it large
        ext = store.extent()
        size = f"{ext[2]} × {ext[3]} cells of {store.resolution_m:g} m" if ext else "its extent"
        print(f"tractionecu map export: not enough memory for one {args.fmt} grid over the map's whole extent "
              f"({size}); export the fields apart (a map directory per field) or as geojson", file=sys.stderr)
        return EXIT_MAP
    for p, reason in store.corrupt_tiles:
        print(f"tractionecu map export: warning: skipped corrupt tile {p} ({reason})", file=sys.stderr)
    print(path)
    return EXIT_OK


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry (``python -m tractionecu.cli.map export ...``)."""
    parser = argparse.ArgumentParser(prog="tractionecu")
    sub = parser.add_subparsers(dest="command")
    add_subparser(sub)
    args = parser.parse_args(["map", *(sys.argv[1:] if argv is None else argv)])
    return int(args.func(args))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
