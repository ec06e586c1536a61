"""CSV import of already-decoded signals."""

import math

import numpy as np
import pytest

from tractionecu.errors import ConfigError, RecordingError
from tractionecu.recording.csv_import import (
    CONTRACT_MAPPING,
    J1939_LOGGER_MAPPING,
    Column,
    CsvMapping,
    import_csv,
)
from tractionecu.recording.summary import summarize


def test_contract_mapping_time_in_ms_sparse_cells(tmp_path):
    p = tmp_path / "signals.csv"
    p.write_text(
        "t;WheelSpeed_FL;FrontAxleLoad;gps_lat;gps_lon;gps_speed;Comment\n"
        "0;1.5;;;;;start\n"
        "10;1.6;24000;;;;\n"
        "20;1.7;;47.1;8.2;2.5;\n"
        "30;1.8;24100;;;;\n"
    )
    rec = import_csv(p, time_unit="ms", time_offset_s=1.7e9)
    ws = rec.signals["WheelSpeed_FL"]
    assert np.allclose(ws.t, 1.7e9 + np.array([0.0, 0.01, 0.02, 0.03]))
    assert np.allclose(ws.value, [1.5, 1.6, 1.7, 1.8]) and ws.unit == "rad/s"
    assert np.all(ws.sa == -1)
    fz = rec.signals["FrontAxleLoad"]
    assert np.allclose(fz.t - 1.7e9, [0.01, 0.03]) and np.allclose(fz.value, [24000, 24100])
    assert len(rec.gps) == 1 and rec.gps.lat[0] == 47.1 and rec.gps.speed[0] == 2.5
    assert math.isnan(rec.gps.alt[0]) and rec.gps.nsat[0] == -1
    st = rec.stats.files["signals.csv"]
    assert st.unmapped == ["Comment"] and st.total_rejected == 0
    assert rec.stats.messages["WheelSpeed_FL"].rate_hz == pytest.approx(100.0)
    tab = rec.table(100.0)
    assert np.allclose(tab["FrontAxleLoad"][1:], [24000, 24000, 24100])
    assert "WheelSpeed_FL" in summarize(rec)


def test_j1939_logger_mapping_with_reference_torque(tmp_path):
    p = tmp_path / "export.csv"
    p.write_text(
        "timestamps,EEC1.ActualEnginePercentTorque,EEC1.EngineSpeed,CCVS1.WheelBasedVehicleSpeed,"
        "gnss_pos.Latitude,gnss_pos.Longitude,gnss_speed.Speed\n"
        "100.0,50,1500,10.8,,,\n"
        "100.1,,,,45.5,-111.0,3.0\n"
        "100.2,125,2000,,,,\n"
    )
    rec = import_csv(p, J1939_LOGGER_MAPPING, reference_torque_nm=400.0)
    assert np.allclose(rec.signals["EngineTorque"].value, [200.0, 500.0])
    assert rec.signals["EngineTorque"].unit == "Nm"
    assert np.allclose(rec.signals["EngineSpeed"].value, [1500 * 2 * np.pi / 60, 2000 * 2 * np.pi / 60])
    assert rec.signals["WheelBasedMachineSpeed"].value[0] == pytest.approx(3.0)
    assert rec.signals["WheelBasedMachineSpeed"].unit == "m/s"
    assert rec.gps.t.tolist() == [100.1] and rec.gps.lon[0] == -111.0 and rec.gps.speed[0] == 3.0


def test_percent_torque_needs_reference(tmp_path):
    p = tmp_path / "export.csv"
    p.write_text("timestamps,EEC1_ActualEnginePercentTorque\n0,50\n")
    with pytest.raises(ConfigError, match="reference_torque_nm"):
        import_csv(p, J1939_LOGGER_MAPPING)


def test_bad_rows_and_cells_are_counted(tmp_path):
    p = tmp_path / "s.csv"
    p.write_text("t,DraftForce\n0.0,100\n0.1,abc\nx,5\n0.05,7\n0.2,200\n\n0.3,nan\n")
    rec = import_csv(p)
    st = rec.stats.files["s.csv"]
    assert dict(st.rejected) == {"bad_value": 1, "bad_time": 1, "time_backwards": 1}
    assert st.examples == {"bad_value": [3], "bad_time": [4], "time_backwards": [5]}
    d = rec.signals["DraftForce"]
    assert d.t.tolist() == [0.0, 0.2, 0.3] and d.value[1] == 200 and math.isnan(d.value[2])
    assert "bad_value: 1 (s.csv line 3)" in summarize(rec)


def test_custom_mapping_and_units(tmp_path):
    p = tmp_path / "c.csv"
    p.write_text("time_ms\tspeed_kmh\tdraft_kN\n1000\t7.2\t12.5\n")
    mp = CsvMapping({"speed_kmh": Column("GroundBasedMachineSpeed", "km/h"), "draft_kN": Column("DraftForce", "kN")},
                    time_column="time_ms", time_unit="ms")
    rec = import_csv(p, mp)
    assert rec.signals["GroundBasedMachineSpeed"].value[0] == pytest.approx(2.0)
    assert rec.signals["DraftForce"].value[0] == pytest.approx(12500.0)
    assert rec.signals["DraftForce"].t[0] == 1.0


def test_contract_mapping_covers_every_contract_signal():
    targets = {c.target for c in CONTRACT_MAPPING.columns.values()}
    from tractionecu.bus.dbc import CONTRACT_SIGNALS

    assert set(CONTRACT_SIGNALS) <= targets


@pytest.mark.parametrize(
    "text, match",
    [
        ("", r"s\.csv: line 1: empty"),
        ("time,WheelSpeed_FL\n0,1\n", r"s\.csv: line 1: no time column 't'"),
        ("t,Foo\n0,1\n", r"s\.csv: line 1: none of the mapped columns"),
        ("t,WheelSpeed_FL\n", r"s\.csv: line 2: no data rows"),
    ],
)
def test_unusable_files_raise_recording_error(tmp_path, text, match):
    p = tmp_path / "s.csv"
    p.write_text(text)
    with pytest.raises(RecordingError, match=match):
        import_csv(p)


def test_missing_file(tmp_path):
    with pytest.raises(RecordingError, match="absent.csv"):
        import_csv(tmp_path / "absent.csv")


def test_bad_mapping_unit_is_config_error():
    with pytest.raises(ConfigError, match="unit"):
        Column("DraftForce", "furlongs")
    with pytest.raises(ConfigError, match="target"):
        Column("gps.heading", "deg")
