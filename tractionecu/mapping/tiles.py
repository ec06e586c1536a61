"""On-disk map format: manifest, fixed-size tiles, atomic writes.

Directory layout
----------------
::

    DIR/manifest.json          map metadata (below), written atomically
    DIR/tiles/t<TX>_<TY>.tile  one file per tile, TX/TY signed integers
    DIR/track.log              vehicle track, append-only records (below)
    DIR/track_values.log       layer values of the accepted samples (mapping/track.py)
    DIR/.lock                  advisory lock held by the single writer

``manifest.json`` keys: ``format`` ("tractionecu-map"), ``version`` (1),
``origin_lat``/``origin_lon`` [deg WGS84], ``crs`` ("EPSG:326zz"/"EPSG:327zz"),
``utm_zone``, ``utm_south``, ``origin_easting_m``/``origin_northing_m`` (UTM
of the origin), ``resolution_m`` (cell size), ``tile_cells`` (cells per tile
side), ``layers`` (list of names), ``soil_classes`` ({name: typical a} or
null), ``created_utc``.  The local frame is x = E − origin_easting_m,
y = N − origin_northing_m.  Cell (col, row) = (floor(x/res), floor(y/res)),
tile (TX, TY) = (col div tile_cells, row div tile_cells) (floor division),
local index (col mod tile_cells, row mod tile_cells).

Tile file, version 1 (all integers little-endian)
-------------------------------------------------
======  ========  ==========================================================
offset  size      content
======  ========  ==========================================================
0       8         magic ``b"TECUTILE"``
8       2         format version (uint16) = 1
10      2         reserved (0)
12      4         header length H (uint32)
16      H         header, UTF-8 JSON: ``tx``, ``ty``, ``tile_cells`` n,
                  ``layers`` (list, L entries), ``encoding`` ("zlib" or
                  "raw"), ``raw_bytes``, ``arrays`` = [["count","<u4"],
                  ["mean","<f8"],["m2","<f8"]]
16+H    P         payload: the three arrays, each shaped (L, n, n) in C order
                  ([layer, row, col], row northwards), concatenated
                  count‖mean‖m2 and zlib-compressed when encoding="zlib"
16+H+P  4         CRC-32 (zlib/ISO-HDLC polynomial) of bytes [0, 16+H+P)
======  ========  ==========================================================

``count`` is the number of samples, ``mean`` the running mean and ``m2`` the
sum of squared deviations (variance = m2 / (count − 1)).

Atomicity
---------
Every tile and the manifest are written to a temporary file in the same
directory (``.<name>.tmp.<pid>.<n>``), flushed, fsync'ed, renamed over the
final name with :func:`os.replace` and the directory is fsync'ed.  A reader
therefore sees either the old or the new complete file, never a mixture.
Leftover temporaries from a crash are removed by the next writer.

``track.log`` is append-only: fixed 29-byte records ``<d d d B`` (t [s],
x [m], y [m], flags bit0 = sample accepted into the map) followed by the
record's CRC-32 (uint32).  A torn last record is detected by its CRC and cut
off when the next writer opens the map.
"""

from __future__ import annotations

import errno
import itertools
import json
import os
import re
import struct
import time
import zlib
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tractionecu.errors import TractionEcuError

from .grid import COUNT_DTYPE, VALUE_DTYPE, TileStats

MAGIC = b"TECUTILE"
TILE_VERSION = 1
MANIFEST_NAME = "manifest.json"
TILES_DIRNAME = "tiles"
TRACK_NAME = "track.log"
LOCK_NAME = ".lock"
MANIFEST_FORMAT = "tractionecu-map"
MANIFEST_VERSION = 1

_PREFIX = struct.Struct("<8sHHI")
_CRC = struct.Struct("<I")
_TRACK_REC = struct.Struct("<dddB")
TRACK_RECORD_SIZE = _TRACK_REC.size + _CRC.size
_TILE_RE = re.compile(r"^t(-?\d+)_(-?\d+)\.tile$")
_TMP_RE = re.compile(r"^\..+\.tmp\.\d+\.\d+$")
_counter = itertools.count()


class MapStoreError(TractionEcuError, OSError):
    """The map directory cannot be used (missing manifest, locked, write failed)."""


class CorruptTileError(TractionEcuError, ValueError):
    """A tile file fails its structure or checksum check.  ``path`` names it."""

    def __init__(self, path: os.PathLike[str] | str, reason: str) -> None:
        super().__init__(f"corrupt map tile {os.fspath(path)}: {reason}")
        self.path = Path(path)
        self.reason = reason


def tile_filename(tx: int, ty: int) -> str:
    return f"t{int(tx)}_{int(ty)}.tile"


def parse_tile_filename(name: str) -> tuple[int, int] | None:
    m = _TILE_RE.match(name)
    return (int(m.group(1)), int(m.group(2))) if m else None


