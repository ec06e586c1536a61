"""The standard J1939 / ISO 11783 messages of the DBC, on frames built by hand from the standards' layouts.

Every frame here is written byte by byte from SAE J1939-71 (EEC1, EC1, ETC2,
CCVS1, EBC2) and ISO 11783-7 (WBSD, rear hitch status), not encoded with the
DBC: a wrong start bit, length, resolution or offset in the DBC fails here.
"""

from __future__ import annotations

import math
import struct

import cantools
import pytest

from tractionecu.bus import j1939
from tractionecu.bus.dbc import J1939_VALID_MAX, Codec, default_dbc_path
from tractionecu.errors import DecodeError

RPM = 2 * math.pi / 60          # rad/s per rpm
KMH = 1 / 3.6                   # m/s per km/h


@pytest.fixture(scope="module")
def codec():
    return Codec()


def frame(pgn: int, data: bytes, sa: int = 0x00, priority: int = 6) -> tuple[int, bytes]:
    return j1939.make_id(priority, pgn, sa), data


def test_eec1_torque_and_engine_speed(codec):
    # byte 1 low nibble: torque mode 1; byte 2 driver's demand 40 %; byte 3 actual 55 %;
    # bytes 4-5 1500 rpm = 12000 x 0.125 rpm; byte 6 SA of the controlling device; byte 8 demand 50 %
    cid, data = frame(61444, bytes([0xF1, 125 + 40, 125 + 55]) + struct.pack("<H", 12000) + bytes([0x00, 0xFF, 125 + 50]),
                      priority=3)
    name, v = codec.decode(cid, data)
    assert name == "EEC1"
    assert v["EngineTorqueMode"] == 1
    assert v["DriversDemandEnginePercentTorque"] == 40 and v["ActualEnginePercentTorque"] == 55
    assert v["EngineDemandPercentTorque"] == 50
    assert v["EngineSpeed"] == pytest.approx(1500 * RPM, rel=1e-12)
    assert codec.signals["EngineSpeed"].unit == "rad/s" and codec.signals["ActualEnginePercentTorque"].unit == "%"


def test_ec1_reference_torque_full_and_short_payloads(codec):
    ec1 = bytearray(b"\xff" * 40)
    ec1[0:3] = struct.pack("<HB", 7200, 125 + 96)      # bytes 1-3: idle point 1, 900 rpm at 96 %
    ec1[15:17] = struct.pack("<H", 17600)              # bytes 16-17: high idle point 6, 2200 rpm
    ec1[19:21] = struct.pack("<H", 260)                # bytes 20-21: reference torque 260 N.m
    cid = j1939.make_id(6, 65251, 0x00)
    for payload in (bytes(ec1), bytes(ec1[:34]), bytes(ec1) + b"\x00\x00"):   # 40 bytes, an older 34, a newer 42
        name, v = codec.decode(cid, payload)
        assert name == "EC1"
        assert v["EngineReferenceTorque"] == 260
        assert v["EngineSpeedAtIdlePoint1"] == pytest.approx(900 * RPM, rel=1e-12)
        assert v["EnginePercentTorqueAtIdlePoint1"] == 96
        assert v["EngineSpeedAtHighIdlePoint6"] == pytest.approx(2200 * RPM, rel=1e-12)
    _, v = codec.decode(cid, bytes(ec1[:19]))         # cut before bytes 20-21: not available
    assert math.isnan(v["EngineReferenceTorque"]) and v["EnginePercentTorqueAtIdlePoint1"] == 96
    assert codec.message("EC1").multi_packet and codec.message("EC1").length == 40


def test_etc2_gears_and_ratio(codec):
    # byte 1 selected gear 3; bytes 2-3 ratio 12.345 (0.001/bit); byte 4 current gear -1 (reverse); 5-8 ASCII ranges
    cid, data = frame(61445, bytes([125 + 3]) + struct.pack("<H", 12345) + bytes([125 - 1]) + b"1 1 ", sa=0x03)
    name, v = codec.decode(cid, data)
    assert name == "ETC2"
    assert v["TransmissionSelectedGear"] == 3 and v["TransmissionCurrentGear"] == -1
    assert v["TransmissionActualGearRatio"] == pytest.approx(12.345, rel=1e-12)
    _, v = codec.decode(cid, bytes([125, 0xFF, 0xFF, 251, 0xFF, 0xFF, 0xFF, 0xFF]))   # neutral, ratio n/a, park
    assert v["TransmissionSelectedGear"] == 0
    assert math.isnan(v["TransmissionActualGearRatio"]) and math.isnan(v["TransmissionCurrentGear"])


