"""The daemon on python-can's virtual bus and a real pty: readiness, bad input, broadcast,
timeouts, watchdog, SIGTERM with flushed tiles and resume."""

from __future__ import annotations

import asyncio
import math
import os
import signal
import socket
import tty
import uuid
from datetime import datetime, timedelta, timezone
from pathlib import Path
from types import SimpleNamespace

import can
import numpy as np
import pytest

from tractionecu.bus import j1939
from tractionecu.bus.dbc import default_codec
from tractionecu.gnss import nmea
from tractionecu.mapping.store import MapStore
from tractionecu.service.config import ServiceConfig, with_overrides
from tractionecu.service.daemon import Service

CODEC = default_codec()


class StandIn:
    """A deterministic estimator stand-in: counts what it is given, always valid."""

    def __init__(self, vehicle=None, fail_at: int | None = None) -> None:
        self.calls: list[tuple[float, dict, dict]] = []
        self.fail_at = fail_at
        self.counters = {"steps": 0}

    def step(self, t, inputs, meas):
        self.calls.append((t, dict(inputs), dict(meas)))
        self.counters["steps"] += 1
        if self.fail_at is not None and len(self.calls) == self.fail_at:
            raise FloatingPointError("stand-in failure")
        return SimpleNamespace(t=t, mu=np.full(4, 0.4), slip=np.full(4, 0.05), rho_s=0.07, a=0.7,
                               P_diag=np.array([1e-4] * 5 + [1e-5] * 4 + [1e-6]),
                               soil_class="stubble", soil_class_index=0, v=2.5, status=0, valid=True)

    def reset(self) -> None:
        pass


