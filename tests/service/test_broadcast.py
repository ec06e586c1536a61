"""The estimate frames carry every status bit: bits 0–15 in EstimateStatus, bits 16–23 in EstimateStatusExt."""

from types import SimpleNamespace

import pytest

from tractionecu.bus.dbc import default_codec
from tractionecu.estimation.estimator import NOT_CONVERGED, SLIP_AVERAGED, SLIP_UNCERTAIN
from tractionecu.service.broadcast import NO_DATA_STATUS, estimate_frames, no_estimate_frames


def _soil(frames, codec):
    for can_id, data in frames:
        name, vals = codec.decode(can_id, data)
        if name == "TECU_EstSoil":
            return vals
    raise AssertionError("no TECU_EstSoil frame")


@pytest.mark.parametrize("status", [0, NOT_CONVERGED, SLIP_UNCERTAIN, SLIP_AVERAGED | NOT_CONVERGED])
def test_status_bits_above_16_reach_the_bus(status):
    codec = default_codec()
    est = SimpleNamespace(mu=[0.5] * 4, slip=[0.05] * 4, rho_s=0.06, a=0.8, status=status, soil_class_index=1)
    vals = _soil(estimate_frames(codec, est, sa=0x80, priority=6), codec)
    assert int(vals["EstimateStatus"]) == status & 0xFFFF
    assert int(vals["EstimateStatusExt"]) == status >> 16
    assert int(vals["EstimateStatus"]) | int(vals["EstimateStatusExt"]) << 16 == status


def test_no_estimate_frames_clear_the_extended_bits():
    codec = default_codec()
    vals = _soil(no_estimate_frames(codec, sa=0x80, priority=6), codec)
    assert int(vals["EstimateStatus"]) == NO_DATA_STATUS & 0xFFFF
    assert int(vals["EstimateStatusExt"]) == NO_DATA_STATUS >> 16
