"""ISO 11783-10 logged data: TASKDATA.XML with a device description and a
binary time log, read back with the ``isoxml`` package (XML) and an
independent decoding of TLG00001.BIN that follows only the header."""

import datetime as dt
import struct
import warnings

import numpy as np
import pytest

from tractionecu.mapping.export import export_isoxml
from tractionecu.mapping.iso11783 import DDI_ACTUAL_WORK_STATE, ISO_DDI, ISO_SCALE
from tractionecu.mapping.store import MapStore

from map_synth import ORIGIN, SOIL_A, SOIL_RHO, passes, soil_xy

T0 = 1_700_000_000.0  # 2023-11-14T22:13:20Z


@pytest.fixture(scope="module")
def logged_map(tmp_path_factory):
    """Passes over three soils at 10 Hz, Unix times; every 50th sample rejected
    (estimate not valid): it stays on the track with work state 0."""
    d = tmp_path_factory.mktemp("map")
    st = MapStore(d, *ORIGIN)
    x, y = passes()
    lat, lon = st.to_latlon(x, y)
    sid = soil_xy(x, y)
    a = np.vectorize(SOIL_A.get)(sid)
    rho = np.vectorize(SOIL_RHO.get)(sid)
    t = T0 + 0.1 * np.arange(len(x))
    valid = np.arange(len(x)) % 50 != 7
    half = len(x) // 2
    # one half one sample at a time, the other as a batch: both log the values
    for i in range(half):
        st.add(float(lat[i]), float(lon[i]), {"a": a[i], "rho_s": rho[i]}, float(t[i]), valid=bool(valid[i]))
    st.add_many(lat[half:], lon[half:], {"a": a[half:], "rho_s": rho[half:]}, t[half:], valid=valid[half:])
    st.close()
    return d, np.asarray(lat), np.asarray(lon), a, rho, t, valid


def _parse_header(path):
    """The TLG XML header as isoxml's TIM model (empty attributes = in the binary)."""
    import isoxml.models.base.v4 as iso4
    from xsdata.formats.dataclass.parsers import XmlParser
    from xsdata.formats.dataclass.parsers.config import ParserConfig

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "" is not a Decimal: it means "in the binary"
        return XmlParser(ParserConfig(fail_on_unknown_properties=False)).from_path(path, iso4.Time)


def _decode_tlg(data, tim):
    """Decode a binary time log from its header alone (ISO 11783-10 annex D)."""
    ptn = tim.positions[0]
    fields = [("north", "<i"), ("east", "<i"), ("up", "<i"), ("status", "<B"), ("pdop", "<H"),
              ("hdop", "<H"), ("number_of_satellites", "<B"), ("gps_utc_time", "<I"), ("gps_utc_date", "<H")]
    present = [(n, f) for n, f in fields if getattr(ptn, n) == ""]
    ndlv = len(tim.data_log_values)
    out = []
    off = 0
    while off < len(data):
        ms, days = struct.unpack_from("<IH", data, off)
        off += 6
        rec = {"ms": ms, "days": days}
        for n, f in present:
            (rec[n],) = struct.unpack_from(f, data, off)
            off += struct.calcsize(f)
        (k,) = struct.unpack_from("<B", data, off)
        off += 1
        vals = {}
        for _ in range(k):
            idx, v = struct.unpack_from("<Bi", data, off)
            off += 5
            assert idx < ndlv
            vals[idx] = v
        rec["dlv"] = vals
        out.append(rec)
    return out


