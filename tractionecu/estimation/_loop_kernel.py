"""The compiled step of :class:`~.estimator.Estimator` over a block of steps (:mod:`.compiled_loop`).

One numba function, :func:`run`, advances the estimator's state over the steps of a block, in the step
path's order and with its operations (the same floats, bit for bit where the equality test checks it:
``tests/estimation/test_compiled_loop.py``).  The state lives in flat arrays:

* ``F`` (float64): configuration constants, the filter's mean and covariance, the held inputs, the
  timers, the bus-rate trackers, the curvature filter, the monitors, and the step's own variables;
* ``I`` (int64): flags, counters, the stage of the step being run and the step index;
* ``CM`` (2M, n): the covariance-matching window (corrections², then diag(K S Kᵀ));
* ``RB`` (10, window): the rate trackers' interval buffers (5 streams, then their runs of long intervals);
* ``WIN`` (cap, 19): the averaged slip's cumulative sums (time, distance, Σ P_vv Δt, 16 per-wheel sums).

A step is a sequence of stages.  Where the step path calls an object this module does not port (the μ(s)
curve, the radius calibration, the systematic uncertainty with a pull-angle tolerance, the filter's
initialisation, the slope of the identified curve, a repaired or gated update), :func:`run` stores what
the object needs, sets the stage to resume at and returns the event's code; the driver
(:mod:`.compiled_loop`) calls the same Python object the step path calls, writes its result into the
state and calls :func:`run` again.  Offsets of the flat arrays are the module's ``F_*`` / ``I_*``
constants (:data:`F_NAMES`, :data:`I_NAMES`).
"""

from __future__ import annotations

import math

import numpy as np

from ..model.vehicle import compiled
from . import _curve_kernel, _kernels
from .kinematics import BETA0_VAR_FACTOR, BETA_MAX_SIGMAS, BIAS_DIST_M, BIAS_TAU_S, FAR_EPOCHS, YAW_TAU_S
from .rates import PERIOD_TOLERANCE

# ----------------------------------------------------------------------------- status bits (estimator.py)
# Copies of estimator.py's values, not imports: numba freezes a global into the machine code it caches and keys
# that cache by this file only, so an import would keep an old value after an edit there.  The test
# test_kernel_constants_are_the_estimators holds each copy to estimator.py's.
WHEEL_TIMEOUT = 0x01
GPS_TIMEOUT = 0x02
TORQUE_TIMEOUT = 0x04
AXLE_TIMEOUT = 0x08
DRAFT_TIMEOUT = 0x10
NOT_CONVERGED = 0x20
INPUT_REJECTED = 0x40
MEAS_GATED = 0x80
COV_REPAIRED = 0x100
FILTER_LOST = 0x200
STANDSTILL = 0x400
UNVERIFIED = 0x800
MACHINE_UNSUPPORTED = 0x1000
SLIP_UNCERTAIN = 0x2000
SLIP_AVERAGED = 0x10000
INVALID_MASK = (WHEEL_TIMEOUT | GPS_TIMEOUT | TORQUE_TIMEOUT | AXLE_TIMEOUT | DRAFT_TIMEOUT | NOT_CONVERGED
                | INPUT_REJECTED | FILTER_LOST | STANDSTILL | MACHINE_UNSUPPORTED)
KAPPA_NOISE_MIN = 0.003
KAPPA_MAX = 0.25

# ----------------------------------------------------------------------------- events (run's return codes; the
# stage functions return a stage or an event, so the two ranges differ)
EV_DONE = 0
EV_INIT = 101        # initialise the filter (Estimator._init_filter), then the step's NaN estimate
EV_PREDICT = 102     # predict sub-step on the Python filter (P not positive definite: its repair)
EV_RECOVER = 103     # non-finite prediction: Estimator._recover
EV_UPDATE = 104      # update on the Python filter (gated or non-finite components: the general path)
EV_CURVE = 106       # μ(s) curve update
EV_SLIPWIN = 107     # averaged slip: the identified curve's slope at the candidate stretches (into EV)
EV_CAL = 108         # radius calibration at a GNSS epoch
EV_WINFULL = 109     # the averaged slip's buffer is full: the driver enlarges it
EV_SYSTEMATIC = 111  # systematic uncertainty with a pull-angle tolerance (its math.hypot stays in Python)
EV_HASCURVE = 112    # whether the latest curve state has an identified curve (CurveState.curve), asked when needed
EV_CURVEJ = 113      # the compiled μ(s) curve update needs Python: a soil segment's close, the once-a-second span and
                     # fit, or more room (I[I_CURVE_R]: _curve_kernel's ALARM, CHECK, GROW, or CURVE_REC_FULL)
CURVE_REC_FULL = 4   # (I[I_CURVE_R]) the curve records (CR) are full: nothing was changed

# ----------------------------------------------------------------------------- stages of a step
ST_BEGIN = 0
ST_AFTER_INIT = 1
ST_PREDICT = 2
ST_AFTER_PREDICT = 3
ST_UPDATE = 4
ST_POST_UPDATE = 5
ST_DIVERGENCE = 6
ST_ESTIMATE = 7
ST_ESTIMATE2 = 8
ST_ESTIMATE3 = 9
ST_CAL = 10
ST_NONE = 11
ST_END = 12
ST_ADAPT = 13
ST_ADAPT2 = 14
ST_SLIPWIN2 = 15
MEMO = 64
"""Entries of the fuzzy supervisor's memo (FuzzySupervisor keeps 64 too; a full memo starts again)."""

# ----------------------------------------------------------------------------- columns of the block arrays
IN_T, IN_HMD, IN_MD, IN_HFZF, IN_FZF, IN_HFDX, IN_FDX, IN_HOM, IN_OM, IN_HDIR, IN_DIR, IN_HV, IN_V, IN_HCRS, \
    IN_CRS = 0, 1, 2, 6, 7, 8, 9, 10, 11, 15, 16, 17, 18, 19, 20
N_IN = 21
OUT_T, OUT_MU, OUT_RHO, OUT_SLIP, OUT_V, OUT_OM, OUT_P, OUT_NIS, OUT_ADAPT, OUT_STATUS, OUT_VALID, OUT_DOF, \
    OUT_LOST, OUT_SIGMU, OUT_SIGRHO, OUT_RAD, OUT_CS, OUT_HASX, OUT_HASSYS = (0, 1, 5, 6, 10, 11, 15, 25, 26, 27,
                                                                          28, 29, 30, 31, 35, 36, 42, 43, 44)
N_OUT = 45
# the fixed-lag smoother's transition of each step (Estimate.transition, .smoother), only with smoothing on:
# link, x⁺ (10), x⁻ (10), G (100)
OUT_SM_LINK, OUT_SM_XF, OUT_SM_XP, OUT_SM_G = 45, 46, 56, 66
N_OUT_SM = 166

# ----------------------------------------------------------------------------- layout of F and I
F_NAMES = (
    # configuration
    ("c_max_gap", 1), ("c_max_step", 1), ("c_standstill", 1), ("c_dir_min", 1), ("c_gps_timeout", 1),
    ("c_wabs", 1), ("c_wrel", 1), ("c_wq2", 1), ("c_rv", 1), ("c_tqabs", 1), ("c_tqrel", 1), ("c_tqq2", 1),
    ("c_fzvar", 1), ("c_fdvar", 1), ("c_weight", 1), ("c_J", 1), ("c_m", 1), ("c_hb", 1), ("c_wb", 1),
    ("c_rho_t", 1), ("c_gate", 1), ("c_cmu", 1), ("c_crho", 1), ("c_exit2", 1), ("c_conv_min", 1),
    ("c_curve_period", 1), ("c_curve_minspd", 1), ("c_slip_max", 1), ("c_avg_max", 1), ("c_avg_corr", 1),
    ("c_adapt_period", 1), ("c_dyn_tau", 1), ("c_lost_after", 1), ("c_mon_rho_max", 1), ("c_mon_minspd", 1),
    ("c_rate_k", 1), ("c_rate_maxint", 1), ("c_kin_b", 1), ("c_kin_csig", 1), ("c_kin_minspd", 1),
    ("c_kin_varbeta", 1), ("c_tanpull", 1), ("c_eta", 1), ("c_drag", 1), ("c_two", 1), ("c_mon_bound", 9),
    ("c_w", 43), ("c_kc", 18), ("c_lo", 10), ("c_hi", 10), ("c_qtune", 10),
    ("c_a_min", 1), ("c_a_max", 1),
    # fuzzy supervisor: a1, a2, a3, m1, m2, m3, factor_min, log(f_max / f_min)
    ("c_fz", 8),
    # systematic uncertainty: u_g, u_eta, tan_pull, u_tan, u_m0, u_a0, u_ag, u_d0, u_dg, lat2_3, weight, mg
    ("c_unc", 12),
    # filter
    ("x", 10), ("P", 100), ("u", 7), ("Qb", 100), ("A", 10), ("sig", 210), ("xn", 10), ("Pn", 100),
    ("Q", 100), ("work", 70), ("small", 55), ("dx", 10), ("ksk", 10),
    # estimator state
    ("t", 1), ("t_init", 1), ("kapvar", 1), ("md_sum", 1), ("tin", 3), ("t_omega", 1), ("t_v", 1),
    ("t_upd_w", 1), ("t_upd_v", 1), ("last_vmeas", 1), ("dir", 1), ("dir_bus", 1), ("t_dir_bus", 1),
    ("f", 1), ("Qdt", 1), ("tq_gain", 1), ("adapt_mu", 1), ("t_adapt", 1), ("t_curve", 1), ("r_lat", 1),
    ("kf", 1), ("kr", 1), ("held_rho", 1), ("held_s", 4), ("win_dir", 1), ("dm_var", 4), ("md_inv", 4),
    ("rad", 6), ("sys_var", 5), ("last_nis", 1), ("ur", 2),
    # the fuzzy supervisor's memo: (strength SMALL, MEDIUM, LARGE, intensity c) per entry
    ("fz_memo", 256), ("fz_st", 3), ("fz_c", 1),
    # dynamics monitor: t, v, m, accel, torque_rate, dt, k
    ("dyn", 7),
    # divergence monitor: nis, wheel, ground, rho since (NaN: None)
    ("mon", 4),
    # curvature filter: h, P0, P1, P2, beta, kappa_w, var_w, k_raw, var_raw, v, t, tw
    ("kin", 12),
    # rate trackers (Md, Fzf, Fdx, omega, v) × (period, last, gap_s, nominal, floor, timeout)
    ("rates", 30),
    # the step's own variables
    ("l_t", 1), ("l_vmeas", 1), ("l_vwheel", 1), ("l_dt", 1), ("l_h", 1), ("l_old_md", 4), ("l_told_md", 1),
    ("l_old_fdx", 1), ("l_told_fdx", 1), ("l_rom", 4), ("l_wl", 4), ("l_z", 5), ("l_R", 5), ("l_buf", 26),
    ("l_v", 1), ("l_since", 1), ("l_s", 4), ("l_rho", 1),
    # the curve update's arguments: σ of μ (4), σ of slip (4)
    ("l_sig_mu", 4), ("l_sig_s", 4), ("c_track", 1),
    # FilterModel.load_floats of the step's held loads (F_z front, F_z rear, r_d front, r_d rear), for the curve
    # update and the radius calibration in Python
    ("l_load", 4),
    # the radius calibration's screen (RadiusCalibration._sample_ok): min_speed, max_accel, max_turn_rel, max_mu;
    # its state as of the last epoch screened here: _period, _t_last, rejections not yet added to its count
    ("c_cal", 4), ("cal", 3),
    # the fixed-lag smoother (Estimate.transition): this step's gain over its sub-steps, a sub-step's gain, the
    # last estimate's x⁺, this step's prior x⁻
    ("sm_g", 100), ("sm_gs", 100), ("sm_xf", 10), ("sm_xp", 10),
)
I_NAMES = (
    ("stage", 1), ("k", 1), ("status", 1), ("predict_only", 1), ("has_om", 1), ("om_fin", 1), ("has_vmeas", 1),
    ("updated", 1), ("wheel_out", 1), ("ground_out", 1), ("n_sub", 1), ("sub", 1), ("foh_md", 1),
    ("foh_fdx", 1), ("ukf", 1), ("lost", 1), ("conv", 1), ("has_held", 1), ("win_n", 1), ("win_lo", 1),
    ("has_mdinv", 1), ("has_sys", 1), ("sys_flag", 1), ("has_lastv", 1), ("dyn_init", 1), ("cm_i", 1),
    ("cm_count", 1), ("cm_M", 1), ("gate_run", 5), ("gate_run_any", 1), ("chol_repairs", 1), ("last_dof", 1),
    ("r_nbuf", 5), ("r_nlong", 5), ("r_observed", 5), ("r_window", 1), ("kin_far", 1), ("kin_restarts", 1),
    ("counters", 9), ("has_curve", 1), ("cs_ver", 1), ("f_cal", 1), ("f_adapt", 1), ("f_input_noise", 1),
    ("repaired_last", 1), ("slip_ok", 1), ("conv_p", 1), ("qb_valid", 1), ("upd_kind", 1), ("init_done", 1),
    ("n_cand", 1), ("avg_found", 1), ("f_sup", 1), ("f_unc", 1), ("fz_n", 1), ("fz_rules", 9),
    # the radius calibration's open block holds samples (RadiusCalibration._blk[4] != 0, after the last push)
    ("cal_open", 1),
    # the curve update compiled (_curve_kernel.ce_update, in the loop: 1) or in Python (0); with the shape
    # identification; the kernel's code when it returns EV_CURVEJ; the current shape-information snapshot
    ("curve_jit", 1), ("curve_shape", 1), ("curve_r", 1), ("curve_info", 1),
    # the fixed-lag smoother: on (EstimatorConfig.smoother_lag_s > 0); this step's prediction links to the last
    # estimate; the last estimate had a filter (sm_xf holds its x⁺)
    ("sm_on", 1), ("sm_link", 1), ("sm_has", 1),
)
COUNTERS = ("steps", "updates", "gated", "rejected_inputs", "rejected_measurements", "chol_repairs", "resets",
            "gap_resets", "lost")


