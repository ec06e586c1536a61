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

    length = concatenate(drive, tmp_path / "long", 45 * 60.0, gap_s=0.01)
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


@pytest.fixture(scope="module")
def joined(drive, tmp_path_factory):
    """Three copies of the two-minute drive: joined mid-drive (each copy restarts at the first one's
    start point and speed 10 ms after the last one ended) and with the logger off for 30 s between."""
    d = tmp_path_factory.mktemp("joined")
    return (concatenate(drive, d / "join", 360.0, gap_s=0.01), d / "join",
            concatenate(drive, d / "gap", 360.0, gap_s=30.0), d / "gap")


def test_a_day_log_is_cut_at_its_breaks(drive, joined):
    """A position jump without a gap in time, or a stretch without any sample, starts a new piece:
    the joints of the copies are found (none in one copy), samples within BREAK_MARGIN_S of them are
    not used, and no work segment spans one."""
    from tractionecu.diagnose import features

    one = features.compute(data.load(drive))
    assert one.frame.break_t == ()
    length, join, _, gap = joined
    span = length / 3
    for rec, step in ((join, span), (gap, span + 30.0 - 0.01)):
        feat = features.compute(data.load(rec))
        fr = feat.frame
        assert len(fr.break_t) == 2
        np.testing.assert_allclose(fr.break_t, [step, 2 * step], atol=0.15)
        for b in fr.break_t:
            near = np.abs(fr.t - b) < features.BREAK_MARGIN_S - 0.1
            assert not feat.valid[near].any()
            before = set(feat.segment[fr.t < b].tolist()) - {-1}
            after = set(feat.segment[fr.t >= b].tolist()) - {-1}
            assert not before & after
        assert any("break" in n for n in feat.notes)
        # No fused speed where nothing was measured (the spline's edge coefficients reached 900 m/s
        # there, and the relaxation filter's distance grid grew with them).
        assert np.nanmax(np.abs(feat.v_ref)) < np.nanmax(np.abs(fr.v_gps)) + 1.0
        assert np.isnan(feat.v_ref[features.logger_off(fr)]).all()


def test_the_speed_nuisance_is_free_to_jump_at_a_break():
    """The spline basis with a break is one independent basis per piece (no column spans the break);
    without breaks it is the basis it always was."""
    from tractionecu.diagnose.features import spline_basis

    t = np.arange(0.0, 60.0, 0.1)
    B0 = spline_basis(t, 3.0, sparse=True)
    np.testing.assert_array_equal(spline_basis(t, 3.0, sparse=True, breaks=()).toarray(), B0.toarray())
    B = spline_basis(t, 3.0, sparse=True, breaks=(25.0,)).toarray()
    left, right = t < 25.0, t >= 25.0
    cols_l = np.flatnonzero(np.abs(B[left]).sum(axis=0) > 0)
    cols_r = np.flatnonzero(np.abs(B[right]).sum(axis=0) > 0)
    assert not set(cols_l) & set(cols_r)
    np.testing.assert_allclose(B.sum(axis=1), 1.0)      # partition of unity within each piece
    y = np.where(left, 1.0, -2.0) + 0.5 * np.sin(t / 10.0)    # a step at the break, slow elsewhere
    for basis, worst in ((B, 0.01), (B0.toarray(), 0.5)):
        beta, *_ = np.linalg.lstsq(basis, y, rcond=None)
        err = np.max(np.abs(basis @ beta - y))
        assert (err < worst) if worst < 0.1 else (err > worst)


