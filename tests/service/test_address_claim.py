"""J1939 address claim against the real John Deere 5055E start-up claims and requests."""

from __future__ import annotations

import dataclasses
import random
from pathlib import Path

import pytest

from tractionecu.bus import j1939
from tractionecu.bus.candump import read_candump
from tractionecu.service.address_claim import (
    CANNOT_CLAIM_MAX_DELAY_S,
    CLAIM_WAIT_S,
    AddressClaimer,
    ClaimState,
    address_claimed_id,
)
from tractionecu.service.config import default_name

JD_LOG = Path(__file__).resolve().parents[1] / "data" / "candump" / "jd5055e_excerpt.log"
JD_ADDRESSES = {0x00, 0x03, 0x06, 0x17, 0x47}


def jd_frames():
    frames = list(read_candump(JD_LOG))
    t0 = frames[0].t
    return [(f.t - t0, f.can_id, f.data) for f in frames]


def run(claimer: AddressClaimer, t_start: float = -0.1):
    """Start before the capture, feed every JD frame; returns every Tx with its time."""
    out = [(t_start, tx) for tx in claimer.start(t_start)]
    for t, cid, data in jd_frames():
        out += [(t, tx) for tx in claimer.handle(t, cid, data)]
    claimer.can_transmit(jd_frames()[-1][0])  # lets CLAIMING become CLAIMED after 250 ms
    return out


def test_jd_capture_has_what_the_tests_rely_on() -> None:
    claims = {cid & 0xFF for _, cid, _ in jd_frames() if j1939.pgn_of(cid) == j1939.PGN_ADDRESS_CLAIMED}
    assert claims == JD_ADDRESSES
    names = {j1939.Name.from_bytes(d) for _, c, d in jd_frames() if j1939.pgn_of(c) == j1939.PGN_ADDRESS_CLAIMED}
    assert all(n.industry_group == 2 and not n.arbitrary_address_capable for n in names)


def test_free_preferred_address_is_kept_and_requests_answered() -> None:
    cl = AddressClaimer(default_name(), 0x90)
    out = run(cl)
    assert cl.state is ClaimState.CLAIMED and cl.address == 0x90
    first = out[0][1]
    assert first.can_id == 0x18EEFF90 and first.data == default_name().to_bytes()
    # the capture holds four global Requests for Address Claimed; every one is answered
    global_requests = [1 for _, c, d in jd_frames()
                       if j1939.pgn_of(c) == j1939.PGN_REQUEST and (c >> 8) & 0xFF == 0xFF
                       and j1939.requested_pgn(d) == j1939.PGN_ADDRESS_CLAIMED]
    assert len(global_requests) == 4
    assert cl.counts["requests_answered"] == 4
    assert all(tx.can_id == 0x18EEFF90 for _, tx in out)
    # requests to 0x00, 0x03, 0x06, 0x47 (from 0x17) are not for us
    assert len(out) == 1 + 4
    assert set(cl.table) == JD_ADDRESSES


def test_transmit_only_250_ms_after_an_uncontested_claim() -> None:
    cl = AddressClaimer(default_name(), 0x90)
    cl.start(10.0)
    assert not cl.can_transmit(10.0 + CLAIM_WAIT_S - 1e-3)
    assert cl.can_transmit(10.0 + CLAIM_WAIT_S)


def test_self_configurable_loses_to_jd_and_moves() -> None:
    cl = AddressClaimer(default_name(), 0x47)   # the JD ECU at 0x47 has a lower (stronger) NAME
    out = run(cl)
    assert cl.counts["contentions_lost"] == 1
    assert cl.state is ClaimState.CLAIMED
    assert cl.address not in JD_ADDRESSES and 128 <= cl.address <= 247
    assert out[-1][1].can_id == address_claimed_id(cl.address) or cl.counts["requests_answered"]
    claims = [tx.can_id & 0xFF for _, tx in out]
    assert claims[0] == 0x47 and cl.address in claims