def test_logged_data_reads_back_with_the_isoxml_package(logged_map, tmp_path):
    isoxml_io = pytest.importorskip("isoxml.util.isoxml_io")
    from isoxml.models.ddi_entities import DDEntity

    d, lat, lon, a, rho, t, valid = logged_map
    out = export_isoxml(d, tmp_path / "TASKDATA")
    assert {p.name for p in out.parent.iterdir()} == {"TASKDATA.XML", "TLG00001.XML", "TLG00001.BIN"}
    task_data, refs = isoxml_io.isoxml_from_path(out.parent)
    assert task_data.version_major.value == "4" and task_data.data_transfer_origin.value == "2"
    task = task_data.tasks[0]
    assert task.status.value == "4"  # completed: logged data, not a prescription
    assert not task.grids and not task.treatment_zones
    assert [tl.filename for tl in task.time_logs] == ["TLG00001"] and task.time_logs[0].type.value == "1"
    assert task.time_logs[0].filelength == len(refs["TLG00001"])
    assert task.times[0].start.to_datetime() == dt.datetime(2023, 11, 14, 22, 13, 20)

    # the device description declares every DDI the log uses, with scale and unit
    dvc = task_data.devices[0]
    assert [e.type.value for e in dvc.elements] == ["1"]
    det = dvc.elements[0]
    dpd = {int.from_bytes(p.ddi, "big"): p for p in dvc.process_data}
    assert {r.device_object_id for r in det.device_object_references} == {p.object_id for p in dpd.values()}
    dvp = {v.object_id: v for v in dvc.value_presentations}
    tim = _parse_header(out.parent / "TLG00001.XML")
    header_ddis = [int.from_bytes(v.process_data_ddi, "big") for v in tim.data_log_values]
    assert header_ddis == [DDI_ACTUAL_WORK_STATE, ISO_DDI["a"], ISO_DDI["rho_s"]]
    assert all(v.device_element_id_ref == det.id for v in tim.data_log_values)
    assert set(header_ddis) == set(dpd)
    # a standard DDI where one exists: its unit is in the data dictionary
    assert DDEntity.from_id(DDI_ACTUAL_WORK_STATE).name == "Actual Work State"
    for ddi in header_ddis[1:]:
        assert ddi >= 0xE000  # proprietary: declared with a value presentation
        p = dvp[dpd[ddi].device_value_presentation_object_id]
        assert p.unit_designator and p.offset == 0
    scale = {ddi: float(dvp[dpd[ddi].device_value_presentation_object_id].scale) for ddi in header_ddis[1:]}
    assert scale == {ISO_DDI["a"]: ISO_SCALE["a"], ISO_DDI["rho_s"]: ISO_SCALE["rho_s"]}
    # the scale is an xs:decimal: no exponent ("1e-05" for ρ_s's scale is refused by a schema-validating reader)
    import re
    scales = re.findall(r'<DVP [^>]*C="([^"]*)"', (out.parent / "TASKDATA.XML").read_text())
    assert len(scales) >= 2 and all(re.fullmatch(r"-?\d+(\.\d+)?", c) for c in scales), scales

    # binary: one record per 10 Hz sample, time, position and the stored values
    assert tim.type.value == ("4",) or tim.type.value == "4"
    recs = _decode_tlg(refs["TLG00001"], tim)
    assert len(recs) == len(t)
    base = dt.datetime(1980, 1, 1, tzinfo=dt.timezone.utc).timestamp()
    got_t = np.array([base + r["days"] * 86400 + r["ms"] / 1000 for r in recs])
    assert np.allclose(got_t, t, atol=0.6e-3)
    assert np.allclose([r["north"] * 1e-7 for r in recs], lat, atol=0.6e-7)
    assert np.allclose([r["east"] * 1e-7 for r in recs], lon, atol=0.6e-7)
    assert {r["status"] for r in recs} == {1}
    work = np.array([r["dlv"][0] for r in recs])
    assert np.array_equal(work, valid.astype(int))
    ok = np.flatnonzero(valid)
    got_a = np.array([recs[i]["dlv"][1] for i in ok]) * ISO_SCALE["a"]
    got_r = np.array([recs[i]["dlv"][2] for i in ok]) * ISO_SCALE["rho_s"]
    assert np.allclose(got_a, a[ok], atol=0.5 * ISO_SCALE["a"] + 1e-12)
    assert np.allclose(got_r, rho[ok], atol=0.5 * ISO_SCALE["rho_s"] + 1e-12)
    assert all(set(recs[i]["dlv"]) == {0} for i in np.flatnonzero(~valid))


def test_track_values_are_what_the_map_stored(logged_map):
    d, lat, lon, a, rho, t, valid = logged_map
    st = MapStore.open(d, read_only=True)
    vals = st.track_values()
    assert vals.shape == (valid.sum(), 1 + len(st.layers))
    assert np.array_equal(vals[:, 0], t[valid])
    assert np.array_equal(vals[:, 1 + st.layers.index("a")], a[valid])
    assert np.array_equal(vals[:, 1 + st.layers.index("rho_s")], rho[valid])
    assert np.isnan(vals[:, 1 + st.layers.index("mu")]).all()


def test_a_map_without_values_logs_positions_and_work_state(logged_map, tmp_path):
    import shutil

    d, lat, lon, a, rho, t, valid = logged_map
    old = tmp_path / "old"
    shutil.copytree(d, old)
    (old / "track_values.log").unlink()
    out = export_isoxml(old, tmp_path / "iso")
    tim = _parse_header(out.parent / "TLG00001.XML")
    recs = _decode_tlg((out.parent / "TLG00001.BIN").read_bytes(), tim)
    assert len(recs) == len(t) and all(set(r["dlv"]) == {0} for r in recs)


