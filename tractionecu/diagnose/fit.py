"""Fitting candidate effects across channels, with autocorrelation-robust intervals.

Estimation
----------
For a candidate with parameters x (its fitted :class:`FitParam` s) the
weighted least-squares problem over the channels it acts on is

    min_x  Σ_c ‖ e_c(x) ‖² / σ_c²,

with e_c the channel residual after the nuisance parameters are profiled out
(variable projection).  A first solve weighs channels by their null residual
RMS; the second by σ_c² = (mean square of the channel's residual at the first
solution) · κ_c, κ_c = tr(S_c)/(s_c² tr(A_c)) the inflation of the channel's
score variance by autocorrelation (S_c, A_c below), so that channels count by
their independent information (a feasible approximation to generalised
least squares).  It is solved
from the best point of the candidate's start grid (the full product grid), by
a bounded Brent search for one parameter and bounded trust-region least
squares (``scipy.optimize.least_squares``) for more.  The search is robust to
the small steps the discrete nuisance (surface class) puts into the cost.

Uncertainty
-----------
Residuals of a vehicle log are autocorrelated (draft fluctuation, GNSS
error, spline nuisance), so the covariance is the sandwich

    Cov(x̂) = A⁻¹ (Σ_c S_c) A⁻¹,   A = Σ_c J̃_cᵀ J̃_c,

with J̃ the Jacobian of the weighted residuals and S_c the Newey–West (HAC,
Bartlett kernel) long-run covariance of the channel's scores g_t = Σ J̃ᵀ ẽ
aggregated per time index; the bandwidth follows Andrews (1991, AR(1) plug-in,
L = 1.1447 (α T)^{1/3}).  95 % intervals are x̂ ± 1.96 SE, clipped to the bounds.

Held-out score
--------------
Two folds of alternating time blocks.  A candidate is fitted on one fold and
its parameters are held while the nuisance is re-fitted on the other; the
held-out sums of squares of both folds are added.  Against the null (no
effect, same nuisance) the held-out log-likelihood ratio of channel c is

    ΔLL_c = ½ n_eff,c ln(SSE_null,c / SSE_cand,c),

with n_eff = T (1 − ρ₁)/(1 + ρ₁) from the lag-1 autocorrelation ρ₁ of the
candidate's held-out residual (T distinct times): the noise left once the
candidate has explained its part (the null's own residual would count the
unexplained effect's smoothness as noise correlation).  The candidate's score is Σ_c ΔLL_c.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from .candidates import CANDIDATES, Candidate
from .channels import Channel, Effects
from .features import Features
from .hac import hac_meat, n_effective


@dataclass
class FitResult:
    candidate: str
    x: NDArray[np.float64]
    cov: NDArray[np.float64]
    params: dict[str, float]
    ci95: dict[str, tuple[float, float]]
    se: dict[str, float]
    sse: dict[str, float]
    n: dict[str, int]
    cost: float
    ok: bool
    message: str = ""
    effects: dict[str, dict[str, float]] = field(default_factory=dict)
    """Every fitted effect's full parameter dict (one entry for a single candidate)."""
    ci95_by: dict[str, dict[str, tuple[float, float]]] = field(default_factory=dict)
    se_by: dict[str, dict[str, float]] = field(default_factory=dict)
    at_bound: dict[str, dict[str, str]] = field(default_factory=dict)
    """``{effect: {param: "lower"|"upper"}}`` for estimates on a parameter bound (reported as such)."""
    names: tuple[str, ...] = ()
    """Fitted parameters in x order, as ``effect.param``."""
    weights: dict[str, float] = field(default_factory=dict)
    """Channel scales σ_c of the final solve (the cost and the sandwich are in these units)."""
    ci95_wald_by: dict[str, dict[str, tuple[float, float]]] = field(default_factory=dict)
    """The sandwich intervals (widened to the folds' disagreement) before :func:`refine_intervals`."""
    interval_info: dict = field(default_factory=dict)
    """How :func:`refine_intervals` made the intervals: method, CPU time, per parameter κ, profile and
    jackknife parts (empty for the sandwich intervals)."""