def _dep_tag() -> int:
    """A number that changes with the source of the compiled code this module calls from other files
    (:mod:`._kernels`, the filter model's RK4 in :mod:`tractionecu.model.vehicle`) and of the constants it
    takes from :mod:`.kinematics` and :mod:`.rates`.

    numba's on-disk cache keys a function by its own file and bytecode and by the values it closes over,
    not by the functions it calls from other files, whose machine code the cached function carries: the
    functions below that call those kernels close over this number, so an edit of the kernels recompiles
    them instead of loading a stale copy (as :func:`._kernels._model_tag` does for ``predict_model``)."""
    import hashlib
    from pathlib import Path

    here = Path(__file__).resolve().parent
    files = (here / "_kernels.py", here.parent / "model" / "vehicle.py", here / "kinematics.py", here / "rates.py",
             here / "_curve_kernel.py")
    h = hashlib.sha256()
    for f in files:
        h.update(f.read_bytes())
    return int(h.hexdigest()[:15], 16)


_TAG = _dep_tag()


def _offsets(names):
    out = {}
    o = 0
    for name, size in names:
        out[name] = o
        o += size
    return out, o


F_OFF, F_SIZE = _offsets(F_NAMES)
I_OFF, I_SIZE = _offsets(I_NAMES)
globals().update({"F_" + k.upper(): v for k, v in F_OFF.items()})
globals().update({"I_" + k.upper(): v for k, v in I_OFF.items()})
N_CAND_COLS = 17
"""Columns of one averaged-slip candidate in EV: slip (4), σ (4), distance-weighted μ̄ (4), distance S, and the
identified curve's |dμ/ds| at the slips (4, filled by the driver)."""

# (the names the compiled code below uses, spelled out for readers and linters)
F_C_MAX_GAP: int; F_C_MAX_STEP: int; F_C_STANDSTILL: int; F_C_DIR_MIN: int; F_C_GPS_TIMEOUT: int  # noqa: E702
F_C_WABS: int; F_C_WREL: int; F_C_WQ2: int; F_C_RV: int; F_C_TQABS: int; F_C_TQREL: int; F_C_TQQ2: int  # noqa: E702
F_C_FZVAR: int; F_C_FDVAR: int; F_C_WEIGHT: int; F_C_J: int; F_C_M: int; F_C_HB: int; F_C_WB: int  # noqa: E702
F_C_RHO_T: int; F_C_GATE: int; F_C_CMU: int; F_C_CRHO: int; F_C_EXIT2: int; F_C_CONV_MIN: int  # noqa: E702
F_C_CURVE_PERIOD: int; F_C_CURVE_MINSPD: int; F_C_SLIP_MAX: int; F_C_AVG_MAX: int; F_C_AVG_CORR: int  # noqa: E702
F_C_ADAPT_PERIOD: int; F_C_DYN_TAU: int; F_C_LOST_AFTER: int; F_C_MON_RHO_MAX: int; F_C_MON_MINSPD: int  # noqa: E702
F_C_RATE_K: int; F_C_RATE_MAXINT: int; F_C_KIN_B: int; F_C_KIN_CSIG: int; F_C_KIN_MINSPD: int  # noqa: E702
F_C_KIN_VARBETA: int; F_C_TANPULL: int; F_C_ETA: int; F_C_DRAG: int; F_C_TWO: int  # noqa: E702
F_C_MON_BOUND: int  # noqa: E702
F_C_W: int; F_C_KC: int; F_C_LO: int; F_C_HI: int; F_C_QTUNE: int; F_C_A_MIN: int; F_C_A_MAX: int  # noqa: E702
F_C_FZ: int; F_C_UNC: int; F_UR: int; F_FZ_MEMO: int; F_FZ_ST: int; F_FZ_C: int  # noqa: E702
F_X: int; F_P: int; F_U: int; F_QB: int; F_A: int; F_SIG: int; F_XN: int; F_PN: int; F_Q: int  # noqa: E702
F_WORK: int; F_SMALL: int; F_DX: int; F_KSK: int  # noqa: E702
F_T: int; F_T_INIT: int; F_KAPVAR: int; F_MD_SUM: int; F_TIN: int; F_T_OMEGA: int; F_T_V: int  # noqa: E702
F_T_UPD_W: int; F_T_UPD_V: int; F_LAST_VMEAS: int; F_DIR: int; F_DIR_BUS: int; F_T_DIR_BUS: int  # noqa: E702
F_F: int; F_QDT: int; F_TQ_GAIN: int; F_ADAPT_MU: int; F_T_ADAPT: int; F_T_CURVE: int; F_R_LAT: int  # noqa: E702
F_KF: int; F_KR: int; F_HELD_RHO: int; F_HELD_S: int; F_WIN_DIR: int; F_DM_VAR: int; F_MD_INV: int  # noqa: E702
F_RAD: int; F_SYS_VAR: int; F_LAST_NIS: int; F_DYN: int; F_MON: int; F_KIN: int; F_RATES: int  # noqa: E702
F_L_T: int; F_L_VMEAS: int; F_L_VWHEEL: int; F_L_DT: int; F_L_H: int; F_L_OLD_MD: int  # noqa: E702
F_L_TOLD_MD: int; F_L_OLD_FDX: int; F_L_TOLD_FDX: int; F_L_ROM: int; F_L_WL: int; F_L_Z: int; F_L_R: int  # noqa: E702
F_L_BUF: int; F_L_V: int; F_L_SINCE: int; F_L_S: int; F_L_RHO: int; F_L_SIG_MU: int; F_L_SIG_S: int  # noqa: E702
F_C_TRACK: int; F_L_LOAD: int; F_C_CAL: int; F_CAL: int  # noqa: E702
F_SM_G: int; F_SM_GS: int; F_SM_XF: int; F_SM_XP: int; I_SM_ON: int; I_SM_LINK: int; I_SM_HAS: int  # noqa: E702
I_STAGE: int; I_K: int; I_STATUS: int; I_PREDICT_ONLY: int; I_HAS_OM: int; I_OM_FIN: int  # noqa: E702
I_HAS_VMEAS: int; I_UPDATED: int; I_WHEEL_OUT: int; I_GROUND_OUT: int; I_N_SUB: int; I_SUB: int  # noqa: E702
I_FOH_MD: int; I_FOH_FDX: int; I_UKF: int; I_LOST: int; I_CONV: int; I_HAS_HELD: int; I_WIN_N: int  # noqa: E702
I_WIN_LO: int; I_HAS_MDINV: int; I_HAS_SYS: int; I_SYS_FLAG: int; I_HAS_LASTV: int; I_DYN_INIT: int  # noqa: E702
I_CM_I: int; I_CM_COUNT: int; I_CM_M: int; I_GATE_RUN: int; I_GATE_RUN_ANY: int; I_CHOL_REPAIRS: int  # noqa: E702
I_LAST_DOF: int; I_R_NBUF: int; I_R_NLONG: int; I_R_OBSERVED: int; I_R_WINDOW: int; I_KIN_FAR: int  # noqa: E702
I_KIN_RESTARTS: int; I_COUNTERS: int; I_HAS_CURVE: int; I_CS_VER: int; I_F_CAL: int; I_F_ADAPT: int  # noqa: E702
I_F_INPUT_NOISE: int; I_REPAIRED_LAST: int; I_SLIP_OK: int; I_CONV_P: int; I_QB_VALID: int  # noqa: E702
I_UPD_KIND: int; I_INIT_DONE: int; I_N_CAND: int; I_AVG_FOUND: int; I_F_SUP: int; I_F_UNC: int  # noqa: E702
I_FZ_N: int; I_FZ_RULES: int; I_CAL_OPEN: int  # noqa: E702
I_CURVE_JIT: int; I_CURVE_SHAPE: int; I_CURVE_R: int; I_CURVE_INFO: int  # noqa: E702

C_STEPS, C_UPDATES, C_GATED, C_REJ_IN, C_REJ_MEAS, C_CHOL, C_RESETS, C_GAP, C_LOST = range(9)
K_MD, K_FZF, K_FDX, K_OMEGA, K_V = range(5)
_TWO_PI = 2.0 * math.pi
_DEG2RAD = math.pi / 180.0        # CPython's math.radians: x * (π / 180)
_YAW_MAX_DT = 10.0 * YAW_TAU_S


# ----------------------------------------------------------------------------- small helpers
def _cal_rejects(F, row):                                                 # pragma: no cover - compiled
    """Whether RadiusCalibration.push rejects this epoch before its slip test: not ``ok`` (the estimate not
    valid) or not RadiusCalibration._sample_ok, same operations."""
    if row[OUT_VALID] == 0.0:
        return True
    v = F[F_L_VMEAS]
    c = F_C_CAL
    if not (abs(v) >= F[c] and abs(F[F_DYN + 3]) <= F[c + 1]):
        return True
    sgn = 1.0 if v > 0.0 else -1.0
    for i in (0, 2):
        wl = F[F_L_WL + i] * sgn
        wr = F[F_L_WL + i + 1] * sgn
        mean = 0.5 * (wl + wr)
        if not (wl > 0.0 and wr > 0.0) or abs(wl - wr) > F[c + 2] * mean:
            return True
        if not abs(0.5 * (row[OUT_MU + i] + row[OUT_MU + i + 1])) <= F[c + 3]:
            return True
    return False


