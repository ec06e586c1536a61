"""Where, when and under which regime the model and the recording disagree.

- *which*: residual RMSE per channel, whiteness by Ljung–Box
  (``statsmodels.stats.diagnostic.acorr_ljungbox``), and NIS coverage: the
  share of per-time residuals r_t with r_t²/σ² inside the χ²(1) 95 % bound
  (3.841), σ the channel's measurement-noise level from successive
  differences, σ = 1.4826 · MAD(Δr)/√2 (slow model errors cancel in Δr, so σ
  is the same before and after an effect is modelled; white residuals at the
  noise level give 0.95, a systematic mismatch gives less);
- *when*: change points of the residual level by PELT (``ruptures``, ``l2``
  cost) on 2-s means (wider on recordings over half an hour: :data:`MAX_CHANGE_WINDOWS`), with a penalty of 3 ln(n) σ²_lr (σ²_lr the residual's
  long-run variance), so that autocorrelated noise does not fragment it;
- *where*: the residual at its GNSS position (the map is drawn by
  :mod:`.report`);
- *regime*: mean and RMS of the residual by speed band, accelerating or
  steady, pass direction, draft level and (slip) front versus rear wheels.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .channels import Channel
from .features import Features


@dataclass
class ChannelStats:
    rmse: float
    ljung_box_p: float
    """p-value of the Ljung–Box test at lag 10 (small: not white)."""
    n: int


def ljung_box_p(resid: NDArray, lags: int = 10) -> float:
    """Ljung–Box p-value of a residual series at lag ``lags`` (NaN when too short).

    Q = n (n + 2) Σ_{k=1..L} ρ_k² / (n − k) against χ²(L), the autocorrelations ρ_k by FFT (the
    same statistic as ``statsmodels.stats.diagnostic.acorr_ljungbox``, whose direct
    autocovariance is quadratic in n and slow on long wheel-sample series).
    """
    from scipy.stats import chi2

    r = np.asarray(resid, dtype=float)
    r = r[np.isfinite(r)]
    n = r.size
    if n < 3 * lags:
        return math.nan
    x = r - r.mean()
    nfft = 1 << int(math.ceil(math.log2(2 * n)))
    f = np.fft.rfft(x, nfft)
    ac = np.fft.irfft(f * np.conj(f), nfft)[:lags + 1]
    if ac[0] <= 0:
        return math.nan
    rho = ac[1:] / ac[0]
    k = np.arange(1, lags + 1)
    q = n * (n + 2) * float(np.sum(rho * rho / (n - k)))
    return float(chi2.sf(q, lags))


CHI2_1_95 = 3.841458820694124
"""95 % quantile of χ² with one degree of freedom."""


def noise_sigma(ch: Channel, resid: NDArray) -> float:
    """Measurement-noise level of a channel's residual [channel unit] from successive differences (module doc)."""
    _, r = per_time(ch, np.asarray(resid, dtype=float))
    if r.size < 10:
        return math.nan
    d = np.diff(r)
    mad = float(np.median(np.abs(d - np.median(d))))
    return 1.4826 * mad / math.sqrt(2.0)


def nis_coverage(ch: Channel, resid: NDArray, sigma: float) -> float:
    """Share of per-time residuals with r²/σ² ≤ χ²₁(0.95) (module doc); NaN without a noise level."""
    _, r = per_time(ch, np.asarray(resid, dtype=float))
    if r.size == 0 or not (math.isfinite(sigma) and sigma > 0):
        return math.nan
    return float(np.mean((r / sigma) ** 2 <= CHI2_1_95))


def channel_stats(resid: NDArray) -> ChannelStats:
    r = np.asarray(resid, dtype=float)
    r = r[np.isfinite(r)]
    return ChannelStats(float(np.sqrt(np.mean(r * r))) if r.size else math.nan, ljung_box_p(r), int(r.size))


def per_time(ch: Channel, resid: NDArray) -> tuple[NDArray, NDArray]:
    """Residual averaged over the rows that share a time index: (frame index, mean residual)."""
    ok = np.isfinite(resid)
    u, inv = np.unique(ch.tidx[ok], return_inverse=True)
    s = np.bincount(inv, weights=resid[ok])
    c = np.bincount(inv)
    return u, s / c


@dataclass
class ChangePoint:
    t_s: float
    x_m: float | None
    y_m: float | None
    level_before: float
    level_after: float


MAX_CHANGE_WINDOWS = 1000
"""Most residual-level windows the change-point search sees (a 2-s window up to 33 minutes of residual;
wider windows beyond, so that its time stays bounded on a working day's recording)."""