class Joint:
    """Several candidates fitted together (forward stepwise augmentation, :mod:`.engine`).

    ``start`` holds the values already found for some of them: their start grid is that value only.
    """

    def __init__(self, names, start: dict[str, NDArray] | None = None):
        self.names = tuple(names)
        self.name = "+".join(self.names)
        self.cands = [CANDIDATES[n] for n in self.names]
        self.fitted = tuple(p for c in self.cands for p in c.fitted)
        self.start = dict(start or {})

    def split(self, x) -> list:
        out, k = [], 0
        for c in self.cands:
            out.append(np.asarray(x[k:k + len(c.fitted)]))
            k += len(c.fitted)
        return out

    def effects(self, x) -> dict[str, dict[str, float]]:
        out = {}
        for c, xc in zip(self.cands, self.split(x)):
            out.update(c.effects(xc))
        return out

    def grids(self) -> list:
        g = []
        for c in self.cands:
            if c.name in self.start:
                g += [np.array([float(v)]) for v in self.start[c.name]]
            else:
                g += [np.asarray(p.starts, dtype=float) for p in c.fitted]
        return g


def as_model(name) -> "Candidate | Joint":
    if isinstance(name, (Candidate, Joint)):
        return name
    if isinstance(name, str):
        return CANDIDATES[name]
    names = tuple(name)
    return CANDIDATES[names[0]] if len(names) == 1 else Joint(names)


def restrict(eff: Effects, ch: Channel) -> Effects:
    """The effects of ``eff`` that act on channel ``ch``."""
    return {k: v for k, v in eff.items() if k in ch.effects}


@dataclass
class HeldOut:
    candidate: str
    sse: dict[str, float]
    n: dict[str, int]
    resid: dict[str, NDArray[np.floating]]
    """Held-out residuals per channel in row order (both folds): float64 for the null model, float32 for a
    candidate (:data:`RESID_DTYPE`)."""
    fold_params: list[dict[str, float]] = field(default_factory=list)
    n_eff: dict[str, float] = field(default_factory=dict)
    """Effective sample size of each channel's held-out residual (:func:`~.hac.n_effective`), computed
    from the float64 residual before it is stored (the held-out score uses it)."""


RESID_DTYPE = np.float32
"""How a candidate's held-out residuals are kept once its score inputs (sums of squares, effective sample
sizes) are taken from the float64 values: a diagnosis keeps one set per candidate with some evidence and
per stepwise trial, 6 MB each in float32 on a 4-hour recording (12 MB in float64).  Their later uses
(whiteness, regimes, the report's statistics and figures) need no more than float32's 7 digits."""


# --------------------------------------------------------------------------- problem
class Problem:
    """Channels of one recording with their null-residual scales."""

    def __init__(self, feat: Features, channels: list[Channel]):
        self.feat = feat
        self.channels = {c.name: c for c in channels}
        self.sigma: dict[str, float] = {}
        for c in channels:
            r = c.residual({}, np.ones(c.m, dtype=bool))
            self.sigma[c.name] = float(np.sqrt(np.mean(r * r))) or 1.0

    def acting(self, cand) -> list[Channel]:
        return [c for c in self.channels.values() if any(n in c.effects for n in cand.names)]

    def rows(self, ch: Channel, fold: int | None, train: bool) -> NDArray[np.bool_]:
        if fold is None:
            return np.ones(ch.m, dtype=bool)
        return (ch.fold != fold) if train else (ch.fold == fold)

    def stacked(self, cand, x, chans: list[Channel], rows: dict[str, NDArray]) -> NDArray:
        eff: Effects = cand.effects(x)
        parts = [c.residual(restrict(eff, c), rows[c.name]) / self.sigma[c.name] for c in chans]
        return np.concatenate(parts) if parts else np.zeros(0)


