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
estimate it was held from, so it still equals what was shown before the hold.  And each wheel's slip where it is
eq. 6 at the step's own state: the same equation at the smoothed wheel speed and v, with the step's own wheel
factor k_i/r_i (the turn's ground-speed factor over the rolling radius at its load, :func:`_slip_at`); a slip
the estimator averaged over the last metres stays, and one it holds (standstill, a slip it cannot support) holds
the smoothed value of the slip it was held from (on the physical truth the slip
error falls by 3–12 %, docs/results/estimator.md).  Nothing else: v and ω (the filter's), σ (a smoothed covariance
would be smaller, so the reported σ stays an upper bound), the status and the μ(s) curve, which the estimator
identifies from its own states and slips.

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

from ..columns import concat
from ..model.vehicle import IX_MU, IX_OMEGA, IX_RHO, IX_V, compiled
from .estimator import SLIP_AVERAGED, SLIP_UNCERTAIN, STANDSTILL

__all__ = ["FixedLagSmoother", "smooth_rows"]


def smooth_rows(T, LINK, XF, XP, G, bound, k0, k1, nrows, out):      # pragma: no cover - compiled
    """The smoothed states of rows k0..k1−1 into out (k1 − k0, n) (module doc).

    T (nrows,) times [s]; LINK (nrows,) 1 where row j's prediction continues row j−1's state; XF (nrows, n) the
    states after each row's update (NaN: the row has no filter); XP the priors, G (nrows, n, n) the gains of
    the rows that link.  A row's window: the rows after it while they link and lie within ``bound`` [s] of it
    (the lag and :data:`LAG_TOLERANCE_S`)."""
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
        while j + 1 < nrows and LINK[j + 1] != 0 and T[j + 1] - T[k] <= bound:
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


def deliver_rows(T, LINK, XF, XP, G, RAW, IDX, meta, carry, lims, bound, m, S, out):  # pragma: no cover - compiled
    """Deliver the first m of the meta[0] buffered rows: their reported μ1..4, ρ_s and slip1..4 (RAW) revised
    into out (m, 9), then the rows left moved to the front.

    A value equal to its state (IDX[0:5]: the state index of each μ and ρ_s) takes the smoothed state, clipped
    into lims (lo 5, hi 5), and becomes the last own value (carry: as reported 5, as delivered 5); a value equal
    to the last own one as reported (held by the estimator) takes it as delivered; any other stays.  A live slip
    (RAW[:, 14] ≠ 0) whose wheel speed and v (RAW 9..13) are the states IDX[5:10] (IDX[5] < 0: none) is eq. 6
    again at the smoothed speeds, with the row's own wheel factor k_i/r_i (:func:`_slip_at`), and becomes the
    wheel's last own slip (carry 10..13 as reported, 14..17 as delivered); a slip that is not live and equals the
    last own one as reported (held) takes it as delivered.  meta: rows, the last break, estimates revised (counted
    here).  S (≥ m, n): work space for the smoothed states."""
    nrows = meta[0]
    smooth_rows(T, LINK, XF, XP, G, bound, 0, m, nrows, S)
    for k in range(m):
        o = out[k]
        for c in range(9):
            o[c] = RAW[k, c]
        if not XF[k, 0] == XF[k, 0]:
            continue
        own = False
        for c in range(5):
            j = IDX[c]
            v = RAW[k, c]
            if v == XF[k, j]:
                val = S[k, j]
                if val < lims[c]:
                    val = lims[c]
                if val > lims[5 + c]:
                    val = lims[5 + c]
                carry[c] = v
                carry[5 + c] = val
                o[c] = val
                own = True
            elif v == carry[c]:
                o[c] = carry[5 + c]
        if IDX[5] >= 0:
            if RAW[k, 14] != 0.0 and RAW[k, 13] == XF[k, IDX[9]]:
                for i in range(4):
                    if RAW[k, 9 + i] == XF[k, IDX[5 + i]]:
                        val = _slip_at(RAW[k, 5 + i], RAW[k, 9 + i], RAW[k, 13], S[k, IDX[5 + i]], S[k, IDX[9]])
                        carry[10 + i] = RAW[k, 5 + i]
                        carry[14 + i] = val
                        o[5 + i] = val
            elif RAW[k, 14] == 0.0:
                for i in range(4):
                    if RAW[k, 5 + i] == carry[10 + i]:
                        o[5 + i] = carry[14 + i]
        if own:
            meta[2] += 1
    left = nrows - m
    n = XF.shape[1]
    w = RAW.shape[1]
    for r in range(left):
        q = m + r
        T[r] = T[q]
        LINK[r] = LINK[q]
        for a in range(n):
            XF[r, a] = XF[q, a]
            XP[r, a] = XP[q, a]
            for b in range(n):
                G[r, a, b] = G[q, a, b]
        for c in range(w):
            RAW[r, c] = RAW[q, c]
    meta[0] = left
    meta[1] = meta[1] - m if meta[1] > m else 0


def _slip_at(s, w, v, ws, vs):                                           # pragma: no cover - compiled
    """Eq. 6's slip s of a wheel at speed w [rad/s] on a ground speed v [m/s], again at the smoothed speeds ws, vs.

    The estimator's slip is 1 − ρ (driving, ρ ≤ 1) or −1 + 1/ρ (braking) of ρ = |k v|/|r ω|, so ρ|ω|/|v| is the
    wheel's own factor |k|/|r| (its ground-speed factor in the turn over its rolling radius at this step's load):
    the same factor at ws, vs gives the slip of the smoothed speeds.  Where a speed is near 0 (|v|, |ω| < 1e-6:
    the estimator's own 0/0) or s is not a number, s stays."""
    if not (abs(v) > 1e-6 and abs(w) > 1e-6 and abs(vs) > 1e-6 and abs(ws) > 1e-6 and s == s):
        return s
    rho = 1.0 - s if s >= 0.0 else 1.0 / (1.0 + s)
    r2 = rho * abs(w) / abs(v) * abs(vs) / abs(ws)
    if r2 <= 1.0:
        return 1.0 - r2
    return -1.0 + 1.0 / r2


def push_row(T, LINK, XF, XP, G, RAW, IDX, meta, carry, lims, bound, t, link, xf, xp, Gr, mu, rho, slip, omega,
             v, live, S, out):                                             # pragma: no cover - compiled
    """Buffer one row (xf NaN: no filter; xp, Gr read only with ``link``; the reported μ (4,), ρ_s, slip (4,),
    ω (4,), v and whether the slip is live: :data:`RAW_COLUMNS`) and deliver the rows now due
    (:func:`deliver_rows`); returns how many."""
    k = meta[0]
    n = XF.shape[1]
    T[k] = t
    if link:
        LINK[k] = 1
        for a in range(n):
            XP[k, a] = xp[a]
            for b in range(n):
                G[k, a, b] = Gr[a, b]
    else:
        LINK[k] = 0
        meta[1] = k
    for a in range(n):
        XF[k, a] = xf[a]
    for c in range(4):
        RAW[k, c] = mu[c]
        RAW[k, 5 + c] = slip[c]
        RAW[k, 9 + c] = omega[c]
    RAW[k, 4] = rho
    RAW[k, 13] = v
    RAW[k, 14] = 1.0 if live else 0.0
    meta[0] = k + 1
    due = meta[1]
    while due < k and not (t - T[due] <= bound):
        due += 1
    if due:
        deliver_rows(T, LINK, XF, XP, G, RAW, IDX, meta, carry, lims, bound, due, S, out)
    return due


smooth_rows = compiled(smooth_rows)
_slip_at = compiled(_slip_at)
deliver_rows = compiled(deliver_rows)
push_row = compiled(push_row)

STATE_INDEX = (IX_MU.start, IX_MU.start + 1, IX_MU.start + 2, IX_MU.start + 3, IX_RHO,
               IX_OMEGA.start, IX_OMEGA.start + 1, IX_OMEGA.start + 2, IX_OMEGA.start + 3, IX_V)
"""The state index of each reported μ1..4 and ρ_s, then of each wheel speed ω1..4 and v the slip rests on: the
hub estimator's.  A transition's fifth element, when there is one, gives another estimator's: the two-inertia
hub's wheel speeds are its rims', and an index of five (the machine level's μ is one state) revises no slip."""
RAW_COLUMNS = 15
"""Per buffered row: the reported μ1..4, ρ_s, slip1..4, ω1..4, v, and 1 where the slip is live (0: held,
averaged over the last metres or at standstill, :data:`SLIP_NOT_LIVE`)."""
SLIP_NOT_LIVE = SLIP_UNCERTAIN | SLIP_AVERAGED | STANDSTILL
"""Status bits of an estimate whose slip is not eq. 6 at its own state (a held or averaged value): never revised."""
LAG_TOLERANCE_S = 1e-6
"""Steps this much later than the lag still count as within it (the round-off of a step grid's times)."""
MIN_WHEEL_PERIODS = 2
"""The lag of an estimator whose wheel speeds come slower holds at least this many of their sample periods
(:meth:`FixedLagSmoother.for_estimator`): the revision of an estimate comes from the samples after it, and at
20 Hz the configured 0.05 s holds one.  ``physical-declared-exact`` at 20/10 Hz, seed 0: μ error with a lag of
one, two, three, four periods 1.57, 1.19, 1.16, 1.18 %; the machine level's 10 Hz J1939 speeds
(``mechanical-three-soils``, seed 0): 2.31, 2.18, 2.19, 2.19 % (0.05 s: 2.64 %; docs/results/estimator.md)."""


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
        lo, hi = (float(b) for b in mu_bounds)
        rlo, rhi = (float(b) for b in rho_bounds)
        self._lims = np.array([lo] * 4 + [rlo] + [hi] * 4 + [rhi])
        self._n = 0              # state size of the buffers (0: none yet)
        self._idx = STATE_INDEX  # the state index of each reported μ1..4, ρ_s, ω1..4, v
        self._IDX = np.array(STATE_INDEX, dtype=np.int64)
        self._cap = 0
        self._items: list[Any] = []        # the pending estimates (push)
        # rows buffered, the last break (the rows before it are due: a later row broke their chain), estimates
        # revised
        self._meta = np.zeros(3, dtype=np.int64)
        self._tail: dict[str, Any] | None = None   # push_arrays: the pending rows' arrays
        # per μ1..4, ρ_s: the last delivered value that was the filter's own, as reported and as delivered (a held
        # value equal to the first is delivered as the second); then the same per wheel's slip
        self._carry = np.full(18, np.nan)

    @classmethod
    def from_config(cls, cfg: Any, wheel_rate_hz: float | None = None) -> "FixedLagSmoother":
        """The smoother of an :class:`~.config.EstimatorConfig` (its lag and state bounds); with the wheel-speed
        rate [Hz] the machine declares, a lag of at least :data:`MIN_WHEEL_PERIODS` of its periods (a lag of 0,
        the smoother off, stays 0)."""
        lag = cfg.smoother_lag_s
        if lag > 0.0 and wheel_rate_hz is not None and wheel_rate_hz > 0.0:
            lag = max(lag, MIN_WHEEL_PERIODS / wheel_rate_hz)
        return cls(lag, (cfg.mu_min, cfg.mu_max), (cfg.rho_min, cfg.rho_max))

    @classmethod
    def for_estimator(cls, est: Any) -> "FixedLagSmoother":
        """The smoother of an estimator: its configuration's (:meth:`from_config`), with the rate of the wheel
        speeds it reads (``smoother_wheel_rate_hz``: the hub estimator's declared rate, the machine level's 10 Hz
        J1939 speeds); a smoother with lag 0 for one without a configuration."""
        cfg = getattr(est, "cfg", None)
        if cfg is None:
            return cls(0.0)
        return cls.from_config(cfg, getattr(est, "smoother_wheel_rate_hz", None))

    @property
    def smoothed(self) -> int:
        """Estimates delivered with their μ or ρ_s revised."""
        return int(self._meta[2])

    # ------------------------------------------------------------------ buffers
    def _alloc(self, n: int, cap: int) -> None:
        m = int(self._meta[0]) if self._n == n else 0
        bufs = (np.full(cap, np.nan), np.zeros(cap, dtype=np.int8), np.full((cap, n), np.nan),
                np.full((cap, n), np.nan), np.zeros((cap, n, n)), np.full((cap, RAW_COLUMNS), np.nan))
        if m:
            for new, old in zip(bufs, (self._T, self._LINK, self._XF, self._XP, self._G, self._RAW)):
                new[:m] = old[:m]
        self._T, self._LINK, self._XF, self._XP, self._G, self._RAW = bufs
        self._S = np.empty((cap, n))
        self._out = np.empty((cap, 9))
        self._nan_x = np.full(n, np.nan)
        self._nan_g = np.full((n, n), np.nan)
        self._n, self._cap = n, cap
        self._meta[0] = m
        self._meta[1] = min(int(self._meta[1]), m)

    def _deliver(self, m: int) -> np.ndarray:
        """Rows [0, m) delivered: their μ1..4, ρ_s, slip1..4 as (m, 9) (a view: read before the next call)."""
        deliver_rows(self._T, self._LINK, self._XF, self._XP, self._G, self._RAW, self._IDX, self._meta,
                     self._carry, self._lims, self._bound, m, self._S, self._out)
        return self._out[:m]

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
        idx = _index(tr[4]) if tr is not None and len(tr) > 4 else self._idx if xf is None else STATE_INDEX
        out: list[Any] = []
        if n != self._n or idx != self._idx:    # another state: nothing before links to it
            out = self.flush()
            self._alloc(n, 64)
            self._idx = idx
            self._IDX = np.array(idx, dtype=np.int64)
            link = False
        if self._meta[0] == self._cap:
            self._alloc(self._n, 2 * self._cap)
        slip = getattr(e, "slip", None)        # (an estimate with a slip has ω, v and a status)
        live = slip is not None and not e.status & SLIP_NOT_LIVE
        due = push_row(self._T, self._LINK, self._XF, self._XP, self._G, self._RAW, self._IDX, self._meta,
                       self._carry, self._lims, self._bound, float(e.t), bool(link),
                       xf if xf is not None else self._nan_x, xp if link else self._nan_x,
                       G if link else self._nan_g, e.mu, float(e.rho_s),
                       slip if slip is not None else _NAN4, e.omega if live else _NAN4,
                       float(e.v) if live else math.nan, live, self._S, self._out)
        self._items.append(e)
        if due:
            out.extend(self._hand_out(self._out[:due]))
        return out

    def flush(self) -> list[Any]:
        """Every pending estimate, smoothed with the steps there are (the end of a run)."""
        if self._tail is not None:
            raise RuntimeError("flush() after push_arrays(): use flush_arrays()")
        m = int(self._meta[0])
        return self._hand_out(self._deliver(m)) if m else []

    def _hand_out(self, vals: np.ndarray) -> list[Any]:
        items = self._items
        m = vals.shape[0]
        out = [items.pop(0)] if m == 1 else items[:m]     # (m 1: the usual case, one step in, one out)
        if m > 1:
            del items[:m]
        for e, v in zip(out, vals):
            e.mu = v[:4].copy()
            e.rho_s = float(v[4])
            if getattr(e, "slip", None) is not None:
                e.slip = v[5:9].copy()
            if getattr(e, "transition", None) is not None:
                e.transition = None
        return out

    # ------------------------------------------------------------------ blocks of arrays
    def push_arrays(self, arr: dict[str, Any]) -> list[dict[str, Any]]:
        """Take a block of estimates as arrays (``t``, ``mu`` (N, 4), ``rho_s``, …, and the transitions
        ``sm_link`` (N,), ``sm_xf`` (N, n), ``sm_xp`` (N, n), ``sm_G`` (N, n, n); the hub estimator's state) and
        return the rows now due, in order, as blocks of arrays without the ``sm_*`` keys (the rows held from the
        last block first, then the new block's: a block is never copied whole)."""
        if self._items:
            raise RuntimeError("push_arrays() after push(): one smoother takes one kind of input")
        if self.lag_s == 0.0:
            return [_strip(arr)]
        parts = [arr] if self._tail is None else [self._tail, arr]
        return self._arrays_due(parts, final=False)

    def flush_arrays(self) -> list[dict[str, Any]]:
        """Every pending row as blocks of arrays (the end of a run)."""
        if self._tail is None:
            return []
        return self._arrays_due([self._tail], final=True)

    def _arrays_due(self, parts: list[dict[str, Any]], final: bool) -> list[dict[str, Any]]:
        """The rows of ``parts`` now due (all with ``final``), smoothed; the rest kept as the tail."""
        self._tail = None

        def cat(key: str, dtype: Any = float) -> np.ndarray:
            # a new array (deliver_rows moves rows within it: the caller's must stay as they are)
            vals = [np.asarray(p[key], dtype=dtype) for p in parts]
            return np.array(vals[0], dtype=dtype, order="C") if len(vals) == 1 else np.concatenate(vals)

        T = cat("t")
        m = T.shape[0]
        if m == 0:
            return []
        LINK = cat("sm_link", np.int8)
        XF, XP, G = cat("sm_xf"), cat("sm_xp"), cat("sm_G")
        if "slip" in parts[0]:
            RAW = np.column_stack([cat("mu"), cat("rho_s"), cat("slip"), cat("omega"), cat("v"),
                                   (cat("status", np.int64) & SLIP_NOT_LIVE) == 0])
        else:                                   # no slip to revise
            RAW = np.column_stack([cat("mu"), cat("rho_s"), np.full((m, RAW_COLUMNS - 5), np.nan)])
            RAW[:, RAW_COLUMNS - 1] = 0.0
        breaks = np.flatnonzero(LINK == 0)
        last_break = int(breaks[-1]) if breaks.size else 0
        if final:
            due = m
        else:
            # the rows before the last break, and those more than the lag before the newest row (push_row's rule)
            late = ~(T[m - 1] - T[:m - 1] <= self._bound)
            due = max(last_break, int(np.argmin(late)) if not late.all() else m - 1)
        meta = self._meta
        meta[0], meta[1] = m, last_break
        out: list[dict[str, Any]] = []
        if due:
            vals = np.empty((due, 9))
            idx = np.asarray(STATE_INDEX, dtype=np.int64)           # (the compiled loop: the hub estimator)
            deliver_rows(T, LINK, XF, XP, G, RAW, idx, meta, self._carry, self._lims, self._bound, due,
                         np.empty((due, XF.shape[1])), vals)
        # the due rows part by part (views), the rest as the new tail (copies: a block is not kept alive)
        left = m - due
        k = 0
        rest: list[dict[str, Any]] = []
        for p in parts:
            n_p = len(p["t"])
            take = min(max(due - k, 0), n_p)
            if take:
                head = {key: v[:take] for key, v in p.items() if not key.startswith("sm_")}
                head["mu"] = vals[k:k + take, :4].copy()
                head["rho_s"] = vals[k:k + take, 4].copy()
                if "slip" in p:
                    head["slip"] = vals[k:k + take, 5:9].copy()
                out.append(head)
            if take < n_p:
                rest.append({key: (v[take:].copy() if isinstance(v, np.ndarray) else list(v[take:]))
                             for key, v in p.items()})
            k += n_p
        if left:
            # the transitions of the rows left, as deliver_rows moved them to the front
            tail = concat(rest) if len(rest) > 1 else rest[0]
            tail["sm_link"] = LINK[:left].copy()
            tail["sm_xf"], tail["sm_xp"], tail["sm_G"] = XF[:left].copy(), XP[:left].copy(), G[:left].copy()
            self._tail = tail
        return out


_NAN4 = np.full(4, np.nan)


def _index(idx: tuple[int, ...]) -> tuple[int, ...]:
    """A transition's state index as ten entries (μ1..4, ρ_s, ω1..4, v): one of five revises no slip (−1)."""
    return tuple(idx) if len(idx) == 10 else tuple(idx) + (-1,) * 5


def _strip(arr: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in arr.items() if not k.startswith("sm_")}

