"""The DBC contract and the PGN-based codec."""

import math
from pathlib import Path

import cantools
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tractionecu.bus import dbc as dbcmod
from tractionecu.bus import j1939
from tractionecu.bus.dbc import CONTRACT_SIGNALS, Codec
from tractionecu.errors import ConfigError, DecodeError, UnknownFrame

REPO = Path(__file__).resolve().parents[2]
DBC = REPO / "dbc" / "tractionecu.dbc"
DATA = REPO / "tests" / "data" / "dbc"

# signal: (PGN, start bit, length, signed, scale, offset)  -- docs/architecture.md
CONTRACT = {
    "WheelBasedMachineSpeed": (65096, 0, 16, False, 0.001, 0),
    "WheelBasedMachineDistance": (65096, 16, 32, False, 0.001, 0),
    "WheelBasedMachineDirection": (65096, 56, 2, False, 1, 0),
    "GroundBasedMachineSpeed": (65097, 0, 16, False, 0.001, 0),
    "GroundBasedMachineDistance": (65097, 16, 32, False, 0.001, 0),
    "GroundBasedMachineDirection": (65097, 56, 2, False, 1, 0),
    "RearHitchPosition": (65093, 0, 8, False, 0.4, 0),
    "RearNominalLowerLinkForce": (65093, 16, 8, False, 0.8, -100),
    "DraftForce": (65093, 24, 16, False, 10, -320000),
    **{f"WheelSpeed_{w}": (65296, 16 * i, 16, True, 0.001, 0) for i, w in enumerate(("FL", "FR", "RL", "RR"))},
    **{f"DriveTorque_{w}": (65297, 16 * i, 16, True, 2, 0) for i, w in enumerate(("FL", "FR", "RL", "RR"))},
    "FrontAxleLoad": (65298, 0, 16, False, 5, 0),
    **{f"Adhesion_{w}": (65312, 16 * i, 16, True, 1e-4, 0) for i, w in enumerate(("FL", "FR", "RL", "RR"))},
    **{f"Slip_{w}": (65313, 16 * i, 16, True, 1e-4, 0) for i, w in enumerate(("FL", "FR", "RL", "RR"))},
    "SoilRollingResistance": (65314, 0, 16, False, 1e-5, 0),
    "CurveParamA": (65314, 16, 16, False, 1e-4, 0),
    "EstimateStatus": (65314, 32, 16, False, 1, 0),
    "SoilClassIndex": (65314, 48, 8, False, 1, 0),
}


@pytest.fixture(scope="module")
def codec():
    return Codec(DBC)


def test_cantools_loads_strictly_and_finds_every_contract_signal():
    db = cantools.database.load_file(str(DBC), strict=True)
    names = {s.name for m in db.messages for s in m.signals}
    for name in CONTRACT_SIGNALS:
        assert name in names, name
    assert db.dbc.attributes["ProtocolType"].value == "J1939"


def test_every_message_is_j1939_extended():
    db = cantools.database.load_file(str(DBC), strict=True)
    for m in db.messages:
        assert m.is_extended_frame, m.name
        assert m.protocol == "j1939", m.name
        assert m.frame_id <= 0x1FFFFFFF


def test_contract_layout_and_scaling():
    db = cantools.database.load_file(str(DBC), strict=True)
    for name, (pgn, start, length, signed, scale, offset) in CONTRACT.items():
        m = next(m for m in db.messages if any(s.name == name for s in m.signals))
        s = m.get_signal_by_name(name)
        assert j1939.parse_id(m.frame_id).pgn == pgn, name
        assert (s.start, s.length, s.is_signed, s.byte_order) == (start, length, signed, "little_endian"), name
        assert s.scale == pytest.approx(scale) and s.offset == pytest.approx(offset), name


def test_network_management_messages_present(codec):
    assert codec.message_for_pgn(60928).name == "AddressClaimed"
    assert codec.message_for_pgn(59904).name == "Request"
    assert codec.message("Request").length == 3


def test_signal_names_helper(codec):
    assert codec.signal_names() == list(CONTRACT_SIGNALS)
    assert codec.signal_names("inputs")[:4] == ["WheelSpeed_FL", "WheelSpeed_FR", "WheelSpeed_RL", "WheelSpeed_RR"]
    assert "IdentityNumber" in codec.signal_names("all")
    assert "IdentityNumber" not in codec.signal_names("data")
    assert "DraftForce" in codec.signal_names("data")


def _values_strategy(codec, message):
    sigs = [codec.signals[n] for n in codec.message(message).signals]
    return st.fixed_dictionaries(
        {s.name: st.integers(s.raw_min, s.raw_max).map(lambda r, s=s: r * s.scale + s.offset) for s in sigs}
    )


@pytest.mark.parametrize("message", sorted(Codec(DBC).messages))
def test_encode_decode_round_trip_every_signal(codec, message):
    @settings(max_examples=60, deadline=None)
    @given(values=_values_strategy(codec, message), jitter=st.floats(-0.49, 0.49))
    def check(values, jitter):
        noisy = {k: v + jitter * codec.signals[k].scale for k, v in values.items()}
        can_id, data = codec.encode(message, noisy)
        name, decoded = codec.decode(can_id, data)
        assert name == message
        for k, v in values.items():
            assert abs(decoded[k] - v) <= 0.5 * codec.signals[k].scale * (1 + 1e-9) + 1e-9, k

    check()


def test_decode_by_pgn_from_another_source_address(codec):
    can_id, data = codec.encode("TECU_WheelSpeeds", {f"WheelSpeed_{w}": 2.5 for w in ("FL", "FR", "RL", "RR")})
    assert j1939.parse_id(can_id).sa == 0x80
    other = (can_id & ~0xFF) | 0x21
    prio7 = (other & ~(0x7 << 26)) | (7 << 26)
    for cid in (other, prio7):
        name, values = codec.decode(cid, data)
        assert name == "TECU_WheelSpeeds"
        assert values["WheelSpeed_RR"] == pytest.approx(2.5)


