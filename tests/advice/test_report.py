"""``replay --plot``: the η-and-s* figure beside Figs. 5 and 6, and the HTML report of the run."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("matplotlib")


def test_replay_plot_writes_the_efficiency_figure_and_the_report(short_recording: Path, tmp_path: Path) -> None:
    from tractionecu.cli.main import main

    out = tmp_path / "run"
    assert main(["replay", str(short_recording), "--out", str(out), "--plot"]) == 0
    png = out / "fig_efficiency.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and (out / "fig6_mu_rho.png").exists()
    html = (out / "report.html").read_text(encoding="utf-8")
    # self-contained: figures embedded, the track drawn as SVG, nothing fetched from anywhere
    assert html.count("data:image/png;base64,") >= 2 and "<svg" in html and "<line" in html
    assert "src=\"http" not in html and "Advice" in html and "η" in html
