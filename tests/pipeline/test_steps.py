"""The step rule's two forms are equal, and the daemon's incremental path gives replay's estimates.

The daemon's path here is the one it runs: NMEA bytes through
:class:`~tractionecu.service.gps.NmeaStream` (strict parse, epochs, the
pipeline's GNSS gate, UTC time), bus samples and accepted GNSS speeds into
:class:`~tractionecu.pipeline.steps.StepAssembler`, one estimator step per
grid time.  Replay is :func:`tractionecu.pipeline.replay.replay`.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from tractionecu.estimation.estimator import Estimator
from tractionecu.estimation.smoother import FixedLagSmoother
from tractionecu.gnss.nmea import checksum
from tractionecu.pipeline.gnss import GnssGate
from tractionecu.pipeline.replay import machine_of, recording_grid, replay
from tractionecu.pipeline.signals import GROUPS
from tractionecu.pipeline.steps import StepAssembler, vector_steps
from tractionecu.recording.reader import read_recording
from tractionecu.service.config import GpsConfig
from tractionecu.service.gps import NmeaStream

NMEA_DELAY_S = 0.02
"""Arrival of an epoch's sentences after its UTC time [s] (receiver output latency)."""

LAG_S = 0.05
"""Each step is taken once every sample stamped up to this long after it has arrived [s]."""


def _bus_events(rec) -> list[tuple[float, int, dict[str, float]]]:
    """Every bus sample of the estimator's groups as (t, order, signal values), one per frame."""
    ev = []
    for names in GROUPS.values():
        s0 = rec.signals[names[0]]
        for i in range(len(s0)):
            ev.append((float(s0.t[i]), len(ev), {nm: float(rec.signals[nm].value[i]) for nm in names}))
    return ev


def _nmea_epochs(path: Path) -> list[list[str]]:
    """The lines of ``gps.nmea`` grouped by epoch (a GGA starts one)."""
    epochs: list[list[str]] = []
    for line in path.read_text(encoding="ascii").splitlines():
        if line.startswith("$GNGGA") or not epochs:
            epochs.append([])
        epochs[-1].append(line)
    return epochs


def _epoch_time(lines: list[str], rec) -> float:
    """UTC epoch time [s] of an epoch's lines, from the aligned track of the clean recording."""
    tod = lines[0].split(",")[1]
    hh, mm, ss = int(tod[:2]), int(tod[2:4]), float(tod[4:])
    t0 = float(rec.gps.t[0])
    day0 = t0 - (t0 % 86400.0)
    return day0 + hh * 3600 + mm * 60 + ss


def _daemon_estimates(rec, nmea_lines: list[tuple[float, str]], grid, gate: GnssGate):
    """Estimates of the daemon's incremental path (module doc) over ``grid``."""
    vehicle, sensors = machine_of(rec)
    est = Estimator(vehicle, sensors=sensors)
    smoother = FixedLagSmoother.from_config(est.cfg)      # the service's loop delivers through it, as replay
    asm = StepAssembler()
    stream = NmeaStream(GpsConfig(), lambda s: asm.push_speed(s.t, s.speed_mps, s.course_deg)
                        if s.speed_mps is not None else None, gate)
    ev: list[tuple[float, int, str, object]] = [(t, k, "bus", v) for t, k, v in _bus_events(rec)]
    ev += [(t, len(ev) + k, "nmea", line) for k, (t, line) in enumerate(nmea_lines)]
    ev.sort(key=lambda e: (e[0], e[1]))
    j = 0
    out = []
    for t in grid.tolist():
        while j < len(ev) and ev[j][0] <= t + LAG_S:
            t_ev, _, kind, payload = ev[j]
            if kind == "bus":
                asm.push_signals(t_ev, payload)  # type: ignore[arg-type]
            else:
                stream.feed((payload + "\r\n").encode("ascii"), t_ev)  # type: ignore[operator]
            j += 1
        inputs, meas = asm.take(t)
        out.extend(smoother.push(est.step(t, inputs, meas)))
    out.extend(smoother.flush())
    return out, asm, stream


def _assert_same(mine, theirs) -> None:
    assert len(mine) == len(theirs)
    for a, b in zip(mine, theirs):
        assert a.t == b.t
        assert a.status == b.status
        np.testing.assert_array_equal(a.mu, b.mu)
        np.testing.assert_array_equal(a.slip, b.slip)
        np.testing.assert_array_equal(a.P_diag, b.P_diag)
        assert a.rho_s == b.rho_s or (np.isnan(a.rho_s) and np.isnan(b.rho_s))
        assert a.a == b.a or (np.isnan(a.a) and np.isnan(b.a))


