"""A long recording made of a short one repeated (benchmarks and memory tests).

Each copy's CAN times move on by the span of the copies before it plus a break, and its NMEA
sentences' UTC time (and date, where a sentence carries one) by the same amount, with the checksums
recomputed: a working day's length from a seven-minute simulation, in the same formats a logger
writes (``can.log`` candump ``-L``, ``gps.nmea``).  A day's log is work periods with the logger off
between them, and the machine may stand anywhere when it starts again; so here, where each copy
starts back at the first copy's start point and speed, the copies are ``gap_s`` apart (time runs
on, nothing is logged), not joined as if the machine jumped mid-drive.  The vehicle file is copied;
truth files are not.
"""

from __future__ import annotations

import datetime as dt
import math
import shutil
from pathlib import Path

_TIME_FIELD = {"GGA": 1, "RMC": 1, "GNS": 1, "ZDA": 1, "GLL": 5}
"""Index of the UTC time field (hhmmss.ss) in the NMEA sentences that carry one."""


def nmea_shift(line: str, shift_s: float) -> str:
    """One NMEA sentence with its UTC time (and date, when it carries one) moved by ``shift_s`` [s]."""
    if not line.startswith("$") or "*" not in line:
        return line
    body = line[1:line.rindex("*")]
    f = body.split(",")
    kind = f[0][2:]
    ti = _TIME_FIELD.get(kind)
    if ti is None or not f[ti]:
        return line
    hh, mm, ss = int(f[ti][0:2]), int(f[ti][2:4]), float(f[ti][4:])
    base = dt.datetime(2000, 1, 1)
    if kind == "RMC" and f[9]:
        base = dt.datetime.strptime(f[9], "%d%m%y")
    elif kind == "ZDA":
        base = dt.datetime(int(f[4]), int(f[3]), int(f[2]))
    t = base + dt.timedelta(hours=hh, minutes=mm, seconds=ss + shift_s)
    dec = len(f[ti].split(".")[1]) if "." in f[ti] else 0
    sec = f"{t.second + t.microsecond / 1e6:0{3 + dec if dec else 2}.{dec}f}"
    f[ti] = f"{t.hour:02d}{t.minute:02d}{sec}"
    if kind == "RMC" and f[9]:
        f[9] = t.strftime("%d%m%y")
    elif kind == "ZDA":
        f[2], f[3], f[4] = f"{t.day:02d}", f"{t.month:02d}", f"{t.year:04d}"
    body = ",".join(f)
    ck = 0
    for ch in body:
        ck ^= ord(ch)
    return f"${body}*{ck:02X}"


GAP_S = 10.0
"""Default time between copies with nothing logged [s]: the logger restarted between work periods."""


def _read(src: Path) -> tuple[list[float], list[str], list[str]]:
    """(CAN times [s], the rest of each candump line, NMEA lines) of one recording."""
    can = (src / "can.log").read_text().splitlines()
    nmea = (src / "gps.nmea").read_text().splitlines() if (src / "gps.nmea").is_file() else []
    if not can:
        raise ValueError(f"{src / 'can.log'}: no CAN frames to concatenate")
    return [float(ln[1:ln.index(")")]) for ln in can], [ln[ln.index(")") + 1:] for ln in can], nmea


def concatenate(src: str | Path | list[str | Path], dst: str | Path, seconds: float, gap_s: float = GAP_S,
                align_s: float | None = None) -> float:
    """``dst``: copies of the recording ``src`` (candump ``-L`` ``can.log``, ``gps.nmea``,
    ``vehicle.toml``) one after the other until about ``seconds`` [s] are recorded (at least one
    copy); returns the recorded length [s] (without the gaps).  A copy starts ``gap_s`` [s] after the
    last CAN frame of the one before (at least one CAN frame period, 10 ms, the copies then joined
    as if the drive went on), or, with ``align_s``, at the next multiple of ``align_s`` [s] after
    that.  (Copies repeat the same noise: aligned to twice the diagnosis's held-out block, a copy's
    held-out half is never another copy's training half.)

    ``src`` may be a list of recordings (e.g. independently seeded runs of one scenario, which do
    not repeat their noise): they are taken in order, cycling, with the same gap, alignment and NMEA
    handling, each moved so that it starts where its turn begins; copies are added while that brings
    the recorded length closer to ``seconds``.  The first recording's vehicle file is copied: the
    sources are meant to be one machine."""
    srcs = [Path(s) for s in src] if isinstance(src, (list, tuple)) else [Path(src)]
    if not srcs:
        raise ValueError("concatenate: no source recordings")
    dst = Path(dst)
    dst.mkdir(parents=True, exist_ok=True)
    if (srcs[0] / "vehicle.toml").is_file():
        shutil.copy(srcs[0] / "vehicle.toml", dst / "vehicle.toml")
    data = [_read(s) for s in srcs] if len(srcs) > 1 else None
    if data is None:
        t, rest, nmea = _read(srcs[0])
        span = t[-1] - t[0] + 0.01
        step = span + max(gap_s - 0.01, 0.0)
        if align_s:
            step = math.ceil(step / align_s) * align_s
        copies = max(1, round(seconds / span))
        plan = [(0, c * step) for c in range(copies)]
        total = copies * span
    else:
        t00 = data[0][0][0]
        plan, total, start, k = [], 0.0, t00, 0
        while True:
            t = data[k % len(data)][0]
            span = t[-1] - t[0] + 0.01
            if plan and abs(total + span - seconds) >= abs(total - seconds):
                break
            plan.append((k % len(data), start - t[0]))
            total += span
            start = start + span - 0.01 + max(gap_s, 0.01)
            if align_s:
                start = t00 + math.ceil((start - t00) / align_s - 1e-9) * align_s
            k += 1
    get = (lambda i: data[i]) if data is not None else (lambda i: (t, rest, nmea))
    with open(dst / "can.log", "w") as fc:
        for i, sh in plan:
            ti, ri, _ = get(i)
            fc.write("".join(f"({x + sh:017.6f}){r}\n" for x, r in zip(ti, ri)))
    if any(get(i)[2] for i, _ in plan):
        with open(dst / "gps.nmea", "w") as fg:
            for i, sh in plan:
                fg.write("".join((nmea_shift(ln, sh) if sh else ln) + "\n" for ln in get(i)[2]))
    return total