def fit(problem: Problem, name, fold: int | None = None, with_cov: bool = True,
        rows_override: dict[str, NDArray] | None = None, x_start: NDArray | None = None) -> FitResult:
    """Fit candidate ``name`` (a name, a tuple of names fitted jointly, or a :class:`Joint`) on all
    rows (``fold`` None), on the rows outside ``fold``, or on ``rows_override``."""
    cand = as_model(name)
    chans = problem.acting(cand)
    rows = rows_override or {c.name: problem.rows(c, fold, train=True) for c in chans}
    lo = np.array([p.lo for p in cand.fitted])
    hi = np.array([p.hi for p in cand.fitted])
    if not chans:
        x = np.array([p.null for p in cand.fitted])
        return FitResult(cand.name, x, np.full((x.size, x.size), np.nan), {}, {}, {}, {}, {}, math.nan, False,
                         "no channel for this effect", effects=cand.effects(x))

    def fun(x):
        return problem.stacked(cand, x, chans, rows)

    x, ok, msg = _minimise(fun, cand, lo, hi, x_start=x_start, chans=chans)
    weights = {c.name: problem.sigma[c.name] for c in chans}
    cov_w = None
    if len(chans) > 1:
        # Re-weight by each channel's score autocorrelation at the solution, κ_c = tr(S_c)/(s_c² tr(A_c))
        # (1 for independent scores), and solve again: channels whose evidence is serially
        # correlated count for what it is worth.
        kap = _kappa(problem, cand, x, chans, rows, lo, hi)
        saved = dict(problem.sigma)
        eff0 = cand.effects(x)
        try:
            for c in chans:
                r = c.residual(restrict(eff0, c), rows[c.name])
                ms = float(np.mean(r * r)) if r.size else saved[c.name] ** 2
                problem.sigma[c.name] = math.sqrt(max(ms, 1e-30) * kap.get(c.name, 1.0))
            x, ok, msg = _minimise(fun, cand, lo, hi, x_start=x, chans=chans)
            weights = {c.name: problem.sigma[c.name] for c in chans}
            if with_cov:
                cov_w = sandwich(problem, cand, x, chans, rows, lo, hi)
        finally:
            problem.sigma.update(saved)
    sse = {}
    nrow = {}
    eff = cand.effects(x)
    for c in chans:
        r = c.residual(restrict(eff, c), rows[c.name])
        sse[c.name] = float(np.sum(r * r))
        nrow[c.name] = int(r.size)
    cost = float(np.sum(fun(x) ** 2))
    cov = np.full((x.size, x.size), np.nan)
    if with_cov:
        cov = cov_w if cov_w is not None else sandwich(problem, cand, x, chans, rows, lo, hi)
    names = [f"{c.name}.{p.name}" for c in (cand.cands if isinstance(cand, Joint) else [cand]) for p in c.fitted]
    if with_cov and "grade.scale" in names:
        j = names.index("grade.scale")
        cov = cov.copy()
        cov[j, j] += _grade_calibration_var(problem, x[j:j + 1])[0, 0]
    se_by: dict[str, dict[str, float]] = {}
    ci_by: dict[str, dict[str, tuple[float, float]]] = {}
    bound: dict[str, dict[str, str]] = {}
    for j, (nm, p) in enumerate(zip(names, cand.fitted)):
        en = nm.split(".", 1)[0]
        s = float(math.sqrt(cov[j, j])) if np.isfinite(cov[j, j]) and cov[j, j] >= 0 else math.nan
        se_by.setdefault(en, {})[p.name] = s
        span = p.hi - p.lo
        side = "lower" if x[j] <= p.lo + 1e-6 * span else ("upper" if x[j] >= p.hi - 1e-6 * span else "")
        if side:
            bound.setdefault(en, {})[p.name] = side
        if math.isfinite(s):
            ci_by.setdefault(en, {})[p.name] = (float(max(p.lo, x[j] - 1.96 * s)), float(min(p.hi, x[j] + 1.96 * s)))
        else:
            ci_by.setdefault(en, {})[p.name] = (math.nan, math.nan)
    first = cand.names[0]
    single = len(cand.names) == 1
    return FitResult(cand.name, x, cov, eff[first] if single else {}, ci_by.get(first, {}) if single else {},
                     se_by.get(first, {}) if single else {}, sse, nrow, cost, ok, msg, effects=eff, ci95_by=ci_by,
                     se_by=se_by, at_bound=bound, names=tuple(names), weights=weights)


