"""Recording → one regular, bin-averaged signal frame for diagnosis.

Diagnosis works on a fixed grid at the GNSS epoch rate (10 Hz for a CAN
recording, the export rate for a CSV).  CAN signals that arrive faster are
averaged over the bin ``[t_k − Δ/2, t_k + Δ/2)`` centred on each grid time, so
the averaging adds no phase lag; GNSS values are taken at their own epochs.

Nothing here reads ``truth.csv`` or ``truth.toml``: only what a real logger
has (CAN signals, NMEA, the nominal ``vehicle.toml``).

Derived quantities (SI units):

- local east/north position x, y [m] on a tangent plane at the first fix,
  x = R (λ − λ0) cos φ0, y = R (φ − φ0);
- heading ψ [rad] (0 = east, counter-clockwise) from the GNSS course over
  ground, ψ = π/2 − course;
- pass index: a new pass starts whenever the implement goes into work.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np
from numpy.typing import NDArray

from ..config import SensorSpec, VehicleParams, load_sensors, load_vehicle
from ..errors import RecordingError
from ..pipeline.gnss import GnssGate
from ..pipeline.signals import (DRAFT, DRIVE_TORQUES, ENGINE_PERCENT_TORQUE, ENGINE_REFERENCE_TORQUE, FRONT_AXLE_LOAD,
                                GROUND_BASED_SPEED, IN_WORK, VEHICLE_SPEED, WHEEL_BASED_SPEED, WHEEL_SPEEDS,
                                signal_state)
from ..recording.containers import MAX_TABLE_ROWS
from ..pipeline.survey import survey_keep
from ..recording.reader import Recording, read_recording, stream_signals
from ..recording.summary import other_source_lines, wrong_length_line

FRAME_SIGNALS = (*WHEEL_SPEEDS, *DRIVE_TORQUES, FRONT_AXLE_LOAD, DRAFT, IN_WORK, WHEEL_BASED_SPEED,
                 GROUND_BASED_SPEED, "EngineTorque", "EngineSpeed", ENGINE_PERCENT_TORQUE, VEHICLE_SPEED)
"""The CAN signals the frame bins (all a streamed recording is read for)."""
EARTH_R = 6378137.0
"""WGS84 equatorial radius [m]."""


@dataclass
class Frame:
    """Regular signal frame (arrays over the grid, NaN = not available)."""

    t: NDArray[np.float64]
    """Time since the start of the recording [s]."""
    t0_epoch: float
    """Epoch time of t = 0 [s]."""
    rate_hz: float
    vehicle: VehicleParams
    omega: NDArray[np.float64] | None = None
    """Wheel speeds (n, 4) [rad/s], order FL, FR, RL, RR."""
    md: NDArray[np.float64] | None = None
    """Drive torques at the wheels' motors (n, 4) [N·m]."""
    omega_dot: NDArray[np.float64] | None = None
    """Bin-mean wheel acceleration (n, 4) [rad/s²]: (ω(t + Δ/2) − ω(t − Δ/2))/Δ from the raw samples."""
    md_edge: NDArray[np.float64] | None = None
    """Drive torques at the bin edges t_k − Δ/2 (n + 1, 4) [N·m] (for rates of change within a bin)."""
    hf_t: NDArray[np.float64] | None = None
    """Times of the raw-rate wheel-speed grid [s] (k per frame bin, in bin order)."""
    hf_omega: NDArray[np.float64] | None = None
    """Wheel speeds on the raw-rate grid (n·k, 4) [rad/s]."""
    fzf: NDArray[np.float64] | None = None
    """Front-axle load [N]."""
    fdx: NDArray[np.float64] | None = None
    """Draft (horizontal drawbar pull) [N]."""
    work: NDArray[np.bool_] | None = None
    """Implement fully in work."""
    v_gps: NDArray[np.float64] | None = None
    """GNSS ground speed [m/s] (without GNSS, the radar's: :attr:`v_gps_source`)."""
    v_gps_source: str = "gnss"
    """Where :attr:`v_gps` comes from: ``gnss``, or ``radar`` (GBSD) on a recording without GNSS."""
    v_wheel_bus: NDArray[np.float64] | None = None
    """The tractor's own wheel-based speed (WBSD / CCVS) [m/s]."""
    alt: NDArray[np.float64] | None = None
    """GNSS altitude [m]."""
    x: NDArray[np.float64] | None = None
    y: NDArray[np.float64] | None = None
    heading: NDArray[np.float64] | None = None
    """Heading [rad], 0 = east, counter-clockwise."""
    engine_torque: NDArray[np.float64] | None = None
    """Engine torque [N·m] (CSV exports)."""
    engine_speed: NDArray[np.float64] | None = None
    """Engine speed [rad/s] (CSV exports)."""
    kappa: NDArray[np.float64] | None = None
    """Path curvature of the rear-axle centre [1/m], positive in a left turn, 0 where straight or unknown
    (:func:`~.features.path_curvature`; set by :func:`~.features.compute`)."""
    kappa_known: NDArray[np.bool_] | None = None
    """Where the curvature is defined (rear wheels turning); False at standstill or without wheel speeds."""
    lat_accel: NDArray[np.float64] | None = None
    """Lateral acceleration v² κ [m/s²] of the lateral load transfer (0 where κ is)."""
    fzf_modelled: bool = False
    """The front-axle load is modelled (static split minus load transfer from the vehicle file's
    hitch and centre-of-gravity heights), not measured."""
    can_time_offset_s: float = 0.0
    """Mean time of the CAN samples in a bin minus the bin's grid time [s] (an even number of
    samples per bin cannot be centred exactly); GNSS values are at the grid times."""
    source: str = ""
    notes: list[str] = field(default_factory=list)
    break_t: tuple[float, ...] = ()
    """Times t [s] at which the recording starts again after a break (the logger off, or the track
    jumping elsewhere; :func:`~.features.find_breaks`): no fit or residual spans one."""
    sensors: SensorSpec = field(default_factory=SensorSpec)
    """The vehicle file's ``[sensors]`` (their tolerances bound what the data cannot separate from a sensor
    error: :mod:`.intervals`); the documented defaults without one."""

    @property
    def n(self) -> int:
        return int(self.t.size)

    @property
    def dt(self) -> float:
        return 1.0 / self.rate_hz

    def has(self, *names: str) -> bool:
        """True when every named signal is present and has finite samples."""
        for nm in names:
            a = getattr(self, nm)
            if a is None or not np.any(np.isfinite(a)):
                return False
        return True

    def subset(self, mask: NDArray[np.bool_]) -> "Frame":
        """A copy restricted to the grid points in ``mask`` (no longer regular)."""
        kw = {}
        for f in self.__dataclass_fields__:
            v = getattr(self, f)
            if isinstance(v, np.ndarray) and v.shape[:1] == self.t.shape:
                kw[f] = v[mask]
            else:
                kw[f] = v
        return Frame(**kw)


