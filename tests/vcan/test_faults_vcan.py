"""Fault injection against the real daemon on SocketCAN vcan0 (UML guest).

Run with: tests/vcan/run-in-vcan.sh .venv/bin/python -m pytest -q -m vcan tests/vcan/test_faults_vcan.py

* vcan0 deleted and re-created: time from re-creation to the first broadcast;
* the bus flooded (random IDs, 11-bit, error-flagged, wrong DLCs) while canplayer
  plays a recording: broadcasts keep their rate, VmRSS stays bounded;
* the wall clock stepped +1 h / -2 h with ``date -s`` (the guest is its own
  kernel): the step and broadcast rates stay on the monotonic clock;
* the map directory on a full tmpfs: estimation goes on, the failure is logged and
  counted, writing resumes when space returns, every tile reads back;
* SIGKILL of the daemon during tile writes: every tile reads back, a restart resumes.

Figures are printed (``pytest -s``) and recorded in docs/reliability.md.
"""

from __future__ import annotations

import ast
import math
import os
import random
import shutil
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
import tty
from pathlib import Path

import can
import pytest

from tractionecu.bus import j1939
from tractionecu.mapping.store import MapStore
from tractionecu.mapping.tiles import iter_tile_files, read_tile
from tractionecu.sim.player import nmea_schedule
from tractionecu.sim import scenarios
from tractionecu.sim.simulator import simulate
from tractionecu.sim.writer import write_recording

pytestmark = pytest.mark.vcan

CHANNEL = "vcan0"
SA = 0x90
EST_PGNS = (65312, 65313, 65314)


def tool(name: str) -> str:
    path = shutil.which(name)
    assert path, f"{name} not found on PATH"
    return path


def ip(*args: str) -> None:
    subprocess.run([tool("ip"), *args], check=True, capture_output=True, text=True)


def observer() -> can.BusABC:
    """A bus that receives only our estimate frames: the kernel filters them, so the test's own reading
    does not compete with the daemon for the guest's one CPU (under a flood it would otherwise parse
    every frame on the bus in Python)."""
    return can.Bus(interface="socketcan", channel=CHANNEL,
                   can_filters=[{"can_id": (pgn << 8) | SA, "can_mask": 0x3FFFFFF, "extended": True}
                                for pgn in EST_PGNS])


def ensure_vcan0() -> None:
    if not os.path.exists(f"/sys/class/net/{CHANNEL}"):
        ip("link", "add", "dev", CHANNEL, "type", "vcan")
    ip("link", "set", CHANNEL, "up")


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("rec") / "rec"
    scn = scenarios.get("paper-straight", seed=7, duration_s=16.0)
    write_recording(scn, simulate(scn), out)
    return out


def write_config(path: Path, state: Path, vehicle: Path, gps_port: str | None, extra: str = "") -> Path:
    gps = f'source = "serial"\nport = "{gps_port}"\n' if gps_port else 'source = "none"\n'
    path.write_text(
        f'[can]\ninterface = "socketcan"\nchannel = "{CHANNEL}"\n\n'
        f"[gps]\n{gps}\n"
        f'[estimation]\nlag_s = 0.1\nvehicle = "{vehicle}"\n\n'
        f'[service]\nstate_dir = "{state}"\n{extra}',
        encoding="utf-8",
    )
    return path


def unit_nice() -> int:
    """``Nice=`` of the systemd unit: the daemon runs at the priority it is deployed with."""
    unit = Path(__file__).resolve().parents[2] / "systemd" / "tractionecu.service"
    for line in unit.read_text().splitlines():
        if line.startswith("Nice="):
            return int(line.split("=", 1)[1])
    return 0


class Daemon:
    def __init__(self, cfg: Path, log: Path) -> None:
        self.log = log
        nice = unit_nice()
        with open(log, "w") as fh:
            self.proc = subprocess.Popen([sys.executable, "-m", "tractionecu.cli.main", "-v", "run", "--quiet",
                                          "--config", str(cfg)],
                                         stdout=subprocess.DEVNULL, stderr=fh, start_new_session=True,
                                         preexec_fn=(lambda: os.nice(nice)) if nice else None)

    def text(self) -> str:
        return self.log.read_text()

    def alive(self) -> None:
        assert self.proc.poll() is None, self.text()

    def stop(self) -> dict:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        rc = self.proc.wait(timeout=30)
        assert rc == 0, self.text()
        return ast.literal_eval(self.text().rsplit("stopped; counters: ", 1)[1].splitlines()[0])

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()

    def rss_kb(self) -> int:
        for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
        raise AssertionError("no VmRSS")