def _grade_calibration_var(problem: Problem, x: NDArray) -> NDArray:
    """Variance a fitted grade scale inherits from the slope it is fitted against (features.GradeEstimate).

    The regressor is λ·g_pooled, so the scale s scales as 1/λ: Var_λ(s) = s² (SE_λ/λ)²; and the GNSS
    altitude error's slow drift leaves a slope error in the surface itself, relative SE ``drift_rel_se``:
    Var(s) += s² drift_rel_se² (type B, from the receiver's declared error).
    """
    g = problem.feat.grade
    k = x.size
    out = np.zeros((k, k))
    if g is None:
        return out
    if math.isfinite(g.reliability) and math.isfinite(g.reliability_se) and g.reliability > 0:
        out[0, 0] += float(x[0]) ** 2 * (g.reliability_se / g.reliability) ** 2
    if math.isfinite(g.drift_rel_se):
        out[0, 0] += float(x[0]) ** 2 * g.drift_rel_se ** 2
    return out


def _minimise(fun, cand, lo: NDArray, hi: NDArray, x_start: NDArray | None = None,
              chans: list[Channel] | None = None) -> tuple[NDArray, bool, str]:
    import itertools

    from scipy.optimize import minimize_scalar

    raw = cand.grids() if isinstance(cand, Joint) else [np.asarray(p.starts, dtype=float) for p in cand.fitted]
    grids = [np.clip(g, p.lo, p.hi) for g, p in zip(raw, cand.fitted)]
    if x_start is not None and len(grids) > 1:
        # A refinement: start from the previous solution only.
        grids = [np.array([v]) for v in np.clip(x_start, lo, hi)]
    pts = [np.array(c) for c in itertools.product(*grids)]
    costs = [float(np.sum(fun(x0) ** 2)) for x0 in pts]
    jb = int(np.argmin(costs))
    x0 = pts[jb]
    if len(grids) == 1:
        g = np.unique(grids[0])
        i = int(np.searchsorted(g, x0[0]))
        a = g[max(i - 1, 0)]
        b = g[min(i + 1, g.size - 1)]
        if b <= a:
            return x0, True, "grid point"
        res = minimize_scalar(lambda v: float(np.sum(fun(np.array([v])) ** 2)), bounds=(a, b), method="bounded",
                              options={"xatol": 1e-4 * (hi[0] - lo[0])})
        x = np.array([res.x]) if res.fun <= costs[jb] else x0
        return x, bool(res.success), str(res.message)
    scale = np.maximum(np.abs(hi - lo) * 0.01, 1e-6)
    # Several parameters: the discrete nuisance (surface class) is chosen at the best start and held
    # during the local search (it would put steps into the cost), then free again.
    fun(x0)
    for c in chans or ():
        c.freeze(True)
    try:
        res = least_squares(fun, x0, bounds=(lo, hi), method="trf", x_scale=scale, diff_step=1e-3, max_nfev=80,
                            ftol=1e-6, xtol=1e-6, gtol=1e-8)
        return res.x, bool(res.success), str(res.message)
    except (ValueError, np.linalg.LinAlgError) as exc:  # pragma: no cover - defensive
        return x0, False, str(exc)
    finally:
        for c in chans or ():
            c.freeze(False)


