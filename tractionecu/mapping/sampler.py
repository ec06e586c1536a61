"""Map samples with a centred, delay-compensated window (like a yield monitor's flow delay).

The estimator's curve parameter ``a`` is smoothed causally, so it lags the
soil under the wheels by the smoothing time; mapped at the current position it
smears every soil boundary forward along the track.  For the map, the same
(μ, s) pairs are instead combined over a window centred on each 10 Hz sample,
with the ratio-of-sums form of :mod:`tractionecu.estimation.curve`:

    â(t_j) = Σ_k K_jk Σ_i w_ki μ̂_ki  /  Σ_k K_jk Σ_i w_ki g(ŝ_ki),   w = 1/σ_μ²,
    K_jk = max(0, 1 − |t_k − t_j| / H)   (triangular kernel, half width H),

using the shape g of the class chosen at t_j (a surface class or a curve shape that is none, such as
the machine-level estimator's ``d497`` prior: :func:`~tractionecu.model.mucurve.curve_class`).  The
triangular kernel blurs a boundary less than a box of the same noise reduction.  Online, a sample is emitted
H seconds late, once its window is complete; offline (replay) the same window
is applied to the whole run.  ρ_s and μ are averaged over the same window.

Why: on firm soil the working slip is low (≈ 3–4 %), where a = μ/g(s)
amplifies the slip error ≈ 20-fold, and the slip error (from the ≈ 0.02 m/s
speed error of 10 Hz GNSS Doppler) is correlated over ≈ 0.5 s, so ``a`` needs
seconds of averaging; a centred window gets that averaging without moving the
boundaries.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model.mucurve import curve_class
from .store import STATUS_FILTER_LOST

DEFAULT_HALF_WINDOW_S = 10.0
"""Half window H [s].  On firm soil (s ≈ 0.035) δa/a ≈ (g'/g)·δs ≈ 19·δs, and δs ≈ δv/v with
the GNSS Doppler noise of 0.05 m/s at 10 Hz: a 5 % error of a needs δs ≲ 0.0026, i.e. the
average of ≈ 150 speed samples (15 s), which a ±10 s window provides.  Measured on
paper-three-soils, seeds 0/1/2: map_soil_accuracy 0.961/0.962/0.961 with the triangular
kernel at H = 10 s (a box of ±10 s: 0.971/0.947/0.957; triangle H = 15 s: 0.967/0.955/0.968;
H = 20 s: 0.964/0.950/0.960).  The service emits map samples H seconds late."""
MIN_MU = 0.15
"""Pairs with |μ̂| below this are ill-conditioned (low slip) and skipped [-] (as the curve fit)."""
MIN_SLIP = 0.005
"""Pairs with |ŝ| below this are skipped [-]."""
MIN_SPEED = 0.5
"""No pairs below this speed [m/s]."""
STATUS_SLIP_UNCERTAIN = 0x2000
"""EstimateStatus bit of a slip its own σ does not support (held by the estimator): its (μ, s) pair is no pair."""
STATUS_SLIP_AVERAGED = 0x10000
"""EstimateStatus bit of a slip averaged over the last metres of travel (reversing, creeping): a mean over
several seconds beside this step's μ, so no (μ, s) pair either."""
STATUS_NO_PAIR = STATUS_SLIP_UNCERTAIN | STATUS_SLIP_AVERAGED
"""EstimateStatus bits whose (μ, s) is no pair for the map."""


def pair_weights(mu: NDArray[np.float64], slip: NDArray[np.float64], var_mu: NDArray[np.float64],
                 v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Weights w = 1/σ_μ² of the well-conditioned (μ, s) pairs, 0 elsewhere; arrays (n, 4)."""
    ok = (np.isfinite(mu) & np.isfinite(slip) & (np.abs(mu) >= MIN_MU) & (mu * slip > 0)
          & (np.abs(slip) >= MIN_SLIP) & (np.abs(v)[:, None] >= MIN_SPEED) & (var_mu > 0))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(ok, 1.0 / var_mu, 0.0)


def centred_map_values(t: NDArray[np.float64], mu: NDArray[np.float64], slip: NDArray[np.float64],
                       var_mu: NDArray[np.float64], v: NDArray[np.float64], rho_s: NDArray[np.float64],
                       soil_class: Any, half_window_s: float = DEFAULT_HALF_WINDOW_S,
                       curves: Any = None) -> dict[str, NDArray[np.float64]]:
    """Centred-window map values at every sample time t (n,) of a whole run.

    ``mu``, ``slip``, ``var_mu`` are (n, 4); ``soil_class`` is a sequence of
    class names (n,).  Returns layers ``a``, ``p``, ``alpha1``, ``alpha2``,
    ``rho_s``, ``mu`` (n,); ``a`` is NaN where the window holds no usable pair.  ``curves`` (n,),
    the estimator's identified curves: where one is on the shape path with an eq. 14 form, its
    a, p, α1, α2 are mapped instead (the shape was fitted over its soil segment already).
    """
    t = np.asarray(t, dtype=float)
    n = t.size
    w = pair_weights(mu, slip, var_mu, np.asarray(v, dtype=float))
    names = np.asarray(soil_class, dtype=object)
    a = np.full(n, np.nan)
    p = np.full(n, np.nan)
    a1 = np.full(n, np.nan)
    a2 = np.full(n, np.nan)
    rho = np.asarray(rho_s, dtype=float)
    rho_ok = np.isfinite(rho)
    num_k = (w * np.nan_to_num(mu)).sum(axis=1)
    slip0 = np.nan_to_num(slip)
    shapes = {c: curve_class(str(c)) for c in np.unique(names)}
    uniq = [c for c, cls in shapes.items() if cls is not None]
    den_k = {c: (w * shapes[c].g(slip0)).sum(axis=1) for c in uniq}
    # Kernel sums by shifting: K samples each side cover the window (K from the densest stretch).
    lo = np.searchsorted(t, t - half_window_s, side="left")
    hi = np.searchsorted(t, t + half_window_s, side="right")
    K = int(max((hi - np.arange(n)).max(initial=1), (np.arange(n) - lo).max(initial=0) + 1))
    num = np.zeros(n)
    den = {c: np.zeros(n) for c in uniq}
    rsum = np.zeros(n)
    rw = np.zeros(n)
    base = np.arange(n)
    for k in range(-K, K + 1):
        j = base + k
        inside = (j >= 0) & (j < n)
        jj = np.clip(j, 0, n - 1)
        kern = np.where(inside, np.clip(1.0 - np.abs(t[jj] - t) / half_window_s, 0.0, None), 0.0)
        num += kern * num_k[jj]
        for c in uniq:
            den[c] += kern * den_k[c][jj]
        rsum += np.where(rho_ok[jj], kern * np.where(rho_ok[jj], rho[jj], 0.0), 0.0)
        rw += np.where(rho_ok[jj], kern, 0.0)
    for c in uniq:
        cls = shapes[c]
        sel = names == c
        d = den[c][sel]
        with np.errstate(divide="ignore", invalid="ignore"):
            a[sel] = np.where(d > 0, num[sel] / d, np.nan)
        p[sel], a1[sel], a2[sel] = cls.p, cls.alpha1, cls.alpha2
    for j, c in enumerate(curves if curves is not None else ()):
        if c is not None and _shape_params(c) is not None:
            a[j], p[j], a1[j], a2[j] = _shape_params(c)  # type: ignore[misc]
    with np.errstate(divide="ignore", invalid="ignore"):
        rho_c = np.where(rw > 0, rsum / rw, np.nan)
        finite = np.isfinite(mu)
        mu_mean = np.where(finite.any(axis=1), np.where(finite, mu, 0.0).sum(axis=1) / finite.sum(axis=1), np.nan)
    return {"a": a, "p": p, "alpha1": a1, "alpha2": a2, "rho_s": rho_c, "mu": mu_mean}


def _shape_params(c: Any) -> tuple[float, float, float, float] | None:
    """(a, p, α1, α2) of an identified curve on the shape path with an eq. 14 form, else None."""
    if not str(getattr(c, "path", "")).startswith("shape:"):
        return None
    vals = (float(c.a), float(c.p), float(c.alpha1), float(c.alpha2))
    return vals if all(np.isfinite(vals)) else None


@dataclass
class _Pending:
    t: float
    lat: float
    lon: float
    fix_quality: int
    hdop: float
    valid: bool
    status: int
    soil_class: str
    rho_s: float
    mu_mean: float
    curve: Any = None


class CentredSampler:
    """Online form of :func:`centred_map_values`: push 10 Hz samples, get them back H seconds later.

    ``push`` returns the samples whose window is now complete, each as
    ``(t, lat, lon, values, valid, status, fix_quality, hdop)`` ready for
    :meth:`MapStore.add`.  Memory is bounded by the window (at 10 Hz and
    H = 10 s, 201 samples), plus ``max_pending`` as a hard cap.
    """

    def __init__(self, half_window_s: float = DEFAULT_HALF_WINDOW_S, max_pending: int = 4096):
        self.h = float(half_window_s)
        self.max_pending = int(max_pending)
        self._hist: deque[tuple[float, NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float]] = deque()
        self._pending: deque[_Pending] = deque()

    def push(self, t: float, lat: float, lon: float, fix_quality: int, hdop: float, est: Any) -> list[tuple]:
        """Add one sample (an :class:`~tractionecu.estimation.estimator.Estimate` at GNSS epoch t)."""
        mu = np.asarray(est.mu, dtype=float)
        slip = np.asarray(est.slip, dtype=float)
        if int(est.status) & STATUS_NO_PAIR:
            slip = np.full(4, np.nan)            # a held slip: no (μ, s) pair for the map's a
        var_mu = np.asarray(est.P_diag, dtype=float)[5:9]
        w = pair_weights(mu[None, :], slip[None, :], var_mu[None, :], np.array([est.v]))[0]
        self._hist.append((t, w, mu, slip, float(est.rho_s)))
        with np.errstate(invalid="ignore"):
            mu_mean = float(np.nanmean(mu)) if np.isfinite(mu).any() else float("nan")
        self._pending.append(_Pending(t, lat, lon, fix_quality, hdop, bool(est.valid), int(est.status),
                                      str(est.soil_class), float(est.rho_s), mu_mean,
                                      getattr(est, "curve", None)))
        while len(self._pending) > self.max_pending:
            self._pending.popleft()
        return self._emit(t)

    def invalidate_since(self, t_since: float) -> None:
        """Samples at or after ``t_since`` [s] came from a lost filter: not mapped, and out of every window."""
        while self._hist and self._hist[-1][0] >= t_since:
            self._hist.pop()
        for s in self._pending:
            if s.t >= t_since:
                s.valid = False
                s.status |= STATUS_FILTER_LOST

    def drain(self) -> list[tuple]:
        """Emit every pending sample with the window it has (end of run / shutdown)."""
        return self._emit(float("inf"))

    def _emit(self, now: float) -> list[tuple]:
        out = []
        while self._pending and self._pending[0].t + self.h <= now:
            s = self._pending.popleft()
            while self._hist and self._hist[0][0] < s.t - self.h:
                self._hist.popleft()
            out.append((s.t, s.lat, s.lon, self._values(s), s.valid, s.status, s.fix_quality, s.hdop))
        return out

    def _values(self, s: _Pending) -> dict[str, float]:
        cls = curve_class(s.soil_class)
        num = den = rho = 0.0
        nr = 0.0
        for (tk, w, mu, slip, r) in self._hist:
            if tk > s.t + self.h:
                break
            kern = max(0.0, 1.0 - abs(tk - s.t) / self.h)
            if cls is not None and w.any():
                num += kern * float((w * np.nan_to_num(mu)).sum())
                den += kern * float((w * cls.g(np.nan_to_num(slip))).sum())
            if np.isfinite(r):
                rho += kern * r
                nr += kern
        a = num / den if den > 0 else float("nan")
        shape = _shape_params(s.curve) if s.curve is not None else None
        if shape is not None:                         # the shape path: its fitted a, p, α1, α2
            return {"a": shape[0], "p": shape[1], "alpha1": shape[2], "alpha2": shape[3],
                    "rho_s": rho / nr if nr else float("nan"), "mu": s.mu_mean}
        return {"a": a, "p": cls.p if cls else float("nan"), "alpha1": cls.alpha1 if cls else float("nan"),
                "alpha2": cls.alpha2 if cls else float("nan"), "rho_s": rho / nr if nr else float("nan"),
                "mu": s.mu_mean}
