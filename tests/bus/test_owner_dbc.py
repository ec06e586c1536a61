"""The owner's own DBC beside the built-in one: messages added by PGN, names, clashes, the [signals] mapping."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from tractionecu.bus import dbc as dbcmod
from tractionecu.bus.dbc import Codec, default_codec, extra_dbcs
from tractionecu.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]
OWNER = REPO / "tests" / "data" / "dbc" / "owner_drivectrl.dbc"
RPM = 2 * math.pi / 60


@pytest.fixture(scope="module")
def codec():
    return Codec(extra=[OWNER])


def one_message_dbc(path: Path, name: str, frame_id: int, signal: str = "Speed") -> Path:
    path.write_text('VERSION ""\nNS_ :\nBS_:\nBU_: X\n'
                    f'BO_ {frame_id} {name}: 8 X\n SG_ {signal} : 0|16@1+ (1,0) [0|0] "" X\n')
    return path


def test_owner_messages_decode_by_pgn_under_message_dot_signal_names(codec):
    assert codec.messages["DriveCtrl_3"].source == OWNER.name and codec.messages["DriveCtrl_3"].pgn == 0xFF55
    assert codec.messages["EEC1"].source == "tractionecu.dbc"
    data = (1234).to_bytes(2, "little") + (0).to_bytes(2, "little") + b"\xff\xff" + (65534).to_bytes(2, "little")
    for sa in (0x27, 0x80, 0x03):                                   # any source address
        name, v = codec.decode(0x18FF5500 | sa, data)
        assert name == "DriveCtrl_3"
        assert v["DriveCtrl_3.WhlSpdFL"] == pytest.approx(12.34) and v["DriveCtrl_3.WhlSpdFR"] == 0
        assert math.isnan(v["DriveCtrl_3.WhlSpdRL"]) and v["DriveCtrl_3.WhlSpdRR"] == pytest.approx(655.34)
    # the same signal name in two messages; a big-endian signed signal with no range ([0|0]: full raw range)
    _, v = codec.decode(0x18FF5627, bytes([0x03, 0x80, 0xFF, 0x38, 0, 0, 0, 0]))
    assert v == {"DriveCtrl_4.Counter": 3, "DriveCtrl_4.GearLever": 3, "DriveCtrl_4.HitchDraft": pytest.approx(-2.0)}
    assert codec.signals["DriveCtrl_4.HitchDraft"].raw_min == -32768


def test_an_unranged_unsigned_owner_signal_takes_all_ones_as_not_available(tmp_path):
    """An owner DBC's 16-bit wheel speed with [0|0] decoded 0xFFFF ("not available" on the bus) as 655.35 rpm,
    20× the real speed, and the estimates were marked valid with μ from −1.1 to +1.2."""
    dbc = tmp_path / "own.dbc"
    dbc.write_text('VERSION ""\n\nNS_ :\n\nBS_:\n\nBU_: X\n\n'
                   'BO_ 2566873127 Own_1: 8 X\n SG_ Spd : 0|16@1+ (0.01,0) [0|0] "rpm" X\n'
                   ' SG_ Flags : 16|2@1+ (1,0) [0|0] "" X\n SG_ Trim : 24|16@1- (1,0) [0|0] "" X\n')
    codec = dbcmod.Codec(extra=[dbc])
    _, v = codec.decode(0x18FF6027, bytes([0xFF, 0xFF, 0x03, 0xFF, 0xFF, 0, 0, 0]))
    assert math.isnan(v["Own_1.Spd"]) and v["Own_1.Flags"] == 3 and v["Own_1.Trim"] == -1
    _, v = codec.decode(0x18FF6027, bytes([0xFE, 0xFF, 0, 0, 0, 0, 0, 0]))
    assert v["Own_1.Spd"] == pytest.approx(655.34)


def test_multiplexed_messages_are_skipped_and_listed(codec):
    assert {(m, why.split(" ")[0]) for _, m, why in codec.skipped} == {("DriveCtrl_5", "multiplexed")}
    assert codec.message_for_pgn(0xFF57) is None and "DriveCtrl_5" not in codec.messages


def test_an_owner_message_on_an_11_bit_identifier_decodes_by_that_identifier(codec):
    """A CANedge logger's GNSS frames, an implement's own bus: CAN 2.0A identifiers of the owner's DBC."""
    info = codec.messages["Dash_Lamps"]
    assert info.pgn is None and info.std_id == 0x3A0 and codec.message_for_std_id(0x3A0) is info
    assert codec.decode(0x3A0, bytes([1, 0]), False) == ("Dash_Lamps", {"Dash_Lamps.Beacon": 1.0})
    with pytest.raises(dbcmod.UnknownFrame):
        codec.decode(0x3A1, bytes(2), False)                       # an 11-bit identifier no DBC defines
    with pytest.raises(dbcmod.UnknownFrame):
        codec.decode(0x3A0, bytes(2), True)                        # the same number as a 29-bit identifier
    with pytest.raises(dbcmod.DecodeError, match=r"Dash_Lamps \(11-bit ID 0x3a0\): DLC 8, expected 2"):
        codec.decode(0x3A0, bytes(8), False)
    assert codec.resolve("Dash_Lamps.Beacon") == "Dash_Lamps.Beacon"
    assert not default_codec().has_std_ids and codec.has_std_ids
    with pytest.raises(dbcmod.UnknownFrame):
        default_codec().decode(0x3A0, bytes(2), False)             # the built-in DBC alone: J1939 only