def test_no_residual_spans_a_joint(joined):
    """Regression: joined copies (the track and speed jump back to the start) gave the nominal model's
    slip residual ten times its size elsewhere within 10 s of each joint (the fused ground speed's
    spline ran smoothly across the jump), and a four-hour recording made so was diagnosed
    ``clock_skew`` (held-out score 700).  Cut at the joints, the residual there is that of the rest,
    and no clock error is found."""
    from tractionecu.diagnose import channels, features, fit
    from tractionecu.diagnose.engine import DETECT_LLR

    length, join, _, gap = joined
    span = length / 3
    for rec in (join, gap):
        feat = features.compute(data.load(rec))
        problem = fit.Problem(feat, channels.build_channels(feat))
        null = fit.held_out(problem, None)
        ch = problem.channels["slip"]
        r = null.resid["slip"]
        near = np.zeros(ch.m, dtype=bool)
        for b in feat.frame.break_t:
            near |= np.abs(ch.t - b) < 10.0
        assert near.sum() > 100
        rms_near = float(np.sqrt(np.nanmean(r[near] ** 2)))
        rms_rest = float(np.sqrt(np.nanmean(r[~near] ** 2)))
        assert rms_near < 1.5 * rms_rest, (rec.name, rms_near, rms_rest)
        f = fit.fit(problem, "clock_skew")
        sc, _ = fit.score(problem, null, fit.held_out(problem, "clock_skew", x_start=f.x))
        assert sc < DETECT_LLR, (rec.name, sc, f.params)


def test_per_row_arrays_are_compact_and_shared(drive):
    """The per-wheel channels keep their fold in one byte and their wheel in one, the frame row index
    once (not a copy as the time index), and the wheel-force channel uses the slip channel's row arrays
    when its rows are the same; it keeps no raw-rate ground speed."""
    from tractionecu.diagnose import channels, features

    feat = features.compute(data.load(drive))
    chs = {c.name: c for c in channels.build_channels(feat)}
    slip, wf = chs["slip"], chs["wheel_force"]
    for ch in (chs[c] for c in ("slip", "wheel_force", "gps_speed", "front_load", "draft") if c in chs):
        assert ch.fold.dtype == np.int8 and set(np.unique(ch.fold)) <= {0, 1}
        np.testing.assert_array_equal(ch.fold, feat.fold[ch.tidx])
    assert slip.tidx is slip.ti and slip.wi.dtype == np.int8
    same = wf.m == slip.m and np.array_equal(wf.ti, slip.ti) and np.array_equal(wf.wi, slip.wi)
    assert (wf.t is slip.t and wf.ti is slip.ti and wf.wi is slip.wi and wf.fold is slip.fold) == same
    if not same:          # rows the raw-rate wheel speeds do not cover: the channel's own (compact) arrays
        assert wf.wi.dtype == np.int8 and wf.tidx is wf.ti
    assert not hasattr(wf, "v_hf")
    np.testing.assert_array_equal(slip.cell, feat.cell[slip.ti] * 2 + (slip.wi >= 2))


def test_held_out_scores_do_not_depend_on_how_the_residuals_are_kept(drive, monkeypatch):
    """A candidate's held-out residuals are kept in float32, its score from the float64 values: the
    scores equal those with float64 residuals kept (each on freshly built channels, so that no warm
    start differs), and the kept residuals are those values rounded."""
    from tractionecu.diagnose import channels, features, fit

    def run():
        feat = features.compute(data.load(drive))
        problem = fit.Problem(feat, channels.build_channels(feat))
        null = fit.held_out(problem, None)
        out = {}
        for name in ("wheel_radius", "mass"):
            ho = fit.held_out(problem, name)
            out[name] = (fit.score(problem, null, ho), ho)
        return null, out

    null32, kept32 = run()
    monkeypatch.setattr(fit, "RESID_DTYPE", np.float64)
    _, kept64 = run()
    assert all(r.dtype == np.float64 for r in null32.resid.values())
    for name in kept32:
        (s32, per32), ho32 = kept32[name]
        (s64, per64), ho64 = kept64[name]
        assert s32 == s64 and per32 == per64
        for c, r in ho32.resid.items():
            assert r.dtype == np.float32
            np.testing.assert_array_equal(r, ho64.resid[c].astype(np.float32))