def test_ccvs1_wheel_based_speed_and_parking_brake(codec):
    # byte 1 bits 3-4 = 01: parking brake set; bytes 2-3: 12.5 km/h = 3200 x 1/256 km/h
    cid, data = frame(65265, bytes([0b11110111]) + struct.pack("<H", 3200) + b"\xff" * 5, sa=0x47)
    name, v = codec.decode(cid, data)
    assert name == "CCVS1"
    assert v["ParkingBrakeSwitch"] == 1
    assert v["WheelBasedVehicleSpeed"] == pytest.approx(12.5 * KMH, rel=1e-12)
    _, v = codec.decode(cid, bytes.fromhex("FFFFFAFFFFFFFFFF"))             # raw 0xFAFF: top of the range
    assert v["WheelBasedVehicleSpeed"] == pytest.approx(64255 / 256 * KMH, rel=1e-12)


def test_ebc2_front_axle_and_relative_wheel_speeds(codec):
    # bytes 1-2: 10 km/h; bytes 3-8: relative speeds, 1/16 km/h per bit, offset -7.8125 km/h
    rel = [+0.5, -0.25, 0.0, +7.8125, -7.8125, +1.0]
    raw = [round((r + 7.8125) * 16) for r in rel]
    cid, data = frame(65215, struct.pack("<H", 2560) + bytes(raw), sa=0x0B)
    name, v = codec.decode(cid, data)
    assert name == "EBC2"
    assert v["FrontAxleSpeed"] == pytest.approx(10 * KMH, rel=1e-12)
    names = ["RelativeSpeedFrontAxleLeftWheel", "RelativeSpeedFrontAxleRightWheel", "RelativeSpeedRearAxle1LeftWheel",
             "RelativeSpeedRearAxle1RightWheel", "RelativeSpeedRearAxle2LeftWheel", "RelativeSpeedRearAxle2RightWheel"]
    for n, r in zip(names, rel):
        assert v[n] == pytest.approx(r * KMH, abs=1e-12), n


def test_wbsd_and_rear_hitch_status(codec):
    # WBSD: bytes 1-2 2.5 m/s (0.001 m/s/bit), bytes 3-6 1234.567 m, byte 8 bits 1-2 = 01 forward
    cid, data = frame(65096, struct.pack("<HI", 2500, 1234567) + bytes([0xFF, 0xFD]), sa=0xF0, priority=3)
    _, v = codec.decode(cid, data)
    assert v["WheelBasedMachineSpeed"] == pytest.approx(2.5) and v["WheelBasedMachineDistance"] == pytest.approx(1234.567)
    assert v["WheelBasedMachineDirection"] == 1
    # hitch: byte 1 position 50 % (0.4 %/bit); byte 2 bits 7-8 = 01 in work; byte 3 lower link force +20 %
    # (0.8 %/bit, offset -100 %); bytes 4-5 draft 15 kN (10 N/bit, offset -320 kN)
    cid, data = frame(65093, bytes([125, 0b01111111, 150]) + struct.pack("<H", 33500) + b"\xff" * 3, sa=0xF0)
    _, v = codec.decode(cid, data)
    assert v["RearHitchPosition"] == pytest.approx(50.0) and v["RearHitchInWorkIndication"] == 1
    assert v["RearNominalLowerLinkForce"] == pytest.approx(20.0) and v["DraftForce"] == pytest.approx(15000.0)