def _pieces(problem: Problem, cand: Candidate, x, chans, rows, lo, hi) -> dict[str, tuple[NDArray, NDArray, float]]:
    """Per channel: (A_c = J̃ᵀJ̃, S_c HAC long-run covariance of the scores, mean square of ẽ)."""
    k = x.size
    eff = cand.effects(x)
    res = {c.name: c.residual(restrict(eff, c), rows[c.name]) / problem.sigma[c.name] for c in chans}
    # Hold discrete nuisance choices (surface class) at the solution while differentiating.
    for c in chans:
        c.freeze(True)
    jac = {c.name: np.zeros((res[c.name].size, k)) for c in chans}
    try:
        for j in range(k):
            h = max(abs(x[j]) * 1e-3, (hi[j] - lo[j]) * 1e-4)
            xp = x.copy()
            xm = x.copy()
            xp[j] = min(x[j] + h, hi[j])
            xm[j] = max(x[j] - h, lo[j])
            if xp[j] == xm[j]:
                continue
            ep = cand.effects(xp)
            em = cand.effects(xm)
            for c in chans:
                rp = c.residual(restrict(ep, c), rows[c.name]) / problem.sigma[c.name]
                rm = c.residual(restrict(em, c), rows[c.name]) / problem.sigma[c.name]
                jac[c.name][:, j] = (rp - rm) / (xp[j] - xm[j])
    finally:
        for c in chans:
            c.freeze(False)
    out = {}
    for c in chans:
        J = jac[c.name]
        e = res[c.name]
        tid = c.tidx[rows[c.name]]
        _, inv = np.unique(tid, return_inverse=True)
        T = inv.max() + 1 if inv.size else 0
        g = np.zeros((T, k))
        for j in range(k):
            g[:, j] = np.bincount(inv, weights=J[:, j] * e, minlength=T)
        S = hac_meat(g) if T > 3 else np.zeros((k, k))
        out[c.name] = (J.T @ J, S, float(np.mean(e * e)) if e.size else 0.0)
    return out


def _kappa(problem: Problem, cand: Candidate, x, chans, rows, lo, hi) -> dict[str, float]:
    out = {}
    for name, (A, S, ms) in _pieces(problem, cand, x, chans, rows, lo, hi).items():
        ta = float(np.trace(A))
        out[name] = float(np.clip(np.trace(S) / (ms * ta), 0.05, 1e4)) if ta > 0 and ms > 0 else 1.0
    return out


def sandwich(problem: Problem, cand: Candidate, x, chans, rows, lo, hi) -> NDArray:
    """HAC sandwich covariance of the fitted parameters (module doc)."""
    k = x.size
    pieces = _pieces(problem, cand, x, chans, rows, lo, hi)
    A = sum(p[0] for p in pieces.values())
    meat = sum(p[1] for p in pieces.values())
    try:
        Ainv = np.linalg.pinv(A)
    except np.linalg.LinAlgError:  # pragma: no cover
        return np.full((k, k), np.nan)
    return Ainv @ meat @ Ainv


PROFILE_NFEV = 30
"""Function evaluations of each re-fit of the other parameters at a profile point (warm-started
from the previous point moved along the sandwich's linear response)."""
JACKKNIFE_NFEV = 30
"""Function evaluations of each delete-one-block re-fit (started from the full fit)."""


def refine_intervals(problem: Problem, fr: FitResult | None) -> FitResult | None:
    """Replace the 95 % intervals of a fit on all rows (module :mod:`.intervals`); a numerical failure
    keeps the sandwich intervals and is recorded in ``interval_info["error"]`` (never a crash)."""
    if fr is None:
        return fr
    try:
        return _refine_intervals(problem, fr)
    except (ValueError, ZeroDivisionError, FloatingPointError, np.linalg.LinAlgError) as exc:
        fr.interval_info = {"method": "sandwich (profile failed)", "error": f"{type(exc).__name__}: {exc}"}
        return fr