def change_points(feat: Features, ch: Channel, resid: NDArray, window_s: float = 2.0,
                  max_points: int = 8) -> list[ChangePoint]:
    """Change points of the residual level (module doc)."""
    import ruptures as rpt

    fr = feat.frame
    idx, r = per_time(ch, resid)
    if idx.size < 20:
        return []
    t = fr.t[idx]
    # Windows widen on long recordings so that PELT (quadratic in the number of windows when the level
    # rarely changes) sees at most MAX_CHANGE_WINDOWS of them.
    window_s = max(window_s, float(fr.t[idx[-1]] - fr.t[idx[0]]) / MAX_CHANGE_WINDOWS)
    nb = max(1, int(round(window_s * fr.rate_hz)))
    blk = (idx // nb)
    ub, inv = np.unique(blk, return_inverse=True)
    means = np.bincount(inv, weights=r) / np.bincount(inv)
    tb = np.bincount(inv, weights=t) / np.bincount(inv)
    if means.size < 10:
        return []
    d = np.diff(means)
    s2 = float(np.var(means)) if means.size > 2 else 0.0
    s2_noise = float(np.mean(d * d) / 2.0) if d.size else s2
    pen = 3.0 * math.log(means.size) * max(s2_noise, 1e-12)
    try:
        bk = rpt.Pelt(model="l2", min_size=3, jump=1).fit(means[:, None]).predict(pen=pen)
    except Exception:  # pragma: no cover - ruptures corner cases
        return []
    bk = [b for b in bk if b < means.size]
    if len(bk) > max_points:
        jumps = [abs(means[b:].mean() - means[:b].mean()) for b in bk]
        keep = sorted(np.argsort(jumps)[-max_points:])
        bk = [bk[i] for i in keep]
    out = []
    edges = [0] + bk + [means.size]
    for j, b in enumerate(bk):
        before = means[edges[j]:b].mean()
        after = means[b:edges[j + 2]].mean()
        k = int(np.argmin(np.abs(fr.t - tb[b])))
        x = float(fr.x[k]) if fr.x is not None and np.isfinite(fr.x[k]) else None
        y = float(fr.y[k]) if fr.y is not None and np.isfinite(fr.y[k]) else None
        out.append(ChangePoint(float(tb[b]), x, y, float(before), float(after)))
    return out


@dataclass
class Regime:
    name: str
    group: str
    n: int
    mean_before: float
    rms_before: float
    mean_after: float = math.nan
    rms_after: float = math.nan


def _groups(feat: Features, ch: Channel) -> dict[str, dict[str, NDArray[np.bool_]]]:
    fr = feat.frame
    i = ch.tidx
    g: dict[str, dict[str, NDArray[np.bool_]]] = {}
    if feat.v_ref is not None:
        v = np.abs(feat.v_ref[i])
        g["speed band"] = {"< 1.5 m/s": v < 1.5, "1.5–2.2 m/s": (v >= 1.5) & (v < 2.2),
                           "2.2–2.8 m/s": (v >= 2.2) & (v < 2.8), "≥ 2.8 m/s": v >= 2.8}
    if feat.accel is not None:
        a = feat.accel[i]
        g["acceleration"] = {"accelerating (> 0.1 m/s²)": a > 0.1, "steady": np.abs(a) <= 0.1,
                             "decelerating (< −0.1 m/s²)": a < -0.1}
    if feat.direction is not None and np.any(feat.direction != 0):
        d = feat.direction[i]
        g["pass direction"] = {"along the field axis": d > 0, "against the field axis": d < 0}
    if fr.fdx is not None:
        f = np.nan_to_num(fr.fdx[i])
        inwork = f > 2000.0
        med = float(np.median(f[inwork])) if inwork.any() else 0.0
        g["draft level"] = {"implement up (< 2 kN)": ~inwork, f"draft ≤ {med / 1000:.1f} kN": inwork & (f <= med),
                            f"draft > {med / 1000:.1f} kN": inwork & (f > med)}
    wi = getattr(ch, "wi", None)
    if wi is not None:
        g["axle"] = {"front wheels": wi < 2, "rear wheels": wi >= 2}
    return g


def regimes(feat: Features, ch: Channel, before: NDArray, after: NDArray | None = None) -> list[Regime]:
    out = []
    for gname, groups in _groups(feat, ch).items():
        for label, m in groups.items():
            m = m & np.isfinite(before)
            if m.sum() < 5:
                continue
            rb = before[m]
            reg = Regime(gname, label, int(m.sum()), float(rb.mean()), float(np.sqrt(np.mean(rb * rb))))
            if after is not None:
                ra = after[m & np.isfinite(after)]
                if ra.size:
                    reg.mean_after = float(ra.mean())
                    reg.rms_after = float(np.sqrt(np.mean(ra * ra)))
            out.append(reg)
    return out


def evidence(feat: Features, ch: Channel, resid: NDArray) -> dict[str, float]:
    """Correlation of the per-time residual with signature regressors (dh/ds, dv/dt, v², F_dx)."""
    fr = feat.frame
    idx, r = per_time(ch, resid)
    out: dict[str, float] = {}

    def corr(name: str, x: NDArray | None) -> None:
        if x is None:
            return
        xx = x[idx]
        ok = np.isfinite(xx) & np.isfinite(r)
        if ok.sum() > 10 and np.std(xx[ok]) > 0 and np.std(r[ok]) > 0:
            out[name] = float(np.corrcoef(xx[ok], r[ok])[0, 1])

    corr("grade dh/ds", np.tan(feat.theta) if feat.theta is not None else None)
    corr("acceleration dv/dt", feat.accel)
    corr("speed squared v²", feat.v_ref ** 2 if feat.v_ref is not None else None)
    corr("draft F_dx", fr.fdx)
    if feat.direction is not None:
        corr("pass direction", feat.direction.astype(float))
    return out
