"""Curve parameter a of μ(s) from estimated (μ, s) pairs (paper section 3.2, eq. 18).

Within a surface class p, α1, α2 are fixed, so μ(s) = a·g(s) with
g(s) = 1 − p e^{α1 s} − (1−p) e^{α2 s}; each wheel's estimated pair (μ̂_i, ŝ_i)
gives a_i = μ̂_i / g(ŝ_i) (:func:`tractionecu.model.mucurve.solve_a_array`, the
vectorised :func:`~tractionecu.model.mucurve.solve_a`).  Near s = 0, g → 0 and
the division amplifies the slip error, δa/a = (g'(s)/g(s))·δs; such
ill-conditioned low-slip pairs are skipped and the rest are smoothed over time
as described below.

Why no per-point error threshold: the slip ŝ comes from the estimated speed,
whose error (≈ 0.01–0.02 m/s, correlated over seconds) is a slip error of
≈ 0.005; at the low slip of firm soil (s ≈ 0.03) a threshold on the
propagated error of each point, evaluated at the noisy ŝ, keeps the points
whose slip error happens to be positive and so biases a low (measured: −24 %
on a firm stubble).  Points are therefore judged by quantities that do not
contain the slip error: |μ̂| ≥ ``min_mu`` (low adhesion means low slip, where
g → 0), speed (done by the caller) and a small ``min_slip`` that only removes
sign changes and g ≈ 0.  The accepted pairs are combined as a ratio of sums,

    â = Σ w μ̂_i / Σ w g(ŝ_i) = Σ (w g_i) a_i / Σ (w g_i),  a_i = μ̂_i / g(ŝ_i) (solve_a),

the g-weighted mean of the per-pair solutions, with forgetting λ = e^{−Δt/τ}
and w = 1/σ_μ².  Being linear in g(ŝ) it is first-order unbiased under slip
noise; the remaining bias is −½ g''(s) σ_s² / g(s) (curvature of g), about
+1–2 % of a at the lowest slips of paper-three-soils (s ≈ 0.03, σ_s ≈ 0.009)
and less elsewhere.  Ill-conditioned pairs (small g) carry small weight.

Class selection (several classes configured): μ̂ comes from the torques and
is accurate, ŝ comes from the estimated speed and is noisy, so each class is
scored on how well it predicts the slip from the adhesion (regressing the
noisy variable on the accurate one avoids the errors-in-variables bias that
makes flat curves win when μ is regressed on a noisy slip):

    s_pred,i = g_c⁻¹(μ̂_i / â_c),   r_i = ŝ_i − s_pred,i,
    σ²_ci = σ_s,i² + (σ_μ,i / (â_c g_c'(s_pred,i)))²,
    L_c ← λ_c L_c + (Δt/τ_s) · mean_i ½ [r_i² / σ²_ci + ln σ²_ci],

the negative log-likelihood of one-step predictions, with â_c the class's
estimate before the new pairs and λ_c = e^{−Δt/τ_class}.  The class with the
smallest L fits best; a switch needs L_current − L_new > ``switch_min_delta``
[nats] (hysteresis).  The slip errors of the four wheels share the speed
error and are correlated over τ_s (``slip_corr_s``, ≈ 0.5 s for the speed
error of the paper-three-soils runs), so the pairs of one instant count as
one sample (the mean) and samples closer than τ_s are discounted by Δt/τ_s;
summing them as independent would make the evidence overconfident and the
class flip on noise.  With the narrow slip range of steady work the shapes
cannot be told apart and the default class stays.

Equation numbers follow the paper's source; see :mod:`tractionecu.estimation`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.stats import f as f_dist

from ..model.mucurve import CURVE_FORMS, SOIL_CLASSES, MuCurve, SoilClass, solve_a_array
from . import _curve_kernel as CK


@dataclass(frozen=True)
class CurveState:
    """Current curve identification."""

    a: float
    """Smoothed a of the best class [-] (NaN until a well-conditioned point was seen)."""
    class_index: int
    """Index of the best-fitting class in the configured list."""
    class_name: str
    a_per_class: NDArray[np.float64]
    """Smoothed a for every configured class [-]."""
    nll_per_class: NDArray[np.float64]
    """Forgetting negative log-likelihood of every class's predictions [nats] (lower fits better)."""
    n_used: int
    """Number of (μ, s) pairs accepted on the last update."""
    shape_curve: MuCurve | None = None
    """The fitted shape on the shape path (None on the class path); see :attr:`curve`."""
    var_a: float = math.nan
    """Variance of a on the class path [-²] from the segment's binned pairs (NaN until fitted)."""
    curve_path: str = ""
    """``"class:<name>"`` (one parameter a, eq. 18) or ``"shape:<form>"`` (shape identified)."""
    segment: int = 0
    """Number of the current soil segment of the shape identification."""
    slip_span: float = math.nan
    """Slip span of the current soil's binned pairs [-] (the shape path needs ``min_span``)."""
    soil: int = 0
    """Number of the soil the current segment is pooled with (:attr:`ShapeState.soil`)."""
    s_range: tuple[float, float] | None = None
    """Range of the current soil's bin mean slips [-] (the class path's :attr:`MuCurve.s_range`; None
    without the shape identification or before a bin has enough weight)."""

    @cached_property
    def curve(self) -> MuCurve | None:
        """The identified curve μ(s) (callable, parameters, covariance): the fitted shape on the
        shape path, a·g_class(s) with var(a) on the class path; None until a is identified."""
        if self.shape_curve is not None:
            return self.shape_curve
        return _class_curve(self.class_name, self.a, self.var_a, self.s_range)


def _class_curve(class_name: str, a: float, var_a: float, s_range: tuple[float, float] | None) -> MuCurve | None:
    """:attr:`CurveState.curve` on the class path: a·g_class(s) with var(a) and the soil's slip range; None until a
    is identified or for a class that is not one of SOIL_CLASSES."""
    if not a == a:
        return None
    cls = SOIL_CLASSES.get(class_name)
    if cls is None:
        return None
    c = MuCurve.from_class(cls, a, var_a)
    if s_range is not None:                # dataclasses.replace(c, s_range=...) on the fresh object: the same
        _set_attr(c, "s_range", s_range)   # fields, without a second construction
    return c