def _refine_intervals(problem: Problem, fr: FitResult) -> FitResult:
    """Replace the 95 % intervals of a fit on all rows by the HAC sandwich interval widened to the
    HAC-scaled profile likelihood's, united with the block jackknife's where the time blocks disagree
    more than the sandwich allows (:mod:`.intervals`), in place; the previous intervals (sandwich
    widened to the two folds' disagreement) stay in ``ci95_wald_by``.

    The channel scales are those of the fit's final solve, the discrete nuisance (surface class) is
    held at the solution's, the channels' continuous nuisance (μ_0, a, k_s, ρ_s, …) is re-fitted inside
    every residual and the other fitted parameters by bounded least squares at each profile point.
    A fit without a finite covariance keeps its intervals.  CPU time and evaluations are recorded in
    ``interval_info``.
    """
    import time

    from . import intervals as iv

    t_cpu = time.process_time()
    effects = []
    for nm in fr.names:
        en = nm.split(".", 1)[0]
        if en not in effects:
            effects.append(en)
    if not effects or fr.cov is None or not np.all(np.isfinite(np.diag(fr.cov))):
        return fr
    cand = as_model(tuple(effects))
    chans = problem.acting(cand)
    if not chans:
        return fr
    x_hat = np.asarray(fr.x, dtype=float)
    k = x_hat.size
    lo = np.array([p.lo for p in cand.fitted])
    hi = np.array([p.hi for p in cand.fitted])
    rows = {c.name: np.ones(c.m, dtype=bool) for c in chans}
    saved = dict(problem.sigma)
    problem.sigma.update(fr.weights)
    n_eval = [0]

    def fun_rows(x, rws):
        n_eval[0] += 1
        return problem.stacked(cand, x, chans, rws)

    info: dict = {"method": "sandwich widened by the profile likelihood (HAC-scaled), united with the block "
                            "jackknife where the blocks disagree; a GNSS delay's upper end extended by the "
                            "drive-line samples' period (their age at the time stamp)",
                  "blocks": iv.JACKKNIFE_BLOCKS, "params": {}}
    try:
        pieces = _pieces(problem, cand, x_hat, chans, rows, lo, hi)
        A = sum(p[0] for p in pieces.values())
        a_inv = np.linalg.pinv(A)
        fun_rows(x_hat, rows)          # the discrete nuisance at the solution
        for c in chans:
            c.freeze(True)
        c_hat = float(np.sum(fun_rows(x_hat, rows) ** 2))
        scale = np.maximum(np.abs(hi - lo) * 0.01, 1e-6)
        prof: dict[int, iv.Interval] = {}
        for j in range(k):
            se = math.sqrt(fr.cov[j, j]) if fr.cov[j, j] > 0 else math.nan
            kap = iv.hac_inflation(fr.cov, a_inv, j)
            free = np.arange(k) != j
            # Linear response of the other parameters to x_j (Gauss–Newton), for warm starts.
            resp = np.zeros(k)
            if k > 1 and a_inv[j, j] > 0:
                resp = a_inv[:, j] / a_inv[j, j]
            state = {"x": x_hat.copy()}

            def reset(state=state):
                state["x"] = x_hat.copy()

            def delta(v, j=j, free=free, resp=resp, state=state):
                z = state["x"].copy()
                if k > 1:
                    z[free] = np.clip(z[free] + resp[free] * (v - z[j]), lo[free], hi[free])
                z[j] = v
                if k > 1:
                    def f(u):
                        zz = z.copy()
                        zz[free] = u
                        return fun_rows(zz, rows)

                    try:
                        res = least_squares(f, z[free], bounds=(lo[free], hi[free]), method="trf",
                                            x_scale=scale[free], diff_step=1e-3, max_nfev=PROFILE_NFEV,
                                            ftol=1e-8, xtol=1e-8, gtol=1e-10)
                        z[free] = res.x
                        c = 2.0 * float(res.cost)
                    except (ValueError, np.linalg.LinAlgError):  # pragma: no cover - defensive
                        c = float(np.sum(fun_rows(z, rows) ** 2))
                else:
                    c = float(np.sum(fun_rows(z, rows) ** 2))
                state["x"] = z
                return c - c_hat

            prof[j] = iv.profile_interval(delta, float(x_hat[j]), float(lo[j]), float(hi[j]), se, kap, reset=reset)
        # Block jackknife: the fit without each contiguous time block.
        t0 = min(float(c.t.min()) for c in chans if c.m)
        t1 = max(float(c.t.max()) for c in chans if c.m)
        labels = {c.name: iv.block_labels(c.t, t0, t1) for c in chans}
        est = []
        for g in range(iv.JACKKNIFE_BLOCKS):
            rg = {c.name: labels[c.name] != g for c in chans}
            if not all(r.any() for r in rg.values()):
                continue
            try:
                res = least_squares(lambda u, rg=rg: fun_rows(u, rg), np.clip(x_hat, lo, hi), bounds=(lo, hi),
                                    method="trf", x_scale=scale, diff_step=1e-3, max_nfev=JACKKNIFE_NFEV,
                                    ftol=1e-8, xtol=1e-8, gtol=1e-10)
                est.append(res.x)
            except (ValueError, np.linalg.LinAlgError):  # pragma: no cover - defensive
                continue
        se_j = iv.jackknife_se(np.array(est)) if len(est) >= 3 else np.full(k, np.nan)
        tq = iv.t_quantile(len(est) - 1) if len(est) >= 3 else math.nan
    finally:
        for c in chans:
            c.freeze(False)
        # Leave the channels' warm starts (the slip channel's a and μ_0) at the solution, where the
        # rest of the diagnosis expects them.
        fun_rows(x_hat, rows)
        problem.sigma.clear()
        problem.sigma.update(saved)
    fr.ci95_wald_by = {en: dict(d) for en, d in fr.ci95_by.items()}
    # The drive-line signals' sample period: how old a torque value may be at its time stamp
    # (intervals.sample_age_extension).
    frame = getattr(problem.feat, "frame", None)
    hf_t = getattr(frame, "hf_t", None)
    age_s = float(np.median(np.diff(hf_t))) if hf_t is not None and hf_t.size > 2 else math.nan
    info["sample_age_s"] = age_s
    # The front-axle pin's gain tolerance times the static front load: an offset the data cannot tell from
    # a gain error (intervals.gain_tolerance_extension).
    pin_gain_n = (float(frame.sensors.axle_gain_tol_rel) * float(frame.vehicle.static_front_load_n())
                  if frame is not None and not getattr(frame, "fzf_modelled", False) else math.nan)
    for j, (nm, p) in enumerate(zip(fr.names, cand.fitted)):
        en, pn = nm.split(".", 1)
        x = float(x_hat[j])
        pi = prof.get(j)
        p_iv = (pi.lo, pi.hi) if pi is not None else (math.nan, math.nan)
        se_hac = math.sqrt(fr.cov[j, j]) if fr.cov[j, j] > 0 else math.nan
        het = iv.heterogeneous(float(se_j[j]), se_hac, len(est))
        j_iv = ((max(p.lo, x - tq * se_j[j]), min(p.hi, x + tq * se_j[j]))
                if math.isfinite(se_j[j]) and math.isfinite(tq) else (math.nan, math.nan))
        # The sandwich interval is kept inside: the profile only widens it (where the cost is flatter
        # than its curvature at x̂); a profile edge nearer than the sandwich's may be a re-fit of the
        # other parameters that stopped early, which no test here could tell from a steeper cost.
        w_iv = ((max(p.lo, x - 1.959964 * se_hac), min(p.hi, x + 1.959964 * se_hac))
                if math.isfinite(se_hac) else (math.nan, math.nan))
        lo_j, hi_j = iv.union(iv.union(p_iv, w_iv), j_iv if het else (math.nan, math.nan))
        if not (math.isfinite(lo_j) and math.isfinite(hi_j)):
            lo_j, hi_j = j_iv
        if not (math.isfinite(lo_j) and math.isfinite(hi_j)):
            continue
        lo_j, hi_j = max(p.lo, min(lo_j, x)), min(p.hi, max(hi_j, x))
        lo_j, hi_j = iv.sample_age_extension(en, pn, (lo_j, hi_j), age_s, p.hi)
        lo_j, hi_j = iv.tyre_law_extension(en, pn, (lo_j, hi_j), p.lo, p.hi)
        lo_j, hi_j = iv.gain_tolerance_extension(en, pn, (lo_j, hi_j), x, pin_gain_n, p.lo, p.hi)
        side = fr.at_bound.get(en, {}).get(pn, "")
        if side == "upper":
            hi_j = p.hi
        elif side == "lower":
            lo_j = p.lo
        # The standard error reported beside the interval: the largest of the sandwich's, the
        # jackknife's (when the blocks disagree) and the profile interval's half-width over 1.96.
        ses = [v for v in (se_hac, float(se_j[j]) if het else math.nan, (p_iv[1] - p_iv[0]) / (2 * 1.959964))
               if math.isfinite(v)]
        se_eq = max(ses) if ses else math.nan
        fr.ci95_by.setdefault(en, {})[pn] = (float(lo_j), float(hi_j))
        fr.se_by.setdefault(en, {})[pn] = float(se_eq)
        if len(effects) == 1:
            fr.ci95[pn] = (float(lo_j), float(hi_j))
            fr.se[pn] = float(se_eq)
        info["params"][nm] = {"kappa": pi.kappa if pi is not None else math.nan,
                              "profile": [float(p_iv[0]), float(p_iv[1])],
                              "profile_evals": pi.evals if pi is not None else 0,
                              "jackknife_se": float(se_j[j]), "jackknife_t": tq, "blocks_disagree": het,
                              "sandwich_se": se_hac}
    info["cost_evaluations"] = n_eval[0]
    info["cpu_s"] = time.process_time() - t_cpu
    fr.interval_info = info
    return fr


