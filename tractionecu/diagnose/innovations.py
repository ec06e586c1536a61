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

from .features import Features
from .locate import ljung_box_p


def estimator_view(recording_dir: str | Path, feat: Features, rate_hz: float = 50.0) -> dict:
    """Replay the estimator over ``recording_dir`` and summarise its innovations (module doc)."""
    from scipy.stats import chi2

    from ..pipeline.replay import replay
    from ..recording.reader import read_recording

    ts: list[float] = []
    rho: list[float] = []
    v_hat: list[float] = []
    nis: list[float] = []
    dof: list[int] = []
    mu_fr: list[float] = []
    valid: list[bool] = []

    def hook(e) -> None:
        ts.append(e.t)
        rho.append(e.rho_s)
        v_hat.append(e.v)
        nis.append(e.nis)
        dof.append(e.nis_dof)
        mu_fr.append(float(np.mean(e.mu[:2]) - np.mean(e.mu[2:])))
        valid.append(bool(e.valid))

    replay(read_recording(recording_dir), rate_hz=rate_hz, on_estimate=hook)
    t = np.asarray(ts)
    ok = np.asarray(valid)
    nis_a = np.asarray(nis)
    dof_a = np.asarray(dof)
    m = ok & np.isfinite(nis_a) & (dof_a > 0)
    out: dict = {"steps": int(t.size), "valid_share": float(ok.mean()) if ok.size else math.nan}
    if m.any():
        lo = chi2.ppf(0.025, dof_a[m])
        hi = chi2.ppf(0.975, dof_a[m])
        inside = (nis_a[m] >= lo) & (nis_a[m] <= hi)
        out["nis_coverage_95"] = float(inside.mean())
        out["nis_mean_per_dof"] = float(np.mean(nis_a[m] / dof_a[m]))
    fr = feat.frame
    te = t - fr.t0_epoch
    # Ground-speed innovation proxy at the GNSS epochs: measured minus the estimate one step before.
    if feat.v_gps is not None and t.size > 2:
        vh = np.asarray(v_hat)
        prior = np.interp(fr.t - 1.0 / rate_hz, te, vh)
        inn = feat.v_gps - prior
        g = np.isfinite(inn) & feat.valid
        if g.sum() > 30:
            out["v_innovation_rmse"] = float(np.sqrt(np.mean(inn[g] ** 2)))
            out["v_innovation_ljung_box_p"] = ljung_box_p(inn[g])
    # Parameter tracks against signatures.
    rho_f = np.interp(fr.t, te, np.asarray(rho)) if t.size else None
    dmu_f = np.interp(fr.t, te, np.asarray(mu_fr)) if t.size else None
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
