"""Fleet replay and diagnosis tasks in this process (the scheduler is not what these test): outputs,
Parquet read back, failures reported, re-runs skipped."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.dataset as ds

from tractionecu.fleet import runner
from tractionecu.fleet.store import DIAGNOSIS_COLUMNS, RECORDINGS_COLUMNS
from tractionecu.fleet.tasks import diagnosis_rows
from tractionecu.pipeline.replay import CSV_COLUMNS


def test_replay_tables_failures_and_rerun(tmp_path: Path, fleet_tree: Path) -> None:
    out = tmp_path / "out"
    recs = runner.run_kind("replay", fleet_tree, out, stream=None)
    by = {(r["machine"], r["date"]): r for r in recs}
    assert set(by) == {("tractor-a", "2026-07-10"), ("tractor-b", "2026-07-11"), ("tractor-b", "2026-07-12")}
    bad = by[("tractor-b", "2026-07-12")]
    assert bad["status"] == "failed" and bad["error"] == "RecordingError" and "broken" in bad["path"]
    ok = [by[("tractor-a", "2026-07-10")], by[("tractor-b", "2026-07-11")]]
    assert all(r["status"] == "ok" and not r["cached"] for r in ok)

    # estimates: 1 Hz, partitioned by machine and date, the replay's columns
    est = pd.read_parquet(out / "estimates")
    assert set(zip(est["machine"].astype(str), est["date"].astype(str))) == {("tractor-a", "2026-07-10"),
                                                                          ("tractor-b", "2026-07-11")}
    for col in CSV_COLUMNS + ("recording", "recording_hash", "field"):
        assert col in est.columns
    assert est["valid"].dtype == bool and est["status"].dtype == np.int64
    for _, g in est.groupby("recording"):
        sec = np.floor(g["t"].to_numpy())
        assert np.all(np.diff(sec) >= 1)                  # one row per second
        assert 18 <= len(g) <= 21                         # a 20 s recording
    assert sum(r["estimates_rows"] for r in ok) == len(est)
    # the 10 Hz map samples, with positions and layer values where accepted
    ms = ds.dataset(out / "map_samples", format="parquet", partitioning="hive").to_table().to_pandas()
    assert len(ms) == sum(r["map_samples"] for r in ok) and ms["accepted"].any()
    acc = ms[ms["accepted"]]
    assert np.isfinite(acc["mu"]).all() and np.isfinite(acc["lat"]).all()
    assert not np.isfinite(ms.loc[~ms["accepted"], "mu"]).any()
    # the recordings and failures tables
    table = pd.read_parquet(out / "recordings.parquet")
    assert list(table.columns) == list(RECORDINGS_COLUMNS) and len(table) == 3
    fail = pd.read_parquet(out / "failures.parquet")
    assert fail["path"].tolist() == [bad["path"]]
    # the farm map of the run, exported
    s = runner.build_farm_map(out, recs, ("geojson",))
    assert s["merged_now"] == 2 and Path(s["exports"]["geojson"]).is_file()

    # a re-run skips the done recordings (same content, same software) and tries the failed one again
    again = runner.run_kind("replay", fleet_tree, out, stream=None)
    assert sorted(r["cached"] for r in again) == [False, True, True]
    assert [r for r in again if not r["cached"]][0]["status"] == "failed"
    assert len(pd.read_parquet(out / "estimates")) == len(est)     # nothing written twice
    s2 = runner.build_farm_map(out, again)
    assert s2["merged_now"] == 0 and s2["reused"] == 2

    # a new day's recording is merged into the farm map as it stands, and the result is the season's merge
    import shutil

    from tractionecu.fleet.merge import max_difference, merge_maps

    shutil.copytree(Path(ok[1]["path"]), fleet_tree / "tractor-b" / "2026-07-13" / "run2")
    day = runner.run_kind("replay", fleet_tree, out, stream=None)
    s3 = runner.build_farm_map(out, day)
    assert (s3["merged_now"], s3["reused"]) == (1, 2)
    keys = sorted(r["key"] for r in day if r["status"] == "ok")
    merge_maps([out / "tasks" / "replay" / k / "farm_map" for k in keys], tmp_path / "scratch")
    d = max_difference(out / "farm_map", tmp_path / "scratch")
    assert d["count"] == 0 and d["cells_only_in_one"] == 0 and d["mean"] <= 1e-12 and d["var"] <= 1e-12
    # a run over part of the season (here one recording's own folder) keeps the rest of the season: the same
    # machine and date from SOURCE's own path, so the same task (cached), and the farm map unchanged (it had
    # shrunk to that part)
    import io

    said = io.StringIO()
    part = runner.run_kind("replay", fleet_tree / "tractor-b" / "2026-07-13" / "run2", out, stream=None, notes=said)
    assert [(r["machine"], r["date"], r["cached"]) for r in part] == [("tractor-b", "2026-07-13", True)]
    assert "3 recording(s) of earlier runs that this SOURCE does not cover kept" in said.getvalue()
    assert len(pd.read_parquet(out / "recordings.parquet")) == 4 and len(pd.read_parquet(out / "failures.parquet")) == 1
    s4 = runner.build_farm_map(out, part, stream=said)
    assert (s4["merged_now"], s4["reused"]) == (0, 3) and "left_out" not in s4
    shutil.rmtree(fleet_tree / "tractor-b" / "2026-07-13")

    # a changed recording is a new task
    gps = Path(ok[0]["path"]) / "gps.nmea"
    gps.write_text(gps.read_text(encoding="ascii"), encoding="ascii")      # same bytes: still cached
    assert sum(r["cached"] for r in runner.run_kind("replay", fleet_tree, out, stream=None)) == 2
    with open(gps, "a", encoding="ascii") as fh:
        fh.write("\n")
    said = io.StringIO()
    third = runner.run_kind("replay", fleet_tree, out, stream=None, notes=said)
    assert sum(r["cached"] for r in third) == 1
    # the changed recording's estimates replace those of its old content (they stood beside them, its rows
    # twice in the dataset); the recording of the removed folder is kept until --prune
    est3 = pd.read_parquet(out / "estimates")
    per = est3.groupby("recording").size()
    assert len(per) == 3 and per.between(18, 21).all()            # no recording twice
    assert est3.groupby("recording")["recording_hash"].nunique().eq(1).all()
    assert "(1 no longer at their path: --prune drops them)" in said.getvalue()
    assert "2 Parquet file(s) of changed or dropped recordings removed" in said.getvalue()
    pruned = runner.run_kind("replay", fleet_tree, out, stream=None, prune=True)
    assert len(pd.read_parquet(out / "estimates")) == len(est)
    assert len(pd.read_parquet(out / "recordings.parquet")) == len(pruned) == 3
    # a done task whose Parquet files are gone runs again (it was cached with nothing in estimates/)
    shutil.rmtree(out / "estimates")
    again = runner.run_kind("replay", fleet_tree, out, stream=None)
    assert sum(r["cached"] for r in again) == 0 and len(pd.read_parquet(out / "estimates")) == len(est)


def test_diagnosis_rows_flatten_effects_with_intervals() -> None:
    rep = {"verdict": "named", "effects": [
        {"name": "torque_gain", "kind": "effect", "named": True, "rank": 1, "score": 40.0,
         "parameters": {"k_front": {"value": 0.05, "ci95": [0.04, 0.06], "unit": "-", "at_bound": ""},
                        "k_rear": {"value": -0.01, "ci95": [-0.03, 0.01], "unit": "-"}}},
        {"name": "load_transfer", "kind": "nominal", "named": False, "parameters": {}}]}
    ref = {"machine": "m", "date": "2026-07-10", "path": "r"}
    rows = diagnosis_rows(rep, ref, "h")
    assert [(r["effect"], r["parameter"], r["value"], r["ci95_lo"], r["ci95_hi"]) for r in rows] == [
        ("torque_gain", "k_front", 0.05, 0.04, 0.06), ("torque_gain", "k_rear", -0.01, -0.03, 0.01)]
    assert set(DIAGNOSIS_COLUMNS) <= set(rows[0])
    none = diagnosis_rows({"verdict": "nominal", "effects": []}, ref, "h")
    assert len(none) == 1 and none[0]["effect"] == "" and math.isnan(none[0]["value"])


def test_diagnose_table(tmp_path: Path, radius_season: Path) -> None:
    out = tmp_path / "out"
    src = radius_season / "tractor-a" / "2026-08-10"
    recs = runner.run_kind("diagnose", src, out, stream=None)
    assert [r["status"] for r in recs] == ["ok"], [(r.get("message"), r.get("traceback")) for r in recs]
    t = pd.read_parquet(out / "diagnosis.parquet")
    assert list(t.columns) == list(DIAGNOSIS_COLUMNS) and len(t) >= 1
    rep = json.loads((out / "tasks" / "diagnose" / recs[0]["key"] / "diagnose" / "report.json").read_text())
    assert len(t) == len(diagnosis_rows(rep, {"machine": "", "date": "", "path": ""}, ""))
    assert (t["recording"] == str(src / "run")).all() and (t["recording_hash"] == recs[0]["recording_hash"]).all()
    p = t[t["parameter"] != ""]
    assert len(p) and ((p["ci95_lo"] <= p["value"]) & (p["value"] <= p["ci95_hi"])).all()
    assert (t["verdict"] == str(rep.get("verdict", ""))).all()


def test_a_task_that_raises_is_retried_then_reported(monkeypatch) -> None:
    """A worker's death (here a MemoryError raised by the task) is retried; past the retries the
    recording is a failure record, and the other recordings are done."""
    calls: dict[str, int] = {}

    def flaky(spec: dict) -> dict:
        p = spec["ref"]["path"]
        calls[p] = calls.get(p, 0) + 1
        if p == "always" or (p == "once" and calls[p] == 1):
            raise MemoryError("worker out of memory")
        return {"kind": "replay", **spec["ref"], "status": "ok", "hours": 0.5, "cached": False}

    monkeypatch.setattr(runner, "run_task", flaky)
    specs = [{"kind": "replay", "ref": {"path": p, "machine": "m", "date": "2026-07-10", "field": ""},
              "out": "", "options": {}} for p in ("once", "always", "fine")]
    prog = runner.Progress("replay", 3, None)
    recs = runner.run_specs(specs, None, retries=2, progress=prog)
    assert [r["status"] for r in recs] == ["ok", "failed", "ok"]
    assert calls == {"once": 2, "always": 3, "fine": 1}
    assert recs[1]["error"] == "MemoryError"
    assert (prog.done, prog.failed, prog.hours) == (3, 1, 1.0)
    assert prog.line().startswith("fleet replay: 3/3 recordings (0 cached, 1 failed), 1.00 h processed")


def test_table_column_types_from_every_value(tmp_path: Path) -> None:
    """A column's type follows all its values: an integer before a fraction made the column int64 and
    wrote the fraction truncated (score 12.7 as 12)."""
    from tractionecu.fleet.store import write_rows

    rows = [{"score": 40, "n": 3, "ok": True, "name": "x"}, {"score": 12.7, "n": None, "ok": None, "name": 5},
            {"score": math.nan, "n": 4, "ok": False, "name": None}]
    write_rows(rows, ("score", "n", "ok", "name"), tmp_path / "t.parquet")
    t = pd.read_parquet(tmp_path / "t.parquet")
    assert t["score"].tolist()[:2] == [40.0, 12.7] and math.isnan(t["score"].iloc[2])
    assert t["n"].tolist()[0] == 3 and t["n"].tolist()[2] == 4 and pd.isna(t["n"].iloc[1])
    assert t["ok"].tolist()[0] is True and t["ok"].tolist()[2] is False
    assert t["name"].tolist() == ["x", "5", ""]


def test_a_copy_of_a_recording_counts_once(tmp_path: Path, short_recordings: dict[str, Path]) -> None:
    """The same recording filed twice (``run`` and ``run-copy``, one machine and day) had one task key: the
    farm map merged its map twice (its cells' counts doubled and their means weighted 2:1 against the other
    recording, unlike the map_samples table), and recordings.parquet listed ``run`` twice and ``run-copy``
    not at all."""
    import io
    import shutil

    from tractionecu.mapping.store import open_store

    src = tmp_path / "season" / "tractor-a" / "2026-07-10"
    shutil.copytree(short_recordings["s1"], src / "run")
    shutil.copytree(short_recordings["s1"], src / "run-copy")
    shutil.copytree(short_recordings["s2"], src / "other")
    out, said = tmp_path / "out", io.StringIO()
    recs = runner.run_kind("replay", tmp_path / "season", out, stream=None, notes=said)
    assert sorted(Path(r["path"]).name for r in recs) == ["other", "run"]
    assert "1 recording(s) hold the same files as another of their machine and date and are left out, so that " \
           f"their data count once: {src / 'run-copy'} (= {src / 'run'})" in said.getvalue()
    runner.build_farm_map(out, recs)
    samples = pd.read_parquet(out / "map_samples")
    farm = open_store(out / "farm_map")
    assert int(farm.grid("a", farm.extent()).count.sum()) == int((samples["accepted"] & samples["a"].notna()).sum())


def test_a_second_fleet_run_on_one_out_is_refused(tmp_path: Path, fleet_tree: Path, capsys, locked_elsewhere) -> None:
    """Two ``fleet map`` runs on one OUT removed each other's task directories, Parquet files and farm map as
    they went: both exited 5 (a recording each 'failed': its estimates.csv gone from under its replay), the
    estimates and map samples tables were left with no row and the farm map with one recording of two.  A run
    now holds OUT's lock: a second one, while another process holds it, is refused by name and writes nothing."""
    from tractionecu.cli.main import main

    out = tmp_path / "out"
    out.mkdir()
    with locked_elsewhere(out):
        assert main(["fleet", "map", str(fleet_tree), "--out", str(out), "--workers", "0", "--no-progress"]) == 1
        assert "another fleet run is writing into this directory" in capsys.readouterr().err
        assert list(out.iterdir()) == []
