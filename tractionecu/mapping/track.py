"""The map's track log: every sample position that passed the GNSS checks.

Records (t [s], x [m], y [m], accepted flag) wait in memory until the next
flush appends them to ``track.log`` (record format in
:mod:`~tractionecu.mapping.tiles`).  While the disk refuses them they stay
in memory, in order, up to ``max_pending`` records; beyond that the oldest
tenth is dropped and counted as ``stats["track_dropped"]``.

:class:`~tractionecu.mapping.store.MapStore` owns one :class:`TrackLog`,
shares its lock with it and holds that lock around every call except
:meth:`TrackLog.write` (the disk write, which runs outside it) and
:meth:`TrackLog.read` (which takes it only to copy the pending records).
"""

from __future__ import annotations

import array
import logging
import os
import threading
from collections import Counter
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .tiles import encode_track_records, read_track

log = logging.getLogger(__name__)


class TrackLog:
    """Pending track records of one map and its ``track.log`` file."""

    def __init__(self, path: Path, max_pending: int, stats: Counter, lock: threading.Lock) -> None:
        self.path = path
        self.max_pending = max(1, int(max_pending))
        self.stats = stats
        self._lock = lock
        self._pending = array.array("d")
        """Records not yet written, flat: t [s], x [m], y [m], accepted flag (0/1), ..."""

    def repair(self) -> None:
        """Cut a torn last record off the file (a crash during an append)."""
        if not self.path.exists():
            return
        _, good = read_track(self.path)
        size = self.path.stat().st_size
        if good != size:
            log.warning("track log %s: dropping %d bytes of a torn record", self.path, size - good)
            with open(self.path, "r+b") as f:
                f.truncate(good)
                f.flush()
                os.fsync(f.fileno())

    def append(self, t: float, x: float, y: float, accepted: bool) -> None:
        """Queue one record."""
        self._pending.extend((t, x, y, 1.0 if accepted else 0.0))
        self._bound()

    def append_rows(self, rows: NDArray[np.float64]) -> None:
        """Queue an (N, 4) float64 array of records, in row order."""
        self._pending.frombytes(np.ascontiguousarray(rows, dtype=np.float64).tobytes())
        self._bound()

    def take(self) -> array.array:
        """The pending records, leaving none pending (for :meth:`write`)."""
        out, self._pending = self._pending, array.array("d")
        return out

    def put_back(self, records: array.array) -> None:
        """Return records :meth:`write` could not write, ahead of those queued since."""
        records.extend(self._pending)
        self._pending = records
        self._bound()

    def write(self, records: array.array) -> None:
        """Append ``records`` (from :meth:`take`) to the file and fsync it; raises OSError."""
        rows = zip(records[0::4], records[1::4], records[2::4], (int(f) for f in records[3::4]))
        with open(self.path, "ab") as f:
            f.write(encode_track_records(list(rows)))
            f.flush()
            os.fsync(f.fileno())

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


__all__ = ["TrackLog"]
