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