def _bin_mean(src_t: NDArray[np.float64], src_v: NDArray[np.float64], grid: NDArray[np.float64],
              half: float) -> NDArray[np.float64]:
    """Mean of the samples in [grid − half, grid + half) (NaN where the bin is empty)."""
    ok = np.isfinite(src_v)
    st, sv = src_t[ok], src_v[ok]
    if st.size == 0:
        return np.full(grid.size, np.nan)
    cs = np.concatenate([[0.0], np.cumsum(sv)])
    lo = np.searchsorted(st, grid - half, side="left")
    hi = np.searchsorted(st, grid + half, side="left")
    cnt = hi - lo
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(cnt > 0, (cs[hi] - cs[lo]) / np.maximum(cnt, 1), np.nan)


def _at(src_t: NDArray[np.float64], src_v: NDArray[np.float64], grid: NDArray[np.float64],
        tol: float) -> NDArray[np.float64]:
    """Value of the sample nearest each grid time within ``tol`` [s] (NaN otherwise)."""
    if src_t.size == 0:
        return np.full(grid.size, np.nan)
    j = np.clip(np.searchsorted(src_t, grid), 1, src_t.size - 1) if src_t.size > 1 else np.zeros(grid.size, int)
    if src_t.size > 1:
        left = j - 1
        j = np.where(np.abs(src_t[left] - grid) <= np.abs(src_t[j] - grid), left, j)
    val = src_v[j].astype(float)
    return np.where(np.abs(src_t[j] - grid) <= tol, val, np.nan)


