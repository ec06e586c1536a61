"""The service's map writer when its directory cannot be written."""

from __future__ import annotations

import asyncio
import logging
from types import SimpleNamespace

import numpy as np

from tractionecu.service.config import MapConfig
from tractionecu.service.gps import GpsSample
from tractionecu.service.mapwriter import MapWriter


def _est(t: float) -> SimpleNamespace:
    nan4 = np.full(4, np.nan)
    return SimpleNamespace(t=t, mu=np.full(4, 0.4), slip=np.full(4, 0.05), rho_s=0.05, a=0.8, v=2.5, valid=True,
                           status=0, soil_class="stubble", P_diag=np.zeros(9), curve_state=None, sigma_mu=nan4)


async def test_an_unwritable_map_directory_is_reported_once_and_retried_with_a_wait(tmp_path, caplog):
    """A map directory under a regular file logged 'cannot open' once per 10 Hz sample (103 identical ERROR
    lines in 10 simulated seconds), and neither the status line nor the page said the map was not written."""
    (tmp_path / "afile").write_text("")
    mw = MapWriter(MapConfig(), tmp_path / "afile" / "map")
    await mw.open()
    caplog.set_level(logging.DEBUG, logger="tractionecu.service.mapwriter")
    for k in range(100):                                 # 10 s of samples at 10 Hz
        fix = GpsSample(k * 0.1, k * 0.1, 48.0 + k * 1e-6, 11.0, 500.0, 2.5, 90.0, 4, 0.8, 12)
        mw.add(_est(k * 0.1), fix)
        await asyncio.sleep(0.002)
    errors = [r for r in caplog.records if r.levelno >= logging.ERROR]
    assert len(errors) == 1 and "cannot open" in errors[0].getMessage()
    assert 1 <= mw.stats["open_errors"] <= 3                # retried after a doubling wait, not per sample
    assert mw.state.startswith("ERROR: cannot open")
    await mw.close()


async def test_positions_beyond_the_maps_range_are_said_not_dropped_silently(tmp_path, caplog):
    """A map whose origin lay 64 km from the field took none of the service's samples, with no warning and the
    status still "writing" (map_samples 0, map_tiles_written 0)."""
    import dataclasses

    cfg = dataclasses.replace(MapConfig(), origin_lat=47.30, origin_lon=11.0)
    mw = MapWriter(cfg, tmp_path / "map")
    await mw.open()
    caplog.set_level(logging.DEBUG, logger="tractionecu.service.mapwriter")
    for k in range(150):          # 15 s at 10 Hz (mapped 10 s late), 0.58° (64 km) north of the origin
        fix = GpsSample(k * 0.1, k * 0.1, 47.88 + k * 1e-6, 11.0, 500.0, 2.5, 0.0, 4, 0.8, 12)
        mw.add(_est(k * 0.1), fix)
        await asyncio.sleep(0.002)
    warned = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warned) == 1 and "64 km from the map's origin" in warned[0] and "beyond the 50 km" in warned[0]
    assert mw.stats["beyond_range"] > 20 and mw.stats["added"] == 0
    assert mw.state.startswith("NOT MAPPING: 64 km from the map's origin")
    await mw.close()


async def test_a_full_disk_when_a_map_with_a_set_origin_is_made_leaves_it_to_be_made_later(tmp_path, monkeypatch):
    """With ``map.origin_lat/lon`` set the map is made at start: on a full disk its manifest could not be written
    and the service stopped with a traceback (exit 1).  The map is now opened again later, as one that could not
    be opened at its first fix, and at the set origin, not at the fix."""
    import dataclasses
    import errno

    from tractionecu.mapping import store as store_module
    from tractionecu.service import mapwriter

    def full(directory, manifest):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(mapwriter, "OPEN_RETRY_MIN_S", 0.05)
    monkeypatch.setattr(store_module, "write_manifest", full)
    cfg = dataclasses.replace(MapConfig(), origin_lat=47.88, origin_lon=11.0, window_half_s=0.3)
    mw = MapWriter(cfg, tmp_path / "map")
    await mw.open()
    assert mw.store is None and mw.stats["open_errors"] == 1 and mw.state.startswith("ERROR: cannot open")
    monkeypatch.undo()                                          # space again
    mw._open_backoff_s = 0.05
    for k in range(40):
        fix = GpsSample(k * 0.1, k * 0.1, 47.8801 + k * 1e-6, 11.0001, 500.0, 2.5, 0.0, 4, 0.8, 12)
        mw.add(_est(k * 0.1), fix)
        await asyncio.sleep(0.01)
    assert mw.store is not None and mw.state == "writing"
    assert (mw.store.frame.origin_lat, mw.store.frame.origin_lon) == (47.88, 11.0)
    assert mw.stats["added"] > 0
    await mw.close()