def broadcasts(bus: can.BusABC, seconds: float) -> list[float]:
    """Monotonic arrival times of our TECU_EstSoil broadcasts during ``seconds``."""
    out = []
    end = time.monotonic() + seconds
    while (left := end - time.monotonic()) > 0:
        m = bus.recv(timeout=min(left, 0.1))
        if m is not None and m.arbitration_id & 0xFF == SA and j1939.pgn_of(m.arbitration_id) == 65314:
            out.append(time.monotonic())
    return out


def drain(bus: can.BusABC) -> None:
    """Discard the frames the observer has queued (so a window counts only what arrives in it)."""
    while bus.recv(timeout=0) is not None:
        pass


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process."""
    f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")


def wait_broadcast(bus: can.BusABC, daemon: Daemon, timeout: float) -> float:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        daemon.alive()
        m = bus.recv(timeout=0.05)
        if m is not None and m.arbitration_id & 0xFF == SA and j1939.pgn_of(m.arbitration_id) in EST_PGNS:
            return time.monotonic()
    raise AssertionError(f"no broadcast within {timeout} s\n" + daemon.text()[-3000:])


class Player:
    """canplayer plays the recording onto vcan0 (looped) and its NMEA goes to a pty at the same pace."""

    def __init__(self, rec: Path, loops: int = 1) -> None:
        self.rec = rec
        self.loops = loops
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.port = os.ttyname(self.slave)
        self.stop_ev = threading.Event()
        self.thread: threading.Thread | None = None
        self.player: subprocess.Popen | None = None

    def start(self) -> None:
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        sched = nmea_schedule(self.rec / "gps.nmea")
        with open(self.rec / "can.log") as fh:
            first_can = float(fh.readline().split(")")[0][1:])
        for _ in range(self.loops):
            if self.stop_ev.is_set():
                return
            self.player = subprocess.Popen([tool("canplayer"), "-I", str(self.rec / "can.log"), f"{CHANNEL}=can0"],
                                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            off = time.time() - first_can
            for t, line in sched:
                if self.stop_ev.is_set():
                    break
                d = t + off - time.time()
                if d > 0:
                    time.sleep(d)
                try:
                    os.write(self.master, (line + "\r\n").encode("ascii"))
                except OSError:
                    return
            self.player.wait()

    def close(self) -> None:
        self.stop_ev.set()
        if self.player is not None and self.player.poll() is None:
            self.player.kill()
            self.player.wait()
        if self.thread is not None:
            self.thread.join(timeout=20)
        os.close(self.master)
        os.close(self.slave)


class MonotonicPlayer(Player):
    """The recording's CAN frames and NMEA lines paced by the monotonic clock, as the other ECUs and the
    receiver on a real bus are: they do not follow this computer's wall clock.  (canplayer paces with
    gettimeofday(): after ``date -s +1h`` it sends the rest of the recording at once, after -2 h it waits
    two hours, and the burst, not the daemon, then decides the broadcast counts.)"""

    def _run(self) -> None:
        events: list[tuple[float, int, bytes | str]] = []
        with open(self.rec / "can.log") as fh:
            for ln in fh:
                stamp, _iface, frame = ln.split()
                cid, data = frame.split("#")
                events.append((float(stamp[1:-1]), int(cid, 16), bytes.fromhex(data)))
        events += [(t, -1, line) for t, line in nmea_schedule(self.rec / "gps.nmea")]
        events.sort(key=lambda e: e[0])
        sock = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
        sock.bind((CHANNEL,))
        try:
            for _ in range(self.loops):
                off = time.monotonic() - events[0][0]
                for t, cid, payload in events:
                    if self.stop_ev.is_set():
                        return
                    d = t + off - time.monotonic()
                    if d > 0:
                        time.sleep(d)
                    try:
                        if cid < 0:
                            os.write(self.master, (str(payload) + "\r\n").encode("ascii"))
                        else:
                            data = bytes(payload)
                            sock.send(struct.pack("=IB3x8s", cid | socket.CAN_EFF_FLAG, len(data), data))
                    except OSError:
                        return
        finally:
            sock.close()


def tiles_whole(map_dir: Path) -> int:
    n = 0
    for _key, path in iter_tile_files(map_dir):
        read_tile(path)                                   # raises CorruptTileError on a bad tile
        n += 1
    assert not list(map_dir.glob("**/*.corrupt*"))
    return n


# ---------------------------------------------------------------------------------------------
def test_vcan0_recreated_broadcasts_again_within_2s(tmp_path: Path, recording: Path) -> None:
    """Default reopen backoff (0.5 s doubling); vcan0 gone for 1.5 s."""
    ensure_vcan0()
    cfg = write_config(tmp_path / "s.toml", tmp_path / "state", recording / "vehicle.toml", None)
    d = Daemon(cfg, tmp_path / "daemon.log")
    bus = observer()
    try:
        wait_broadcast(bus, d, 60)
        bus.shutdown()
        ip("link", "del", CHANNEL)
        time.sleep(1.5)
        d.alive()
        ip("link", "add", "dev", CHANNEL, "type", "vcan")
        ip("link", "set", CHANNEL, "up")
        t_up = time.monotonic()
        bus = observer()
        t_bc = wait_broadcast(bus, d, 15)
        counters = d.stop()
    finally:
        bus.shutdown()
        d.kill()
        ensure_vcan0()
    rec_s = t_bc - t_up
    print(f"\nvcan0 re-created after 1.5 s away: first broadcast {rec_s:.2f} s after it came up; "
          f"can counters {counters['can']}")
    assert counters["can"]["link_failures"] >= 1
    assert rec_s <= 2.0


def test_vcan0_recreated_after_a_longer_outage_broadcasts_again_within_2s(tmp_path: Path, recording: Path) -> None:
    ensure_vcan0()
    cfg = write_config(tmp_path / "s.toml", tmp_path / "state", recording / "vehicle.toml", None)
    d = Daemon(cfg, tmp_path / "daemon.log")
    bus = observer()
    try:
        wait_broadcast(bus, d, 60)
        bus.shutdown()
        ip("link", "del", CHANNEL)
        time.sleep(4.0)
        ip("link", "add", "dev", CHANNEL, "type", "vcan")
        ip("link", "set", CHANNEL, "up")
        t_up = time.monotonic()
        bus = observer()
        t_bc = wait_broadcast(bus, d, 15)
        d.stop()
    finally:
        bus.shutdown()
        d.kill()
        ensure_vcan0()
    print(f"\nvcan0 re-created after 4 s away: first broadcast {t_bc - t_up:.2f} s after it came up")
    assert t_bc - t_up <= 2.0


FLOOD_RATE = 2500
"""Hostile frames per second on top of the recording."""
FLOOD = r"""
import random, socket, struct, sys, time
rate, seconds = float(sys.argv[1]), float(sys.argv[2])
rng = random.Random(5)
s = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
s.bind(("vcan0",))
dbc_ids = [0x18FF1080, 0x18FF1180, 0x18FF1280, 0x18FE4582, 0x18EAFF33, 0x18EEFF33]
sent = errors = 0
end = time.monotonic() + seconds
nxt = time.monotonic()
while time.monotonic() < end:
    for _ in range(int(rate / 100)):
        k = rng.randrange(4)
        if k == 0:
            cid, n = rng.getrandbits(29) | 0x80000000, rng.randrange(9)          # random 29-bit ID
        elif k == 1:
            cid, n = rng.getrandbits(11), rng.randrange(9)                       # random 11-bit ID
        elif k == 2:
            cid, n = 0x20000000 | rng.getrandbits(29), 8                         # error-flagged frame
        else:
            cid, n = rng.choice(dbc_ids) | 0x80000000, rng.choice([0, 1, 3, 5, 7])  # DBC ID, wrong DLC
        try:
            s.send(struct.pack("=IB3x8s", cid, n, rng.randbytes(8)))
            sent += 1
        except OSError:
            errors += 1
    nxt += 0.01
    d = nxt - time.monotonic()
    if d > 0:
        time.sleep(d)
