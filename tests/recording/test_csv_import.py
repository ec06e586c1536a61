"""CSV import of already-decoded signals."""

import math
from pathlib import Path

import numpy as np
import pytest

from tractionecu.errors import ConfigError, RecordingError
from tractionecu.recording.csv_import import (
    CONTRACT_MAPPING,
    J1939_LOGGER_MAPPING,
    Column,
    CsvMapping,
    import_csv,
    mapping_named,
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


def test_a_line_with_two_bad_cells_is_named_once(tmp_path):
    """A row holding both ``inf`` and ``ERR`` was listed twice among the examples ("line 2, 2, 13")."""
    p = tmp_path / "s.csv"
    p.write_text("t,DraftForce,FrontAxleLoad\n0.0,inf,ERR\n0.1,100,200\n0.2,abc,300\n")
    st = import_csv(p).stats.files["s.csv"]
    assert st.rejected["bad_value"] == 3 and st.examples["bad_value"] == [2, 4]


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


# ---------------------------------------------------------------- --csv-mapping auto
DATA = Path(__file__).resolve().parents[1] / "data" / "csv"


@pytest.mark.parametrize("header", [
    "t_ms,CAN1.EEC1.ActualEnginePercentTorque,CAN1.EEC1.EngineSpeed,CAN2.gnss_speed.Speed,CAN1.EEC2.Pedal",
    "time,can0_EEC1_ActualEnginePercentTorque,can0_EEC1_EngineSpeed,can1_gnss_speed_Speed,can0_EEC2_Pedal",
    "Timestamp,EEC1.ActualEnginePercentTorque,eec1_enginespeed,CAN2_gnss_speed.Speed,EEC2.Pedal",
])
def test_auto_mapping_matches_bus_prefixes_and_separators(tmp_path, header, caplog):
    p = tmp_path / "export.csv"
    p.write_text(header + "\n1700000000000,50,1500,3.0,12\n1700000000100,125,2000,,13\n")
    rec = import_csv(p, mapping_named("auto"), reference_torque_nm=400.0)
    assert np.allclose(rec.signals["EngineTorque"].value, [200.0, 500.0])
    assert np.allclose(rec.signals["EngineTorque"].t, [1.7e9, 1.7e9 + 0.1])
    assert rec.gps.speed.tolist() == [3.0]
    unmapped = rec.stats.files["export.csv"].unmapped
    assert len(unmapped) == 1 and unmapped[0].endswith("Pedal")
    assert "columns the mapping ignores" in caplog.text and unmapped[0] in caplog.text


@pytest.mark.parametrize("cells,tz,want", [
    (("1700000000", "1700000000.5"), None, [1.7e9, 1.7e9 + 0.5]),                    # epoch s
    (("1700000000000", "1700000000500"), None, [1.7e9, 1.7e9 + 0.5]),                # epoch ms
    (("12.0", "12.5"), None, [12.0, 12.5]),                                          # relative s
    (("2023-11-14T22:13:20Z", "2023-11-14T22:13:20.500Z"), None, [1.7e9, 1.7e9 + 0.5]),  # ISO 8601
    (("2023-11-14T23:13:20+01:00", "2023-11-14T23:13:20.5+01:00"), "+05:00", [1.7e9, 1.7e9 + 0.5]),
    (("2023-11-14 22:13:20", "2023-11-14 22:13:20.500"), None, [1.7e9, 1.7e9 + 0.5]),  # naive: UTC
    (("2023-11-15 00:13:20", "2023-11-15 00:13:20.500"), "+02:00", [1.7e9, 1.7e9 + 0.5]),
    (("2023-11-14 23:13:20", "2023-11-14 23:13:20.500"), "Europe/Berlin", [1.7e9, 1.7e9 + 0.5]),
])
def test_auto_time_formats(tmp_path, cells, tz, want):
    p = tmp_path / "export.csv"
    p.write_text("timestamps,EEC1_EngineSpeed\n" + "".join(f"{c},600\n" for c in cells))
    rec = import_csv(p, mapping_named("auto", timezone=tz))
    assert np.allclose(rec.signals["EngineSpeed"].t, want, rtol=0, atol=1e-6)


def test_bad_timezone_is_a_config_error():
    with pytest.raises(ConfigError, match="timezone"):
        mapping_named("auto", timezone="Mars/Olympus")
    with pytest.raises(ConfigError, match="csv_mapping"):
        mapping_named("nope")


def test_prefixed_real_export_reads_like_the_plain_one():
    """The CSS-Electronics export with bus-prefixed names and local date-times
    (tests/data/csv/README.md) gives the signals of the plain export, on epoch time."""
    plain = import_csv(DATA / "css_engine_gnss_1hz.csv", J1939_LOGGER_MAPPING, reference_torque_nm=1500.0,
                       time_offset_s=1635188454.0)
    pref = import_csv(DATA / "css_engine_gnss_prefixed_datetime.csv", mapping_named("auto", timezone="+06:00"),
                      reference_torque_nm=1500.0)
    assert pref.stats.files["css_engine_gnss_prefixed_datetime.csv"].unmapped == []
    assert set(pref.signals) == set(plain.signals) == {"EngineTorque", "EngineSpeed", "WheelBasedMachineSpeed"}
    for k in plain.signals:
        assert np.array_equal(pref.signals[k].t, plain.signals[k].t)
        assert np.array_equal(pref.signals[k].value, plain.signals[k].value)
    assert np.array_equal(pref.gps.t, plain.gps.t) and np.array_equal(pref.gps.lat, plain.gps.lat)


def test_diagnose_runs_on_the_prefixed_real_export(tmp_path):
    import json

    from tractionecu.cli.main import main

    out = tmp_path / "rep"
    assert main(["diagnose", str(DATA / "css_engine_gnss_prefixed_datetime.csv"), "--out", str(out),
                 "--csv-mapping", "auto", "--csv-timezone", "+06:00", "--reference-torque", "1500"]) == 4
    rep = json.loads((out / "report.json").read_text())
    assert "0 of 128 samples usable" in rep["statement"]


def test_auto_mapping_reads_bracketed_units_and_spn_numbered_names(tmp_path, caplog):
    # regression: the simulator's own logger-style 1 Hz export ("Time [s]", "EEC1 SPN190 Engine Speed [rpm]",
    # ...) was refused with "no time column 'timestamps'": the loose mapping kept the bracketed unit in the
    # name and matched no SPN-numbered J1939 name
    from tractionecu.sim.physwriter import EXPORT_COLUMNS
    p = tmp_path / "export_1hz.csv"
    row1 = ["0.0", "2026-05-17T10:00:00Z", "1800", "60", "7", "3.2", "9.0", "9.3", "12000", "52.1", "11.6", "8.8"]
    row2 = ["1.0", "2026-05-17T10:00:01Z", "1900", "70", "7", "3.2", "10.8", "11.1", "13000", "52.1", "11.6", "10.6"]
    p.write_text(",".join(EXPORT_COLUMNS) + "\n" + ",".join(row1) + "\n" + ",".join(row2) + "\n")
    rec = import_csv(p, mapping_named("auto"), reference_torque_nm=500.0)
    sig = rec.signals
    assert np.allclose(sig["EngineTorque"].value, [300.0, 350.0])
    assert np.allclose(sig["EngineSpeed"].value, [1800 * np.pi / 30, 1900 * np.pi / 30])
    assert np.allclose(sig["WheelBasedMachineSpeed"].value, [2.5, 3.0])
    assert np.allclose(sig["FrontAxleSpeed"].value, [9.3 / 3.6, 11.1 / 3.6])
    assert np.allclose(sig["DraftForce"].value, [12000.0, 13000.0])
    assert np.allclose(sig["TransmissionActualGearRatio"].value, [3.2, 3.2])
    assert sig["EngineSpeed"].t.tolist() == [0.0, 1.0]
    assert np.allclose(rec.gps.speed, [8.8 / 3.6, 10.6 / 3.6]) and rec.gps.lat.tolist() == [52.1, 52.1]
    assert rec.stats.files["export_1hz.csv"].unmapped == ["Date Time UTC"]


def test_auto_mapping_names_an_unknown_bracketed_unit(tmp_path):
    p = tmp_path / "export.csv"
    p.write_text("Time [s],EEC1 SPN190 Engine Speed [furlong/fortnight],GNSS Speed [km/h]\n0,1,3.6\n1,2,7.2\n")
    rec = import_csv(p, mapping_named("auto"))
    assert "EngineSpeed" not in rec.signals and np.allclose(rec.gps.speed, [1.0, 2.0])
    assert rec.stats.files["export.csv"].unmapped == ["EEC1 SPN190 Engine Speed [furlong/fortnight] "
                                                      "(unit [furlong/fortnight] not known)"]


def test_infinite_cells_are_counted_not_passed_on(tmp_path):
    """'inf' and '-inf' cells of an export went into the signals as infinite values (float() reads them),
    uncounted; the diagnosis then fitted through them."""
    p = tmp_path / "s.csv"
    p.write_text("t,DraftForce,FrontAxleLoad\n0.0,100,40000\n0.1,inf,40010\n0.2,-INF,40020\n0.3,nan,40030\n")
    rec = import_csv(p)
    st = rec.stats.files["s.csv"]
    assert dict(st.rejected) == {"bad_value": 2} and st.examples == {"bad_value": [3, 4]}
    d = rec.signals["DraftForce"]
    assert d.t.tolist() == [0.0, 0.3] and d.value[0] == 100 and math.isnan(d.value[1])   # NaN: not available
    assert rec.signals["FrontAxleLoad"].t.tolist() == [0.0, 0.1, 0.2, 0.3]


def test_a_european_export_with_decimal_commas_is_read(tmp_path):
    """A spreadsheet export in a European locale (";" between cells, "1376,1") had every number rejected as
    bad_value and diagnosis said "untestable — missing signals: engine_speed, v_wheel_bus, v_gps"."""
    p = tmp_path / "euro.csv"
    p.write_text("Time [s];EEC1 SPN190 Engine Speed [rpm];GNSS Speed [km/h];RHS SPN1879 Rear Draft [N]\n"
                 "0,5;1376,1;2,58;1.450,5\n1,5;1815,6;4,15;-450\n")
    rec = import_csv(p, mapping_named("auto"))
    assert rec.signals["EngineSpeed"].t.tolist() == [0.5, 1.5]
    assert np.allclose(rec.signals["EngineSpeed"].value, [1376.1 * np.pi / 30, 1815.6 * np.pi / 30])
    assert np.allclose(rec.gps.speed, [2.58 / 3.6, 4.15 / 3.6])
    assert np.allclose(rec.signals["DraftForce"].value, [1450.5, -450.0])
    assert not rec.stats.files["euro.csv"].rejected


@pytest.mark.parametrize("name", ["Date Time UTC", "Time (UTC)", "Timestamp UTC"])
def test_a_utc_date_time_column_is_the_time(tmp_path, name):
    """An export whose only time column was "Date Time UTC" or "Time (UTC)" was refused: "no time column
    'timestamps' in header"."""
    p = tmp_path / "t.csv"
    p.write_text(f"{name},GNSS Speed [km/h]\n2026-07-10 08:00:01,3.6\n2026-07-10 08:00:02,7.2\n")
    rec = import_csv(p, mapping_named("auto"))
    assert np.allclose(rec.gps.t - rec.gps.t[0], [0.0, 1.0]) and rec.gps.t[0] == pytest.approx(1783670401.0)