class CurveEstimator:
    """Online a and class identification from per-wheel (μ, s) pairs.

    Parameters
    ----------
    classes : the surface classes (shapes) to consider; the first is the
        default until the data discriminate.
    tau_s : forgetting time constant of the a smoothing [s].
    min_mu : pairs with |μ̂| below this are skipped as ill-conditioned (low slip) [-].
    min_slip : pairs with |ŝ| below this are skipped [-] (sign changes, g ≈ 0).
    class_tau_s : forgetting time constant of the class evidence [s].
    switch_min_delta : a class switch needs the new class's negative
        log-likelihood this much below the current one's [nats].
    slip_corr_s : correlation time of the slip error [s]; evidence from
        samples closer than this is discounted.
    shape : identify the curve's shape per soil segment when its slips span
        enough of it (:class:`ShapeIdentifier`); False keeps the paper's
        one-parameter path only.
    shape_kw : keyword arguments of :class:`ShapeIdentifier` (min_span,
        min_bins, fit_period_s, ...).
    fz_ref_n : reference wheel load of the identified curve [N] (static mean wheel load m g/4).
    load : let the shape identification fit the curve's load dependence (:func:`fit_curve`), with the
        wheel loads given to :meth:`update`; off by default.
    """

    @classmethod
    def from_config(cls, cfg: Any, fz_ref_n: float = math.nan) -> "CurveEstimator":
        """The curve identification an :class:`~tractionecu.estimation.config.EstimatorConfig` asks for
        (its ``soil_classes`` and ``curve_*`` settings); both estimators build theirs here.
        ``fz_ref_n``: the reference wheel load of the identified curve [N] (the machine's static mean
        wheel load m g/4; NaN: no load dependence is identified, and the load term is off whatever
        ``curve_shape_load`` says: every pair would fall in the reference group)."""
        return cls(cfg.soil_classes, tau_s=cfg.curve_tau_s, min_mu=cfg.curve_min_mu, min_slip=cfg.curve_min_slip,
                   class_tau_s=cfg.curve_class_tau_s, slip_corr_s=cfg.curve_slip_corr_s, shape=cfg.curve_shape,
                   shape_kw={"min_span": cfg.curve_shape_min_span}, switch_min_delta=cfg.curve_switch_min_delta,
                   fz_ref_n=fz_ref_n, load=bool(getattr(cfg, "curve_shape_load", True)) and fz_ref_n > 0.0)

    def __init__(self, classes: Sequence[SoilClass | str] = ("stubble",), *, tau_s: float = 5.0,
                 min_mu: float = 0.15, min_slip: float = 0.005, class_tau_s: float = 30.0,
                 switch_min_delta: float = 10.0, slip_corr_s: float = 0.5, shape: bool = True,
                 shape_kw: dict | None = None, fz_ref_n: float = math.nan, load: bool = False):
        cls = [SOIL_CLASSES[c] if isinstance(c, str) else c for c in classes]
        if not cls:
            raise ValueError("at least one surface class is needed")
        self.classes = cls
        self.tau = float(tau_s)
        self.min_mu = float(min_mu)
        self.min_slip = float(min_slip)
        self.class_tau = float(class_tau_s)
        self.switch_min_delta = float(switch_min_delta)
        self.slip_corr = float(slip_corr_s)
        nc = len(cls)
        self.fz_ref_n = float(fz_ref_n)
        # the state the compiled update (:mod:`._curve_kernel`) shares: last time, constants, and per class the
        # forgetting sums Σ w μ̂, Σ w g(ŝ) and the class evidence (views of it: _num, _den, _nll)
        C = self._C = np.zeros(CK.C_SIZE + 3 * nc)
        C[[CK.C_TAU, CK.C_CTAU, CK.C_MINMU, CK.C_MINSLIP, CK.C_REF]] = (self.tau, self.class_tau, self.min_mu,
                                                                        self.min_slip, self.fz_ref_n)
        C[[CK.C_P, CK.C_A1, CK.C_A2, CK.C_Q]] = (cls[0].p, cls[0].alpha1, cls[0].alpha2, 1.0 - cls[0].p)
        self._path0 = "class:" + cls[0].name
        grid = np.linspace(0.0, 1.0, 4001)
        self._inv = [(c.g(grid), grid) for c in cls]     # g is increasing on [0, 1]: table for g⁻¹
        self._best = 0
        kw = {"fz_ref_n": self.fz_ref_n, "load": bool(load), **(shape_kw or {})}
        self.shape = (ShapeIdentifier(cls, slip_corr_s=slip_corr_s, **kw) if shape else None)
        self._SC = np.empty((4, 8))                      # the kernel's scratch for the shape's pairs
        self._none = np.empty(0)
        CK.warm_up()                                     # compiled (or loaded) now, not at the first update

    # per class Σ w μ̂, Σ w g(ŝ) and the class evidence: views of the shared state (properties, so that a copy
    # of the estimator keeps them in its own state)
    @property
    def _num(self) -> NDArray[np.float64]:
        return self._C[CK.C_NUM:CK.C_NUM + len(self.classes)]

    @_num.setter
    def _num(self, v: Any) -> None:
        self._C[CK.C_NUM:CK.C_NUM + len(self.classes)] = v

    @property
    def _den(self) -> NDArray[np.float64]:
        nc = len(self.classes)
        return self._C[CK.C_NUM + nc:CK.C_NUM + 2 * nc]

    @_den.setter
    def _den(self, v: Any) -> None:
        nc = len(self.classes)
        self._C[CK.C_NUM + nc:CK.C_NUM + 2 * nc] = v

    @property
    def _nll(self) -> NDArray[np.float64]:
        nc = len(self.classes)
        return self._C[CK.C_NUM + 2 * nc:CK.C_NUM + 3 * nc]

    @_nll.setter
    def _nll(self, v: Any) -> None:
        nc = len(self.classes)
        self._C[CK.C_NUM + 2 * nc:CK.C_NUM + 3 * nc] = v

    @property
    def n_used(self) -> int:
        """Number of (μ, s) pairs accepted on the last update."""
        return int(self._C[CK.C_NUSED])

    @n_used.setter
    def n_used(self, n: int) -> None:
        self._C[CK.C_NUSED] = n

    def update(self, t: float, mu: NDArray[np.float64], s: NDArray[np.float64],
               sigma_mu: NDArray[np.float64], sigma_s: NDArray[np.float64] | None = None,
               fz: NDArray[np.float64] | None = None, mu_bin: NDArray[np.float64] | None = None) -> CurveState:
        """Add the pairs of one instant t [s]: μ̂ (k,), ŝ (k,), the standard errors of μ̂ and ŝ (k,)
        and, optionally, the wheel loads F_z (k,) [N] (the shape identification then fits the
        curve's load dependence where the loads differ, with ``fz_ref_n`` as the reference)."""
        if (len(self.classes) == 1 and mu_bin is None and type(mu) is np.ndarray and type(s) is np.ndarray
                and type(sigma_mu) is np.ndarray and mu.dtype == _F64 and s.dtype == _F64
                and sigma_mu.dtype == _F64 and mu.ndim == 1 and s.shape == mu.shape == sigma_mu.shape):
            return self._update_one(t, mu, s, sigma_mu, sigma_s, fz)
        C = self._C
        dt = 0.0 if not C[CK.C_HAS_T] else max(t - float(C[CK.C_T]), 0.0)
        if self.shape is not None:
            self._feed_shape(t, dt, np.asarray(mu, dtype=float), np.asarray(s, dtype=float), sigma_s, fz, mu_bin)
        if len(self.classes) == 1:
            # the one-class forgetting and a sums of the compiled update, without its shape part (fed above,
            # with the binning adhesion the kernel does not take)
            s1 = np.ascontiguousarray(s, dtype=float)
            _ce_update(C, _NO_S, _NO_SI, _NO_B, _NO_B, _NO_HT, _NO_HP, _NO_HP, self._SC, float(t),
                       np.ascontiguousarray(mu, dtype=float), s1,
                       np.ascontiguousarray(np.broadcast_to(np.asarray(sigma_mu, dtype=float), s1.shape)),
                       self._none, self._none, False, False, False)
            return self.state()
        C[CK.C_T] = t
        C[CK.C_HAS_T] = 1.0
        lam = math.exp(-dt / self.tau)
        lam_c = math.exp(-dt / self.class_tau)
        self._num = self._num * lam
        self._den = self._den * lam
        self._nll = self._nll * lam_c
        ok = np.isfinite(mu) & np.isfinite(s) & (np.abs(mu) >= self.min_mu) & (mu * s > 0)
        self.n_used = 0
        if ok.any():
            m, sv = mu[ok], s[ok]
            sm2 = np.maximum(sigma_mu[ok], 1e-6) ** 2
            ss = np.zeros_like(sv) if sigma_s is None else sigma_s[ok]
            w = 1.0 / sm2
            used = 0
            multi = len(self.classes) > 1
            discount = min(1.0, dt / self.slip_corr) if dt > 0 else 1.0
            for c, cls in enumerate(self.classes):
                a, _, good = solve_a_array(m, sv, cls, min_slip=self.min_slip, max_rel_err=math.inf)
                if not good.any():
                    continue
                g = cls.g(sv[good])
                if multi and self._den[c] > 0:
                    a_prev = self._num[c] / self._den[c]
                    gs, sg = self._inv[c]
                    s_pred = np.interp(np.abs(m[good]) / a_prev, gs, sg)
                    var = ss[good] ** 2 + sm2[good] / (a_prev * cls.dg(s_pred)) ** 2
                    r = np.abs(sv[good]) - s_pred
                    self._nll[c] += discount * 0.5 * float((r * r / var + np.log(var)).mean())
                wg = w[good] * g
                self._num[c] += float((wg * a[good]).sum())      # = Σ w μ̂
                self._den[c] += float(wg.sum())                  # = Σ w g(ŝ)
                used = max(used, int(good.sum()))
            self.n_used = used
        return self.state()

    def _update_one(self, t: float, mu: NDArray[np.float64], s: NDArray[np.float64], sigma_mu: NDArray[np.float64],
                    sigma_s: NDArray[np.float64] | None, fz: NDArray[np.float64] | None) -> CurveState:
        """:meth:`update` with one class and float64 arrays of one shape (the estimators' call), compiled
        (:func:`._curve_kernel.ce_update`: the forgetting, the pairs' choice, g(ŝ), the a sums and the shape
        identification's pairs); the soil segment's close and the once-a-second span and fit here."""
        n = mu.shape[0]
        ss = (np.ascontiguousarray(sigma_s, dtype=float) if isinstance(sigma_s, np.ndarray) and sigma_s.shape == (n,)
              else None)
        if fz is None or not self.fz_ref_n > 0:
            fzv = None
        else:
            fzv = fz if (type(fz) is np.ndarray and fz.dtype == _F64) else np.asarray(fz, dtype=float)
            if fzv.shape != (n,):
                fzv = None
        none = self._none
        sh = self.shape
        t = float(t)
        if sh is None:
            _ce_update(self._C, _NO_S, _NO_SI, _NO_B, _NO_B, _NO_HT, _NO_HP, _NO_HP, self._SC, t, mu, s, sigma_mu,
                       none if ss is None else ss, none if fzv is None else fzv, False, ss is not None,
                       fzv is not None)
            return self.state()
        while True:
            r = _ce_update(self._C, sh._S, sh._SI, sh._B, sh._MT, sh._HT, sh._HP, sh._PD, sh._SC, t, mu, s, sigma_mu,
                           none if ss is None else ss, none if fzv is None else fzv, True, ss is not None,
                           fzv is not None)
            if r != CK.GROW:
                break
            sh._grow(n)
        sh._after(r, t)
        return self.state()

    def _feed_shape(self, t: float, dt: float, mu: NDArray[np.float64], s: NDArray[np.float64],
                    sigma_s: NDArray[np.float64] | None, fz: NDArray[np.float64] | None = None,
                    mu_bin: NDArray[np.float64] | None = None) -> None:
        """The pairs the a fit accepts (same rules) go to the shape identification, with their
        relative wheel loads z = F_z/F_z,ref − 1 when the loads and the reference are known, and their
        binning adhesion (``mu_bin``, :meth:`ShapeIdentifier.update`) when given."""
        ml = mu.tolist()
        sl = s.tolist()
        n = len(sl)
        ssl = sigma_s.tolist() if isinstance(sigma_s, np.ndarray) and sigma_s.shape == (n,) else [0.0] * n
        ref = self.fz_ref_n
        if fz is not None and ref > 0 and np.shape(fz) == (n,):
            zl = [f / ref - 1.0 if f == f else 0.0 for f in np.asarray(fz, dtype=float).tolist()]
        else:
            zl = [0.0] * n
        bl = (np.asarray(mu_bin, dtype=float).tolist() if mu_bin is not None and np.shape(mu_bin) == (n,)
              else None)
        m_ok, s_ok, ss_ok, z_ok, b_ok = [], [], [], [], []
        min_mu, min_slip = self.min_mu, self.min_slip
        for i, (m, x, ss, zz) in enumerate(zip(ml, sl, ssl, zl)):
            if m * x > 0 and abs(m) >= min_mu and abs(x) >= min_slip and abs(m) < math.inf and abs(x) < math.inf:
                if bl is not None and not abs(bl[i]) < math.inf:
                    continue                                   # no binning adhesion: the pair is skipped
                m_ok.append(m)
                s_ok.append(x)
                ss_ok.append(ss)
                z_ok.append(zz)
                if bl is not None:
                    b_ok.append(bl[i])
        if m_ok:
            self.shape.update(t, dt, m_ok, s_ok, ss_ok, z_ok, b_ok if bl is not None else None)  # type: ignore[union-attr]

    def state(self) -> CurveState:
        """The current identification (a, best class, per-class a and evidence)."""
        nc = len(self.classes)
        cl = self._C.tolist()
        o = CK.C_NUM
        nll = cl[o + 2 * nc:o + 3 * nc]
        if nc > 1:
            cand = int(np.argmin(nll))
            if cand != self._best and nll[self._best] - nll[cand] > self.switch_min_delta:
                self._best = cand
        return self._state_of(cl[o:o + nc], cl[o + nc:o + 2 * nc], nll, int(cl[CK.C_NUSED]), self._shape_info())

    def _shape_info(self) -> tuple[Any, ...] | None:
        """What a state takes from the shape identification (its span, fit, soil and segment), None without it;
        it changes only at a segment's close and at the once-a-second check."""
        sh = self.shape
        if sh is None:
            return None
        return (sh._span, sh.fit, sh.soil_ids[sh.match] if sh.match >= 0 else sh._next_id, sh.segment)

    def _curve_of(self, num: float, den: float, info: tuple[Any, ...] | None) -> MuCurve | None:
        """The identified curve of a one-class estimator's state (``_state_of([num], [den], ...).curve``) without
        making the state."""
        if info is not None:
            (lo, hi, nb), fit, _, _ = info
            if fit is not None and fit.shape_selected:
                return fit.curve
        a_b = num / den if den > 0 else math.nan
        cls = self.classes[0]
        if info is None:
            return _class_curve(cls.name, a_b, math.nan, None)
        var_a = math.nan
        if fit is not None and fit.best_class.soil_class is cls:
            var_a = float(fit.best_class.cov[0, 0]) * (a_b / fit.best_class.a) ** 2
        return _class_curve(cls.name, a_b, var_a, (lo, hi) if nb else None)

    def _state_of(self, num: list[float], den: list[float], nll_l: list[float], n_used: int,
                  info: tuple[Any, ...] | None) -> CurveState:
        """The state of the per-class sums Σ w μ̂ ``num``, Σ w g(ŝ) ``den``, the evidence ``nll_l``, the pairs
        used and the shape identification's :meth:`_shape_info` (as :meth:`state` makes it then)."""
        al = [n / d if d > 0 else math.nan for n, d in zip(num, den)]
        a = np.array(al)
        b = self._best
        a_b = al[b]
        cls = self.classes[b]
        name = cls.name
        path = self._path0 if b == 0 else "class:" + name
        nll = np.array(nll_l)
        if info is None:
            return _curve_state(a_b, b, name, a, nll, n_used, None, math.nan, path, 0, math.nan, 0, None)
        (lo, hi, nb), fit, soil, segment = info
        if fit is not None and fit.shape_selected:
            c = fit.curve
            return _curve_state(c.a, b, name, a, nll, n_used, c, math.nan, c.path, segment,
                                hi - lo if nb else math.nan, soil, None)
        var_a = math.nan
        if fit is not None and fit.best_class.soil_class is cls:   # the bins' interval, scaled to a
            var_a = float(fit.best_class.cov[0, 0]) * (a_b / fit.best_class.a) ** 2
        return _curve_state(a_b, b, name, a, nll, n_used, None, var_a, path,
                            segment, hi - lo if nb else math.nan, soil, (lo, hi) if nb else None)


