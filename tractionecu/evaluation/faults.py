"""Faults injected into a recording, as they happen on real machines (tests and benchmarks).

Each function copies a recording directory and changes what a fault would
change on the wire: frames re-encoded through the DBC (so quantisation and
ranges stay those of the bus), NMEA sentences re-signed with a correct
checksum (a receiver that reports a wrong speed still writes valid sentences).
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Callable

from tractionecu.bus import j1939
from tractionecu.bus.candump import read_candump, write_candump
from tractionecu.bus.dbc import default_codec
from tractionecu.errors import DecodeError, UnknownFrame
from tractionecu.gnss.nmea import checksum
from tractionecu.recording.reader import read_recording

KNOT = 1852.0 / 3600.0
"""One knot [m/s]."""

FrameEdit = Callable[[float, str, dict[str, float]], "dict[str, float] | None"]
"""(t [s], message name, decoded values) -> new values, or None to drop the frame."""


def rewrite_can(src: Path, dst: Path, edit: FrameEdit) -> Path:
    """Copy recording ``src`` to ``dst`` with every decodable frame passed through ``edit``."""
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst)
    codec = default_codec()
    out = []
    for fr in read_candump(src / "can.log"):
        try:
            name, values = codec.decode(fr.can_id, fr.data, fr.is_extended)
        except (UnknownFrame, DecodeError):
            out.append(fr)
            continue
        new = edit(fr.t, name, dict(values))
        if new is None:
            continue
        if new == values:
            out.append(fr)
            continue
        cid = j1939.parse_id(fr.can_id)
        can_id, data = codec.encode(name, new, sa=cid.sa, priority=cid.priority)
        out.append((fr.t, fr.channel, can_id, True, data))
    write_candump(dst / "can.log", out)
    return dst


def gnss_epoch_times(rec_dir: Path) -> dict[str, float]:
    """UTC time-of-day field of each GNSS epoch -> its epoch time [s] (from the recording reader)."""
    rec = read_recording(rec_dir)
    out: dict[str, float] = {}
    for t in rec.gps.t.tolist():
        tod = t % 86400.0
        hh, rem = divmod(tod, 3600.0)
        mm, ss = divmod(rem, 60.0)
        out[f"{int(hh):02d}{int(mm):02d}{ss:05.2f}"] = t
    return out


def _resign(body_fields: list[str]) -> str:
    text = ",".join(body_fields)
    return f"${text}*{checksum(text)}"


def shift_gnss_speed(src: Path, dst: Path, t0: float, t1: float, delta_mps: float) -> Path:
    """Copy ``src`` to ``dst`` with the GNSS speed over ground raised by ``delta_mps`` in [t0, t1) [s].

    RMC and VTG carry the speed of an epoch; VTG has no time of its own and
    belongs to the RMC/GGA before it.
    """
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst)
    times = gnss_epoch_times(src)
    lines = (src / "gps.nmea").read_text(encoding="ascii").splitlines()
    out = []
    t_cur = None
    for line in lines:
        body = line[1:line.index("*")].split(",")
        kind = body[0][2:]
        if kind in ("GGA", "RMC"):
            t_cur = times.get(body[1])
        inside = t_cur is not None and t0 <= t_cur < t1
        if inside and kind == "RMC" and body[7]:
            body[7] = f"{float(body[7]) + delta_mps / KNOT:.3f}"
            line = _resign(body)
        elif inside and kind == "VTG" and body[5]:
            kn = float(body[5]) + delta_mps / KNOT
            body[5] = f"{kn:.3f}"
            body[7] = f"{kn * KNOT * 3.6:.3f}"
            line = _resign(body)
        out.append(line)
    (dst / "gps.nmea").write_text("\n".join(out) + "\n", encoding="ascii")
    return dst


def cut(src: Path, dst: Path, t0: float, t1: float) -> Path:
    """Copy ``src`` to ``dst`` without any CAN frame or GNSS epoch in [t0, t1) [s] (a logger or bus outage)."""
    rewrite_can(src, dst, lambda t, name, v: None if t0 <= t < t1 else v)
    times = gnss_epoch_times(src)
    out = []
    t_cur = None
    for line in (src / "gps.nmea").read_text(encoding="ascii").splitlines():
        body = line[1:line.index("*")].split(",")
        if body[0][2:] in ("GGA", "RMC"):
            t_cur = times.get(body[1])
        if t_cur is not None and t0 <= t_cur < t1:
            continue
        out.append(line)
    (dst / "gps.nmea").write_text("\n".join(out) + "\n", encoding="ascii")
    return dst


# --------------------------------------------------------------------------- sensor faults
# The measuring chain's faults of the effect library (``tractionecu.model.effects.SENSOR_FAULTS``),
# written the way the faulty sensor would put them on the bus.  Times ``t0``/``t1`` are seconds
# since the first CAN frame.

WHEEL_ORDER = ("FL", "FR", "RL", "RR")


def _t_start(src: Path) -> float:
    for fr in read_candump(src / "can.log"):
        return float(fr.t)
    return 0.0


def torque_gain(src: Path, dst: Path, gains: dict[str, float]) -> Path:
    """Drive torques read (1 + k) times the true ones, per wheel: ``gains`` maps FL/FR/RL/RR to k
    (both wheels of an axle for the library's per-axle fault; one wheel for an out-of-library one)."""
    def edit(t, name, v):
        if name != "TECU_DriveTorques":
            return v
        return {k: (x * (1.0 + gains.get(k.rsplit("_", 1)[-1], 0.0)) if k.startswith("DriveTorque_") else x)
                for k, x in v.items()}
    return rewrite_can(src, dst, edit)


def torque_offset(src: Path, dst: Path, offsets_nm: dict[str, float]) -> Path:
    """Drive torques read b [N·m] above the true ones, per wheel (``offsets_nm``: FL/FR/RL/RR → b)."""
    def edit(t, name, v):
        if name != "TECU_DriveTorques":
            return v
        return {k: (x + offsets_nm.get(k.rsplit("_", 1)[-1], 0.0) if k.startswith("DriveTorque_") else x)
                for k, x in v.items()}
    return rewrite_can(src, dst, edit)


def signal_offset(src: Path, dst: Path, message: str, signal: str,
                  offset: Callable[[float], float]) -> Path:
    """``signal`` of ``message`` reads ``offset(t)`` above the truth (t since the first frame [s]):
    a constant offset, a linear drift b_0 + b_1 t, or any time-varying error."""
    t0 = _t_start(src)

    def edit(t, name, v):
        if name != message or signal not in v:
            return v
        out = dict(v)
        out[signal] = v[signal] + offset(t - t0)
        return out
    return rewrite_can(src, dst, edit)


def draft_offset(src: Path, dst: Path, b0_n: float, b1_npm: float = 0.0) -> Path:
    """Draft sensor offset and drift: F_dx,meas = F_dx + b_0 + b_1 t (b_1 per minute)."""
    return signal_offset(src, dst, "RearHitchStatus", "DraftForce", lambda t: b0_n + b1_npm * t / 60.0)


def axle_load_offset(src: Path, dst: Path, b0_n: float, b1_npm: float = 0.0) -> Path:
    """Front-axle load sensor offset and drift: F_zf,meas = F_zf + b_0 + b_1 t (b_1 per minute)."""
    return signal_offset(src, dst, "TECU_AxleLoad", "FrontAxleLoad", lambda t: b0_n + b1_npm * t / 60.0)


def wheel_speed_hold(src: Path, dst: Path, wheel: str, t0: float, duration_s: float, kind: str = "hold") -> Path:
    """One wheel-speed sensor holds its last value (``kind="hold"``) or reads 0 (``"dropout"``) for
    ``duration_s`` from ``t0`` [s since the first frame]."""
    start = _t_start(src)
    key = f"WheelSpeed_{wheel}"
    held: list[float] = []

    def edit(t, name, v):
        if name != "TECU_WheelSpeeds":
            return v
        if not (t0 <= t - start < t0 + duration_s):
            held[:] = [v[key]]
            return v
        out = dict(v)
        out[key] = 0.0 if kind == "dropout" else (held[0] if held else v[key])
        return out
    return rewrite_can(src, dst, edit)


def clock_skew(src: Path, dst: Path, offset_s: float, rate_ppm: float = 0.0) -> Path:
    """The CAN logger's clock runs ahead of GNSS time by δ(t) = δ_0 + κ t: every CAN frame's time
    stamp moves by δ (the GNSS sentences keep theirs)."""
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst)
    frames = list(read_candump(src / "can.log"))
    t0 = float(frames[0].t) if frames else 0.0
    out = [(fr.t + offset_s + rate_ppm * 1e-6 * (fr.t - t0), fr.channel, fr.can_id, fr.is_extended, fr.data)
           for fr in frames]
    write_candump(dst / "can.log", out)
    return dst