print(sent, errors)
"""


def test_flood_while_playing_keeps_broadcasting_and_memory_bounded(tmp_path: Path, recording: Path) -> None:
    """canplayer plays the recording while FLOOD_RATE hostile frames/s are sent: a 250 kbit/s ISOBUS
    carries at most about 1900 extended 8-byte frames/s, so this is more than a 100 % loaded bus."""
    ensure_vcan0()
    pl = Player(recording)
    cfg = write_config(tmp_path / "s.toml", tmp_path / "state", recording / "vehicle.toml", pl.port)
    d = Daemon(cfg, tmp_path / "daemon.log")
    bus = observer()
    flood = None
    rss: list[int] = []
    try:
        wait_broadcast(bus, d, 60)
        pl.start()
        time.sleep(2.0)
        flood = subprocess.Popen([sys.executable, "-c", FLOOD, str(FLOOD_RATE), "12"], stdout=subprocess.PIPE, text=True)
        drain(bus)
        seen: list[float] = []
        for _ in range(24):
            seen += broadcasts(bus, 0.5)
            rss.append(d.rss_kb())
        out, _ = flood.communicate(timeout=30)
        d.alive()
        counters = d.stop()
    finally:
        if flood is not None and flood.poll() is None:
            flood.kill()
        pl.close()
        bus.shutdown()
        d.kill()
    sent, errors = (int(x) for x in out.split())
    rate = len(seen) / 12.0
    gaps = [b - a for a, b in zip(seen, seen[1:])]
    early, late = max(rss[2:8]), max(rss[-6:])
    print(f"\nflood: {sent} hostile frames sent ({errors} send errors) in 12 s with canplayer; "
          f"EstSoil broadcasts {rate:.1f}/s, longest gap {max(gaps):.2f} s; VmRSS {rss[0]} -> {early} (1-4 s) -> "
          f"{late} kB (last 3 s), growth {100 * (late - early) / early:+.1f} %; service {counters['service']}; "
          f"bad_frames {counters['bad_frames']}; can {counters['can']}")
    # the guest has one CPU shared with the flooder and canplayer; the watchdog allows 5 s
    assert rate >= 8.0 and max(gaps) < 1.5
    assert counters["service"]["steps"] > 1000
    assert counters["service"].get("bad_frames", 0) > 0           # the wrong-DLC DBC frames were seen and counted
    assert late <= early * 1.05


def test_wall_clock_steps_do_not_move_the_schedule(tmp_path: Path, recording: Path) -> None:
    """``date -s`` +1 h, then -2 h, while the recording plays; broadcast rate per monotonic second is unchanged."""
    ensure_vcan0()
    pl = MonotonicPlayer(recording)
    cfg = write_config(tmp_path / "s.toml", tmp_path / "state", recording / "vehicle.toml", pl.port)
    d = Daemon(cfg, tmp_path / "daemon.log")
    bus = observer()
    m0, w0 = time.monotonic(), time.time()
    try:
        wait_broadcast(bus, d, 60)
        pl.start()
        time.sleep(3.0)                                   # past the grid phasing to the first wheel speed
        drain(bus)
        before = broadcasts(bus, 3.0)
        subprocess.run(["date", "-s", "@%.3f" % (time.time() + 3600)], check=True, capture_output=True)
        fwd = broadcasts(bus, 3.0)
        subprocess.run(["date", "-s", "@%.3f" % (time.time() - 7200)], check=True, capture_output=True)
        back = broadcasts(bus, 3.0)
        settle = broadcasts(bus, 3.0)
        d.alive()
        counters = d.stop()
    finally:
        subprocess.run(["date", "-s", "@%.3f" % (w0 + time.monotonic() - m0)], capture_output=True)
        pl.close()
        bus.shutdown()
        d.kill()
    n = [len(x) for x in (before, fwd, back, settle)]
    gaps = [b - a for x in (before, fwd, back, settle) for a, b in zip(x, x[1:])]
    print(f"\nclock steps: EstSoil broadcasts in 3 s before / after +1 h / after -2 h / settling: {n}; longest gap "
          f"{max(gaps):.3f} s; service {counters['service']}; can {counters['can']}")
    # A wall-clock schedule would stall for 1 h after +1 h (no broadcast at all) and skip 72 000 steps
    # after -2 h (or send them in a burst).  The monotonic one keeps 10 Hz per monotonic second: every
    # window has broadcasts and no step is skipped.  The counts are load-dependent in one way only: a
    # starved guest delays steps (up to estimation.max_catch_up_s = 1 s, 10 broadcasts, before it would
    # skip), and the delayed ones arrive in a later window (a loaded run gave [30, 20, 29]: the +1 h
    # window lost 10 to the next).  So single windows are bounded loosely, and the 9 s after the first
    # step, which includes a settling window to work off the backlog, carry 90 broadcasts up to one
    # catch-up budget at either end.
    assert min(n) >= 10, n
    assert 80 <= n[1] + n[2] + n[3] <= 100, n
    assert counters["service"].get("skipped_steps", 0) == 0


def test_disk_full_keeps_estimating_reports_and_resumes(tmp_path: Path, recording: Path) -> None:
    """State directory on a 1 MiB tmpfs filled up by another file during the run, then freed."""
    ensure_vcan0()
    mnt = tmp_path / "small"
    mnt.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)], check=True)
    pl = Player(recording)
    state = mnt / "state"
    cfg = write_config(tmp_path / "s.toml", state, recording / "vehicle.toml", pl.port,
                       extra="\n[map]\nflush_interval_s = 0.5\n")
    d = Daemon(cfg, tmp_path / "daemon.log")
    bus = observer()
    try:
        wait_broadcast(bus, d, 60)
        pl.start()
        end = time.monotonic() + 20
        while not list(iter_tile_files(state / "map")):
            assert time.monotonic() < end, d.text()[-3000:]
            time.sleep(0.2)
        filler = mnt / "filler"
        with open(filler, "wb") as f:                         # the disk fills up
            try:
                while True:
                    f.write(b"\0" * 65536)
            except OSError:
                pass
        drain(bus)                                            # what queued while the disk was filled
        full = broadcasts(bus, 4.0)
        d.alive()
        log_full = d.text()
        filler.unlink()                                       # space returns
        freed = broadcasts(bus, 4.0)
        counters = d.stop()
    finally:
        pl.close()
        bus.shutdown()
        d.kill()
    ntiles = tiles_whole(state / "map")
    with MapStore.open(state / "map") as store:
        assert store.stats["corrupt_tiles"] == 0
    subprocess.run(["umount", str(mnt)], check=False)
    m = counters["map"]
    print(f"\ndisk full for 4 s: EstSoil broadcasts {len(full)} (full) / {len(freed)} (freed) in 4 s; map {m}; "
          f"{ntiles} tiles read back whole")
    assert len(full) >= 36 and len(freed) >= 36
    assert "map flush failed" in log_full
    assert m.get("flush_errors", 0) >= 1
    assert m.get("flushes", 0) >= 1 and m.get("closed", 0) == 1   # the final flush after space returned worked


def test_sigkill_daemon_during_tile_writes(tmp_path: Path, recording: Path) -> None:
    """3 seeded SIGKILLs of the real daemon while it flushes tiles every 0.1 s; then a restart resumes."""
    ensure_vcan0()
    rng = random.Random(99)
    state = tmp_path / "state"
    map_dir = state / "map"
    pl = Player(recording, loops=3)
    cfg = write_config(tmp_path / "s.toml", state, recording / "vehicle.toml", pl.port,
                       extra="\n[map]\nflush_interval_s = 0.1\n")
    bus = observer()
    counts = []
    try:
        pl.start()
        for trial in range(3):
            while bus.recv(timeout=0) is not None:       # frames of the killed daemon still queued here
                pass
            d = Daemon(cfg, tmp_path / f"daemon{trial}.log")
            try:
                wait_broadcast(bus, d, 60)
                end = time.monotonic() + 20
                while len(list(iter_tile_files(map_dir))) <= (counts[-1] if counts else 0) and trial == 0:
                    assert time.monotonic() < end, d.text()[-3000:]
                    time.sleep(0.1)
                time.sleep(rng.uniform(0.5, 2.0))
                os.kill(d.proc.pid, signal.SIGKILL)
                d.proc.wait()
            finally:
                d.kill()
            counts.append(tiles_whole(map_dir))
            if trial:
                assert "resumed" in d.text() and f"with {counts[trial - 1]} tile" in d.text(), d.text()[-2000:]
    finally:
        pl.close()
        bus.shutdown()
    print(f"\ndaemon SIGKILLed 3 times during 10 Hz tile flushes: tiles on disk after each {counts}, all whole")
    assert counts[0] >= 1 and counts == sorted(counts)


REQUEST_FLOOD = r"""
import json, socket, struct, sys, time
other_rate, us_rate, seconds, us = float(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
s = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
s.bind(("vcan0",))
def request(da, sa, pgn):
    return struct.pack("=IB3x8s", 0x80000000 | (6 << 26) | (0xEA << 16) | (da << 8) | sa, 3,
                       pgn.to_bytes(3, "little") + bytes(5))
to_other = request(0x00, 0x33, 0xFEEB)       # the captured attack: Requests for PGN 0xFEEB to 0x00
to_us = request(us, 0x33, 0xFEEB)
n = {"other": 0, "us": 0, "probe": 0, "errors": 0}
probes = []                                  # (requested PGN, wall time sent): each must get its NACK
print("ready", flush=True)
sys.stdin.readline()                         # go
end = time.monotonic() + seconds
nxt = time.monotonic()
tick = 0
def send(frame, kind):
    try:
        s.send(frame)
        n[kind] += 1
        return True
    except OSError:
        n["errors"] += 1
        return False
while time.monotonic() < end:
    for _ in range(int(other_rate / 100)):
        send(to_other, "other")
    for i in range(int(us_rate / 100)):
        if i == 0 and tick % 25 == 0:        # every 0.25 s one Request from 0x34 for a PGN not asked before
            pgn = 0xFE00 + len(probes) % 256
            t = time.time()
            if send(request(us, 0x34, pgn), "probe"):
                probes.append((pgn, t))
        else:
            send(to_us, "us")
    tick += 1
    nxt += 0.01
    d = nxt - time.monotonic()
    if d > 0:
        time.sleep(d)
print(json.dumps({**n, "probes": probes}))
"""
ACK_PGN = 59392
RESPONSE_TIME_S = 0.2
"""J1939-21 response time Tr: an answer to a Request is due within 200 ms."""


def test_request_flood_with_a_cpu_hog_keeps_broadcasting_and_answering(tmp_path: Path, recording: Path) -> None:
    """The captured attack, harder: 2,500 Requests/s to another destination and 500/s to us for 15 s
    while canplayer plays the recording and a busy loop holds the guest's one CPU.  The kernel filter
    drops the Requests to 0x00; those to us are queued and served after the estimation steps."""
    import json

    ensure_vcan0()
    pl = Player(recording, loops=2)
    cfg = write_config(tmp_path / "s.toml", tmp_path / "state", recording / "vehicle.toml", pl.port)
    d = Daemon(cfg, tmp_path / "daemon.log")
    bus = can.Bus(interface="socketcan", channel=CHANNEL,
                  can_filters=[{"can_id": (65314 << 8) | SA, "can_mask": 0x3FFFFFF, "extended": True},
                               {"can_id": (ACK_PGN << 8) | (0xFF << 8) | SA, "can_mask": 0x3FFFFFF, "extended": True}])
    flood = hog = None
    try:
        wait_broadcast(bus, d, 60)
        pl.start()
        time.sleep(1.0)
        hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
        time.sleep(1.0)
        flood = subprocess.Popen([sys.executable, "-c", REQUEST_FLOOD, "2500", "500", "15", str(SA)],
                                 stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert flood.stdin is not None and flood.stdout is not None and flood.stdout.readline() == "ready\n"
        drain(bus)                                   # then the flood starts: its first answer is not discarded
        flood.stdin.write("go\n")
        flood.stdin.flush()
        cpu0 = cpu_s(d.proc.pid), cpu_s(hog.pid)
        seen: list[float] = []
        nacks: dict[int, float] = {}
        end = time.monotonic() + 15.0
        while (left := end - time.monotonic()) > 0:
            m = bus.recv(timeout=min(left, 0.1))
            if m is None:
                continue
            if j1939.pgn_of(m.arbitration_id) == 65314:
                seen.append(time.monotonic())
            elif m.data[0] == 1 and m.data[4] == 0x34:                     # NACK to a probe
                nacks.setdefault(int.from_bytes(m.data[5:8], "little"), m.timestamp)
        cpu = cpu_s(d.proc.pid) - cpu0[0], cpu_s(hog.pid) - cpu0[1]
        out, _ = flood.communicate(timeout=30)
        end = time.monotonic() + 1.0                                       # the last probe's answer
        while (left := end - time.monotonic()) > 0:
            m = bus.recv(timeout=min(left, 0.1))
            if m is not None and j1939.pgn_of(m.arbitration_id) == ACK_PGN and m.data[4] == 0x34:
                nacks.setdefault(int.from_bytes(m.data[5:8], "little"), m.timestamp)
        d.alive()
        counters = d.stop()
    finally:
        for p in (flood, hog):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait()
        pl.close()
        bus.shutdown()
        d.kill()
    sent = json.loads(out)
    probes = sent.pop("probes")
    gaps = [b - a for a, b in zip(seen, seen[1:])]
    latency = [nacks[pgn] - t if pgn in nacks else math.inf for pgn, t in probes]
    sv, cn = counters["service"], counters["can"]
    to_us = sent["us"] + sent["probe"]
    print(f"\nrequest flood with a CPU hog: sent {sent} in 15 s; EstSoil broadcasts {len(seen)} "
          f"({len(seen) / 15.0:.1f}/s), longest gap {max(gaps):.3f} s; probe answers {len(nacks)}/{len(probes)}, "
          f"latency max {max(latency) * 1e3:.0f} ms, median {sorted(latency)[len(latency) // 2] * 1e3:.0f} ms; "
          f"CPU in the 15 s: daemon {cpu[0]:.1f} s, hog {cpu[1]:.1f} s; service {sv}; can {cn}")
    assert sent["errors"] == 0 and sent["other"] >= 0.99 * 2500 * 15
    # broadcasts every 0.1 s: 150 in 15 s up to the one at either end, none held back by the flood
    log = "\n".join(line for line in d.text().splitlines() if "behind" in line or "lost" in line or "skipping" in line)
    assert len(seen) >= 145 and max(gaps) <= 0.5, (len(seen), max(gaps), log)
    assert sv.get("skipped_steps", 0) == 0
    # every probe Request (a new PGN each) answered with a NACK within the J1939 response time
    assert max(latency) <= RESPONSE_TIME_S, latency
    # every frame accounted for: none of the Requests to 0x00 reached the daemon; each one to us was
    # dropped by a full kernel buffer, shed from the full queue, joined an identical one waiting, is still
    # waiting, or was served; each served one answered or counted as rate-limited
    assert sv.get("requests_not_for_us", 0) == 0
    kinds = ("network_management", "decoded_frames", "bad_frames", "unknown_pgn_frames", "foreign_estimate_frames",
             "error_frames", "remote_frames", "standard_id_frames", "canfd_frames")
    assert cn["rx_frames"] == sum(sv.get(k, 0) for k in kinds), (cn, sv)
    arrived = sv["network_management"]
    assert to_us - cn.get("rx_kernel_dropped", 0) <= arrived <= to_us
    assert sv["requests"] + sv.get("requests_shed", 0) + sv.get("requests_coalesced", 0) + sv["requests_waiting"] == arrived
    assert (sv.get("requests_nacked", 0) + sv.get("requests_rate_limited", 0) + sv.get("requests_unanswered", 0)
            == sv["requests"])