_F64 = np.dtype(np.float64)
_ce_update = CK.ce_update
_shape_post = CK.shape_post
_NO_S = np.zeros(CK.S_SIZE)
_NO_SI = np.zeros(CK.SI_SIZE, dtype=np.int64)
_NO_B = np.zeros((6, 1))
_NO_HT = np.zeros((1, 3))
_NO_HP = np.zeros((1, 5))
_CS_FIELDS = tuple(f.name for f in dataclasses.fields(CurveState))
_new_object = object.__new__
_set_attr = object.__setattr__


def _curve_state(a: float, class_index: int, class_name: str, a_per_class: NDArray[np.float64],
                 nll_per_class: NDArray[np.float64], n_used: int, shape_curve: MuCurve | None, var_a: float,
                 curve_path: str, segment: int, slip_span: float, soil: int,
                 s_range: tuple[float, float] | None) -> CurveState:
    """``CurveState(...)`` with every field given, built without the frozen dataclass's per-field
    ``__setattr__`` calls (one per update: a tenth of its cost); an equal object."""
    st = _new_object(CurveState)
    _set_attr(st, "__dict__", {"a": a, "class_index": class_index, "class_name": class_name,
                               "a_per_class": a_per_class, "nll_per_class": nll_per_class, "n_used": n_used,
                               "shape_curve": shape_curve, "var_a": var_a, "curve_path": curve_path,
                               "segment": segment, "slip_span": slip_span, "soil": soil, "s_range": s_range})
    return st


assert _CS_FIELDS == ("a", "class_index", "class_name", "a_per_class", "nll_per_class", "n_used", "shape_curve",
                      "var_a", "curve_path", "segment", "slip_span", "soil", "s_range"), _CS_FIELDS


# ============================================================================= shape beyond one parameter
# Paper section 3.2 fixes p, α1, α2 per class and solves only a (eq. 18).  When the slips seen on
# one soil span enough of the curve, the shape itself is identifiable; :class:`ShapeIdentifier`
# then fits it, online and with bounded memory, as follows.
#
# Sufficient statistics.  Pairs are binned by |μ̂| (bins of MU_BIN_WIDTH), the accurate variable
# (μ̂ comes from the torques; ŝ from the estimated speed and carries its error): each bin holds
# the weighted count W and sums of s, s², μ, μ².  The mean slip of a μ-bin is then unbiased by the
# slip error (binning by the noisy ŝ would flatten the curve: errors in variables); μ̄ of the bin
# sits within the bin.  Weights follow the class evidence above: the pairs of one instant share
# the speed error, so one instant counts as one sample, discounted by Δt/τ_s.
#
# Soil segments.  A soil change moves the slip at a given μ (same draft, other curve).  For each
# instant the slip residual r = ŝ − s̄_bin(μ̂) against the current segment's bins (the nearest bin
# with enough weight within ±3 bins, its mean slip moved to μ̂ along the first class's slope
# ds/dμ = 1/(a g'(s)): a new soil's μ often lands in a bin next to the old soil's), standardised
# by the bin's own scatter, feeds a two-sided CUSUM (allowance k, threshold h, increments
# discounted by Δt/τ_s); an alarm closes the segment and opens a new one, which takes over the
# pairs since the CUSUM last left zero (they were the new soil's).  Bins are compared with no
# curve shape assumed, so off-class soils are segmented as well as class soils.  The segment
# statistics are additive, so the take-over is exact; their total weight is capped
# (``max_weight``) by rescaling, a slow forgetting.  The allowance k = 0.5 is half the shift to be found
# (Page's CUSUM): on physical-three-soils the slip at equal μ̂ of soft and firm stubble differs by
# 0.014 (front) to 0.027 (rear) against the filter's scatter of 0.015 to 0.025 there, a shift of about one
# standard deviation; with k = 0.75 the test never fired and the three soils were fitted as one.
#
# Soils (segments pooled).  A field is crossed again and again (every pass crosses every soil), so a
# segment is often a soil seen before.  Each closed segment's fit bins are kept as a soil; the current
# segment is compared with every soil (:meth:`PairBins.shift_test`: the mean difference of their bin
# mean slips at equal μ̂, weighted by the inverse variances of the differences, over the bins both have)
# and is that soil when the difference is within ``match_z`` = 3 standard errors over at least
# ``match_min_bins`` common bins (the closest such soil), else a new soil.  At its close a segment's
# bins join its soil.  The fit and its span are those of the segment's bins pooled with its soil's
# (a crossing of a few tens of metres seldom shows enough of the curve alone: on physical-three-soils
# no crossing of firm or mid stubble did).  Because a false alarm only splits a
# soil into segments that are pooled again, the change test can afford the sensitivity above.  The soil
# number (:attr:`CurveState.soil`) is reported with the curve.  At most ``max_soils`` soils are kept
# (the one seen longest ago is forgotten).
#
# Fit (:func:`fit_curve`).  Over the bins with W ≥ ``min_bin_weight``: residuals in μ at the bin
# means, with the effective variance var(μ̄) + μ'(s̄)² var(s̄) (first-order errors in
# variables; the slope from the previous pass), candidates
#   the configured classes a·g_c(s)      (1 parameter, the paper's path),
#   exp1          a(1 − e^{α1 s})          (2),
#   exp1_offset   c + (a−c)(1 − e^{α1 s})   (3, only when asked for: not an eq. 14 form),
#   eq14          a(1 − p e^{α1 s} − (1−p) e^{α2 s})   (4),
# each linear in its amplitudes once the exponents are fixed, so every form is solved exactly on a
# grid of k = −α (variable projection: weighted normal equations of one or two basis functions)
# and the best grid point refined by damped Gauss–Newton (Levenberg–Marquardt) within the bounds
# (P_MIN ≤ p ≤ P_MAX with μ'(0) ≥ 0, α1 ≤ 1.3 α2 < 0, 2 ≤ −α ≤ 200, −0.1 ≤ c ≤ 0.3).  Forms are compared by BIC,
# n ln(SSE/n) + m ln n (n bins, m parameters); the best free form replaces the class only when
# its BIC is lower by ``bic_margin`` and an F test of its extra parameters rejects the class at
# ``test_level`` (eq. 14 contains every class), and only if it is well posed: covariance finite,
# σ_a/a ≤ ``max_rel_sigma_a`` (the asymptote is not an extrapolation the data cannot support),
# eq. 14 exponents distinct by a factor ≥ 1.3 and p not within 0.02 of 0 or 1 (else it is exp1).  The
# covariance is (JᵀWJ)⁻¹ · max(1, χ²/(n − m)).  Cost: 1–3 ms per fit; a segment is refitted at
# most every ``fit_period_s`` and only when its weight grew by half (module figures in the
# test and docs/results/curve-shape.md).

