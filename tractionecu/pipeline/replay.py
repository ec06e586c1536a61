"""The replay engine: a recording through the estimator, in memory or into a run directory.

:func:`replay` decodes nothing itself: it takes a
:class:`~tractionecu.recording.reader.Recording`, gates its GNSS track with
the service's rule (:class:`~.gnss.GnssGate`), builds the step grid and the
step arguments (:mod:`.steps`, the same rule the daemon applies sample by
sample) and steps one :class:`~tractionecu.estimation.estimator.Estimator`.
The result stays in memory (:class:`ReplayResult`), so diagnosis reads it
without files.

:func:`replay_to_dir` is ``tractionecu replay``'s job: read the recording,
replay it and write

* ``estimates.csv`` — one row per step (columns :data:`CSV_COLUMNS`);
* ``config.toml`` — the resolved vehicle, sensor and estimator configuration;
* ``map/`` — tiles of the estimates at the accepted GNSS epochs
  (:func:`tractionecu.mapping.from_replay.write_replay_map`).

A recording without the signals replay needs (:data:`~.signals.REPLAY_REQUIRED`:
the hub profile's wheel speeds and drive torques, the one profile the
estimator runs) raises :class:`MissingSignals` before anything is written;
it carries the recording, so the caller can report the profiles and the
motion (:mod:`.signals`).

Scoring against simulated truth is not here: it is the evaluation side's
(:mod:`tractionecu.evaluation`), which the on-board core never imports.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..config import SensorSpec, VehicleParams, load_sensors, load_vehicle, to_toml
from ..errors import ConfigError
from ..estimation.estimator import FILTER_LOST, Estimate, Estimator, EstimatorConfig
from ..model.vehicle import N_STATE, STATE_NAMES, WHEELS
from ..recording.reader import Recording, read_recording
from .gnss import GnssGate
from .signals import ANCHOR_SIGNAL, missing_signals
from .steps import GRID_MARGIN_S, GRID_MAX_GAP_S, build_grid, vector_steps

_BATCH = 2048
"""Estimates kept before they are copied into the result arrays (bounded memory, bulk copies)."""

CSV_COLUMNS = tuple(["t"] + [f"mu_{w}" for w in WHEELS] + ["rho_s", "a", "soil_class"] + [f"slip_{w}" for w in WHEELS]
                    + ["v"] + [f"omega_{w}" for w in WHEELS] + [f"var_{n}" for n in STATE_NAMES]
                    + ["nis", "nis_dof", "adapt", "status", "valid"])
"""Columns of ``estimates.csv``."""

__all__ = ["CSV_COLUMNS", "MissingSignals", "ReplayResult", "machine_of", "recording_grid", "replay",
           "replay_to_dir", "write_estimates_csv"]


class MissingSignals(ConfigError):
    """The recording lacks signals replay cannot run without; ``recording`` and ``missing`` (signal names)."""

    def __init__(self, recording: Recording, missing: list[str]) -> None:
        self.recording = recording
        self.missing = missing
        super().__init__(f"{recording.path}: the recording has no {', '.join(missing)}: the estimator's hub "
                         f"profile needs them (tractionecu inspect lists what the recording holds)")


@dataclass
class ReplayResult:
    """Estimates of one replay as arrays over the step grid.

    ``arrays`` holds ``t`` [s] (n,), ``mu``, ``slip``, ``omega`` (n, 4),
    ``P_diag`` (n, 10), ``rho_s``, ``a``, ``v``, ``nis``, ``adapt`` (n,),
    ``nis_dof``, ``status`` (int), ``valid`` (bool) and ``soil_class`` (list
    of str); ``gps_mask`` marks the recording's GNSS epochs that passed the
    gate; ``counters`` are the estimator's, ``gnss`` the gate's.  When the
    estimator declares itself lost, the estimates of the lost period (from
    its ``lost_since``) are marked not valid with ``FILTER_LOST`` afterwards.
    """

    arrays: dict[str, Any]
    rate_hz: float
    gps_mask: np.ndarray
    counters: dict[str, int] = field(default_factory=dict)
    gnss: Counter[str] = field(default_factory=Counter)
    loop_seconds: float = 0.0

    @property
    def steps(self) -> int:
        """Number of estimator steps."""
        return int(self.arrays["t"].size)

    @property
    def sim_seconds(self) -> float:
        """Span of the step grid [s]."""
        t = self.arrays["t"]
        return float(t[-1] - t[0]) if t.size > 1 else 0.0


def recording_grid(rec: Recording, rate_hz: float) -> np.ndarray:
    """The step grid of a recording (:func:`~.steps.build_grid` on its wheel-speed frames).

    Raises :class:`MissingSignals` when the recording lacks a signal of :data:`~.signals.REPLAY_REQUIRED`.
    """
    if not rate_hz > 0:
        raise ConfigError(f"rate_hz: must be > 0, got {rate_hz}")
    missing = missing_signals(rec)
    if missing:
        raise MissingSignals(rec, missing)
    ws = rec.signals[ANCHOR_SIGNAL].t
    # The grid ends with the data that drives the estimator: never more than a wheel-speed gap past the
    # last wheel-speed frame, whatever other signal runs on (or whatever time an odd clock put there).
    return build_grid(ws, min(float(rec.t_end), float(ws[-1]) + GRID_MAX_GAP_S), rate_hz)


def machine_of(rec: Recording) -> tuple[VehicleParams, SensorSpec]:
    """The recording's ``vehicle.toml`` (vehicle and ``[sensors]``), else the documented defaults."""
    if rec.vehicle_toml_path is None:
        return VehicleParams(), SensorSpec()
    return load_vehicle(rec.vehicle_toml_path), load_sensors(rec.vehicle_toml_path)