def test_vector_and_incremental_forms_give_equal_arguments(short_recording: Path) -> None:
    rec = read_recording(short_recording)
    grid = recording_grid(rec, 100.0)
    mask = GnssGate().track_mask(rec.gps)
    vec = list(vector_steps(rec.signals, rec.gps.t[mask], rec.gps.speed[mask], grid, course=rec.gps.course[mask]))
    asm = StepAssembler()
    ev = [(t, k, "bus", v) for t, k, v in _bus_events(rec)]
    ev += [(float(t), len(ev) + k, "v", (float(v), float(c)))
           for k, (t, v, c) in enumerate(zip(rec.gps.t[mask], rec.gps.speed[mask], rec.gps.course[mask]))]
    ev.sort(key=lambda e: (e[0], e[1]))
    j = 0
    passed = {"Md": 0, "Fzf": 0, "Fdx": 0, "omega": 0, "dir": 0, "v": 0, "course": 0}
    for k, t in enumerate(grid.tolist()):
        while j < len(ev) and ev[j][0] <= t + LAG_S:
            if ev[j][2] == "bus":
                asm.push_signals(ev[j][0], ev[j][3])  # type: ignore[arg-type]
            else:
                asm.push_speed(ev[j][0], *ev[j][3])  # type: ignore[misc]
            j += 1
        inc = asm.take(t)
        for a, b in zip(vec[k], inc):
            assert a.keys() == b.keys(), f"step {k}: {a.keys()} != {b.keys()}"
            for key in a:
                np.testing.assert_array_equal(a[key], b[key])
                passed[key] += 1
    assert asm.anchor == grid[0]
    assert asm.counts["late"] == 0
    # every group was passed, each about at its own rate (100, 50, 50, 100 Hz and 10 Hz GNSS)
    n = grid.size
    assert passed["omega"] > 0.95 * n and passed["Md"] > 0.95 * n
    assert 0.45 * n < passed["Fzf"] < 0.55 * n and 0.45 * n < passed["Fdx"] < 0.55 * n
    assert 0.09 * n < passed["v"] < 0.11 * n
    assert passed["course"] == passed["v"]          # the course goes with the speed of its epoch


def test_daemon_path_matches_replay_exactly(short_recording: Path) -> None:
    rec = read_recording(short_recording)
    got_replay = []
    replay(rec, on_estimate=got_replay.append)
    nmea = [(_epoch_time(ep, rec) + NMEA_DELAY_S, line) for ep in _nmea_epochs(short_recording / "gps.nmea")
            for line in ep]
    mine, asm, stream = _daemon_estimates(rec, nmea, recording_grid(rec, 100.0), GnssGate())
    _assert_same(mine, got_replay)
    assert asm.counts["late"] == 0 and stream.stats["accepted"] == len(rec.gps)
    assert sum(e.valid for e in mine) > len(mine) // 3, "the estimator never converged on the fixture"


def _resign(line: str, fields: dict[int, str]) -> str:
    """``line`` with some comma-separated fields replaced and its checksum recomputed."""
    body = line[1:line.index("*")].split(",")
    for i, v in fields.items():
        body[i] = v
    text = ",".join(body)
    return f"${text}*{checksum(text)}"


@pytest.fixture(scope="module")
def bad_gnss_recording(short_recording: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``short_recording`` with bad GNSS epochs: RMC status V, GGA quality 0, HDOP 9.9, a repeated epoch."""
    out = tmp_path_factory.mktemp("bad-gnss") / "rec"
    shutil.copytree(short_recording, out)
    epochs = _nmea_epochs(out / "gps.nmea")
    assert all(ep[0].startswith("$GNGGA") and ep[1].startswith("$GNRMC") for ep in epochs)
    for k in range(20, 30):                       # 1 s of invalid fixes (receiver says V)
        epochs[k][1] = _resign(epochs[k][1], {2: "V"})
    for k in range(40, 45):                       # no fix in GGA
        epochs[k][0] = _resign(epochs[k][0], {6: "0"})
    for k in range(60, 70):                       # poor geometry
        epochs[k][0] = _resign(epochs[k][0], {8: "9.9"})
    lines = [line for k, ep in enumerate(epochs) for line in ep + (epochs[k - 1] if k == 80 else [])]
    (out / "gps.nmea").write_text("\n".join(lines) + "\n", encoding="ascii")
    return out


def test_bad_gnss_epochs_daemon_and_replay_agree(bad_gnss_recording: Path) -> None:
    rec = read_recording(bad_gnss_recording)
    gate = GnssGate()
    got_replay = []
    res = replay(rec, gate=gate, on_estimate=got_replay.append)
    assert dict(res.gnss) == {"gated_invalid": 10, "gated_fix_quality": 5, "gated_hdop": 10}
    assert rec.stats.files["gps.nmea"].rejected["time_backwards"] == 1   # the repeated epoch, at alignment
    assert int(res.gps_mask.sum()) == len(rec.gps) - 25

    # The daemon receives the same bytes, each epoch 20 ms after its UTC time; the repeated
    # epoch arrives when it was sent (after the epoch that followed it).
    epochs = _nmea_epochs(bad_gnss_recording / "gps.nmea")
    nmea = []
    last = -np.inf
    for ep in epochs:
        t = max(_epoch_time(ep, rec), last) + NMEA_DELAY_S
        last = t - NMEA_DELAY_S
        nmea += [(t, line) for line in ep]
    mine, asm, stream = _daemon_estimates(rec, nmea, recording_grid(rec, 100.0), gate)
    assert stream.stats["gated_invalid"] == 10 and stream.stats["gated_fix_quality"] == 5
    assert stream.stats["gated_hdop"] == 10 and stream.stats["gated_repeated"] == 1
    assert stream.stats["accepted"] == int(res.gps_mask.sum())
    _assert_same(mine, got_replay)

    # The bad epochs mattered: feeding every recorded epoch to the estimator gives other estimates.
    ungated = []
    replay(rec, gate=GnssGate(min_fix_quality=0, max_hdop=99.0), on_estimate=ungated.append)
    assert any(not np.array_equal(a.mu, b.mu) for a, b in zip(ungated, got_replay))