#
# Load (``load``: EstimatorConfig.curve_shape_load, on by default where a reference load is known).  On soil
# the curve depends on the wheel load (Brixius 1987: B_n ∝ 1/F_z; Pacejka 2006 p_Dx2 for tyres in general),
# and the four wheels of a hub-drive tractor at work carry very different loads (front ≈ 0.65, rear ≈ 1.4 of
# m g/4 with draft transfer), so one curve pooled over them is the soil's curve at no particular load.  Each
# pair keeps its relative load z = F_z/F_z,ref − 1 (F_z,ref = m g/4, the load at which a map's curve and the
# truth's table are given); the fit's bins are kept per load group (LOAD_EDGES).  The one-curve selection is
# made on the groups added up (:meth:`PairBins.pooled`: the same bins as without the load term), and where
# the groups' loads differ (LOAD_MIN_SPREAD) every candidate is also fitted on the groups as (1 + q z) μ(s),
# −Q_MAX ≤ q ≤ 0.  q is kept when |q| ≥ 2 σ_q and the load selection's BIC is ``bic_margin`` lower than the
# one-curve selection's on the same (grouped) bins; the curve reported is μ(s) at F_z,ref (``MuCurve.mu(s,
# fz)`` at any other load), path ``shape:<form>+load``.  The light and the heavy wheels need not work at the
# same slips: the form ties their curves together (each group's bins show its own bend), and σ_q, from the
# fit's covariance, says where the load and the bend cannot be told apart.  (An earlier rule asked for an
# overlap of the groups' slips; on soft soil the front wheels of a hub-drive tractor work at 0.08–0.13 and
# the rear at 0.05–0.09, so the term was never fitted where it matters most: docs/results/curve-shape.md, "Load-aware
# identification".)  The soil segments' change test and pooling use the groups added up, as without the load
# term.

MU_BIN_WIDTH = 0.02
"""Width of the |μ̂| bins [-]."""
_NEAR = (0, -1, 1, -2, 2, -3, 3)
"""Bin offsets searched, in order, for the change test's reference."""
MU_BIN_MAX = 1.5
"""Upper end of the |μ̂| bins [-] (pairs above it go to the last bin)."""
K_MIN, K_MAX = 2.0, 200.0
"""Bounds of the decay rates k = −α [-] of the free forms' exponents.  k ≥ 2: μ reaches at least 55 % of a by
s = 0.4, as every published field curve does (the classes here have k ≥ 3.5; Brixius 1987: k = 7.5);
a smaller k would be a near-linear curve whose asymptote no slip range can show."""
P_MIN, P_MAX = -4.0, 4.0
"""Bounds of eq. 14's weight p [-] in the shape fit.  The paper's classes have 0 ≤ p ≤ 1 (a rise
with two time constants); p > 1 gives a curve that peaks and falls back to a (wet, plastic soils:
Pacejka 2006 §4.3), p < 0 with μ'(0) = −a(p α1 + (1−p) α2) ≥ 0 an S-shaped rise whose slope
grows first (loose soils where the lugs sink before the soil shears), e.g. p = −1, α1 = 2α2:
a(1 − e^{α2 s})²."""
K_GRID = np.geomspace(K_MIN, K_MAX, 28)
DEFAULT_FORMS = ("exp1", "eq14")
"""Free forms tried by default.  Both are eq. 14 (exp1 with p = 1), so every identified curve has
eq. 14's parameters a, p, α1, α2 (maps, ISO 11783 export, the advice's s*); ``exp1_offset``
(μ(0⁺) = c ≠ 0) can be asked for but has no eq. 14 form."""
PRIOR_A = (0.8, 0.15)
"""Prior on the asymptote a of a fitted shape [-]: mean and standard deviation.  The asymptotic gross
traction ratio of agricultural tyres is 0.88 (1 − e^{−0.1 B_n}) in Brixius (1987, ASABE D497.7):
0.76–0.88 for mobility numbers 20–80, and the classes here span 0.6–0.9.  A slip range of a few
per cent seldom shows where the curve levels off; without the prior an S-shaped or nearly linear
stretch leaves a unbounded.  Where the data do show it, the prior (σ 0.15) hardly moves it; its
weight is in the covariance, so the interval of a says how much is prior."""
LOAD_EDGES = (-0.12, 0.12)
"""Edges of the load groups in relative wheel load z = F_z/F_z,ref − 1 [-] of the fit's bins: a hub-drive
tractor at work has its front wheels near z ≈ −0.35 and its rear wheels near +0.4 (draft load transfer);
binned apart, each group's bins show its own curve, and the load term ties the two together (section comment)."""
LOAD_MIN_SPREAD = 0.1
"""Weighted standard deviation of the bins' z̄ [-] below which the load sensitivity q is not fitted
(the loads do not differ enough to separate it from the curve)."""
Q_MAX = 0.8
"""Bounds of the load sensitivity q [-] in the fit: −Q_MAX ≤ q ≤ 0.  A tyre's friction coefficient
falls with its load (Pacejka 2006, §4.3.2: p_Dx2 < 0; on soil, Brixius' mobility number B_n ∝ 1/F_z:
q ≈ −0.4 at B_n = 15, −0.13 at 33, ≈ 0 above 60); a q > 0 the data ask for is something else (an
axle's slip or torque bias), which the load term must not absorb."""
S_INF = 50.0
"""Slip at which the prior on a enters the fit [-]: every form equals its a there (e^{−2·50} ≈ 0)."""
"""Grid of k of the variable-projection start."""


class PairBins:
    """Binned sufficient statistics of (|ŝ|, |μ̂|) pairs by |μ̂| (see the section comment).

    Per bin: weight W and the weighted sums of s, s², μ, μ² and of the relative wheel load
    z = F_z/F_z,ref − 1, kept as Python lists (one pair updates six numbers on the step path;
    numpy's scalar indexing would cost more than the sums).  The wheels of one μ-bin are pooled:
    its mean load z̄ goes with its mean slip s̄ (to first order, (1 + q z̄) μ(s̄) is the bin's mean).
    """

    __slots__ = ("W", "S1", "S2", "M1", "M2", "Z1", "groups", "_one")
    N_BINS = int(round(MU_BIN_MAX / MU_BIN_WIDTH))
    N_GROUPS = 3

    def __init__(self, groups: bool = False) -> None:
        """``groups``: bins per load group as well (:meth:`group_index`), N_GROUPS × N_BINS bins."""
        self.groups = bool(groups)
        n = self.N_BINS * (self.N_GROUPS if groups else 1)
        self.W = [0.0] * n
        self.S1 = [0.0] * n
        self.S2 = [0.0] * n
        self.M1 = [0.0] * n
        self.M2 = [0.0] * n
        self.Z1 = [0.0] * n
        self._one: PairBins | None = None

    @classmethod
    def index(cls, mu: float) -> int:
        """Bin of |μ| [-]."""
        return min(int(abs(mu) / MU_BIN_WIDTH), cls.N_BINS - 1)

    @classmethod
    def group_index(cls, k: int, z: float) -> int:
        """Bin of μ-bin k (:meth:`index`) in the load group of z = F_z/F_z,ref − 1 [-] (bins with
        ``groups``): 0 light (z < LOAD_EDGES[0]), 1 near the reference and every pair without a load,
        2 heavy (z > LOAD_EDGES[1])."""
        return (0 if z < LOAD_EDGES[0] else (2 if z > LOAD_EDGES[1] else 1)) * cls.N_BINS + k

    def add(self, k: int, w: float, s: float, mu: float, z: float = 0.0) -> None:
        """Add (w < 0: remove) one pair of weight w in bin k (relative load z [-])."""
        self._one = None
        self.W[k] += w
        ws = w * s
        self.S1[k] += ws
        self.S2[k] += ws * s
        wm = w * mu
        self.M1[k] += wm
        self.M2[k] += wm * mu
        self.Z1[k] += w * z

    def merged(self, other: "PairBins") -> "PairBins":
        """A new PairBins holding the pairs of both (same layout)."""
        c = self.copy()
        c.merge(other)
        return c

    def merge(self, other: "PairBins") -> None:
        """Add the pairs of ``other`` (same layout) to these bins."""
        self._one = None
        for mine, theirs in zip((self.W, self.S1, self.S2, self.M1, self.M2, self.Z1),
                                (other.W, other.S1, other.S2, other.M1, other.M2, other.Z1)):
            mine[:] = [x + y for x, y in zip(mine, theirs)]

    def shift_test(self, other: "PairBins", min_w: float, sigma_s_floor: float = 0.002) -> tuple[float, float, int]:
        """Mean slip difference at equal μ̂ of these bins against ``other``: (D, σ_D, n) [-] over the n bins
        with weight ≥ min_w in both, D = Σ (s̄ − s̄')/v / Σ 1/v with v = var s/W + var s'/W' of the two
        bin means (floored at ``sigma_s_floor``²/W), σ_D = (Σ 1/v)^(−1/2)."""
        return self._shift_test(other, min_w, sigma_s_floor, range(min(len(self.W), len(other.W))))

    def _shift_test(self, other: "PairBins", min_w: float, sigma_s_floor: float, bins: Sequence[int]
                    ) -> tuple[float, float, int]:
        """:meth:`shift_test` over the given bins, ascending (those skipped for their weight may be left out:
        :meth:`ShapeIdentifier._match` passes the bins of its own segment that have the weight, once for all soils)."""
        num = den = 0.0
        n = 0
        W1, A1, A2, W2, B1, B2 = self.W, self.S1, self.S2, other.W, other.S1, other.S2
        for k in bins:
            w1 = W1[k]
            w2 = W2[k]
            if w1 < min_w or w2 < min_w:
                continue
            a1, a2, b1, b2 = A1[k], A2[k], B1[k], B2[k]
            m1, m2 = a1 / w1, b1 / w2
            floor = sigma_s_floor * sigma_s_floor
            v = max(a2 / w1 - m1 * m1, floor) / w1 + max(b2 / w2 - m2 * m2, floor) / w2
            num += (m1 - m2) / v
            den += 1.0 / v
            n += 1
        if not n:
            return math.nan, math.nan, 0
        return num / den, 1.0 / math.sqrt(den), n

    @classmethod
    def _of(cls, A: NDArray[np.float64], groups: bool) -> "PairBins":
        """Bins holding the rows of A (W, Σws, Σws², Σwμ, Σwμ², Σwz) as lists of floats."""
        c = cls.__new__(cls)
        c.groups = bool(groups)
        c._one = None
        c.W, c.S1, c.S2, c.M1, c.M2, c.Z1 = A.tolist()
        return c

    def pooled(self) -> "PairBins":
        """The bins with their load groups added up (N_BINS bins; ``self`` when the bins have no groups): the
        bins a fit without the load term, the change test and the soils' match use.  Read only: it is kept until
        these bins change (:meth:`add`, :meth:`merge`, :meth:`scale`; a soil's bins change only when a segment
        joins them, and are matched every second)."""
        if not self.groups:
            return self
        if self._one is None:
            self._one = PairBins._of(_pool_groups(self.arrays()), False)
        return self._one

    def copy(self) -> "PairBins":
        c = PairBins(self.groups)
        c.W, c.S1, c.S2, c.M1, c.M2, c.Z1 = self.W[:], self.S1[:], self.S2[:], self.M1[:], self.M2[:], self.Z1[:]
        return c

    def scale(self, f: float) -> None:
        self._one = None
        for arr in (self.W, self.S1, self.S2, self.M1, self.M2, self.Z1):
            arr[:] = [x * f for x in arr]

    @property
    def total(self) -> float:
        return sum(self.W)

    def bin_mean_s(self, k: int) -> tuple[float, float, float]:
        """(W, mean s, variance of s) of bin k."""
        w = self.W[k]
        if w <= 1e-12:
            return 0.0, math.nan, math.nan
        m = self.S1[k] / w
        return w, m, max(self.S2[k] / w - m * m, 0.0)

    def arrays(self) -> NDArray[np.float64]:
        """(6, n_bins) array of W, Σws, Σws², Σwμ, Σwμ², Σwz."""
        return np.array([self.W, self.S1, self.S2, self.M1, self.M2, self.Z1])

    def load_means(self, min_w: float) -> NDArray[np.float64]:
        """Mean relative wheel load z̄ [-] of the bins :meth:`means` returns (same order)."""
        W = np.array(self.W)
        sel = W >= min_w
        return np.array(self.Z1)[sel] / W[sel]

    def means(self, min_w: float) -> tuple[NDArray[np.float64], ...]:
        """(s̄, μ̄, var s, var μ, W) of the bins with W ≥ min_w (within-bin variances)."""
        A = self.arrays()
        sel = A[0] >= min_w
        W = A[0, sel]
        s = A[1, sel] / W
        m = A[3, sel] / W
        vs = np.maximum(A[2, sel] / W - s * s, 0.0)
        vm = np.maximum(A[4, sel] / W - m * m, 0.0)
        return s, m, vs, vm, W

    def span(self, min_w: float) -> tuple[float, float, int]:
        """(lowest, highest mean slip, number of bins) over the bins with W ≥ min_w."""
        s = [s1 / w for w, s1 in zip(self.W, self.S1) if w >= min_w]
        if not s:
            return math.nan, math.nan, 0
        return min(s), max(s), len(s)