def replay(rec: Recording, *, rate_hz: float = 100.0, vehicle: VehicleParams | None = None,
           sensors: SensorSpec | None = None, cfg: EstimatorConfig | None = None, gate: GnssGate | None = None,
           on_estimate: Callable[[Estimate], None] | None = None) -> ReplayResult:
    """Step the estimator over ``rec`` and keep every estimate (module doc).

    ``vehicle`` and ``sensors`` default to the recording's ``vehicle.toml``
    (:func:`machine_of`); ``on_estimate`` is called with every
    :class:`~tractionecu.estimation.estimator.Estimate` in time order.
    """
    if vehicle is None or sensors is None:
        v0, s0 = machine_of(rec)
        vehicle = vehicle or v0
        sensors = sensors or s0
    gate = gate or GnssGate()
    est = Estimator(vehicle, cfg or EstimatorConfig(), sensors)
    gnss: Counter[str] = Counter()
    gps_mask = gate.track_mask(rec.gps, gnss)
    grid = recording_grid(rec, rate_hz)
    steps = vector_steps(rec.signals, rec.gps.t[gps_mask], rec.gps.speed[gps_mask], grid)
    sink = _Sink(grid)
    step = est.step
    keep = sink.keep
    t_l = grid.tolist()
    wall = time.perf_counter()
    for t, (inputs, meas) in zip(t_l, steps):
        e = step(t, inputs, meas)
        keep(e)
        if on_estimate is not None:
            on_estimate(e)
    sink.close()
    return ReplayResult(sink.arrays(), float(rate_hz), gps_mask, dict(est.counters), gnss,
                        time.perf_counter() - wall)


class _Sink:
    """Estimates into preallocated arrays, copied in batches of :data:`_BATCH` (bounded memory, bulk copies)."""

    _SCALARS = ("rho_s", "a", "v", "nis", "adapt")
    _VECTORS = (("mu", 4), ("slip", 4), ("omega", 4), ("P_diag", N_STATE))

    def __init__(self, grid: np.ndarray) -> None:
        n = grid.size
        self.t = grid
        self.scalars = {k: np.empty(n) for k in self._SCALARS}
        self.vectors = {k: np.empty((n, m)) for k, m in self._VECTORS}
        self.dof = np.empty(n, dtype=np.int64)
        self.status = np.empty(n, dtype=np.int64)
        self.valid = np.empty(n, dtype=bool)
        self.cls: list[str] = []
        self.batch: list[Estimate] = []
        self.k0 = 0

    def keep(self, e: Estimate) -> None:
        self.batch.append(e)
        if len(self.batch) == _BATCH:
            self._flush()
        if not math.isnan(e.lost_since):
            self._mark_lost(e.lost_since)

    def _mark_lost(self, since: float) -> None:
        """The estimates since ``since`` [s] came from a lost filter: not valid, FILTER_LOST set."""
        self._flush()
        k = int(np.searchsorted(self.t[:self.k0], since, side="left"))
        self.valid[k:self.k0] = False
        self.status[k:self.k0] |= FILTER_LOST

    def _flush(self) -> None:
        b = self.batch
        k0, k1 = self.k0, self.k0 + len(b)
        for name, arr in self.scalars.items():
            arr[k0:k1] = [getattr(e, name) for e in b]
        for name, arr in self.vectors.items():
            arr[k0:k1] = [getattr(e, name) for e in b]
        self.dof[k0:k1] = [e.nis_dof for e in b]
        self.status[k0:k1] = [e.status for e in b]
        self.valid[k0:k1] = [e.valid for e in b]
        self.cls.extend(e.soil_class for e in b)
        self.k0 = k1
        b.clear()

    def close(self) -> None:
        self._flush()

    def arrays(self) -> dict[str, Any]:
        return {"t": self.t, **self.vectors, "nis_dof": self.dof, "status": self.status, "valid": self.valid,
                "soil_class": self.cls, **self.scalars}


