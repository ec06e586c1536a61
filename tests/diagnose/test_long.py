"""Diagnosis on long recordings: the recording is streamed into the frame, the estimator view keeps no
per-step arrays, and the data flow stays within a memory limit that the whole-recording code exceeds."""

import subprocess
import sys

import numpy as np
import pytest

from tractionecu.diagnose import data
from tractionecu.recording.concat import concatenate
from tractionecu.recording.reader import read_recording


@pytest.fixture(scope="module")
def drive(make_recording):
    """Two minutes of ``paper-three-soils`` (passes over the field, GNSS altitude and position)."""
    return make_recording("paper-three-soils", 7, 120.0)


def _frames_agree(a: data.Frame, b: data.Frame, rtol: float) -> None:
    for f in a.__dataclass_fields__:
        x, y = getattr(a, f), getattr(b, f)
        if isinstance(x, np.ndarray):
            assert y is not None and x.shape == y.shape, f
            if x.dtype.kind == "f":
                np.testing.assert_array_equal(np.isnan(x), np.isnan(y), err_msg=f)
                np.testing.assert_allclose(y, x, rtol=rtol, atol=rtol * float(np.nanmax(np.abs(x)) or 1.0),
                                           err_msg=f)
            else:
                np.testing.assert_array_equal(y, x, err_msg=f)
        elif f not in ("vehicle", "notes"):
            assert (x is None) == (y is None), f
    assert a.can_time_offset_s == pytest.approx(b.can_time_offset_s, abs=1e-9)


def test_a_streamed_frame_equals_the_frame_of_the_whole_recording(drive, monkeypatch):
    """Read in blocks of about 300 frames (dozens of blocks, bins and wheel-speed windows split between
    them), the frame is the one built from the recording read whole, but for rounding."""
    from tractionecu.config import load_vehicle
    from tractionecu.recording import fastdecode

    whole = data.frame_from_recording(read_recording(drive), load_vehicle(drive / "vehicle.toml"))
    monkeypatch.setattr(fastdecode, "CHUNK_CHARS", 1 << 14)
    streamed = data.load(drive)
    assert streamed.n == whole.n > 1000
    assert streamed.hf_omega is not None and streamed.md_edge is not None
    _frames_agree(whole, streamed, rtol=1e-9)


def test_the_estimator_view_reduces_steps_as_the_replay_keeps_them(short_recording):
    """The running NIS counts and the tracks sampled on the frame grid equal what the whole replay's
    arrays give (the view before it streamed kept every step)."""
    from scipy.stats import chi2

    from tractionecu.diagnose.features import compute
    from tractionecu.diagnose.innovations import estimator_view
    from tractionecu.pipeline.replay import replay

    feat = compute(data.load(short_recording))
    view = estimator_view(short_recording, feat)
    arr = replay(read_recording(short_recording), rate_hz=50.0).arrays
    ok = arr["valid"]
    m = ok & np.isfinite(arr["nis"]) & (arr["nis_dof"] > 0)
    x, dof = arr["nis"][m], arr["nis_dof"][m]
    assert view["steps"] == arr["t"].size > 300
    assert view["valid_share"] == pytest.approx(float(ok.mean()), abs=1e-12)
    assert m.any()
    inside = (x >= chi2.ppf(0.025, dof)) & (x <= chi2.ppf(0.975, dof))
    assert view["nis_coverage_95"] == pytest.approx(float(inside.mean()), abs=1e-12)
    assert view["nis_mean_per_dof"] == pytest.approx(float(np.mean(x / dof)), rel=1e-9)
    fr = feat.frame
    prior = np.interp(fr.t - 1.0 / 50.0, arr["t"] - fr.t0_epoch, arr["v"])
    inn = feat.v_gps - prior
    g = np.isfinite(inn) & feat.valid
    assert view["v_innovation_rmse"] == pytest.approx(float(np.sqrt(np.mean(inn[g] ** 2))), rel=1e-6)


_LIMITED = """
import resource, sys
import numpy as np
import scipy.linalg, scipy.sparse, scipy.interpolate, scipy.spatial, scipy.optimize, scipy.stats
from tractionecu.diagnose import data, features, channels, fit
vm = int([l for l in open('/proc/self/status') if l.startswith('VmPeak')][0].split()[1]) * 1024
limit = vm + int(sys.argv[1])
resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
try:
    fr = data.load(sys.argv[2])
    feat = features.compute(fr)
    problem = fit.Problem(feat, channels.build_channels(feat))
    null = fit.held_out(problem, None)
except MemoryError:
    print("MemoryError", file=sys.stderr)
    sys.exit(99)
print(fr.n, fr.t[-1], ",".join(sorted(problem.channels)),
      sum(int(np.isfinite(r).sum()) for r in null.resid.values()))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_AS and /proc are Linux's")
def test_a_long_recording_is_prepared_for_diagnosis_within_a_memory_limit(drive, tmp_path):
    """Two minutes of driving repeated to 45 minutes, read, binned, turned into features and channels
    and fitted with the nominal model (the held-out null fit), with the address space limited to what
    the interpreter has after its imports plus 320 MB.  The code before streaming read the capture
    whole and fitted the speed spline with a dense basis (n × n/30): +600 MB of address space on this
    recording, growing with the square of its length; streamed and banded it takes +180 MB (measured
    with VmPeak)."""
    import os

    length = concatenate(drive, tmp_path / "long", 45 * 60.0)
    env = dict(os.environ)
    for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env[k] = "1"
    p = subprocess.run([sys.executable, "-c", _LIMITED, str(320 * 2 ** 20), str(tmp_path / "long")],
                       capture_output=True, text=True, env=env, cwd=tmp_path)
    assert p.returncode == 0, p.stderr[-3000:]
    n, t_last, chans, n_resid = p.stdout.split()
    assert int(n) == pytest.approx(length * 10, abs=3)
    assert float(t_last) == pytest.approx(length, abs=0.5)
    assert {"gps_speed", "speed"} <= set(chans.split(","))
    assert int(n_resid) > int(n)
