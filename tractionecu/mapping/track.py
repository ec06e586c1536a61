"""The map's track log: every sample position that passed the GNSS checks.

Records (t [s], x [m], y [m], accepted flag) wait in memory until the next
flush appends them to ``track.log`` (record format in
:mod:`~tractionecu.mapping.tiles`).  While the disk refuses them they stay
in memory, in order, up to ``max_pending`` records; beyond that the oldest
tenth is dropped and counted as ``stats["track_dropped"]``.

The layer values of every sample accepted into the map go beside it, to
``track_values.log`` (:data:`VALUES_NAME`), so that the ISO 11783-10 time log
can carry the values the map stored.  Record: t [s] (``<d``), one ``<d`` per
map layer in manifest order (NaN where the sample had no value for a layer),
CRC-32 (``<I``) of those bytes.  A value record's t equals the t of its
accepted track record.  Maps written before this file existed have none; the
track itself is unchanged, so older readers are not affected.

:class:`~tractionecu.mapping.store.MapStore` owns one :class:`TrackLog`,
shares its lock with it and holds that lock around every call except
:meth:`TrackLog.write` (the disk write, which runs outside it) and
:meth:`TrackLog.read` (which takes it only to copy the pending records).
"""

from __future__ import annotations

import array
import logging
import os
import struct
import threading
import zlib
from collections import Counter
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .tiles import TRACK_RECORD_SIZE, atomic_write_bytes, encode_track_records, read_track

log = logging.getLogger(__name__)

VALUES_NAME = "track_values.log"
_CRC = struct.Struct("<I")


