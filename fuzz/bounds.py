"""Memory and time bounds of the readers under hostile input.

Each check runs in a fresh process (so peak RSS is its own) and measures
the growth of the peak resident set size (``ru_maxrss``) while one reader
consumes a hostile input, at two input sizes.  The service's byte stream
and the epoch assembler must not grow with the input at all; the offline
file readers hold one line at a time and their result in memory by design,
so for them the growth is reported as a multiple of the huge line.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

VALID_CAN = b"(1783670400.010078) can0 0CFF1080#8001770180018501\n"
VALID_GGA = b"$GNGGA,080000.10,4752.89620,N,11033.20399,W,2,16,0.90,861.4,M,0.0,M,,*6F\n"
VALID_RMC = b"$GNRMC,080000.10,A,4752.89620,N,11033.20399,W,0.528,90.00,100726,,,A,V*25\n"


def _rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _write_huge(path: Path, head: bytes, size: int, tail: bytes, filler: bytes = b"A") -> None:
    chunk = filler * (1 << 20)
    with open(path, "wb") as fh:
        fh.write(head)
        left = size
        while left > 0:
            fh.write(chunk[: min(left, len(chunk))])
            left -= len(chunk)
        fh.write(tail)


def _check(name: str, size: int, q: mp.Queue) -> None:
    """Child process: build the hostile input, measure, put (rss growth MiB, seconds, note) on ``q``."""
    import logging

    logging.disable(logging.CRITICAL)
    sys.path.insert(0, str(REPO))
    from tractionecu.bus.dbc import default_codec
    from tractionecu.gnss.nmea import EpochAssembler, parse_line
    from tractionecu.recording.csv_import import import_csv
    from tractionecu.recording.reader import read_recording
    from tractionecu.service.config import GpsConfig
    from tractionecu.service.gps import NmeaStream

    default_codec()
    with tempfile.TemporaryDirectory(prefix="tecu-bounds-") as tmp:
        d = Path(tmp)
        note = ""
        try:
            if name == "candump_huge_line":
                _write_huge(d / "can.log", VALID_CAN, size, b"\n" + VALID_CAN.replace(b".010078", b".020078"), b"(")
                r0, t0 = _rss_mib(), time.perf_counter()
                rec = read_recording(d)
                st = rec.stats.files["can.log"]
                note = f"{st.frames} frames, rejected {dict(st.rejected)}"
            elif name == "nmea_file_huge_line":
                (d / "can.log").write_bytes(VALID_CAN)
                _write_huge(d / "gps.nmea", VALID_GGA + b"$GNGGA,", size, b"\n" + VALID_RMC, b"9")
                r0, t0 = _rss_mib(), time.perf_counter()
                rec = read_recording(d)
                ns = rec.stats.files["gps.nmea"]
                note = f"{len(rec.gps)} epochs, rejected {dict(ns.rejected)}"
            elif name == "csv_huge_line":
                _write_huge(d / "x.csv", b"t,WheelSpeed_FL\n0.0,1.0\n", size, b"\n0.01,1.1\n", b"7")
                r0, t0 = _rss_mib(), time.perf_counter()
                rec = import_csv(d / "x.csv")
                st = rec.stats.files["x.csv"]
                note = f"{st.rows} rows, rejected {dict(st.rejected)}"
            elif name == "gps_stream_no_newline":
                out: list = []
                s = NmeaStream(GpsConfig(), out.append)
                r0, t0 = _rss_mib(), time.perf_counter()
                chunk = b"$GNGGA," + b"9" * 4089
                for i in range(size // len(chunk)):
                    s.feed(chunk, 1783670400.0 + i * 1e-3)
                s.feed(b"\r\n" + VALID_GGA, 1783670500.0)
                note = f"buffer {len(s._buf)} B, overlong {s.stats['rejected_overlong']}"
            elif name == "gps_stream_ubx_flood":
                from fuzz.mutate import ubx_frame
                import random

                rng = random.Random(1)
                out = []
                s = NmeaStream(GpsConfig(), out.append)
                blob = b"".join(ubx_frame(rng, 512) for _ in range(2000))
                r0, t0 = _rss_mib(), time.perf_counter()
                fed = 0
                while fed < size:
                    s.feed(blob, 1783670400.0 + fed * 1e-9)
                    fed += len(blob)
                note = f"buffer {len(s._buf)} B, lines {s.stats['lines']}"
            elif name == "epoch_same_time_flood":
                # one epoch that never closes: the same GGA time repeated `size // 80` times
                n = size // len(VALID_GGA)
                rec = parse_line(VALID_GGA.decode())
                asm = EpochAssembler()
                r0, t0 = _rss_mib(), time.perf_counter()
                for i in range(n):
                    asm.push(i + 1, rec)
                fix = asm.flush()
                note = f"{n} sentences into one epoch, kept {len(fix.sentences)} sentence names"
            else:
                raise ValueError(name)
            q.put((_rss_mib() - r0, time.perf_counter() - t0, note, None))
        except BaseException as e:  # noqa: BLE001 - reported, not raised
            q.put((_rss_mib() - r0 if "r0" in locals() else float("nan"), 0.0, note, f"{type(e).__name__}: {str(e)[:200]}"))


CHECKS: dict[str, tuple[str, ...]] = {
    "candump": ("candump_huge_line",),
    "nmea": ("nmea_file_huge_line", "gps_stream_no_newline", "gps_stream_ubx_flood", "epoch_same_time_flood"),
    "csv": ("csv_huge_line",),
}

LIVE = {"gps_stream_no_newline", "gps_stream_ubx_flood"}
"""Service paths: memory must not grow with the input at all."""

CONSTANT = {"epoch_same_time_flood"}
"""Offline checks whose memory must not grow with the input either."""

FILE_FACTOR = 4.0
"""File readers read one line at a time, so a huge line is held whole (plus a
copy or two while it is stripped, split or decoded): peak growth up to this
many times the line is accepted as bounded by the file.  A constant bound
would need a line reader with a length limit (see fuzz/README.md)."""


def run_one(name: str, size: int, timeout_s: float = 300.0) -> dict:
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    p = ctx.Process(target=_check, args=(name, size, q))
    p.start()
    try:
        growth, secs, note, err = q.get(timeout=timeout_s)
    except Exception:  # noqa: BLE001 - queue.Empty: a hang
        p.kill()
        growth, secs, note, err = float("nan"), timeout_s, "", f"no result within {timeout_s:g} s"
    p.join()
    return {"check": name, "input_mib": size / (1 << 20), "rss_growth_mib": growth, "seconds": secs,
            "note": note, "error": err}


def run_bounds(paths: list[str], sizes: tuple[int, ...] = (16 << 20, 64 << 20)) -> list[dict]:
    """Every check of the given fuzz paths at each size; each result has a printable ``line`` and ``ok``."""
    out = []
    for path in paths:
        for name in CHECKS.get(path, ()):
            res = [run_one(name, s) for s in sizes]
            small, big = res[0], res[-1]
            ratio = big["rss_growth_mib"] / big["input_mib"]
            if any(r["error"] for r in res):
                ok, verdict = False, "FAILED"
            elif name in LIVE or name in CONSTANT:
                ok = big["rss_growth_mib"] < 8.0
                verdict = "bounded (constant)" if ok else "NOT BOUNDED"
            else:
                ok = ratio <= FILE_FACTOR
                verdict = f"bounded by the file ({ratio:.1f} x the line)" if ok else f"NOT BOUNDED ({ratio:.1f} x the line)"
            figs = "; ".join(f"{r['input_mib']:.0f} MiB input -> +{r['rss_growth_mib']:.1f} MiB RSS, {r['seconds']:.2f} s"
                             for r in res)
            line = f"bound    {name:<24} {verdict}: {figs}  ({big['note'] or big['error']})"
            if big["error"] and big["note"]:
                line += f" error: {big['error']}"
            out.append({"check": name, "ok": ok, "results": res, "line": line})
    return out


if __name__ == "__main__":
    sys.path.insert(0, str(REPO))
    for r in run_bounds(sys.argv[1].split(",") if len(sys.argv) > 1 else list(CHECKS)):
        print(r["line"], flush=True)