def test_an_11_bit_identifier_or_name_defined_twice(tmp_path):
    a = one_message_dbc(tmp_path / "a.dbc", "Lamps", 0x3A0)
    with pytest.raises(ConfigError, match=r"11-bit identifier 0x3a0 defined twice: Dash_Lamps in owner_drivectrl"):
        Codec(extra=[OWNER, a])
    twice = tmp_path / "twice.dbc"                                  # one name on two identifiers of one file
    twice.write_text('VERSION ""\nNS_ :\nBS_:\nBU_: X\n'
                     'BO_ 3 gnss_pos: 8 X\n SG_ Lat : 0|16@1+ (1,0) [0|0] "" X\n'
                     'BO_ 19 gnss_pos: 8 X\n SG_ Lat : 0|16@1+ (1,0) [0|0] "" X\n')
    c = Codec(extra=[twice])
    assert c.messages["gnss_pos"].std_id == 3 and c.message_for_std_id(19) is None
    assert c.skipped == [("twice.dbc", "gnss_pos", "defined again on another 11-bit identifier (the first is decoded)")]


def test_a_pgn_defined_twice_names_both_files(tmp_path):
    clash = one_message_dbc(tmp_path / "clash.dbc", "MyWheels", 0x80000000 | 0x18FF1027)    # PGN 65296
    with pytest.raises(ConfigError) as e:
        Codec(extra=[clash])
    msg = str(e.value)
    assert "PGN 65296" in msg and "TECU_WheelSpeeds in tractionecu.dbc" in msg and "MyWheels in clash.dbc" in msg
    other = one_message_dbc(tmp_path / "other.dbc", "Again", 0x80000000 | 0x18FF5599)        # PGN 0xFF55 again
    with pytest.raises(ConfigError, match=r"DriveCtrl_3 in owner_drivectrl\.dbc, Again in other\.dbc"):
        Codec(extra=[OWNER, other])


def test_a_message_name_defined_twice_names_both_files(tmp_path):
    same = one_message_dbc(tmp_path / "same.dbc", "EEC1", 0x80000000 | 0x18FF6001)
    with pytest.raises(ConfigError, match=r"message name EEC1 defined twice: EEC1 in tractionecu\.dbc, EEC1 in same"):
        Codec(extra=[same])


