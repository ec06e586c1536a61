"""Fleet replay on the batch path (``fleet replay --batch``) against the step path: the same tables.

The batch path writes the Parquet estimates from its arrays (full precision), the step path from the
text of ``estimates.csv`` (``%.6g``, times ``%.3f``): numbers agree to the text's rounding, integer, bool
and text columns exactly; the recordings table, the map samples and the farm map agree exactly.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from tractionecu.fleet import runner
from tractionecu.fleet.merge import max_difference
from tractionecu.pipeline.replay import CSV_COLUMNS


def _table(out: Path, name: str) -> pd.DataFrame:
    t = pd.read_parquet(out / name)
    return t.sort_values([c for c in ("recording", "t") if c in t.columns]).reset_index(drop=True)


def test_batch_fleet_replay_equals_the_step_path(tmp_path: Path, fleet_tree: Path) -> None:
    step = runner.run_kind("replay", fleet_tree, tmp_path / "step", stream=None)
    batch = runner.run_kind("replay", fleet_tree, tmp_path / "batch", stream=None, batch=True)
    assert [r["status"] for r in batch] == [r["status"] for r in step]
    ok_s = sorted((r for r in step if r["status"] == "ok"), key=lambda r: r["path"])
    ok_b = sorted((r for r in batch if r["status"] == "ok"), key=lambda r: r["path"])
    assert len(ok_b) == 2 and all(r["key"] != s["key"] for r, s in zip(ok_b, ok_s))   # its own outputs
    for r, s in zip(ok_b, ok_s):
        for col in ("hours", "steps", "valid_share", "estimates_rows", "map_samples", "map_samples_own_frame",
                    "radius_scale_front", "radius_hw95_rear", "radius_blocks_rear", "rho_s_mean", "rho_s_hw95"):
            assert r[col] == s[col] or (r[col] != r[col] and s[col] != s[col]), col

    a, b = _table(tmp_path / "step", "estimates"), _table(tmp_path / "batch", "estimates")
    assert list(b.columns) == list(a.columns) and len(a) == len(b) and len(a) >= 36
    for c in CSV_COLUMNS:
        x, y = a[c].to_numpy(), b[c].to_numpy()
        if x.dtype.kind == "f":
            assert np.array_equal(np.isnan(x), np.isnan(y)), c
            f = ~np.isnan(x)
            # the text's %.3f (t), %.4g (adapt, sigma_*), %.6g (the others)
            rel = 5e-4 if c == "adapt" or c.startswith("sigma_") else 5e-6
            tol = 6e-4 if c == "t" else rel * np.abs(y[f]) + 1e-300
            assert (np.abs(x[f] - y[f]) <= tol).all(), c
        else:
            assert (x == y).all(), c
    assert b["valid"].dtype == bool and b["status"].dtype == np.int64 and b["nis_dof"].dtype == np.int64

    ma, mb = _table(tmp_path / "step", "map_samples"), _table(tmp_path / "batch", "map_samples")
    assert ma.drop(columns=["recording_hash"]).equals(mb.drop(columns=["recording_hash"]))
    fa = runner.build_farm_map(tmp_path / "step", step)
    fb = runner.build_farm_map(tmp_path / "batch", batch)
    assert fa["merged_now"] == fb["merged_now"] == 2
    d = max_difference(tmp_path / "step" / "farm_map", tmp_path / "batch" / "farm_map")
    assert d["count"] == 0 and d["cells_only_in_one"] == 0 and d["mean"] == 0 and d["var"] == 0


def test_cli_flag_batch_and_keep_csv(tmp_path: Path, fleet_tree: Path, capsys) -> None:
    """`fleet replay --batch` writes no estimates.csv (its Parquet comes from the arrays); with --keep-csv the
    task writes it as `tractionecu replay` does, and keeps it."""
    from tractionecu.cli.main import main

    out = tmp_path / "out"
    code = main(["fleet", "replay", str(fleet_tree), "--out", str(out), "--workers", "0", "--batch", "--no-progress"])
    assert code == 5 and "2/3 recordings" in capsys.readouterr().out
    runs = sorted((out / "tasks" / "replay").glob("*/replay"))
    assert len(runs) == 2
    assert all((r / "config.toml").is_file() and (r / "map").is_dir() and not (r / "estimates.csv").exists()
               for r in runs)
    assert len(pd.read_parquet(out / "estimates")) >= 36
    out2 = tmp_path / "out2"
    main(["fleet", "replay", str(fleet_tree), "--out", str(out2), "--workers", "0", "--batch", "--keep-csv",
          "--no-progress"])
    assert all((r / "estimates.csv").is_file() for r in (out2 / "tasks" / "replay").glob("*/replay"))


def test_cli_config_reaches_every_replay_and_its_task_key(tmp_path: Path, fleet_tree: Path, capsys) -> None:
    """`fleet replay --config TOML` replays with that estimator configuration (the fleet had no way to set one:
    every task ran the defaults): each task's config.toml holds it, the estimates follow it, and it is part of
    the task key, so the default run's tasks are not taken for it.  A bad file stops the run before any replay."""
    from tractionecu.cli.main import main

    cfg = tmp_path / "estimator.toml"
    cfg.write_text("[estimator]\nsmoother_lag_s = 0.0\n", encoding="utf-8")
    runs = {}
    for name, extra in (("default", []), ("lag0", ["--config", str(cfg)])):
        out = tmp_path / name
        assert main(["fleet", "replay", str(fleet_tree), "--out", str(out), "--workers", "0", "--batch",
                     "--no-progress", *extra]) == 5
        runs[name] = out
    capsys.readouterr()
    keys = {name: sorted(p.name for p in (out / "tasks" / "replay").iterdir()) for name, out in runs.items()}
    assert len(keys["lag0"]) == len(keys["default"]) == 3 and not set(keys["lag0"]) & set(keys["default"])
    for r in (runs["lag0"] / "tasks" / "replay").glob("*/replay"):
        assert "smoother_lag_s = 0.0" in (r / "config.toml").read_text()
    for r in (runs["default"] / "tasks" / "replay").glob("*/replay"):
        assert "smoother_lag_s = 0.05" in (r / "config.toml").read_text()
    a, b = _table(runs["default"], "estimates"), _table(runs["lag0"], "estimates")
    assert len(a) == len(b) >= 36 and a["t"].equals(b["t"])
    assert not np.allclose(a["mu_FL"], b["mu_FL"], equal_nan=True)        # the filter alone, not smoothed

    bad = tmp_path / "bad.toml"
    bad.write_text("[estimator]\nsmoother_lag_s = -1.0\n", encoding="utf-8")
    assert main(["fleet", "replay", str(fleet_tree), "--out", str(tmp_path / "bad"), "--workers", "0",
                 "--no-progress", "--config", str(bad)]) == 1
    assert "smoother_lag_s" in capsys.readouterr().err
    assert not (tmp_path / "bad" / "tasks").exists()
