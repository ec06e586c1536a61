"""The map writer hands freed C-heap pages back to the OS after each flush (glibc ``malloc_trim``)."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from tractionecu.service import heap


def rss_anon_mib() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("RssAnon:"):
            return int(line.split()[1]) / 1024
    pytest.skip("no RssAnon in /proc/self/status")


@pytest.mark.skipif(heap._MALLOC_TRIM is None, reason="not glibc: release_free_heap is a no-op")
def test_memory_freed_in_a_worker_thread_is_returned_after_trim() -> None:
    """Regression for the soak's step: 60 MiB of 1 KiB blocks made and freed in a worker thread
    (as the flush worker's tile snapshots are) stay resident until the heap is trimmed."""
    survivors: list[np.ndarray] = []

    def burst() -> None:
        blocks = [np.ones(128) for _ in range(60_000)]   # 1 KiB each: from malloc, not mmap
        survivors.extend(blocks[::200])                 # a few live blocks pin the arena

    heap.release_free_heap()                       # start from a trimmed heap
    base = rss_anon_mib()
    t = threading.Thread(target=burst)
    t.start()
    t.join()
    held = rss_anon_mib() - base
    heap.release_free_heap()
    after = rss_anon_mib() - base
    assert held > 40.0, f"the burst was not resident ({held:.1f} MiB): the test measures nothing"
    assert after < 0.3 * held, f"{held:.1f} MiB held, {after:.1f} MiB after the trim"