def read_values(path: Path, n_layers: int) -> tuple[NDArray[np.float64], int]:
    """Read ``track_values.log``: (N, 1 + n_layers) array of t and layer values;
    byte length of the valid prefix.  Reading stops at the first bad record."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        return np.zeros((0, 1 + n_layers)), 0
    size = 8 * (1 + n_layers)
    n = len(data) // (size + 4)
    if n == 0:
        return np.zeros((0, 1 + n_layers)), 0
    rec = np.frombuffer(data, dtype=np.uint8, count=n * (size + 4)).reshape(n, size + 4)
    good = n
    for k in range(n):
        if zlib.crc32(rec[k, :size].tobytes()) & 0xFFFFFFFF != _CRC.unpack(rec[k, size:].tobytes())[0]:
            good = k
            break
    arr = np.frombuffer(rec[:good, :size].tobytes(), dtype="<f8").reshape(good, 1 + n_layers)
    return arr.astype(np.float64), good * (size + 4)


def _encode_values(records: array.array, width: int) -> bytes:
    out = bytearray()
    raw = memoryview(records.tobytes())
    size = 8 * width
    for off in range(0, len(raw), size):
        rec = raw[off:off + size]
        out += rec
        out += _CRC.pack(zlib.crc32(rec) & 0xFFFFFFFF)
    return bytes(out)


def _append(path: Path, data: bytes) -> None:
    """Append ``data`` to ``path`` and fsync; on failure (a full disk takes part of a block) the file is cut
    back to its size before, so that the records :meth:`TrackLog.put_back` appends again later follow whole
    records and no torn fragment is left inside the file."""
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        start = os.lseek(fd, 0, os.SEEK_END)
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
            os.fsync(fd)
        except OSError:
            try:
                os.ftruncate(fd, start)
                os.fsync(fd)
            except OSError:                              # pragma: no cover - repair() still skips the fragment
                pass
            raise
    finally:
        os.close(fd)


def resync_records(data: bytes, rec_size: int) -> bytes:
    """The whole records of a log of fixed-size records each ending in the CRC-32 of the bytes before it:
    read in order; at a record whose CRC fails, the reading moves on byte by byte to the next whole one."""
    out = bytearray()
    pos, n, body = 0, len(data), rec_size - 4
    while pos + rec_size <= n:
        rec = data[pos:pos + body]
        if zlib.crc32(rec) & 0xFFFFFFFF == _CRC.unpack_from(data, pos + body)[0]:
            out += data[pos:pos + rec_size]
            pos += rec_size
        else:
            pos += 1
    return bytes(out)


class TrackLog:
    """Pending track records of one map and its ``track.log`` file."""

    def __init__(self, path: Path, max_pending: int, stats: Counter, lock: threading.Lock,
                 n_layers: int = 0) -> None:
        self.path = path
        self.values_path = path.with_name(VALUES_NAME)
        self.n_layers = int(n_layers)
        self._pending_values = array.array("d")
        """Values of accepted samples not yet written, flat: t, one value per layer, ..."""
        self.max_pending = max(1, int(max_pending))
        self.stats = stats
        self._lock = lock
        self._pending = array.array("d")
        """Records not yet written, flat: t [s], x [m], y [m], accepted flag (0/1), ..."""

    def repair(self) -> None:
        """Cut a torn last record off the files (a crash during an append); a torn record inside a file (a
        disk that filled during an append, before appends were cut back on failure) is skipped and every whole
        record after it kept (:func:`resync_records`)."""
        for path, good, rec_size in ((self.path, lambda: read_track(self.path)[1], TRACK_RECORD_SIZE),
                                     (self.values_path, lambda: read_values(self.values_path, self.n_layers)[1],
                                      8 * (1 + self.n_layers) + 4)):
            if not path.exists():
                continue
            size = path.stat().st_size
            keep = good()
            if keep == size:
                continue
            data = path.read_bytes()
            whole = resync_records(data, rec_size)
            if len(whole) > keep:
                log.warning("track log %s: skipping %d bytes of torn records inside the file, %d records after "
                            "them kept", path, size - len(whole), (len(whole) - keep) // rec_size)
                atomic_write_bytes(path, whole)
                continue
            log.warning("track log %s: dropping %d bytes of a torn record", path, size - keep)
            with open(path, "r+b") as f:
                f.truncate(keep)
                f.flush()
                os.fsync(f.fileno())

    def append(self, t: float, x: float, y: float, accepted: bool,
               values: list[float] | None = None) -> None:
        """Queue one record; ``values`` (one per layer) of an accepted sample go to the values log."""
        self._pending.extend((t, x, y, 1.0 if accepted else 0.0))
        if accepted and values is not None and self.n_layers:
            self._pending_values.append(t)
            self._pending_values.extend(values)
        self._bound()

    def append_rows(self, rows: NDArray[np.float64], values: NDArray[np.float64] | None = None) -> None:
        """Queue an (N, 4) float64 array of records, in row order; ``values``: an
        (M, 1 + layers) array of t and layer values of the accepted ones."""
        self._pending.frombytes(np.ascontiguousarray(rows, dtype=np.float64).tobytes())
        if values is not None and self.n_layers and len(values):
            self._pending_values.frombytes(np.ascontiguousarray(values, dtype=np.float64).tobytes())
        self._bound()

    def read_values(self) -> NDArray[np.float64]:
        """Written and pending value records: (N, 1 + layers) array of t and layer values."""
        arr, _ = read_values(self.values_path, self.n_layers)
        with self._lock:
            pending = np.frombuffer(self._pending_values, dtype=np.float64).reshape(-1, 1 + self.n_layers).copy()
        return np.vstack([arr, pending]) if len(pending) else arr

    def take(self) -> tuple[array.array, array.array]:
        """The pending track and value records, leaving none pending (for :meth:`write`)."""
        out = (self._pending, self._pending_values)
        self._pending, self._pending_values = array.array("d"), array.array("d")
        return out

    def put_back(self, records: tuple[array.array, array.array]) -> None:
        """Return records :meth:`write` could not write, ahead of those queued since."""
        track, values = records
        track.extend(self._pending)
        values.extend(self._pending_values)
        self._pending, self._pending_values = track, values
        self._bound()

    def write(self, records: tuple[array.array, array.array]) -> tuple[list[str], tuple[array.array, array.array]]:
        """Append ``records`` (from :meth:`take`) to the two files, fsync'ed.

        Returns the errors (one per file that refused its records) and the
        records not written, for :meth:`put_back`."""
        track, values = records
        errors: list[str] = []
        left = (array.array("d"), array.array("d"))
        width = 1 + self.n_layers
        jobs = ((self.path, track, lambda r: encode_track_records(
                    list(zip(r[0::4], r[1::4], r[2::4], (int(f) for f in r[3::4]))))),
                (self.values_path, values, lambda r: _encode_values(r, width)))
        for k, (path, recs, encode) in enumerate(jobs):
            if not recs:
                continue
            try:
                _append(path, encode(recs))
            except OSError as e:
                errors.append(f"{path.name}: {e}")
                left[k].extend(recs)
        return errors, left

    def read(self) -> NDArray[np.float64]:
        """Written and pending records: (N, 4) array of t [s], x [m], y [m], accepted flag."""
        arr, _ = read_track(self.path)
        with self._lock:
            pending = np.frombuffer(self._pending, dtype=np.float64).reshape(-1, 4).copy()
        return np.vstack([arr, pending]) if len(pending) else arr

    def _bound(self) -> None:
        n = len(self._pending) // 4
        if n > self.max_pending:
            drop = n - self.max_pending + self.max_pending // 10
            del self._pending[:4 * drop]
            self.stats["track_dropped"] += drop
            if self.stats["track_dropped"] == drop:
                log.warning("map %s: track records cannot be written; dropping the oldest (%d)", self.path.parent, drop)
        width = 1 + self.n_layers
        nv = len(self._pending_values) // width
        if nv > self.max_pending:
            drop = nv - self.max_pending + self.max_pending // 10
            del self._pending_values[:width * drop]
            self.stats["track_values_dropped"] += drop


__all__ = ["VALUES_NAME", "TrackLog", "read_values"]
