"""The draft sensor's reading with the implement lifted: a direct look at its zero.

A hitch load pin measures the implement's pull.  Lifted out of work (headland turns, transport) the
implement hangs on the hitch and pulls nothing, so what the draft signal reads there is the sensor's
own zero error: an offset b_0 + b_1 t of the draft sensor (library effect ``draft_offset``, formula
F_dx,meas = F_dx + b_0 + b_1 t) shows in these readings directly, at every headland.

In driving the constant part b_0 of that offset is a constant resistance (the soil's ρ_s) in the speed
equation and a constant load on the front-axle pin, where an axle-load offset reproduces it; the lifted
readings separate them.  They also show the offset's *shape*: a drift follows a straight line in time,
a re-zeroed or knocked sensor steps.

- :class:`LiftedDraftChannel`: the draft reading on lifted rows, at least :data:`TRIM_S` away from a
  change of the in-work state (lowering and raising move the implement and load the pin), against
  the prediction 0 (nominal) or b_0 + b_1 t (``draft_offset``).  It is a channel of the diagnosis like
  the balances: a fitted draft offset must agree with it, and a candidate that contradicts it (a
  9.6 kN offset standing in for a front-axle load offset, while the lifted pin reads 0) is not named
  (:func:`.engine._contradicted`).
- :func:`shape_check`: do the lifted readings follow a straight line in time at all?  The reading's
  mean per lifted stretch against the weighted least-squares line through them; a misfit beyond the
  stretches' own noise (χ² test at :data:`SHAPE_P`) and larger than :data:`SHAPE_MIN_N` means the
  offset has another shape (a step), outside the library: the fault is located, not named.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from ..model import effects as fx
from .channels import Channel, Effects

TRIM_S = 3.0
"""Lifted rows closer than this to a change of the in-work state are left out [s]: the implement is
being lowered or raised and loads the pin."""
MIN_ROWS = 50
"""Fewest lifted rows for the channel."""
MIN_STRETCHES = 2
"""Fewest separate lifted stretches (headlands) for the channel: one stretch shows a level, not a zero
that holds over the recording."""
SHAPE_P = 1e-3
"""Significance of the lack-of-fit test of a straight line through the stretch means."""
SHAPE_MIN_N = 300.0
"""Smallest departure of a stretch mean from the line that counts [N]: 0.3 % of a 100 kN pin's full
scale, the sensor tolerance of the vehicle file's draft_offset_tol_n."""


def _lifted_rows(feat) -> NDArray[np.int64]:
    fr = feat.frame
    if getattr(fr, "fdx", None) is None or getattr(fr, "work", None) is None:
        return np.zeros(0, dtype=np.int64)
    w = fr.work.astype(np.int8)
    ok = np.isfinite(fr.fdx) & (w == 0)
    valid = getattr(feat, "valid", None)
    if valid is not None:
        ok &= valid
    edges = np.nonzero(np.diff(w) != 0)[0]
    if edges.size:
        te = 0.5 * (fr.t[edges] + fr.t[edges + 1])          # sorted: the state changes in time order
        k = np.searchsorted(te, fr.t)
        near = np.minimum(np.abs(fr.t - te[np.clip(k - 1, 0, te.size - 1)]), np.abs(fr.t - te[np.clip(k, 0, te.size - 1)]))
        ok &= near >= TRIM_S
    return np.nonzero(ok)[0]


def _stretches(idx: NDArray[np.int64]) -> NDArray[np.int64]:
    """Label of each lifted row's contiguous stretch (0, 1, …)."""
    if idx.size == 0:
        return np.zeros(0, dtype=np.int64)
    return np.concatenate([[0], np.cumsum(np.diff(idx) > 1)]).astype(np.int64)


class LiftedDraftChannel(Channel):
    """Draft reading with the implement lifted against the sensor's zero error (module doc)."""

    def __init__(self, feat, rows: NDArray[np.int64]):
        fr = feat.frame
        super().__init__("lifted_draft", "N", "draft reading with the implement lifted (the sensor's zero)",
                         frozenset({"draft_offset"}), fr.t[rows], rows.astype(np.int64),
                         feat.fold[rows].astype(np.int8), "none (a lifted implement pulls nothing)",
                         extra={"data_check": True})
        self.y = np.asarray(fr.fdx[rows], dtype=float)
        self.stretch = _stretches(rows)

    def parts(self, eff: Effects, rows: NDArray[np.bool_]) -> tuple[NDArray, NDArray]:
        y = self.y[rows]
        if "draft_offset" in eff:
            p = eff["draft_offset"]
            return y, fx.offset_drift(self.t[rows], p["b0_n"], p["b1_npm"])
        return y, np.zeros(y.size)

    def residual(self, eff: Effects, rows: NDArray[np.bool_]) -> NDArray:
        y, f = self.parts(eff, rows)
        return y - f