def test_fixed_address_name_loses_sends_cannot_claim_and_stays_silent() -> None:
    # fixed address, and numerically above the JD tractor ECU's NAME 0x200200000429F556
    fixed = dataclasses.replace(default_name(), arbitrary_address_capable=False, vehicle_system=127)
    assert fixed.to_int() > 0x200200000429F556
    cl = AddressClaimer(fixed, 0x00, rng=random.Random(1))   # 0x00 is the JD tractor ECU's address
    out = run(cl)
    assert cl.state is ClaimState.CANNOT_CLAIM and cl.address is None
    cannot = [(t, tx) for t, tx in out if tx.can_id == address_claimed_id(j1939.ADDRESS_NULL)]
    assert cannot and cannot[0][1].data == fixed.to_bytes()
    assert cannot[0][1].delay_s == 0.0  # the immediate answer to the lost contention
    # later global Requests get Cannot Claim after a pseudo-random delay of 0..153 ms
    assert all(0.0 <= tx.delay_s <= CANNOT_CLAIM_MAX_DELAY_S for _, tx in cannot[1:])
    assert len(cannot) >= 2
    assert not cl.can_transmit(100.0)
    assert all(tx.can_id == address_claimed_id(j1939.ADDRESS_NULL) for t, tx in out if t > cannot[0][0])


def test_stronger_name_defends_its_address() -> None:
    strong = j1939.Name(identity_number=1, industry_group=2)   # 0x2000000000000001 < every JD NAME
    cl = AddressClaimer(strong, 0x47)
    out = run(cl)
    assert cl.state is ClaimState.CLAIMED and cl.address == 0x47
    assert cl.counts["contentions_won"] == 3  # the capture repeats the 0x47 claim three times
    assert sum(tx.can_id == 0x18EEFF47 for _, tx in out) == 1 + 3 + cl.counts["requests_answered"]


def test_start_skips_an_address_already_claimed_by_a_stronger_name() -> None:
    cl = AddressClaimer(default_name(), 0x47)
    for t, cid, data in jd_frames():
        cl.handle(t, cid, data)
    txs = cl.start(2.0)
    assert txs[0].can_id & 0xFF not in JD_ADDRESSES


def test_cannot_claim_from_another_name_frees_its_address() -> None:
    cl = AddressClaimer(default_name(), 0x90)
    other = j1939.Name(identity_number=7, industry_group=2).to_bytes()
    cl.handle(0.0, address_claimed_id(0x91), other)
    assert cl.table == {0x91: int.from_bytes(other, "little")}
    cl.handle(0.1, address_claimed_id(j1939.ADDRESS_NULL), other)
    assert cl.table == {}


def test_malformed_and_unrelated_frames() -> None:
    cl = AddressClaimer(default_name(), 0x90)
    cl.start(0.0)
    assert cl.handle(0.1, address_claimed_id(0x90), b"\x01\x02") == []
    assert cl.handle(0.1, j1939.make_id(6, j1939.PGN_REQUEST, 0x10, 0xFF), b"\x00") == []
    assert cl.counts["malformed"] == 2
    # a Request for another PGN, and one addressed to somebody else
    assert cl.handle(0.2, j1939.make_id(6, j1939.PGN_REQUEST, 0x10, 0xFF), j1939.request_data(65262)) == []
    assert cl.handle(0.2, j1939.make_id(6, j1939.PGN_REQUEST, 0x10, 0x22),
                     j1939.request_data(j1939.PGN_ADDRESS_CLAIMED)) == []
    # a Request addressed to us is answered
    txs = cl.handle(0.3, j1939.make_id(6, j1939.PGN_REQUEST, 0x10, 0x90), j1939.request_data(j1939.PGN_ADDRESS_CLAIMED))
    assert [t.can_id for t in txs] == [0x18EEFF90]
    # our own claim echoed back changes nothing
    assert cl.handle(0.4, address_claimed_id(0x90), default_name().to_bytes()) == []
    assert cl.handle(0.4, 0x0CF00400, bytes(8)) == []


def test_no_free_address_left_gives_cannot_claim() -> None:
    cl = AddressClaimer(default_name(), 0x90, address_range=(0x90, 0x91))
    strong = j1939.Name(identity_number=1, industry_group=2).to_bytes()
    cl.start(0.0)
    cl.handle(0.01, address_claimed_id(0x91), j1939.Name(identity_number=2, industry_group=2).to_bytes())
    txs = cl.handle(0.02, address_claimed_id(0x90), strong)
    assert cl.state is ClaimState.CANNOT_CLAIM
    assert txs[0].can_id == address_claimed_id(j1939.ADDRESS_NULL)


@pytest.mark.parametrize("bad", [-1, 254, 300])
def test_preferred_address_range(bad: int) -> None:
    with pytest.raises(ValueError):
        AddressClaimer(default_name(), bad)
