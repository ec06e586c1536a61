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
