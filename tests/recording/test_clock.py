"""CAN and GNSS clocks that disagree: the offset found from the speeds, applied, reported, or refused."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from tractionecu import read_recording, replay
from tractionecu.errors import RecordingError
from tractionecu.recording.clock import estimate_offset

TOL_S = 0.05
"""The offset must be found within this [s] (issue 16)."""


def shifted(src: Path, dst: Path, new_t0: float) -> float:
    """Copy the recording with its CAN times moved to start at ``new_t0``; returns the true offset
    (GNSS time − shifted CAN time)."""
    shutil.copytree(src, dst)
    lines = (src / "can.log").read_text().splitlines()
    t0 = float(lines[0][1:lines[0].index(")")])
    out = [f"({float(ln[1:ln.index(')')]) - t0 + new_t0:017.6f}){ln[ln.index(')') + 1:]}" for ln in lines]
    (dst / "can.log").write_text("\n".join(out) + "\n")
    return t0 - new_t0


@pytest.fixture(scope="module")
def unshifted(short_recording):
    rec = read_recording(short_recording)
    return rec, replay(rec)


@pytest.mark.parametrize("new_t0", [0.0, 5.0], ids=["at-0", "1970+5s"])
def test_shifted_can_clock_is_found_and_replay_gives_the_same_estimates(short_recording, tmp_path, unshifted,
                                                                        new_t0):
    rec0, res0 = unshifted
    assert rec0.stats.clock_note == "" and rec0.stats.clock_offset_s == 0.0   # a good clock is left alone
    true = shifted(short_recording, tmp_path / "rec", new_t0)
    rec = read_recording(tmp_path / "rec")
    st = rec.stats
    assert abs(st.clock_offset_s - true) < TOL_S
    assert 0 < st.clock_sigma_s < TOL_S
    assert "CAN clock offset" in st.clock_note and "applied" in st.clock_note and "1970-01-01" in st.clock_note
    assert rec.t_end - rec.t_start < 13.0                      # on the GNSS axis, no span of decades
    res = replay(rec)
    a, b = res0.arrays, res.arrays
    assert a["t"].size == b["t"].size
    # the grid moves with the offset's error; the estimates do not (beyond what 30 ms of GNSS timing moves)
    assert np.max(np.abs(a["t"] - b["t"])) < TOL_S
    half = slice(a["t"].size // 2, None)
    assert np.max(np.abs(a["mu"][half] - b["mu"][half])) < 0.002
    assert np.max(np.abs(a["rho_s"][half] - b["rho_s"][half])) < 0.01
    assert b["valid"][half].all()


@pytest.mark.parametrize("late_s", [3.0, -2.0])
def test_a_trusted_clock_seconds_off_is_found_although_the_spans_overlap(short_recording, tmp_path, unshifted,
                                                                           late_s):
    """A candump clock 3 s late overlapped the GNSS epochs over 75 % and was left alone (only spans were
    compared): replay's μ error went from 1.0 to 10.7 % on a 60 s recording, with no word about the clock."""
    rec0, res0 = unshifted
    first = (short_recording / "can.log").read_text().split("\n", 1)[0]
    t0 = float(first[1:first.index(")")])
    true = shifted(short_recording, tmp_path / "rec", t0 + late_s)
    rec = read_recording(tmp_path / "rec")
    st = rec.stats
    assert abs(st.clock_offset_s - true) < TOL_S
    assert "disagree although their spans overlap" in st.clock_note and "applied" in st.clock_note
    res = replay(rec)
    half = slice(res0.arrays["t"].size // 2, None)
    a, b = res0.arrays, res.arrays
    n = min(a["t"].size, b["t"].size)
    assert np.max(np.abs(a["t"][:n] - b["t"][:n])) < TOL_S
    assert np.max(np.abs(a["mu"][half][: n // 2] - b["mu"][half][: n // 2])) < 0.002


def test_the_wheel_speeds_alone_also_find_the_offset(unshifted):
    rec, _ = unshifted
    wheels = {k: v for k, v in rec.signals.items() if k.startswith("WheelSpeed_")}
    off = estimate_offset(wheels, rec.gps.t - 1e9, rec.gps.speed)
    assert off.found and off.signal == "mean wheel speed"
    # wheel speed runs ahead of ground speed while slip builds up: ~0.11 s on this acceleration
    assert abs(off.offset_s + 1e9) < 0.15


def test_no_overlap_and_no_offset_is_a_clear_error(short_recording, tmp_path):
    shifted(short_recording, tmp_path / "rec", 0.0)
    # a GNSS log of another drive: constant speed, nothing to time it by
    lines = (tmp_path / "rec" / "gps.nmea").read_text().splitlines()
    keep = [ln for ln in lines if not ln.startswith(("$GPVTG", "$GNVTG"))]
    fixed = []
    for ln in keep:
        f = ln.split(",")
        if f[0].endswith("RMC"):
            f[7] = "5.0"
            body = ",".join(f).split("*")[0]
            cs = 0
            for c in body[1:]:
                cs ^= ord(c)
            ln = f"{body}*{cs:02X}"
        fixed.append(ln)
    (tmp_path / "rec" / "gps.nmea").write_text("\n".join(fixed) + "\n")
    with pytest.raises(RecordingError, match=r"CAN and GNSS clocks disagree: .* overlap over 0% .*"
                                             r"offset between them could not be found: .*constant"):
        read_recording(tmp_path / "rec")
    rec = read_recording(tmp_path / "rec", clock="report")
    assert "offset not found" in rec.stats.clock_note and rec.stats.clock_offset_s == 0.0


def test_inspect_reports_the_offset_and_the_unset_clock(short_recording, tmp_path, capsys):
    from tractionecu.cli.main import main

    shifted(short_recording, tmp_path / "rec", 0.0)
    assert main(["inspect", str(tmp_path / "rec")]) == 0
    out = capsys.readouterr().out
    assert "CAN capture format: candump" in out
    assert "clock: " in out and "CAN clock offset +1" in out and "applied" in out
    assert "WARNING: the CAN capture's own clock starts at 0.000 s (1970-01-01)" in out


def test_a_time_jump_is_warned_about_and_sizes_no_array(short_recording, tmp_path, capsys):
    from tractionecu.cli.main import main
    from tractionecu.diagnose.data import frame_from_recording
    from tractionecu.config import VehicleParams

    jump = 1e8                                         # three years forward in the middle of the capture
    shutil.copytree(short_recording, tmp_path / "rec")
    lines = (short_recording / "can.log").read_text().splitlines()
    tail = [f"({float(ln[1:ln.index(')')]) + jump:017.6f}){ln[ln.index(')') + 1:]}" for ln in lines[-400:]]
    (tmp_path / "rec" / "can.log").write_text("\n".join(lines + tail) + "\n")
    assert main(["inspect", str(tmp_path / "rec")]) == 0
    out = capsys.readouterr().out
    assert "WARNING: implausible duration 1e+08 s" in out
    assert "WARNING: 1 time jump(s) between consecutive CAN frames over 60 s: 1e+08 s at 2026-" in out
    rec = read_recording(tmp_path / "rec")
    res = replay(rec)                                  # the grid covers the spans with wheel speeds only
    assert res.arrays["t"].size < 1400                # 12 s + the 1 s after the jump at 100 Hz
    with pytest.raises(RecordingError, match="time jumps"):
        rec.table(100.0)
    with pytest.raises(RecordingError, match="time jumps"):
        frame_from_recording(rec, VehicleParams())


def test_a_drive_that_repeats_itself_keeps_its_logged_times(short_recording, tmp_path):
    """Copies of one drive joined end to end (the same noise in every copy) correlate best some copies
    away: the check moved a 45-minute log by 1200 s.  Its speeds agree at the logged times, and an offset
    the logs' spans contradict is never applied."""
    from tractionecu.recording.clock import check_offset
    from tractionecu.recording.concat import concatenate

    concatenate(short_recording, tmp_path / "rep", 6 * 12.0, gap_s=0.01)
    rec = read_recording(tmp_path / "rep")
    assert rec.stats.clock_offset_s == 0.0
    assert "applied" not in rec.stats.clock_note or "not applied" in rec.stats.clock_note
    # one speed 3 s late while the logs' spans agree: the speeds disagree, the spans contradict the offset
    raw = read_recording(short_recording, clock="keep")
    sp = raw.signals["GroundBasedMachineSpeed"]
    late = {"GroundBasedMachineSpeed": type(sp)(sp.t + 3.0, sp.value, sp.sa, sp.unit)}
    off = check_offset(late, raw.gps.t, raw.gps.speed, (raw.stats.can_t_first, raw.stats.can_t_last))
    assert not off.found and "not applied" in off.reason and "-3.0" in off.reason
    assert check_offset(late, raw.gps.t, raw.gps.speed).found      # without the spans: found


def _corr_at(ct, cv, gt, gv, off):
    """The refinement's correlation at one offset, one interpolation and ``np.corrcoef`` (the search's own code
    before it went in passes)."""
    tc = gt - off
    m = (tc >= ct[0]) & (tc <= ct[-1])
    if m.sum() < 5:
        return math.nan
    x = np.interp(tc[m], ct, cv)
    y = gv[m]
    if x.std() <= 0 or y.std() <= 0:
        return math.nan
    return float(np.corrcoef(x, y)[0, 1])


@pytest.mark.parametrize("seed", range(3))
def test_the_refinement_correlates_every_offset_as_one_at_a_time(seed, monkeypatch):
    """The fine search's correlations in passes (``_corr_many``) are those of one offset at a time: where the
    speeds overlap in part, not at all, or one is constant, and across pass boundaries."""
    from tractionecu.recording import clock

    rng = np.random.default_rng(seed)
    ct = np.sort(rng.uniform(0.0, 300.0, 3000))
    cv = np.cumsum(rng.normal(0.0, 0.1, ct.size))
    gt = np.arange(0.0, 300.0, 0.1) + rng.uniform(-5.0, 5.0)
    gv = np.interp(gt - 0.3, ct, cv) + rng.normal(0.0, 0.05, gt.size)
    offs = np.concatenate([np.arange(-0.4, 0.4, 0.001), [296.0, 299.99, 1e4]])   # a few samples, none
    monkeypatch.setattr(clock, "FINE_CHUNK", 7 * gt.size + 5)                  # passes of 7 offsets
    for c in (cv, np.full(ct.size, 2.5)):
        one = np.array([_corr_at(ct, c, gt, gv, o) for o in offs])
        many = clock._corr_many(ct, c, gt, gv, offs)
        assert np.array_equal(np.isnan(one), np.isnan(many))
        assert np.allclose(one, many, rtol=0.0, atol=1e-12, equal_nan=True)
    assert np.isfinite(one).sum() == 0 and np.isfinite(many).sum() == 0       # a constant CAN speed
    r = clock._corr_many(ct, cv, gt, gv, offs)
    assert abs(offs[int(np.nanargmax(r))] - 0.3) < 0.02