class Rig:
    """A Service on a fresh virtual channel, a pty GNSS and a notify socket."""

    def __init__(self, tmp: Path, estimator=None, gps_present: bool = True, env: dict | None = None,
                 **overrides) -> None:
        self.channel = f"svc-{uuid.uuid4().hex[:8]}"
        self.port = tmp / "ttyGNSS"
        self.master = self.slave = None
        if gps_present:
            self.plug()
        name = f"tecu-notify-{uuid.uuid4().hex}"
        self.notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.notify.bind("\0" + name)
        self.notify.setblocking(False)
        sections = {
            "can": {"interface": "virtual", "channel": self.channel, "reopen_min_s": 0.02, "reopen_max_s": 0.1},
            "gps": {"port": str(self.port), "reopen_min_s": 0.02, "reopen_max_s": 0.1},
            "service": {"state_dir": str(tmp / "state"), "status_interval_s": 0.2},
            "map": {"flush_interval_s": 0.2, "window_half_s": 0.3},   # short runs: map samples 0.3 s late
        }
        for k, v in overrides.items():
            sections.setdefault(k, {}).update(v)
        self.cfg = with_overrides(ServiceConfig(), **sections)
        self.estimator = estimator
        env = {"NOTIFY_SOCKET": "@" + name, **(env or {})}
        self.svc = Service(self.cfg, estimator_factory=(lambda v, s: estimator) if estimator else None, env=env,
                           warm_up_estimator=estimator is None)
        self.peer = can.Bus(interface="virtual", channel=self.channel)
        self.task: asyncio.Task | None = None
        self.stop = asyncio.Event()

    def plug(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.port.symlink_to(os.ttyname(self.slave))

    async def __aenter__(self) -> Rig:
        self.task = asyncio.create_task(self.svc.run(self.stop))
        return self

    async def __aexit__(self, *exc) -> None:
        self.stop.set()
        if self.task is not None:
            await asyncio.wait_for(self.task, 20)
        self.peer.shutdown()
        self.notify.close()
        for fd in (self.master, self.slave):
            if fd is not None:
                os.close(fd)

    def notifications(self) -> list[str]:
        out = []
        while True:
            try:
                out.append(self.notify.recv(4096).decode())
            except BlockingIOError:
                return out

    def send(self, name: str, values: dict, sa: int = 0x80) -> None:
        cid, data = CODEC.encode(name, values, sa=sa)
        self.peer.send(can.Message(arbitration_id=cid, data=data))

    def inputs(self, torques: bool = True) -> None:
        self.send("TECU_WheelSpeeds", {f"WheelSpeed_{w}": 3.2 for w in ("FL", "FR", "RL", "RR")})
        if torques:
            self.send("TECU_DriveTorques", {f"DriveTorque_{w}": 900.0 for w in ("FL", "FR", "RL", "RR")})
        self.send("TECU_AxleLoad", {"FrontAxleLoad": 25000.0, "FrontAxleLoadStatus": 0})
        self.send("RearHitchStatus", {"DraftForce": 12000.0}, sa=0x82)

    def nmea(self, utc: datetime) -> None:
        lat, lon = 47.88 + 1e-6 * utc.second, -110.55
        lines = [nmea.format_gga(utc, lat, lon, 2, 12, 0.9, 850.0), nmea.format_rmc(utc, lat, lon, 2.5, 90.0),
                 nmea.format_vtg(2.5, 90.0)]
        os.write(self.master, ("\r\n".join(lines) + "\r\n").encode())

    def received(self) -> list[can.Message]:
        out = []
        while (m := self.peer.recv(timeout=0)) is not None:
            out.append(m)
        return out


async def until(pred, timeout: float = 10.0) -> None:
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while not pred():
        assert loop.time() < end, "condition not reached in time"
        await asyncio.sleep(0.01)


async def drive(rig: Rig, seconds: float, torques: bool = True, gps: bool = True) -> None:
    """Send the inputs at 100 Hz and GNSS at 10 Hz for ``seconds``."""
    loop = asyncio.get_running_loop()
    t0 = loop.time()
    k = 0
    while loop.time() - t0 < seconds:
        rig.inputs(torques)
        if gps and k % 10 == 0:
            rig.nmea(datetime.now(timezone.utc))
        k += 1
        await asyncio.sleep(0.01)


async def test_ready_waits_for_bus_and_gps_then_claims_and_broadcasts(tmp_path: Path) -> None:
    rig = Rig(tmp_path, StandIn(), gps_present=False)
    async with rig:
        await asyncio.wait_for(rig.svc.can.is_open.wait(), 10)
        await until(lambda: rig.svc.gps.stats["open_failures"] >= 2)
        assert not rig.svc.ready.is_set()
        assert not any("READY=1" in n for n in rig.notifications())
        rig.plug()
        await asyncio.wait_for(rig.svc.ready.wait(), 10)
        seen: list[str] = []
        await until(lambda: seen.extend(rig.notifications()) or any(n.startswith("READY=1") for n in seen))
        await until(lambda: rig.svc.stats["broadcasts"] >= 3)
        frames = rig.received()
    ids = [m.arbitration_id for m in frames]
    assert ids[0] == 0x18EEFF90 and bytes(frames[0].data) == rig.svc.network.claimer.name_bytes
    est = [m for m in frames if j1939.pgn_of(m.arbitration_id) in (65312, 65313, 65314)]
    assert est and all(m.arbitration_id & 0xFF == 0x90 for m in est)
    # before any wheel speed: every value "not available", every timeout bit set
    name, vals = CODEC.decode(est[2].arbitration_id, bytes(est[2].data))
    assert name == "TECU_EstSoil" and int(vals["EstimateStatus"]) == 0x3F
    assert math.isnan(vals["SoilRollingResistance"])
    assert (tmp_path / "state" / "run-config.toml").is_file()


async def test_ready_without_a_gnss_receiver_after_the_wait(tmp_path: Path, monkeypatch) -> None:
    """With the receiver unplugged (or gps.port wrong) READY=1 never came: under Type=notify systemd fails the
    start at TimeoutStartSec and restarts the service every two minutes, losing its convergence and map."""
    from tractionecu.service import daemon

    monkeypatch.setattr(daemon, "READY_GPS_WAIT_S", 0.3)
    rig = Rig(tmp_path, StandIn(), gps_present=False)
    async with rig:
        await asyncio.wait_for(rig.svc.ready.wait(), 10)
        seen: list[str] = []
        await until(lambda: seen.extend(rig.notifications()) or any(n.startswith("READY=1") for n in seen))
        assert not rig.svc.gps.is_open.is_set()
        ready = next(n for n in seen if n.startswith("READY=1"))
        assert "not open: estimating without GNSS until it opens" in ready


async def test_bad_frames_are_counted_and_skipped(tmp_path: Path) -> None:
    rig = Rig(tmp_path, StandIn(), can={"kernel_filters": False})
    async with rig:
        await asyncio.wait_for(rig.svc.ready.wait(), 10)
        p = rig.peer
        p.send(can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\x01"))
        p.send(can.Message(arbitration_id=0x18FF1080, is_remote_frame=True, dlc=8))
        p.send(can.Message(arbitration_id=0x20000004, is_error_frame=True, data=bytes(8)))
        p.send(can.Message(arbitration_id=0x0CF00300, data=bytes(8)))            # EEC2: not in the DBC
        p.send(can.Message(arbitration_id=0x18FF1080, data=b"\x01\x02\x03"))     # wheel speeds, DLC 3
        p.send(can.Message(arbitration_id=0x18FF2033, data=bytes(8)))            # an estimate from another ECU
        p.send(can.Message(arbitration_id=0x18FF10A5, data=bytes(8), is_fd=True))
        rig.send("TECU_WheelSpeeds", {"WheelSpeed_FL": 1.0}, sa=0x33)            # then good frames, any SA
        rig.inputs()                             # its wheel speeds from 0x80: a second source, counted, not used
        await until(lambda: rig.svc.stats["other_source_frames"] == 1)
        st = rig.svc.stats
        assert st["rx_TECU_WheelSpeeds"] == 1
        assert st["standard_id_frames"] == 1 and st["remote_frames"] == 1 and st["error_frames"] == 1
        assert rig.svc.dispatcher.unknown_pgns[0xF003] == 1
        assert rig.svc.dispatcher.bad_frames["TECU_WheelSpeeds"] == 1
        assert st["foreign_estimate_frames"] == 1 and st["canfd_frames"] == 1
        assert rig.task is not None and not rig.task.done()


async def test_kernel_filters_pass_only_the_dbc_pgns(tmp_path: Path) -> None:
    rig = Rig(tmp_path, StandIn())          # can.kernel_filters = true (default)
    async with rig:
        await asyncio.wait_for(rig.svc.ready.wait(), 10)
        for _ in range(5):
            rig.peer.send(can.Message(arbitration_id=0x0CF00300, data=bytes(8)))     # EEC2
            rig.peer.send(can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\x01"))
        rig.send("TECU_WheelSpeeds", {"WheelSpeed_FL": 1.0}, sa=0x33)
        await until(lambda: rig.svc.stats["rx_TECU_WheelSpeeds"] == 1)
        assert rig.svc.stats["unknown_pgn_frames"] == 0 and rig.svc.stats["standard_id_frames"] == 0
        assert rig.svc.can.stats["rx_frames"] == 1


def test_pgn_filters() -> None:
    from tractionecu.service.daemon import pgn_filters

    f = {x["can_id"]: x["can_mask"] for x in pgn_filters([65296, 60928])}
    assert f[65296 << 8] == 0x3FFFF00                # PDU2: PGN incl. group extension, any SA
    assert f[60928 << 8] == 0x3FF0000                # PDU1: destination and SA are free
    assert all(x["extended"] for x in pgn_filters([65296]))
    # Requests (and TP, ETP, acknowledgements) pass only to our address and to the global one
    f = {x["can_id"]: x["can_mask"] for x in pgn_filters([59904, 60416, 59392], 0x90)}
    assert f == {(pgn | da) << 8: 0x3FFFF00 for pgn in (59904, 60416, 59392) for da in (0x90, 0xFF)}
    assert {x["can_id"] for x in pgn_filters([59904], None)} == {(59904 | 0xFF) << 8}


async def test_filters_follow_our_address_after_a_lost_contention(tmp_path: Path) -> None:
    rig = Rig(tmp_path, StandIn())          # can.kernel_filters = true (default)
    async with rig:
        await asyncio.wait_for(rig.svc.ready.wait(), 10)
        await until(lambda: rig.svc.network.claimer.can_transmit(rig.svc.clock.now()))

        def request(da: int, pgn: int = 0xFEEB) -> None:
            rig.peer.send(can.Message(arbitration_id=j1939.make_id(6, j1939.PGN_REQUEST, 0x33, da),
                                      data=j1939.request_data(pgn)))

        for da in (0x00, 0x91, 0x90, 0xFF):
            request(da)
        await until(lambda: rig.svc.stats["requests"] == 2)
        await asyncio.sleep(0.1)
        assert rig.svc.stats["network_management"] == 2 and rig.svc.stats["requests_not_for_us"] == 0
        # a NAME of higher priority claims 0x90: we move to 0x91, the filters with us
        rig.peer.send(can.Message(arbitration_id=0x18EEFF90, data=(1).to_bytes(8, "little")))
        await until(lambda: rig.svc.network.address == 0x91)
        assert rig.svc.can.stats["filter_updates"] >= 1
        await until(lambda: rig.svc.network.claimer.can_transmit(rig.svc.clock.now()))   # 250 ms after the claim
        for da in (0x00, 0x90, 0x91, 0xFF):
            request(da)
        await until(lambda: rig.svc.stats["requests"] == 4)
        await asyncio.sleep(0.1)
        assert rig.svc.stats["network_management"] == 5      # 4 Requests and the contending claim
        nacks = [m for m in rig.received() if j1939.pgn_of(m.arbitration_id) == 59392]
        assert [(m.arbitration_id & 0xFF, m.data[0], m.data[4]) for m in nacks] == [(0x90, 1, 0x33), (0x91, 1, 0x33)]


async def test_inputs_reach_the_estimator_and_a_timeout_sets_its_bit(tmp_path: Path) -> None:
    rig = Rig(tmp_path)   # the real estimator
    async with rig:
        await asyncio.wait_for(rig.svc.ready.wait(), 10)
        while rig.svc.stats["steps"] < 100:
            await drive(rig, 0.2)
        assert rig.svc.estimation.grid_t0 is not None
        rig.received()
        status = 0
        for _ in range(100):
            await drive(rig, 0.2, torques=False)        # drive torques stop
            soil = [CODEC.decode(m.arbitration_id, bytes(m.data))[1] for m in rig.received()
                    if j1939.pgn_of(m.arbitration_id) == 65314]
            if soil and int(soil[-1]["EstimateStatus"]) & 0x04:
                status = int(soil[-1]["EstimateStatus"])
                break
    assert status & 0x04, "torque timeout bit never set"
    assert not status & 0x01, "wheel speeds kept coming, yet their timeout bit is set"


async def test_estimator_failure_is_counted_not_fatal(tmp_path: Path) -> None:
    rig = Rig(tmp_path, StandIn(fail_at=3))
    async with rig:
        await asyncio.wait_for(rig.svc.ready.wait(), 10)
        while rig.svc.stats["steps"] < 5:
            await drive(rig, 0.1, gps=False)
        assert rig.svc.stats["estimator_errors"] == 1


async def test_watchdog_and_status_notifications(tmp_path: Path) -> None:
    rig = Rig(tmp_path, StandIn(), env={"WATCHDOG_USEC": "400000"})
    async with rig:
        await asyncio.wait_for(rig.svc.ready.wait(), 10)
        seen: list[str] = []
        await until(lambda: (seen.extend(rig.notifications()) or True)
                    and "WATCHDOG=1" in seen and any(s.startswith("STATUS=") and "CAN open" in s for s in seen))
    assert any(s.startswith("READY=1") for s in seen)


class Slow(StandIn):
    """A stand-in whose steps take ``delay_s`` (a loaded CPU) while ``slow`` is set."""

    slow = False
    delay_s = 0.03

    def step(self, t, inputs, meas):
        if self.slow:
            import time
            time.sleep(self.delay_s)
        return super().step(t, inputs, meas)


async def test_watchdog_stops_while_the_loop_is_behind_and_resumes(tmp_path: Path) -> None:
    est = Slow()
    rig = Rig(tmp_path, est, env={"WATCHDOG_USEC": "400000"}, service={"watchdog_behind_s": 0.5})
    async with rig:
        await asyncio.wait_for(rig.svc.ready.wait(), 10)
        rig.inputs()                                     # phase the grid: the loop steps the estimator
        await until(lambda: rig.svc.stats["steps"] > 0)
        seen: list[str] = []
        await until(lambda: (seen.extend(rig.notifications()) or True) and "WATCHDOG=1" in seen)
        est.slow = True                                  # 30 ms per 10 ms step: behind, more each step
        await until(lambda: rig.svc.stats["watchdog_withheld"] == 1, 10)
        withheld_at = asyncio.get_running_loop().time()
        rig.notifications()
        await asyncio.sleep(1.0)
        during = rig.notifications()
        assert "WATCHDOG=1" not in during, during
        assert any(n.startswith("STATUS=estimation behind schedule") for n in during), during
        est.slow = False
        after: list[str] = []
        await until(lambda: (after.extend(rig.notifications()) or True) and "WATCHDOG=1" in after, 10)
        assert "STATUS=estimation back on schedule" in after, after
        assert rig.svc.estimation.behind_since is None
        assert asyncio.get_running_loop().time() - withheld_at >= 1.0


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
async def test_sigterm_flushes_tiles_and_a_restart_resumes_them(tmp_path: Path, sig: int) -> None:
    """SIGHUP (a closed terminal, a ``kill -HUP`` meant as reload) killed the service unflushed, losing the
    last 15–20 s of map; it now stops it as SIGTERM does."""
    rig = Rig(tmp_path, StandIn())
    async with rig:
        await asyncio.wait_for(rig.svc.ready.wait(), 10)
        while rig.svc.map.stats["added"] < 5:
            await drive(rig, 0.2)
        os.kill(os.getpid(), sig)                      # the real signal, handled by the service's loop
        assert rig.task is not None
        rc = await asyncio.wait_for(rig.task, 20)
    assert rc == 0
    added = rig.svc.map.stats["added"]
    map_dir = tmp_path / "state" / "map"
    with MapStore.open(map_dir, read_only=True) as store:
        mean, *_ = store.mean_grid("rho_s")
        assert np.nansum(np.isfinite(mean)) >= 1
        assert np.nanmax(mean) == pytest.approx(0.07)
        n_tiles = len(store.tile_keys())

    rig.port.unlink()
    rig2 = Rig(tmp_path, StandIn())
    async with rig2:
        await asyncio.wait_for(rig2.svc.ready.wait(), 10)
        assert rig2.svc.map.stats["resumed_tiles"] == n_tiles
    assert added >= 5


def test_unknown_pgn_table_is_bounded_under_random_pgns(tmp_path: Path) -> None:
    """Hostile traffic with every PGN must not grow the per-PGN table (2^18 possible keys)."""
    from tractionecu.service.dispatch import MAX_TRACKED_UNKNOWN_PGNS

    cfg = with_overrides(ServiceConfig(), gps={"source": "none"}, service={"state_dir": str(tmp_path / "state")})
    svc = Service(cfg, env={}, warm_up_estimator=False)
    pgns = [p for p in range(0xF000, 0xF000 + 3000) if CODEC.message_for_pgn(p) is None]
    for k, pgn in enumerate(pgns):
        svc.dispatcher.on_frame(1.0 + k * 1e-3, can.Message(arbitration_id=(6 << 26) | (pgn << 8) | 0x42,
                                                            data=bytes(8)))
    svc.dispatcher.on_frame(9.0, can.Message(arbitration_id=(6 << 26) | (pgns[0] << 8) | 0x42, data=bytes(8)))
    assert len(svc.dispatcher.unknown_pgns) == MAX_TRACKED_UNKNOWN_PGNS
    assert svc.dispatcher.unknown_pgns[pgns[0]] == 2                       # a tracked PGN keeps counting
    assert svc.stats["unknown_pgn_frames"] == len(pgns) + 1
    assert svc.stats["unknown_pgn_untracked"] == len(pgns) - MAX_TRACKED_UNKNOWN_PGNS


def test_without_a_gnss_source_the_map_state_says_so(tmp_path: Path) -> None:
    """gps.source = "none": the page's map health said "waiting for a GNSS fix" for ever."""
    cfg = with_overrides(ServiceConfig(), gps={"source": "none"}, service={"state_dir": str(tmp_path / "state")})
    svc = Service(cfg, env={}, warm_up_estimator=False)
    assert svc.map is not None and svc.map.state == 'no GNSS source (gps.source = "none"): nothing is mapped'
    cfg = with_overrides(ServiceConfig(), service={"state_dir": str(tmp_path / "state2")})
    assert Service(cfg, env={}, warm_up_estimator=False).map.state == "waiting for a GNSS fix"


def test_broadcast_values_clipped_to_the_dbc_range_are_in_the_counters(tmp_path: Path) -> None:
    """The codec counted values sent at the DBC's limit, and nothing in the service read the count."""
    from tractionecu.service import broadcast

    cfg = with_overrides(ServiceConfig(), gps={"source": "none"}, service={"state_dir": str(tmp_path / "state")})
    svc = Service(cfg, env={}, warm_up_estimator=False)
    assert "broadcast_clipped" not in svc.counters()
    est = StandIn().step(1.0, {}, {})
    est.rho_s = 5.0                                              # the DBC carries ρ_s up to 0.65534
    broadcast.estimate_frames(svc.network.codec, est, 0x90, 6)
    assert svc.counters()["broadcast_clipped"] == {"SoilRollingResistance": 1}


def test_a_second_service_on_a_state_directory_is_refused_at_its_start(tmp_path: Path, capsys,
                                                                          locked_elsewhere) -> None:
    """A second service on one state directory (a second instance of the unit, ``run --simulate`` twice) was
    refused only when it came to open the map: one started before the map existed ran on beside the first,
    retrying the map for as long as it ran, and a second ``run --simulate`` first wrote its simulation over the
    one the first was playing (which lost half its frames).  The state directory is now locked by the service
    from its start, and by ``run --simulate`` from before it writes the simulation: the second one is refused
    by name and writes nothing there."""
    from tractionecu.cli.main import main
    from tractionecu.mapping.tiles import MapStoreError

    state = tmp_path / "state"
    state.mkdir()
    with locked_elsewhere(state):
        cfg = with_overrides(ServiceConfig(), gps={"source": "none"}, service={"state_dir": str(state)},
                             can={"interface": "virtual", "channel": f"svc-{uuid.uuid4().hex[:8]}"})
        with pytest.raises(MapStoreError, match="another tractionecu service runs on this state directory"):
            asyncio.run(Service(cfg, env={}, warm_up_estimator=False).run())
        assert main(["run", "--simulate", "--duration", "5", "--no-web", "--state-dir", str(state)]) == 1
        assert "another tractionecu service runs on this state directory" in capsys.readouterr().err
        assert list(state.iterdir()) == []                 # no run-config.toml, no simulation, no map
    svc = Service(cfg, env={}, warm_up_estimator=False)
    svc._write_state()                                     # the lock went with the process that held it
    assert (state / "run-config.toml").is_file()
    svc._release_state()


async def test_a_full_disk_at_start_leaves_the_service_running(tmp_path: Path, monkeypatch) -> None:
    """With the state directory's disk full the service did not start (``service.state_dir: cannot write``, exit
    1, restarted by systemd again and again: no estimate on the bus), for the record of its configuration it
    writes there.  It now starts and broadcasts, the write counted and logged; the earlier run-config.toml
    is left whole (it was truncated to 0 bytes)."""
    import errno

    from tractionecu.service import daemon

    state = tmp_path / "state"
    state.mkdir()
    (state / "run-config.toml").write_text("# the earlier run's\n", encoding="utf-8")

    def full(path, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(daemon, "atomic_write_bytes", full)
    rig = Rig(tmp_path, StandIn())
    async with rig:
        await asyncio.wait_for(rig.svc.ready.wait(), 10)
        await until(lambda: rig.svc.stats["broadcasts"] >= 3)
    assert rig.svc.stats["state_write_errors"] == 1
    assert (state / "run-config.toml").read_text(encoding="utf-8") == "# the earlier run's\n"
