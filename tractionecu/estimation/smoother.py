"""Fixed-lag smoothing of the estimates: each μ and ρ_s revised by the steps that follow it within a lag.

The filter's μ is a random walk (paper eq. 8, "their dynamics neglected") that learns each wheel's force
from the wheel's acceleration, so it trails a μ that moves: on a truth whose tyre force builds up over a
relaxation length, by 20–30 ms at 100 Hz (docs/results/estimator.md).  The steps just after a time hold
what the filter could not yet know at it.  The unscented Rauch–Tung–Striebel smoother (Särkkä 2008,
"Unscented Rauch–Tung–Striebel smoother", IEEE TAC 53(3), eqs. 13–15) takes them back:

    x̂ₖ = xₖ⁺ + Gₖ₊₁ (x̂ₖ₊₁ − xₖ₊₁⁻),   Gₖ₊₁ = Cₖ,ₖ₊₁ (Pₖ₊₁⁻)⁻¹,

with x⁺ the state after step k's update, x⁻ the prior step k+1 was updated from and C the cross-covariance
of the state before and after the prediction (:func:`._kernels.cross_gain`; over a step's sub-steps the
gains multiply, :func:`._kernels.gain_compose`).  The recursion starts at the last step within
``EstimatorConfig.smoother_lag_s`` after k (x̂ = x⁺ there) and runs back to k; a fixed-lag smoother on a
sliding window.  The estimate of step k is therefore delivered when the first step more than the lag after
it arrives: at 100 Hz and the default 0.05 s, six steps (60 ms) later.  The map is made at 10 Hz and the
J1939 broadcast every 100 ms, so the delay stays within one of their periods.

What changes: μ per wheel and ρ_s, where the estimate reports the filter's state, clipped into their bounds;
a value the estimator holds (ρ_s at standstill: the last value from moving) holds the smoothed value of the
estimate it was held from, so it still equals what was shown before the hold.  Nothing else: the
slip, v, σ (the filter's; a smoothed covariance would be smaller, so the reported σ stays an upper bound),
the status and the μ(s) curve, which the estimator identifies from its own states.

The window ends, and the estimate is delivered as smoothed by fewer steps, where the chain of the filter
breaks: a step whose prediction did not start from the previous estimate's state (a restart, a gap, a lost
filter, a repaired covariance, the filter's state size switched), or a step without a filter.  The last
estimates of a run are delivered at :meth:`FixedLagSmoother.flush` with the steps there are.

Two ways in, the same arithmetic (:func:`smooth_rows`, compiled):

* :meth:`FixedLagSmoother.push` takes the estimates one by one (the step path, the service) and returns those
  that are due, in order;
* :meth:`FixedLagSmoother.push_arrays` takes a block of estimates as arrays (the compiled loop's, with the
  transitions as ``sm_*`` columns) and returns the rows that are due, as arrays.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..model.vehicle import IX_MU, IX_RHO, compiled

__all__ = ["FixedLagSmoother", "smooth_rows"]


def smooth_rows(T, LINK, XF, XP, G, lag, k0, k1, nrows, out):         # pragma: no cover - compiled
    """The smoothed states of rows k0..k1−1 into out (k1 − k0, n) (module doc).

    T (nrows,) times [s]; LINK (nrows,) 1 where row j's prediction continues row j−1's state; XF (nrows, n) the
    states after each row's update (NaN: the row has no filter); XP the priors, G (nrows, n, n) the gains of
    the rows that link.  A row's window: the rows after it while they link and lie within ``lag`` [s] of it (the
    caller's bound, :data:`LAG_TOLERANCE_S` included)."""
    n = XF.shape[1]
    s = np.empty(n)
    d = np.empty(n)
    for k in range(k0, k1):
        o = out[k - k0]
        if not XF[k, 0] == XF[k, 0]:
            for a in range(n):
                o[a] = math.nan
            continue
        j = k
        while j + 1 < nrows and LINK[j + 1] != 0 and T[j + 1] - T[k] <= lag:
            j += 1
        for a in range(n):
            s[a] = XF[j, a]
        for i in range(j, k, -1):
            for a in range(n):
                d[a] = s[a] - XP[i, a]
            for a in range(n):
                acc = XF[i - 1, a]
                for b in range(n):
                    acc += G[i, a, b] * d[b]
                s[a] = acc
        for a in range(n):
            o[a] = s[a]


