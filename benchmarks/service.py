"""Service benchmark: the daemon on a full 250 kbit/s J1939 bus, on a real SocketCAN vcan0.

Run from the repository root::

    python benchmarks/service.py --json OUT.json [--seconds 30]

Where: inside the User-Mode Linux guest of ``tests/vcan/run-in-vcan.sh`` (real
kernel SocketCAN, vcan0, one CPU).  Run on a host without CAN, the script
starts the guest itself and runs there; the guest's one CPU is shared by the
daemon, ``canplayer``, ``candump`` and this script.

Load: ``canplayer`` replays a log of about 1,900 frames/s (an 8-byte extended
frame is about 130 bits with stuffing, so 250 kbit/s carries at most about
1,900 of them): the relevant PGNs at their real rates from a simulated
``paper-three-soils`` drive (wheel speeds and drive torques 100 Hz, axle load
and hitch 50 Hz, WBSD and GBSD 10 Hz: 320 frames/s) plus about 1,580 frames/s
of other J1939 traffic (28 PGNs from 9 source addresses at 10, 50 and 100 Hz,
random data).  The GNSS NMEA (GGA, RMC, VTG at 10 Hz) goes to the daemon
through a pty.  The daemon runs with the default configuration (100 Hz
estimation, 10 Hz broadcast, lag 10 ms, map on) as ``tractionecu run``.

Figures (printed and written as JSON keys):

``service_cpu_fraction_full_bus``
    CPU time (user + system, all threads) of the daemon process over the
    measuring window divided by the window's wall time; 1.0 = one core.
``broadcast_jitter_p99_ms``
    99th percentile of |interval − 100 ms| between consecutive
    ``TECU_EstSoil`` frames, kernel receive times of ``candump``.
``input_to_broadcast_latency_p99_ms``
    99th percentile, over broadcasts, of the time from the newest wheel-speed
    frame used by the broadcast step (kernel time) to the broadcast frame
    (kernel time).  By design it is at least the grid margin (1.5 ms) plus
    ``estimation.lag_s`` (10 ms).
``service_rss_mb``
    resident set size of the daemon at the end of the window [MiB]
    (``service_peak_rss_mb``: its peak).

Also: ``bus_frames_per_s`` (offered by the log in the window),
``player_drift_s`` (how far canplayer fell behind the log over the run),
``where``, the daemon's counters (``daemon_counters``).
"""

from __future__ import annotations

import argparse
import ast
import json
import math
import os
import random
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import tty
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

CHANNEL = "vcan0"
TARGETS = {"service_cpu_fraction_full_bus": 0.25, "broadcast_jitter_p99_ms": 5.0}
WARMUP_S = 6.0
"""Wall seconds between the daemon's start and the first frame (import, open, address claim)."""


def in_guest() -> bool:
    if os.environ.get("TECU_IN_VCAN_GUEST") == "1":
        return True
    try:
        s = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    except (AttributeError, OSError):
        return False
    s.close()
    return os.path.exists(f"/sys/class/net/{CHANNEL}")


def other_traffic(t0: float, seconds: float, seed: int = 7) -> list[tuple[float, str]]:
    """About 1,580 frames/s of J1939 traffic the service does not use: (time, candump frame)."""
    rng = random.Random(seed)
    # PGNs seen on tractors (EEC1, EEC2, ETC1, ETC2, CCVS, engine temperature, fuel, ...) and proprietary A/B
    pgns = [0xF004, 0xF003, 0xF002, 0xF005, 0xFEF1, 0xFEEE, 0xFEF2, 0xFEEF, 0xFEF5, 0xFEF6, 0xFEF7,
            0xFEDF, 0xFE4A, 0xFE4B, 0xFF00, 0xFF01, 0xFF02, 0xFF30, 0xFF31, 0xFF40, 0xEF00, 0xFE56,
            0xFE68, 0xFEE5, 0xFEE9, 0xFEFC, 0xFD09, 0xFE6C]
    sas = [0x00, 0x03, 0x06, 0x17, 0x23, 0x27, 0x28, 0x47, 0xF0]
    rates = [100.0] * 10 + [50.0] * 11 + [10.0] * 7          # 1000 + 550 + 70 = 1,620 frames/s nominal
    out: list[tuple[float, str]] = []
    for i, (pgn, hz) in enumerate(zip(pgns, rates)):
        sa = sas[i % len(sas)]
        prio = 3 if hz >= 100 else 6
        ps_pgn = pgn | (0xFF if (pgn >> 8) < 0xF0 else 0)
        can_id = (prio << 26) | (ps_pgn << 8) | sa
        phase = rng.uniform(0, 1.0 / hz)
        n = int(seconds * hz)
        for k in range(n):
            data = bytes(rng.getrandbits(8) for _ in range(8))
            out.append((t0 + phase + k / hz, f"{can_id:08X}#{data.hex().upper()}"))
    return out


def proc_cpu_s(pid: int) -> float:
    f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")


