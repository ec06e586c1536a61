"""`tractionecu fleet replay` and `fleet map` on a local two-worker Dask cluster."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from tractionecu.cli.main import main
from tractionecu.fleet.merge import max_difference, merge_maps


def test_fleet_replay_and_map_on_two_workers(tmp_path: Path, fleet_tree: Path, capsys) -> None:
    out = tmp_path / "out"
    code = main(["fleet", "map", str(fleet_tree), "--out", str(out), "--workers", "2", "--memory-limit", "1GiB",
                 "--format", "geojson", "--format", "isoxml"])
    printed = capsys.readouterr()
    assert code == 5                                      # the broken recording is reported, the rest done
    assert "2/3 recordings" in printed.out and "broken" in printed.err
    assert "fleet replay: 3/3 recordings" in printed.err   # the progress line
    recs = pd.read_parquet(out / "recordings.parquet")
    ok = recs[recs["status"] == "ok"]
    assert len(ok) == 2
    # the two tasks ran in worker processes, not here
    import json
    import os
    pids = {json.loads((out / "tasks" / "replay" / k / "done.json").read_text())["pid"] for k in ok["key"]}
    assert os.getpid() not in pids
    assert (out / "farm_export" / "map.geojson").is_file()
    assert (out / "farm_export" / "TASKDATA" / "TASKDATA.XML").is_file()
    # the farm map is the merge of the two recordings' maps
    merge_maps([out / "tasks" / "replay" / k / "farm_map" for k in sorted(ok["key"])], tmp_path / "check")
    d = max_difference(out / "farm_map", tmp_path / "check")
    assert d["count"] == 0 and d["cells_only_in_one"] == 0 and d["mean"] <= 1e-12

    code = main(["fleet", "replay", str(fleet_tree), "--out", str(out), "--workers", "2", "--no-progress"])
    assert code == 5
    again = pd.read_parquet(out / "recordings.parquet").set_index("path")
    # skipped unless the package's sources changed in between (the software version is their digest)
    for path, first in ok.set_index("path").iterrows():
        assert again.loc[path, "cached"] or again.loc[path, "software"] != first["software"]
