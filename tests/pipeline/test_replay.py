"""``tractionecu replay`` on a short simulated recording: the pipeline's run directory, scored by the evaluation side."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from tractionecu.cli.main import main
from tractionecu.evaluation.replay import score_replay
from tractionecu.evaluation.scoring import r_squared
from tractionecu.pipeline.replay import CSV_COLUMNS, replay
from tractionecu.pipeline.rundir import replay_to_dir
from tractionecu.recording.reader import read_recording
from tractionecu.sim import scenarios
from tractionecu.sim.simulator import simulate
from tractionecu.sim.writer import write_recording


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    out = tmp_path_factory.mktemp("rec")
    scn = scenarios.get("paper-three-soils", seed=3, duration_s=40.0)
    write_recording(scn, simulate(scn), out)
    return out


def test_replay_writes_estimates_scorecard_and_config(rec, tmp_path):
    seen = []
    res, recording, result = replay_to_dir(rec, tmp_path / "run", on_estimate=seen.append)
    run = tmp_path / "run"
    assert not (run / "scorecard.json").exists()          # the core does not score
    res.update(score_replay(run, recording, result.arrays, plot=False, summary=res))
    assert len(seen) == res["steps"] > 3500
    with open(run / "estimates.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    assert tuple(rows[0]) == CSV_COLUMNS and len(rows) == res["steps"] + 1
    sc = json.loads((run / "scorecard.json").read_text())
    for key in ("mu_mean_abs_rel_error", "rho_s_mean_abs_error", "r2_mu_curve", "reconvergence_s", "nis_within_95"):
        assert key in sc
    assert sc["mu_mean_abs_rel_error"] < 0.02
    assert 0.85 < sc["nis_within_95"] <= 1.0
    assert "stubble-firm" in sc["r2_mu_curve"]
    assert (run / "config.toml").read_text().count("[estimator]") == 1
    # the last estimate is valid and the filter ran every step at 100 Hz
    assert seen[-1].valid
    assert np.allclose(np.diff([e.t for e in seen]), 0.01, rtol=0, atol=1e-6)   # epoch-second floats


def test_replay_is_deterministic(rec, tmp_path):
    replay_to_dir(rec, tmp_path / "a")
    replay_to_dir(rec, tmp_path / "b")
    assert (tmp_path / "a" / "estimates.csv").read_bytes() == (tmp_path / "b" / "estimates.csv").read_bytes()


def test_in_memory_replay_equals_the_run_directory(rec, tmp_path):
    """Diagnosis reads the replay in memory: the same estimates as the written run, no files."""
    _, _, written = replay_to_dir(rec, tmp_path / "run", write_map=False)
    before = set(tmp_path.iterdir())
    mem = replay(read_recording(rec))
    assert set(tmp_path.iterdir()) == before
    for key in ("t", "mu", "slip", "rho_s", "a", "P_diag", "status", "valid"):
        np.testing.assert_array_equal(mem.arrays[key], written.arrays[key])
    assert mem.arrays["soil_class"] == written.arrays["soil_class"]


def test_cli_replay_prints_the_scorecard(rec, tmp_path, capsys):
    assert main(["replay", str(rec), "--out", str(tmp_path / "cli"), "--rate", "50"]) == 0
    out = capsys.readouterr().out
    assert "mu_mean_abs_rel_error" in out and "r2_mu_curve[stubble-firm]" in out
    assert (tmp_path / "cli" / "estimates.csv").is_file()


def test_cli_replay_missing_recording_is_an_error(tmp_path, capsys):
    assert main(["replay", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 1
    assert "nope" in capsys.readouterr().err


def test_r_squared():
    y = np.linspace(0, 1, 11)
    assert r_squared(y, y) == 1.0
    assert r_squared(np.full(11, y.mean()), y) == pytest.approx(0.0)


def test_grid_ends_with_the_wheel_speeds_whatever_runs_on(rec):
    """A signal that runs on long after the drive-train (or a stray late time stamp) asks for no steps."""
    from tractionecu.pipeline.replay import recording_grid
    from tractionecu.pipeline.steps import GRID_MAX_GAP_S

    r = read_recording(rec)
    ws_end = float(r.signals["WheelSpeed_FL"].t[-1])
    late = r.signals["DraftForce"]
    late.t = np.append(late.t, ws_end + 3600.0 * 24 * 365)   # one draft sample a year later
    late.value = np.append(late.value, late.value[-1])
    late.sa = np.append(late.sa, late.sa[-1])
    grid = recording_grid(r, 100.0)
    assert grid[-1] <= ws_end + GRID_MAX_GAP_S


# ----------------------------------------------------------------------------- streaming (issue 21)
def _nmea_speed_spike(src, dst, t0_frac: float, seconds: float, knots: float = 20.0) -> None:
    """``dst``: ``src`` with the GNSS speed over ground set to ``knots`` for ``seconds`` from ``t0_frac`` of
    the log (the filter refuses it for longer than lost_after_s and is declared lost)."""
    import shutil

    shutil.copytree(src, dst)
    lines = (src / "gps.nmea").read_text().splitlines()
    out = []
    n0 = int(len(lines) * t0_frac)
    n1 = n0 + int(len(lines) * seconds / 40.0)
    for i, ln in enumerate(lines):
        if n0 <= i < n1 and ln[3:6] in ("RMC", "VTG"):
            f = ln[1:ln.index("*")].split(",")
            if ln[3:6] == "RMC":
                f[7] = f"{knots:.1f}"
            else:
                f[5], f[7] = f"{knots:.1f}", f"{knots * 1.852:.1f}"
            body = ",".join(f)
            ck = 0
            for ch in body:
                ck ^= ord(ch)
            ln = f"${body}*{ck:02X}"
        out.append(ln)
    (dst / "gps.nmea").write_text("\n".join(out) + "\n")


@pytest.mark.parametrize("keep_arrays", [True, False], ids=["arrays-kept", "streamed-only"])
@pytest.mark.parametrize("loop", [dict(compiled=False), dict(), dict(hold_bytes=1 << 30)],
                         ids=["step-path", "compiled-streamed", "compiled-one-pass"])
def test_a_streamed_replay_writes_what_the_in_memory_one_writes(rec, tmp_path, monkeypatch, keep_arrays, loop):
    """Read in blocks of 30 000 characters, with a lost filter whose period starts before the block it is
    declared in: the same estimates.csv bytes, map tiles and arrays as the recording replayed in memory on the
    step path, whichever loop replays it from its path (the compiled one with the capture decoded again block by
    block, its default, or decoded once with the blocks held)."""
    from tractionecu.recording import fastdecode

    _nmea_speed_spike(rec, tmp_path / "rec", 0.5, 3.0)
    mem_rec = read_recording(tmp_path / "rec")
    s_mem, _, r_mem = replay_to_dir(mem_rec, tmp_path / "mem", compiled=False)
    assert r_mem.counters["lost"] >= 1 and s_mem["loop"] == "python: compiled=False"
    monkeypatch.setattr(fastdecode, "CHUNK_CHARS", 30_000)
    s_str, survey, r_str = replay_to_dir(tmp_path / "rec", tmp_path / "str", keep_arrays=keep_arrays, **loop)
    assert s_str["loop"] == ("python: compiled=False" if loop.get("compiled") is False else "compiled")
    assert s_str["decode"].startswith("one pass" if "hold_bytes" in loop else "streamed")
    assert (tmp_path / "str" / "estimates.csv").read_bytes() == (tmp_path / "mem" / "estimates.csv").read_bytes()
    assert r_str.counters == r_mem.counters and r_str.steps == r_mem.steps
    assert s_str["sim_seconds"] == s_mem["sim_seconds"] and s_str["map_samples"] == s_mem["map_samples"] > 0
    tiles = sorted(p.relative_to(tmp_path / "mem") for p in (tmp_path / "mem" / "map").rglob("*")
                   if p.is_file() and p.name != "manifest.json")
    assert tiles and tiles == sorted(p.relative_to(tmp_path / "str") for p in (tmp_path / "str" / "map").rglob("*")
                                     if p.is_file() and p.name != "manifest.json")
    for p in tiles:
        assert (tmp_path / "str" / p).read_bytes() == (tmp_path / "mem" / p).read_bytes(), p
    assert len(survey.signals["DriveTorque_FL"]) == 2                         # a stub: not held
    if keep_arrays:
        for k, v in r_mem.arrays.items():
            if isinstance(v, np.ndarray):
                np.testing.assert_array_equal(r_str.arrays[k], v, err_msg=k)
    else:
        assert r_str.arrays["t"].size < r_mem.steps // 5                       # the map's steps only


def _long_can_only(src, dst, copies: int) -> float:
    """``dst``: the CAN log of ``src`` ``copies`` times back to back; returns the recorded length [s]."""
    dst.mkdir()
    lines = (src / "can.log").read_text().splitlines()
    t = [float(ln[1:ln.index(")")]) for ln in lines]
    span = t[-1] - t[0] + 0.01
    rest = [ln[ln.index(")") + 1:] for ln in lines]
    with open(dst / "can.log", "w") as fh:
        for c in range(copies):
            fh.write("".join(f"({x + c * span:017.6f}){r}\n" for x, r in zip(t, rest)))
    return copies * span


_LIMITED = """
import resource, sys
limit = int(sys.argv[1])
resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
sys.argv = ["tractionecu", *sys.argv[2:]]
from tractionecu.cli.main import main
try:
    rc = main(sys.argv[1:])