def local_xy(lat: NDArray[np.float64], lon: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Tangent-plane east/north [m] about the first finite fix."""
    ok = np.isfinite(lat) & np.isfinite(lon)
    if not ok.any():
        return np.full(lat.shape, np.nan), np.full(lat.shape, np.nan)
    lat0 = float(lat[ok][0])
    lon0 = float(lon[ok][0])
    x = np.radians(lon - lon0) * EARTH_R * math.cos(math.radians(lat0))
    y = np.radians(lat - lat0) * EARTH_R
    return x, y


MEDIAN_SAMPLES = 1 << 17
"""Wheel-speed samples (22 minutes at 100 Hz) from which the raw sample period is taken when a
recording is streamed: the median interval of the first ones (of all of them when it is shorter)."""


class _Windows:
    """Running means of samples over fixed time windows ``[lo, hi)``, fed block by block.

    ``lo``/``hi`` are the window bounds in grid order, ``per_bin`` windows per frame bin (the windows
    of bin k are ``k·per_bin ... (k+1)·per_bin − 1``).  Each block's samples (sorted in time) are summed
    into the windows it covers by a cumulative sum over the block, as :func:`_bin_mean` does over a
    whole series: fed as one block, the result is :func:`_bin_mean`'s."""

    def __init__(self, grid: NDArray[np.float64], lo: NDArray[np.float64], hi: NDArray[np.float64],
                 per_bin: int, period: float, width: int = 1) -> None:
        self.grid, self.lo, self.hi, self.per_bin, self.period = grid, lo, hi, per_bin, period
        self.sum = np.zeros((lo.size, width))
        self.cnt = np.zeros((lo.size, width), dtype=np.int32)
        self.t: NDArray[np.float64] | None = None

    def add(self, t: NDArray[np.float64], v: NDArray[np.float64], col: int = 0) -> None:
        ok = np.isfinite(v)
        st, sv = t[ok], v[ok]
        if st.size == 0:
            return
        k0 = max(int(np.searchsorted(self.grid, st[0] - 2 * self.period)) - 1, 0)
        k1 = min(int(np.searchsorted(self.grid, st[-1] + 2 * self.period)) + 1, self.grid.size)
        w0, w1 = k0 * self.per_bin, min(k1 * self.per_bin + (self.lo.size - self.grid.size * self.per_bin),
                                        self.lo.size)
        if w1 <= w0:
            return
        cs = np.concatenate([[0.0], np.cumsum(sv)])
        lo = np.searchsorted(st, self.lo[w0:w1], side="left")
        hi = np.searchsorted(st, self.hi[w0:w1], side="left")
        self.sum[w0:w1, col] += cs[hi] - cs[lo]
        self.cnt[w0:w1, col] += (hi - lo).astype(np.int32)

    def mean(self) -> NDArray[np.float64]:
        """(windows, width) means, NaN where a window is empty (the sums' memory is reused)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.divide(self.sum, np.maximum(self.cnt, 1), out=self.sum)
        out[self.cnt == 0] = np.nan
        return out


def _reference_torque(sig: Mapping, vehicle: VehicleParams) -> float | None:
    """The engine's reference torque [N·m]: EC1's (SPN 544, the median of its numbers), else the vehicle
    file's ``[drivetrain] engine_reference_torque_nm`` when it declares one."""
    s = sig.get(ENGINE_REFERENCE_TORQUE)
    if s is not None and len(s):
        v = np.asarray(s.value, dtype=float)
        v = v[np.isfinite(v) & (v > 0)]
        if v.size:
            return float(np.median(v))
    declared = float(vehicle.drivetrain.engine_reference_torque_nm)
    return declared if declared > 0 else None


def frame_from_recording(rec: Recording, vehicle: VehicleParams, rate_hz: float | None = None,
                         blocks: Iterable[Mapping[str, tuple[NDArray, NDArray]]] | None = None) -> Frame:
    """Resample a :class:`Recording` onto a regular grid (see module doc).

    ``blocks``: the CAN signals in blocks of ``{name: (t, value)}`` in time order (a streamed
    recording, :func:`tractionecu.recording.reader.stream_signals`); ``rec`` then needs only its
    survey (GNSS track, statistics and which signals exist).  Without ``blocks`` the signals of
    ``rec`` are the one block.  Memory is that of the frame and one block."""
    sig = rec.signals
    gps = rec.gps
    if rate_hz is None:
        if len(gps) > 2:
            rate_hz = 1.0 / float(np.median(np.diff(gps.t)))
        else:
            ts = [s.t for s in sig.values() if len(s) > 2]
            if not ts:
                raise RecordingError(f"{rec.path}: no signal with more than two samples")
            rate_hz = 1.0 / float(np.median(np.diff(max(ts, key=len))))
        rate_hz = min(rate_hz, 10.0)
    period = 1.0 / rate_hz
    t_start, t_end = rec.t_start, rec.t_end
    if not (t_end - t_start) * rate_hz < MAX_TABLE_ROWS:
        raise RecordingError(f"{rec.path}: {t_end - t_start:.3g} s at {rate_hz:g} Hz is more than {MAX_TABLE_ROWS} "
                             "rows; the recording's time jumps (see `tractionecu inspect`)")
    if len(gps) > 2:
        # Grid on the GNSS epochs (extended by whole periods where CAN data run longer).
        g0 = float(gps.t[0])
        k0 = math.ceil((t_start - g0) / period)
        k1 = math.floor((t_end - g0) / period)
        grid = g0 + np.arange(k0, k1 + 1) * period
    else:
        grid = t_start + np.arange(int(math.floor((t_end - t_start) / period)) + 1) * period
    half = 0.5 * period
    if blocks is None:
        blocks = [{name: (s.t, s.value) for name, s in sig.items()}]
    present = [n for n in FRAME_SIGNALS if len(sig.get(n, ()))]
    means = {n: _Windows(grid, grid - half, grid + half, 1, period) for n in present}
    have_wheels = all(n in means for n in WHEEL_SPEEDS) and all(n in means for n in DRIVE_TORQUES)
    edges = np.concatenate([grid - half, [grid[-1] + half]])
    w0name = WHEEL_SPEEDS[0]
    fine: dict[str, _Windows] = {}
    t_first = math.nan
    raw_dt = math.nan
    pending: list[Mapping[str, tuple[NDArray, NDArray]]] = []
    seen: list[NDArray] = []

    def start_fine() -> None:
        # Values at the bin edges from the raw samples nearest each edge (about ±1.5 sample periods),
        # and the raw wheel speeds on a uniform grid of the raw period (bin means), for dynamics
        # faster than the frame rate (tyre relaxation).
        nonlocal raw_dt
        tw = np.concatenate(seen) if seen else np.zeros(0)
        raw_dt = float(np.median(np.diff(tw))) if tw.size > 2 else period
        if not (have_wheels and raw_dt < 0.5 * period):
            return
        eh = 1.5 * raw_dt
        fine["edge"] = _Windows(grid, edges - eh, edges + eh, 1, period, width=8)
        k = int(round(period / raw_dt))
        hf_grid = (grid[:, None] + (np.arange(k) - (k - 1) / 2.0)[None, :] * raw_dt).ravel()
        fine["hf"] = _Windows(grid, hf_grid - raw_dt / 2, hf_grid + raw_dt / 2, k, period, width=4)
        fine["hf"].t = hf_grid

    def feed(block: Mapping[str, tuple[NDArray, NDArray]]) -> None:
        nonlocal t_first
        for name, (t, v) in block.items():
            acc = means.get(name)
            if acc is None:
                continue
            acc.add(t, v)
            if name == w0name and t.size:
                if not math.isfinite(t_first):
                    t_first = float(t[0])
                if "toff" not in fine:
                    fine["toff"] = _Windows(grid, grid - half, grid + half, 1, period)
                fine["toff"].add(t, t - t_first)
            if "edge" in fine:
                if name in WHEEL_SPEEDS:
                    i = WHEEL_SPEEDS.index(name)
                    fine["edge"].add(t, v, i)
                    fine["hf"].add(t, v, i)
                elif name in DRIVE_TORQUES:
                    fine["edge"].add(t, v, 4 + DRIVE_TORQUES.index(name))

    n_seen = 0
    for block in blocks:
        if pending is not None:
            pending.append(block)
            if w0name in block:
                seen.append(np.asarray(block[w0name][0], dtype=float))
                n_seen += seen[-1].size
            if n_seen < MEDIAN_SAMPLES:
                continue
            start_fine()
            for b in pending:
                feed(b)
            pending = None
            seen = []
            continue
        feed(block)
    if pending is not None:
        start_fine()
        for b in pending:
            feed(b)
        pending = None

    def mean(name: str) -> NDArray[np.float64] | None:
        acc = means.get(name)
        return None if acc is None else acc.mean()[:, 0]

    fr = Frame(t=grid - grid[0], t0_epoch=float(grid[0]), rate_hz=rate_hz, vehicle=vehicle, source=str(rec.path))
    if have_wheels:
        fr.omega = np.stack([mean(n) for n in WHEEL_SPEEDS], axis=1)
        fr.md = np.stack([mean(n) for n in DRIVE_TORQUES], axis=1)
    if "edge" in fine:
        e = fine["edge"].mean()
        fr.omega_dot = np.diff(e[:, :4], axis=0) / period
        fr.md_edge = np.ascontiguousarray(e[:, 4:])
        fr.hf_t = fine["hf"].t - grid[0]
        fr.hf_omega = fine["hf"].mean()
    if "toff" in fine and int(fine["toff"].cnt.sum()) > 2:
        tb = fine["toff"].mean()[:, 0] + t_first
        d = tb - grid
        fr.can_time_offset_s = float(np.nanmedian(d)) if np.isfinite(d).any() else 0.0
    fr.fzf = mean(FRONT_AXLE_LOAD)
    fr.fdx = mean(DRAFT)
    wk = mean(IN_WORK)
    if wk is not None:
        fr.work = np.nan_to_num(wk, nan=0.0) > 0.999
    elif fr.fdx is not None:
        fr.notes.append("no in-work indication: work inferred from draft > 30 % of its 95th percentile")
        d = np.nan_to_num(fr.fdx)
        fr.work = d > 0.3 * np.percentile(d, 95)
    fr.v_wheel_bus = mean(WHEEL_BASED_SPEED)
    if fr.v_wheel_bus is None:
        fr.v_wheel_bus = mean(VEHICLE_SPEED)              # CCVS1's wheel-based speed where no WBSD is sent
    fr.engine_torque = mean("EngineTorque")               # a decoded export's (csv_import)
    if fr.engine_torque is None and ENGINE_PERCENT_TORQUE in means:
        # a bus recording's EEC1: the indicated percent torque less the nominal friction percent (the vehicle
        # file's, as the machine-level estimator takes it) of the reference torque (EC1, SPN 544; else the
        # vehicle file's): the engine's net torque T_e = (p − p_f)/100 · T_ref
        ref = _reference_torque(sig, vehicle)
        if ref is not None:
            p_f = float(vehicle.drivetrain.engine_friction_percent)
            fr.engine_torque = (mean(ENGINE_PERCENT_TORQUE) - p_f) / 100.0 * ref
    fr.engine_speed = mean("EngineSpeed")
    if len(gps):
        tol = 0.6 * period
        # The epochs replay's gate refuses (receiver's invalid flag, no fix, HDOP, repeated) are not used here
        # either: an invalid epoch's speed of 0 read as a GNSS-speed mismatch 14 times its noise.
        refused: Counter[str] = Counter()
        judged = gps
        if len(gps) and (np.asarray(gps.fix_quality) < 0).all():
            # a decoded export without a fix-quality column: that check has nothing to judge by
            judged = dataclasses.replace(gps, fix_quality=np.ones_like(gps.fix_quality))
        keep = GnssGate().track_mask(judged, refused)
        if not keep.all():
            why = ", ".join(f"{k.removeprefix('gated_')} {n}" for k, n in refused.items())
            fr.notes.append(f"{int((~keep).sum())} of {len(gps)} GNSS epochs refused by the GNSS gate ({why}): "
                            "not used, as replay does not use them")

        def kept(v: NDArray[np.float64]) -> NDArray[np.float64]:
            return _at(gps.t, np.where(keep, v, np.nan), grid, tol)

        fr.v_gps = kept(gps.speed)
        fr.alt = kept(gps.alt)
        fr.x, fr.y = local_xy(kept(gps.lat), kept(gps.lon))
        course = kept(gps.course)
        fr.heading = np.where(np.isfinite(course), np.radians(90.0 - course), np.nan)
        fr.heading = _track_heading(fr)
    if fr.v_gps is None and GROUND_BASED_SPEED in means:
        fr.v_gps = mean(GROUND_BASED_SPEED)
        fr.v_gps_source = "radar"
        fr.notes.append("no GNSS: the radar's ground speed (GBSD) stands in for the GNSS speed; it is on the CAN "
                        "clock, so a CAN-to-GNSS clock skew is not tested, and a latency found is the radar's")
    if fr.v_gps is not None:
        d = travel_direction(fr.omega)
        if d is not None:
            fr.v_gps = fr.v_gps * d
            if (d < 0).any():
                fr.notes.append(f"reversing on {np.mean(d < 0):.1%} of the recording (the wheels' sense of "
                                "rotation): the GNSS speed, which carries no sign, takes it")
    return fr


DIRECTION_MIN_RAD_S = 0.2
"""Mean wheel speed [rad/s] beyond which its sign gives the direction of travel (about 0.15 m/s)."""


def mean_wheel_speed(omega: NDArray[np.float64]) -> NDArray[np.float64]:
    """Each row's mean of its finite wheel speeds [rad/s] (rows × wheels, or one wheel-based speed per row);
    NaN where none is finite."""
    om = np.asarray(omega, dtype=float)
    if om.ndim == 1:
        om = om[:, None]
    fin = np.isfinite(om)
    cnt = fin.sum(axis=1)
    return np.where(cnt > 0, np.where(fin, om, 0.0).sum(axis=1) / np.maximum(cnt, 1), np.nan)


def travel_direction(omega: NDArray[np.float64] | None) -> NDArray[np.float64] | None:
    """The direction of travel per row, ±1, from the sign of the mean wheel speed (a drive measures its sense of
    rotation): held through standstill and creeping (|mean ω| ≤ :data:`DIRECTION_MIN_RAD_S`), forward before the
    first decided row; None without wheel speeds.  The GNSS speed over ground (RMC/VTG) carries no sign."""
    if omega is None:
        return None
    w = mean_wheel_speed(omega)
    d = np.where(w > DIRECTION_MIN_RAD_S, 1.0, np.where(w < -DIRECTION_MIN_RAD_S, -1.0, np.nan))
    idx = np.where(np.isfinite(d), np.arange(d.size), -1)
    idx = np.maximum.accumulate(idx)
    out = np.where(idx >= 0, d[np.maximum(idx, 0)], 1.0)
    return out


def _track_heading(fr: Frame) -> NDArray[np.float64] | None:
    """Heading from the GNSS course where moving; from the track where the course is missing."""
    h = fr.heading
    if fr.x is None:
        return h
    dx = np.gradient(fr.x)
    dy = np.gradient(fr.y)
    trk = np.arctan2(dy, dx)
    if h is None:
        return trk
    return np.where(np.isfinite(h), h, trk)


def load(path: str | Path | Recording, vehicle: VehicleParams | str | Path | None = None,
         rate_hz: float | None = None, reference_torque_nm: float | None = None) -> Frame:
    """Read a recording directory (or take a Recording) and its vehicle file into a :class:`Frame`.

    ``vehicle`` defaults to the recording's ``vehicle.toml``; without one the
    package defaults are used and a note says so.  ``reference_torque_nm`` [N·m] stands in for the vehicle
    file's ``[drivetrain] engine_reference_torque_nm``: the engine's reference torque where the bus sends no
    EC1 (SPN 544).
    """
    blocks = None
    if isinstance(path, Recording):
        rec = path
    else:
        rec = read_recording(path, keep=survey_keep)
        if len(rec.gps) > 2:
            # Streamed: the survey (GNSS track, statistics, clock offset, which signals exist), then
            # the CAN capture again block by block into the frame's bins.
            blocks = (blk for blk, _before in stream_signals(rec, names=FRAME_SIGNALS))
        else:
            rec = read_recording(path)   # no GNSS: the frame rate comes from the signals themselves
    notes = []
    sensors = SensorSpec()
    if isinstance(vehicle, VehicleParams):
        veh = vehicle
    elif vehicle is not None:
        veh = load_vehicle(vehicle)
        sensors = load_sensors(vehicle)
    elif rec.vehicle_toml_path is not None:
        veh = load_vehicle(rec.vehicle_toml_path)
        sensors = load_sensors(rec.vehicle_toml_path)
    else:
        veh = VehicleParams()
        notes.append("no vehicle.toml: package default vehicle parameters used")
    if reference_torque_nm is not None:
        from dataclasses import replace

        veh = replace(veh, drivetrain=replace(veh.drivetrain, engine_reference_torque_nm=float(reference_torque_nm)))
        if signal_state(rec, ENGINE_REFERENCE_TORQUE) != "found":
            notes.append(f"engine reference torque {float(reference_torque_nm):g} N·m as given (the bus sends no EC1)")
    if getattr(rec.stats, "clock_note", ""):
        # the CAN-to-GNSS clock offset the reader applied (or found and kept), as replay and inspect say it
        notes.append(f"clock: {rec.stats.clock_note}")
    notes += skipped_input_notes(rec)
    fr = frame_from_recording(rec, veh, rate_hz, blocks)
    fr.notes[:0] = notes
    fr.sensors = sensors
    return fr


def skipped_input_notes(rec: Recording) -> list[str]:
    """What the reader left out of the recording (lines by reason with the first line numbers, frames of a
    known message with the wrong length), as ``inspect`` and ``replay`` say it: a diagnosis of a damaged
    capture says what it did not see."""
    out = []
    st = rec.stats
    for fname, fst in getattr(st, "files", {}).items():
        if getattr(fst, "total_rejected", 0):
            out.append(f"{fname}: skipped " + "; ".join(fst.describe()))
        out += getattr(fst, "notes", list)()
    if line := wrong_length_line(st):
        out.append(line)
    if getattr(st, "other_sources", None):
        out += other_source_lines(st)
    return out
