import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from tractionecu.errors import ConfigError
from tractionecu.mapping import tiles as tiles_mod
from tractionecu.mapping.grid import TileStats
from tractionecu.mapping.store import MapStore
from tractionecu.mapping.tiles import (
    CorruptTileError,
    MapStoreError,
    decode_tile,
    encode_tile,
    iter_tile_files,
    read_tile,
    TRACK_RECORD_SIZE,
    read_track,
)

from map_synth import ORIGIN

REPO = Path(__file__).resolve().parents[2]


def add_xy(store, x, y, values, t=0.0, **kw):
    lat, lon = store.to_latlon(x, y)
    return store.add(float(lat), float(lon), values, t, **kw)


def test_tile_roundtrip_and_checksum():
    rng = np.random.default_rng(0)
    ts = TileStats(("a", "mu"), 5)
    for _ in range(50):
        ts.add(int(rng.integers(5)), int(rng.integers(5)), [(0, rng.normal()), (1, rng.normal())])
    data = encode_tile(-3, 7, ts)
    tx, ty, back = decode_tile(data)
    assert (tx, ty) == (-3, 7) and back.layers == ("a", "mu")
    assert np.array_equal(back.count, ts.count) and np.array_equal(back.mean, ts.mean)
    assert np.array_equal(back.m2, ts.m2)
    for pos in (0, 9, 20, len(data) // 2, len(data) - 1):
        bad = bytearray(data)
        bad[pos] ^= 0x40
        with pytest.raises(CorruptTileError):
            decode_tile(bytes(bad))
    for cut in (0, 10, len(data) - 1):
        with pytest.raises(CorruptTileError):
            decode_tile(data[:cut])


def test_manifest_documents_the_map(tmp_path):
    st = MapStore(tmp_path, *ORIGIN, resolution_m=0.25, tile_cells=32, soil_classes={"stubble": 0.75})
    m = json.loads((tmp_path / "manifest.json").read_text())
    assert m["crs"] == "EPSG:32633" and m["utm_zone"] == 33 and m["utm_south"] is False
    assert (m["origin_lat"], m["origin_lon"]) == ORIGIN
    assert m["resolution_m"] == 0.25 and m["tile_cells"] == 32
    assert m["layers"] == ["a", "p", "alpha1", "alpha2", "rho_s", "mu"]
    assert m["soil_classes"] == {"stubble": 0.75}
    st.close()
    with pytest.raises(ConfigError, match="resolution_m"):
        MapStore(tmp_path, *ORIGIN, resolution_m=0.5, tile_cells=32)
    with pytest.raises(ConfigError, match="origin_lat"):
        MapStore(tmp_path, 50.0, ORIGIN[1], resolution_m=0.25, tile_cells=32)


def test_rejections(tmp_path):
    st = MapStore(tmp_path, *ORIGIN, min_fix_quality=2, max_hdop=2.0)
    ok = {"a": 0.7}
    assert add_xy(st, 1.0, 1.0, ok)
    assert not add_xy(st, 1.0, 1.0, {"a": math.nan})
    # each layer is its own mean: a non-finite value leaves only its own layer alone
    assert add_xy(st, 1.0, 1.0, {"a": 0.7, "mu": math.inf})
    assert not add_xy(st, 1.0, 1.0, {"a": math.nan, "mu": math.inf})
    assert not add_xy(st, 1.0, 1.0, {"a": 0.7}, valid=False)
    assert not add_xy(st, 1.0, 1.0, {"a": 0.7}, status=0x20)  # not converged
    assert add_xy(st, 1.0, 1.0, {"a": 0.7}, status=0x80)      # one NIS-gated measurement is fine
    assert not add_xy(st, 1.0, 1.0, ok, fix_quality=1)
    assert add_xy(st, 1.0, 1.0, ok, fix_quality=4, hdop=0.8)
    assert not add_xy(st, 1.0, 1.0, ok, hdop=3.0)
    assert not add_xy(st, 1.0, 1.0, {"unknown": 1.0})
    assert not st.add(math.nan, ORIGIN[1], ok, 0.0)
    assert not st.add(ORIGIN[0], ORIGIN[1], ok, math.nan)
    assert not st.add(ORIGIN[0] + 1.0, ORIGIN[1], ok, 0.0)  # 111 km away
    assert st.stats["accepted"] == 4 and st.stats["rejected_status"] == 1
    assert st.stats["rejected_value"] == 2 and st.stats["rejected_invalid"] == 1
    assert st.stats["rejected_fix"] == 1 and st.stats["rejected_hdop"] == 1
    assert st.stats["rejected_no_layer"] == 1 and st.stats["rejected_position"] == 2
    assert st.stats["rejected_range"] == 1
    g = st.grid("a")
    assert g.count.sum() == 4 and np.nanmax(g.mean) == pytest.approx(0.7)
    assert st.grid("mu").count.sum() == 0
    # the track holds every position that passed the GNSS checks, flagged
    st.flush(force=True)
    tr = st.track()
    assert len(tr) == 9 and tr[:, 3].sum() == 4
    st.close()


def test_resume_keeps_averaging(tmp_path):
    rng = np.random.default_rng(1)
    x = rng.uniform(0, 40, 3000)
    y = rng.uniform(0, 40, 3000)
    a = rng.normal(0.6, 0.05, 3000)
    with MapStore(tmp_path, *ORIGIN, resolution_m=2.0, tile_cells=8) as st:
        for i in range(1500):
            assert add_xy(st, x[i], y[i], {"a": a[i]}, 0.1 * i)
    st2 = MapStore.open(tmp_path)
    assert st2.resolution_m == 2.0 and st2.tile_cells == 8
    for i in range(1500, 3000):
        assert add_xy(st2, x[i], y[i], {"a": a[i]}, 0.1 * i)
    st2.close()
    ro = MapStore.open(tmp_path, read_only=True)
    g = ro.grid("a")
    xs, ys = ro.to_local(*ro.to_latlon(x, y))
    col = np.floor(xs / 2.0).astype(int) - int(round(g.x0 / 2.0))
    row = np.floor(ys / 2.0).astype(int) - int(round(g.y0 / 2.0))
    for r, c in {(int(r), int(c)) for r, c in zip(row, col)}:
        sel = (row == r) & (col == c)
        assert g.count[r, c] == sel.sum()
        assert g.mean[r, c] == pytest.approx(a[sel].mean(), rel=1e-12)
        if sel.sum() > 1:
            assert g.var[r, c] == pytest.approx(a[sel].var(ddof=1), rel=1e-9)
    assert g.count.sum() == 3000
    assert len(read_track(tmp_path / "track.log")[0]) == 3000


def test_only_dirty_tiles_are_rewritten_and_rate_limit(tmp_path):
    st = MapStore(tmp_path, *ORIGIN, resolution_m=1.0, tile_cells=10, min_flush_interval_s=3600.0)
    add_xy(st, 5.0, 5.0, {"a": 0.5})    # tile (0, 0)
    add_xy(st, 25.0, 5.0, {"a": 0.6})   # tile (2, 0)
    assert sorted(st.dirty_tiles()) == [(0, 0), (2, 0)]
    assert st.flush() == 2
    assert st.dirty_tiles() == []
    inode = {k: p.stat().st_ino for k, p in iter_tile_files(tmp_path)}
    add_xy(st, 6.0, 5.0, {"a": 0.7})
    assert st.flush() == 0                 # within the minimum interval: nothing written
    assert st.dirty_tiles() == [(0, 0)]
    assert st.flush(force=True) == 1
    after = {k: p.stat().st_ino for k, p in iter_tile_files(tmp_path)}
    assert after[(2, 0)] == inode[(2, 0)]  # untouched file kept
    assert after[(0, 0)] != inode[(0, 0)]  # rewritten by rename
    assert st.flush(force=True) == 0
    st.close()


def test_rate_limit_allows_ten_per_second(tmp_path):
    st = MapStore(tmp_path, *ORIGIN)
    writes = 0
    t_end = time.monotonic() + 0.55
    k = 0
    while time.monotonic() < t_end:
        add_xy(st, 0.5 * (k % 50), 1.0, {"a": 0.5}, k)
        writes += 1 if st.flush() else 0
        k += 1
    assert 1 <= writes <= 6
    st.close()


def test_failed_write_keeps_old_tile_and_stays_dirty(tmp_path, monkeypatch):
    st = MapStore(tmp_path, *ORIGIN, resolution_m=1.0, tile_cells=10)
    add_xy(st, 1.0, 1.0, {"a": 0.5})
    st.flush(force=True)
    path = tmp_path / "tiles" / "t0_0.tile"
    before = path.read_bytes()
    add_xy(st, 1.0, 1.0, {"a": 0.9})

    def boom(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(tiles_mod.os, "replace", boom)
    with pytest.raises(MapStoreError, match="No space"):
        st.flush(force=True)
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert not [p for p in (tmp_path / "tiles").iterdir() if ".tmp." in p.name]
    assert st.dirty_tiles() == [(0, 0)]
    assert st.flush(force=True) == 1
    _, _, ts = read_tile(path)
    assert ts.count[0].sum() == 2 and ts.mean[0][ts.count[0] > 0][0] == pytest.approx(0.7)
    st.close()


def test_stray_temporaries_are_removed_on_open(tmp_path):
    with MapStore(tmp_path, *ORIGIN, resolution_m=1.0, tile_cells=10) as st:
        add_xy(st, 1.0, 1.0, {"a": 0.5})
    good = (tmp_path / "tiles" / "t0_0.tile").read_bytes()
    stray = tmp_path / "tiles" / ".t0_0.tile.tmp.4242.7"
    stray.write_bytes(good[: len(good) // 2])
    (tmp_path / ".manifest.json.tmp.4242.8").write_bytes(b"{")
    st = MapStore.open(tmp_path)
    assert not stray.exists() and not (tmp_path / ".manifest.json.tmp.4242.8").exists()
    assert len(st.removed_temporaries) == 2 and st.corrupt_tiles == []
    assert st.grid("a").count.sum() == 1
    st.close()


def test_corrupt_tile_is_reported_not_fatal(tmp_path):
    with MapStore(tmp_path, *ORIGIN, resolution_m=1.0, tile_cells=10) as st:
        add_xy(st, 1.0, 1.0, {"a": 0.5})
        add_xy(st, 15.0, 1.0, {"a": 0.6})
    bad = tmp_path / "tiles" / "t0_0.tile"
    data = bytearray(bad.read_bytes())
    data[len(data) // 2] ^= 0xFF
    bad.write_bytes(bytes(data))
    (tmp_path / "tiles" / "t1_0.tile").write_bytes((tmp_path / "tiles" / "t1_0.tile").read_bytes()[:10])

    ro = MapStore.open(tmp_path, read_only=True)  # readers report, never rename
    assert sorted(p.name for p, _ in ro.corrupt_tiles) == ["t0_0.tile", "t1_0.tile"]
    assert bad.exists()
    assert ro.grid("a").count.sum() == 0

    st = MapStore.open(tmp_path)
    reasons = dict((p.name, r) for p, r in st.corrupt_tiles)
    assert "CRC" in reasons["t0_0.tile"] and "truncated" in reasons["t1_0.tile"]
    assert (tmp_path / "tiles" / "t0_0.tile.corrupt").exists()
    assert add_xy(st, 1.0, 1.0, {"a": 0.8})  # the tile restarts empty
    st.close()
    g = MapStore.open(tmp_path, read_only=True).grid("a")
    assert g.count.sum() == 1 and np.nanmax(g.mean) == pytest.approx(0.8)


def test_second_writer_is_refused(tmp_path):
    st = MapStore(tmp_path, *ORIGIN)
    with pytest.raises(MapStoreError, match="another process"):
        MapStore.open(tmp_path)
    MapStore.open(tmp_path, read_only=True)  # readers are fine
    st.close()
    MapStore.open(tmp_path).close()


def test_flush_from_worker_thread_while_adding(tmp_path):
    rng = np.random.default_rng(5)
    st = MapStore(tmp_path, *ORIGIN, resolution_m=1.0, tile_cells=8, min_flush_interval_s=0.0)
    n = 6000
    x = rng.uniform(0, 60, n)
    y = rng.uniform(0, 30, n)
    a = rng.normal(0.5, 0.1, n)
    stop = threading.Event()
    written = []

    def worker():
        while not stop.is_set():
            written.append(st.flush())

    th = threading.Thread(target=worker)
    th.start()
    try:
        for i in range(n):
            add_xy(st, x[i], y[i], {"a": a[i]}, 0.1 * i)
    finally:
        stop.set()
        th.join()
    st.close()
    assert sum(written) > 0
    g = MapStore.open(tmp_path, read_only=True).grid("a")
    assert g.count.sum() == n
    assert np.nansum(g.mean * g.count) == pytest.approx(a.sum(), rel=1e-12)
    assert len(read_track(tmp_path / "track.log")[0]) == n


def test_clean_tiles_are_evicted_and_reloaded(tmp_path):
    st = MapStore(tmp_path, *ORIGIN, resolution_m=1.0, tile_cells=4, max_resident_tiles=2,
                  min_flush_interval_s=0.0)
    for k in range(6):
        add_xy(st, 4.0 * k + 1.0, 1.0, {"a": 0.1 * k})
        st.flush()
    assert len(st._tiles) <= 2
    for k in range(6):
        add_xy(st, 4.0 * k + 1.0, 1.0, {"a": 0.1 * k + 0.2})
        st.flush()
    g = st.grid("a")
    assert g.count.sum() == 12
    vals = np.sort(g.mean[np.isfinite(g.mean)])
    assert np.allclose(vals, 0.1 * np.arange(6) + 0.1)
    st.close()


def test_torn_track_record_is_cut(tmp_path):
    with MapStore(tmp_path, *ORIGIN) as st:
        for k in range(5):
            add_xy(st, k, 0.0, {"a": 0.5}, k)
    with open(tmp_path / "track.log", "ab") as f:
        f.write(b"\x01\x02\x03")
    assert len(read_track(tmp_path / "track.log")[0]) == 5
    with MapStore.open(tmp_path) as st:
        add_xy(st, 9.0, 0.0, {"a": 0.5}, 9.0)
    tr, good = read_track(tmp_path / "track.log")
    assert len(tr) == 6 and good == (tmp_path / "track.log").stat().st_size
    assert tr[-1, 0] == 9.0


def test_a_full_disk_mid_append_leaves_no_torn_record_and_an_old_one_is_skipped(tmp_path, monkeypatch):
    """A disk that filled during an append left a 14-byte fragment inside track.log; the records put back and
    appended after it were unreadable, and the next start cut the file at the fragment, deleting 621 records
    that had been written and fsync'ed."""
    import errno

    from tractionecu.mapping import track as track_mod

    st = MapStore(tmp_path, *ORIGIN, min_flush_interval_s=0.0)
    for k in range(5):
        add_xy(st, k, 0.0, {"a": 0.5}, k)
    st.flush(force=True)
    real_write = os.write

    def full(fd, data):                     # the disk takes 14 bytes of the block, then is full
        real_write(fd, bytes(data[:14]))
        raise OSError(errno.ENOSPC, "No space left on device")

    for k in range(5, 8):
        add_xy(st, k, 0.0, {"a": 0.5}, k)
    monkeypatch.setattr(track_mod.os, "write", full)
    with pytest.raises(MapStoreError, match="No space left"):
        st.flush(force=True)                                # said, and the records are held
    monkeypatch.setattr(track_mod.os, "write", real_write)
    assert len(read_track(tmp_path / "track.log")[0]) == 5
    assert (tmp_path / "track.log").stat().st_size == 5 * TRACK_RECORD_SIZE     # cut back: no fragment
    st.flush(force=True)                                                            # the disk has room again
    st.close()
    tr, good = read_track(tmp_path / "track.log")
    assert tr[:, 0].tolist() == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]
    # a fragment inside a file written before appends were cut back: the records after it are kept
    data = (tmp_path / "track.log").read_bytes()
    (tmp_path / "track.log").write_bytes(data[:3 * TRACK_RECORD_SIZE] + data[:14] + data[3 * TRACK_RECORD_SIZE:])
    with MapStore.open(tmp_path) as st:
        pass
    assert read_track(tmp_path / "track.log")[0][:, 0].tolist() == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]


WRITER = textwrap.dedent("""
    import sys, numpy as np
    from tractionecu.mapping.store import MapStore
    st = MapStore(sys.argv[1], 50.91, 13.34, resolution_m=0.5, tile_cells=192, min_flush_interval_s=0.0)
    rng = np.random.default_rng(int(sys.argv[2]))
    k = 0
    while True:
        for _ in range(20):
            x, y = rng.uniform(0, 190), rng.uniform(0, 190)
            lat, lon = st.to_latlon(x, y)
            st.add(lat, lon, {n: rng.normal() for n in st.layers}, k * 0.1)
            k += 1
        st.flush()
        print(k, flush=True)
""")


def _env():
    return dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))


def test_random_kills_never_leave_a_partial_tile(tmp_path):
    """SIGKILL a busy writer at random moments; every tile on disk reads back whole."""
    rng = np.random.default_rng(99)
    for attempt in range(4):
        d = tmp_path / f"m{attempt}"
        proc = subprocess.Popen([sys.executable, "-c", WRITER, str(d), str(attempt)], stdout=subprocess.PIPE,
                                env=_env())
        try:
            assert proc.stdout is not None
            proc.stdout.readline()  # at least one flush happened
            time.sleep(float(rng.uniform(0.0, 0.4)))
        finally:
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            proc.stdout.close()
        files = list(iter_tile_files(d))
        assert files
        for _, p in files:
            read_tile(p)  # raises CorruptTileError if partial
        st = MapStore.open(d)
        assert st.corrupt_tiles == []
        assert st.grid("a").count.sum() > 0
        st.close()


CRASHER = textwrap.dedent("""
    import os, signal, sys
    from tractionecu.mapping import tiles
    from tractionecu.mapping.store import MapStore
    where = sys.argv[2]
    st = MapStore(sys.argv[1], 50.91, 13.34, resolution_m=1.0, tile_cells=16)
    lat, lon = st.to_latlon(3.0, 3.0)
    st.add(lat, lon, {"a": 0.25}, 0.0)
    st.flush(force=True)                      # old version on disk: a = 0.25
    st.add(lat, lon, {"a": 0.75}, 0.1)        # new version would be mean 0.5

    def die():
        os.kill(os.getpid(), signal.SIGKILL)

    if where == "mid_write":
        real_open = open

        class HalfWriter:
            def __init__(self, f):
                self.f = f
            def __enter__(self):
                return self
            def __exit__(self, *a):
                self.f.close()
            def write(self, data):
                self.f.write(data[: len(data) // 2])
                self.f.flush()
                os.fsync(self.f.fileno())
                die()

        def fake_open(path, mode="r", *a, **k):
            f = real_open(path, mode, *a, **k)
            return HalfWriter(f) if ".tmp." in str(path) else f

        tiles.open = fake_open
    elif where == "before_rename":
        tiles.os.replace = lambda src, dst: die()
    elif where == "before_dir_fsync":
        tiles.fsync_dir = lambda d: die()
    st.flush(force=True)
    print("not killed")
""")


@pytest.mark.parametrize("where,expect_mean", [("mid_write", 0.25), ("before_rename", 0.25),
                                               ("before_dir_fsync", 0.5)])
def test_crash_inside_an_atomic_write(tmp_path, where, expect_mean):
    """Kill the writer at a chosen point of the write sequence: the tile is the
    old or the new version, whole; a stray temp file is cleaned on reopen."""
    proc = subprocess.run([sys.executable, "-c", CRASHER, str(tmp_path), where], env=_env(),
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    path = tmp_path / "tiles" / "t0_0.tile"
    _, _, ts = read_tile(path)
    assert ts.count[0].sum() == (1 if expect_mean == 0.25 else 2)
    assert ts.mean[0][ts.count[0] > 0][0] == pytest.approx(expect_mean)
    temps = [p for p in (tmp_path / "tiles").iterdir() if ".tmp." in p.name]
    if where != "before_dir_fsync":
        assert len(temps) == 1  # the interrupted temporary
    st = MapStore.open(tmp_path)
    assert st.corrupt_tiles == []
    assert not [p for p in (tmp_path / "tiles").iterdir() if ".tmp." in p.name]
    st.close()


def test_add_many_equals_add_one_by_one(tmp_path):
    rng = np.random.default_rng(8)
    n = 3000
    one = MapStore(tmp_path / "one", *ORIGIN, resolution_m=1.0, tile_cells=8, max_hdop=2.0)
    x = rng.uniform(-20, 40, n)
    y = rng.uniform(-10, 30, n)
    lat, lon = one.to_latlon(x, y)
    lat[5] = np.nan
    lat[6] = ORIGIN[0] + 2.0
    a = rng.normal(0.6, 0.1, n)
    rho = rng.normal(0.08, 0.01, n)
    a[rng.uniform(size=n) < 0.02] = np.nan
    valid = rng.uniform(size=n) > 0.05
    status = np.where(rng.uniform(size=n) < 0.05, 0x20, np.where(rng.uniform(size=n) < 0.1, 0x80, 0))
    hdop = rng.uniform(0.5, 2.5, n)
    t = 0.1 * np.arange(n)
    ref = np.array([one.add(float(lat[i]), float(lon[i]), {"a": a[i], "rho_s": rho[i]}, float(t[i]),
                            valid=bool(valid[i]), status=int(status[i]), hdop=float(hdop[i])) for i in range(n)])
    many = MapStore(tmp_path / "many", *ORIGIN, resolution_m=1.0, tile_cells=8, max_hdop=2.0)
    got = many.add_many(lat, lon, {"a": a, "rho_s": rho, "ignored": a}, t, valid=valid, status=status, hdop=hdop)
    assert np.array_equal(got, ref) and 0 < got.sum() < n
    assert many.stats == one.stats
    for layer in ("a", "rho_s"):
        g1, g2 = one.grid(layer), many.grid(layer)
        assert (g1.x0, g1.y0) == (g2.x0, g2.y0)
        assert np.array_equal(g1.count, g2.count)
        assert np.allclose(g1.mean, g2.mean, rtol=1e-12, atol=0, equal_nan=True)
        assert np.allclose(g1.var, g2.var, rtol=1e-9, atol=0, equal_nan=True)
    t1, t2 = one.track(), many.track()
    assert np.array_equal(t1[:, [0, 3]], t2[:, [0, 3]])
    # scalar (math) and vectorised (numpy) projections differ by round-off only
    assert np.max(np.abs(t1[:, 1:3] - t2[:, 1:3])) < 1e-9
    one.close()
    many.close()


def test_track_waits_in_order_while_the_disk_is_full_and_is_bounded(tmp_path, monkeypatch):
    """Unwritten track records are kept in order across failed flushes, written when space returns,
    and held to ``max_track_pending`` (oldest dropped, counted) if the disk stays full."""
    st = MapStore(tmp_path, *ORIGIN, resolution_m=1.0, tile_cells=10, max_track_pending=50)
    for k in range(10):
        add_xy(st, 1.0 + k, 1.0, {"a": 0.5}, t=float(k))
    st.flush(force=True)
    real_open = os.open

    def full(path, flags, *a, **kw):
        if str(path).endswith("track.log") and flags & os.O_APPEND:
            raise OSError(28, "No space left on device")
        return real_open(path, flags, *a, **kw)

    monkeypatch.setattr(os, "open", full)
    for k in range(10, 40):
        add_xy(st, 1.0, 1.0 + k % 5, {"a": 0.5}, t=float(k))
        if k % 10 == 9:
            with pytest.raises(MapStoreError, match="No space"):
                st.flush(force=True)
    monkeypatch.undo()
    assert st.stats["track_dropped"] == 0
    np.testing.assert_array_equal(st.track()[:, 0], np.arange(40.0))
    st.flush(force=True)
    on_disk, _ = read_track(tmp_path / "track.log")
    np.testing.assert_array_equal(on_disk[:, 0], np.arange(40.0))

    # the disk stays full: memory holds at most 50 records, the oldest go first and are counted
    monkeypatch.setattr(os, "open", full)
    for k in range(40, 200):
        add_xy(st, 1.0, 1.0, {"a": 0.5}, t=float(k))
    monkeypatch.undo()
    pending = st.track()[40:, 0]
    assert 45 <= len(pending) <= 50
    assert st.stats["track_dropped"] == 160 - len(pending)
    np.testing.assert_array_equal(pending, np.arange(200.0 - len(pending), 200.0))
    st.close()


def test_the_manifest_says_which_estimator_level_made_the_map(tmp_path):
    """Issue 14: the map carries the estimation level. A machine-level μ (EstimateStatus 0x4000) is one value
    for all four wheels and must not read as per-wheel precision."""
    st = MapStore(tmp_path, *ORIGIN, resolution_m=0.5)
    assert json.loads((tmp_path / "manifest.json").read_text())["estimate_levels"] == []
    assert add_xy(st, 1.0, 1.0, {"mu": 0.4, "a": 0.7}, 1.0, status=0x4000)
    assert not add_xy(st, 2.0, 1.0, {"mu": 0.4}, 2.0, status=0x4000 | 0x20)      # rejected: no level from it
    st.flush(force=True)
    assert json.loads((tmp_path / "manifest.json").read_text())["estimate_levels"] == ["machine"]
    st.close()
    st = MapStore.open(tmp_path)                                               # resumed: the levels stay
    assert st.estimate_levels == {"machine"}
    lat, lon = st.to_latlon(np.array([3.0, 4.0]), np.array([1.0, 1.0]))
    ok = st.add_many(lat, lon, {"mu": np.array([0.3, 0.35])}, np.array([3.0, 4.0]), status=np.array([0, 0]))
    assert ok.all()
    st.close()
    assert json.loads((tmp_path / "manifest.json").read_text())["estimate_levels"] == ["machine", "wheel"]


def test_a_nan_layer_leaves_the_others_of_a_batch_sample(tmp_path):
    """A replay's map refused every epoch whose windowed `a` was NaN, though its μ and ρ_s were valid (1068
    of 1163 μ samples mapped where the service, which drops a NaN per layer, mapped all 1163)."""
    st = MapStore(tmp_path, *ORIGIN)
    lat, lon = st.to_latlon(np.array([1.0, 1.0, 1.0]), np.array([1.0, 1.0, 1.0]))
    ok = st.add_many(lat, lon, {"a": np.array([0.7, np.nan, np.nan]), "mu": np.array([0.4, 0.5, np.nan])},
                     np.array([0.0, 0.1, 0.2]))
    assert ok.tolist() == [True, True, False] and st.stats["rejected_value"] == 1
    assert st.grid("a").count.sum() == 1 and st.grid("mu").count.sum() == 2
    assert np.nanmax(st.grid("mu").mean) == pytest.approx(0.45)
    st.close()


def test_a_replays_origin_is_not_a_refused_or_glitched_first_fix():
    """A dead-reckoned (or unfixed) first fix 60 km away became the replay map's origin: "map: 0 of 1201
    GNSS epochs mapped (… 1200 beyond the map's range)"."""
    from types import SimpleNamespace

    from tractionecu.mapping.from_replay import replay_origin

    lat = np.r_[47.3333, 47.8816 + 1e-6 * np.arange(30)]
    lon = np.r_[-110.55, np.full(30, -110.5534)]
    q = np.r_[6, np.full(30, 2)]
    assert replay_origin(SimpleNamespace(lat=lat, lon=lon, fix_quality=q))[0] == pytest.approx(47.8816, abs=1e-4)
    q[0] = 2                                          # a measured fix, but one the replay's gate refused
    mask = np.r_[False, np.ones(30, bool)]
    assert replay_origin(SimpleNamespace(lat=lat, lon=lon, fix_quality=q), mask)[0] == pytest.approx(47.8816, abs=1e-4)


def test_a_map_directory_removed_while_open_is_made_again(tmp_path):
    """``rm -rf`` of the service's map directory mid-run: every later flush failed ("No such file or
    directory: …/tiles/…tmp"), the run exited 1 and the 693 samples held in memory were lost."""
    import shutil

    d = tmp_path / "map"
    st = MapStore(d, *ORIGIN, min_flush_interval_s=0.0)
    for k in range(20):
        add_xy(st, k, 0.0, {"a": 0.5}, k)
    st.flush(force=True)
    shutil.rmtree(d)
    for k in range(20, 30):
        add_xy(st, k, 0.0, {"a": 0.6}, k)
    st.flush(force=True)
    st.close()
    assert st.stats["recreated"] == 1 and st.stats["tiles_lost_with_directory"] == 0
    again = MapStore.open(d, read_only=True)
    assert again.grid("a").count.sum() == 30                 # every sample the store held in memory