def held_out(problem: Problem, name, start: dict[str, NDArray] | None = None,
             x_start: NDArray | None = None) -> HeldOut:
    """Held-out sums of squares of every channel for candidate ``name`` (None = null; a tuple of names
    is fitted jointly, ``start`` holding values already found for some of them; ``x_start``: start
    the fold fits of a several-parameter model from these values instead of its grid)."""
    sse = {c: 0.0 for c in problem.channels}
    n = {c: 0 for c in problem.channels}
    resid = {c: np.full(ch.m, np.nan) for c, ch in problem.channels.items()}
    fold_params = []
    label = "null"
    for fold in (0, 1):
        eff: Effects = {}
        if name is not None and not (isinstance(name, tuple) and not name):
            model = as_model(name) if start is None or isinstance(name, str) else Joint(name, start)
            label = model.name
            fr = fit(problem, model, fold=fold, with_cov=False, x_start=x_start)
            eff = fr.effects
            fold_params.append(fr.params if len(model.names) == 1 else fr.effects)
        for cname, ch in problem.channels.items():
            rows = ch.fold == fold
            if not rows.any():
                continue
            r = ch.residual(restrict(eff, ch), rows)
            resid[cname][rows] = r
            sse[cname] += float(np.sum(r * r))
            n[cname] += int(r.size)
    n_eff = {}
    if label != "null":
        for cname, ch in problem.channels.items():
            ok = np.isfinite(resid[cname])
            n_eff[cname] = n_effective(resid[cname][ok], ch.tidx[ok])
            resid[cname] = resid[cname].astype(RESID_DTYPE)
    return HeldOut(label, sse, n, resid, fold_params, n_eff)


def score(problem: Problem, null: HeldOut, cand: HeldOut) -> tuple[float, dict[str, float]]:
    """Held-out log-likelihood ratio of a candidate against the null (module doc)."""
    per = {}
    for c, ch in problem.channels.items():
        s0, s1 = null.sse[c], cand.sse[c]
        if not (s0 > 0 and s1 > 0):
            per[c] = 0.0
            continue
        # The noise is what is left once the candidate explains its part: the effective sample
        # size comes from the candidate's held-out residual (equal to the null's when it explains nothing).
        neff = cand.n_eff.get(c)
        if neff is None:
            ok = np.isfinite(cand.resid[c])
            neff = n_effective(cand.resid[c][ok], ch.tidx[ok])
        per[c] = 0.5 * neff * math.log(s0 / s1)
    return float(sum(per.values())), per