# ----------------------------------------------------------------------------- run directory
def write_estimates_csv(path: Path, arrays: dict[str, Any]) -> None:
    """Write ``estimates.csv`` (columns :data:`CSV_COLUMNS`)."""
    left = np.column_stack([arrays["t"], arrays["mu"], arrays["rho_s"], arrays["a"]]).tolist()
    right = np.column_stack([arrays["slip"], arrays["v"], arrays["omega"], arrays["P_diag"], arrays["nis"],
                             arrays["nis_dof"], arrays["adapt"], arrays["status"], arrays["valid"]]).tolist()
    fl = "%.3f" + ",%.6g" * 6 + ",%s,"
    fr = ",".join(["%.6g"] * 20) + ",%d,%.4g,%d,%d"
    cls = arrays["soil_class"]
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(",".join(CSV_COLUMNS) + "\n")
        fh.write("\n".join([fl % (*a, c) + fr % tuple(b) for a, c, b in zip(left, cls, right)]))
        fh.write("\n")


def resolved_config(vehicle: VehicleParams, sensors: SensorSpec, cfg: EstimatorConfig, rate_hz: float,
                    gate: GnssGate) -> str:
    """``config.toml`` of a replay: everything needed to run it again (SI units)."""
    return ("# Resolved configuration of this replay (SI units)\n" + to_toml(vehicle, "vehicle") + "\n"
            + to_toml(sensors, "sensors") + "\n" + cfg.to_toml()
            + f"\n[replay]\nrate_hz = {float(rate_hz)!r}\ngrid_margin_s = {GRID_MARGIN_S!r}\n"
            + f"gnss_min_fix_quality = {gate.min_fix_quality}\ngnss_max_hdop = {float(gate.max_hdop)!r}\n")


def replay_to_dir(recording: str | Path | Recording, out_dir: str | Path, *, rate_hz: float = 100.0,
                  cfg: EstimatorConfig | None = None, sensors: SensorSpec | None = None,
                  gate: GnssGate | None = None, write_map: bool = True,
                  on_estimate: Callable[[Estimate], None] | None = None,
                  ) -> tuple[dict[str, Any], Recording, ReplayResult]:
    """Read, replay and write ``estimates.csv``, ``config.toml`` and the map (module doc).

    Returns the run summary (``steps``, ``sim_seconds``, ``read_seconds``,
    ``loop_seconds``, ``write_seconds``, ``wall_seconds``,
    ``realtime_factor``, ``counters``, ``gnss_gated``, output paths and map
    counts), the recording and the in-memory result.
    """
    wall0 = time.perf_counter()
    out = Path(out_dir)
    rec = recording if isinstance(recording, Recording) else read_recording(recording)
    missing = missing_signals(rec)
    if missing:
        raise MissingSignals(rec, missing)
    out.mkdir(parents=True, exist_ok=True)
    read_s = time.perf_counter() - wall0
    vehicle, s0 = machine_of(rec)
    sensors = sensors or s0
    cfg = cfg or EstimatorConfig()
    gate = gate or GnssGate()
    res = replay(rec, rate_hz=rate_hz, vehicle=vehicle, sensors=sensors, cfg=cfg, gate=gate,
                 on_estimate=on_estimate)
    t_w = time.perf_counter()
    csv_path = out / "estimates.csv"
    write_estimates_csv(csv_path, res.arrays)
    cfg_path = out / "config.toml"
    cfg_path.write_text(resolved_config(vehicle, sensors, cfg, rate_hz, gate), encoding="utf-8")
    summary_map: dict[str, Any] = {}
    if write_map:
        from ..mapping.from_replay import write_replay_map

        summary_map = write_replay_map(out, rec, res.arrays, gps_mask=res.gps_mask)
    wall = time.perf_counter() - wall0
    summary: dict[str, Any] = {
        "recording": str(rec.path), "steps": res.steps, "rate_hz": float(rate_hz), "sim_seconds": res.sim_seconds,
        "read_seconds": read_s, "loop_seconds": res.loop_seconds, "write_seconds": time.perf_counter() - t_w,
        "counters": res.counters, "gnss_gated": dict(res.gnss), "estimates_csv": str(csv_path),
        "config": str(cfg_path), **summary_map, "wall_seconds": wall,
        "realtime_factor": res.sim_seconds / wall if wall > 0 else float("inf"),
    }
    return summary, rec, res
