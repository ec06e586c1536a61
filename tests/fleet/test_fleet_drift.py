"""Drift across the fleet: the machine whose rolling radius changed is named, the other is not."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from tractionecu.fleet import runner
from tractionecu.fleet.drift import drift_table, report_markdown


def test_radius_change_is_reported(tmp_path: Path, radius_season: Path) -> None:
    out = tmp_path / "out"
    recs = runner.run_kind("replay", radius_season, out, stream=None)
    assert [r["status"] for r in recs] == ["ok"] * 4
    d = runner.write_drift(out)
    assert d["moved"] == ["tractor-a"]
    t = pd.read_parquet(out / "drift.parquet")
    a = t[(t["machine"] == "tractor-a") & (t["series"] == "radius_scale_rear")].iloc[0]
    assert a["moved"] and 0.02 < a["change"] < 0.04 and a["slope_per_day"] > 0
    b = t[(t["machine"] == "tractor-b") & t["series"].str.startswith("radius_scale")]
    assert len(b) == 2 and not b["moved"].any()
    text = (out / "drift.md").read_text(encoding="utf-8")
    assert "moved beyond their interval: tractor-a." in text and "**tractor-b**" not in text


def test_pooling_and_the_interval_rule() -> None:
    rows = [
        {"machine": "m", "series": "torque_gain.k_front", "date": "2026-07-01", "value": 0.00, "hw95": 0.02, "recording": "1"},
        {"machine": "m", "series": "torque_gain.k_front", "date": "2026-07-01", "value": 0.02, "hw95": 0.02, "recording": "2"},
        {"machine": "m", "series": "torque_gain.k_front", "date": "2026-07-31", "value": 0.05, "hw95": 0.02, "recording": "3"},
        {"machine": "n", "series": "torque_gain.k_front", "date": "2026-07-01", "value": 0.00, "hw95": 0.02, "recording": "4"},
        {"machine": "n", "series": "torque_gain.k_front", "date": "2026-07-31", "value": 0.03, "hw95": 0.02, "recording": "5"},
    ]
    t = {r["machine"]: r for r in drift_table(rows)}
    m = t["m"]
    # two recordings of one date pooled with equal weights: 0.01 ± 0.02/√2
    assert abs(m["first_value"] - 0.01) < 1e-12 and abs(m["first_hw95"] - 0.02 / 2**0.5) < 1e-12
    assert m["moved"] and abs(m["slope_per_day"] - 0.04 / 30) < 1e-12
    assert not t["n"]["moved"]                     # 0.03 apart, intervals 0.02 + 0.02 overlap
    assert "m" in report_markdown(list(t.values())).splitlines()[2]
