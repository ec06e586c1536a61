"""PolyCAN CSV -> candump conversion."""

import pytest

from tractionecu.bus import j1939
from tractionecu.errors import RecordingError
from tractionecu.recording.polycan import main, read_polycan

HEADER = ",time,pgn,priority,source,destination,data,description\n"


def test_ids_rebuilt_for_pdu1_pdu2_and_data_page(tmp_path):
    p = tmp_path / "x.csv"
    p.write_text(
        HEADER
        + "0,0.0,60928,6,71,255,4D 74 30 04 00 34 02 20 ,Unknown\n"
        + "1,28.0,59904,6,0,255,00 EE 00 ,Unknown\n"
        + "2,59.0,61184,6,0,6,64 0E 03 02 FF FF FF FF ,Unknown\n"
        + "3,1097.0,126720,3,3,6,01 01 FF FF FF FF FF F5 ,Unknown\n"
        + "4,1097.5,65097,3,71,255,FF FF FF FF FF FF FF FF ,Unknown\n"
    )
    frames = list(read_polycan(p, epoch0=1000.0))
    assert [f.can_id for f in frames] == [0x18EEFF47, 0x18EAFF00, 0x18EF0600, 0x0DEF0603, 0x0CFE4947]
    assert [f.t for f in frames] == [1000.0, 1000.028, 1000.059, 1001.097, 1001.0975]
    assert frames[1].data == bytes.fromhex("00EE00")
    assert all(f.is_extended for f in frames)
    assert j1939.parse_id(frames[3].can_id) == (3, 126720, 3, 6)


def test_bad_row_names_file_and_line(tmp_path):
    p = tmp_path / "x.csv"
    p.write_text(HEADER + "0,0.0,60928,6,71,255,4D 74 ZZ ,Unknown\n")
    with pytest.raises(RecordingError, match=r"x\.csv: line 2"):
        list(read_polycan(p))


def test_not_polycan(tmp_path):
    p = tmp_path / "x.csv"
    p.write_text("a,b\n1,2\n")
    with pytest.raises(RecordingError, match=r"x\.csv: line 1: not a PolyCAN export"):
        list(read_polycan(p))


def test_command_line(tmp_path, capsys):
    p = tmp_path / "x.csv"
    p.write_text(HEADER + "0,0.0,65097,3,71,255,FF FF FF FF FF FF FF FF ,Unknown\n")
    out = tmp_path / "x.log"
    assert main([str(p), str(out), "--epoch0", "1538352000"]) == 0
    assert out.read_text() == "(1538352000.000000) can0 0CFE4947#FFFFFFFFFFFFFFFF\n"
    assert main([str(tmp_path / "absent.csv"), str(out)]) == 1
