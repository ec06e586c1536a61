"""SIGKILL at random moments while map tiles are written: every tile reads back whole,
nothing flushed is lost, and the next start resumes the map.

A child process opens (or resumes) a MapStore and loops: add BATCH samples of
``mu`` at seeded random positions over 16 tiles, ``flush(force=True)``, print the
total number of samples now on disk.  The parent SIGKILLs it a seeded random
0–250 ms after its first flush, TRIALS times in a row on the same directory.
After each kill:

* every ``*.tile`` decodes (``tiles.read_tile``: magic, header, CRC) and
  ``MapStore.open`` sets nothing aside as corrupt;
* the ``mu`` count summed over the tiles is at least the last total the child
  reported as flushed (nothing acknowledged is lost) and at most that plus one
  batch (a flush interrupted part-way);
* the next trial's child resumes that map and continues from it.

The same against the real daemon (SIGKILL during its flushes) runs in the vcan
guest: ``tests/vcan/test_faults_vcan.py``.
"""

from __future__ import annotations

import random
import signal
import subprocess
import sys
import time
from pathlib import Path

from tractionecu.mapping.store import MapStore
from tractionecu.mapping.tiles import MANIFEST_NAME, iter_tile_files, read_tile

TRIALS = 50
SEED = 20240607
BATCH = 40

CHILD = r"""
import sys, random
from pathlib import Path
from tractionecu.mapping.store import MapStore
from tractionecu.mapping.tiles import MANIFEST_NAME
d, seed = Path(sys.argv[1]), int(sys.argv[2])
rng = random.Random(seed)
if (d / MANIFEST_NAME).exists():
    s = MapStore.open(d, min_flush_interval_s=0.0)
else:
    s = MapStore(d, 47.88, -110.55, min_flush_interval_s=0.0)
li = s.layers.index("mu")
total = 0
for k in s.tile_keys():
    total += int(s._tile(k).stats.count[li].sum())
while True:
    for _ in range(%d):
        s.add(47.88 + rng.uniform(-4e-4, 4e-4), -110.55 + rng.uniform(-6e-4, 6e-4), {"mu": rng.uniform(0.1, 0.9)},
              1.7e9 + total, fix_quality=4, hdop=0.8)
        total += 1
    s.flush(force=True)
    print(total, flush=True)
""" % BATCH


def on_disk(directory: Path) -> int:
    """Samples of ``mu`` in every tile file; raises if any tile does not decode."""
    n = 0
    for _key, path in iter_tile_files(directory):
        _tx, _ty, stats = read_tile(path)
        n += int(stats.count[stats.layers.index("mu")].sum())
    return n


def test_sigkill_during_tile_writes_never_corrupts_or_loses_flushed_samples(tmp_path: Path) -> None:
    rng = random.Random(SEED)
    d = tmp_path / "map"
    acked_prev = 0
    delays = []
    for trial in range(TRIALS):
        p = subprocess.Popen([sys.executable, "-c", CHILD, str(d), str(SEED + trial)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        first = p.stdout.readline()
        assert first.strip(), f"trial {trial}: child did not start: {p.stderr.read()}"
        delay = rng.uniform(0.0, 0.25)
        delays.append(delay)
        time.sleep(delay)
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=10)
        assert p.returncode == -signal.SIGKILL
        lines = [first] + p.stdout.read().splitlines()
        p.stdout.close()
        p.stderr.close()
        acked = int([ln for ln in lines if ln.strip()][-1])
        assert acked >= acked_prev + BATCH, f"trial {trial}: the restart did not resume the map"
        n = on_disk(d)
        assert acked <= n <= acked + BATCH, f"trial {trial}: {n} samples on disk, {acked} acknowledged"
        acked_prev = acked
    with MapStore.open(d) as s:
        assert s.stats["corrupt_tiles"] == 0 and not s.corrupt_tiles
        assert len(s.tile_keys()) >= 12
    assert not list(d.glob("**/*.corrupt*"))
    assert (d / MANIFEST_NAME).is_file()
    print(f"\n{TRIALS} SIGKILLs (delays {min(delays) * 1e3:.0f}-{max(delays) * 1e3:.0f} ms after the first flush): "
          f"0 corrupt tiles, {acked_prev} samples acknowledged, {on_disk(d)} on disk")