def iter_tile_files(directory: Path) -> Iterator[tuple[tuple[int, int], Path]]:
    """(tile key, path) of every tile file under ``directory/tiles``."""
    tdir = Path(directory) / TILES_DIRNAME
    if not tdir.is_dir():
        return
    for entry in sorted(os.scandir(tdir), key=lambda e: e.name):
        key = parse_tile_filename(entry.name)
        if key is not None and entry.is_file():
            yield key, Path(entry.path)


# ---------------------------------------------------------------- atomic I/O
DISK_FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})
"""Write errors of a disk that is full (or a quota or file size limit reached): passing, not a configuration error."""


def fsync_dir(directory: os.PathLike[str] | str) -> None:
    """fsync a directory so that a rename in it is durable (no-op where unsupported)."""
    try:
        fd = os.open(os.fspath(directory), os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write_bytes(path: os.PathLike[str] | str, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically: temp file, fsync, rename, fsync dir."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp.{os.getpid()}.{next(_counter)}")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    fsync_dir(path.parent)


class DirectoryLock:
    """The advisory exclusive lock of a directory (flock on the directory itself: no file is left in it), taken
    without waiting by :func:`lock_directory`; :meth:`close` releases it.  A replay's output directory and the
    service's state directory each take one (a map has its own, ``.lock``, beside its tiles)."""

    def __init__(self, directory: os.PathLike[str] | str, busy: str, wait_s: float = 0.0) -> None:
        self.directory = Path(directory)
        self._fd: int | None = os.open(self.directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
        try:
            import fcntl
        except ImportError:  # pragma: no cover - non-POSIX
            return
        deadline = time.monotonic() + wait_s
        while True:
            try:
                fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                return
            except OSError:
                if time.monotonic() >= deadline:
                    self.close()
                    raise MapStoreError(f"{directory}: {busy}") from None
            time.sleep(0.05)

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> DirectoryLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def lock_directory(directory: os.PathLike[str] | str, busy: str, wait_s: float = 0.0) -> DirectoryLock:
    """Take the lock of ``directory`` (:class:`DirectoryLock`), waiting up to ``wait_s`` [s] for another holder
    to release it; :class:`MapStoreError` "``directory``: ``busy``" when another process still holds it."""
    return DirectoryLock(directory, busy, wait_s)


def remove_stray_temporaries(directory: Path) -> list[Path]:
    """Delete temp files left by an interrupted write; returns what was removed."""
    removed = []
    for d in (Path(directory), Path(directory) / TILES_DIRNAME):
        if not d.is_dir():
            continue
        for entry in os.scandir(d):
            if _TMP_RE.match(entry.name) and entry.is_file():
                try:
                    os.unlink(entry.path)
                    removed.append(Path(entry.path))
                except OSError:
                    pass
    return removed


# ---------------------------------------------------------------- tiles
def encode_tile(tx: int, ty: int, stats: TileStats, *, compress: bool = True) -> bytes:
    """Serialise one tile to the version-1 byte format."""
    raw = b"".join((np.ascontiguousarray(stats.count, COUNT_DTYPE).tobytes(),
                    np.ascontiguousarray(stats.mean, VALUE_DTYPE).tobytes(),
                    np.ascontiguousarray(stats.m2, VALUE_DTYPE).tobytes()))
    payload = zlib.compress(raw, 1) if compress else raw
    header = json.dumps({
        "tx": int(tx), "ty": int(ty), "tile_cells": stats.cells, "layers": list(stats.layers),
        "encoding": "zlib" if compress else "raw", "raw_bytes": len(raw),
        "arrays": [["count", COUNT_DTYPE.str], ["mean", VALUE_DTYPE.str], ["m2", VALUE_DTYPE.str]],
    }, separators=(",", ":")).encode("utf-8")
    body = _PREFIX.pack(MAGIC, TILE_VERSION, 0, len(header)) + header + payload
    return body + _CRC.pack(zlib.crc32(body) & 0xFFFFFFFF)


def decode_tile(data: bytes, path: os.PathLike[str] | str = "<bytes>") -> tuple[int, int, TileStats]:
    """Parse and verify a tile; raises :class:`CorruptTileError` on any defect."""
    if len(data) < _PREFIX.size + _CRC.size:
        raise CorruptTileError(path, f"truncated ({len(data)} bytes)")
    body, (crc,) = data[:-_CRC.size], _CRC.unpack(data[-_CRC.size:])
    if zlib.crc32(body) & 0xFFFFFFFF != crc:
        raise CorruptTileError(path, "CRC-32 mismatch")
    magic, version, _, hlen = _PREFIX.unpack_from(body)
    if magic != MAGIC:
        raise CorruptTileError(path, "bad magic")
    if version != TILE_VERSION:
        raise CorruptTileError(path, f"unsupported tile version {version}")
    try:
        header = json.loads(body[_PREFIX.size:_PREFIX.size + hlen].decode("utf-8"))
        tx, ty, n = int(header["tx"]), int(header["ty"]), int(header["tile_cells"])
        layers = [str(x) for x in header["layers"]]
        encoding = header["encoding"]
        raw_bytes = int(header["raw_bytes"])
    except (ValueError, KeyError, TypeError, UnicodeDecodeError) as e:
        raise CorruptTileError(path, f"bad header ({e})") from None
    payload = body[_PREFIX.size + hlen:]
    if encoding == "zlib":
        try:
            raw = zlib.decompress(payload)
        except zlib.error as e:
            raise CorruptTileError(path, f"payload does not decompress ({e})") from None
    elif encoding == "raw":
        raw = payload
    else:
        raise CorruptTileError(path, f"unknown encoding {encoding!r}")
    cells = len(layers) * n * n
    expect = cells * (COUNT_DTYPE.itemsize + 2 * VALUE_DTYPE.itemsize)
    if len(raw) != raw_bytes or len(raw) != expect:
        raise CorruptTileError(path, f"payload has {len(raw)} bytes, expected {expect}")
    shape = (len(layers), n, n)
    o1 = cells * COUNT_DTYPE.itemsize
    o2 = o1 + cells * VALUE_DTYPE.itemsize
    count = np.frombuffer(raw, COUNT_DTYPE, cells, 0).reshape(shape).copy()
    mean = np.frombuffer(raw, VALUE_DTYPE, cells, o1).reshape(shape).copy()
    m2 = np.frombuffer(raw, VALUE_DTYPE, cells, o2).reshape(shape).copy()
    return tx, ty, TileStats(layers, n, count, mean, m2)


def write_tile(directory: Path, tx: int, ty: int, stats: TileStats) -> Path:
    """Atomically write one tile under ``directory/tiles``; returns its path."""
    tdir = Path(directory) / TILES_DIRNAME
    path = tdir / tile_filename(tx, ty)
    atomic_write_bytes(path, encode_tile(tx, ty, stats))
    return path


def read_tile(path: os.PathLike[str] | str) -> tuple[int, int, TileStats]:
    """Read and verify one tile file (:class:`CorruptTileError` if damaged)."""
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise CorruptTileError(path, f"unreadable ({e})") from None
    return decode_tile(data, path)


# ---------------------------------------------------------------- manifest
def write_manifest(directory: Path, manifest: dict[str, Any]) -> None:
    atomic_write_bytes(Path(directory) / MANIFEST_NAME,
                       (json.dumps(manifest, indent=2, sort_keys=True) + "\n").encode("utf-8"))


def read_manifest(directory: Path) -> dict[str, Any]:
    path = Path(directory) / MANIFEST_NAME
    try:
        m = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise MapStoreError(f"{path}: no map manifest") from None
    except (OSError, ValueError) as e:
        raise MapStoreError(f"{path}: unreadable map manifest ({e})") from None
    if not isinstance(m, dict) or m.get("format") != MANIFEST_FORMAT:
        raise MapStoreError(f"{path}: not a {MANIFEST_FORMAT} manifest")
    if int(m.get("version", 0)) > MANIFEST_VERSION:
        raise MapStoreError(f"{path}: manifest version {m.get('version')} is newer than supported")
    return m


# ---------------------------------------------------------------- track log
def encode_track_records(records: Sequence[tuple[float, float, float, int]]) -> bytes:
    out = bytearray()
    for t, x, y, flags in records:
        rec = _TRACK_REC.pack(t, x, y, flags)
        out += rec
        out += _CRC.pack(zlib.crc32(rec) & 0xFFFFFFFF)
    return bytes(out)


def read_track(path: os.PathLike[str] | str) -> tuple[np.ndarray, int]:
    """Read ``track.log``: returns (records as an (N, 4) float array t, x, y, flags;
    byte length of the valid prefix).  Reading stops at the first bad record."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        return np.zeros((0, 4)), 0
    rows = []
    n = len(data) // TRACK_RECORD_SIZE
    good = 0
    for k in range(n):
        off = k * TRACK_RECORD_SIZE
        rec = data[off:off + _TRACK_REC.size]
        (crc,) = _CRC.unpack_from(data, off + _TRACK_REC.size)
        if zlib.crc32(rec) & 0xFFFFFFFF != crc:
            break
        rows.append(_TRACK_REC.unpack(rec))
        good = off + TRACK_RECORD_SIZE
    arr = np.array(rows, dtype=np.float64).reshape(-1, 4)
    return arr, good


__all__ = [
    "CorruptTileError",
    "DirectoryLock",
    "MapStoreError",
    "atomic_write_bytes",
    "decode_tile",
    "encode_tile",
    "iter_tile_files",
    "lock_directory",
    "read_manifest",
    "read_tile",
    "read_track",
    "remove_stray_temporaries",
    "write_manifest",
    "write_tile",
]