def _pool_groups(A: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rows (6, N_GROUPS · N_BINS) of grouped bins added up per μ-bin, (6, N_BINS): (g0 + g1) + g2."""
    n = PairBins.N_BINS
    return np.add(np.add(A[:, :n], A[:, n:2 * n]), A[:, 2 * n:3 * n])


_NEAR_BINS = tuple(tuple(k + d for d in _NEAR if 0 <= k + d < PairBins.N_BINS) for k in range(PairBins.N_BINS))
"""Per μ-bin k: the bins of :data:`_NEAR` around it that exist, in the order searched."""


@dataclass(frozen=True)
class CurveFit:
    """Result of :func:`fit_curve` on one soil segment's bins."""

    curve: MuCurve
    """The selected curve (a class or a free shape)."""
    best_class: MuCurve
    """The best of the configured classes on the same bins (a fitted to the bins)."""
    bic: dict[str, float]
    """BIC of every candidate that was well posed (``class:<name>`` and forms)."""
    n_bins: int
    s_range: tuple[float, float]

    @property
    def shape_selected(self) -> bool:
        return self.curve.form != "class"


def _solve_amplitudes(B: NDArray[np.float64], mu: NDArray[np.float64], w: NDArray[np.float64]
                      ) -> tuple[NDArray[np.float64], float] | None:
    """Weighted least squares μ ≈ bᵀB (B: m × n basis values); (b, SSE) or None if singular."""
    Bw = B * w
    G = Bw @ B.T
    h = Bw @ mu
    try:
        b = np.linalg.solve(G, h)
    except np.linalg.LinAlgError:
        return None
    r = mu - b @ B
    return b, float((w * r * r).sum())


def _grid_start(form: str, s: NDArray[np.float64], mu: NDArray[np.float64], w: NDArray[np.float64]
                ) -> tuple[tuple[float, ...], float] | None:
    """Best grid point of a free form (variable projection over K_GRID): (theta, SSE)."""
    E = -np.expm1(-K_GRID[:, None] * s[None, :])                 # (nk, n): 1 − e^{−k s}
    Ew = E * w
    G = Ew @ E.T                                                 # Σ w E_i E_j
    h = Ew @ mu                                                  # Σ w E_i μ
    mm = float((w * mu * mu).sum())
    gd = np.diag(G).copy()
    if form == "exp1":
        b = h / gd
        sse = mm - h * b
        sse[b <= 0] = np.inf
        j = int(np.argmin(sse))
        return ((float(b[j]), -float(K_GRID[j])), float(sse[j])) if np.isfinite(sse[j]) else None
    if form == "exp1_offset":
        w1 = float(w.sum())
        g1 = Ew.sum(axis=1)                                      # Σ w E_j
        h1 = float((w * mu).sum())
        det = w1 * gd - g1 * g1
        with np.errstate(divide="ignore", invalid="ignore"):
            c = (gd * h1 - g1 * h) / det
            b = (w1 * h - g1 * h1) / det
            sse = mm - (c * h1 + b * h)
        bad = ~(np.abs(det) > 1e-9 * w1 * gd) | (c < -0.1) | (c > 0.3) | (b <= 0)
        sse[bad] = np.inf
        j = int(np.argmin(sse))
        return ((float(c[j]), float(c[j] + b[j]), -float(K_GRID[j])), float(sse[j])) if np.isfinite(sse[j]) else None
    # eq14: pairs (i, j) with k_i > 1.3 k_j: α1 = −k_i < α2 = −k_j; b1 = a p, b2 = a(1−p) ≥ 0
    i, j = np.triu_indices(K_GRID.size, 1)
    keep = K_GRID[j] >= 1.3 * K_GRID[i]
    i, j = j[keep], i[keep]                                      # i: the faster rate (α1)
    gii, gjj, gij = gd[i], gd[j], G[i, j]
    det = gii * gjj - gij * gij
    with np.errstate(divide="ignore", invalid="ignore"):
        b1 = (gjj * h[i] - gij * h[j]) / det
        b2 = (gii * h[j] - gij * h[i]) / det
        sse = mm - (b1 * h[i] + b2 * h[j])
        a_ = b1 + b2
        p_ = b1 / a_
        slope0 = b1 * K_GRID[i] + b2 * K_GRID[j]
    # a > 0, P_MIN ≤ p ≤ P_MAX, and μ'(0) = b1 k_i + b2 k_j ≥ 0 (no pull against the slip); a singular
    # pair (det ≈ 0) gives inf or NaN coefficients, which the first test rejects
    bad = (~(det > 1e-9 * gii * gjj) | ~(a_ > 0) | (p_ < P_MIN) | (p_ > P_MAX) | ~(slope0 >= 0))
    sse[bad] = np.inf
    q = int(np.argmin(sse))
    if not np.isfinite(sse[q]):
        return None
    a = float(b1[q] + b2[q])
    return (a, float(b1[q]) / a, -float(K_GRID[i[q]]), -float(K_GRID[j[q]])), float(sse[q])


_BOUNDS = {
    "exp1": (np.array([1e-3, -K_MAX]), np.array([3.0, -K_MIN])),
    "exp1_offset": (np.array([-0.1, 1e-3, -K_MAX]), np.array([0.3, 3.0, -K_MIN])),
    "eq14": (np.array([1e-3, P_MIN, -K_MAX, -K_MAX]), np.array([3.0, P_MAX, -K_MIN, -K_MIN])),
}


def _model(form: str, th: NDArray[np.float64], s: NDArray[np.float64]
           ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """μ(s) of a free form for s > 0 and its Jacobian ∂μ/∂θ (n × m), analytic."""
    if form == "exp1":
        a, al = th
        e = np.exp(al * s)
        return a * (1.0 - e), np.column_stack([1.0 - e, -a * s * e])
    if form == "exp1_offset":
        c, a, al = th
        e = np.exp(al * s)
        return c + (a - c) * (1.0 - e), np.column_stack([e, 1.0 - e, -(a - c) * s * e])
    a, p, a1, a2 = th
    e1, e2 = np.exp(a1 * s), np.exp(a2 * s)
    g = 1.0 - p * e1 - (1.0 - p) * e2
    return a * g, np.column_stack([g, a * (e2 - e1), -a * p * s * e1, -a * (1.0 - p) * s * e2])


def _model_load(form: str, th: NDArray[np.float64], s: NDArray[np.float64], z: NDArray[np.float64] | None
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`_model` times the load factor (1 + q z), q the last element of th when z is given."""
    if z is None:
        return _model(form, th, s)
    f, J = _model(form, th[:-1], s)
    fac = 1.0 + th[-1] * z
    return fac * f, np.column_stack([J * fac[:, None], z * f])


def _refine(form: str, theta0: tuple[float, ...], s: NDArray[np.float64], mu: NDArray[np.float64],
            w: NDArray[np.float64], iters: int = 8, z: NDArray[np.float64] | None = None
            ) -> tuple[NDArray[np.float64], float, NDArray[np.float64]]:
    """Levenberg–Marquardt from theta0 within the form's bounds: (theta, SSE, Jacobian at theta).
    With z (relative wheel loads of the points), theta0 ends with the load sensitivity q."""
    lo, hi = _BOUNDS[form]
    if z is not None:
        lo, hi = np.append(lo, -Q_MAX), np.append(hi, 0.0)
    th = np.clip(np.asarray(theta0, dtype=float), lo, hi)
    f, J = _model_load(form, th, s, z)
    r = mu - f
    cur = float((w * r * r).sum())
    lam = 1e-3
    for _ in range(iters):
        Jw = J * w[:, None]
        A = J.T @ Jw
        g = Jw.T @ r
        D = np.diag(np.diag(A) + 1e-12)
        improved = False
        for _ in range(8):
            try:
                step = np.linalg.solve(A + lam * D, g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            cand = np.clip(th + step, lo, hi)
            if form == "eq14":
                if cand[2] > 1.3 * cand[3]:                         # α1 ≤ 1.3 α2: distinct exponents
                    cand[2] = 1.3 * cand[3]
                if cand[1] * cand[2] + (1.0 - cand[1]) * cand[3] > 0:   # μ'(0) < 0: not a traction curve
                    lam *= 10.0
                    continue
            fc, Jc = _model_load(form, cand, s, z)
            rc = mu - fc
            val = float((w * rc * rc).sum())
            if val < cur:
                small = cur - val <= 1e-6 * cur
                th, cur, J, r, lam = cand, val, Jc, rc, max(lam * 0.1, 1e-9)
                improved = not small
                break
            lam *= 10.0
        if not improved:
            break
    return th, cur, J


def fit_curve(bins: PairBins, classes: Sequence[SoilClass], *, min_bin_weight: float = 2.0,
              sigma_s_floor: float = 0.002, sigma_mu_floor: float = 0.002, bic_margin: float = 6.0,
              max_rel_sigma_a: float = 0.3, forms: Sequence[str] = DEFAULT_FORMS,
              prior_a: tuple[float, float] | None = PRIOR_A, test_level: float = 0.01,
              load: bool = True, fz_ref_n: float = math.nan, load_z: float = 2.0) -> CurveFit | None:
    """Fit the candidates to one segment's bins and select (see the section comment above).

    Returns None with fewer than 3 usable bins.  ``sigma_s_floor``, ``sigma_mu_floor``: floors of
    the within-bin standard deviations of ŝ and μ̂ [-] (a bin of identical samples is not exact).
    ``prior_a``: (mean, standard deviation) of the prior on the asymptote a [-] (None: none).
    ``test_level``: a free shape replaces the best class only if an F test of its extra parameters
    rejects the class at this level (and its BIC is ``bic_margin`` lower).

    Load dependence (``load``): the selection without it is made on the bins with their load groups added
    up (:meth:`PairBins.pooled`; the bins themselves when they have no groups) and is the result unless the
    load term is kept.  When the groups' mean relative wheel loads z̄ = F_z/F_z,ref − 1 spread by at least
    :data:`LOAD_MIN_SPREAD`, every candidate is fitted on the groups' bins as (1 + q z) μ(s; θ), the curve
    μ(s; θ) being the one at the reference load ``fz_ref_n`` [N]; q is kept when the selected curve's
    |q| ≥ ``load_z`` σ_q and its BIC is ``bic_margin`` lower than the selection without q on the same
    (grouped) bins, else the curve is one for every load.
    """
    kw = dict(bic_margin=bic_margin, max_rel_sigma_a=max_rel_sigma_a, forms=forms, prior_a=prior_a,
              test_level=test_level, fz_ref_n=fz_ref_n)

    def means(b: PairBins) -> tuple[NDArray[np.float64], ...]:
        s, mu, vs, vm, W = b.means(min_bin_weight)
        return (s, mu, np.maximum(vs, sigma_s_floor ** 2) / W,     # the variances of the bin means
                np.maximum(vm, sigma_mu_floor ** 2) / W, W)

    one = bins.pooled()
    s, mu, var_s, var_m, W = means(one)
    if s.size < 3:
        return None
    fit0 = _fit_bins(s, mu, var_s, var_m, None, classes, **kw)
    if not load:
        return fit0
    if one is not bins:
        s, mu, var_s, var_m, W = means(bins)
    if s.size < 5:
        return fit0
    z = bins.load_means(min_bin_weight)
    zm = float(np.average(z, weights=W))
    if not math.sqrt(float(np.average((z - zm) ** 2, weights=W))) >= LOAD_MIN_SPREAD:
        return fit0
    fit = _fit_bins(s, mu, var_s, var_m, z, classes, **kw)
    c = fit.curve
    # the load term must be significant and pay for its parameter: BIC lower by bic_margin than the
    # one-curve selection on the same bins (made only for a significant q)
    if not (c.load_q != 0.0 and abs(c.load_q) >= load_z * c.load_q_sigma):
        return fit0
    ref = fit0 if one is bins else _fit_bins(s, mu, var_s, var_m, None, classes, **kw)
    return fit if fit.bic[_bic_key(c)] + bic_margin < ref.bic[_bic_key(ref.curve)] else fit0


def _bic_key(c: MuCurve) -> str:
    """Key of a selected curve in :attr:`CurveFit.bic`."""
    return c.path.removesuffix("+load") if c.form == "class" else c.form


def _fit_bins(s: NDArray[np.float64], mu: NDArray[np.float64], var_s: NDArray[np.float64], var_m: NDArray[np.float64],
              z: NDArray[np.float64] | None, classes: Sequence[SoilClass], *, bic_margin: float,
              max_rel_sigma_a: float, forms: Sequence[str], prior_a: tuple[float, float] | None,
              test_level: float, fz_ref_n: float) -> CurveFit:
    """:func:`fit_curve` on the bin means (s̄, μ̄) with the variances of the means; with the bins'
    relative loads z every candidate carries the load factor (1 + q z)."""
    n = s.size
    s_range = (float(s.min()), float(s.max()))
    ld = z is not None
    zz = np.zeros(n) if z is None else np.asarray(z, dtype=float)
    if prior_a is not None:
        # the prior on a as one more observation at s → ∞, where every form equals its a
        s = np.append(s, S_INF)
        mu = np.append(mu, prior_a[0])
        var_s = np.append(var_s, 0.0)
        var_m = np.append(var_m, prior_a[1] ** 2)
        zz = np.append(zz, 0.0)                                  # (at the reference load)
    zl = zz if ld else None
    extra = 1 if ld else 0                                       # the load sensitivity q
    suffix = "+load" if ld else ""

    def bic(sse: float, m: int) -> float:
        return n * math.log(max(sse, 1e-300) / n) + m * math.log(n)

    def with_load(cv: MuCurve, q: float, var_q: float) -> MuCurve:
        if not ld:
            return cv
        return dataclasses.replace(cv, load_q=float(q), load_q_sigma=math.sqrt(max(var_q, 0.0)), fz_ref_n=fz_ref_n)

    def pred(cv: MuCurve) -> NDArray[np.float64]:
        return cv.eval_theta(cv.theta, s) * (1.0 + cv.load_q * zz)

    slope = np.array([c.dg(s) for c in classes]).mean(axis=0) * float((mu / np.maximum(classes[0].g(s), 1e-9)).mean())
    result: dict[str, tuple[MuCurve, float, float]] = {}        # (curve, BIC, data SSE)

    def data_sse(fn: NDArray[np.float64], w: NDArray[np.float64]) -> float:
        r = mu[:n] - fn[:n]
        return float((w[:n] * r * r).sum())

    for final in (False, True):
        # first pass: grid solutions only, for the slope of the effective variance; second: refined
        w = 1.0 / (var_m + slope * slope * var_s)
        result = {}
        for c in classes:                                        # a is identified: no prior
            g = c.g(s[:n])
            wd = w[:n]
            if not ld:
                den = float((wd * g * g).sum())
                a = float((wd * g * mu[:n]).sum()) / den
                r = mu[:n] - a * g
                sse = float((wd * r * r).sum())
                chi = max(1.0, sse / max(n - 1, 1))
                result[f"class:{c.name}"] = (MuCurve.from_class(c, a, chi / den), bic(sse, 1), sse)
                continue
            B = np.vstack([g, zz[:n] * g])                       # μ = a g + a q z g: linear in (a, a q)
            sol = _solve_amplitudes(B, mu[:n], wd)
            if sol is None or not sol[0][0] > 0:
                continue
            (b0, b1), sse = sol
            a, q = float(b0), float(b1 / b0)
            if not -Q_MAX <= q <= 0.0:                           # outside the physical bounds: at the bound
                q = min(max(q, -Q_MAX), 0.0)
                fz_ = g * (1.0 + q * zz[:n])
                a = float((wd * fz_ * mu[:n]).sum()) / float((wd * fz_ * fz_).sum())
                r = mu[:n] - a * fz_
                sse = float((wd * r * r).sum())
            J = np.column_stack([g * (1.0 + q * zz[:n]), a * zz[:n] * g])
            try:
                C = np.linalg.inv(J.T @ (J * wd[:, None])) * max(1.0, sse / max(n - 2, 1))
            except np.linalg.LinAlgError:
                continue
            cv = with_load(MuCurve.from_class(c, a, float(C[0, 0])), q, float(C[1, 1]))
            result[f"class:{c.name}"] = (cv, bic(sse, 2), sse)
        for form in forms:
            m = len(CURVE_FORMS[form])
            if n <= m + extra + 1:
                continue
            q = 0.0
            start = None
            for _ in range(2 if ld else 1):                      # alternate: the shape at q, then q at the shape
                fac = 1.0 + q * zz
                start = _grid_start(form, s, mu / fac, w * fac * fac)
                if start is None or not ld:
                    break
                f0 = MuCurve(form, start[0], np.full((m, m), np.nan), "").eval_theta(start[0], s)
                den = float((w * (zz * f0) ** 2).sum())
                q = float(np.clip((w * zz * f0 * (mu - f0)).sum() / den, -Q_MAX, 0.0)) if den > 0 else 0.0
            if start is None:
                continue
            if not final:
                cv = with_load(MuCurve(form, start[0], np.full((m, m), np.nan), f"shape:{form}{suffix}"), q, math.nan)
                sse = data_sse(pred(cv), w)
                result[form] = (cv, bic(sse, m + extra), sse)
                continue
            th0 = tuple(start[0]) + ((q,) if ld else ())
            th, sse_all, J = _refine(form, th0, s, mu, w, z=zl)
            try:
                C = np.linalg.inv(J.T @ (J * w[:, None])) * max(1.0, sse_all / max(n - m - extra, 1))
            except np.linalg.LinAlgError:
                continue
            cv = MuCurve(form, tuple(float(x) for x in th[:m]), C[:m, :m], f"shape:{form}{suffix}", s_range=s_range)
            cv = with_load(cv, float(th[-1]), float(C[-1, -1])) if ld else cv
            if not _well_posed(cv, max_rel_sigma_a):
                continue
            sse = data_sse(pred(cv), w)
            result[form] = (cv, bic(sse, m + extra), sse)
        if not result:
            break
        best = min(result.values(), key=lambda x: x[1])[0]
        slope = best.dmu_ds(s) * (1.0 + best.load_q * zz)
        slope[n:] = 0.0                                          # the prior's observation has no slip error
    classes_fit = [v for k, v in result.items() if k.startswith("class:")]
    if not classes_fit:                                          # (load fit only: every class singular)
        c = classes[0]
        cv = MuCurve.from_class(c, float(mu[:n].mean() / max(float(np.mean(c.g(s[:n]))), 1e-9)), math.nan)
        classes_fit = [(with_load(cv, 0.0, math.inf), math.inf, math.inf)]
    cls_best = min(classes_fit, key=lambda x: x[1])
    free = [v for k, v in result.items() if not k.startswith("class:")]
    chosen = cls_best[0]
    if free:
        f_best = min(free, key=lambda x: x[1])
        m_f = len(f_best[0].theta)
        sse_c, sse_f = cls_best[2], f_best[2]
        # the class must be rejected as well: F test of the extra parameters at ``test_level``
        # (BIC alone is too lenient with a dozen bins, and eq. 14 contains every class)
        dof = max(n - m_f - extra, 1)
        F = ((sse_c - sse_f) / (m_f - 1)) / (sse_f / dof)
        if f_best[1] + bic_margin < cls_best[1] and F > _f_ppf(1.0 - test_level, m_f - 1, dof):
            chosen = f_best[0]
    return CurveFit(chosen, cls_best[0], {k: v[1] for k, v in result.items()}, n, s_range)


@lru_cache(maxsize=256)
def _f_ppf(q: float, dfn: int, dfd: int) -> float:
    """Quantile q of the F distribution (dfn, dfd) (scipy's, kept: a fit asks for a few pairs of
    degrees of freedom again and again, and scipy's call costs a fifth of a fit)."""
    return f_dist.ppf(q, dfn, dfd)


def _well_posed(c: MuCurve, max_rel_sigma_a: float) -> bool:
    """The checks of a free-shape fit (section comment): finite covariance, a identified, eq. 14 not degenerate."""
    C = np.asarray(c.cov)
    if not (np.all(np.isfinite(C)) and np.all(np.diag(C) >= 0)):
        return False
    a = c.a
    if not (a > 0 and math.sqrt(c.sigma["a"] ** 2) <= max_rel_sigma_a * a):
        return False
    if c.form == "eq14":
        _, p, a1, a2 = c.theta
        if not (P_MIN <= p <= P_MAX and abs(p) > 0.02 and abs(p - 1.0) > 0.02 and a1 <= 1.3 * a2 < 0
                and p * a1 + (1.0 - p) * a2 <= 0):
            return False
    if c.form == "exp1_offset" and not (-0.1 <= c.theta[0] < c.theta[1]):
        return False
    if c.form in ("exp1", "exp1_offset") and c.alpha1 <= -0.99 * K_MAX:
        # a single exponent on its bound is a step at zero slip and a flat curve after it, not a shape the
        # pairs identify (an exp1 fit at α1 = −200 held a below the μ it had been fed for the rest of a run);
        # eq. 14 may put one of its two exponents there for a steep rise ahead of a slower one
        return False
    return True


@dataclass(frozen=True)
class ShapeState:
    """State of :class:`ShapeIdentifier`."""

    segment: int
    """Number of the current soil segment (0, 1, ...)."""
    fit: CurveFit | None
    """Last fit of the current segment (None until its slips span enough of the curve)."""
    s_range: tuple[float, float]
    """Range of the bin mean slips of the current segment [-] (bins with enough weight)."""
    n_bins: int
    """Bins of the current segment with enough weight."""
    n_fits: int
    """Fits done so far (all segments)."""
    soil: int = 0
    """Number of the soil the current segment is pooled with (segments whose slips at equal μ̂ do not differ
    are one soil; a segment unlike every earlier one is a new soil, numbered in order of appearance)."""


class ShapeIdentifier:
    """Online shape identification per soil segment (section comment above).

    Parameters
    ----------
    classes : the configured surface classes (the one-parameter candidates).
    min_span : slip span of the segment's bin means needed to fit a shape [-].
    min_bins : bins with ``min_bin_weight`` needed to fit a shape.
    min_bin_weight : effective samples a bin needs to be used (fit and change test).
    fit_period_s : least time between two fits of one segment [s].
    slip_corr_s : correlation time of the slip error [s] (one sample per τ_s).
    cusum_k, cusum_h : CUSUM allowance and threshold of the change test [standardised units].
    match_z : a segment is pooled with an earlier soil when its mean slip at equal μ̂ differs from that
        soil's by at most this many standard errors (:meth:`PairBins.shift_test`) over at least
        ``match_min_bins`` common bins.
    max_soils : soils kept for the pooling (beyond it the one seen longest ago is forgotten).
    max_weight : total effective weight of a segment beyond which its bins are rescaled.
    history_s : the pairs of this long are kept for the take-over by a new segment [s].
    confirm_s : the fit uses the pairs older than this [s] (see :meth:`_maybe_fit`).
    bic_margin : a free shape replaces the class when its BIC is this much lower.
    max_rel_sigma_a : a free shape whose σ_a/a exceeds this is not well posed.
    load : fit the load sensitivity q where the pairs' wheel loads differ (:func:`fit_curve`): the fit's bins
        are kept per load group; the change test and the soils' match use them added up.
    fz_ref_n : reference wheel load F_z,ref [N] of the identified curve (the static mean wheel load).
    """

    def __init__(self, classes: Sequence[SoilClass], *, min_span: float = 0.04, min_bins: int = 6,
                 min_bin_weight: float = 2.0, fit_period_s: float = 10.0, slip_corr_s: float = 0.5,
                 cusum_k: float = 0.5, cusum_h: float = 4.0, max_weight: float = 2000.0,
                 history_s: float = 10.0, confirm_s: float = 5.0, bic_margin: float = 6.0,
                 max_rel_sigma_a: float = 0.3, load: bool = False, fz_ref_n: float = math.nan,
                 match_z: float = 3.0, match_min_bins: int = 3, max_soils: int = 16):
        self.classes = list(classes)
        self.match_z = float(match_z)
        self.match_min_bins = int(match_min_bins)
        self.max_soils = int(max_soils)
        self.min_span = float(min_span)
        self.min_bins = int(min_bins)
        self.min_bin_weight = float(min_bin_weight)
        self.fit_period = float(fit_period_s)
        self.slip_corr = float(slip_corr_s)
        self.k = float(cusum_k)
        self.h = float(cusum_h)
        self.max_weight = float(max_weight)
        self.history_s = float(history_s)
        self.bic_margin = float(bic_margin)
        self.max_rel_sigma_a = float(max_rel_sigma_a)
        self.confirm_s = min(float(confirm_s), float(history_s))
        self.load = bool(load)
        self.fz_ref_n = float(fz_ref_n)
        c0 = self.classes[0]
        self._c0 = (c0.p, c0.alpha1, c0.alpha2, 1.0 - c0.p)   # the change test's class slope: p, α1, α2, 1 − p
        self.reset()

    def reset(self) -> None:
        # the state the compiled update (:mod:`._curve_kernel`) works on: constants, CUSUM sums and times (S),
        # the history ring's positions (SI), the segment's bins (B), the fit's bins (MT), the history of the
        # last ``history_s`` (HT: instants, HP: pairs; the young pairs are the newest of them), the instant's
        # pairs (PD) and the kernel's scratch (SC)
        S = self._S = np.zeros(CK.S_SIZE)
        S[[CK.S_SLIPCORR, CK.S_WMIN, CK.S_K, CK.S_H, CK.S_MAXW, CK.S_HIST, CK.S_CONFIRM]] = (
            self.slip_corr, self.min_bin_weight, self.k, self.h, self.max_weight, self.history_s, self.confirm_s)
        S[[CK.S_P, CK.S_A1, CK.S_A2, CK.S_Q]] = self._c0
        S[CK.S_TWO] = 2.0
        S[[CK.S_TCP, CK.S_TCN, CK.S_TCHECK, CK.S_TLAST]] = -math.inf   # (each CUSUM side's time it last left 0)
        self._SI = np.zeros(CK.SI_SIZE, dtype=np.int64)
        self._SI[CK.SI_LOAD] = int(self.load)
        self._B = np.zeros((6, PairBins.N_BINS))
        self._MT = np.zeros((6, PairBins.N_BINS * (PairBins.N_GROUPS if self.load else 1)))
        self._HT = np.zeros((256, 3))
        self._HP = np.zeros((1024, 5))
        self._PD = np.zeros((8, 5))
        self._SC = np.zeros((4, 8))
        self.segment = 0
        self.fit: CurveFit | None = None
        self.n_fits = 0
        self._t_fit = -math.inf
        self._span: tuple[float, float, int] = (math.nan, math.nan, 0)
        self.soils: list[PairBins] = []
        """The mature bins of every soil seen before the current segment (closed segments pooled)."""
        self.soil_seen: list[float] = []
        """Time each soil was last the current one [s] (the one seen longest ago is forgotten beyond ``max_soils``)."""
        self.soil_ids: list[int] = []
        """Number of each soil in :attr:`soils` (in order of appearance, kept when an older soil is forgotten)."""
        self.match = -1
        """Index in :attr:`soils` of the soil the current segment is pooled with (−1: a new soil)."""
        self._next_id = 0
        self._fit_match = -1
        self._t_last = -math.inf

    @property
    def soil(self) -> int:
        """Number of the current soil (:attr:`ShapeState.soil`)."""
        return self.soil_ids[self.match] if self.match >= 0 else self._next_id

    @property
    def bins(self) -> PairBins:
        """The current segment's bins (a copy of the compiled state's; the change test's reference)."""
        return PairBins._of(self._B, False)

    @bins.setter
    def bins(self, b: PairBins) -> None:
        self._B[:] = b.arrays()

    @property
    def mature(self) -> PairBins:
        """The segment's pairs older than ``confirm_s`` (the fit's data), binned by load group as well when the
        load term is on (else as the change test's bins: the paper path's data unchanged); a copy of the compiled
        state's."""
        return PairBins._of(self._MT, self.load)

    @mature.setter
    def mature(self, b: PairBins) -> None:
        self._MT[:] = b.arrays()

    def _scalar(i: int, doc: str) -> property:             # type: ignore[misc]  # (a class-body helper)
        return property(lambda self: float(self._S[i]), lambda self, v: self._S.__setitem__(i, v), doc=doc)

    _cp = _scalar(CK.S_CP, "CUSUM sum of the positive side")
    _cn = _scalar(CK.S_CN, "CUSUM sum of the negative side")
    _t_cp = _scalar(CK.S_TCP, "time the positive side last left zero [s]")
    _t_cn = _scalar(CK.S_TCN, "time the negative side last left zero [s]")
    _t_check = _scalar(CK.S_TCHECK, "time of the last once-a-second check [s]")
    _t_last = _scalar(CK.S_TLAST, "time of the last instant with pairs [s]")
    _w_fit = _scalar(CK.S_WFIT, "the segment's total weight at its last fit")
    del _scalar

    def _grow(self, n: int) -> None:
        """Room in the history ring for one more instant of n pairs (the positions renumbered from 0)."""
        HT, HP, SI = self._HT, self._HP, self._SI
        cap, capp = HT.shape[0], HP.shape[0]
        hh, tail = int(SI[CK.SI_HHEAD]), int(SI[CK.SI_TAIL])
        p0 = int(HT[hh % cap, 1]) if tail > hh else int(SI[CK.SI_PTAIL])
        used_p = int(SI[CK.SI_PTAIL]) - p0
        HT2 = np.zeros((max(2 * cap, tail - hh + 2), 3))
        HP2 = np.zeros((max(2 * capp, used_p + 2 * n), 5))
        for j, r in enumerate(range(hh, tail)):
            HT2[j] = HT[r % cap]
            HT2[j, 1] -= p0
        for j in range(used_p):
            HP2[j] = HP[(p0 + j) % capp]
        SI[CK.SI_YHEAD] -= hh
        SI[CK.SI_HHEAD] = 0
        SI[CK.SI_TAIL] = tail - hh
        SI[CK.SI_PTAIL] = used_p
        self._HT, self._HP = HT2, HP2
        if n > self._PD.shape[0]:
            self._PD = np.zeros((n, 5))
            self._SC = np.zeros((4, n))

    def _after(self, r: int, t: float) -> None:
        """The compiled update's Python part: on an alarm the segment's close and the pairs' binning, on the
        once-a-second check the span and fit."""
        if r == CK.ALARM:
            self._new_segment(float(self._S[CK.S_T_FROM]))
            r = _shape_post(self._S, self._SI, self._B, self._MT, self._HT, self._HP, self._PD)
        if r == CK.CHECK:
            self._maybe_fit(t)

    def _match(self, mat: PairBins | None = None) -> int:
        """The earlier soil the current segment's mature bins (``mat``, None: :attr:`mature`; their load groups
        added up) do not differ from (smallest |D|/σ_D), −1 if none."""
        best, best_z = -1, self.match_z
        mat, min_w = (self._mature_one() if mat is None else mat.pooled()), self.min_bin_weight
        nb = len(mat.W)
        own = [k for k, w in enumerate(mat.W) if not w < min_w]   # the bins shift_test does not skip for W
        for j, sb in enumerate(self.soils):
            sb = sb.pooled()
            d, sd, n = (mat._shift_test(sb, min_w, 0.002, own) if len(sb.W) == nb else mat.shift_test(sb, min_w))
            if n >= self.match_min_bins and abs(d) <= best_z * sd:
                best, best_z = j, abs(d) / sd
        return best

    def _mature_one(self) -> PairBins:
        """:attr:`mature` with its load groups added up (:meth:`PairBins.pooled`), from the compiled state's rows."""
        return PairBins._of(_pool_groups(self._MT), False) if self.load else self.mature

    def _close_soil(self) -> None:
        """The closing segment's mature pairs go to its soil (a new soil if it matched none and has
        ``match_min_bins`` bins: a few seconds of data between two alarms are dropped)."""
        m = self.mature
        if self.soils:
            self.match = self._match()
        if self.match >= 0:
            sb = self.soils[self.match]
            sb.merge(m)
            total = sb.total
            if total > self.max_weight:
                sb.scale(self.max_weight / total)
            self.soil_seen[self.match] = self._t_last
        elif m.pooled().span(self.min_bin_weight)[2] >= self.match_min_bins:
            if len(self.soils) >= self.max_soils:
                j = min(range(len(self.soils)), key=lambda i: self.soil_seen[i])
                del self.soils[j], self.soil_seen[j], self.soil_ids[j]
            self.soils.append(m)
            self.soil_seen.append(self._t_last)
            self.soil_ids.append(self._next_id)
            self._next_id += 1

    def _new_segment(self, t_from: float) -> None:
        """Close the segment; the pairs at or after t_from move to the new one."""
        self._close_soil()
        self.match = -1
        self._fit_match = -1
        CK.new_segment(self._S, self._SI, self._B, self._MT, self._HT, self._HP, float(t_from))
        self.segment += 1
        self.fit = None
        self._t_fit = -math.inf
        self._span = (math.nan, math.nan, 0)

    def update(self, t: float, dt: float, mu: Sequence[float], s: Sequence[float], sigma_s: Sequence[float],
               z: Sequence[float] | None = None, mu_bin: Sequence[float] | None = None) -> None:
        """Add the accepted pairs (|μ̂|, |ŝ| of one instant t [s], Δt [s] since the last instant) and
        their relative wheel loads z = F_z/F_z,ref − 1 [-] (None: all at the reference load).

        ``mu_bin``: the adhesion [-] each pair is binned by, when not μ̂ itself (None: μ̂).  The bins
        hold the means of ŝ and μ̂ given the binning variable; binned by μ̂, whose error is correlated
        with the slip error (the filter's μ̂ and ŝ share its innovations), the bin mean slips are
        pulled towards the axle's mean slip and the curve flattens where one axle's μ̂ spans little.
        A variable with the same information on μ and an error independent of ŝ (the drive torque over
        the wheel load, M/(r_d F_z)) gives bin means on the curve (grouping estimator, Wald 1940)."""
        n = len(mu)
        if n == 0:
            return
        m = np.array(mu, dtype=float)
        mb = m if mu_bin is None else np.array(mu_bin, dtype=float)
        if not np.isfinite(mb).all():
            raise ValueError("the binning adhesion of a pair is not finite")
        args = (float(t), float(dt), m, np.array(s, dtype=float), np.array(sigma_s, dtype=float),
                np.zeros(n) if z is None else np.array(z, dtype=float), mb, n)
        while True:
            r = CK.shape_pre(self._S, self._SI, self._B, self._HT, self._HP, self._PD, *args)
            if r != CK.GROW:
                break
            self._grow(n)
        if r == CK.ALARM:
            self._new_segment(float(self._S[CK.S_T_FROM]))
        self._after(_shape_post(self._S, self._SI, self._B, self._MT, self._HT, self._HP, self._PD), float(t))

    def _maybe_fit(self, t: float) -> None:
        """Once a second: the span; a fit when it suffices, the change test is quiet (both CUSUM
        sides under h/2) and the segment has new weight (≥ 50 % more than at its last fit, at most
        every ``fit_period_s``; the first fit of a segment at once).  The fit and its span use the
        pairs older than ``confirm_s``: a soil change is found within a few seconds, and the new
        soil's first pairs must not reach the old soil's fit (they would widen its span with
        another curve)."""
        one = self._mature_one()                            # (match and span: the load groups added up)
        if self.soils and max(self._cp, self._cn) <= 0.5 * self.h:
            self.match = self._match(one)
        pool = self.match                                   # the segment with its soil's earlier segments
        if pool < 0:
            W, S1 = one.W, one.S1
        else:                                               # the merged bins' W and Σws (PairBins.merge's
            sb = self.soils[pool].pooled()                  # sums); all six only when a fit needs them
            W = [x + y for x, y in zip(one.W, sb.W)]
            S1 = [x + y for x, y in zip(one.S1, sb.S1)]
        min_w = self.min_bin_weight
        sm = [s1 / w for w, s1 in zip(W, S1) if w >= min_w]  # PairBins.span
        lo, hi, nb = (min(sm), max(sm), len(sm)) if sm else (math.nan, math.nan, 0)
        self._span = (lo, hi, nb)
        if pool != self._fit_match:                         # other bins than the last fit's: that fit is not theirs
            self.fit = None
            self._w_fit = 0.0
        if nb < self.min_bins or not (hi - lo >= self.min_span):
            return
        if max(self._cp, self._cn) > 0.5 * self.h:          # a change may be under way
            return
        total = sum(W)                                      # PairBins.total
        if self.fit is not None and (t - self._t_fit < self.fit_period or total < 1.5 * self._w_fit):
            return
        mat = one if not self.load else self.mature         # (the fit's bins: per load group with the load term)
        bins = mat if pool < 0 else mat.merged(self.soils[pool])
        self._fit_match = pool
        self._t_fit = t
        self._w_fit = total
        self.fit = fit_curve(bins, self.classes, min_bin_weight=self.min_bin_weight,
                             bic_margin=self.bic_margin, max_rel_sigma_a=self.max_rel_sigma_a,
                             load=self.load, fz_ref_n=self.fz_ref_n)
        self.n_fits += 1

    def state(self) -> ShapeState:
        lo, hi, nb = self._span
        return ShapeState(self.segment, self.fit, (lo, hi), nb, self.n_fits, self.soil)
