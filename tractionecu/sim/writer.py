"""Turn a truth trace into a recording directory, as a real logger would see it.

Sensors (see :class:`~tractionecu.config.SensorSpec` for figures and
sources) sample the truth at their own rates, add noise and quantisation; the
values go through the DBC onto candump lines (``can.log``) and through the
NMEA formatter into ``gps.nmea``.  ``vehicle.toml`` holds what a machine's
owner knows: the nominal parameters (``[vehicle]``) and the sensor figures
(``[sensors]``); the truth (``truth.csv``, ``truth.toml``) sits beside them for
scoring and is never read by diagnosis.

In reverse the hub drives report negative wheel speeds and torques (signed
DBC signals); WBSD and GBSD carry unsigned speeds and distances and the
direction in SPN 1864 / SPN 1861 (DBC: 0 reverse, 1 forward), taken from the
direction of travel selected; the GNSS receiver reports an unsigned speed over
ground (RMC/VTG have no sign) and the course over ground of the motion,
which is the body heading + 180° in reverse.  Below ``GNSS_COURSE_HOLD_MPS``
(:mod:`.gnss_receiver`) the receiver holds its last course, as receivers do
when the velocity vector is dominated by noise.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from ..bus.candump import CandumpWriter
from ..bus.dbc import Codec, default_codec
from ..config import save_vehicle, to_toml
from ..model.vehicle import WHEELS, rolling_radius
from .frames import DRIVETRAIN_SA, FORWARD, HITCH_SA, NAV_SA, REVERSE, TRACTOR_SA
from .gnss_receiver import course_over_ground, gnss_sentences
from .physwriter import EXPORT_CSV, write_physical_recording
from .sensors import ou_noise, quantise, torque_meas, wheel_speed_meas
from .simulator import Scenario, TruthTrace


def write_recording(scn: Scenario, tr: TruthTrace, out: str | Path, codec: Codec | None = None) -> dict[str, int]:
    """Write ``can.log``, ``gps.nmea``, ``vehicle.toml``, ``truth.csv``, ``truth.toml`` to ``out`` (an
    ``export_1hz.csv`` an earlier mechanical run left there is removed: it is not this run's).

    Returns counts of frames per message and NMEA lines.  A physical-truth scenario is written by
    :func:`tractionecu.sim.physwriter.write_physical_recording` (its own sensors and, for a mechanical
    tractor, the standard J1939 messages).
    """
    if getattr(scn, "truth", "paper") == "physical":
        return write_physical_recording(scn, tr, out, codec)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    codec = codec or default_codec()
    spec = scn.sensors
    rng = np.random.default_rng(scn.seed + 1_000_003)
    n = len(tr.t)
    dt = scn.control_dt
    t0 = scn.start_epoch
    counts: dict[str, int] = {}

    # ---- sensor values at the control rate --------------------------------------
    omega_m = wheel_speed_meas(tr.omega, spec, rng)
    md_m = torque_meas(tr.md, spec, rng)
    fzf_m = quantise(tr.fzf + spec.axle_sigma_n * rng.standard_normal(n), spec.axle_quant_n)
    fdx_m = quantise(tr.fdx + spec.draft_sigma_n * rng.standard_normal(n), spec.draft_quant_n)
    r_nom = rolling_radius(tr.fz[:, 2:].mean(axis=1), scn.vehicle)
    v_wheel = r_nom * tr.omega[:, 2:].mean(axis=1)   # tractor's wheel-based speed (rear axle)

    frames: list[tuple[float, int, bytes]] = []
    jitter = lambda: float(rng.uniform(0.0, spec.can_jitter_s))  # noqa: E731

    def emit(name: str, t: float, values: dict, sa: int) -> None:
        cid, data = codec.encode(name, values, sa=sa)
        frames.append((t0 + t + jitter(), cid, data))
        counts[name] = counts.get(name, 0) + 1

    wheel_every = max(1, round(1.0 / (spec.wheel_rate_hz * dt)))
    pin_every = max(1, round(1.0 / (spec.loadpin_rate_hz * dt)))
    gps_every = max(1, round(1.0 / (spec.gps_rate_hz * dt)))
    dist_w = np.cumsum(np.abs(v_wheel)) * dt
    dir_code = np.where(tr.direction > 0, FORWARD, REVERSE)

    for k in range(n):
        t = float(tr.t[k])
        if k % wheel_every == 0:
            emit("TECU_WheelSpeeds", t, {f"WheelSpeed_{w}": float(omega_m[k, i]) for i, w in enumerate(WHEELS)}, DRIVETRAIN_SA)
            emit("TECU_DriveTorques", t + 0.0002, {f"DriveTorque_{w}": float(md_m[k, i]) for i, w in enumerate(WHEELS)}, DRIVETRAIN_SA)
        if k % pin_every == 0:
            emit("TECU_AxleLoad", t + 0.0004, {"FrontAxleLoad": float(fzf_m[k]), "FrontAxleLoadStatus": 0}, DRIVETRAIN_SA)
            emit("RearHitchStatus", t + 0.0006, {
                "RearHitchPosition": 20.0 if tr.work[k] else 80.0,
                "RearHitchInWorkIndication": 1 if tr.work[k] else 0,
                "RearNominalLowerLinkForce": float(np.clip(fdx_m[k] / 500.0, -100, 100)),
                "DraftForce": float(fdx_m[k]),
            }, HITCH_SA)
        if k % 10 == 0:
            emit("WBSD", t + 0.0008, {"WheelBasedMachineSpeed": float(abs(v_wheel[k])),
                                      "WheelBasedMachineDistance": float(dist_w[k]),
                                      "WheelBasedMachineDirection": int(dir_code[k])}, TRACTOR_SA)

    # ---- GNSS ------------------------------------------------------------------------
    gi = np.arange(gps_every - 1, n, gps_every)   # epochs on whole 1/rate boundaries (t = (k+1)·dt)
    tg = tr.t[gi]
    v_true = tr.v
    if "gps_latency" in scn.effects:
        from ..model.effects import delayed
        v_true = delayed(tr.t, tr.v, scn.effects["gps_latency"]["tau_s"])
    v_gps = np.abs(v_true[gi]) + spec.gps_speed_sigma * rng.standard_normal(len(gi))
    g_dt = gps_every * dt
    ex = ou_noise(len(gi), g_dt, spec.gps_pos_sigma / math.sqrt(2), spec.gps_pos_tau_s, rng)
    ey = ou_noise(len(gi), g_dt, spec.gps_pos_sigma / math.sqrt(2), spec.gps_pos_tau_s, rng)
    ez = ou_noise(len(gi), g_dt, spec.gps_alt_sigma, spec.gps_pos_tau_s, rng)
    lat, lon = scn.field.to_latlon(tr.x[gi] + ex, tr.y[gi] + ey)
    alt = scn.field.origin_alt + tr.alt[gi] + ez
    course = course_over_ground(tr.heading[gi], v_true[gi])
    gbsd_dist = np.cumsum(np.abs(v_gps)) * g_dt
    lines: list[str] = []
    for j, k in enumerate(gi):
        lines += gnss_sentences(spec, t0, float(tg[j]), float(lat[j]), float(lon[j]), float(alt[j]),
                                float(v_gps[j]), float(course[j]))
        emit("GBSD", float(tg[j]) + 0.03, {"GroundBasedMachineSpeed": max(float(v_gps[j]), 0.0),
                                           "GroundBasedMachineDistance": float(gbsd_dist[j]),
                                           "GroundBasedMachineDirection": int(dir_code[k])}, NAV_SA)
    (out / "gps.nmea").write_text("\n".join(lines) + "\n", encoding="ascii")
    counts["nmea_lines"] = len(lines)

    frames.sort(key=lambda f: f[0])
    with open(out / "can.log", "w", encoding="ascii", newline="\n") as fh:
        w = CandumpWriter(fh, "can0")
        for t, cid, data in frames:
            w.write(t, cid, data, True)

    save_vehicle(scn.vehicle, out / "vehicle.toml", scn.sensors)
    _write_truth(scn, tr, out)
    (out / EXPORT_CSV).unlink(missing_ok=True)      # an earlier mechanical run's export is not this run's
    return counts


def _write_truth(scn: Scenario, tr: TruthTrace, out: Path) -> None:
    lat, lon = scn.field.to_latlon(tr.x, tr.y)
    names = [r.name for r in scn.field.regions]
    # A plan with reverse segments adds the direction of travel (+1 / −1) as a last column; v is signed.
    with_dir = bool(np.any(scn.plan.direction < 0))
    cols = (["t"] + [f"mu_{w}" for w in WHEELS] + ["rho_s", "a", "soil_id", "soil_name"]
            + [f"slip_{w}" for w in WHEELS] + ["v", "x", "y", "lat", "lon", "alt", "fdx", "fzf", "work"]
            + (["direction"] if with_dir else []))
    with open(out / "truth.csv", "w", newline="", encoding="utf-8") as fh:
        wr = csv.writer(fh)
        wr.writerow(cols)
        t_abs = scn.start_epoch + tr.t
        for k in range(len(tr.t)):
            wr.writerow([f"{t_abs[k]:.3f}"] + [f"{x:.5f}" for x in tr.mu[k]]
                        + [f"{tr.rho_s[k]:.5f}", f"{tr.a[k]:.4f}", int(tr.soil[k]), names[tr.soil[k]]]
                        + [f"{x:.5f}" for x in tr.slip[k]]
                        + [f"{tr.v[k]:.4f}", f"{tr.x[k]:.3f}", f"{tr.y[k]:.3f}", f"{lat[k]:.8f}", f"{lon[k]:.8f}",
                           f"{tr.alt[k] + scn.field.origin_alt:.3f}", f"{tr.fdx[k]:.1f}", f"{tr.fzf[k]:.1f}",
                           int(tr.work[k])] + ([int(tr.direction[k])] if with_dir else []))
    lines = ["# Simulation truth: never read by diagnosis.",
             f'scenario = "{scn.name}"', f"seed = {scn.seed}", f"start_epoch = {scn.start_epoch}",
             f"duration_s = {float(tr.t[-1]):.2f}", ""]
    lines.append("[field]")
    lines.append(f"origin_lat = {scn.field.origin_lat}")
    lines.append(f"origin_lon = {scn.field.origin_lon}")
    lines.append("")
    for r in scn.field.regions:
        lines += ["[[soils]]", f'name = "{r.name}"', f'soil_class = "{r.soil_class}"', f"a = {r.a}", f"rho_s = {r.rho_s}",
                  "polygon = [" + ", ".join(f"[{x}, {y}]" for x, y in r.polygon) + "]", ""]
    lines.append("[effects]")
    for name, params in scn.effects.items():
        lines.append(f"[effects.{name}]")
        lines += [f"{k} = {float(v)!r}" for k, v in params.items()]
    lines.append("")
    lines.append(to_toml(scn.implement, "implement"))
    lines.append(to_toml(scn.sensors, "sensors"))
    (out / "truth.toml").write_text("\n".join(lines), encoding="utf-8")
