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

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..config import VehicleParams, load_vehicle
from ..errors import RecordingError
from ..pipeline.signals import (DRAFT, DRIVE_TORQUES, FRONT_AXLE_LOAD, GROUND_BASED_SPEED, IN_WORK, WHEEL_BASED_SPEED,
                                WHEEL_SPEEDS)
from ..recording.containers import MAX_TABLE_ROWS
from ..recording.reader import Recording, read_recording

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
    """GNSS ground speed [m/s]."""
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
    fzf_modelled: bool = False
    """The front-axle load is modelled (static split minus load transfer from the vehicle file's
    hitch and centre-of-gravity heights), not measured."""
    can_time_offset_s: float = 0.0
    """Mean time of the CAN samples in a bin minus the bin's grid time [s] (an even number of
    samples per bin cannot be centred exactly); GNSS values are at the grid times."""
    source: str = ""
    notes: list[str] = field(default_factory=list)

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


def frame_from_recording(rec: Recording, vehicle: VehicleParams, rate_hz: float | None = None) -> Frame:
    """Resample a :class:`Recording` onto a regular grid (see module doc)."""
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

    def mean(name: str) -> NDArray[np.float64] | None:
        s = sig.get(name)
        return None if s is None or len(s) == 0 else _bin_mean(s.t, s.value, grid, half)

    fr = Frame(t=grid - grid[0], t0_epoch=float(grid[0]), rate_hz=rate_hz, vehicle=vehicle, source=str(rec.path))
    om = [mean(n) for n in WHEEL_SPEEDS]
    if all(o is not None for o in om):
        fr.omega = np.stack(om, axis=1)  # type: ignore[arg-type]
    md = [mean(n) for n in DRIVE_TORQUES]
    if all(m is not None for m in md):
        fr.md = np.stack(md, axis=1)  # type: ignore[arg-type]
    # Values at the bin edges from the raw samples nearest each edge (about ±1.5 sample periods).
    edges = np.concatenate([grid - half, [grid[-1] + half]])
    if fr.omega is not None and fr.md is not None:
        s0 = sig[WHEEL_SPEEDS[0]]
        raw_dt = float(np.median(np.diff(s0.t))) if len(s0) > 2 else period
        if raw_dt < 0.5 * period:
            eh = 1.5 * raw_dt
            om_e = np.stack([_bin_mean(sig[n].t, sig[n].value, edges, eh) for n in WHEEL_SPEEDS], axis=1)
            fr.omega_dot = np.diff(om_e, axis=0) / period
            fr.md_edge = np.stack([_bin_mean(sig[n].t, sig[n].value, edges, eh) for n in DRIVE_TORQUES], axis=1)
            # Raw wheel speeds on a uniform grid of the raw period (bin means), for dynamics
            # faster than the frame rate (tyre relaxation).
            k = int(round(period / raw_dt))
            hf_grid = (grid[:, None] + (np.arange(k) - (k - 1) / 2.0)[None, :] * raw_dt).ravel()
            fr.hf_t = hf_grid - grid[0]
            fr.hf_omega = np.stack([_bin_mean(sig[n].t, sig[n].value, hf_grid, raw_dt / 2) for n in WHEEL_SPEEDS],
                                   axis=1)
    s0 = sig.get(WHEEL_SPEEDS[0])
    if s0 is not None and len(s0) > 2:
        tb = _bin_mean(s0.t, s0.t - s0.t[0], grid, half) + s0.t[0]
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
    fr.engine_torque = mean("EngineTorque")
    fr.engine_speed = mean("EngineSpeed")
    if len(gps):
        tol = 0.6 * period
        fr.v_gps = _at(gps.t, gps.speed, grid, tol)
        fr.alt = _at(gps.t, gps.alt, grid, tol)
        lat = _at(gps.t, gps.lat, grid, tol)
        lon = _at(gps.t, gps.lon, grid, tol)
        fr.x, fr.y = local_xy(lat, lon)
        course = _at(gps.t, gps.course, grid, tol)
        fr.heading = np.where(np.isfinite(course), np.radians(90.0 - course), np.nan)
        fr.heading = _track_heading(fr)
    if fr.v_gps is None and GROUND_BASED_SPEED in sig:
        fr.v_gps = mean(GROUND_BASED_SPEED)
    return fr


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
         rate_hz: float | None = None) -> Frame:
    """Read a recording directory (or take a Recording) and its vehicle file into a :class:`Frame`.

    ``vehicle`` defaults to the recording's ``vehicle.toml``; without one the
    package defaults are used and a note says so.
    """
    rec = path if isinstance(path, Recording) else read_recording(path)
    notes = []
    if isinstance(vehicle, VehicleParams):
        veh = vehicle
    elif vehicle is not None:
        veh = load_vehicle(vehicle)
    elif rec.vehicle_toml_path is not None:
        veh = load_vehicle(rec.vehicle_toml_path)
    else:
        veh = VehicleParams()
        notes.append("no vehicle.toml: package default vehicle parameters used")
    fr = frame_from_recording(rec, veh, rate_hz)
    fr.notes[:0] = notes
    return fr