def _load_floats(F, fzf, fdx):                                            # pragma: no cover - compiled
    """FilterModel.load_floats: (F_z front, F_z rear, r_d front, r_d rear), same operations."""
    kc = F_C_KC
    w_n, k, lim, r0 = F[kc], F[kc + 1], F[kc + 2], F[kc + 3]
    tb = F[F_C_TANPULL]
    ff = 0.5 * fzf
    fr = 0.5 * (w_n - fzf) if tb == 0.0 else 0.5 * ((w_n - fzf) + fdx * tb)
    d = ff
    if not d > 0.0:
        d = 0.0 if d <= 0.0 else d
    d = d / k
    rdf = r0 - (lim if d > lim else d)
    d = fr
    if not d > 0.0:
        d = 0.0 if d <= 0.0 else d
    d = d / k
    rdr = r0 - (lim if d > lim else d)
    return ff, fr, rdf, rdr


def _wrap(a):                                                             # pragma: no cover - compiled
    return a - _TWO_PI * math.floor((a + math.pi) / _TWO_PI)


def _pow2(F, x):                                                          # pragma: no cover - compiled
    """Python's ``x ** 2`` of a float: the C library's pow(x, 2.0), which differs from x·x in the last bit for
    about one x in a thousand.  The exponent is read from F (2.0) so that the compiler cannot turn the call
    into x·x."""
    return math.pow(x, F[F_C_TWO])


def _pymax(a, b):                                                         # pragma: no cover - compiled
    """Python's max(a, b) of two floats: b only if b > a."""
    return b if b > a else a