def lifted_draft_channel(feat) -> LiftedDraftChannel | None:
    """The channel when the recording has a draft, an in-work indication and enough lifted rows in at
    least :data:`MIN_STRETCHES` stretches; else None."""
    rows = _lifted_rows(feat)
    if rows.size < MIN_ROWS or (_stretches(rows).max() + 1 if rows.size else 0) < MIN_STRETCHES:
        return None
    return LiftedDraftChannel(feat, rows)


def _stretch_means(ch: LiftedDraftChannel) -> tuple[NDArray, NDArray, NDArray]:
    """(time, mean reading, standard error) per lifted stretch; the standard error from the pooled
    within-stretch spread and the lag-1 autocorrelation of the readings (effective sample size)."""
    lab = ch.stretch
    n_s = int(lab.max()) + 1
    cnt = np.bincount(lab, minlength=n_s).astype(float)
    tm = np.bincount(lab, weights=ch.t, minlength=n_s) / cnt
    ym = np.bincount(lab, weights=ch.y, minlength=n_s) / cnt
    dev = ch.y - ym[lab]
    var = float(np.sum(dev * dev) / max(dev.size - n_s, 1))
    same = lab[1:] == lab[:-1]
    rho = 0.0
    if same.any() and var > 0:
        rho = float(np.clip(np.sum(dev[1:][same] * dev[:-1][same]) / (np.sum(dev * dev) or 1.0), 0.0, 0.99))
    n_eff = cnt * (1.0 - rho) / (1.0 + rho)
    se = np.sqrt(var / np.maximum(n_eff, 1.0))
    return tm, ym, se


def shape_check(ch: LiftedDraftChannel | None) -> dict:
    """Do the lifted readings follow b_0 + b_1 t?  Returns the stretch means, the weighted line through
    them, the χ² of its misfit with its p-value and, when the misfit is significant and material
    (module doc), ``linear: False`` and where the readings depart most (the largest jump between
    successive stretches)."""
    if ch is None:
        return {}
    tm, ym, se = _stretch_means(ch)
    k = tm.size
    out: dict = {"t_s": tm.tolist(), "mean_n": ym.tolist(), "se_n": se.tolist(), "linear": True}
    if k < 3 or not np.all(se > 0):
        return out
    from scipy.stats import chi2

    w = 1.0 / se ** 2
    A = np.column_stack([np.ones(k), tm])
    beta = np.linalg.solve(A.T @ (A * w[:, None]), A.T @ (w * ym))
    res = ym - A @ beta
    stat = float(np.sum(w * res * res))
    p = float(chi2.sf(stat, k - 2))
    out.update({"line_b0_n": float(beta[0]), "line_b1_npm": float(beta[1] * 60.0), "chi2": stat, "dof": k - 2,
                "p": p, "max_departure_n": float(np.max(np.abs(res)))})
    if p < SHAPE_P and np.max(np.abs(res)) >= SHAPE_MIN_N:
        j = int(np.argmax(np.abs(np.diff(ym))))
        out.update({"linear": False, "jump_between_s": [float(tm[j]), float(tm[j + 1])],
                    "level_before_n": float(ym[j]), "level_after_n": float(ym[j + 1])})
        out["statement"] = (
            "Unexplained mismatch in the draft sensor: with the implement lifted it reads "
            f"{ym[j] / 1000:.2f} kN around t = {tm[j]:.0f} s and {ym[j + 1] / 1000:.2f} kN around t = {tm[j + 1]:.0f} s "
            f"(lifted readings per headland: {', '.join(f'{v / 1000:.2f}' for v in ym)} kN); no straight line in time "
            f"fits them (χ² = {stat:.0f} on {k - 2} degrees of freedom, largest departure {np.max(np.abs(res)):.0f} N), "
            "so it is not the library's offset-and-drift b_0 + b_1 t (a step, re-zeroing or knock of the pin).  "
            "No library effect is named for it.")
    return out
