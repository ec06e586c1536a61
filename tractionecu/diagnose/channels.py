"""Residual channels: each compares one recorded signal with what the nominal model predicts.

The channels stay in one module (over 500 lines): they are one family on one
base class, share the wheel-state cache and the per-group nuisance fit, and
are built together by :func:`build_channels`.

A channel has rows (time samples, windows or wheel samples), a measured
quantity ``y``, a prediction ``f`` from the model with a set of effects
switched on (the effect library's own functions), and *nuisance* parameters
the nominal model leaves free, which are always re-fitted (profiled out) on
whatever rows are used.  Its residual e = y − f − N β̂ is what diagnosis ranks.

Channels (units of the residual in brackets):

``speed`` [N] — equation error of the speed equation (paper eq. 8 with
F_h,i from eq. 2) over windows of :data:`SPEED_WINDOW_S`:

    y = ⟨Σ F_h,i − F_dx⟩ − m Δv_gps/Δt,     f = Δm Δv_ref/Δt + ⟨F_grade⟩ + ⟨F_aero⟩,
    nuisance ρ_s,cell m g (one soil rolling resistance per field cell).

``gps_speed`` [m/s] — GNSS speed against the force-integrated speed:

    y = v_gps(t),  f = v_int(t − τ),  v_int = (1/m)∫(Σ F_h,i − F_dx − F_grade − F_aero) dt,
    nuisance b(t) cubic B-spline (slow forces: ρ_s, unknown grade).

``front_load`` [N] — measured front-axle load against the static split:

    y = F_zf − f_front m g,   f = −ΔF_z,rear(F_dx, a, θ) + Δm f_Δm g.

``draft`` [N] — measured draft in full work against a speed-independent draft:

    y = F_dx,   f = D_seg · (1 + c (v² − v_ref²)),   nuisance D_seg per work segment.

``slip`` [-] — per-wheel adhesion from the torque balance against the μ(s) curve
(paper eq. 14) at the measured slip:

    y = μ_i = F_h,i / F_z,i,   f = a_cell g_class(s_i'),   nuisance a per field cell,

where s_i' is the slip the effect implies (radius (1 + ε) r_d; relaxed slip
ds'/dt = (|v|/σ)(s − s'); rear loads with Δm).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
from numpy.typing import NDArray

from ..config import G
from ..model import effects as fx
from ..model.mucurve import SOIL_CLASSES, SoilClass
from ..model.vehicle import wheel_speed_factors
from .features import (Features, SplineFit, balance_acceleration, cumtrapz0, fused_speed, moving_mean,
                       speed_integral, spline_basis, SPLINE_KNOT_S, wheel_state, wheel_torque, WheelState)
from .hac import hac_meat

SPEED_WINDOW_S = 2.0
"""Window of the speed-equation error [s]."""
SLIP_MIN_SPEED = 0.8
"""Slip rows need at least this ground speed [m/s]."""
FRONT_LOAD_SMOOTH_S = 1.0
"""Moving average applied alike to the front-axle load and its regressors [s]."""
DRAFT_EDGE_S = 1.0
"""Draft rows skip this much at each end of a work segment [s] (implement ramps)."""
DRAFT_SPEED_SMOOTH_S = 5.0
"""Averaging window of the speed in the draft channel [s]."""

Effects = Mapping[str, Mapping[str, float]]


def _p(eff: Effects, name: str, key: str, default: float) -> float:
    return float(eff[name][key]) if name in eff and key in eff[name] else default


def _clock(eff: Effects) -> tuple[float, float] | None:
    """(δ_0 [s], κ [ppm]) of a ``clock_skew`` in ``eff``, None without one."""
    if "clock_skew" not in eff:
        return None
    return _p(eff, "clock_skew", "offset_s", 0.0), _p(eff, "clock_skew", "rate_ppm", 0.0)


WHEEL_CACHE_BYTES = 48 * 2 ** 20
"""Most memory the wheel-state memo holds [B] (a state is five (n, 4) arrays: 23 MB on a 4-hour recording).

A fit evaluates each parameter vector once, on every channel it acts on, and the effects that leave
the wheels alone share the nominal state: the states used again are the last few and the nominal
one, which a least-recently-used memo of a few states keeps (a state costs a few vector operations
over the frame to recompute; the fused speed under a GNSS latency, a spline fit, is kept likewise)."""


class _WheelCache:
    """wheel_state() memoised on the parameters that change it (at most 64 states and
    :data:`WHEEL_CACHE_BYTES`, the least recently used dropped first)."""

    def __init__(self, feat: Features):
        from collections import OrderedDict

        self.feat = feat
        self._cache: OrderedDict[tuple, WheelState] = OrderedDict()
        self._bytes = 0

    def v_ref(self, eff: Effects) -> NDArray:
        """Fused ground speed; re-fitted when the candidate delays the GNSS speed or shifts the CAN clock."""
        tau = _p(eff, "gps_latency", "tau_s", 0.0)
        clock = _clock(eff)
        if tau == 0.0 and clock is None:
            return self.feat.v_ref
        key = ("v", tau, clock)
        v = self._lookup(key)
        if v is None:
            f = self.feat
            v = fused_speed(f.frame, f.v_int, f.valid, tau, clock)
            self._put(key, v)
        return v

    @staticmethod
    def _size(val) -> int:
        return val.nbytes if isinstance(val, np.ndarray) else sum(
            a.nbytes for a in vars(val).values() if isinstance(a, np.ndarray))

    def _lookup(self, key):
        val = self._cache.get(key)
        if val is not None:
            self._cache.move_to_end(key)
        return val

    def _put(self, key, val) -> None:
        size = self._size(val)
        while self._cache and (len(self._cache) >= 64 or self._bytes + size > WHEEL_CACHE_BYTES):
            _, old = self._cache.popitem(last=False)
            self._bytes -= self._size(old)
        self._cache[key] = val
        self._bytes += size

    def get(self, eff: Effects, with_slip: bool = False) -> WheelState:
        kw = wheel_kwargs(eff, self.feat.frame)
        key = (tuple((k, v if not isinstance(v, np.ndarray) else v.tobytes()) for k, v in sorted(kw.items())),
               (_p(eff, "gps_latency", "tau_s", 0.0), _clock(eff)) if with_slip else None, with_slip)
        ws = self._lookup(key)
        if ws is None:
            f = self.feat
            v = self.v_ref(eff) if with_slip else None
            ws = wheel_state(f.frame, f.omega_dot, v, **kw)
            self._put(key, ws)
        return ws


def wheel_kwargs(eff: Effects, fr) -> dict:
    """Arguments of :func:`~.features.wheel_state` for the effects and sensor faults in ``eff``."""
    kw: dict = {}
    dm = _p(eff, "mass", "delta_kg", 0.0)
    if dm:
        kw["delta_m"] = dm
    eps = _p(eff, "wheel_radius", "epsilon", 0.0)
    rho_f = 1.0
    if "tyre_pressure" in eff:
        e2, rho_f = fx.tyre_pressure_terms(eff["tyre_pressure"]["p_ratio"])
        eps = (1.0 + eps) * (1.0 + e2) - 1.0
    if eps:
        kw["eps_r"] = eps
    if rho_f != 1.0:
        kw["rho_t_factor"] = rho_f
    if "drivetrain" in eff:
        kw["eta"] = _p(eff, "drivetrain", "eta", 1.0)
        kw["loss_nm"] = _p(eff, "drivetrain", "loss_nm", 0.0)
    if "torque_gain" in eff:
        kw["gain"] = (_p(eff, "torque_gain", "k_front", 0.0), _p(eff, "torque_gain", "k_rear", 0.0))
    if "torque_offset" in eff:
        kw["offset_nm"] = (_p(eff, "torque_offset", "b_front_nm", 0.0), _p(eff, "torque_offset", "b_rear_nm", 0.0))
    if "axle_load_offset" in eff:
        p = eff["axle_load_offset"]
        kw["fzf_offset"] = fx.offset_drift(fr.t, p["b0_n"], p["b1_npm"])
    return kw


def draft_of(eff: Effects, fr) -> NDArray:
    """The draft [N] with a fitted draft-sensor offset and drift removed (NaN → 0)."""
    d = np.nan_to_num(fr.fdx) if fr.fdx is not None else np.zeros(fr.n)
    if "draft_offset" in eff:
        p = eff["draft_offset"]
        d = d - fx.offset_drift(fr.t, p["b0_n"], p["b1_npm"])
    return d


@dataclass
class Channel:
    """Base: rows, fold and time index per row; subclasses give y, f and the nuisance fit."""

    name: str
    unit: str
    signal: str
    """What the residual is about, in words."""
    effects: frozenset[str]
    """Effects whose terms act on this channel."""
    t: NDArray[np.float64]
    tidx: NDArray[np.int64]
    """Time index of each row (rows sharing one are aggregated before HAC)."""
    fold: NDArray[np.int8]
    """Held-out fold (0 or 1) of each row."""
    nuisance: str = ""
    extra: dict = field(default_factory=dict)

    @property
    def m(self) -> int:
        return int(self.t.size)

    def residual(self, eff: Effects, rows: NDArray[np.bool_]) -> NDArray[np.float64]:  # pragma: no cover
        raise NotImplementedError

    def parts(self, eff: Effects, rows: NDArray[np.bool_]) -> tuple[NDArray, NDArray]:  # pragma: no cover
        """(measured y, full prediction f + nuisance) on ``rows``."""
        raise NotImplementedError

    def freeze(self, on: bool) -> None:
        """Hold discrete nuisance choices at their last values (for derivatives)."""


def _fold_of(feat: Features, idx: NDArray) -> NDArray[np.int8]:
    """Held-out fold (0 or 1) of frame rows ``idx``, one byte per row (a per-wheel channel of a 4-hour
    recording has over half a million rows)."""
    return feat.fold[idx].astype(np.int8)


def _onehot_scaled_fit(y: NDArray, x: NDArray, group: NDArray[np.int64], ng: int) -> NDArray:
    """β_g = Σ x y / Σ x² per group; returns the fitted values β_g x."""
    num = np.bincount(group, weights=x * y, minlength=ng)
    den = np.bincount(group, weights=x * x, minlength=ng)
    beta = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
    return beta[group] * x


SLIP_RESISTANCE_NOMINAL = True
"""The speed channel's nominal resistance grows with slip: ρ_s,cell m g + k_s Σ_i F_z,i |s_i|.

