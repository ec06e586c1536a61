"""J1939 identifier and NAME helpers."""

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tractionecu.bus import j1939
from tractionecu.bus.j1939 import Name, make_id, parse_id


def test_pdu2_id_round_trip_known_value():
    # WBSD from the tractor ECU: priority 3, PGN 0xFE48, SA 0xF0
    assert make_id(3, 65096, 0xF0) == 0x0CFE48F0
    assert parse_id(0x0CFE48F0) == (3, 65096, 0xF0, None)


def test_pdu1_destination_is_masked_out_of_pgn():
    # Address Claimed to global, as on the John Deere bus
    assert parse_id(0x18EEFF47) == (6, 60928, 0x47, 0xFF)
    # Proprietary A (0xEF00) from 0x00 to 0x06
    cid = parse_id(0x18EF0600)
    assert cid.pgn == 61184 and cid.da == 0x06 and cid.sa == 0x00
    assert make_id(6, 61184, 0x00, 0x06) == 0x18EF0600


def test_pdu1_on_data_page_1():
    # PGN 126720 = 0x1EF00 (proprietary A2) to DA 6 from SA 3
    can_id = make_id(3, 126720, 3, 6)
    assert can_id == 0x0DEF0603
    assert parse_id(can_id) == (3, 126720, 3, 6)


def test_pdu1_default_destination_is_global():
    assert parse_id(make_id(6, j1939.PGN_REQUEST, 0x90)).da == 0xFF


@pytest.mark.parametrize(
    "args",
    [(8, 65096, 0), (3, 0x40000, 0), (3, 65096, 256), (6, 0xEE01, 0), (3, 65096, 0, 5), (6, 60928, 0, 256)],
)
def test_make_id_rejects_bad_fields(args):
    with pytest.raises(ValueError):
        make_id(*args)


def test_parse_id_rejects_more_than_29_bits():
    with pytest.raises(ValueError):
        parse_id(0x20000000)


@given(
    prio=st.integers(0, 7),
    dp=st.integers(0, 1),
    pf=st.integers(0, 255),
    ps=st.integers(0, 255),
    sa=st.integers(0, 255),
)
def test_parse_make_round_trip(prio, dp, pf, ps, sa):
    can_id = (prio << 26) | (dp << 24) | (pf << 16) | (ps << 8) | sa
    cid = parse_id(can_id)
    if pf < 240:
        assert cid.pgn == (dp << 16) | (pf << 8) and cid.da == ps
    else:
        assert cid.pgn == (dp << 16) | (pf << 8) | ps and cid.da is None
    assert make_id(cid.priority, cid.pgn, cid.sa, cid.da) == can_id


def test_name_of_real_john_deere_claim():
    # Address Claimed data of SA 0x47 on the JD 5055E capture
    n = Name.from_bytes(bytes.fromhex("4D74300400340220"))
    assert n.to_int() == 0x200234000430744D
    assert n.identity_number == 0x10744D
    assert n.manufacturer_code == 33
    assert n.function == 52
    assert n.vehicle_system == 1
    assert n.industry_group == j1939.INDUSTRY_GROUP_AGRICULTURE
    assert n.arbitrary_address_capable is False
    assert n.to_bytes() == bytes.fromhex("4D74300400340220")


def test_self_configurable_bit_is_bit_63():
    n = Name(arbitrary_address_capable=True)
    assert n.to_int() == 1 << 63
    assert n.to_bytes()[7] == 0x80


names = st.builds(
    Name,
    identity_number=st.integers(0, (1 << 21) - 1),
    manufacturer_code=st.integers(0, (1 << 11) - 1),
    ecu_instance=st.integers(0, 7),
    function_instance=st.integers(0, 31),
    function=st.integers(0, 255),
    reserved=st.integers(0, 1),
    vehicle_system=st.integers(0, 127),
    vehicle_system_instance=st.integers(0, 15),
    industry_group=st.integers(0, 7),
    arbitrary_address_capable=st.booleans(),
)


@given(names)
def test_name_round_trip(n):
    assert Name.from_int(n.to_int()) == n
    assert Name.from_bytes(n.to_bytes()) == n


def test_name_field_overflow_rejected():
    with pytest.raises(ValueError):
        Name(function_instance=32)
    with pytest.raises(ValueError):
        Name.from_bytes(b"\x00" * 7)


def test_request_data():
    assert j1939.request_data(60928) == bytes.fromhex("00EE00")
    assert j1939.requested_pgn(bytes.fromhex("00EE00")) == 60928


def test_service_address_in_self_configurable_range():
    assert 128 <= j1939.DEFAULT_SERVICE_ADDRESS <= 235
    assert j1939.DEFAULT_SERVICE_ADDRESS not in (j1939.TECU_ADDRESS, j1939.DRIVETRAIN_ECU_ADDRESS)