def test_decode_pdu1_whatever_destination(codec):
    data = bytes.fromhex("00EE00")
    for da in (0xFF, 0x00, 0x47):
        name, values = codec.decode(j1939.make_id(6, 59904, 0x17, da), data)
        assert name == "Request" and values["RequestedPGN"] == 60928


def test_encode_uses_given_sa_priority(codec):
    can_id, _ = codec.encode("TECU_EstSlip", {}, sa=0xA1, priority=5)
    assert j1939.parse_id(can_id) == (5, 65313, 0xA1, None)


def test_wrong_dlc_raises_decode_error(codec):
    can_id, data = codec.encode("GBSD", {"GroundBasedMachineSpeed": 1.0})
    with pytest.raises(DecodeError):
        codec.decode(can_id, data[:7])
    with pytest.raises(DecodeError):
        codec.decode(can_id, data + b"\xff")


def test_unknown_pgn_and_11_bit_raise_unknown_frame(codec):
    with pytest.raises(UnknownFrame) as e:
        codec.decode(0x0CF00300, bytes(8))  # EEC2, not in the DBC
    assert e.value.pgn == 61443
    with pytest.raises(UnknownFrame):
        codec.decode(0x123, bytes(8), is_extended=False)


def test_not_available_codes_decode_to_nan(codec):
    # JD 5055E sends GBSD with every byte 0xFF
    _, v = codec.decode(0x0CFE4947, bytes([0xFF] * 8))
    assert math.isnan(v["GroundBasedMachineSpeed"]) and math.isnan(v["GroundBasedMachineDistance"])
    assert v["GroundBasedMachineDirection"] == 3.0
    # raw 0xFAFF is the top of the valid range
    _, v = codec.decode(0x0CFE49F0, bytes([0xFF, 0xFA, 0, 0, 0, 0, 0, 0]))
    assert v["GroundBasedMachineSpeed"] == pytest.approx(64.255)


def test_nan_and_missing_encode_as_not_available(codec):
    can_id, data = codec.encode("TECU_WheelSpeeds", {"WheelSpeed_FL": float("nan"), "WheelSpeed_FR": 1.0})
    assert data[0:2] == b"\x00\x80" and data[4:8] == b"\x00\x80\x00\x80"
    _, v = codec.decode(can_id, data)
    assert math.isnan(v["WheelSpeed_FL"]) and math.isnan(v["WheelSpeed_RR"]) and v["WheelSpeed_FR"] == 1.0


def test_unused_bits_are_ones(codec):
    _, data = codec.encode("TECU_AxleLoad", {"FrontAxleLoad": 0.0, "FrontAxleLoadStatus": 0})
    assert data[2] == 0xFC and data[3:] == b"\xff" * 5


def test_draft_force_offset(codec):
    _, data = codec.encode("RearHitchStatus", {"DraftForce": 0.0})
    assert int.from_bytes(data[3:5], "little") == 32000
    _, data = codec.encode("RearHitchStatus", {"DraftForce": -320000.0})
    assert int.from_bytes(data[3:5], "little") == 0


def test_clipping_is_reported(codec):
    clipped = []
    before = codec.clip_counts["DriveTorque_FL"]
    can_id, data = codec.encode(
        "TECU_DriveTorques", {"DriveTorque_FL": 1e6, "DriveTorque_FR": -1e6, "DriveTorque_RL": 10.0}, clipped=clipped
    )
    assert clipped == ["DriveTorque_FL", "DriveTorque_FR"]
    assert codec.clip_counts["DriveTorque_FL"] == before + 1
    _, v = codec.decode(can_id, data)
    assert v["DriveTorque_FL"] == 65534 and v["DriveTorque_FR"] == -65534 and v["DriveTorque_RL"] == 10


def test_unknown_signal_name_rejected(codec):
    with pytest.raises(KeyError):
        codec.encode("TECU_EstSoil", {"SoilRollingResistence": 0.1})


def test_installed_contract_is_the_repo_dbc():
    # editable install: the very file; normal install: the copy in the wheel
    assert dbcmod.package_dbc_path().read_bytes() == DBC.read_bytes()
    assert Codec().path == dbcmod.package_dbc_path()


def test_codec_falls_back_to_repo_dbc_when_not_installed(monkeypatch):
    def not_installed():
        raise ModuleNotFoundError("No module named 'tractionecu.contract'")

    monkeypatch.setattr(dbcmod, "package_dbc_path", not_installed)
    assert dbcmod.default_dbc_path() == dbcmod.repo_dbc_path()
    assert Codec().path.resolve() == DBC.resolve()


def test_default_codec_uses_repo_dbc_in_a_checkout():
    assert Codec().path.resolve() == DBC.resolve()


def test_pyproject_lists_every_package():
    # pyproject.toml maps tractionecu.contract onto dbc/, so packages are listed, not found
    tomllib = pytest.importorskip("tomllib")
    tool = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    tree = {".".join(p.parent.relative_to(REPO).parts) for p in (REPO / "tractionecu").rglob("__init__.py")}
    assert set(tool["packages"]) == tree | {"tractionecu.contract"}
    assert tool["package-dir"] == {"tractionecu.contract": "dbc"}


def test_missing_contract_signal_is_a_config_error():
    with pytest.raises(ConfigError, match="WheelSpeed_RR"):
        Codec(DATA / "missing_contract_signal.dbc")


def test_missing_dbc_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="absent.dbc"):
        Codec(tmp_path / "absent.dbc")