What every tractor on soil has: the motion resistance of a tyre rises with its slip (the tyre digs
in and bulldozes; Brixius 1987: MR/W = 1/B_n + 0.04 + 0.5 s/√B_n, so k_s = 0.5/√B_n).  One k_s per
recording in [0, :data:`SLIP_RESISTANCE_MAX`] (a per-cell k_s would also take up part of a grade,
whose climbs raise the slip)."""
SLIP_RESISTANCE_MAX = 0.15
"""Largest slip coefficient k_s of the motion resistance [-]: 0.5/√B_n at B_n = 11, softer than the
mobility numbers of trafficable field soils (B_n ≈ 15–80 for tractor tyres on tilled to firm soil)."""


def _rho_and_slip_fit(y: NDArray, mg: float, xs: NDArray, group: NDArray[np.int64], ng: int,
                      d: NDArray | None = None) -> NDArray:
    """ρ_g m g d + k xs fitted by least squares with one ρ per group and one k in [0, SLIP_RESISTANCE_MAX]
    shared by all (the groups' ρ are profiled out first).  ``d``: the direction of travel over each row (the
    window mean of sign v, ±1 in steady travel), on which a motion resistance turns; None: forward (1)."""
    if d is None:
        d = np.ones_like(y)
    dd = np.maximum(np.bincount(group, weights=d * d, minlength=ng), 1e-12)
    ym = np.bincount(group, weights=d * y, minlength=ng) / dd
    xm = np.bincount(group, weights=d * xs, minlength=ng) / dd
    yt, xt = y - ym[group] * d, xs - xm[group] * d
    den = float(np.dot(xt, xt))
    k = float(np.clip(np.dot(xt, yt) / den, 0.0, SLIP_RESISTANCE_MAX)) if den > 0 else 0.0
    rho = ym - k * xm
    return rho[group] * d + k * xs


# --------------------------------------------------------------------------- speed
class SpeedChannel(Channel):
    def __init__(self, feat: Features, wc: _WheelCache):
        fr = feat.frame
        self.feat, self.wc = feat, wc
        W = int(round(SPEED_WINDOW_S * fr.rate_hz))
        self.W = W
        self.k_avg = max(1, W // 4)
        starts = np.arange(0, fr.n - W, W)
        ok = np.array([feat.valid[a:a + W].all() for a in starts], dtype=bool)
        self.starts = starts[ok]
        mid = self.starts + W // 2
        super().__init__("speed", "N", "speed equation (eq. 8): unexplained resistive force",
                         frozenset({"grade", "mass", "drivetrain", "aero", "wheel_radius", "torque_gain",
                                    "torque_offset", "draft_offset", "axle_load_offset", "tyre_pressure"}),
                         fr.t[mid], mid.astype(np.int64), feat.fold[mid],
                         "ρ_s and the slip coefficient k_s of the motion resistance per field cell")
        self.cell = feat.cell[mid]
        self.ncell = feat.n_cells
        ka = self.k_avg
        idx = self.starts[:, None] + np.arange(W)[None, :]
        self._idx = idx
        self._a = self.starts + (ka - 1) / 2.0
        self._b = self.starts + W - 1 - (ka - 1) / 2.0
        self.dt_win = (self._b - self._a) * fr.dt
        v = feat.v_gps
        self.dv = v[idx[:, W - ka:]].mean(axis=1) - v[idx[:, :ka]].mean(axis=1)
        # The same speed change from the fused speed: the regressor of a mass error (its GNSS noise
        # would attenuate the fitted mass; the GNSS Δv stays on the measured side).
        vr = feat.v_ref
        self.dv_ref = vr[idx[:, W - ka:]].mean(axis=1) - vr[idx[:, :ka]].mean(axis=1)
        th = feat.theta
        self.theta = np.nan_to_num(th) if th is not None else np.zeros(fr.n)
        self.v_ref = feat.v_ref
        # The motion resistance opposes the travel: its regressors turn with the direction (reversing at a
        # headland), the window mean of sign v (±1 in steady travel, between across a stop).
        self._sign_v = np.sign(np.nan_to_num(feat.v_ref))
        self.direction = self._win_mean(self._sign_v)

    def _win_mean(self, x: NDArray) -> NDArray:
        """Mean of x over the span between the two speed-averaging centroids (trapezoid)."""
        cs = np.concatenate([[0.0], np.cumsum(x)])
        a = np.floor(self._a).astype(int)
        b = np.ceil(self._b).astype(int)
        s = cs[b + 1] - cs[a] - 0.5 * (x[a] + x[b])
        return s / (b - a)

    def parts(self, eff: Effects, rows: NDArray[np.bool_]) -> tuple[NDArray, NDArray]:
        fr = self.feat.frame
        ws = self.wc.get(eff)
        dm = _p(eff, "mass", "delta_kg", 0.0)
        m = fr.vehicle.mass_kg + dm
        force = ws.fx_sum - draft_of(eff, fr)
        y = self._win_mean(force) - fr.vehicle.mass_kg * self.dv / self.dt_win
        f = dm * self.dv_ref / self.dt_win
        if "grade" in eff:
            f = f + eff["grade"]["scale"] * self._win_mean(fx.grade_force(m, self.theta))
        if "aero" in eff:
            f = f + self._win_mean(fx.aero_force(self.v_ref, eff["aero"]["cd_area_m2"]))
        y, f = y[rows], f[rows]
        d = self.direction[rows]
        if SLIP_RESISTANCE_NOMINAL:
            xs = self._slip_load(eff)[rows]
            nu = _rho_and_slip_fit(y - f, m * G, xs, self.cell[rows], self.ncell, d)
        else:
            nu = _onehot_scaled_fit(y - f, m * G * d, self.cell[rows], self.ncell)
        return y, f + nu

    def _slip_load(self, eff: Effects) -> NDArray:
        """Window mean of sign(v) Σ_i F_z,i |s_i| [N]: the regressor of the slip-dependent motion resistance,
        which opposes the travel."""
        ws = self.wc.get(eff, with_slip=True)
        s = np.clip(np.nan_to_num(ws.slip), -0.5, 0.5) if ws.slip is not None else np.zeros_like(ws.fz)
        return self._win_mean(self._sign_v * np.nansum(np.nan_to_num(ws.fz) * np.abs(s), axis=1))

    def residual(self, eff: Effects, rows: NDArray[np.bool_]) -> NDArray:
        y, p = self.parts(eff, rows)
        return y - p


# --------------------------------------------------------------------------- GNSS speed
SPLINE_MEMO = 6
"""Row sets whose spline factors the GNSS-speed channel keeps (least recently used dropped first): a
held-out score cycles through five (each fold's training and held-out rows, all rows); each factor
holds its rows' basis, 8 MB on a 4-hour recording."""


class GpsSpeedChannel(Channel):
    def __init__(self, feat: Features, wc: _WheelCache):
        fr = feat.frame
        self.feat, self.wc = feat, wc
        rows = np.nonzero(feat.valid & np.isfinite(feat.v_gps))[0]
        super().__init__("gps_speed", "m/s", "GNSS speed against the force-integrated speed",
                         frozenset({"gps_latency", "mass", "drivetrain", "wheel_radius", "torque_gain",
                                    "torque_offset", "draft_offset", "axle_load_offset", "clock_skew"}),
                         fr.t[rows], rows, _fold_of(feat, rows), "slow speed correction b(t), cubic spline")
        self.rows_idx = rows
        self.B = spline_basis(fr.t, SPLINE_KNOT_S, sparse=True, breaks=fr.break_t)[rows]
        self.y = feat.v_gps[rows]
        self.theta = np.nan_to_num(feat.theta) if feat.theta is not None else np.zeros(fr.n)
        self._qr: dict[bytes, tuple] = {}

    def _project(self, r: NDArray, rows: NDArray[np.bool_]) -> NDArray:
        """Least-squares fit of the spline nuisance to r on ``rows``: B (BᵀB)⁻¹ Bᵀ r (B is sparse, BᵀB
        banded: :class:`~.features.SplineFit`, linear in the recording's length)."""
        key = np.packbits(rows).tobytes()
        q = self._qr.pop(key, None)
        if q is None:
            while len(self._qr) >= SPLINE_MEMO:
                self._qr.pop(next(iter(self._qr)))       # the least recently used row set
            q = SplineFit(self.B[np.flatnonzero(rows)], min_support=1e-6)
        self._qr[key] = q
        return q.project(r)

    def v_model(self, eff: Effects) -> NDArray:
        fr = self.feat.frame
        ws = self.wc.get(eff)
        m = fr.vehicle.mass_kg + _p(eff, "mass", "delta_kg", 0.0)
        force = ws.fx_sum - draft_of(eff, fr)
        if "grade" in eff:
            force = force - eff["grade"]["scale"] * fx.grade_force(m, self.theta)
        if "aero" in eff and self.feat.v_ref is not None:
            force = force - fx.aero_force(self.feat.v_ref, eff["aero"]["cd_area_m2"])
        v = speed_integral(fr, balance_acceleration(fr, force, m))
        if "gps_latency" in eff:
            v = fx.delayed(fr.t, v, eff["gps_latency"]["tau_s"])
        if "clock_skew" in eff:
            # The force samples of CAN time t stand for GNSS time t − δ(t).
            p = eff["clock_skew"]
            v = np.interp(fr.t, fr.t - fx.clock_shift_s(fr.t, p["offset_s"], p["rate_ppm"]), v)
        return v[self.rows_idx]

    def parts(self, eff: Effects, rows: NDArray[np.bool_]) -> tuple[NDArray, NDArray]:
        f = self.v_model(eff)[rows]
        y = self.y[rows]
        return y, f + self._project(y - f, rows)

    def residual(self, eff: Effects, rows: NDArray[np.bool_]) -> NDArray:
        y, p = self.parts(eff, rows)
        return y - p


# --------------------------------------------------------------------------- front axle load
class FrontLoadChannel(Channel):
    """Measured front-axle load against the static split and the load transfer (nominal model).

        y = F_zf − f_front m g,   f = −ΔF_z,rear(F_dx, a, θ; h_hitch, h_cg) + Δm f_Δm g + b_0 + b_1 t,

    with the heights h_hitch, h_cg a *nuisance*: every tractor pulling from a hitch transfers load
    (library ``load_transfer``), so the nominal model fits the heights (linear least squares on the
    rows in use) instead of treating the transfer as a fault.  :meth:`nominal_heights` reports them.
    """

    def __init__(self, feat: Features):
        fr = feat.frame
        self.feat = feat
        rows = np.nonzero(feat.valid & np.isfinite(fr.fzf))[0]
        super().__init__("front_load", "N", "front-axle load against the static split and the load transfer",
                         frozenset({"mass", "axle_load_offset", "draft_offset"}), fr.t[rows], rows,
                         _fold_of(feat, rows), "load-transfer heights h_hitch, h_cg (nominal model)")
        self.rows_idx = rows
        veh = fr.vehicle
        # The measured load and the regressors pass through the same moving average: the relation is
        # linear, so it is kept, while the sensors' white noise in the regressors (which would
        # attenuate the fitted heights) drops.
        k = max(1, int(round(FRONT_LOAD_SMOOTH_S * fr.rate_hz)))
        self.k = k

        def sm(x: NDArray | None) -> NDArray:
            if x is None:
                return np.zeros(rows.size)
            return np.nan_to_num(moving_mean(x, k)[rows])

        self.sm = sm
        self.y = sm(fr.fzf) - veh.static_front_load_n()
        self.fdx = sm(fr.fdx)
        self.acc = sm(feat.accel)
        self.theta = sm(feat.theta)
        self.t_rows = fr.t[rows]
        self.last_heights: tuple[float, float] = (math.nan, math.nan)

    def _design(self, eff: Effects) -> NDArray:
        """Regressors of the heights (h_hitch, h_cg): −ΔF_z,rear = −(F_dx h_hitch + m (a + g sin θ) h_cg)/L."""
        veh = self.feat.frame.vehicle
        m = veh.mass_kg + _p(eff, "mass", "delta_kg", 0.0)
        fdx = self.fdx
        if "draft_offset" in eff:
            p = eff["draft_offset"]
            fdx = fdx - fx.offset_drift(self.t_rows, p["b0_n"], p["b1_npm"])
        x1 = -fx.load_transfer_rear(fdx, 0.0, 0.0, m, veh.wheelbase_m, 1.0, 0.0)
        x2 = -fx.load_transfer_rear(0.0, self.acc, self.theta, m, veh.wheelbase_m, 0.0, 1.0)
        return np.stack([x1, x2], axis=1)

    def _effects_part(self, eff: Effects) -> NDArray:
        f = np.zeros(self.y.size)
        if "mass" in eff:
            f = f + _p(eff, "mass", "delta_kg", 0.0) * eff["mass"]["front_share"] * G
        if "axle_load_offset" in eff:
            p = eff["axle_load_offset"]
            f = f + fx.offset_drift(self.t_rows, p["b0_n"], p["b1_npm"])
        return f

    def parts(self, eff: Effects, rows: NDArray[np.bool_]) -> tuple[NDArray, NDArray]:
        f = self._effects_part(eff)[rows]
        y = self.y[rows]
        X = self._design(eff)[rows]
        if X.shape[0] > 2:
            h, *_ = np.linalg.lstsq(X, y - f, rcond=None)
            self.last_heights = (float(h[0]), float(h[1]))
            f = f + X @ h
        return y, f

    def nominal_heights(self, eff: Effects) -> dict:
        """Load-transfer heights of the nominal model on all rows with HAC 95 % intervals."""

        y = self.y - self._effects_part(eff)
        X = self._design(eff)
        h, *_ = np.linalg.lstsq(X, y, rcond=None)
        e = y - X @ h
        A = X.T @ X
        try:
            Ai = np.linalg.inv(A)
        except np.linalg.LinAlgError:
            return {}
        cov = Ai @ hac_meat(X * e[:, None]) @ Ai
        se = np.sqrt(np.maximum(np.diag(cov), 0.0))
        out = {}
        for j, name in enumerate(("h_hitch_m", "h_cg_m")):
            out[name] = {"value": float(h[j]), "ci95": [float(h[j] - 1.96 * se[j]), float(h[j] + 1.96 * se[j])],
                         "unit": "m"}
        return out

    def residual(self, eff: Effects, rows: NDArray[np.bool_]) -> NDArray:
        y, p = self.parts(eff, rows)
        return y - p


# --------------------------------------------------------------------------- draft
class DraftChannel(Channel):
    def __init__(self, feat: Features):
        fr = feat.frame
        self.feat = feat
        edge = int(round(DRAFT_EDGE_S * fr.rate_hz))
        keep = np.zeros(fr.n, dtype=bool)
        for s in range(int(feat.segment.max()) + 1 if feat.segment.size else 0):
            idx = np.nonzero(feat.segment == s)[0]
            if idx.size > 2 * edge + 10:
                keep[idx[edge:-edge]] = True
        keep &= feat.valid & np.isfinite(fr.fdx) if fr.fdx is not None else False
        rows = np.nonzero(keep)[0]
        super().__init__("draft", "N", "draft in work against a speed-independent draft per work segment",
                         frozenset({"draft_speed"}), fr.t[rows], rows, _fold_of(feat, rows),
                         "draft level D per work segment")
        self.rows_idx = rows
        self.y = fr.fdx[rows] if rows.size else np.zeros(0)
        seg = feat.segment[rows]
        _, self.seg = np.unique(seg, return_inverse=True)
        self.nseg = int(self.seg.max()) + 1 if rows.size else 0
        # Speed regressor: v_ref averaged over DRAFT_SPEED_SMOOTH_S.  The draft's own fluctuation
        # slows the tractor within a second (feedback); the average keeps the operator's speed
        # changes and drops most of that feedback, which would bias c towards negative values.
        k = max(1, int(round(DRAFT_SPEED_SMOOTH_S * fr.rate_hz)))
        vs = np.nan_to_num(moving_mean(feat.v_ref, k)) if feat.v_ref is not None else np.zeros(fr.n)
        self.v = vs[rows]

    def parts(self, eff: Effects, rows: NDArray[np.bool_]) -> tuple[NDArray, NDArray]:
        if "draft_speed" in eff:
            p = eff["draft_speed"]
            x = fx.draft_speed_factor(self.v, p["c_s2pm2"], p["v_ref_mps"])
        else:
            x = np.ones(self.y.size)
        y = self.y[rows]
        return y, _onehot_scaled_fit(y, x[rows], self.seg[rows], self.nseg)

    def residual(self, eff: Effects, rows: NDArray[np.bool_]) -> NDArray:
        y, p = self.parts(eff, rows)
        return y - p


# --------------------------------------------------------------------------- slip
def relaxed(s: NDArray, v: NDArray, sigma_m: float, dt: float) -> NDArray:
    """Relaxed slip s' of the effect library's ``relaxation_rate``, ds'/dt = (|v|/σ)(s − s').

    Integrated exactly for an input held over each step:
    s'_k = s'_{k−1} + (1 − e^{−λ_k Δt})(s_k − s'_{k−1}), λ_k = |v_k|/σ.
    Non-finite samples restart the filter.
    """
    lam = fx.relaxation_rate(1.0, 0.0, v, sigma_m)
    alpha = 1.0 - np.exp(-lam * dt)
    out = np.empty_like(s)
    prev = np.full(s.shape[1:], np.nan)
    for k in range(s.shape[0]):
        sk = s[k]
        ak = alpha[k]
        nxt = np.where(np.isfinite(prev), prev + ak * (sk - prev), sk)
        out[k] = nxt
        prev = nxt
    return out

WHEEL_FORCE_SMOOTH_S = 0.05
"""Centred moving average of the raw-rate slip [s] (removes wheel-speed sensor noise, keeps a few hertz)."""
HF_CHUNK_ROWS = 8192
"""Frame rows whose raw-rate samples the wheel-force channel processes at once (bounds its temporaries)."""
WHEEL_FORCE_HP_S = 2.0
"""Moving-average window removed from both sides of the wheel-force channel [s]."""


def _highpass(x: NDArray, k: int) -> NDArray:
    """x minus its centred moving average over k samples, per column (edges use the available samples)."""
    from scipy.ndimage import uniform_filter1d

    return x - uniform_filter1d(x, size=k, axis=0, mode="nearest")


def relaxed_by_distance(t: NDArray, s: NDArray, v: NDArray, sigma_m: float, dx: float = 0.02) -> NDArray:
    """Relaxed slip of the library's ``relaxation_rate``, ds'/dt = (|v|/σ)(s − s'), for columns of s (n, k).

    In travelled distance x = ∫|v| dt the equation is ds'/dx = (s − s')/σ, a filter with
    constant coefficients: s is resampled on a uniform distance grid (step ``dx`` [m]),
    filtered exactly for an input held over each step, s'_j = φ s'_{j−1} + (1 − φ) s_j with
    φ = e^{−dx/σ} (= exp(−relaxation_rate(1, 0, 1, σ)·dx)), and resampled back.
    """
    from scipy.signal import lfilter

    x = cumtrapz0(np.abs(v), float(np.median(np.diff(t))) if t.size > 1 else 1.0)
    x = np.maximum.accumulate(x + 1e-9 * np.arange(x.size))
    xg = np.arange(x[0], x[-1] + dx, dx)
    phi = float(np.exp(-fx.relaxation_rate(1.0, 0.0, 1.0, sigma_m) * dx))
    out = np.empty_like(s)
    for j in range(s.shape[1]):
        sg = np.interp(xg, x, np.nan_to_num(s[:, j]))
        yg, _ = lfilter([1.0 - phi], [1.0, -phi], sg, zi=[phi * sg[0]])
        out[:, j] = np.interp(x, xg, yg)
    return out


def fill_missing_raw(t: NDArray, x: NDArray) -> NDArray:
    """Raw-rate samples (n, k) with each column's missing values (NaN) interpolated linearly in time
    from its neighbours (held at the ends; a column with no finite value becomes 0).

    A raw window without a sample is not a wheel at standstill: read as 0 rad/s it gave a slip of
    −0.9 that the smoothing and the relaxation filter then spread into the valid rows around it.
    A window is empty when the logger's time stamps of a message fall on the windows' edges (the
    frames of one message carry all four wheels, so the spike is common to them).  The rows with a
    missing sample stay out of the channel; only their neighbours' regressor is repaired."""
    bad = ~np.isfinite(x)
    if not bad.any():
        return x
    out = np.array(x, dtype=float, copy=True)
    for j in range(out.shape[1]):
        m = bad[:, j]
        if not m.any():
            continue
        if m.all():
            out[:, j] = 0.0
            continue
        out[m, j] = np.interp(t[m], t[~m], out[~m, j])
    return out


class WheelForceChannel(Channel):
    """Per-wheel adhesion from the torque balance against the μ(s) curve at the raw wheel-speed rate.

        y_i = HP[sgn ω_i · μ_i],  μ_i = ((M_i − J ω̇_i)/r_i − ρ_t F_z,i sgn ω_i)/F_z,i      (bin means, paper eq. 2),
        f_i = a_cell HP[⟨g(s_i')⟩],   s_i = 1 − v/(r_i ω_i) at the raw rate,

    with ⟨·⟩ the bin mean, HP[x] = x minus its moving average over :data:`WHEEL_FORCE_HP_S` and s_i' = s_i, or the relaxed slip of
    :func:`relaxed_by_distance` for the relaxation candidate.  Relaxation turns the
    wheel into a lightly damped oscillator of a few hertz, which only the raw-rate
    slip resolves.  Nuisance: a per field cell; the surface class is the one the
    slip channel's nominal fit selects.
    """

    def __init__(self, feat: Features, wc: _WheelCache):
        fr = feat.frame
        self.feat, self.wc = feat, wc
        ws = wc.get({}, with_slip=True)
        k = fr.hf_t.size // fr.n
        self.k = k
        ok = (feat.valid[:, None] & (np.abs(feat.v_ref)[:, None] > SLIP_MIN_SPEED) & np.isfinite(ws.mu)
              & np.isfinite(ws.slip) & (np.abs(ws.slip) < 0.5)
              & np.all(np.isfinite(fr.hf_omega.reshape(fr.n, k, 4)), axis=1))
        ti, wi = np.nonzero(ok)
        super().__init__("wheel_force", "-", "per-wheel adhesion from torque against μ(s) at the raw slip",
                         frozenset({"relaxation"}), fr.t[ti], ti, _fold_of(feat, ti),
                         "soil class shape and curve parameter a per field cell")
        self.ti, self.wi = ti, wi.astype(np.int8)
        self.cell = feat.cell[ti].astype(np.int32)
        self.ncell = feat.n_cells
        # Both sides high-passed (minus a WHEEL_FORCE_HP_S moving average): the slow error of the
        # ground speed, which dominates slip, cancels, and the fast dynamics remain.
        self.kw = max(3, int(round(WHEEL_FORCE_HP_S * fr.rate_hz)))
        # the adhesion along the wheel's rotation, as the slip (positive where a wheel drives, also in reverse)
        mu = np.nan_to_num(ws.mu)
        if (fr.omega[ti, wi] < 0.0).any():
            mu = np.where(fr.omega < 0.0, -mu, mu)
        self.y_hp = _highpass(mu, self.kw)[ti, wi]
        v_hf = self._v_hf()
        # The raw-rate slip, HF_CHUNK_ROWS frame rows at a time (its temporaries are each as large as
        # the raw-rate wheel speeds: 46 MB at four hours).
        s_raw = np.empty(fr.hf_omega.shape)
        # In a turn each wheel's ground speed is k_i(κ)·v (model doc "Kinematics in turns"), κ held over a bin.
        kfac = None
        if fr.kappa is not None and np.any(fr.kappa != 0.0):
            kfac = wheel_speed_factors(fr.kappa, fr.vehicle.track_width_m, fr.vehicle.wheelbase_m)
        for a in range(0, fr.n, HF_CHUNK_ROWS):
            b = min(a + HF_CHUNK_ROWS, fr.n)
            hs = slice(a * k, b * k)
            r_hf = np.repeat(ws.r[a:b], k, axis=0)
            with np.errstate(divide="ignore", invalid="ignore"):
                vw = np.abs(r_hf * fill_missing_raw(fr.hf_t[hs], fr.hf_omega[hs]))
                va = np.abs(v_hf[hs])[:, None]
                if kfac is not None:
                    va = va * np.repeat(kfac[a:b], k, axis=0)
                s = np.where(va <= vw, 1.0 - va / np.maximum(vw, 1e-6), -1.0 + vw / np.maximum(va, 1e-6))
            s_raw[hs] = np.clip(np.nan_to_num(s), -0.9, 0.9)
        # Zero-phase smoothing over WHEEL_FORCE_SMOOTH_S of the raw slip (sensor noise): a causal
        # relaxation filter must not win by denoising the regressor, only by a real lag.
        from scipy.ndimage import uniform_filter1d

        ks = max(1, int(round(WHEEL_FORCE_SMOOTH_S / float(np.median(np.diff(fr.hf_t))))))
        self.s_hf = uniform_filter1d(s_raw, size=ks, axis=0, mode="nearest")
        del s_raw, v_hf
        self.soil: SoilClass = SOIL_CLASSES["stubble"]
        self.fixed_class = False
        self._frozen = False
        self._g_plain: dict[str, NDArray] = {}
        """Per surface class, the high-passed bin means of g(s) at the rows without relaxation (they
        do not depend on the candidate)."""

    def _v_hf(self) -> NDArray:
        """The fused ground speed on the raw-rate grid [m/s] (recomputed where needed, not kept: as large
        as one wheel's raw-rate samples)."""
        return np.interp(self.feat.frame.hf_t, self.feat.frame.t, self.feat.v_ref)

    def share_rows(self, other: Channel) -> None:
        """Use ``other``'s row arrays (times, time index, wheel, fold) where they are the same rows."""
        if (getattr(other, "ti", None) is not None and other.ti.size == self.ti.size
                and np.array_equal(other.ti, self.ti) and np.array_equal(other.wi, self.wi)):
            self.t, self.tidx, self.ti, self.wi, self.fold = other.t, other.tidx, other.ti, other.wi, other.fold

    def _g_rows(self, cls: SoilClass, s: NDArray) -> NDArray:
        """HP[⟨g(s)⟩] at every row: bin means of g over the raw-rate samples, HF_CHUNK_ROWS frame rows
        at a time, then high-passed."""
        fr = self.feat.frame
        k = self.k
        gb = np.empty((fr.n, 4))
        for a in range(0, fr.n, HF_CHUNK_ROWS):
            b = min(a + HF_CHUNK_ROWS, fr.n)
            gb[a:b] = cls.g(s[a * k:b * k]).reshape(b - a, k, 4).mean(axis=1)
        return _highpass(gb, self.kw)[self.ti, self.wi]

    def use_class(self, cls: SoilClass) -> None:
        """Hold the surface class (the level information of the slip channel fixes it better than the
        high-passed fluctuations here, where class shape and relaxation length trade off)."""
        self.soil = cls
        self.fixed_class = True

    def freeze(self, on: bool) -> None:
        self._frozen = on

    def parts(self, eff: Effects, rows: NDArray[np.bool_]) -> tuple[NDArray, NDArray]:
        fr = self.feat.frame
        s = self.s_hf
        relax = "relaxation" in eff
        if relax:
            s = relaxed_by_distance(fr.hf_t, s, self._v_hf(), eff["relaxation"]["sigma_m"])
        y = self.y_hp[rows]
        cell = self.cell[rows]
        best, best_sse = None, math.inf
        classes = {self.soil.name: self.soil} if (self._frozen or self.fixed_class) else SOIL_CLASSES
        for cls in classes.values():
            if relax:
                gb = self._g_rows(cls, s)[rows]
            else:
                g_all = self._g_plain.get(cls.name)
                if g_all is None:
                    g_all = self._g_plain[cls.name] = self._g_rows(cls, s)
                gb = g_all[rows]
            p = _onehot_scaled_fit(y, gb, cell, self.ncell)
            sse = float(np.sum((y - p) ** 2))
            if sse < best_sse:
                best, best_sse, self.soil = p, sse, cls
        return y, best

    def residual(self, eff: Effects, rows: NDArray[np.bool_]) -> NDArray:
        y, p = self.parts(eff, rows)
        return y - p



class _CurveInverse:
    """s = g⁻¹(q) of a surface class by table lookup (g is odd and increasing)."""

    def __init__(self, cls: SoilClass, s_max: float = 0.6):
        self.cls = cls
        self.s = np.linspace(0.0, s_max, 3001)
        self.g = cls.g(self.s)

    def __call__(self, q: NDArray) -> NDArray:
        aq = np.minimum(np.abs(q), self.g[-1])
        return np.sign(q) * np.interp(aq, self.g, self.s)


A_GRID = np.linspace(0.2, 1.3, 45)
"""Grid of the curve parameter a searched per field cell [-] (refined by a parabola)."""
MU0_NOMINAL = True
"""The nominal model fits the zero-slip traction ratio μ_0 per axle (see :data:`MU0_RANGE`)."""
WARM_CONVERGED = 1e-3
"""A warm-started Gauss–Newton fit of a (and μ_0) whose last step moved a by less than this [-] has
settled; otherwise the slip channel also solves from the grid start."""
MU0_RANGE = (-0.03, 0.06)
"""Range of the zero-slip traction ratio μ_0 per axle [-] in the nominal model of the slip channel.

What every tyre has: the adhesion from the torque balance, μ = M/(r F_z) − ρ_t, uses the
vehicle file's declared ρ_t, while a real tyre's hysteresis (internal) loss depends on its
construction, load, inflation and temperature: Brixius (1987) puts it at 0.04 of the wheel load,
ASABE D497 rolling-resistance ratios on firm surfaces are 0.01–0.04, against a declared ρ_t of
0.01–0.03.  The difference shows as μ(0) ≠ 0, μ = a g(s) + μ_0; a healthy machine has it.
The range is that difference: a torque-sensor offset or a pressure loss beyond it still shows."""


SLIP_EFFECTS = frozenset({"wheel_radius", "gps_latency", "clock_skew", "torque_gain", "torque_offset",
                          "tyre_pressure", "axle_load_offset", "mass"})
"""Effects and faults the slip channel's prediction depends on.  Every term that changes the wheel
loads is one: the rear loads are the weight less the front pin's reading, F_z,rear = (m + Δm) g − F_zf
(:func:`~.features.wheel_loads`), so a mass the vehicle file lacks (``mass``) changes them as an
axle-load offset does, and with them the adhesion μ = F_x/F_z and the loaded radius (paper eq. 9) the
slip is formed with.  Without ``mass`` here a fitted mass left the slip channel with rear loads short by
Δm g, and the rolling-radius error beside it took up the difference.  A GNSS latency and a CAN clock that
runs ahead of GNSS time (``clock_skew``) both move the GNSS-fitted speed the slip is formed with against
the CAN wheel speeds; a clock ahead is a GNSS *lead*, which no latency τ ≥ 0 describes."""


class SlipChannel(Channel):
    """Per-wheel slip against the slip the μ(s) curve needs for the measured adhesion.

    Slip carries the noise (the ground speed's), adhesion from the torque
    balance is precise, so the curve is inverted, s = g⁻¹(μ/a), and the
    residual is taken in measured slip, where its scale does not depend on
    the candidate:

        e_i = (s_i − ŝ_i) r_nom,i |ω_i|,   s_i = 1 − v_ref/(r_nom,i ω_i)   (nominal radius and speed),
        ŝ_i = 1 − (v_ref/v_ref') (r_i / r_nom,i) (1 − s_i'),
        s_i' = s_dyn + (σ/|v|) ṡ_dyn,   s_dyn = g⁻¹(μ_i / a_cell),

    where r_i, v_ref', μ_i are the radius, ground speed and adhesion the
    candidate implies and the relaxation term (inverse of ds_dyn/dt =
    (|v|/σ)(s − s_dyn)) is present only for the relaxation candidate.
    The nuisance is the surface class (shape) and a per field cell.  The
    factor r_nom|ω| turns the slip error into the ground-speed error [m/s]
    that causes it, so slow and fast driving weigh alike.
    """

    def __init__(self, feat: Features, wc: _WheelCache):
        fr = feat.frame
        self.feat, self.wc = feat, wc
        ws = wc.get({}, with_slip=True)
        ok = (feat.valid[:, None] & (np.abs(feat.v_ref)[:, None] > SLIP_MIN_SPEED) & np.isfinite(ws.slip)
              & np.isfinite(ws.mu) & (np.abs(ws.slip) < 0.5))
        ti, wi = np.nonzero(ok)
        super().__init__("slip", "m/s", "per-wheel slip against the slip the μ(s) curve needs",
                         SLIP_EFFECTS,
                         fr.t[ti], ti, _fold_of(feat, ti),
                         "soil class shape and curve parameter a per field cell and axle")
        self.ti, self.wi = ti, wi.astype(np.int8)
        # a per field cell *and axle*: the rear wheels run in the front wheels' ruts (multi-pass
        # soil) and carry another load, and real tyre–soil traction depends on both, so the axles'
        # adhesion levels differ on a healthy machine.  (A per-axle torque gain is therefore tested
        # by the force balance of the speed channels, not by the level of μ.)
        self.cell = (feat.cell[ti] * 2 + (wi >= 2)).astype(np.int32)
        self.ncell = feat.n_cells * 2
        self.soil: SoilClass = SOIL_CLASSES["stubble"]
        self.a_cell = np.full(self.ncell, np.nan)
        self.mu0 = np.zeros(2)
        # The slip of eq. 6 is positive where a wheel drives, forwards and in reverse; the adhesion from the
        # torque balance carries the force's sign.  The curve relates the slip to the adhesion along the
        # wheel's rotation, sgn ω · μ, where a tyre's zero-slip traction ratio μ_0 (a rolling loss) keeps its
        # sign and a torque sensor's offset turns with the travel.  None: every row forwards.
        sg = np.where(fr.omega[ti, wi] < 0.0, -1.0, 1.0)
        self.sg = sg if (sg < 0.0).any() else None
        self.y = ws.slip[ti, wi]
        self.r_nom = ws.r[ti, wi]
        self.wv = ws.r[ti, wi] * np.abs(fr.omega[ti, wi])
        self.v0 = feat.v_ref[ti]
        self.inv = {name: _CurveInverse(c) for name, c in SOIL_CLASSES.items()}
        self._frozen = False

    def freeze(self, on: bool) -> None:
        self._frozen = on

    def _inputs(self, eff: Effects) -> tuple[NDArray, NDArray, NDArray | None]:
        """(adhesion along the wheel's rotation sgn ω · μ, slip-scale factor k with ŝ = 1 − k (1 − s'),
        sgn ω · μ̇·σ/|v| or None) on all rows."""
        ws = self.wc.get(eff)
        mu_full = ws.mu
        mu = mu_full[self.ti, self.wi]
        if self.sg is not None:
            mu = mu * self.sg
        k = ws.r[self.ti, self.wi] / self.r_nom
        if "gps_latency" in eff or "clock_skew" in eff:
            k = k * self.v0 / self.wc.v_ref(eff)[self.ti]
        lead = None
        if "relaxation" in eff:
            mu_dot = self._mu_dot(ws, eff)[self.ti, self.wi]
            lam = fx.relaxation_rate(1.0, 0.0, self.wc.v_ref(eff)[self.ti], eff["relaxation"]["sigma_m"])
            lead = mu_dot / lam if self.sg is None else self.sg * mu_dot / lam
        return mu, k, lead

    def _mu_dot(self, ws: WheelState, eff: Effects) -> NDArray:
        """dμ/dt averaged over each bin [1/s]: difference of μ at the bin edges.

        At an edge, μ = (M_edge − J (ω̄_k − ω̄_{k−1})/Δ)/(r F_z) − ρ_t sgn ω (M_edge the wheel torque of the
        effects in ``eff``, as the bin means: a torque sensor's gain and offset, a fitted drivetrain or the
        declared reduction, :func:`~.features.wheel_torque`) with the torque sampled at the edge and the wheel
        acceleration from the bin means on either side; without edge data, the central difference of the bin
        means.
        """
        fr = self.feat.frame
        if fr.md_edge is None:
            return np.gradient(np.nan_to_num(ws.mu), fr.dt, axis=0)
        veh = fr.vehicle
        om = np.nan_to_num(fr.omega)
        wd = np.zeros_like(fr.md_edge)
        wd[1:-1] = np.diff(om, axis=0) / fr.dt
        rf = ws.r * ws.fz
        rf_e = np.concatenate([rf[:1], 0.5 * (rf[1:] + rf[:-1]), rf[-1:]])
        sg = np.sign(np.concatenate([om[:1], om]))
        kw = wheel_kwargs(eff, fr)
        md_e = wheel_torque(np.nan_to_num(fr.md_edge), np.concatenate([om[:1], om]), veh,
                            **{k: kw[k] for k in ("eta", "loss_nm", "gain", "offset_nm") if k in kw})
        mu_e = (md_e - veh.wheel_inertia_kgm2 * wd) / rf_e - veh.rho_t * sg
        return np.diff(mu_e, axis=0) / fr.dt

    def _predict(self, inv: _CurveInverse, mu: NDArray, k: NDArray, lead: NDArray | None, a: NDArray) -> NDArray:
        s_dyn = inv(mu / a)
        if lead is not None:
            s_dyn = s_dyn + lead / (a * np.maximum(inv.cls.dg(s_dyn), 1e-3))
        return 1.0 - k * (1.0 - s_dyn)

    def _grid_a(self, inv: _CurveInverse, mu, k, lead, y, wv, cell) -> NDArray:
        """a per cell by a grid search with parabolic refinement."""
        nc = self.ncell
        sse = np.empty((A_GRID.size, nc))
        for j, a in enumerate(A_GRID):
            e = (y - self._predict(inv, mu, k, lead, a)) * wv
            sse[j] = np.bincount(cell, weights=e * e, minlength=nc)
        jb = np.argmin(sse, axis=0)
        cidx = np.arange(nc)
        s0 = sse[np.clip(jb - 1, 0, None), cidx]
        s1 = sse[jb, cidx]
        s2 = sse[np.clip(jb + 1, None, A_GRID.size - 1), cidx]
        den = s0 - 2 * s1 + s2
        inner = (jb > 0) & (jb < A_GRID.size - 1)
        with np.errstate(invalid="ignore", divide="ignore"):
            off = np.where(inner & (den > 0), 0.5 * (s0 - s2) / den, 0.0)
        return A_GRID[jb] + np.clip(off, -0.5, 0.5) * (A_GRID[1] - A_GRID[0])

    def _gauss_newton_a(self, inv: _CurveInverse, mu, k, lead, y, wv, cell, a0: NDArray, iters: int = 6,
                        mu0: NDArray | None = None) -> tuple[NDArray, NDArray]:
        """Refine a per cell and the zero-slip traction ratio μ_0 per axle (nominal model, module
        :data:`MU0_RANGE`) by Gauss–Newton steps on the sum of squares: s_dyn = g⁻¹((μ − μ_0)/a)."""
        a = a0.copy()
        m0 = np.zeros(2) if mu0 is None else mu0.copy()
        nc = self.ncell
        axle = cell % 2
        for _ in range(iters):
            ac = a[cell]
            q = mu - m0[axle]
            s_dyn = inv(q / ac)
            dg = np.maximum(inv.cls.dg(s_dyn), 1e-3)
            ds = -(q / (ac * ac)) / dg
            dm = -1.0 / (ac * dg)
            sp = s_dyn
            if lead is not None:
                sp = s_dyn + lead / (ac * dg)
                ds = ds - lead / (ac * ac * dg)
            e = (y - (1.0 - k * (1.0 - sp))) * wv
            Ja = -k * ds * wv
            Jm = -k * dm * wv
            D = np.bincount(cell, weights=Ja * Ja, minlength=nc)
            B = np.bincount(cell, weights=Ja * Jm, minlength=nc)
            ga = np.bincount(cell, weights=Ja * e, minlength=nc)
            if not MU0_NOMINAL:
                step = np.where(D > 0, ga / np.where(D > 0, D, 1.0), 0.0)
                a = np.clip(a - step, A_GRID[0] * 0.5, A_GRID[-1] * 1.5)
                continue
            E = np.bincount(axle, weights=Jm * Jm, minlength=2)
            gm = np.bincount(axle, weights=Jm * e, minlength=2)
            # Normal equations [[diag D, B·1_axle], [(B·1_axle)ᵀ, diag E]] [Δa; Δμ_0] = [ga; gm], by the
            # Schur complement on the two axle offsets (each cell belongs to one axle).
            Dp = np.where(D > 0, D, 1.0)
            ax_c = np.arange(nc) % 2
            S = E - np.bincount(ax_c, weights=B * B / Dp, minlength=2)
            rhs = gm - np.bincount(ax_c, weights=B * ga / Dp, minlength=2)
            dmu = np.where(S > 1e-12 * np.maximum(E, 1e-300), rhs / np.where(S > 0, S, 1.0), 0.0)
            # A projected step: μ_0 stays in its range, and a takes the step that is optimal for the
            # change of μ_0 actually made.
            m_new = np.clip(m0 - dmu, MU0_RANGE[0], MU0_RANGE[1])
            dmu = m0 - m_new
            m0 = m_new
            step = np.where(D > 0, (ga - B * dmu[ax_c]) / Dp, 0.0)
            a_new = np.clip(a - step, A_GRID[0] * 0.5, A_GRID[-1] * 1.5)
            # Size of the last step (a, and μ_0 on the scale of a: μ_0 ≈ a g'(0) Δs, g'(0) ≈ 10).
            self._gn_moved = float(max(np.max(np.abs(a_new - a), initial=0.0), 10.0 * np.max(np.abs(dmu))))
            a = a_new
        return a, m0

    def parts(self, eff: Effects, rows: NDArray[np.bool_]) -> tuple[NDArray, NDArray]:
        mu, k, lead = self._inputs(eff)
        mu, k, y, cell, wv = mu[rows], k[rows], self.y[rows], self.cell[rows], self.wv[rows]
        lead = lead[rows] if lead is not None else None
        if not hasattr(self, "_a_start"):
            m0, k0, _ = self._inputs({})
            self._a_start = {name: self._grid_a(inv, m0, k0, None, self.y, self.wv, self.cell)
                             for name, inv in self.inv.items()}
        best, best_sse = None, math.inf
        invs = {self.soil.name: self.inv[self.soil.name]} if self._frozen else self.inv
        if not hasattr(self, "_a_warm"):
            self._a_warm: dict[str, tuple[NDArray, NDArray]] = {}
        for name, inv in invs.items():
            # Warm start from the last solution of this class (successive calls of a fit differ a
            # little): three Gauss–Newton steps then reach what six reach from the grid start.  With
            # μ_0 fitted beside a, a warm start from a distant call (a grid point at the far end of a
            # fault's range, where μ_0 sat on a bound) does not converge in three steps: the cost then
            # depended on the order of the calls (a radius error of -0.015 was fitted as +0.004).  The
            # grid start is solved too when the warm steps have not settled (last step above
            # WARM_CONVERGED), and the better of the two kept.
            warm = self._a_warm.get(name)
            total = math.inf
            if warm is not None:
                self._gn_moved = math.inf
                a, m0 = self._gauss_newton_a(inv, mu, k, lead, y, wv, cell, warm[0], iters=3, mu0=warm[1])
                p = self._predict(inv, mu - m0[cell % 2], k, lead, a[cell])
                total = float(np.sum(((y - p) * wv) ** 2))
            if warm is None or (MU0_NOMINAL and self._gn_moved > WARM_CONVERGED):
                ac, mc = self._gauss_newton_a(inv, mu, k, lead, y, wv, cell, self._a_start[name])
                pc = self._predict(inv, mu - mc[cell % 2], k, lead, ac[cell])
                tc = float(np.sum(((y - pc) * wv) ** 2))
                if tc < total:
                    a, m0, p, total = ac, mc, pc, tc
            self._a_warm[name] = (a, m0)
            if total < best_sse:
                best, best_sse = p, total
                self.soil, self.a_cell, self.mu0 = inv.cls, a, m0
        return y * wv, best * wv

    def residual(self, eff: Effects, rows: NDArray[np.bool_]) -> NDArray:
        y, p = self.parts(eff, rows)
        return y - p


def release_memos(channels) -> None:
    """Drop what the channels keep only to spare recomputation (the wheel-state memo, the GNSS-speed
    spline factors, the wheel-force channel's g(s) tables): about 170 MB on a 4-hour recording, of no
    use once the fits are done.  The residuals stay what they were; a later call recomputes."""
    for ch in channels:
        wc = getattr(ch, "wc", None)
        if wc is not None:
            wc._cache.clear()
            wc._bytes = 0
        for memo in ("_qr", "_g_plain"):
            m = getattr(ch, memo, None)
            if isinstance(m, dict):
                m.clear()


def build_channels(feat: Features) -> list[Channel]:
    """Every channel the frame's signals support."""
    fr = feat.frame
    out: list[Channel] = []
    wc = _WheelCache(feat)
    wheels = fr.has("omega", "md", "fzf")
    # Without a draft signal the pull is unknown: the speed equation, the force-integrated speed and the
    # front-axle load's transfer would each take it up as a fault (a healthy hub tractor whose hitch status
    # was not logged was named "drivetrain η = 0.5" and "mass +2140 kg").
    pull = fr.fdx is not None
    if not pull and wheels:
        feat.notes.append("no draft signal: the pull is unknown, so the speed equation, the GNSS speed against the "
                          "force-integrated speed and the front-axle load are not tested; the slip is taken against "
                          "the GNSS speed's spline")
    if wheels and feat.v_gps is not None:
        if pull:
            out.append(SpeedChannel(feat, wc))
            out.append(GpsSpeedChannel(feat, wc))
        out.append(SlipChannel(feat, wc))
        if fr.hf_omega is not None:
            wf = WheelForceChannel(feat, wc)
            slip_ch = out[-1]
            slip_ch.residual({}, np.ones(slip_ch.m, dtype=bool))
            wf.use_class(slip_ch.soil)
            wf.share_rows(slip_ch)
            out.append(wf)
    if fr.has("fzf") and not fr.fzf_modelled and pull:
        out.append(FrontLoadChannel(feat))
    if fr.has("fdx") and fr.work is not None and (feat.segment >= 0).any():
        ch = DraftChannel(feat)
        if ch.m > 50:
            out.append(ch)
    return [c for c in out if c.m > 20]