except MemoryError:
    print("MemoryError", file=sys.stderr)
    rc = 99
sys.exit(rc)
"""


def _baseline_vm(tmp_path) -> int:
    """Peak virtual memory [B] of an interpreter that imported what replay imports: the limit's floor."""
    import subprocess
    import sys

    code = ("import tractionecu.pipeline.replay, tractionecu.cli.main, tractionecu.mapping.from_replay\n"
            "print([l for l in open('/proc/self/status') if l.startswith('VmPeak')][0].split()[1])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env=_one_thread_env(), cwd=tmp_path).stdout
    return int(out) * 1024


def _one_thread_env() -> dict:
    import os

    env = dict(os.environ)
    for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env[k] = "1"
    return env


@pytest.mark.skipif(not __import__("sys").platform.startswith("linux"), reason="RLIMIT_AS and /proc are Linux's")
def test_a_long_recording_replays_within_a_memory_limit(rec, tmp_path):
    """40 s of drive repeated to 8 minutes (CAN only, default vehicle), replayed with the address space
    limited to what the interpreter needs plus 125 MB.  The replay before it streamed (the capture read
    whole, every step held, estimates.csv formatted from one list) peaked at +173 MB of address space on
    this recording; the streamed one at +73 MB, whatever the length (measured with VmPeak)."""
    import subprocess
    import sys

    length = _long_can_only(rec, tmp_path / "long", 12)
    limit = _baseline_vm(tmp_path) + 125 * 2 ** 20
    p = subprocess.run([sys.executable, "-c", _LIMITED, str(limit), "replay", str(tmp_path / "long"), "--out",
                        str(tmp_path / "run"), "--no-map"], capture_output=True, text=True, env=_one_thread_env(),
                       cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    with open(tmp_path / "run" / "estimates.csv") as fh:
        n = sum(1 for _ in fh) - 1
    assert n == pytest.approx(length * 100, rel=0.01)


def test_a_replay_into_a_directory_another_replay_writes_is_refused(short_recording, tmp_path, locked_elsewhere):
    """Two replays into one directory both wrote ``estimates.csv.partial``: the second truncated the first's, which
    went on writing at its offset and moved a file with a hole of NUL bytes over ``estimates.csv`` (exit 0);
    the second then failed on the rename.  A replay now holds its output directory's lock while it runs: a
    second one, in another process, is refused by name and the estimates written before are left whole."""
    from tractionecu.mapping.tiles import MapStoreError

    run = tmp_path / "run"
    replay_to_dir(short_recording, run, write_map=False)
    before = (run / "estimates.csv").read_bytes()
    with locked_elsewhere(run):
        with pytest.raises(MapStoreError, match="another replay is writing into this directory"):
            replay_to_dir(short_recording, run, write_map=False)
        assert main(["replay", str(short_recording), "--out", str(run), "--no-map"]) == 1
    assert (run / "estimates.csv").read_bytes() == before
    assert sorted(p.name for p in run.iterdir()) == ["config.toml", "estimates.csv"]
    replay_to_dir(short_recording, run, write_map=False)      # the lock goes with the process that held it
    assert (run / "estimates.csv").read_bytes() == before


def test_a_replay_reads_its_vehicle_file_once_while_it_is_unchanged(rec, tmp_path, monkeypatch):
    """The check, the run directory's writer and the loop each asked for the machine: three reads of
    ``vehicle.toml`` per replay.  One now; an edited file is read again."""
    import shutil

    from tractionecu.pipeline import replay as replay_mod

    copy = tmp_path / "rec"
    shutil.copytree(rec, copy)
    calls = []
    real = replay_mod.load_vehicle
    monkeypatch.setattr(replay_mod, "load_vehicle", lambda p: calls.append(p) or real(p))
    replay_to_dir(copy, tmp_path / "a", write_map=False)
    assert len(calls) == 1
    text = (copy / "vehicle.toml").read_text()
    (copy / "vehicle.toml").write_text(text + "\n# edited\n")      # another size: read again
    replay_to_dir(copy, tmp_path / "b", write_map=False)
    assert len(calls) == 2
    assert (tmp_path / "a" / "estimates.csv").read_bytes() == (tmp_path / "b" / "estimates.csv").read_bytes()