def test_torn_values_record_is_cut_on_reopen(tmp_path):
    st = MapStore(tmp_path / "m", *ORIGIN)
    assert st.add(ORIGIN[0], ORIGIN[1], {"a": 0.7}, T0)
    assert st.add(ORIGIN[0], ORIGIN[1], {"a": 0.8}, T0 + 0.1)
    st.close()
    p = tmp_path / "m" / "track_values.log"
    size = p.stat().st_size
    with open(p, "ab") as f:
        f.write(b"\x00" * 17)
    st = MapStore.open(tmp_path / "m")
    assert p.stat().st_size == size
    assert np.array_equal(st.track_values()[:, 1], [0.7, 0.8])
    st.close()


def test_a_farm_map_of_two_machines_at_the_same_times_logs_each_ones_values(tmp_path):
    """Two machines working at the same clock times, merged into one farm map: the time log looked each
    sample's values up by time alone, so one machine's records carried the other's (12 of 900 'a' values
    right on a fleet of six recordings)."""
    from tractionecu.fleet.merge import merge_maps

    t = T0 + 0.1 * np.arange(200)
    dirs = []
    for k, a_value in enumerate((0.6, 0.9)):
        d = tmp_path / f"m{k}"
        st = MapStore(d, *ORIGIN)
        lat, lon = st.to_latlon(np.linspace(0.0, 100.0, t.size), np.full(t.size, 30.0 * k))
        st.add_many(lat, lon, {"a": np.full(t.size, a_value), "rho_s": np.full(t.size, 0.05 + 0.02 * k)}, t)
        st.close()
        dirs.append(d)
    merge_maps(dirs, tmp_path / "farm")
    out = export_isoxml(tmp_path / "farm", tmp_path / "TASKDATA")
    # one time log per machine: the second machine's time ran back to the first one's start inside TLG00001
    logs = [_decode_tlg((out.parent / f"{n}.BIN").read_bytes(), _parse_header(out.parent / f"{n}.XML"))
            for n in ("TLG00001", "TLG00002")]
    assert not (out.parent / "TLG00003.BIN").exists()
    assert 'A="TLG00002" B="%d"' % (out.parent / "TLG00002.BIN").stat().st_size in out.read_text()
    for log in logs:
        stamp = np.array([r["days"] * 86400.0 + r["ms"] / 1000.0 for r in log])
        assert len(log) == t.size and np.all(np.diff(stamp) > 0)
    recs = logs[0] + logs[1]
    north = np.array([r["north"] for r in recs])
    got_a = np.array([r["dlv"][1] for r in recs]) * ISO_SCALE["a"]
    first = north < 0.5 * (north.min() + north.max())   # the first machine's pass, 30 m south of the other
    assert first.sum() == t.size
    assert np.allclose(got_a[first], 0.6, atol=1e-3) and np.allclose(got_a[~first], 0.9, atol=1e-3)


def test_an_export_waits_for_another_writing_the_same_taskdata(logged_map, tmp_path, monkeypatch, locked_elsewhere):
    """Two exports into one TASKDATA directory (the default ``DIR/export/TASKDATA`` of one map, exported twice at
    once while the service writes it) interleaved their files: one's TASKDATA.XML named time logs of the length
    of the other's, or a TLG00002 the other had removed as an earlier export's (1 of 20 pairs of exports).  An
    export now writes its files under the directory's lock: while another process holds it, nothing is
    written; the export goes on once it is released, or after a wait is refused by name."""
    import threading

    from tractionecu.mapping import iso11783
    from tractionecu.mapping.tiles import MapStoreError

    d = logged_map[0]
    out = tmp_path / "TASKDATA"
    out.mkdir()
    with locked_elsewhere(out):
        monkeypatch.setattr(iso11783, "EXPORT_LOCK_WAIT_S", 0.2)
        with pytest.raises(MapStoreError, match="another export is writing into this directory"):
            export_isoxml(d, out)
        assert list(out.iterdir()) == []
        monkeypatch.setattr(iso11783, "EXPORT_LOCK_WAIT_S", 30.0)
        done = []
        th = threading.Thread(target=lambda: done.append(export_isoxml(d, out)))
        th.start()
        th.join(0.5)
        assert th.is_alive() and list(out.iterdir()) == []      # waiting, nothing written
    th.join(30)
    assert done and {p.name for p in out.iterdir()} == {"TASKDATA.XML", "TLG00001.XML", "TLG00001.BIN"}
