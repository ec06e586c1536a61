"""A PolyCAN CSV export (the TractorHacking John Deere 5055E captures) is read as a capture format.

``tractionecu inspect highRPM1.csv`` refused the export as an "unknown CAN capture format" and advised
python-can's ``logconvert``, which cannot read it either; only a module-level converter
(``python -m tractionecu.recording.polycan``) knew the format.  It is now detected by its header and read
like the other formats, with a bad row counted and skipped instead of ending the read.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tractionecu.bus import j1939
from tractionecu.bus.candump import ReadStats, read_candump
from tractionecu.cli.main import main
from tractionecu.recording.formats import TRUSTED_CLOCK, detect, read_frames

EXCERPT = Path(__file__).resolve().parents[1] / "data" / "candump" / "jd5055e_excerpt.log"


def _polycan(frames, path: Path, bad_rows: dict[int, str] | None = None) -> None:
    """Write ``frames`` as PolyCAN writes them: time in ms from the first frame, the PGN with a PDU1
    destination masked out, priority, source and destination in decimal, data as spaced hex."""
    t0 = frames[0].t
    rows = [",time,pgn,priority,source,destination,data,description"]
    for k, f in enumerate(frames):
        prio, pgn, sa = (f.can_id >> 26) & 0x7, (f.can_id >> 8) & 0x3FFFF, f.can_id & 0xFF
        da = 255
        if j1939.is_pdu1(pgn):
            da, pgn = pgn & 0xFF, pgn & 0x3FF00
        data = " ".join(f"{b:02X}" for b in f.data) + " "
        rows.append(f"{k},{(f.t - t0) * 1000.0:.3f},{pgn},{prio},{sa},{da},{data},Unknown")
    for at, text in sorted((bad_rows or {}).items()):
        rows.insert(at - 1, text)                                # at: the 1-based line of the file
    path.write_text("\n".join(rows) + "\n")


def test_polycan_export_is_detected_and_reads_the_same_frames(tmp_path):
    frames = list(read_candump(EXCERPT))
    p = tmp_path / "capture.csv"
    _polycan(frames, p)
    assert detect(p) == "polycan"
    assert "polycan" not in TRUSTED_CLOCK                          # ms from the start: no absolute clock
    rs = ReadStats(source=p.name)
    table, fmt = read_frames(p, rs)
    assert fmt == "polycan" and rs.frames == len(frames) and rs.total_rejected == 0
    assert table.can_id.tolist() == [f.can_id for f in frames]
    np.testing.assert_allclose(table.t, [f.t - frames[0].t for f in frames], atol=1e-6)


def test_a_bad_row_is_counted_with_its_line_and_skipped(tmp_path):
    frames = list(read_candump(EXCERPT))
    p = tmp_path / "capture.csv"
    _polycan(frames, p, {5: "x,not a time,61444,3,0,255,00 11,Unknown", 9: "y,12.0,61444,3,0,255,ZZ,Unknown"})
    rs = ReadStats(source=p.name)
    _table, _fmt = read_frames(p, rs)
    assert rs.frames == len(frames)
    assert rs.rejected["garbage"] == 2 and rs.examples["garbage"] == [5, 9]


def test_inspect_reads_a_polycan_export(tmp_path, capsys):
    p = tmp_path / "capture.csv"
    _polycan(list(read_candump(EXCERPT)), p)
    assert main(["inspect", str(p)]) == 0
    out = capsys.readouterr().out
    assert "CAN capture format: polycan" in out and "EEC1" in out
