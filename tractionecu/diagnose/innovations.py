"""Second view: the estimator's innovations and parameter tracks.

The AUKF-FS (:mod:`tractionecu.estimation.estimator`) is replayed over the
recording.  A model that lacks a physical effect shows in it as

- NIS outside its χ² band more often than the nominal 5 % (95 % band per
  step, ``nis_dof`` degrees of freedom);
- non-white ground-speed innovations (Ljung–Box on v_gps − v̂ at the GNSS
  epochs, with v̂ the estimate just before the epoch's update);
- parameter tracks that follow a signature: ρ̂_s following sin θ (grade),
  or dv/dt (mass), front-minus-rear μ̂ following the draft (load transfer).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .features import Features
from .locate import ljung_box_p


class _OnGrid:
    """Estimator tracks sampled on the frame grid as the steps arrive: ``np.interp`` of each track at
    fixed query times, one batch of steps at a time (each batch joined to the last step before it,
    so the values are those of one ``np.interp`` over the whole track), plus running NIS sums.
    Memory: the frame-grid outputs and one batch."""

    BATCH = 4096

    def __init__(self, queries: list[NDArray[np.float64]], n_tracks: int) -> None:
        from scipy.stats import chi2

        self.chi2 = chi2
        self.q = queries                       # per track: sorted query times [epoch s]
        self.out = [np.full(q.size, np.nan) for q in queries]
        self.k = [0] * len(queries)            # next query not yet answered
        self.buf = np.empty((self.BATCH, 1 + n_tracks))
        self.nis = np.empty((self.BATCH, 3))   # nis, dof, valid
        self.m = 0
        self.prev: NDArray[np.float64] | None = None   # the last step of the batch before
        self.steps = 0
        self.n_valid = 0
        self.nis_n = 0
        self.nis_in = 0
        self.nis_per_dof = 0.0
        self._band: dict[int, tuple[float, float]] = {}

    def add(self, t: float, tracks: tuple[float, ...], nis: float, dof: int, valid: bool) -> None:
        self.buf[self.m, 0] = t
        self.buf[self.m, 1:] = tracks
        self.nis[self.m] = (nis, dof, valid)
        self.m += 1
        if self.m == self.BATCH:
            self._flush()

    def _flush(self, last: bool = False) -> None:
        b = self.buf[:self.m]
        n = self.nis[:self.m]
        self.steps += self.m
        ok = n[:, 2] > 0
        self.n_valid += int(ok.sum())
        mk = ok & np.isfinite(n[:, 0]) & (n[:, 1] > 0)
        if mk.any():
            dof = n[mk, 1].astype(int)
            lo = self.chi2.ppf(0.025, dof)
            hi = self.chi2.ppf(0.975, dof)
            x = n[mk, 0]
            self.nis_n += int(mk.sum())
            self.nis_in += int(np.sum((x >= lo) & (x <= hi)))
            self.nis_per_dof += float(np.sum(x / dof))
        seg = b if self.prev is None else np.vstack([self.prev[None, :], b])
        if seg.shape[0]:
            for j, q in enumerate(self.q):
                k0 = self.k[j]
                k1 = q.size if last else int(np.searchsorted(q, seg[-1, 0], side="right"))
                if k1 > k0:
                    self.out[j][k0:k1] = np.interp(q[k0:k1], seg[:, 0], seg[:, 1 + j])
                    self.k[j] = k1
            self.prev = seg[-1].copy()
        self.m = 0

    def close(self) -> None:
        self._flush(last=True)


def estimator_view(recording_dir: str | Path, feat: Features, rate_hz: float = 50.0) -> dict:
    """Replay the estimator over ``recording_dir`` and summarise its innovations (module doc).

    The recording is streamed (:func:`~tractionecu.pipeline.replay.replay_streamed`) and every step
    is reduced as it comes: NIS coverage by running counts, the tracks sampled on the frame grid
    (:class:`_OnGrid`), so memory does not grow with the number of steps."""
    from ..pipeline.replay import replay_streamed

    fr = feat.frame
    q_prior = fr.t - 1.0 / rate_hz + fr.t0_epoch
    q_now = fr.t + fr.t0_epoch
    grid = _OnGrid([q_prior, q_now, q_now], 3)

    def hook(e) -> None:
        grid.add(e.t, (e.v, e.rho_s, float(np.mean(e.mu[:2]) - np.mean(e.mu[2:]))), e.nis, e.nis_dof, bool(e.valid))

    replay_streamed(recording_dir, rate_hz=rate_hz, on_estimate=hook)
    grid.close()
    out: dict = {"steps": int(grid.steps),
                 "valid_share": float(grid.n_valid / grid.steps) if grid.steps else math.nan}
    if grid.nis_n:
        out["nis_coverage_95"] = float(grid.nis_in / grid.nis_n)
        out["nis_mean_per_dof"] = float(grid.nis_per_dof / grid.nis_n)
    have = grid.steps > 0
    # Ground-speed innovation proxy at the GNSS epochs: measured minus the estimate one step before.
    if feat.v_gps is not None and grid.steps > 2:
        inn = feat.v_gps - grid.out[0]
        g = np.isfinite(inn) & feat.valid
        if g.sum() > 30:
            out["v_innovation_rmse"] = float(np.sqrt(np.mean(inn[g] ** 2)))
            out["v_innovation_ljung_box_p"] = ljung_box_p(inn[g])
    # Parameter tracks against signatures.
    rho_f = grid.out[1] if have else None
    dmu_f = grid.out[2] if have else None
    corr: dict[str, float] = {}

    def c(name: str, a, b) -> None:
        if a is None or b is None:
            return
        k = feat.valid & np.isfinite(a) & np.isfinite(b)
        if k.sum() > 30 and np.std(a[k]) > 0 and np.std(b[k]) > 0:
            corr[name] = float(np.corrcoef(a[k], b[k])[0, 1])

    if feat.theta is not None:
        c("rho_s vs sin θ (grade)", rho_f, np.sin(feat.theta))
    c("rho_s vs pass direction", rho_f, feat.direction.astype(float))
    c("rho_s vs dv/dt (mass)", rho_f, feat.accel)
    if fr.fdx is not None:
        c("μ front − μ rear vs draft (load transfer)", dmu_f, fr.fdx)
    out["track_correlation"] = corr
    return out