def test_bad_extra_files_are_config_errors(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        Codec(extra=[tmp_path / "absent.dbc"])
    (tmp_path / "junk.dbc").write_text("BO_ this is not a DBC\n")
    with pytest.raises(ConfigError, match="junk.dbc"):
        Codec(extra=[tmp_path / "junk.dbc"])


def test_mapping_resolves_and_names_the_bad_key(codec):
    ok = codec.resolve_mapping({"WheelSpeed_FL": ("DriveCtrl_3.WhlSpdFL", RPM),
                                "DraftForce": ("DriveCtrl_4.HitchDraft", 1000.0),
                                "WheelBasedVehicleSpeed": ("CCVS1.WheelBasedVehicleSpeed", 1.0)})
    assert ok == [("WheelSpeed_FL", "DriveCtrl_3.WhlSpdFL", RPM), ("DraftForce", "DriveCtrl_4.HitchDraft", 1000.0),
                  ("WheelBasedVehicleSpeed", "WheelBasedVehicleSpeed", 1.0)]
    cases = {
        "WheelSpeed_XX": ("DriveCtrl_3.WhlSpdFL", "signals.WheelSpeed_XX: not a contract signal"),
        "Adhesion_FL": ("DriveCtrl_3.WhlSpdFL", "signals.Adhesion_FL: not a contract signal"),       # an output
        # the efficiency report is the service's output too (an owner signal mapped onto it was taken and read
        # by nothing, and the list of the known names offered it)
        "OptimalSlip": ("DriveCtrl_3.WhlSpdFL", "signals.OptimalSlip: not a contract signal"),
        "WheelSpeed_FR": ("DriveCtrl_9.WhlSpdFR", "signals.WheelSpeed_FR: no message 'DriveCtrl_9'"),
        "WheelSpeed_RL": ("DriveCtrl_3.WhlSpdXL", "signals.WheelSpeed_RL: message DriveCtrl_3 (owner_drivectrl.dbc) "
                                                  "has no signal 'WhlSpdXL' (it has WhlSpdFL"),
        "WheelSpeed_RR": ("WhlSpdRR", "signals.WheelSpeed_RR: 'WhlSpdRR' is not a signal of tractionecu.dbc; "
                                      "write Message.Signal"),
        "DriveTorque_FL": ("DriveCtrl_5.OilTemp", "signals.DriveTorque_FL: no message 'DriveCtrl_5'"),   # skipped
    }
    for target, (ref, text) in cases.items():
        with pytest.raises(ConfigError) as e:
            codec.resolve_mapping({target: (ref, 1.0)})
        assert text in str(e.value), (target, str(e.value))
        assert "OptimalSlip" not in str(e.value).partition("(known:")[2]


def test_without_the_owner_dbc_the_error_says_to_give_it():
    with pytest.raises(ConfigError, match=r"signals.WheelSpeed_FL: no message 'DriveCtrl_3' in the loaded DBCs "
                                          r"\(tractionecu.dbc\); add the owner's DBC \(--dbc FILE for replay, "
                                          r'inspect and diagnose; dbc = \["FILE"\] in the service.s \[can\] table\)'):
        Codec().resolve_mapping({"WheelSpeed_FL": ("DriveCtrl_3.WhlSpdFL", 1.0)})


def test_extra_dbcs_block_extends_the_shared_codec_and_restores_it():
    before = default_codec()
    with extra_dbcs([OWNER]) as c:
        assert default_codec() is c and "DriveCtrl_3" in c.messages and c.extra_paths == (OWNER,)
    assert dbcmod.default_codec() is before and "DriveCtrl_3" not in before.messages
    with extra_dbcs([]) as c:
        assert c is before
    with pytest.raises(ConfigError):
        with extra_dbcs([OWNER.with_name("absent.dbc")]):
            pass
    assert default_codec() is before


def test_skipped_messages_are_logged_once_per_file_and_reason(tmp_path, caplog):
    """An owner's DBC with skipped messages (the CANedge gnss.dbc defines its 9 messages twice, on two
    identifiers) logged one warning per message and again for every codec built from it (inspect --dbc:
    18 lines)."""
    p = tmp_path / "gnss.dbc"
    p.write_text('VERSION ""\nNS_ :\nBS_:\nBU_: X\n'
                 'BO_ 3 gnss_pos: 8 X\n SG_ Lat : 0|16@1+ (1,0) [0|0] "" X\n'
                 'BO_ 7 gnss_speed: 8 X\n SG_ Speed : 0|16@1+ (1,0) [0|0] "" X\n'
                 'BO_ 19 gnss_pos: 8 X\n SG_ Lat : 0|16@1+ (1,0) [0|0] "" X\n'
                 'BO_ 23 gnss_speed: 8 X\n SG_ Speed : 0|16@1+ (1,0) [0|0] "" X\n')
    with caplog.at_level("WARNING", logger="tractionecu.bus.dbc"):
        for _ in range(3):
            c = Codec(extra=[p])
            assert [m for _, m, _ in c.skipped] == ["gnss_pos", "gnss_speed"]      # still listed every time
    lines = [r.getMessage() for r in caplog.records if r.name == "tractionecu.bus.dbc"]
    assert lines == ["dbc: gnss.dbc: 2 message(s) skipped, defined again on another 11-bit identifier (the first is "
                     "decoded): gnss_pos, gnss_speed"]


def test_a_signal_of_another_quantity_needs_a_scale(codec):
    # a wheel speed in rpm mapped onto a drive torque or the draft was decoded as N·m or N without a word
    for target, unit in (("DriveTorque_FL", "torque in Nm"), ("DraftForce", "force in N")):
        with pytest.raises(ConfigError) as e:
            codec.resolve_mapping({target: ("DriveCtrl_3.WhlSpdFL", 1.0)})
        assert (f"signals.{target}: DriveCtrl_3.WhlSpdFL is a rotational speed in rpm, {target} a {unit}: "
                f"map a {unit.split(' in ')[0]} signal, or give the scale") in str(e.value)
    # a draft in kN onto the axle load (one quantity), and a wheel speed onto a ground speed with the tyre's
    # radius as its scale (a deliberate conversion) are taken
    assert codec.resolve_mapping({"FrontAxleLoad": ("DriveCtrl_4.HitchDraft", 1000.0)})
    assert codec.resolve_mapping({"WheelBasedVehicleSpeed": ("DriveCtrl_3.WhlSpdFL", RPM * 0.8)})
    # a signal without a known unit is not judged
    assert codec.resolve_mapping({"DriveTorque_FL": ("DriveCtrl_4.GearLever", 1.0)})