@pytest.mark.parametrize("signal, cid, size, start", [
    ("EngineSpeed", 0x0CF00400, 2, 3),
    ("ActualEnginePercentTorque", 0x0CF00400, 1, 2),
    ("WheelBasedVehicleSpeed", 0x18FEF147, 2, 1),
    ("FrontAxleSpeed", 0x18FEBF0B, 2, 0),
    ("RelativeSpeedFrontAxleLeftWheel", 0x18FEBF0B, 1, 2),
    ("RelativeSpeedRearAxle1RightWheel", 0x18FEBF0B, 1, 5),
    ("TransmissionActualGearRatio", 0x18F00503, 2, 1),
    ("DraftForce", 0x18FE45F0, 2, 3),
    ("WheelBasedMachineDistance", 0x0CFE48F0, 4, 2),
])
def test_j1939_error_and_not_available_codes_are_missing(codec, signal, cid, size, start):
    """J1939-71 ranges: 0xFB.. parameter specific, 0xFC..0xFD reserved, 0xFE.. error, 0xFF.. not available."""
    def value(raw: int) -> float:
        data = bytearray(b"\x00" * 8)
        data[start:start + size] = raw.to_bytes(size, "little")
        return codec.decode(cid, bytes(data))[1][signal]

    top = J1939_VALID_MAX[8 * size]
    assert math.isfinite(value(top)) and math.isfinite(value(0))
    for hi in (0xFB, 0xFC, 0xFD, 0xFE, 0xFF):
        for raw in (hi << (8 * size - 8), ((hi + 1) << (8 * size - 8)) - 1):
            assert math.isnan(value(raw)), (signal, hex(raw))


def test_j1939_range_holds_whatever_the_dbc_maximum_says():
    """A DBC that rounds the maximum (250.996 km/h for raw 0xFAFF) still gives raw 0xFAFF as a number."""
    css = cantools.database.load_string(
        'VERSION ""\nNS_ :\nBS_:\nBU_:\n'
        'BO_ 2566844926 CCVS1: 8 Vector__XXX\n SG_ WheelBasedVehicleSpeed : 8|16@1+ (0.00390625,0) [0|250.996] "km/h" Vector__XXX\n'
        'BA_DEF_ SG_  "SPN" INT 0 524287;\nBA_DEF_DEF_  "SPN" 0;\nBA_ "SPN" SG_ 2566844926 WheelBasedVehicleSpeed 84;\n',
        database_format="dbc")
    from tractionecu.bus.dbc import _signal_info
    s = _signal_info("x", "CCVS1", 65265, css.messages[0].signals[0])
    assert (s.raw_min, s.raw_max) == (0, 0xFAFF) and s.maximum == pytest.approx(250.99609375)


def test_status_fields_keep_their_coded_states(codec):
    _, v = codec.decode(0x18FEF147, bytes.fromhex("FBFFFFFFFFFFFFFF"))     # parking brake bits 3-4 = 10: error
    assert v["ParkingBrakeSwitch"] == 2 and math.isnan(v["WheelBasedVehicleSpeed"])
    _, v = codec.decode(0x0CF00400, bytes.fromhex("FFFFFFFFFFFFFFFF"))
    assert v["EngineTorqueMode"] == 15 and math.isnan(v["EngineSpeed"])


def test_standard_messages_decode_from_any_source_and_priority(codec):
    data = bytes([0xF0, 0xFF, 125]) + struct.pack("<H", 7200) + b"\xff\xff\xff"
    for cid in (0x0CF00400, 0x0CF00417, 0x18F00400, 0x1CF004F0):
        name, v = codec.decode(cid, data)
        assert name == "EEC1" and v["EngineSpeed"] == pytest.approx(900 * RPM)


def test_every_standard_signal_has_its_spn_and_a_comment_citing_it():
    db = cantools.database.load_file(str(default_dbc_path()), strict=True)
    for mname in ("EEC1", "EC1", "ETC2", "CCVS1", "EBC2", "WBSD", "GBSD", "RearHitchStatus"):
        m = db.get_message_by_name(mname)
        assert m.comment and ("J1939-71" in m.comment or "ISO 11783-7" in m.comment), mname
        for s in m.signals:
            assert s.spn, (mname, s.name)
            assert s.comment and s.comment.startswith(f"SPN {s.spn}"), (mname, s.name)


def test_eight_byte_messages_keep_their_exact_length(codec):
    with pytest.raises(DecodeError):
        codec.decode(0x0CF00400, bytes(7))
    with pytest.raises(DecodeError):
        codec.decode(0x18FEBF0B, bytes(9))
