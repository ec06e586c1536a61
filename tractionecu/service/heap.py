"""The process heap over a run of hours: what start-up leaves to the collector, and glibc's free memory.

Both functions are no-ops where they do not apply (``gc.freeze`` exists from
Python 3.7; the glibc calls are skipped on other C libraries).  Measured
effect in ``benchmarks/soak.py`` and ``docs/reliability.md``.
"""

from __future__ import annotations

import ctypes
import gc
from typing import Any


def _libc(name: str, argtypes: list[Any]) -> Any:
    """A glibc function from the running process, or None (not glibc)."""
    try:
        fn = getattr(ctypes.CDLL(None), name)
    except (OSError, AttributeError):
        return None
    fn.argtypes, fn.restype = argtypes, ctypes.c_int
    return fn


_MALLOC_TRIM = _libc("malloc_trim", [ctypes.c_size_t])
_MALLOPT = _libc("mallopt", [ctypes.c_int, ctypes.c_int])


def release_free_heap() -> None:
    """Return the C heap's free pages to the OS (glibc ``malloc_trim(0)``; a no-op elsewhere).

    glibc keeps memory that was freed inside its heaps, and the flush worker
    has an arena of its own: after a burst of tile snapshots the resident size
    stays up although nothing is in use (seen in the soak as +20 MiB "free"
    heap in one step).  Trimming after each flush, in the worker thread, costs
    ≈ 0.2 ms every ``map.flush_interval_s``.
    """
    if _MALLOC_TRIM is not None:
        _MALLOC_TRIM(0)


M_MMAP_THRESHOLD = -3
"""glibc ``mallopt`` parameter number (malloc.h)."""
MMAP_THRESHOLD_BYTES = 128 * 1024
"""Blocks this large or larger are mapped on their own and unmapped when freed [B]."""


def settle_heap() -> None:
    """Prepare the heap for a run of hours, once start-up is over.

    * Collect once and move every object start-up made out of the cyclic
      collector's reach.  Modules, compiled kernels and the DBC live as long
      as the process; left in the collector, every full collection during the
      run scans them again, a pause of ≈ 40 ms for the ≈ 130,000 start-up
      objects, four 100 Hz steps.  After :func:`gc.freeze` a full collection
      scans only what the loop made.
    * Fix glibc's mmap threshold at 128 KiB.  By default glibc raises it each
      time a mapped block is freed, after which the map writer's 200 kB tile
      snapshots come from the heap and leave it fragmented: with the trim
      of :func:`release_free_heap` alone, resident memory still crept up
      ≈ 0.4 MiB per simulated hour in the soak.  Fixed, each snapshot is
      mapped and returned whole: ≈ 0.2 MiB per hour, +2.4 % over 23 h.
    """
    gc.collect()
    gc.freeze()
    if _MALLOPT is not None:
        _MALLOPT(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
