"""GGA fix qualities: a code is not an accuracy order, and dead reckoning is no measured position."""

from __future__ import annotations

import numpy as np
import pytest

from tractionecu.gnss.fix import fix_accepted, fix_rank
from tractionecu.mapping.store import MapStore
from tractionecu.pipeline.gnss import GnssGate


def test_ranks_follow_accuracy_not_the_code():
    assert [fix_rank(q) for q in range(9)] == [0, 1, 2, 2, 4, 3, 0, 0, 0]
    assert fix_rank(-1) == 0 and fix_rank(9) == 0 and fix_rank(float("nan")) == 0


@pytest.mark.parametrize("min_q, accepted", [(1, [1, 2, 3, 4, 5]), (2, [2, 3, 4, 5]), (5, [4, 5]), (4, [4])])
def test_dead_reckoning_manual_and_simulated_fixes_are_never_accepted(min_q, accepted):
    """Quality 6 (dead reckoning), 7 (manual) and 8 (simulation), also from RMC modes E/M/S, passed every
    minimum as numbers above it, and RTK float (5) passed a minimum of RTK fixed (4)."""
    q = np.arange(-1, 10)
    ok = fix_accepted(q, min_q)
    assert q[ok].tolist() == accepted
    assert [fix_accepted(int(x), min_q) for x in q] == ok.tolist()
    gate = GnssGate(min_fix_quality=min_q)
    assert [gate.reason(True, int(x), 1.0, 50.0, 8.0) is None for x in q] == ok.tolist()


def test_an_ungated_replay_takes_every_known_quality():
    assert fix_accepted(np.arange(-1, 9), 0).tolist() == [False] + [True] * 9


def test_the_map_refuses_dead_reckoning_and_keeps_an_epoch_without_hdop(tmp_path):
    """An epoch without GGA has no HDOP (NaN): the gate let it through, the map refused it, so a GNSS
    log of RMC and VTG only gave 'map: 0 of 600 GNSS epochs mapped' with no reason."""
    st = MapStore(tmp_path / "m", 50.0, 8.0)
    n = 4
    ok = st.add_many(np.full(n, 50.0), np.full(n, 8.0), {"mu": np.full(n, 0.5)}, np.arange(n) * 0.1,
                     fix_quality=np.array([1, 6, 4, 8]), hdop=np.array([np.nan, 1.0, 0.8, 1.0]))
    assert ok.tolist() == [True, False, True, False]
    assert st.stats["rejected_fix"] == 2
    assert st.add(50.0, 8.0, {"mu": 0.5}, 1.0, fix_quality=1, hdop=float("nan"))
    assert not st.add(50.0, 8.0, {"mu": 0.5}, 1.1, fix_quality=7, hdop=1.0)
    st.close()