def proc_mem_mb(pid: int) -> tuple[float, float]:
    rss = peak = math.nan
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            rss = int(line.split()[1]) / 1024
        elif line.startswith("VmHWM:"):
            peak = int(line.split()[1]) / 1024
    return rss, peak


def p99(xs: list[float]) -> float:
    import numpy as np

    return float(np.percentile(np.asarray(xs), 99)) if xs else math.nan


def config_text(channel: str, port: str, vehicle: Path, state: Path, options: list[str]) -> str:
    """The daemon's TOML: defaults, the bench's devices, and ``section.key=value`` overrides."""
    tables: dict[str, dict[str, str]] = {
        "can": {"interface": '"socketcan"', "channel": f'"{channel}"'},
        "gps": {"port": f'"{port}"'},
        "estimation": {"vehicle": f'"{vehicle}"'},
        "service": {"state_dir": f'"{state}"'},
    }
    for opt in options:
        key, _, value = opt.partition("=")
        section, _, name = key.partition(".")
        tables.setdefault(section, {})[name] = value
    return "".join(f"[{sec}]\n" + "".join(f"{k} = {v}\n" for k, v in kv.items()) + "\n" for sec, kv in tables.items())


def run(seconds: float, keep: Path | None, options: list[str]) -> dict:
    from tractionecu.bus import j1939
    from tractionecu.bus.candump import read_candump
    from tractionecu.cli.replay import GRID_MARGIN_S
    from tractionecu.service.simulate import nmea_schedule
    from tractionecu.sim import scenarios
    from tractionecu.sim.simulator import simulate
    from tractionecu.sim.writer import write_recording

    work = Path(tempfile.mkdtemp(prefix="tecu-bench-"))
    try:
        rec = work / "rec"
        scn = scenarios.get("paper-three-soils", seed=1, duration_s=seconds + 4.0)
        write_recording(scn, simulate(scn), rec)
        relevant = [(f.t, f"{f.can_id:08X}#{f.data.hex().upper()}") for f in read_candump(rec / "can.log")]
        t_first = relevant[0][0]
        frames = sorted(relevant + other_traffic(t_first, seconds + 3.0))
        with open(work / "bus.log", "w") as fh:
            for t, fr in frames:
                fh.write(f"({t:017.6f}) can0 {fr}\n")
        nmea = nmea_schedule(rec / "gps.nmea")

        master, slave = os.openpty()
        tty.setraw(slave)
        state = work / "state"
        cfg = work / "service.toml"
        cfg.write_text(config_text(CHANNEL, os.ttyname(slave), rec / "vehicle.toml", state, options))
        dump = open(work / "capture.log", "w")
        # candump with kernel filters: our three estimate PGNs (any SA) and the wheel speeds
        flt = ",".join(f"{(pgn << 8):08X}:03FFFF00" for pgn in (65312, 65313, 65314, 65296))
        cand = subprocess.Popen(["candump", "-L", f"{CHANNEL},{flt}"], stdout=dump, stderr=subprocess.DEVNULL)

        daemon_log = open(work / "daemon.log", "w")
        daemon = subprocess.Popen([sys.executable, "-m", "tractionecu.cli.main", "-v", "run", "--quiet",
                                   "--config", str(cfg)], stdout=subprocess.DEVNULL, stderr=daemon_log)
        time.sleep(WARMUP_S)
        if daemon.poll() is not None:
            raise RuntimeError("daemon died: " + (work / "daemon.log").read_text())
        # the recording's times become "now": the playback starts at t_play, the NMEA is shifted to match
        t_play = time.time() + 0.2
        shift = t_play - t_first

        def feed() -> None:
            from datetime import datetime, timezone

            from tractionecu.gnss import nmea as nm

            for t, line in nmea:
                d = t + shift - time.time()
                if d > 0:
                    time.sleep(d)
                # re-stamp the sentence with the shifted UTC time so the daemon sees a live receiver
                rec_ = nm.parse_line(line)
                if rec_ is not None and rec_.sentence in ("GGA", "RMC"):
                    utc = datetime.fromtimestamp(round(t + shift, 2), tz=timezone.utc)
                    fields = line.split("*")[0].split(",")
                    fields[1] = f"{utc:%H%M%S}.{utc.microsecond // 10000:02d}"
                    if rec_.sentence == "RMC":
                        fields[9] = f"{utc:%d%m%y}"
                    body = ",".join(fields)[1:]
                    line = f"${body}*{nm.checksum(body)}"
                try:
                    os.write(master, (line + "\r\n").encode())
                except OSError:
                    return

        feeder = threading.Thread(target=feed, daemon=True)
        time.sleep(max(0.0, t_play - time.time()))
        player = subprocess.Popen(["canplayer", "-I", str(work / "bus.log"), f"{CHANNEL}=can0"])
        feeder.start()
        time.sleep(3.0)                                   # the estimator converges, the map opens
        cpu0, w0 = proc_cpu_s(daemon.pid), time.monotonic()
        time.sleep(seconds - 3.0)
        cpu1, w1 = proc_cpu_s(daemon.pid), time.monotonic()
        rss, peak = proc_mem_mb(daemon.pid)
        player.terminate()
        player.wait(timeout=10)
        daemon.send_signal(signal.SIGTERM)
        rc = daemon.wait(timeout=60)
        cand.send_signal(signal.SIGINT)
        cand.wait(timeout=5)
        dump.close()
        daemon_log.close()
        os.close(master)
        os.close(slave)
        log = (work / "daemon.log").read_text()
        if rc != 0:
            raise RuntimeError(f"daemon exit {rc}: {log[-2000:]}")
        counters = ast.literal_eval(log.rsplit("stopped; counters: ", 1)[1].splitlines()[0])

        cap = list(read_candump(work / "capture.log"))
        ws = [f.t for f in cap if j1939.pgn_of(f.can_id) == 65296]
        soil = [f.t for f in cap if j1939.pgn_of(f.can_id) == 65314 and f.can_id & 0xFF != 0x80]
        g0 = ws[0] + GRID_MARGIN_S
        lag = 0.01
        # steady state: broadcasts inside the measuring window
        soil = [t for t in soil if t > ws[0] + 3.0 and t < ws[0] + seconds - 0.5]
        jitter = [abs((b - a) - 0.1) * 1e3 for a, b in zip(soil, soil[1:])]
        import bisect

        lat = []
        for tb in soil:
            k = math.floor((tb - lag - g0) * 100 + 1e-6)       # the step this broadcast came from
            tk = g0 + k / 100
            i = bisect.bisect_right(ws, tk) - 1
            if i >= 0:
                lat.append((tb - ws[i]) * 1e3)
        # offered load: frames of the log inside the measuring window; canplayer kept pace if the
        # wheel-speed frames' kernel times advanced like their log times
        log_t = [t for t, _ in frames]
        win0, win1 = t_first + 3.0, t_first + seconds - 0.5
        bus_rate = sum(win0 <= t < win1 for t in log_t) / (win1 - win0)
        ws_log = [f.t for f in read_candump(rec / "can.log") if j1939.pgn_of(f.can_id) == 65296]
        n = min(len(ws), len(ws_log)) - 1
        player_drift = (ws[n] - ws[0]) - (ws_log[n] - ws_log[0])
        res = {
            "where": "vcan0 (real SocketCAN) in the User-Mode Linux guest, 1 CPU",
            "service_cpu_fraction_full_bus": (cpu1 - cpu0) / (w1 - w0),
            "broadcast_jitter_p99_ms": p99(jitter),
            "input_to_broadcast_latency_p99_ms": p99(lat),
            "input_to_broadcast_latency_median_ms": float(sorted(lat)[len(lat) // 2]) if lat else math.nan,
            "service_rss_mb": rss,
            "service_peak_rss_mb": peak,
            "bus_frames_per_s": bus_rate,
            "player_drift_s": player_drift,
            "broadcasts_measured": len(soil),
            "measured_seconds": w1 - w0,
            "daemon_counters": counters,
        }
        return res
    finally:
        if keep is not None:
            shutil.copytree(work, keep, dirs_exist_ok=True)
        shutil.rmtree(work, ignore_errors=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", required=True, metavar="OUT", help="write the figures here")
    ap.add_argument("--seconds", type=float, default=30.0, help="length of the full-bus run [s]")
    ap.add_argument("--keep", metavar="DIR", default=None, help="copy logs and captures here")
    ap.add_argument("--option", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="override a daemon config key (TOML value), e.g. map.enabled=false; repeatable")
    args = ap.parse_args(argv)
    out = Path(args.json).resolve()
    if not in_guest():
        script = REPO / "tests" / "vcan" / "run-in-vcan.sh"
        cmd = ["bash", str(script), sys.executable, str(Path(__file__).resolve()), "--json", str(out),
               "--seconds", str(args.seconds)]
        if args.keep:
            cmd += ["--keep", str(Path(args.keep).resolve())]
        for o in args.option:
            cmd += ["--option", o]
        print("starting the UML guest (tests/vcan/run-in-vcan.sh) for a real SocketCAN vcan0 ...", flush=True)
        return subprocess.call(cmd, cwd=REPO)
    res = run(args.seconds, Path(args.keep) if args.keep else None, args.option)
    res["options"] = args.option
    figures = {k: v for k, v in res.items() if k != "daemon_counters"}
    for k, v in figures.items():
        target = TARGETS.get(k)
        tail = "" if target is None else f"   (target <= {target})"
        print(f"{k}: {v:.4g}{tail}" if isinstance(v, float) else f"{k}: {v}")
    out.write_text(json.dumps(res, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    ok = all(res[k] <= t for k, t in TARGETS.items())
    print("targets met" if ok else "TARGETS MISSED")
    return 0


if __name__ == "__main__":
    sys.exit(main())
