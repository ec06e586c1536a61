"""The estimator's step compiled over a block of steps, for batch replay (where latency does not matter).

:class:`CompiledLoop` runs :meth:`Estimator.step <.estimator.Estimator.step>` over the step arguments of a
whole block (arrays, one row per step) and returns the block's estimates as arrays.  What it compiles
(numba, :mod:`._loop_kernel`), in the step path's order and with its operations:

* the input holds and their rejection, the bus-rate trackers and the timeouts (:mod:`.rates`), the
  direction of travel and the GNSS course test, the curvature filter (:mod:`.kinematics`);
* Q (its rebuild, the torque and curvature terms), the prediction with its sub-steps (the compiled
  filter core :func:`._kernels.predict_model`), the first-order hold and the torque feed-forward;
* the measurement update of contiguous outputs (:func:`._kernels.update_block`), covariance
  matching's window, the divergence and dynamics monitors, the estimate's outputs
  (:func:`._kernels.estimate_outputs`), convergence with its hysteresis, standstill, the held values,
  the averaged slip's sums and candidate stretches, the status bits and the reported σ.

It returns to Python at the events that need Python objects, and calls the SAME objects the step path
calls (those of the :class:`~.estimator.Estimator` it was built from), so their results feed back
identically:

* the μ(s) curve's update (``curve_period_s``) only in part: the one-class update (the a sums and the shape
  identification's pairs) runs compiled inside the loop, by the function the step path's
  :class:`~.curve.CurveEstimator` calls (:func:`._curve_kernel.ce_update`, on that estimator's own arrays); Python
  finishes it at a soil segment's close and at the once-a-second span, soil match and fit, and makes the curve states
  on demand from the loop's records (:class:`_CurveStates`); a curve identification of another kind (several
  classes, a subclass) is updated in Python at every update.  The identified curve's slope when an averaged slip is
  weighed stays in Python;
* the radius calibration at GNSS epochs (:class:`~.calibration.RadiusCalibration`);
* the systematic uncertainty (:class:`~.uncertainty.SystematicUncertainty`) only with a declared pull-angle
  tolerance (else it is compiled, with covariance matching's ratio, the fuzzy supervisor's intensity (the
  centroid by the function :class:`~.supervisor.FuzzySupervisor` calls, :func:`._kernels.fuzzy_centroid`) and
  the rest of the adaptation period);
* the filter's initialisation (:meth:`Estimator._init_filter`), a prediction whose covariance needs
  the Cholesky repair, a non-finite prediction (:meth:`Estimator._recover`) and an update that the
  compiled block update leaves to the general path (a gated or non-finite component): these run on
  the estimator's own :class:`~.ukf.UnscentedFilter`, its state set from the compiled one and read back.

Coverage (:func:`supported`): the hub estimator (:class:`~.estimator.Estimator` itself) with numba on, on
a vehicle without the features a vehicle file switches on that it does not port (a tyre carcass, a
two-inertia hub; a declared hub efficiency and drag are ported).  Anything else (the machine-level
estimator, those features, numba off) is not covered: :func:`supported` says why, and batch replay runs
the step path's Python estimator instead.

Contract: every estimate column equal to the step path's to 1e-9 (``tests/estimation/test_compiled_loop.py``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import EstimatorError
from ..model.vehicle import JIT

__all__ = ["CompiledLoop", "supported"]

_OUT_NAMES = ("t", "rho_s", "v", "nis", "adapt", "sigma_rho_s")


def supported(est: Any) -> tuple[bool, str]:
    """(whether :class:`CompiledLoop` covers this estimator, why not)."""
    from .estimator import Estimator

    if not JIT:
        return False, "numba is off (TRACTIONECU_JIT=0 or not installed)"
    if type(est) is not Estimator:
        return False, f"{type(est).__name__} is not the hub estimator the compiled loop ports"
    if est.model.cx != 0.0 or getattr(est, "_cx", 0.0) != 0.0:
        return False, "the vehicle declares a tyre carcass (tyre_carcass_stiffness_npm)"
    if getattr(est, "_hub", None) is not None or getattr(est.model, "hub", None) is not None:
        return False, "the vehicle declares a two-inertia hub"
    if est.ukf is not None or est.counters["steps"]:
        return False, "the estimator has already been stepped (the compiled loop starts from a reset one)"
    return True, ""


def check_steps(vehicle: Any, seconds: float = 4.0, rate_hz: float = 100.0) -> list[tuple[float, dict, dict]]:
    """A short, deterministic drive of ``vehicle`` as step arguments (:meth:`CompiledLoop.self_check`): start from
    rest, 2.5 m/s with about 8 % slip, torques and draft that wobble, wheel speeds and torques every step, the
    axle loads at half the rate, the GNSS speed and course at 10 Hz, and one turn of the curvature."""
    r = float(vehicle.r0_m) * 0.97
    fzf = float(vehicle.static_front_load_n())
    m = float(vehicle.mass_kg)
    steps = []
    n = int(round(seconds * rate_hz))
    for k in range(n):
        t = 1000.0 + k / rate_hz
        v = min(2.5, 0.5 + 1.5 * k / rate_hz)
        w = v / r * (1.08 + 0.01 * math.sin(0.7 * k))
        turn = 0.01 * math.sin(0.02 * k)
        om = [w * (1.0 - turn), w * (1.0 + turn), w * (1.0 - turn) * 1.001, w * (1.0 + turn) * 0.999]
        md = [0.11 * m * 9.81 / 4.0 * r * (1.0 + 0.05 * math.sin(0.3 * k + j)) for j in range(4)]
        inputs: dict[str, Any] = {"Md": md}
        if k % 2 == 0:
            inputs["Fzf"] = fzf * (1.0 + 0.01 * math.sin(0.1 * k))
            inputs["Fdx"] = 0.05 * m * 9.81 * (1.0 + 0.1 * math.sin(0.05 * k))
        meas: dict[str, Any] = {"omega": om}
        if k % 10 == 9:
            meas["v"] = v * (1.0 + 0.002 * math.sin(1.3 * k))
            meas["course"] = 90.0 + 20.0 * math.sin(0.01 * k)
        steps.append((t, inputs, meas))
    return steps


_CHECKED: dict[str, tuple[bool, float]] = {}

CURVE_CACHE_MAX = 4096
"""Curves kept by :meth:`CompiledLoop.resolve_curves` for the versions it resolved (a block of 4096 steps has
about 400 at the curve's 10 Hz); past it the cache starts again."""


class _CurveStates:
    """The curve states of the compiled curve update, by version (``I[I_CS_VER]``), made on demand from its records
    (``CR``: Σ w μ̂, Σ w g(ŝ), class evidence, pairs used, snapshot of the shape information) by
    :meth:`CurveEstimator._state_of <.curve.CurveEstimator._state_of>`, the function that makes the step path's
    states; version 0 is the estimator's state when the loop began."""

    def __init__(self, first: Any, ce: Any) -> None:
        self.ce = ce
        self.CR = np.zeros((4096, 5))
        self.class_name = ce.classes[0].name
        self._cache: dict[int, Any] = {0: first}
        self._a0 = first.a
        self.infos: list[Any] = [ce._shape_info()]

    def grow(self) -> None:
        """Twice the records' room."""
        CR = np.zeros((2 * self.CR.shape[0], 5))
        CR[:self.CR.shape[0]] = self.CR
        self.CR = CR

    def record(self, I: np.ndarray, K: Any) -> int:
        """Record the curve estimator's state after an update finished in Python (a new snapshot of its shape
        information, which such an update changes); returns the new version."""
        from . import _curve_kernel as CK

        self.infos.append(self.ce._shape_info())
        I[K.I_CURVE_INFO] = len(self.infos) - 1
        v = int(I[K.I_CS_VER]) + 1
        C = self.ce._C
        self.CR[v] = (C[CK.C_NUM], C[CK.C_NUM + 1], C[CK.C_NUM + 2], C[CK.C_NUSED], I[K.I_CURVE_INFO])
        return v

    def a_of(self, v: int) -> float:
        """The state's a (:attr:`CurveState.a <.curve.CurveState.a>`: the fitted shape's on the shape path) without
        making the state."""
        if v == 0:
            return self._a0
        n, d, _, _, iv = self.CR[v].tolist()
        info = self.infos[int(iv)]
        if info is not None and info[1] is not None and info[1].shape_selected:
            return info[1].curve.a
        return n / d if d > 0 else math.nan

    def curve_of(self, v: int) -> Any:
        """The state's identified curve (:attr:`CurveState.curve <.curve.CurveState.curve>`), without making the
        state when it was not made."""
        cs = self._cache.get(v)
        if cs is not None:
            return cs.curve
        num, den, _, _, iv = self.CR[v].tolist()
        return self.ce._curve_of(num, den, self.infos[int(iv)])

    def __getitem__(self, v: int) -> Any:
        cs = self._cache.get(v)
        if cs is None:
            num, den, nll, nu, iv = self.CR[v].tolist()
            cs = self._cache[v] = self.ce._state_of([num], [den], [nll], int(nu), self.infos[int(iv)])
        return cs


class CompiledLoop:
    """The compiled step of ``est`` (module doc); ``est`` must be fresh (reset) and :func:`supported`.

    :meth:`step_block` takes the step arguments of a block (:meth:`block_inputs`) and returns its estimates
    as an array (columns ``_loop_kernel.OUT_*``); :meth:`arrays` turns that into the batch sink's arrays.
    ``est`` keeps serving as the home of the Python objects (curve, calibration, supervisor, uncertainty,
    the filter object of the general paths); its own step state is not kept up to date.
    """

    def __init__(self, est: Any) -> None:
        from . import _loop_kernel as K
        from .ukf import UnscentedFilter

        ok, why = supported(est)
        if not ok:
            raise ValueError(f"compiled loop: not supported: {why}")
        self.K = K
        self.est = est
        cfg = est.cfg
        self.cfg = cfg
        F = np.zeros(K.F_SIZE)
        I = np.zeros(K.I_SIZE, dtype=np.int64)
        o = K.F_OFF
        veh = est.vehicle
        const = {
            "c_max_gap": cfg.max_gap_s, "c_max_step": cfg.max_step_s, "c_standstill": cfg.standstill_speed_mps,
            "c_dir_min": cfg.direction_min_speed_mps, "c_gps_timeout": cfg.gps_timeout_s,
            "c_wabs": est._w_abs, "c_wrel": est._w_rel, "c_wq2": est._w_q2, "c_rv": est._r_v,
            "c_tqabs": est._tq_abs, "c_tqrel": est._tq_rel, "c_tqq2": est._tq_q2, "c_fzvar": est._fz_var,
            "c_fdvar": est._fd_var, "c_weight": est._weight, "c_J": est.J, "c_m": est.m, "c_hb": est._hb,
            "c_wb": veh.wheelbase_m, "c_rho_t": veh.rho_t, "c_gate": est._gate,
            "c_cmu": cfg.conv_sigma_mu ** 2, "c_crho": cfg.conv_sigma_rho ** 2,
            "c_exit2": cfg.conv_exit_factor * cfg.conv_exit_factor, "c_conv_min": cfg.conv_min_s,
            "c_curve_period": cfg.curve_period_s, "c_curve_minspd": cfg.curve_min_speed_mps,
            "c_slip_max": cfg.slip_sigma_max, "c_avg_max": cfg.slip_avg_max_m, "c_avg_corr": cfg.slip_avg_corr_s,
            "c_adapt_period": cfg.adapt_period_s, "c_dyn_tau": est._dyn.tau,
            "c_lost_after": est._monitor.lost_after_s, "c_mon_rho_max": est._monitor.rho_max,
            "c_mon_minspd": est._monitor.min_speed, "c_rate_k": est._rates.k,
            "c_rate_maxint": next(iter(est._rates.trackers.values())).max_interval_s,
            "c_kin_b": est._kin.b, "c_kin_csig": est._kin.course_sigma, "c_kin_minspd": est._kin.min_speed,
            "c_kin_varbeta": est._kin.var_beta, "c_tanpull": est.model.tan_pull, "c_eta": est._eta,
            "c_drag": est._drag, "c_track": veh.track_width_m, "c_two": 2.0,
        }
        fz = est._fuzzy
        const.update({"c_a_min": est._cm.a_min, "c_a_max": est._cm.a_max})
        for name, val in const.items():
            F[o[name]] = val
        fc = fz.cfg
        F[o["c_fz"]:o["c_fz"] + 8] = [fc.accel_low_mps2, fc.accel_mid_mps2, fc.accel_high_mps2,
                                      fc.torque_rate_low_nmps, fc.torque_rate_mid_nmps, fc.torque_rate_high_nmps,
                                      fc.factor_min, fz._log_ratio]
        unc = est._unc
        if unc is not None:
            F[o["c_unc"]:o["c_unc"] + 12] = [unc.u_g, unc.u_eta, unc.tan_pull, unc.u_tan, unc.u_m0, unc.u_a0,
                                              unc.u_ag, unc.u_d0, unc.u_dg, unc.lat2_3, unc.weight, unc.mg]
        F[o["c_mon_bound"]:o["c_mon_bound"] + 9] = est._monitor._bound
        probe = UnscentedFilter(est.model.step, np.zeros(10), np.eye(10), range(5), alpha=cfg.alpha, beta=cfg.beta,
                                kappa=cfg.kappa)
        F[o["c_w"]:o["c_w"] + 43] = probe._w
        F[o["c_kc"]:o["c_kc"] + 18] = est.model._kc
        F[o["c_lo"]:o["c_lo"] + 10] = est._lo
        F[o["c_hi"]:o["c_hi"] + 10] = est._hi
        F[o["c_qtune"]:o["c_qtune"] + 10] = est._q_tune
        # the reset estimator's state
        F[o["u"]:o["u"] + 7] = est._u
        F[o["A"]:o["A"] + 10] = est._A
        scal = {"t": math.nan, "t_init": math.nan, "kapvar": est._kappa_var, "md_sum": est._md_sum,
                "t_omega": est._t_omega, "t_v": est._t_v, "t_upd_w": est._t_upd_w, "t_upd_v": est._t_upd_v,
                "last_vmeas": math.nan, "dir": est._dir, "dir_bus": est._dir_bus, "t_dir_bus": est._t_dir_bus,
                "f": est._f, "Qdt": est._Qdt, "tq_gain": est._tq_gain, "adapt_mu": est._adapt_mu,
                "t_adapt": est._t_adapt, "t_curve": est._t_curve, "r_lat": est._r_lat, "kf": est._kf,
                "kr": est._kr, "last_nis": math.nan}
        for name, val in scal.items():
            F[o[name]] = val
        F[o["tin"]:o["tin"] + 3] = [est._t_in[key] for key in ("Md", "Fzf", "Fdx")]
        F[o["dm_var"]:o["dm_var"] + 4] = est._dm_var
        F[o["rad"]:o["rad"] + 6] = np.concatenate(est._rad)
        dyn = est._dyn
        F[o["dyn"]:o["dyn"] + 7] = [0.0, dyn._v, dyn._m, dyn.accel, dyn.torque_rate, dyn._dt, dyn._k]
        F[o["mon"]:o["mon"] + 4] = math.nan
        kin = est._kin
        F[o["kin"]:o["kin"] + 12] = [kin.h, kin.P[0], kin.P[1], kin.P[2], kin.beta, kin.kappa_w, kin.var_w,
                                     kin._k_raw, kin._var_raw, kin.v, kin._t, kin._tw]
        keys = ("Md", "Fzf", "Fdx", "omega", "v")
        for j, key in enumerate(keys):
            tr = est._rates.trackers[key]
            F[o["rates"] + 6 * j:o["rates"] + 6 * j + 6] = [tr.period, tr._last, tr._gap_s, tr.nominal_s,
                                                              est._rates.floors_s[key], est._rates.timeout_s[key]]
        io = K.I_OFF
        I[io["cm_M"]] = cfg.adapt_window
        I[io["r_window"]] = cfg.rate_window
        I[io["f_cal"]] = est._cal is not None
        if est._cal is not None:
            cc = est._cal.cfg
            F[o["c_cal"]:o["c_cal"] + 4] = [cc.min_speed_mps, cc.max_accel_mps2, cc.max_turn_rel, cc.max_mu]
            F[o["cal"]:o["cal"] + 3] = [est._cal._period, est._cal._t_last, 0.0]
            I[io["cal_open"]] = est._cal._blk[4] != 0
        I[io["f_adapt"]] = bool(cfg.adaptation)
        I[io["f_input_noise"]] = bool(cfg.input_noise)
        I[io["f_sup"]] = bool(cfg.supervisor)
        I[io["sm_on"]] = bool(est._smooth)          # each row carries its transition (Estimate.transition)
        self._n_out = K.N_OUT_SM if est._smooth else K.N_OUT
        # the systematic uncertainty compiled, or (with a pull-angle tolerance: math.hypot) in Python
        I[io["f_unc"]] = 0 if unc is None else (2 if unc.u_tan != 0.0 else 1)
        from .supervisor import RULES

        I[io["fz_rules"]:io["fz_rules"] + 9] = np.asarray(RULES, dtype=np.int64).ravel()
        self.F, self.I = F, I
        self.CM = np.zeros((2 * cfg.adapt_window, 10))
        self.RB = np.zeros((10, cfg.rate_window))
        self.WIN = np.zeros((16384, 19))
        self.EV = np.zeros(1 + 16 * K.N_CAND_COLS)
        # the curve update compiled in the loop (_curve_kernel.ce_update, the step path's own) where the estimator's
        # curve identification is the plain one-class CurveEstimator; its states are then made on demand from the
        # loop's records (_CurveStates), else they are the Python update's (a list)
        from .curve import CurveEstimator

        ce = est._curve
        self._jit = type(ce) is CurveEstimator and len(ce.classes) == 1
        self.states: Any = _CurveStates(est._curve_state, ce) if self._jit else [est._curve_state]
        I[io["curve_jit"]] = int(self._jit)
        I[io["curve_shape"]] = int(ce.shape is not None)
        self._cv = self._curve_arrays()
        self._fz = est._fuzzy.centroid_table
        self._curves: dict[int, tuple[Any, str]] = {}
        self._cal_blocks = 0
        self._radius_sigma()
        self._handlers = {K.EV_INIT: self._ev_init, K.EV_PREDICT: self._ev_predict, K.EV_RECOVER: self._ev_recover,
                          K.EV_UPDATE: self._ev_update,
                          K.EV_SYSTEMATIC: self._ev_systematic, K.EV_CURVE: self._ev_curve,
                          K.EV_SLIPWIN: self._ev_slipwin, K.EV_CAL: self._ev_cal, K.EV_WINFULL: self._ev_winfull,
                          K.EV_HASCURVE: self._ev_hascurve, K.EV_CURVEJ: self._ev_curvefit}
        self._ev_names = {K.EV_INIT: "init", K.EV_PREDICT: "predict", K.EV_RECOVER: "recover", K.EV_UPDATE: "update",
                          K.EV_SYSTEMATIC: "systematic", K.EV_CURVE: "curve",
                          K.EV_SLIPWIN: "slipwin", K.EV_CAL: "cal", K.EV_WINFULL: "winfull",
                          K.EV_HASCURVE: "hascurve", K.EV_CURVEJ: "curvefit"}
        self.events = {name: 0 for name in self._ev_names.values()}
        """Returns to Python per event (module doc)."""
        # views of the state (numpy views into F: written by the compiled code, read here)
        self._x = F[o["x"]:o["x"] + 10]
        self._P = F[o["P"]:o["P"] + 100].reshape(10, 10)
        self._u = F[o["u"]:o["u"] + 7]

    # ------------------------------------------------------------------ inputs
    @staticmethod
    def block_inputs(t: np.ndarray, streams: list[tuple[str, bool, Any, list[bool]]]) -> np.ndarray:
        """The step arguments of a block as one array (n, N_IN) from replay's streams (key, is_input, values,
        new): a stream's columns are filled where it has a new sample (its flag column 1), else the flag is 0."""
        from . import _loop_kernel as K

        n = t.size
        IN = np.zeros((n, K.N_IN))
        IN[:, K.IN_T] = t
        cols = {"Md": (K.IN_HMD, K.IN_MD, 4), "Fzf": (K.IN_HFZF, K.IN_FZF, 1), "Fdx": (K.IN_HFDX, K.IN_FDX, 1),
                "omega": (K.IN_HOM, K.IN_OM, 4), "dir": (K.IN_HDIR, K.IN_DIR, 1), "v": (K.IN_HV, K.IN_V, 1),
                "course": (K.IN_HCRS, K.IN_CRS, 1)}
        for key, _is_input, vals, new in streams:
            spec = cols.get(key)
            if spec is None:
                raise ValueError(f"compiled loop: unknown step argument {key!r}")
            h, c, m = spec
            nw = np.asarray(new, dtype=bool)
            if not nw.any():
                continue
            IN[:, h] = nw
            if m == 4:
                np.copyto(IN[:, c:c + 4], np.asarray(vals, dtype=float), where=nw[:, None])
            else:
                np.copyto(IN[:, c], np.asarray(vals, dtype=float), where=nw)
        return IN

    @classmethod
    def inputs_from_steps(cls, steps: list[tuple[float, dict[str, Any], dict[str, Any]]]) -> np.ndarray:
        """:meth:`block_inputs` of steps given as the step path's arguments ``(t, inputs, measurements)``."""
        keys = ("Md", "Fzf", "Fdx", "omega", "dir", "v", "course")
        t = np.array([float(s[0]) for s in steps])
        streams = []
        for key in keys:
            new = [key in (s[1] if key in ("Md", "Fzf", "Fdx") else s[2]) for s in steps]
            m = 4 if key in ("Md", "omega") else 1
            vals = np.full((len(steps), m), np.nan)
            for i, s in enumerate(steps):
                d = s[1] if key in ("Md", "Fzf", "Fdx") else s[2]
                if key in d:
                    vals[i] = np.asarray(d[key], dtype=float)
            streams.append((key, False, vals if m == 4 else vals[:, 0], new))
        return cls.block_inputs(t, streams)

    @staticmethod
    def self_check(est: Any, tol: float = 1e-9) -> tuple[bool, float]:
        """(equal, largest difference): a fresh Python estimator and a fresh compiled loop of ``est``'s vehicle,
        configuration and sensors stepped over :func:`check_steps`, every estimate column compared (status
        exactly).  Batch replay runs it once per machine and process before it trusts the compiled loop, so a
        feature of the step path that the loop does not port (one a future vehicle file switches on) makes
        batch replay fall back and say so instead of differing."""
        from .estimator import Estimator

        key = repr((est.vehicle, est.cfg, est.sensors))
        hit = _CHECKED.get(key)
        if hit is not None:
            return hit
        steps = check_steps(est.vehicle)
        py = Estimator(est.vehicle, est.cfg, est.sensors)
        loop = CompiledLoop(Estimator(est.vehicle, est.cfg, est.sensors))
        K = loop.K
        out = loop.step_block(loop.inputs_from_steps(steps))
        worst = 0.0
        for k, (t, inputs, meas) in enumerate(steps):
            e = py.step(t, inputs, meas)
            row = out[k]
            if row[K.OUT_STATUS] != e.status:
                worst = math.inf
                break
            for col, val in ((K.OUT_MU, e.mu), (K.OUT_SLIP, e.slip), (K.OUT_OM, e.omega), (K.OUT_P, e.P_diag),
                             (K.OUT_SIGMU, e.sigma_mu)):
                got = row[col:col + len(val)]
                if not np.array_equal(np.isnan(got), np.isnan(val)):
                    worst = math.inf
                    break
                d = np.abs(got - val)
                d = d[~np.isnan(d)]
                if d.size:
                    worst = max(worst, float(d.max()))
            for col, x in ((K.OUT_RHO, e.rho_s), (K.OUT_V, e.v), (K.OUT_ADAPT, e.adapt)):
                if not (row[col] == x or (math.isnan(row[col]) and math.isnan(x))):
                    worst = max(worst, abs(float(row[col]) - float(x)))
            if loop._n_out == K.N_OUT_SM:      # the smoother's transitions
                tr = e.transition
                link = row[K.OUT_SM_LINK]
                if tr is None:
                    if link == link:
                        worst = math.inf
                    continue
                if link != (1.0 if tr[0] else 0.0):
                    worst = math.inf
                    break
                parts = [(K.OUT_SM_XF, tr[1])]
                if tr[0]:
                    parts += [(K.OUT_SM_XP, tr[2]), (K.OUT_SM_G, tr[3].ravel())]
                for col, val in parts:
                    d = np.abs(row[col:col + val.size] - val)
                    worst = max(worst, float(d.max()) if np.isfinite(d).all() else math.inf)
        res = (worst <= tol, worst)
        _CHECKED[key] = res
        return res

    # ------------------------------------------------------------------ the loop
    def step_block(self, IN: np.ndarray) -> np.ndarray:
        """Step every row of ``IN`` (:meth:`block_inputs`); the estimates (n, N_OUT)."""
        K = self.K
        n = IN.shape[0]
        OUT = np.empty((n, self._n_out))
        I = self.I
        I[K.I_K] = 0
        I[K.I_STAGE] = K.ST_BEGIN
        run = K.run
        F, EV, CM, RB = self.F, self.EV, self.CM, self.RB
        handlers, names, events = self._handlers, self._ev_names, self.events
        while True:
            ev = run(F, I, IN, OUT, EV, CM, RB, self.WIN, n, self._cv, self._fz)
            if ev == K.EV_DONE:
                self._cal_sync()
                return OUT
            events[names[ev]] += 1
            handlers[ev](IN, OUT)

    @property
    def counters(self) -> dict[str, int]:
        """The estimator's counters (Estimator.counters)."""
        K = self.K
        out = {name: int(self.I[K.I_COUNTERS + j]) for j, name in enumerate(K.COUNTERS)}
        out["chol_repairs"] = int(self.I[K.I_CHOL_REPAIRS])
        # a replay grid's times are finite and increasing, one step each
        out["rejected_times"] = out["time_backwards"] = out["repeated_measurements"] = 0
        return out

    def arrays(self, OUT: np.ndarray) -> dict[str, Any]:
        """The batch sink's arrays of a block (:class:`~tractionecu.pipeline.batch.BatchSink`), with ``lost_since``
        and, for ``curve`` and ``curve_path``, ``curve_key`` (:meth:`resolve_curves`)."""
        K = self.K
        n = OUT.shape[0]
        # the columns are views of OUT (a fresh array per block, written by nobody after): the sink copies what it
        # keeps (its rows, its concatenation), so a copy here would be a second one
        arr: dict[str, Any] = {"t": OUT[:, K.OUT_T]}
        arr["rho_s"] = OUT[:, K.OUT_RHO]
        arr["v"] = OUT[:, K.OUT_V]
        arr["nis"] = OUT[:, K.OUT_NIS]
        arr["adapt"] = OUT[:, K.OUT_ADAPT]
        arr["nis_dof"] = OUT[:, K.OUT_DOF].astype(np.int64)
        arr["status"] = OUT[:, K.OUT_STATUS].astype(np.int64)
        arr["valid"] = OUT[:, K.OUT_VALID] != 0.0
        arr["mu"] = OUT[:, K.OUT_MU:K.OUT_MU + 4]
        arr["slip"] = OUT[:, K.OUT_SLIP:K.OUT_SLIP + 4]
        arr["omega"] = OUT[:, K.OUT_OM:K.OUT_OM + 4]
        arr["P_diag"] = OUT[:, K.OUT_P:K.OUT_P + 10]
        arr["radius_scale"] = OUT[:, K.OUT_RAD:K.OUT_RAD + 2]
        arr["radius_halfwidth"] = OUT[:, K.OUT_RAD + 2:K.OUT_RAD + 4]
        arr["radius_applied"] = OUT[:, K.OUT_RAD + 4:K.OUT_RAD + 6]
        arr["sigma_mu"] = OUT[:, K.OUT_SIGMU:K.OUT_SIGMU + 4]
        arr["sigma_rho_s"] = OUT[:, K.OUT_SIGRHO]
        ver = OUT[:, K.OUT_CS].astype(np.int64)
        hasx = OUT[:, K.OUT_HASX] != 0.0
        # the curve state each step reports (a and class; a only with a filter); the identified curve and
        # its path are left as the key of that state (curve_key) until resolve_curves: building a curve
        # costs, and a consumer of selected rows needs it for those rows only
        key = ver * 2 + hasx
        uniq, inv = np.unique(key, return_inverse=True)
        ents = []
        states = self.states
        if self._jit:                    # a and the class from the records, without making the states
            for kk in uniq.tolist():
                ents.append((states.a_of(kk // 2) if kk % 2 else math.nan, states.class_name))
        else:
            for kk in uniq.tolist():
                cs = states[kk // 2]
                ents.append((cs.a if kk % 2 else math.nan, cs.class_name))
        a_u = np.array([e[0] for e in ents] if n else [], dtype=float)
        arr["a"] = a_u[inv] if n else np.empty(0)
        names = np.empty(len(ents), dtype=object)
        names[:] = [e[1] for e in ents]
        arr["soil_class"] = names[inv].tolist()
        arr["curve_key"] = key
        arr["lost_since"] = OUT[:, K.OUT_LOST]
        if self._n_out == K.N_OUT_SM:          # the transitions, for the fixed-lag smoother (.smoother)
            arr["sm_link"] = OUT[:, K.OUT_SM_LINK] == 1.0
            arr["sm_xf"] = OUT[:, K.OUT_SM_XF:K.OUT_SM_XF + 10]
            arr["sm_xp"] = OUT[:, K.OUT_SM_XP:K.OUT_SM_XP + 10]
            arr["sm_G"] = OUT[:, K.OUT_SM_G:K.OUT_SM_G + 100].reshape(n, 10, 10)
        return arr

    def resolve_curves(self, arr: dict[str, Any]) -> dict[str, Any]:
        """Replace ``curve_key`` (:meth:`arrays`) in ``arr`` by ``curve`` (the identified μ(s) of each step, None
        without one or without a filter, as Estimate.curve) and ``curve_path``; returns ``arr``."""
        key = arr.pop("curve_key", None)
        if key is None:
            return arr
        cache = self._curves
        if len(cache) > CURVE_CACHE_MAX:
            # the versions of earlier blocks are seldom asked for again (a map's rows, once): a replay resolves
            # every row's, and the cache had kept one curve per version of the run (31 000 over a 1.04 h replay)
            cache.clear()
        uniq, inv = np.unique(np.asarray(key, dtype=np.int64), return_inverse=True)
        curves = np.empty(uniq.size, dtype=object)
        paths = np.empty(uniq.size, dtype=object)
        for j, kk in enumerate(uniq.tolist()):
            ent = cache.get(kk)
            if ent is None:
                v = kk // 2
                c = None if not kk % 2 else (self.states.curve_of(v) if self._jit else self.states[v].curve)
                ent = cache[kk] = (c, c.path if c is not None else "")
            curves[j] = ent[0]
            paths[j] = ent[1]
        arr["curve"] = curves[inv].tolist()
        arr["curve_path"] = paths[inv].tolist()
        return arr

    # ------------------------------------------------------------------ events
    def _sync_est(self) -> None:
        """The estimator's attributes its _init_filter reads, from the compiled state."""
        K, F, I, est = self.K, self.F, self.I, self.est
        est._u[:] = self._u
        est._last_v_meas = float(F[K.F_LAST_VMEAS]) if I[K.I_HAS_LASTV] else None
        est._t_v = float(F[K.F_T_V])

    def _new_filter(self, t: float) -> None:
        """The compiled state of a filter just made by Estimator._init_filter (its x, P and resets)."""
        K, F, I, est = self.K, self.F, self.I, self.est
        self._x[:] = est.ukf.x
        self._P[:, :] = est.ukf.P
        I[K.I_UKF] = 1
        F[K.F_T_INIT] = t
        I[K.I_CONV] = 0
        I[K.I_WIN_N] = 0
        I[K.I_WIN_LO] = 0
        F[K.F_MON:K.F_MON + 4] = math.nan
        I[K.I_GATE_RUN:K.I_GATE_RUN + 5] = 0
        I[K.I_GATE_RUN_ANY] = 0
        I[K.I_CHOL_REPAIRS] = 0
        I[K.I_LAST_DOF] = 0
        F[K.F_LAST_NIS] = math.nan

    def _ev_init(self, IN: np.ndarray, OUT: np.ndarray) -> None:
        K = self.K
        k = int(self.I[K.I_K])
        t = float(self.F[K.F_L_T])
        self._sync_est()
        self.est._init_filter(t, np.asarray(IN[k, K.IN_OM:K.IN_OM + 4], dtype=float))
        self._new_filter(t)

    def _shadow(self) -> Any:
        """The estimator's filter object with the compiled state."""
        K, I = self.K, self.I
        ukf = self.est.ukf
        ukf.x = self._x.copy()
        ukf.P = self._P.copy()
        ukf._gate_run[:] = I[K.I_GATE_RUN:K.I_GATE_RUN + 5]
        ukf._gate_run_any = bool(I[K.I_GATE_RUN_ANY])
        ukf.chol_repairs = int(I[K.I_CHOL_REPAIRS])
        return ukf

    def _ev_predict(self, IN: np.ndarray, OUT: np.ndarray) -> None:
        K, F, I = self.K, self.F, self.I
        ukf = self._shadow()
        h = float(F[K.F_L_H])
        o = K.F_Q if I[K.I_F_INPUT_NOISE] else K.F_QB
        Q = F[o:o + 100].reshape(10, 10).copy()
        try:
            ukf.predict(self._u.copy(), h, Q)
        except EstimatorError:
            self._ev_recover(IN, OUT)
            return
        self._x[:] = ukf.x
        self._P[:, :] = ukf.P
        I[K.I_REPAIRED_LAST] = 1 if ukf.repaired_last else 0
        I[K.I_CHOL_REPAIRS] = ukf.chol_repairs
        I[K.I_SUB] += 1
        I[K.I_STAGE] = K.ST_PREDICT

    def _ev_recover(self, IN: np.ndarray, OUT: np.ndarray) -> None:
        """Estimator._recover after a non-finite prediction (the sub-step loop ends)."""
        K, F, I, est = self.K, self.F, self.I, self.est
        t = float(F[K.F_L_T])
        I[K.I_COUNTERS + K.C_RESETS] += 1
        x = self._x.copy()
        if not np.isfinite(x).all():
            raise EstimatorError("compiled loop: non-finite filter mean and no finite one to restart from")
        self._sync_est()
        est.ukf = None
        est._init_filter(t, x[:4])
        est.ukf.x = x.copy()
        self._new_filter(t)
        I[K.I_STATUS] |= K.COV_REPAIRED
        I[K.I_REPAIRED_LAST] = 0
        I[K.I_STAGE] = K.ST_AFTER_PREDICT

    def _ev_update(self, IN: np.ndarray, OUT: np.ndarray) -> None:
        """ukf.update on the estimator's filter (the general path: gating, non-finite components)."""
        from .estimator import _SL_V, _SL_W, _SL_WV

        K, F, I = self.K, self.F, self.I
        ukf = self._shadow()
        kind = int(I[K.I_UPD_KIND])
        z = F[K.F_L_Z:K.F_L_Z + 5]
        R = F[K.F_L_R:K.F_L_R + 5]
        if kind == 3:
            ukf.update(np.array(z.tolist()), _SL_WV, np.array(R.tolist()))
        elif kind == 1:
            ukf.update(np.array(z[:4].tolist()), _SL_W, np.array(R[:4].tolist()))
        else:
            ukf.update(np.array([float(z[0])]), _SL_V, np.array([float(R[0])]))
        self._x[:] = ukf.x
        self._P[:, :] = ukf.P
        I[K.I_GATE_RUN:K.I_GATE_RUN + 5] = ukf._gate_run
        I[K.I_GATE_RUN_ANY] = 1 if ukf._gate_run_any else 0
        I[K.I_LAST_DOF] = ukf.last_dof
        F[K.F_LAST_NIS] = ukf.last_nis
        if ukf.last_dof and self.cfg.adaptation:
            dx, ksk = ukf.correction()
            F[K.F_DX:K.F_DX + 10] = dx
            F[K.F_KSK:K.F_KSK + 10] = ksk
        K.post_update(F, I, self.CM, int(ukf.last_gated), int(ukf.last_outside))

    def _radius_sigma(self) -> None:
        """The radius's standard uncertainty per axle the systematic uncertainty uses (Estimator._systematic);
        it changes only when the calibration accepts a block (RadiusCalibration.radius_sigma reads the axles'
        applied flag and half-width, which only a block changes)."""
        est = self.est
        unc = est._unc
        if unc is not None:
            ur = est._cal.radius_sigma(unc.u_r) if est._cal is not None else (unc.u_r, unc.u_r)
            self.F[self.K.F_UR:self.K.F_UR + 2] = ur

    def _ev_systematic(self, IN: np.ndarray, OUT: np.ndarray) -> None:
        """Estimator._systematic on the estimator's SystematicUncertainty (a declared pull-angle tolerance)."""
        K, F, I, est = self.K, self.F, self.I, self.est
        unc = est._unc
        pd = self._P.diagonal()[5:10]
        u = self._u
        _, _, rdf, rdr = est.model.load_floats(float(u[4]), float(u[5]))
        ur = est._cal.radius_sigma(unc.u_r) if est._cal is not None else (unc.u_r, unc.u_r)
        vm, vr = unc.variances(u[:4].tolist(), float(u[4]), float(u[5]), rdf * float(F[K.F_KF]),
                               rdr * float(F[K.F_KR]), *ur)
        vm.append(vr)
        sv = np.array(vm)
        if not np.isfinite(sv).all():
            sv[:] = 0.0
        F[K.F_SYS_VAR:K.F_SYS_VAR + 5] = sv
        I[K.I_HAS_SYS] = 1
        I[K.I_SYS_FLAG] = 1 if bool((sv > pd).any()) else 0
        F[K.F_R_LAT] = unc.gnss_latency_var(float(F[K.F_DYN + 3]))

    def _ev_curve(self, IN: np.ndarray, OUT: np.ndarray) -> None:
        """The μ(s) curve's update (Estimator._estimate), on the estimator's CurveEstimator."""
        K, F, I, est = self.K, self.F, self.I, self.est
        t = float(F[K.F_L_T])
        b = K.F_L_BUF
        # the wheel loads of the held F_zf, F_dx (FilterModel._load_terms' F_z, computed compiled with its operations)
        ff, fr = F[K.F_L_LOAD:K.F_L_LOAD + 2].tolist()
        fz = np.array([ff, ff, fr, fr])
        # μ, slip, σ_μ = √P_μμ and σ_s (computed compiled, as Estimator._estimate does) as fresh arrays
        ms = F[b:b + 8].copy()                     # μ, slip; then σ_μ, σ_s (adjacent in F)
        sg = F[K.F_L_SIG_MU:K.F_L_SIG_MU + 8].copy()
        cs = est._curve.update(t, ms[:4], ms[4:], sg[:4], sg[4:], fz)
        self.states.append(cs)
        I[K.I_CS_VER] = len(self.states) - 1
        I[K.I_HAS_CURVE] = -1            # asked for when an averaged slip needs it (CurveState.curve costs)

    def _curve_arrays(self) -> tuple[np.ndarray, ...]:
        """The compiled curve update's state (``_loop_kernel._curve_jit``'s CV): the estimator's CurveEstimator's
        and ShapeIdentifier's own arrays (placeholders without them) and the records."""
        ce = self.est._curve
        if not self._jit:
            z1, z2 = np.zeros(1), np.zeros((1, 1))
            return (z1, z1, np.zeros(1, dtype=np.int64), z2, z2, z2, z2, z2, z2, z2)
        sh = ce.shape
        if sh is None:
            from .curve import _NO_B, _NO_HP, _NO_HT, _NO_S, _NO_SI
            return (ce._C, _NO_S, _NO_SI, _NO_B, _NO_B, _NO_HT, _NO_HP, _NO_HP, ce._SC, self.states.CR)
        return (ce._C, sh._S, sh._SI, sh._B, sh._MT, sh._HT, sh._HP, sh._PD, sh._SC, self.states.CR)

    def _ev_curvefit(self, IN: np.ndarray, OUT: np.ndarray) -> None:
        """The compiled curve update's Python part (``_loop_kernel._curve_jit``): a soil segment's close and the
        once-a-second span and fit (ShapeIdentifier._after), or, when the history or the records were full (nothing
        done), more room and the whole update by CurveEstimator.update; then the new version's record."""
        K, F, I, est = self.K, self.F, self.I, self.est
        from . import _curve_kernel as CK

        ce = est._curve
        r = int(I[K.I_CURVE_R])
        t = float(F[K.F_L_T])
        states = self.states
        if r == K.CURVE_REC_FULL or r == CK.GROW:
            if r == K.CURVE_REC_FULL:
                states.grow()
            b = K.F_L_BUF
            ff, fr = F[K.F_L_LOAD:K.F_L_LOAD + 2].tolist()
            ms = F[b:b + 8].copy()
            sg = F[K.F_L_SIG_MU:K.F_L_SIG_MU + 8].copy()
            ce.update(t, ms[:4], ms[4:], sg[:4], sg[4:], np.array([ff, ff, fr, fr]))
        else:
            ce.shape._after(r, t)
        v = states.record(I, K)
        I[K.I_CS_VER] = v
        I[K.I_HAS_CURVE] = -1
        self._cv = self._curve_arrays()

    def _ev_hascurve(self, IN: np.ndarray, OUT: np.ndarray) -> None:
        """Whether the current curve state has an identified curve (the averaged slip needs one)."""
        K, I = self.K, self.I
        I[K.I_HAS_CURVE] = 1 if self.states[int(I[K.I_CS_VER])].curve is not None else 0

    def _ev_slipwin(self, IN: np.ndarray, OUT: np.ndarray) -> None:
        """The averaged slip (Estimator._slip_window): the identified curve's |dμ/ds| at every candidate stretch's
        slips, in one dmu_ds call (elementwise the values of one call per stretch); the compiled loop chooses."""
        K, I = self.K, self.I
        curve = self.states[int(I[K.I_CS_VER])].curve
        nc = int(I[K.I_N_CAND])
        cand = self.EV[1:1 + nc * K.N_CAND_COLS].reshape(nc, K.N_CAND_COLS)
        cand[:, 13:17] = np.abs(curve.dmu_ds(np.abs(cand[:, :4])))

    def _ev_cal(self, IN: np.ndarray, OUT: np.ndarray) -> None:
        """Estimator._calibrate: one GNSS epoch to the radius calibration; a new scale applied."""
        K, F, I, est = self.K, self.F, self.I, self.est
        k = int(I[K.I_K])
        t = float(F[K.F_L_T])
        cal = est._cal
        u = self._u
        rdf, rdr = F[K.F_L_LOAD + 2:K.F_L_LOAD + 4].tolist()      # FilterModel.load_floats' r_d, computed compiled
        cs = self.states[int(I[K.I_CS_VER])]
        v_meas = float(F[K.F_L_VMEAS])
        wl = F[K.F_L_WL:K.F_L_WL + 4].tolist()
        if I[K.I_UPD_KIND] == 3:
            wl.append(v_meas)
        row = OUT[k]
        self._cal_sync()
        cal.push(t, v_meas, wl, rdf, rdr, row[K.OUT_MU:K.OUT_MU + 4].tolist(), float(F[K.F_DYN + 3]),
                 bool(row[K.OUT_VALID] != 0.0), cs.a, cs.class_name)
        F[K.F_CAL:K.F_CAL + 2] = [cal._period, cal._t_last]
        I[K.I_CAL_OPEN] = cal._blk[4] != 0
        n = cal._axles[0].n
        if n != self._cal_blocks:            # a block was accepted: the scales, and the radius's σ, may change
            self._cal_blocks = n
            self._radius_sigma()
            f, r = cal.state()
            kf, kr = cal.applied
            F[K.F_RAD:K.F_RAD + 6] = [f.scale, r.scale, f.halfwidth, r.halfwidth, kf, kr]
            if kf != F[K.F_KF] or kr != F[K.F_KR]:
                new_inv = np.array([1.0 / kf, 1.0 / kf, 1.0 / kr, 1.0 / kr])
                old_inv = F[K.F_MD_INV:K.F_MD_INV + 4].copy() if I[K.I_HAS_MDINV] else np.ones(4)
                u[:4] *= new_inv / old_inv
                F[K.F_MD_INV:K.F_MD_INV + 4] = new_inv
                I[K.I_HAS_MDINV] = 1
                F[K.F_KF] = kf
                F[K.F_KR] = kr

    def _cal_sync(self) -> None:
        """The radius calibration's state after the epochs the compiled loop screened and it rejects while no
        block is open (its epoch period, last epoch's time and count of rejections; ``_loop_kernel._cal_rejects``)."""
        cal = self.est._cal
        if cal is None:
            return
        K, F = self.K, self.F
        cal._period, cal._t_last, pending = F[K.F_CAL:K.F_CAL + 3].tolist()
        if pending:
            cal.rejected += int(pending)
            F[K.F_CAL + 2] = 0.0

    def _ev_winfull(self, IN: np.ndarray, OUT: np.ndarray) -> None:
        """The averaged slip's buffer holds only reachable entries and is full: twice as large."""
        w = np.zeros((2 * self.WIN.shape[0], self.WIN.shape[1]))
        w[:self.WIN.shape[0]] = self.WIN
        self.WIN = w