# ----------------------------------------------------------------------------- rate trackers (rates.py)
def _rate_median(F, I, RB, j):                                            # pragma: no cover - compiled
    nb = I[I_R_NBUF + j]
    b = np.sort(RB[j, :nb].copy())
    n = nb
    p = b[n // 2] if n % 2 else 0.5 * (b[n // 2 - 1] + b[n // 2])
    I[I_R_NBUF + j] = 0
    I[I_R_OBSERVED + j] = 1
    o = F_RATES + 6 * j
    if abs(p - F[o]) <= PERIOD_TOLERANCE * F[o]:
        return False
    F[o] = p
    F[o + 2] = F[F_C_RATE_K] * p
    return True


def _rate_push(F, I, RB, j, t):                                           # pragma: no cover - compiled
    """PeriodTracker.push of stream j; True when its period changed."""
    o = F_RATES + 6 * j
    d = t - F[o + 1]
    if not d > 0.0:
        return False
    F[o + 1] = t
    window = I[I_R_WINDOW]
    maxint = F[F_C_RATE_MAXINT]
    if d <= F[o + 2] and d <= maxint:
        nb = I[I_R_NBUF + j]
        RB[j, nb] = d
        nb += 1
        I[I_R_NBUF + j] = nb
        I[I_R_NLONG + j] = 0
        if nb < window:
            return False
        return _rate_median(F, I, RB, j)
    if d > maxint or d == math.inf:
        return False
    if d > F[o + 2]:
        nl = I[I_R_NLONG + j]
        RB[5 + j, nl] = d
        nl += 1
        I[I_R_NLONG + j] = nl
        if nl < window:
            return False
        for i in range(nl):
            RB[j, i] = RB[5 + j, i]
        I[I_R_NBUF + j] = nl
        I[I_R_NLONG + j] = 0
    return _rate_median(F, I, RB, j)


def _rate_refresh(F, j):                                                  # pragma: no cover - compiled
    o = F_RATES + 6 * j
    fl = F[o + 4]
    kp = F[F_C_RATE_K] * F[o]
    F[o + 5] = kp if kp > fl else fl          # max(floor, k·period)


# ----------------------------------------------------------------------------- curvature filter (kinematics.py)
def _kin_predict(F, t):                                                   # pragma: no cover - compiled
    o = F_KIN
    dt = t - F[o + 10] if F[o + 10] == F[o + 10] else 0.0
    F[o + 10] = t
    if not dt > 0.0:
        return
    if F[o] == F[o] and F[o + 7] == F[o + 7]:
        vd = F[o + 9] * dt
        F[o] = _wrap(F[o] - (F[o + 7] - F[o + 4]) * vd)
        phh = F[o + 1] + 2.0 * vd * F[o + 2] + vd * vd * F[o + 3] + F[o + 8] * vd * vd
        phb = F[o + 2] + vd * F[o + 3]
        F[o + 1] = phh
        F[o + 2] = phb
    phi = math.exp(-abs(F[o + 9]) * dt / BIAS_DIST_M)
    F[o + 4] *= phi
    F[o + 2] *= phi
    F[o + 3] = phi * phi * F[o + 3] + F[F_C_KIN_VARBETA] * (1.0 - phi * phi)


def _kin_wheels(F, t, w_rl, w_rr, var_rl, var_rr, v):                    # pragma: no cover - compiled
    o = F_KIN
    sm = w_rr + w_rl
    if not math.isfinite(sm) or abs(sm) < 1e-9:
        return
    _kin_predict(F, t)
    F[o + 9] = v if math.isfinite(v) else 0.0
    b = F[F_C_KIN_B]
    k = 2.0 / b * (w_rr - w_rl) / sm
    g = 4.0 / (b * sm * sm)
    var = g * g * (w_rl * w_rl * var_rr + w_rr * w_rr * var_rl)
    F[o + 7] = k
    F[o + 8] = var
    tw = F[o + 11]
    dt = t - tw if tw == tw else math.inf
    F[o + 11] = t
    if not F[o + 5] == F[o + 5] or not dt < _YAW_MAX_DT:
        F[o + 5] = k
        F[o + 6] = var
        return
    a = dt / (YAW_TAU_S + dt)
    F[o + 5] += a * (k - F[o + 5])
    F[o + 6] = (1.0 - a) * (1.0 - a) * F[o + 6] + a * a * var


def _kin_standstill(F):                                                   # pragma: no cover - compiled
    F[F_KIN + 4] = 0.0
    F[F_KIN + 2] = 0.0
    F[F_KIN + 3] = F[F_C_KIN_VARBETA]


def _kin_course(F, I, t, course_deg, speed, direction):                   # pragma: no cover - compiled
    o = F_KIN
    if not (math.isfinite(course_deg) and math.isfinite(speed)) or abs(speed) < F[F_C_KIN_MINSPD]:
        return
    _kin_predict(F, t)
    z = course_deg * _DEG2RAD + (math.pi if direction < 0 else 0.0)
    r = _pow2(F, F[F_C_KIN_CSIG] / abs(speed))
    vb = F[F_C_KIN_VARBETA]
    if F[o] != F[o]:
        F[o] = _wrap(z)
        F[o + 1] = r
        F[o + 2] = 0.0
        return
    nu = _wrap(z - F[o])
    s = F[o + 1] + r
    if nu * nu > 16.0 * s:
        I[I_KIN_FAR] += 1
        if I[I_KIN_FAR] >= FAR_EPOCHS:
            I[I_KIN_RESTARTS] += 1
            F[o] = _wrap(z)
            F[o + 4] = 0.0
            F[o + 1] = r
            F[o + 2] = 0.0
            F[o + 3] = BETA0_VAR_FACTOR * vb
            I[I_KIN_FAR] = 0
        return
    I[I_KIN_FAR] = 0
    kh = F[o + 1] / s
    kb = F[o + 2] / s
    F[o] = _wrap(F[o] + kh * nu)
    F[o + 4] += kb * nu
    p00 = F[o + 1]
    p01 = F[o + 2]
    p11 = F[o + 3]
    F[o + 1] = p00 - kh * p00
    F[o + 2] = p01 - kh * p01
    F[o + 3] = p11 - kb * p01
    if F[o + 4] * F[o + 4] > BETA_MAX_SIGMAS * BETA_MAX_SIGMAS * vb:
        I[I_KIN_RESTARTS] += 1
        F[o] = _wrap(z)
        F[o + 4] = 0.0
        F[o + 1] = r
        F[o + 2] = 0.0
        F[o + 3] = vb


def _kin_course_direction(F, course_deg, speed):                          # pragma: no cover - compiled
    o = F_KIN
    smax = 0.35
    if (F[o] != F[o] or not math.isfinite(course_deg) or abs(speed) < F[F_C_KIN_MINSPD]
            or F[o + 1] > smax * smax):
        return 0.0
    d = abs(_wrap(course_deg * _DEG2RAD - F[o]))
    if d < math.pi / 3.0:
        return 1.0
    if d > 2.0 * math.pi / 3.0:
        return -1.0
    return 0.0


# ----------------------------------------------------------------------------- noise
def _mk_rebuild_Q(tag):
    """_rebuild_Q closed over the dependency tag (:func:`_dep_tag`)."""
    def _rebuild_Q(F, I, dt):                                                 # pragma: no cover - compiled
        if tag < 0:                  # never: ties the compiled code (and its cache entry) to the kernels' source
            raise AssertionError("dependency tag")
        J = F[F_C_J]
        m = F[F_C_M]
        F[F_TQ_GAIN] = F[F_RATES + 6 * K_MD] * dt / (J * J)
        inputs = I[I_F_INPUT_NOISE] != 0 and I[I_UKF] != 0
        g_v = 0.0
        c_fz = 0.0
        c_fd = 0.0
        qt = F[F_C_QTUNE:F_C_QTUNE + 10]
        x = qt
        _, _, rdf, rdr = _load_floats(F, F[F_U + 4], F[F_U + 5])
        rd = np.empty(4)
        rd[0] = rdf
        rd[1] = rdf
        rd[2] = rdr
        rd[3] = rdr
        if inputs:
            x = F[F_X:F_X + 10]
            dot = -0.5 * x[5]
            dot += -0.5 * x[6]
            dot += 0.5 * x[7]
            dot += 0.5 * x[8]
            g_v = -dot / m
            c_fz = F[F_C_FZVAR] * F[F_RATES + 6 * K_FZF] * dt
            c_fd = F[F_C_FDVAR] * F[F_RATES + 6 * K_FDX] * dt / (m * m)
        Qb = F[F_QB:F_QB + 100].reshape((10, 10))
        _kernels.process_noise(qt, F[F_F] * dt, F[F_A:F_A + 10], inputs, rd, x, F[F_C_RHO_T], J, g_v, c_fz, c_fd, Qb)
        I[I_QB_VALID] = 1
        F[F_QDT] = dt
    return _rebuild_Q


def _mk_make_Q(tag):
    """_make_Q closed over the dependency tag (:func:`_dep_tag`)."""
    def _make_Q(F, I, h):                                                     # pragma: no cover - compiled
        """Estimator._Q(h) into F's Q block (or the base itself without input noise); returns the matrix."""
        if tag < 0:                  # never: ties the compiled code (and its cache entry) to the kernels' source
            raise AssertionError("dependency tag")
        if I[I_QB_VALID] == 0 or abs(h - F[F_QDT]) > 1e-6 * h:
            _rebuild_Q(F, I, h)
        Qb = F[F_QB:F_QB + 100].reshape((10, 10))
        if I[I_F_INPUT_NOISE] == 0:
            return Qb
        Q = F[F_Q:F_Q + 100].reshape((10, 10))
        _kernels.add_torque_noise(Qb, F[F_U:F_U + 7], F[F_C_TQABS], F[F_C_TQREL], F[F_C_TQQ2], F[F_TQ_GAIN], Q)
        kap = F[F_U + 6]
        if (kap > KAPPA_NOISE_MIN or kap < -KAPPA_NOISE_MIN) and I[I_UKF] != 0:
            _kernels.add_kappa_noise(Q, F[F_X:F_X + 10], F[F_U:F_U + 7], F[F_C_KC:F_C_KC + 18], math.inf, 0,
                                     F[F_KAPVAR] * BIAS_TAU_S * h)   # v's term only (Estimator._Q)
        return Q
    return _make_Q


# ----------------------------------------------------------------------------- stages
def _win_reset(I):                                                        # pragma: no cover - compiled
    I[I_WIN_N] = 0
    I[I_WIN_LO] = 0


def _mon_reset(F):                                                        # pragma: no cover - compiled
    for i in range(4):
        F[F_MON + i] = math.nan


def _stage_begin(F, I, RB, IN, k):                                        # pragma: no cover - compiled
    """Estimator.step up to the initialisation: inputs, rates, timeouts, measurements, curvature."""
    t = IN[k, IN_T]
    F[F_L_T] = t
    status = 0
    predict_only = False
    I[I_COUNTERS + C_STEPS] += 1
    u = F[F_U:F_U + 7]
    I[I_FOH_MD] = 0
    I[I_FOH_FDX] = 0
    # ---- inputs
    if IN[k, IN_HMD] != 0.0:
        a0 = IN[k, IN_MD]
        a1 = IN[k, IN_MD + 1]
        a2 = IN[k, IN_MD + 2]
        a3 = IN[k, IN_MD + 3]
        sm = a0 + a1 + a2 + a3
        if math.isfinite(sm):
            I[I_FOH_MD] = 1
            for i in range(4):
                F[F_L_OLD_MD + i] = u[i]
            F[F_L_TOLD_MD] = F[F_TIN]
            eta = F[F_C_ETA]
            drag = F[F_C_DRAG]
            for i in range(4):
                a = IN[k, IN_MD + i]
                if eta != 1.0:               # motor to wheel torque (losses against the power flow)
                    a = a * (eta if a * F[F_DIR] >= 0.0 else 1.0 / eta)
                if drag != 0.0 and I[I_UKF]:
                    a = a - drag * F[F_X + i]      # the hub's drag at the wheel speed
                u[i] = a * F[F_MD_INV + i] if I[I_HAS_MDINV] else a
            F[F_MD_SUM] = sm
            F[F_TIN] = t
        else:
            status |= INPUT_REJECTED
    for key in range(2):
        col = IN_FZF if key == 0 else IN_FDX
        if IN[k, col - 1] == 0.0:
            continue
        fv = IN[k, col]
        if math.isfinite(fv) and (key != 0 or 0.0 < fv < F[F_C_WEIGHT]):
            if key == 1:
                I[I_FOH_FDX] = 1
                F[F_L_OLD_FDX] = u[5]
                F[F_L_TOLD_FDX] = F[F_TIN + 2]
            u[4 + key] = fv
            F[F_TIN + 1 + key] = t
        else:
            status |= INPUT_REJECTED
    if status & INPUT_REJECTED:
        I[I_COUNTERS + C_REJ_IN] += 1
        predict_only = True
    for j in range(3):
        if F[F_TIN + j] == t and _rate_push(F, I, RB, j, t):
            _rate_refresh(F, j)
    if t - F[F_TIN] > F[F_RATES + 6 * K_MD + 5]:
        status |= TORQUE_TIMEOUT
        predict_only = True
    if t - F[F_TIN + 1] > F[F_RATES + 6 * K_FZF + 5]:
        status |= AXLE_TIMEOUT
        predict_only = True
    if t - F[F_TIN + 2] > F[F_RATES + 6 * K_FDX + 5]:
        status |= DRAFT_TIMEOUT
        predict_only = True
    # ---- measurements
    has_om = IN[k, IN_HOM] != 0.0
    om_fin = False
    v_wheel = math.nan
    has_vmeas = False
    v_meas = math.nan
    gps_to = F[F_C_GPS_TIMEOUT]
    dmin = F[F_C_DIR_MIN]
    if has_om:
        w0 = IN[k, IN_OM]
        w1 = IN[k, IN_OM + 1]
        w2 = IN[k, IN_OM + 2]
        w3 = IN[k, IN_OM + 3]
        F[F_L_WL] = w0
        F[F_L_WL + 1] = w1
        F[F_L_WL + 2] = w2
        F[F_L_WL + 3] = w3
        if math.isfinite(w0 + w1 + w2 + w3):
            om_fin = True
            F[F_T_OMEGA] = t
            _, _, rdf, rdr = _load_floats(F, u[4], u[5])
            v_wheel = 0.25 * (rdf * (w0 + w1) + rdr * (w2 + w3))
            if v_wheel != v_wheel:
                v_wheel = math.nan
            elif t - F[F_T_DIR_BUS] <= gps_to:
                F[F_DIR] = F[F_DIR_BUS]
            elif v_wheel >= dmin:
                F[F_DIR] = 1.0
            elif v_wheel <= -dmin:
                F[F_DIR] = -1.0
            a = F[F_C_WABS]
            r = F[F_C_WREL]
            q2 = F[F_C_WQ2]
            for i in range(4):
                s = a + r * abs(F[F_L_WL + i])
                F[F_L_ROM + i] = s * s + q2
            vk = F[F_X + 4] if I[I_UKF] else v_wheel
            _kin_wheels(F, t, w2, w3, F[F_L_ROM + 2], F[F_L_ROM + 3], vk)
        else:
            nfin = 0
            for i in range(4):
                if math.isfinite(F[F_L_WL + i]):
                    nfin += 1
            status |= INPUT_REJECTED
            I[I_COUNTERS + C_REJ_MEAS] += 4 - nfin
            if nfin > 0:
                F[F_T_OMEGA] = t
    if IN[k, IN_HDIR] != 0.0:
        d = IN[k, IN_DIR]
        if d == 0 or d == 1:
            F[F_DIR] = 1.0 if d == 1 else -1.0
            F[F_DIR_BUS] = F[F_DIR]
            F[F_T_DIR_BUS] = t
    has_v = IN[k, IN_HV] != 0.0
    if has_v and IN[k, IN_HCRS] != 0.0:
        c = IN[k, IN_CRS]
        sp = abs(IN[k, IN_V])
        if t - F[F_T_DIR_BUS] > gps_to and (v_wheel != v_wheel or abs(v_wheel) < dmin):
            dc = _kin_course_direction(F, c, sp)
            if dc != 0.0:
                F[F_DIR] = dc
        _kin_course(F, I, t, c, sp, F[F_DIR])
    if has_v:
        v_meas = abs(IN[k, IN_V]) * F[F_DIR]
        if math.isfinite(v_meas):
            F[F_T_V] = t
            F[F_LAST_VMEAS] = v_meas
            I[I_HAS_LASTV] = 1
            has_vmeas = True
        else:
            status |= INPUT_REJECTED
            I[I_COUNTERS + C_REJ_MEAS] += 1
    if F[F_T_OMEGA] == t and _rate_push(F, I, RB, K_OMEGA, t):
        _rate_refresh(F, K_OMEGA)
    if F[F_T_V] == t and _rate_push(F, I, RB, K_V, t):
        _rate_refresh(F, K_V)
    if t - F[F_T_OMEGA] > F[F_RATES + 6 * K_OMEGA + 5]:
        status |= WHEEL_TIMEOUT
    if t - F[F_T_V] > F[F_RATES + 6 * K_V + 5]:
        status |= GPS_TIMEOUT
    # ---- path curvature
    if I[I_UKF]:
        v_ref = F[F_X + 4]
    else:
        v_ref = v_wheel if v_wheel == v_wheel else 0.0
    ss = F[F_C_STANDSTILL]
    if -ss < v_ref < ss:
        _kin_standstill(F)
    o = F_KIN
    if not F[o + 5] == F[o + 5] or abs(v_ref) < ss:
        kap = 0.0
        kvar = math.inf
    else:
        kap = F[o + 5] - F[o + 4]
        kvar = F[o + 6] + F[o + 3]
    if kap > KAPPA_MAX:
        kap = KAPPA_MAX
    elif kap < -KAPPA_MAX:
        kap = -KAPPA_MAX
    u[6] = kap
    F[F_KAPVAR] = kvar if kvar < KAPPA_MAX * KAPPA_MAX else KAPPA_MAX * KAPPA_MAX
    I[I_STATUS] = status
    I[I_PREDICT_ONLY] = 1 if predict_only else 0
    I[I_HAS_OM] = 1 if has_om else 0
    I[I_OM_FIN] = 1 if om_fin else 0
    I[I_HAS_VMEAS] = 1 if has_vmeas else 0
    F[F_L_VMEAS] = v_meas
    F[F_L_VWHEEL] = v_wheel
    # ---- initialisation
    if I[I_UKF] == 0:
        if om_fin and math.isfinite(F[F_TIN]) and math.isfinite(F[F_TIN + 1]) and math.isfinite(F[F_TIN + 2]):
            return EV_INIT
        I[I_STATUS] = status | NOT_CONVERGED
        return ST_NONE
    # ---- predict
    dt = t - F[F_T] if F[F_T] == F[F_T] else 0.0
    if dt > F[F_C_MAX_GAP]:
        I[I_COUNTERS + C_GAP] += 1
        I[I_UKF] = 0
        F[F_T] = t
        I[I_STATUS] = status | NOT_CONVERGED
        return ST_NONE
    if dt > 0.0:
        n_sub = max(1, int(math.ceil(dt / F[F_C_MAX_STEP] - 1e-9)))
        I[I_N_SUB] = n_sub
        I[I_SUB] = 0
        F[F_L_H] = dt / n_sub
        F[F_L_DT] = dt
        I[I_REPAIRED_LAST] = 0
        return ST_PREDICT
    return ST_UPDATE


def _mk_stage_predict(tag):
    """_stage_predict closed over the dependency tag (:func:`_dep_tag`)."""
    def _stage_predict(F, I):                                                 # pragma: no cover - compiled
        """The sub-steps of the prediction (compiled predict_model); EV_PREDICT / EV_RECOVER otherwise."""
        if tag < 0:                  # never: ties the compiled code (and its cache entry) to the kernels' source
            raise AssertionError("dependency tag")
        h = F[F_L_H]
        n_sub = I[I_N_SUB]
        x = F[F_X:F_X + 10]
        P = F[F_P:F_P + 100].reshape((10, 10))
        xn = F[F_XN:F_XN + 10]
        Pn = F[F_PN:F_PN + 100].reshape((10, 10))
        sig = F[F_SIG:F_SIG + 210].reshape((21, 10))
        sm = I[I_SM_ON] != 0
        if sm and I[I_SUB] == 0:
            # the smoother's link (Estimator.step): the prediction starts from the last estimate's x⁺
            link = I[I_SM_HAS] != 0
            for j in range(10):
                if not x[j] == F[F_SM_XF + j]:
                    link = False
            I[I_SM_LINK] = 1 if link else 0
        G = F[F_SM_G:F_SM_G + 100].reshape((10, 10))
        Gs = F[F_SM_GS:F_SM_GS + 100].reshape((10, 10))
        while I[I_SUB] < n_sub:
            Q = _make_Q(F, I, h)
            I[I_REPAIRED_LAST] = 0
            if sm:
                code = _kernels.predict_model_gain(x, P, F[F_U:F_U + 7], h, Q, F[F_C_W:F_C_W + 43],
                                                   F[F_C_KC:F_C_KC + 18], sig, xn, Pn, Gs)
                if code == 3:              # predicted, without its gain: the chain breaks here
                    I[I_SM_LINK] = 0
                    code = 0
                elif code == 0 and I[I_SM_LINK] != 0:
                    _kernels.gain_compose(G, Gs, I[I_SUB] == 0)
            else:
                code = _kernels.predict_model(x, P, F[F_U:F_U + 7], h, Q, F[F_C_W:F_C_W + 43],
                                              F[F_C_KC:F_C_KC + 18], sig, xn, Pn)
            if code == 0:
                x[:] = xn
                P[:, :] = Pn
                I[I_SUB] += 1
                continue
            I[I_SM_LINK] = 0
            if code == 1:
                return EV_PREDICT          # the driver predicts this sub-step on the Python filter (its repair)
            return EV_RECOVER
        return ST_AFTER_PREDICT
    return _stage_predict


def _foh(F, I, t, t_prev):                                                # pragma: no cover - compiled
    """Estimator._first_order_hold (Md, then F_dx), same operations."""
    u = F[F_U:F_U + 7]
    x = F[F_X:F_X + 10]
    for e in range(2):
        if (I[I_FOH_MD] if e == 0 else I[I_FOH_FDX]) == 0:
            continue
        t_old = F[F_L_TOLD_MD] if e == 0 else F[F_L_TOLD_FDX]
        t0 = _pymax(F[F_T_UPD_W] if e == 0 else F[F_T_UPD_V], t_old)
        if not t0 < t_prev or not t - t_old <= F[F_C_MAX_GAP]:
            continue
        w = (0.5 * (t0 + t) - t_old) / (t - t_old)
        if e == 0:
            J = F[F_C_J]
            ff, fr, rdf, rdr = _load_floats(F, u[4], u[5])
            for i in range(4):
                old = F[F_L_OLD_MD + i]
                new = u[i]
                d = (old + (new - old) * w) * (t - t0) - (old * (t_prev - t0) + new * (t - t_prev))
                x[i] += d / J
            for i in range(4):
                old = F[F_L_OLD_MD + i]
                new = u[i]
                dm = new - old
                ev = F[F_DM_VAR + i]
                ev += 0.05 * (dm * dm - ev)
                F[F_DM_VAR + i] = ev
                sm = F[F_C_TQABS] + F[F_C_TQREL] * abs(new)
                nv = 2.0 * (sm * sm + F[F_C_TQQ2])
                mx = ev if ev >= 1e-9 or ev != ev else 1e-9
                ww = 1.0 - nv / mx
                if ww < 0.0:
                    ww = 0.0
                elif ww > 1.0:
                    ww = 1.0
                rd = rdf if i < 2 else rdr
                fz = ff if i < 2 else fr
                g = ww / (rd * fz)
                x[5 + i] += g * dm
                F[F_P + (5 + i) * 11] += g * g * nv
        else:
            old = F[F_L_OLD_FDX]
            new = u[5]
            d = (old + (new - old) * w) * (t - t0) - (old * (t_prev - t0) + new * (t - t_prev))
            x[4] -= d / F[F_C_M]


def _stage_after_predict(F, I):                                           # pragma: no cover - compiled
    t = F[F_L_T]
    if I[I_REPAIRED_LAST]:
        I[I_STATUS] |= COV_REPAIRED
    if I[I_UKF] and (I[I_FOH_MD] or I[I_FOH_FDX]):
        _foh(F, I, t, F[F_T])
    F[F_T] = t
    if I[I_SM_LINK]:
        for j in range(10):
            F[F_SM_XP + j] = F[F_X + j]
    return ST_UPDATE


def _mk_stage_update(tag):
    """_stage_update closed over the dependency tag (:func:`_dep_tag`)."""
    def _stage_update(F, I, CM):                                                  # pragma: no cover - compiled
        """The measurement update (compiled update_block); EV_UPDATE for the general path."""
        if tag < 0:                  # never: ties the compiled code (and its cache entry) to the kernels' source
            raise AssertionError("dependency tag")
        I[I_UPDATED] = 0
        I[I_WHEEL_OUT] = -1
        I[I_GROUND_OUT] = -1
        has_om = I[I_HAS_OM] != 0
        has_v = I[I_HAS_VMEAS] != 0
        if I[I_PREDICT_ONLY] or not (has_om or has_v):
            I[I_UPD_KIND] = 0
            return ST_DIVERGENCE
        om_fin = I[I_OM_FIN] != 0
        if has_om and not om_fin:
            # (the R of non-finite wheel speeds: _R_list of the values, NaN where they are)
            for i in range(4):
                s = F[F_C_WABS] + F[F_C_WREL] * abs(F[F_L_WL + i])
                F[F_L_ROM + i] = s * s + F[F_C_WQ2]
        rv = F[F_C_RV] + F[F_R_LAT]
        if has_om and has_v:
            kind = 3
            m = 5
            i0 = 0
            for i in range(4):
                F[F_L_Z + i] = F[F_L_WL + i]
                F[F_L_R + i] = F[F_L_ROM + i]
            F[F_L_Z + 4] = F[F_L_VMEAS]
            F[F_L_R + 4] = rv
        elif has_om:
            kind = 1
            m = 4
            i0 = 0
            for i in range(4):
                F[F_L_Z + i] = F[F_L_WL + i]
                F[F_L_R + i] = F[F_L_ROM + i]
        else:
            kind = 2
            m = 1
            i0 = 4
            F[F_L_Z] = F[F_L_VMEAS]
            F[F_L_R] = rv
        I[I_UPD_KIND] = kind
        x = F[F_X:F_X + 10]
        P = F[F_P:F_P + 100].reshape((10, 10))
        xn = F[F_XN:F_XN + 10]
        Pn = F[F_PN:F_PN + 100].reshape((10, 10))
        work = F[F_WORK:F_WORK + 10 * (m + 2)].reshape((10, m + 2))
        small = F[F_SMALL:F_SMALL + (2 * m + 1) * m].reshape((2 * m + 1, m))
        code, nis, _clamped = _kernels.update_block(x, P, F[F_L_Z:F_L_Z + m], F[F_L_R:F_L_R + m], i0, F[F_C_GATE],
                                                    F[F_C_LO:F_C_LO + 10], F[F_C_HI:F_C_HI + 10], xn, Pn, work, small)
        if code != 0:
            return EV_UPDATE
        if I[I_GATE_RUN_ANY]:
            c0 = 4 if kind == 2 else 0
            c1 = 4 if kind == 1 else 5
            anyr = False
            for j in range(5):
                if c0 <= j < c1:
                    I[I_GATE_RUN + j] = 0
                if I[I_GATE_RUN + j] != 0:
                    anyr = True
            I[I_GATE_RUN_ANY] = 1 if anyr else 0
        x[:] = xn
        P[:, :] = Pn
        F[F_LAST_NIS] = nis
        I[I_LAST_DOF] = m
        for i in range(10):
            F[F_DX + i] = work[i, m]
            F[F_KSK + i] = work[i, m + 1]
        post_update(F, I, CM, 0, 0)
        return ST_DIVERGENCE
    return _stage_update


def _mkpost_update(tag):
    """post_update closed over the dependency tag (:func:`_dep_tag`)."""
    def post_update(F, I, CM, gated, outside):                                # pragma: no cover - compiled
        """After ukf.update (either path; the driver calls it after the general one): the gate bits, the
        counters, covariance matching's window (CovarianceMatching.push of F's dx, ksk)."""
        if tag < 0:                  # never: ties the compiled code (and its cache entry) to the kernels' source
            raise AssertionError("dependency tag")
        kind = I[I_UPD_KIND]
        t = F[F_L_T]
        if kind & 1:
            I[I_WHEEL_OUT] = 1 if (outside & 0xF) != 0 else 0
        if kind & 2:
            I[I_GROUND_OUT] = 1 if (outside & 0x10) != 0 else 0
        if gated:
            I[I_STATUS] |= MEAS_GATED
            nb = 0
            g = gated
            while g:
                nb += g & 1
                g >>= 1
            I[I_COUNTERS + C_GATED] += nb
        if I[I_LAST_DOF]:
            I[I_UPDATED] = 1
            if kind & 1:
                F[F_T_UPD_W] = t
            if kind & 2:
                F[F_T_UPD_V] = t
            I[I_COUNTERS + C_UPDATES] += 1
            if I[I_F_ADAPT]:
                M = I[I_CM_M]
                i = I[I_CM_I]
                _kernels.cm_push(CM[:M], CM[M:], i, F[F_DX:F_DX + 10], F[F_KSK:F_KSK + 10])
                i += 1
                I[I_CM_I] = 0 if i == M else i
                if I[I_CM_COUNT] < M:
                    I[I_CM_COUNT] += 1
    return post_update


def _stage_divergence(F, I, CM):                                          # pragma: no cover - compiled
    t = F[F_L_T]
    x = F[F_X:F_X + 10]
    updated = I[I_UPDATED] != 0
    nis = F[F_LAST_NIS] if updated else math.nan
    dof = I[I_LAST_DOF] if updated else 0
    v_wheel = F[F_L_VWHEEL]
    since = _mon_update(F, t, I[I_WHEEL_OUT], I[I_GROUND_OUT], nis, dof, x[4], v_wheel, x[9])
    if since == since:
        # Estimator._declare_lost
        I[I_COUNTERS + C_LOST] += 1
        I[I_LOST] = 1
        I[I_UKF] = 0
        I[I_CM_I] = 0
        I[I_CM_COUNT] = 0
        CM[:, :] = 0.0
        for i in range(10):
            F[F_A + i] = 1.0
        I[I_QB_VALID] = 0
        I[I_STATUS] |= FILTER_LOST
        F[F_L_SINCE] = since
        return ST_NONE
    _dyn_update(F, I, t, x[4], F[F_MD_SUM])
    if t - F[F_T_ADAPT] >= F[F_C_ADAPT_PERIOD]:
        F[F_T_ADAPT] = t
        I[I_QB_VALID] = 0
        return ST_ADAPT
    return ST_ESTIMATE


def _mk_stage_adapt(tag):
    """_stage_adapt closed over the dependency tag (:func:`_dep_tag`)."""
    def _stage_adapt(F, I, CM, FZ):                                           # pragma: no cover - compiled
        """The adaptation period (Estimator.step): A_k (CovarianceMatching.compute), the fuzzy supervisor's rule
        strengths and their intensity (FuzzySupervisor.intensity: its memo, else the centroid over ``FZ``, its
        ``centroid_table``, entered into the memo)."""
        if tag < 0:                  # never: ties the compiled code (and its cache entry) to the kernels' source
            raise AssertionError("dependency tag")
        if I[I_F_ADAPT]:
            M = I[I_CM_M]
            A = F[F_A:F_A + 10]
            if I[I_CM_COUNT] < M:
                A[:] = 1.0
            else:
                _kernels.cm_ratio(CM[:M], CM[M:], F[F_C_A_MIN], F[F_C_A_MAX], A)
        if I[I_F_SUP] == 0:
            return ST_ADAPT2
        c = F_C_FZ
        st = F[F_FZ_ST:F_FZ_ST + 3]
        _kernels.fuzzy_strengths(abs(F[F_DYN + 3]), abs(F[F_DYN + 4]), F[c], F[c + 1], F[c + 2], F[c + 3], F[c + 4],
                                 F[c + 5], I[I_FZ_RULES:I_FZ_RULES + 9].reshape((3, 3)), st)
        for j in range(I[I_FZ_N]):
            o = F_FZ_MEMO + 4 * j
            if F[o] == st[0] and F[o + 1] == st[1] and F[o + 2] == st[2]:
                F[F_FZ_C] = F[o + 3]
                return ST_ADAPT2
        c = _kernels.fuzzy_centroid(st[0], st[1], st[2], FZ)
        j = I[I_FZ_N]
        if j >= MEMO:
            j = 0
        o = F_FZ_MEMO + 4 * j
        F[o] = st[0]
        F[o + 1] = st[1]
        F[o + 2] = st[2]
        F[o + 3] = c
        I[I_FZ_N] = j + 1
        F[F_FZ_C] = c
        return ST_ADAPT2
    return _stage_adapt


def _stage_adapt2(F, I):                                                  # pragma: no cover - compiled
    """The rest of the adaptation period: f_k, the μ adaptation, the systematic uncertainty (Estimator._systematic);
    EV_SYSTEMATIC where that needs Python."""
    if I[I_F_SUP]:
        F[F_F] = F[F_C_FZ + 6] * math.exp(F[F_C_FZ + 7] * F[F_FZ_C])
    A = F[F_A:F_A + 10]
    mean = A[5]
    mean += A[6]
    mean += A[7]
    mean += A[8]
    F[F_ADAPT_MU] = F[F_F] * (mean / 4.0)
    f_unc = I[I_F_UNC]
    if f_unc == 0:
        return ST_ESTIMATE
    if f_unc == 2:
        return EV_SYSTEMATIC
    u = F[F_U:F_U + 7]
    _, _, rdf, rdr = _load_floats(F, u[4], u[5])
    _systematic(F, I, u, u[4], u[5], rdf * F[F_KF], rdr * F[F_KR], F[F_UR], F[F_UR + 1])
    return ST_ESTIMATE


def _systematic(F, I, md, fzf, fdx, rdf, rdr, ur_f, ur_r):                # pragma: no cover - compiled
    """SystematicUncertainty.variances (without a pull-angle tolerance) and Estimator._systematic's use of them,
    same operations."""
    c = F_C_UNC
    u_g, u_eta, tan_pull, u_m0, u_a0, u_ag, u_d0, u_dg = (F[c], F[c + 1], F[c + 2], F[c + 4], F[c + 5], F[c + 6],
                                                          F[c + 7], F[c + 8])
    weight = F[c + 10]
    mg = F[c + 11]
    ff = 0.5 * fzf
    fr = 0.5 * (weight - fzf) if tan_pull == 0.0 else 0.5 * ((weight - fzf) + fdx * tan_pull)
    u_fz = 0.5 * math.sqrt(_pow2(F, u_a0) + _pow2(F, u_ag * fzf))
    g2 = u_g * u_g
    if u_eta != 0.0:
        g2 += u_eta * u_eta
    m02 = u_m0 * u_m0
    sv = F[F_SYS_VAR:F_SYS_VAR + 5]
    f_r0 = 0.0
    f_r1 = 0.0
    off2 = 0.0
    for i in range(4):
        front = i < 2
        r = rdf if front else rdr
        fz = ff if front else fr
        ur = ur_f if front else ur_r
        m_r = md[i] / r
        cc = m_r / fz
        lz = u_fz / fz
        sv[i] = cc * cc * (g2 + ur * ur + lz * lz) + m02 / _pow2(F, r * fz)
        if front:
            f_r0 += abs(m_r)
        else:
            f_r1 += abs(m_r)
        off2 += m02 / (r * r)
    tot = f_r0 + f_r1
    num = (_pow2(F, u_g * tot) + _pow2(F, u_eta * tot) + _pow2(F, ur_f * f_r0) + _pow2(F, ur_r * f_r1) + off2
           + _pow2(F, u_d0) + _pow2(F, u_dg * fdx))
    sv[4] = num / (mg * mg)
    fin = True
    for i in range(5):
        if not math.isfinite(sv[i]):
            fin = False
    if not fin:
        sv[:] = 0.0
    I[I_HAS_SYS] = 1
    flag = 0
    for i in range(5):
        if sv[i] > F[F_P + (5 + i) * 11]:
            flag = 1
    I[I_SYS_FLAG] = flag
    a = F[F_DYN + 3]
    F[F_R_LAT] = F[c + 9] * a * a


def _mon_update(F, t, wheel_out, ground_out, nis, dof, v_hat, v_wheel, rho):  # pragma: no cover - compiled
    """DivergenceMonitor.update; the start of the lost period, or NaN."""
    lost_after = F[F_C_LOST_AFTER]
    if lost_after <= 0.0:
        return math.nan
    o = F_MON
    if wheel_out >= 0:
        if wheel_out == 0:
            F[o + 1] = math.nan
        elif F[o + 1] != F[o + 1]:
            F[o + 1] = t
    if ground_out >= 0:
        if ground_out == 0:
            F[o + 2] = math.nan
        elif F[o + 2] != F[o + 2]:
            F[o + 2] = t
    if dof > 0:
        if nis <= F[F_C_MON_BOUND + (dof if dof <= 8 else 8)]:
            F[o] = math.nan
        elif F[o] != F[o]:
            F[o] = t
    first = t
    for j in (1, 2, 0):
        s = F[o + j]
        if s == s and s < first:
            first = s
    if t - first >= lost_after:
        _mon_reset(F)
        return first
    if v_wheel != v_wheel:
        return math.nan
    ms = F[F_C_MON_MINSPD]
    moving = v_wheel >= ms or v_wheel <= -ms
    if moving and (v_hat >= ms and v_wheel < 0.0 or v_hat <= -ms and v_wheel > 0.0):
        _mon_reset(F)
        return t
    if moving and rho >= 0.9 * F[F_C_MON_RHO_MAX]:
        if F[o + 3] != F[o + 3]:
            F[o + 3] = t
        elif t - F[o + 3] >= lost_after:
            since = F[o + 3]
            _mon_reset(F)
            return since
    else:
        F[o + 3] = math.nan
    return math.nan


def _dyn_update(F, I, t, v, m_total):                                     # pragma: no cover - compiled
    """DynamicsMonitor.update: t, v, m, accel, torque_rate, dt, k."""
    o = F_DYN
    if I[I_DYN_INIT] == 0:
        I[I_DYN_INIT] = 1
        F[o] = t
        F[o + 1] = v
        F[o + 2] = m_total
        return
    dt = t - F[o]
    if dt <= 0.0:
        return
    if dt != F[o + 5]:
        F[o + 5] = dt
        F[o + 6] = 1.0 - math.exp(-dt / F[F_C_DYN_TAU])
    k = F[o + 6]
    v_new = F[o + 1] + k * (v - F[o + 1])
    m_new = F[o + 2] + k * (m_total - F[o + 2])
    F[o + 3] += k * ((v_new - F[o + 1]) / dt - F[o + 3])
    F[o + 4] += k * ((m_new - F[o + 2]) / dt - F[o + 4])
    F[o] = t
    F[o + 1] = v_new
    F[o + 2] = m_new


def _mk_stage_estimate(tag):
    """_stage_estimate closed over the dependency tag (:func:`_dep_tag`)."""
    def _stage_estimate(F, I):                                                # pragma: no cover - compiled
        """Estimator._estimate up to the curve update: outputs, convergence and slip tests."""
        if tag < 0:                  # never: ties the compiled code (and its cache entry) to the kernels' source
            raise AssertionError("dependency tag")
        t = F[F_L_T]
        if I[I_LOST]:
            I[I_STATUS] |= FILTER_LOST
        c_mu = F[F_C_CMU]
        c_rho = F[F_C_CRHO]
        if I[I_CONV]:
            c_mu *= F[F_C_EXIT2]
            c_rho *= F[F_C_EXIT2]
        kap = F[F_U + 6]
        ff0, fr0, rdf0, rdr0 = _load_floats(F, F[F_U + 4], F[F_U + 5])
        rdf = rdf0
        rdr = rdr0
        buf = F[F_L_BUF:F_L_BUF + 26]
        x = F[F_X:F_X + 10]
        code = _kernels.estimate_outputs(x, F[F_P:F_P + 100].reshape((10, 10)), rdf * F[F_KF], rdr * F[F_KR], c_mu,
                                         c_rho, kap, F[F_C_HB], F[F_C_WB], F[F_KAPVAR], F[F_C_SLIP_MAX], buf,
                                         F[F_C_KC:F_C_KC + 18], F[F_U:F_U + 7])
        v = x[4]
        F[F_L_V] = v
        I[I_CONV_P] = 1 if (code & 1) == 1 else 0
        slip_ok = code >= 2
        I[I_SLIP_OK] = 1 if slip_ok else 0
        if (t - F[F_T_CURVE] >= F[F_C_CURVE_PERIOD] and abs(v) >= F[F_C_CURVE_MINSPD] and not I[I_LOST]
                and slip_ok and -KAPPA_MAX < kap < KAPPA_MAX):
            F[F_T_CURVE] = t
            # ∂s/∂v·σ_v and ∂s/∂κ·σ_κ of eq. 6, the wheel's ground speed k_i(κ)·v (Estimator._estimate)
            h = 0.5 * F[F_C_TRACK]
            wb = F[F_C_WB]
            left = 1.0 - h * kap
            right = 1.0 + h * kap
            lk = wb * kap
            kfl = math.sqrt(left * left + lk * lk)
            kfr = math.sqrt(right * right + lk * lk)
            kv = F[F_KAPVAR]
            for i in range(4):
                dk = ((-h * left + wb * lk) / kfl if i == 0 else ((h * right + wb * lk) / kfr if i == 1 else
                                                                 (-h if i == 2 else h)))
                kw = buf[22 + i]
                vd = v * dk
                sig_vi = math.sqrt(buf[16] * kw * kw + vd * vd * kv)
                rd = rdf0 if i < 2 else rdr0
                den = rd * abs(buf[8 + i])
                if not den != den and den < 1e-3:
                    den = 1e-3
                F[F_L_SIG_S + i] = sig_vi / den
                F[F_L_SIG_MU + i] = math.sqrt(buf[17 + i])
            F[F_L_LOAD] = ff0
            F[F_L_LOAD + 1] = fr0
            F[F_L_LOAD + 2] = rdf0
            F[F_L_LOAD + 3] = rdr0
            return EV_CURVE
        return ST_ESTIMATE2
    return _stage_estimate


def _mk_curve_jit(tag):
    """_curve_jit closed over the dependency tag (:func:`_dep_tag`)."""
    def _curve_jit(F, I, CV):                                                  # pragma: no cover - compiled
        """The μ(s) curve's update in the loop (CompiledLoop._ev_curve's call of CurveEstimator.update: μ̂, ŝ, σ_μ,
        σ_s and the wheel loads F_z front, front, rear, rear) by the same compiled update the step path calls
        (:func:`._curve_kernel.ce_update`) on the estimator's own state (CV: C, S, SI, B, MT, HT, HP, PD, SC and the
        curve records CR: per version Σ w μ̂, Σ w g(ŝ), evidence, pairs used, shape-information snapshot).  True when
        done (the new version recorded), False when Python must finish it (I[I_CURVE_R])."""
        if tag < 0:                  # never: ties the compiled code (and its cache entry) to the kernels' source
            raise AssertionError("dependency tag")
        C, S, SI, B, MT, HT, HP, PD, SC, CR = CV
        v = I[I_CS_VER] + 1
        if v >= CR.shape[0]:
            I[I_CURVE_R] = CURVE_REC_FULL
            return False
        b = F_L_BUF
        fz = np.empty(4)
        fz[0] = F[F_L_LOAD]
        fz[1] = F[F_L_LOAD]
        fz[2] = F[F_L_LOAD + 1]
        fz[3] = F[F_L_LOAD + 1]
        r = _curve_kernel.ce_update(C, S, SI, B, MT, HT, HP, PD, SC, F[F_L_T], F[b:b + 4], F[b + 4:b + 8],
                                    F[F_L_SIG_MU:F_L_SIG_MU + 4], F[F_L_SIG_S:F_L_SIG_S + 4], fz,
                                    I[I_CURVE_SHAPE] != 0, True, True)
        if r != _curve_kernel.DONE:
            I[I_CURVE_R] = r
            return False
        CR[v, 0] = C[_curve_kernel.C_NUM]
        CR[v, 1] = C[_curve_kernel.C_NUM + 1]
        CR[v, 2] = C[_curve_kernel.C_NUM + 2]
        CR[v, 3] = C[_curve_kernel.C_NUSED]
        CR[v, 4] = I[I_CURVE_INFO]
        I[I_CS_VER] = v
        I[I_HAS_CURVE] = -1          # asked for when an averaged slip needs it
        return True
    return _curve_jit


SLIP_STEADY_S = 1.0
"""Estimator's SLIP_STEADY_S (:mod:`.estimator`): the averaged slip's steadiness time [s]."""


def _bisect_left(WIN, lo, n, col, x):                                     # pragma: no cover - compiled
    a = 0
    b = n
    while a < b:
        mid = (a + b) // 2
        if WIN[lo + mid, col] < x:
            a = mid + 1
        else:
            b = mid
    return a


def _slip_window(F, I, WIN, EV):                                          # pragma: no cover - compiled
    """Estimator._slip_window up to the curve's slope: returns -1 (no average), 0 (candidates in EV for the
    driver), EV_WINFULL or EV_HASCURVE (I[I_HAS_CURVE] -1: not known yet)."""
    t = F[F_L_T]
    v = F[F_L_V]
    buf = F[F_L_BUF:F_L_BUF + 26]
    d = 1.0 if v > 0.0 else -1.0
    n = I[I_WIN_N]
    lo = I[I_WIN_LO]
    if n and (d != F[F_WIN_DIR] or not 0.0 < t - WIN[lo + n - 1, 0] <= F[F_C_MAX_GAP]):
        _win_reset(I)
        n = 0
        lo = 0
    if n == 0:
        F[F_WIN_DIR] = d
        WIN[0, :] = 0.0
        WIN[0, 0] = t
        I[I_WIN_N] = 1
        I[I_WIN_LO] = 0
        return -1
    if lo + n >= WIN.shape[0]:
        # drop what no window reaches any more (the step path drops it past 4096 entries; the same windows)
        j_lo = _bisect_left(WIN, lo, n, 1, WIN[lo + n - 1, 1] - F[F_C_AVG_MAX])
        jt = _bisect_left(WIN, lo, n, 0, t - SLIP_STEADY_S)      # nor the steadiness test's look-back
        if jt < j_lo:
            j_lo = jt
        if j_lo == 0:
            return EV_WINFULL
        keep = n - j_lo
        for r in range(keep):
            for c in range(19):
                WIN[r, c] = WIN[lo + j_lo + r, c]
        lo = 0
        n = keep
        I[I_WIN_LO] = 0
        I[I_WIN_N] = n
    if I[I_HAS_CURVE] < 0:
        return EV_HASCURVE           # (nothing changed yet: the same stage runs again with the answer)
    _, _, rdf, rdr = _load_floats(F, F[F_U + 4], F[F_U + 5])
    rdf *= F[F_KF]
    rdr *= F[F_KR]
    av = abs(v)
    last = lo + n - 1
    dt = t - WIN[last, 0]
    kap = F[F_U + 6]
    hb = F[F_C_HB]
    wb = F[F_C_WB]
    # wheel_speed_factor_slopes(kap, 2 hb, wb)
    h = 0.5 * (2.0 * hb)
    left = 1.0 - h * kap
    right = 1.0 + h * kap
    lk = wb * kap
    kfl = math.sqrt(left * left + lk * lk)
    kfr = math.sqrt(right * right + lk * lk)
    dk0 = (-h * left + wb * lk) / kfl
    dk1 = (h * right + wb * lk) / kfr
    dk2 = -h
    dk3 = h
    nw = last + 1
    WIN[nw, 0] = t
    WIN[nw, 1] = WIN[last, 1] + av * dt
    WIN[nw, 2] = WIN[last, 2] + buf[12 + 4] * dt
    for i in range(4):
        ki = buf[22 + i]
        rd = rdf if i < 2 else rdr
        dk = dk0 if i == 0 else (dk1 if i == 1 else (dk2 if i == 2 else dk3))
        WIN[nw, 3 + i] = WIN[last, 3 + i] + ki * av * dt
        WIN[nw, 7 + i] = WIN[last, 7 + i] + abs(rd * buf[8 + i]) * dt
        WIN[nw, 11 + i] = WIN[last, 11 + i] + abs(v * dk) * dt
        WIN[nw, 15 + i] = WIN[last, 15 + i] + buf[i] * av * dt
    n += 1
    I[I_WIN_N] = n
    if I[I_HAS_CURVE] == 0 or n < 3:
        return -1
    tau = F[F_C_AVG_CORR]
    kv = F[F_KAPVAR]
    bound = F[F_C_SLIP_MAX]
    cn = lo + n - 1
    # steady travel only: each wheel's rolled speed now against its mean over the last SLIP_STEADY_S (same
    # operations as the step path)
    jq = _bisect_left(WIN, lo, n, 0, t - SLIP_STEADY_S)
    if jq > n - 2:
        jq = n - 2
    tq = t - WIN[lo + jq, 0]
    for i in range(4):
        rd = rdf if i < 2 else rdr
        rq = (WIN[cn, 7 + i] - WIN[lo + jq, 7 + i]) / tq
        if not (rq > 0.0 and abs(abs(rd * buf[8 + i]) - rq) <= bound * rq):
            return -1
    length = F[F_C_AVG_MAX]
    lastj = -1
    nc = 0
    ws_last = WIN[cn, 1]
    for _ in range(16):
        j = _bisect_left(WIN, lo, n, 1, ws_last - length)
        length *= 0.8
        if j == lastj or j > n - 3:
            continue
        lastj = j
        cj = lo + j
        T = WIN[cn, 0] - WIN[cj, 0]
        S = ws_last - WIN[cj, 1]
        if not (T > 0.0 and S > 0.0):
            continue
        r = tau / T
        var_v = (WIN[cn, 2] - WIN[cj, 2]) / T * 2.0 * r * (1.0 - r * (1.0 - math.exp(-1.0 / r)))
        base = 1 + nc * N_CAND_COLS
        ok = True
        mx = 0.0
        for i in range(4):
            g = WIN[cn, 3 + i] - WIN[cj, 3 + i]
            w = WIN[cn, 7 + i] - WIN[cj, 7 + i]
            kk = WIN[cn, 11 + i] - WIN[cj, 11 + i]
            # a wheel that rolled less than half its ground distance (s̄ < −0.5) is locked or its speed is dead:
            # no driven wheel slides so under drive torque, and its σ from the distances is near zero (four
            # wheel speeds stuck at 0 reported slip −1 as supported)
            if not (g > 0.0 and w > 0.5 * g):
                ok = False
                break
            sg = math.sqrt(g * g / (S * S) * var_v * T * T + kk * kk * kv)
            if g <= w:
                EV[base + i] = 1.0 - g / w
                sgi = sg / w
            else:
                EV[base + i] = -1.0 + w / g
                sgi = sg * w / (g * g)
            EV[base + 4 + i] = sgi
            mx = sgi if i == 0 else _pymax(mx, sgi)
            EV[base + 8 + i] = (WIN[cn, 15 + i] - WIN[cj, 15 + i]) / S
        if not ok or mx > bound:
            continue
        EV[base + 12] = S
        nc += 1
    EV[0] = nc
    I[I_N_CAND] = nc
    return 0 if nc > 0 else -1


def _stage_estimate2(F, I, WIN, EV):                                      # pragma: no cover - compiled
    """Estimator._estimate after the curve update: convergence, standstill, the slip's support."""
    t = F[F_L_T]
    conv = F[F_T_INIT] == F[F_T_INIT] and t - F[F_T_INIT] >= F[F_C_CONV_MIN] and I[I_CONV_P] != 0
    I[I_CONV] = 1 if conv else 0
    status = I[I_STATUS]
    if not conv:
        status |= NOT_CONVERGED
    elif I[I_LOST]:
        I[I_LOST] = 0
        status &= ~FILTER_LOST
    I[I_STATUS] = status
    buf = F[F_L_BUF:F_L_BUF + 26]
    F[F_L_RHO] = F[F_X + 9]
    for i in range(4):
        F[F_L_S + i] = buf[4 + i]
    v = F[F_L_V]
    I[I_AVG_FOUND] = 0
    if abs(v) < F[F_C_STANDSTILL]:
        return ST_ESTIMATE3
    if I[I_SLIP_OK] == 0 and F[F_C_AVG_MAX] > 0.0 and -KAPPA_MAX < F[F_U + 6] < KAPPA_MAX:
        r = _slip_window(F, I, WIN, EV)
        if r == 0:
            return EV_SLIPWIN
        if r == EV_WINFULL or r == EV_HASCURVE:
            return r
    return ST_ESTIMATE3


def _stage_slipwin2(F, I, EV):                                            # pragma: no cover - compiled
    """The rest of Estimator._slip_window with the curve's slopes (EV, from the driver): each candidate's σ with
    the lag behind a changing μ, the smallest chosen if within slip_sigma_max (same operations)."""
    nc = I[I_N_CAND]
    best = -1
    top_best = math.inf
    for c in range(nc):
        base = 1 + c * N_CAND_COLS
        top = 0.0
        for i in range(4):
            slope = EV[base + 13 + i]
            lag = abs(F[F_L_BUF + i] - EV[base + 8 + i]) / slope if slope > 0.0 else math.inf
            sg = EV[base + 4 + i]
            si = math.sqrt(sg * sg + lag * lag)
            top = si if si > top else top
        if top < top_best:
            top_best = top
            best = c
    if best >= 0 and top_best <= F[F_C_SLIP_MAX]:
        base = 1 + best * N_CAND_COLS
        for i in range(4):
            F[F_L_S + i] = EV[base + i]
        I[I_AVG_FOUND] = 1
    return ST_ESTIMATE3


def _stage_estimate3(F, I, OUT, k):                                       # pragma: no cover - compiled
    """The rest of Estimator._estimate: held values, the estimate's row."""
    status = I[I_STATUS]
    v = F[F_L_V]
    conv = I[I_CONV] != 0
    slip_ok = I[I_SLIP_OK] != 0
    if abs(v) < F[F_C_STANDSTILL]:
        status |= STANDSTILL
        if I[I_HAS_HELD]:
            F[F_L_RHO] = F[F_HELD_RHO]
            for i in range(4):
                F[F_L_S + i] = F[F_HELD_S + i]
        if I[I_WIN_N]:
            _win_reset(I)
    else:
        # the curvature input at its clip: the slip is not known (Estimator._estimate)
        clipped = not -KAPPA_MAX < F[F_U + 6] < KAPPA_MAX
        if clipped:
            status |= SLIP_UNCERTAIN
            if I[I_HAS_HELD]:
                for i in range(4):
                    F[F_L_S + i] = F[F_HELD_S + i]
            if I[I_WIN_N]:
                _win_reset(I)
        elif not slip_ok:
            if I[I_AVG_FOUND]:
                status |= SLIP_AVERAGED
            else:
                status |= SLIP_UNCERTAIN
                if I[I_HAS_HELD]:
                    for i in range(4):
                        F[F_L_S + i] = F[F_HELD_S + i]
        elif I[I_WIN_N]:
            _win_reset(I)
        if conv and ((slip_ok and not clipped) or I[I_HAS_HELD]):
            I[I_HAS_HELD] = 1
            F[F_HELD_RHO] = F[F_L_RHO]
            for i in range(4):
                F[F_HELD_S + i] = F[F_L_S + i]
    if I[I_SYS_FLAG]:
        status |= UNVERIFIED
    I[I_STATUS] = status
    buf = F[F_L_BUF:F_L_BUF + 26]
    row = OUT[k]
    row[OUT_T] = F[F_L_T]
    for i in range(4):
        row[OUT_MU + i] = buf[i]
        row[OUT_SLIP + i] = F[F_L_S + i]
        row[OUT_OM + i] = buf[8 + i]
    row[OUT_RHO] = F[F_L_RHO]
    row[OUT_V] = v
    for i in range(10):
        row[OUT_P + i] = buf[12 + i]
    updated = I[I_UPDATED] != 0
    row[OUT_NIS] = F[F_LAST_NIS] if updated else math.nan
    row[OUT_DOF] = I[I_LAST_DOF] if updated else 0
    row[OUT_ADAPT] = F[F_ADAPT_MU]
    row[OUT_STATUS] = status
    row[OUT_VALID] = 1.0 if (status & INVALID_MASK) == 0 else 0.0
    row[OUT_LOST] = math.nan
    has_sys = I[I_HAS_SYS] != 0
    for i in range(5):
        p = buf[17 + i]
        row[(OUT_SIGMU + i) if i < 4 else OUT_SIGRHO] = math.sqrt(p + F[F_SYS_VAR + i] if has_sys else p)
    for i in range(6):
        row[OUT_RAD + i] = F[F_RAD + i]
    row[OUT_CS] = I[I_CS_VER]
    row[OUT_HASX] = 1.0
    row[OUT_HASSYS] = 1.0 if has_sys else 0.0
    if I[I_SM_ON]:
        link = I[I_SM_LINK] != 0
        row[OUT_SM_LINK] = 1.0 if link else 0.0
        for j in range(10):
            xj = F[F_X + j]
            row[OUT_SM_XF + j] = xj
            F[F_SM_XF + j] = xj
            row[OUT_SM_XP + j] = F[F_SM_XP + j] if link else math.nan
        for j in range(100):
            row[OUT_SM_G + j] = F[F_SM_G + j] if link else math.nan
        I[I_SM_HAS] = 1
    if I[I_F_CAL] and I[I_HAS_VMEAS] and I[I_HAS_OM]:
        if I[I_CAL_OPEN] == 0 and _cal_rejects(F, row):
            # RadiusCalibration.push of an epoch it rejects while no block is open: the epoch period's
            # smoothing, the count of rejections and the last epoch's time, nothing else (kept here, handed to
            # the calibration before its next push and at the block's end)
            tl = F[F_CAL + 1]
            t = F[F_L_T]
            if math.isfinite(tl) and t > tl:
                dt = t - tl
                per = F[F_CAL]
                F[F_CAL] = dt if not per > 0.0 else 0.9 * per + 0.1 * dt
            F[F_CAL + 2] += 1.0
            F[F_CAL + 1] = t
            return ST_END
        ff, fr, rdf, rdr = _load_floats(F, F[F_U + 4], F[F_U + 5])
        F[F_L_LOAD] = ff
        F[F_L_LOAD + 1] = fr
        F[F_L_LOAD + 2] = rdf
        F[F_L_LOAD + 3] = rdr
        return EV_CAL
    return ST_END


def _stage_none(F, I, OUT, k):                                            # pragma: no cover - compiled
    """Estimator._estimate without a filter: the NaN estimate (lost_since on the step a filter is lost)."""
    status = I[I_STATUS]
    if I[I_LOST]:
        status |= FILTER_LOST
    if I[I_WIN_N]:
        _win_reset(I)
    status |= NOT_CONVERGED
    I[I_SM_HAS] = 0
    row = OUT[k]
    row[:] = math.nan
    row[OUT_T] = F[F_L_T]
    row[OUT_ADAPT] = F[F_F]
    row[OUT_STATUS] = status
    row[OUT_VALID] = 0.0
    row[OUT_DOF] = 0
    row[OUT_LOST] = F[F_L_SINCE]
    for i in range(6):
        row[OUT_RAD + i] = F[F_RAD + i]
    row[OUT_CS] = I[I_CS_VER]
    row[OUT_HASX] = 0.0
    row[OUT_HASSYS] = 0.0
    return ST_END


def _mkrun(tag):
    """run closed over the dependency tag (:func:`_dep_tag`)."""
    def run(F, I, IN, OUT, EV, CM, RB, WIN, n, CV, FZ):                       # pragma: no cover - compiled
        """Step the estimator from step I[I_K] (at stage I[I_STAGE]) until step n or an event (module doc).
        ``CV``: the compiled curve update's state (:func:`_curve_jit`; with I[I_CURVE_JIT] 0 it is not used);
        ``FZ``: the fuzzy supervisor's centroid table (FuzzySupervisor.centroid_table).

        Returns EV_DONE when every step up to n is done, else the event's code; the stage to resume at is
        in I[I_STAGE] (the driver sets it when its handler decides)."""
        if tag < 0:                  # never: ties the compiled code (and its cache entry) to the kernels' source
            raise AssertionError("dependency tag")
        while I[I_K] < n:
            k = I[I_K]
            st = I[I_STAGE]
            if st == ST_BEGIN:
                F[F_L_SINCE] = math.nan
                I[I_SM_LINK] = 0
                nxt = _stage_begin(F, I, RB, IN, k)
                if nxt == EV_INIT:
                    I[I_STAGE] = ST_AFTER_INIT
                    return EV_INIT
                I[I_STAGE] = nxt
            elif st == ST_AFTER_INIT:
                F[F_T] = F[F_L_T]
                I[I_STATUS] |= NOT_CONVERGED
                I[I_STAGE] = ST_NONE
            elif st == ST_PREDICT:
                nxt = _stage_predict(F, I)
                if nxt == EV_PREDICT or nxt == EV_RECOVER:
                    return nxt               # the driver sets the stage
                I[I_STAGE] = nxt
            elif st == ST_AFTER_PREDICT:
                I[I_STAGE] = _stage_after_predict(F, I)
            elif st == ST_UPDATE:
                nxt = _stage_update(F, I, CM)
                if nxt == EV_UPDATE:
                    I[I_STAGE] = ST_POST_UPDATE
                    return EV_UPDATE
                I[I_STAGE] = nxt
            elif st == ST_POST_UPDATE:
                I[I_STAGE] = ST_DIVERGENCE       # (the driver did the bookkeeping of the general path)
            elif st == ST_DIVERGENCE:
                I[I_STAGE] = _stage_divergence(F, I, CM)
            elif st == ST_ADAPT:
                I[I_STAGE] = _stage_adapt(F, I, CM, FZ)
            elif st == ST_ADAPT2:
                nxt = _stage_adapt2(F, I)
                if nxt == EV_SYSTEMATIC:
                    I[I_STAGE] = ST_ESTIMATE
                    return EV_SYSTEMATIC
                I[I_STAGE] = nxt
            elif st == ST_ESTIMATE:
                nxt = _stage_estimate(F, I)
                if nxt == EV_CURVE:
                    I[I_STAGE] = ST_ESTIMATE2
                    if I[I_CURVE_JIT] == 0:
                        return EV_CURVE
                    if not _curve_jit(F, I, CV):
                        return EV_CURVEJ
                    continue
                I[I_STAGE] = nxt
            elif st == ST_ESTIMATE2:
                nxt = _stage_estimate2(F, I, WIN, EV)
                if nxt == EV_SLIPWIN:
                    I[I_STAGE] = ST_SLIPWIN2
                    return EV_SLIPWIN
                if nxt == EV_WINFULL or nxt == EV_HASCURVE:
                    return nxt                   # the same stage again (a larger buffer, the curve's presence)
                I[I_STAGE] = nxt
            elif st == ST_SLIPWIN2:
                I[I_STAGE] = _stage_slipwin2(F, I, EV)
            elif st == ST_ESTIMATE3:
                nxt = _stage_estimate3(F, I, OUT, k)
                if nxt == EV_CAL:
                    I[I_STAGE] = ST_END
                    return EV_CAL
                I[I_STAGE] = nxt
            elif st == ST_NONE:
                I[I_STAGE] = _stage_none(F, I, OUT, k)
            else:                                # ST_END
                I[I_K] = k + 1
                I[I_STAGE] = ST_BEGIN
        return EV_DONE
    return run


_load_floats = compiled(_load_floats, inline=True)
_cal_rejects = compiled(_cal_rejects)
_wrap = compiled(_wrap, inline=True)
_pymax = compiled(_pymax, inline=True)
_pow2 = compiled(_pow2)
_rate_median = compiled(_rate_median)
_rate_push = compiled(_rate_push)
_rate_refresh = compiled(_rate_refresh)
_kin_predict = compiled(_kin_predict)
_kin_wheels = compiled(_kin_wheels)
_kin_standstill = compiled(_kin_standstill)
_kin_course = compiled(_kin_course)
_kin_course_direction = compiled(_kin_course_direction)
_rebuild_Q = compiled(_mk_rebuild_Q(_TAG))
_make_Q = compiled(_mk_make_Q(_TAG))
_win_reset = compiled(_win_reset)
_mon_reset = compiled(_mon_reset)
_stage_begin = compiled(_stage_begin)
_stage_predict = compiled(_mk_stage_predict(_TAG))
_foh = compiled(_foh)
_stage_after_predict = compiled(_stage_after_predict)
post_update = compiled(_mkpost_update(_TAG))
_stage_update = compiled(_mk_stage_update(_TAG))
_mon_update = compiled(_mon_update)
_dyn_update = compiled(_dyn_update)
_stage_divergence = compiled(_stage_divergence)
_stage_adapt = compiled(_mk_stage_adapt(_TAG))
_systematic = compiled(_systematic)
_stage_adapt2 = compiled(_stage_adapt2)
_stage_estimate = compiled(_mk_stage_estimate(_TAG))
_curve_jit = compiled(_mk_curve_jit(_TAG))
_bisect_left = compiled(_bisect_left)
_slip_window = compiled(_slip_window)
_stage_estimate2 = compiled(_stage_estimate2)
_stage_slipwin2 = compiled(_stage_slipwin2)
_stage_estimate3 = compiled(_stage_estimate3)
_stage_none = compiled(_stage_none)
run = compiled(_mkrun(_TAG))
