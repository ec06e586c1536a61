"""Map writer: estimates at 10 Hz into :class:`~tractionecu.mapping.store.MapStore` tiles.

* :meth:`MapWriter.add` runs on the event loop at the map rate; it only
  updates in-memory running statistics (``MapStore.add`` is cheap and
  thread-safe).
* Tiles are written by :meth:`MapStore.flush` in a single worker thread every
  ``map.flush_interval_s`` (atomic tile writes; the event loop never waits
  for the disk), and once more by :meth:`MapWriter.close` on shutdown
  (SIGTERM).
* On start the store resumes the tiles already in the directory.  The field
  origin is ``map.origin_lat/lon`` if given, else the existing map's, else
  the first accepted fix.

Layers written: ``a`` and the class shape ``p, alpha1, alpha2`` (once a is
identified), ``rho_s``, and ``mu`` = mean adhesion over the four wheels.
The values are those of a window centred on each 10 Hz sample
(:class:`~tractionecu.mapping.sampler.CentredSampler`, the same computation
``replay`` applies offline), so a sample is mapped ``map.window_half_s``
seconds after it was taken; on shutdown the pending samples are mapped with
the window they have.  Only estimates with ``valid`` set are accumulated (the
store counts the rest as ``rejected_invalid``).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import math
from collections import Counter
from pathlib import Path
from typing import Any

from ..counting import WarnOnce
from ..mapping.sampler import CentredSampler
from ..mapping.tiles import DISK_FULL_ERRNOS, MANIFEST_NAME
from ..model.mucurve import curve_class
from .config import MapConfig
from .gps import GpsSample
from .heap import release_free_heap

log = logging.getLogger(__name__)


def layer_values(est: Any) -> dict[str, float]:
    """Map layer values of an ``Estimate`` (finite values only)."""
    out: dict[str, float] = {}
    mu = [float(x) for x in est.mu]
    if all(math.isfinite(x) for x in mu):
        out["mu"] = sum(mu) / len(mu)
    rho = float(est.rho_s)
    if math.isfinite(rho):
        out["rho_s"] = rho
    a = float(est.a)
    if math.isfinite(a):
        out["a"] = a
        cls = curve_class(str(getattr(est, "soil_class", "")))
        if cls is not None:
            out["p"], out["alpha1"], out["alpha2"] = cls.p, cls.alpha1, cls.alpha2
    return out


OPEN_RETRY_MIN_S = 1.0
"""First wait before opening the map again after it could not be opened [s] (doubling)."""
OPEN_RETRY_MAX_S = 60.0
"""Longest wait between attempts to open the map [s]."""


class MapWriter:
    """Accumulate on the loop, flush in a worker thread.

    Parameters
    ----------
    cfg:
        The ``[map]`` table.
    directory:
        Map directory (created if missing).
    """

    def __init__(self, cfg: MapConfig, directory: Path) -> None:
        self.cfg = cfg
        self.directory = Path(directory)
        self.store: Any = None
        self.stats: Counter[str] = Counter()
        self.last_error = ""
        self._pool = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="map-flush")
        self._flushing: asyncio.Future[Any] | None = None
        self._opening: asyncio.Future[Any] | None = None
        self._open_retry_mono = -math.inf
        self._open_backoff_s = OPEN_RETRY_MIN_S
        self._warn = WarnOnce(log)
        self._last_flush_mono = -math.inf
        self.sampler = CentredSampler(cfg.window_half_s)
        self.no_gnss = False
        """The service has no GNSS source (``gps.source = "none"``): nothing can be mapped."""
        self.beyond_range_km: float | None = None
        """Distance of the last refused position from the map's origin [km] while positions beyond the map's
        range are refused (None once one is mapped again)."""

    async def open(self) -> None:
        """Resume an existing map (tiles read in the worker thread), or wait for the first fix.

        A full disk (the new map's manifest cannot be written) does not stop the service: the map is opened
        again, as one that could not be opened at its first fix (:meth:`_opened`)."""
        loop = asyncio.get_running_loop()
        try:
            if math.isfinite(self.cfg.origin_lat):
                await self._open_at(loop, self.cfg.origin_lat, self.cfg.origin_lon)
            elif (self.directory / MANIFEST_NAME).exists():
                from ..mapping.store import MapStore

                self.store = await loop.run_in_executor(self._pool, lambda: MapStore.open(self.directory))
                self._log_resume()
        except OSError as e:
            if e.errno not in DISK_FULL_ERRNOS:
                raise
            self._open_failed(e)

    async def _open_at(self, loop: asyncio.AbstractEventLoop, lat: float, lon: float) -> None:
        from ..mapping.store import MapStore

        def make() -> Any:
            return MapStore(self.directory, lat, lon, resolution_m=self.cfg.resolution_m)

        if (self.directory / MANIFEST_NAME).exists():
            def make() -> Any:  # noqa: F811 - an existing map keeps its own resolution
                return MapStore.open(self.directory)
        self.store = await loop.run_in_executor(self._pool, make)
        self._log_resume()

    def _log_resume(self) -> None:
        n = len(self.store.tile_keys())
        log.info("map %s: %s with %d tile(s), origin %.6f, %.6f", self.directory,
                 "resumed" if n else "new", n, self.store.frame.origin_lat, self.store.frame.origin_lon)
        self.stats["resumed_tiles"] = n

    def add(self, est: Any, fix: GpsSample | None) -> bool:
        """Take one estimate at the fix's position; map the samples whose window is complete.

        Returns False if this estimate cannot be mapped (no fix) or a ready
        sample was not accepted.
        """
        if fix is None:
            self.stats["no_fix"] += 1
            return False
        if self.store is None and self._opening is None:
            loop = asyncio.get_running_loop()
            if loop.time() >= self._open_retry_mono:
                lat, lon = ((self.cfg.origin_lat, self.cfg.origin_lon) if math.isfinite(self.cfg.origin_lat)
                            else (fix.lat_deg, fix.lon_deg))
                self._opening = asyncio.ensure_future(self._open_at(loop, lat, lon))
                self._opening.add_done_callback(self._opened)
        try:
            ready = self.sampler.push(est.t, fix.lat_deg, fix.lon_deg, fix.fix_quality, fix.hdop, est)
        except Exception as e:  # a malformed estimate must not stop the loop
            self.stats["add_errors"] += 1
            self.last_error = str(e)
            log.warning("map sample failed: %s", e)
            return False
        return self._add_ready(ready)

    def discard_since(self, t_since: float) -> None:
        """The estimator was lost since ``t_since`` [s]: nothing of that period is mapped (samples still
        waiting for their window are dropped from it and not stored)."""
        self.sampler.invalidate_since(t_since)
        self.stats["lost_periods"] += 1

    def _add_ready(self, ready: list[tuple]) -> bool:
        all_ok = True
        for (t, lat, lon, values, valid, status, fix_quality, hdop) in ready:
            if self.store is None:
                self.stats["waiting_for_store"] += 1
                all_ok = False
                continue
            vals = {k: v for k, v in values.items() if math.isfinite(v)}
            try:
                far = self.store.stats.get("rejected_range", 0)
                ok = self.store.add(lat, lon, vals, t, valid=valid, status=status, fix_quality=fix_quality, hdop=hdop)
                far = self.store.stats.get("rejected_range", 0) > far
            except Exception as e:  # a closed or broken store must not stop the loop
                self.stats["add_errors"] += 1
                self.last_error = str(e)
                log.warning("map add failed: %s", e)
                all_ok = False
                continue
            self.stats["added" if ok else "rejected"] += 1
            if far:
                self._beyond_range(lat, lon)
            elif ok and self.beyond_range_km is not None:
                self.beyond_range_km = None
                self._warn.forget("range")
            all_ok = all_ok and ok
        return all_ok

    def _beyond_range(self, lat: float, lon: float) -> None:
        """A position beyond the map's range (:class:`~tractionecu.mapping.store.MapStore` ``max_range_m``
        from its origin) was refused: count it, say so once per spell, and let :attr:`state` show it."""
        st = self.store
        x, y = st.to_local(lat, lon)
        self.beyond_range_km = math.hypot(float(x), float(y)) / 1000.0
        self.stats["beyond_range"] += 1
        self._warn("range", "map %s: the machine is %.0f km from the map's origin %.6f, %.6f, beyond the %.0f km "
                   "a map covers: nothing here is mapped (a map holds one farm: run this place with another "
                   "--state-dir, or move the map directory away so that a new one starts here)", self.directory,
                   self.beyond_range_km, st.frame.origin_lat, st.frame.origin_lon, st.max_range_m / 1000.0)

    def _opened(self, fut: asyncio.Future[Any]) -> None:
        if fut.cancelled():
            return
        e = fut.exception()
        if e is not None:
            self._open_failed(e)
        else:
            self._warn.forget("open")
            self._open_backoff_s = OPEN_RETRY_MIN_S
            self.last_error = ""

    def _open_failed(self, e: BaseException) -> None:
        # retried with a doubling wait: the samples meanwhile wait in the sampler's window or are
        # counted (waiting_for_store); one error line, not one per 10 Hz sample
        self.stats["open_errors"] += 1
        self.last_error = f"cannot open: {e}"
        self._warn("open", "map %s: cannot open: %s; retrying every %g s at most", self.directory, e,
                   OPEN_RETRY_MAX_S, level=logging.ERROR)
        self._open_retry_mono = asyncio.get_running_loop().time() + self._open_backoff_s
        self._open_backoff_s = min(2 * self._open_backoff_s, OPEN_RETRY_MAX_S)
        self._opening = None

    @property
    def state(self) -> str:
        """What the page and the status line say of the map: ``writing``, ``waiting for a GNSS fix`` or the
        error that stops it."""
        if self.last_error:
            return "ERROR: " + self.last_error
        if self.no_gnss and self.store is None:
            return 'no GNSS source (gps.source = "none"): nothing is mapped'
        if self.store is not None and self.beyond_range_km is not None:
            return (f"NOT MAPPING: {self.beyond_range_km:.0f} km from the map's origin, beyond its "
                    f"{self.store.max_range_m / 1000.0:.0f} km range")
        return "writing" if self.store is not None else "waiting for a GNSS fix"

    def maybe_flush(self, now_mono: float) -> None:
        """Start a flush in the worker thread if the interval is over and none is running."""
        if self.store is None or now_mono - self._last_flush_mono < self.cfg.flush_interval_s:
            return
        if self._flushing is not None and not self._flushing.done():
            return
        self._last_flush_mono = now_mono
        loop = asyncio.get_running_loop()
        self._flushing = loop.run_in_executor(self._pool, self._flush_and_trim)
        self._flushing.add_done_callback(self._flushed)

    async def wait_flushed(self) -> None:
        """Wait for the flush running in the worker thread, if any (its error is counted, not raised)."""
        if self._flushing is not None:
            try:
                await self._flushing
            except Exception:
                pass

    def _flush_and_trim(self) -> int:
        """Worker thread: write the dirty tiles, then hand the C heap's free pages back to the OS."""
        try:
            return int(self.store.flush() or 0)
        finally:
            release_free_heap()

    def _flushed(self, fut: asyncio.Future[Any]) -> None:
        if fut.cancelled():
            return
        e = fut.exception()
        if e is not None:
            self.stats["flush_errors"] += 1
            self.last_error = f"flush failed: {e}"
            self._warn("flush", "map flush failed: %s (the tiles stay in memory and are written at the next "
                       "flush that succeeds)", e, level=logging.ERROR)
        else:
            if "flush" in self._warn:
                log.warning("map %s: flushing again", self.directory)
                self._warn.forget("flush")
                self.last_error = ""
            self.stats["flushes"] += 1
            self.stats["tiles_written"] += int(fut.result() or 0)

    async def close(self) -> None:
        """Write every dirty tile and release the store (in the worker thread)."""
        loop = asyncio.get_running_loop()
        if self._opening is not None and not self._opening.done():
            try:
                await self._opening
            except Exception:
                pass
        self._add_ready(self.sampler.drain())
        await self.wait_flushed()
        try:
            if self.store is not None:
                await loop.run_in_executor(self._pool, self.store.close)
                self.stats["closed"] += 1
        finally:
            self._pool.shutdown(wait=True)