smooth_rows = compiled(smooth_rows)

STATE_INDEX = (IX_MU.start, IX_MU.start + 1, IX_MU.start + 2, IX_MU.start + 3, IX_RHO)
"""The state index of each reported μ1..4 and ρ_s: the hub estimator's (a transition's fifth element, when
there is one, gives another estimator's: the machine level's μ is one state)."""
LAG_TOLERANCE_S = 1e-6
"""Steps this much later than the lag still count as within it (the round-off of a step grid's times)."""


class FixedLagSmoother:
    """Estimates in, the same estimates out ``lag_s`` later with μ and ρ_s smoothed (module doc).

    ``mu_bounds`` and ``rho_bounds``: the estimator's state bounds (``EstimatorConfig`` ``mu_min``/``mu_max``,
    ``rho_min``/``rho_max``) the smoothed values are clipped into.  With ``lag_s`` 0 every estimate passes at
    once, unchanged."""

    def __init__(self, lag_s: float, mu_bounds: tuple[float, float] = (-math.inf, math.inf),
                 rho_bounds: tuple[float, float] = (-math.inf, math.inf)) -> None:
        lag_s = float(lag_s)
        if not (math.isfinite(lag_s) and lag_s >= 0.0):
            raise ValueError(f"smoother lag must be a finite number of seconds >= 0, got {lag_s!r}")
        self.lag_s = lag_s
        # the window's bound: the lag and a microsecond (a grid of t0 + k/rate carries round-off: a step 0.05 s
        # after another at 100 Hz lay either side of a bound of exactly 0.05 s)
        self._bound = lag_s + LAG_TOLERANCE_S
        self._mu_lo, self._mu_hi = (float(b) for b in mu_bounds)
        self._rho_lo, self._rho_hi = (float(b) for b in rho_bounds)
        self.smoothed = 0
        """Estimates delivered with their μ or ρ_s revised."""
        self._n = 0              # state size of the buffers (0: none yet)
        self._idx = STATE_INDEX  # the state index of each reported μ1..4 and ρ_s
        self._cap = 0
        self._items: list[Any] = []        # pending estimates (push) or row payload (push_arrays)
        self._len = 0            # rows in the buffers; the pending ones are [0, _len)
        self._last_break = 0     # the rows before this one are due (a later row broke their chain)
        self._tail: dict[str, Any] | None = None   # push_arrays: the pending rows' arrays
        # per μ1..4, ρ_s: the last delivered value that was the filter's own, as reported and as smoothed
        # (a held value equal to the first is delivered as the second)
        self._raw = np.full(5, np.nan)
        self._sm = np.full(5, np.nan)

    @classmethod
    def from_config(cls, cfg: Any) -> "FixedLagSmoother":
        """The smoother of an :class:`~.config.EstimatorConfig` (its lag and state bounds)."""
        return cls(cfg.smoother_lag_s, (cfg.mu_min, cfg.mu_max), (cfg.rho_min, cfg.rho_max))

    # ------------------------------------------------------------------ buffers
    def _alloc(self, n: int, cap: int) -> None:
        T = np.full(cap, np.nan)
        LINK = np.zeros(cap, dtype=np.int8)
        XF = np.full((cap, n), np.nan)
        XP = np.full((cap, n), np.nan)
        G = np.zeros((cap, n, n))
        if self._len and self._n == n:
            m = self._len
            T[:m], LINK[:m], XF[:m], XP[:m], G[:m] = self._T[:m], self._LINK[:m], self._XF[:m], self._XP[:m], self._G[:m]
        self._T, self._LINK, self._XF, self._XP, self._G = T, LINK, XF, XP, G
        self._n, self._cap = n, cap

    def _drop(self, m: int) -> None:
        """Forget the first m rows (delivered)."""
        left = self._len - m
        if left:
            for a in (self._T, self._LINK, self._XF, self._XP, self._G):
                a[:left] = a[m:self._len]
        self._len = left
        self._last_break = max(0, self._last_break - m)

    def _due(self) -> int:
        """How many of the first rows are due: those before the last break of their chain, and those more than
        the lag before the newest row."""
        m = self._len
        if m == 0:
            return 0
        due = self._last_break
        t_new = self._T[m - 1]
        T = self._T
        while due < m - 1 and not (t_new - T[due] <= self._bound):
            due += 1
        return due

    def _states(self, m: int) -> NDArray[np.float64]:
        out = np.empty((m, self._n))
        smooth_rows(self._T, self._LINK, self._XF, self._XP, self._G, self._bound, 0, m, self._len, out)
        return out

    # ------------------------------------------------------------------ one by one
    def push(self, e: Any) -> list[Any]:
        """Take the next estimate (in time order); return the estimates now due, oldest first.

        The smoother is the estimator's last stage: it revises the estimates it takes in place (``mu`` gets a new
        array, ``rho_s`` a new value, ``transition`` None) before anyone else has seen them."""
        tr = getattr(e, "transition", None)
        if self.lag_s == 0.0 or (tr is None and not self._items):
            if tr is not None:
                e.transition = None
            return [e]
        link, xf, xp, G = tr[:4] if tr is not None else (False, None, None, None)
        n = xf.shape[0] if xf is not None else self._n
        idx = tr[4] if tr is not None and len(tr) > 4 else self._idx if xf is None else STATE_INDEX
        out: list[Any] = []
        if n != self._n or idx != self._idx:    # another state: nothing before links to it
            out = self.flush()
            self._alloc(n, 64)
            self._idx = idx
            link = False
        if self._len == self._cap:
            self._alloc(self._n, 2 * self._cap)
        k = self._len
        self._T[k] = e.t
        if link:
            self._LINK[k] = 1
            self._XP[k] = xp
            self._G[k] = G
        else:
            self._LINK[k] = 0
            self._last_break = k
        if xf is not None:
            self._XF[k] = xf
        else:
            self._XF[k] = np.nan
        self._len = k + 1
        self._items.append(e)
        due = self._due()
        if due:
            out.extend(self._deliver(due))
        return out

    def flush(self) -> list[Any]:
        """Every pending estimate, smoothed with the steps there are (the end of a run)."""
        if self._tail is not None:
            raise RuntimeError("flush() after push_arrays(): use flush_arrays()")
        return self._deliver(self._len) if self._len else []

    def _deliver(self, m: int) -> list[Any]:
        S = self._states(m)
        XF = self._XF
        out = []
        for k in range(m):
            e = self._items[k]
            if XF[k, 0] == XF[k, 0]:
                e.mu, e.rho_s = self._revise(e.mu, e.rho_s, XF[k], S[k])
            if getattr(e, "transition", None) is not None:
                e.transition = None
            out.append(e)
        del self._items[:m]
        self._drop(m)
        return out

    def _revise(self, mu: NDArray[np.float64], rho: float, xf: NDArray[np.float64],
                s: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
        new = mu.copy()
        raw, sm = self._raw, self._sm
        changed = False
        idx = self._idx
        for c in range(5):
            j = idx[c]
            v = rho if c == 4 else float(mu[c])
            if v == xf[j]:
                lo, hi = (self._rho_lo, self._rho_hi) if c == 4 else (self._mu_lo, self._mu_hi)
                out = min(max(float(s[j]), lo), hi)
                raw[c], sm[c] = v, out
                changed = True
            elif v == raw[c]:                 # held from the last own value
                out = float(sm[c])
            else:
                continue
            if c == 4:
                rho = out
            else:
                new[c] = out
        if changed:
            self.smoothed += 1
        return new, rho

    # ------------------------------------------------------------------ blocks of arrays
    def push_arrays(self, arr: dict[str, Any]) -> dict[str, Any] | None:
        """Take a block of estimates as arrays (``t``, ``mu`` (N, 4), ``rho_s``, …, and the transitions
        ``sm_link`` (N,), ``sm_xf`` (N, n), ``sm_xp`` (N, n), ``sm_G`` (N, n, n)); return the rows now due as
        arrays without the ``sm_*`` keys, or None when none is due."""
        if self._items:
            raise RuntimeError("push_arrays() after push(): one smoother takes one kind of input")
        if self.lag_s == 0.0:
            return _strip(arr)
        tail = arr if self._tail is None else _concat([self._tail, arr])
        xf = np.asarray(tail["sm_xf"], dtype=float)
        n = xf.shape[1]
        m = xf.shape[0]
        if m > self._cap or n != self._n:
            self._alloc(n, max(64, 2 * m))
        self._len = m
        self._T[:m] = tail["t"]
        self._LINK[:m] = tail["sm_link"]
        self._XF[:m] = xf
        self._XP[:m] = tail["sm_xp"]
        self._G[:m] = tail["sm_G"]
        breaks = np.flatnonzero(self._LINK[:m] == 0)
        self._last_break = int(breaks[-1]) if breaks.size else 0
        due = self._due()
        self._tail = tail
        return self._deliver_arrays(due) if due else None

    def flush_arrays(self) -> dict[str, Any] | None:
        """Every pending row as arrays (the end of a run), or None."""
        if self._tail is None or self._len == 0:
            return None
        return self._deliver_arrays(self._len)

    def _deliver_arrays(self, m: int) -> dict[str, Any]:
        tail = self._tail
        assert tail is not None
        S = self._states(m)
        head = {k: v[:m] for k, v in tail.items()}
        rest = {k: v[m:] for k, v in tail.items()}
        XF = self._XF[:m]
        idx = list(STATE_INDEX)                   # (the compiled loop: the hub estimator)
        R = np.column_stack([np.asarray(head["mu"], dtype=float), np.asarray(head["rho_s"], dtype=float)])
        X = XF[:, idx]
        lo = np.array([self._mu_lo] * 4 + [self._rho_lo])
        hi = np.array([self._mu_hi] * 4 + [self._rho_hi])
        own = R == X                                           # False on rows without a filter (NaN)
        val = np.where(own, np.clip(S[:, idx], lo, hi), R)
        # a held value: the smoothed value of the last own one it equals (:meth:`_revise`)
        last = np.maximum.accumulate(np.where(own, np.arange(m)[:, None], -1), axis=0)
        cols = np.arange(5)
        li = np.maximum(last, 0)
        lr = np.where(last >= 0, R[li, cols], self._raw)
        ls = np.where(last >= 0, val[li, cols], self._sm)
        val = np.where(~own & (R == lr), ls, val)
        if m:                                  # the last own values, for the next rows
            self._raw = lr[-1].copy()
            self._sm = ls[-1].copy()
        self.smoothed += int(np.count_nonzero(own.any(axis=1)))
        head["mu"] = val[:, :4]
        head["rho_s"] = val[:, 4].copy()
        self._drop(m)
        self._tail = rest if self._len else None
        return _strip(head)


def _strip(arr: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in arr.items() if not k.startswith("sm_")}


def _concat(parts: list[dict[str, Any]]) -> dict[str, Any]:
    out = {}
    for k in parts[0]:
        vals = [p[k] for p in parts]
        if isinstance(vals[0], np.ndarray):
            out[k] = np.concatenate(vals)
        else:
            out[k] = [x for v in vals for x in v]
    return out
