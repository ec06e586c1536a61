"""The daemon's parts through their public methods: dispatch, fix buffer, network, estimation loop,
lifecycle, and the service's declared start/stop order."""

from __future__ import annotations

import asyncio
import logging
import math
import random
import uuid
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

import can
import numpy as np
import pytest

from tractionecu.bus import j1939
from tractionecu.bus.dbc import default_codec
from tractionecu.config import VehicleParams
from tractionecu.pipeline.gnss import GnssGate
from tractionecu.pipeline.steps import GRID_MARGIN_S, StepAssembler
from tractionecu.service.address_claim import ClaimState
from tractionecu.service.broadcast import MESSAGES, NO_DATA_STATUS
from tractionecu.service.clock import ServiceClock
from tractionecu.service.config import ServiceConfig, with_overrides
from tractionecu.service.daemon import Service
from tractionecu.service.dispatch import FrameDispatcher
from tractionecu.service.fixes import FixBuffer
from tractionecu.service.gps import GpsSample
from tractionecu.service.lifecycle import DeviceTask, Hook, Lifecycle, TaskPart
from tractionecu.service.loop import EstimationLoop
from tractionecu.service.network import Network

CODEC = default_codec()
WHEELS = ("FL", "FR", "RL", "RR")


def frame(name: str, values: dict, sa: int = 0x80) -> can.Message:
    cid, data = CODEC.encode(name, values, sa=sa)
    return can.Message(arbitration_id=cid, data=data)


def wheel_speeds(v: float = 3.2) -> can.Message:
    return frame("TECU_WheelSpeeds", {f"WheelSpeed_{w}": v for w in WHEELS})


def fix(t: float, speed: float | None = 2.5, arrival: float | None = None) -> GpsSample:
    return GpsSample(t, t if arrival is None else arrival, 47.88, -110.55, 850.0, speed, 90.0, 2, 0.9, 12)


def dispatcher(on_network=None) -> tuple[FrameDispatcher, StepAssembler, FixBuffer]:
    steps = StepAssembler()
    fixes = FixBuffer(GnssGate(max_age_s=0.5))
    return FrameDispatcher(CODEC, steps, fixes, on_network=on_network, lag_s=0.01), steps, fixes


class StandIn:
    """An estimator stand-in: records its steps; fails at step ``fail_at``."""

    def __init__(self, fail_at: int | None = None) -> None:
        self.calls: list[tuple[float, dict, dict]] = []
        self.fail_at = fail_at
        self.resets = 0

    def step(self, t, inputs, meas):
        self.calls.append((t, dict(inputs), dict(meas)))
        if self.fail_at is not None and len(self.calls) == self.fail_at:
            raise FloatingPointError("stand-in failure")
        return SimpleNamespace(t=t, mu=np.full(4, 0.4), slip=np.full(4, 0.05), rho_s=0.07, a=0.7,
                               soil_class_index=0, v=2.5, status=0, valid=True)

    def reset(self) -> None:
        self.resets += 1


# ----------------------------------------------------------------------------- dispatch
def test_dispatch_counts_every_kind_of_bad_frame_and_passes_none_on() -> None:
    d, steps, _ = dispatcher()
    d.on_frame(1.0, can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\x01"))
    d.on_frame(1.0, can.Message(arbitration_id=0x20000004, is_error_frame=True, data=bytes(8)))
    d.on_frame(1.0, can.Message(arbitration_id=0x18FF1080, is_remote_frame=True, dlc=8))
    d.on_frame(1.0, can.Message(arbitration_id=0x18FF10A5, data=bytes(8), is_fd=True))
    d.on_frame(1.0, can.Message(arbitration_id=0x0CF00300, data=bytes(8)))        # EEC2: not in the DBC
    d.on_frame(1.0, can.Message(arbitration_id=0x18FF1080, data=b"\x01\x02\x03"))  # wheel speeds, DLC 3
    d.on_frame(1.0, can.Message(arbitration_id=0x18FF2033, data=bytes(8)))         # another ECU's estimate
    st = d.stats
    assert (st["standard_id_frames"], st["error_frames"], st["remote_frames"], st["canfd_frames"]) == (1, 1, 1, 1)
    assert st["unknown_pgn_frames"] == 1 and d.unknown_pgns == Counter({0xF003: 1})
    assert st["bad_frames"] == 1 and d.bad_frames == Counter({"TECU_WheelSpeeds": 1})
    assert st["foreign_estimate_frames"] == 1
    assert st["decoded_frames"] == 0
    assert steps.anchor is None and steps.take(2.0) == ({}, {})


def test_dispatch_logs_a_bad_frame_once_per_message(caplog: pytest.LogCaptureFixture) -> None:
    d, _, _ = dispatcher()
    with caplog.at_level(logging.DEBUG, logger="tractionecu.service.dispatch"):
        for _ in range(3):
            d.on_frame(1.0, can.Message(arbitration_id=0x18FF1080, data=b"\x01\x02\x03"))
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and "skipped frame 18FF1080#010203" in warnings[0].getMessage()
    assert d.bad_frames["TECU_WheelSpeeds"] == 3


def test_dispatch_decodes_into_the_step_assembler_which_phases_the_grid() -> None:
    d, steps, _ = dispatcher()
    d.on_frame(5.0, frame("TECU_DriveTorques", {f"DriveTorque_{w}": 900.0 for w in WHEELS}))
    assert steps.anchor is None                           # only a wheel-speed frame phases the grid
    d.on_frame(5.002, wheel_speeds(3.2))
    assert steps.anchor == 5.002 + GRID_MARGIN_S
    assert d.stats["decoded_frames"] == 2 and d.stats["rx_TECU_WheelSpeeds"] == 1
    inputs, meas = steps.take(steps.anchor)
    np.testing.assert_allclose(inputs["Md"], 900.0)
    np.testing.assert_allclose(meas["omega"], CODEC.quantize("WheelSpeed_FL", 3.2))


def test_dispatch_hands_network_management_to_the_network() -> None:
    seen: list[tuple[int, bytes]] = []
    d, _, _ = dispatcher(on_network=lambda cid, data: seen.append((cid, data)))
    claim = can.Message(arbitration_id=0x18EEFF33, data=bytes(range(8)))
    request = can.Message(arbitration_id=0x18EAFF33, data=b"\x00\xEE\x00")
    d.on_frame(1.0, claim)
    d.on_frame(1.0, request)
    assert seen == [(0x18EEFF33, bytes(range(8))), (0x18EAFF33, b"\x00\xEE\x00")]
    alone, _, _ = dispatcher()                          # no network: only counted
    alone.on_frame(1.0, claim)
    assert alone.stats["network_management"] == 1


def test_dispatch_fix_goes_to_the_buffer_and_its_speed_to_the_assembler() -> None:
    d, steps, fixes = dispatcher()
    d.on_fix(fix(10.0, speed=2.5))
    d.on_fix(fix(10.1, speed=None))
    assert d.stats["gps_fixes"] == 2 and fixes.last is not None and fixes.last.t == 10.1 and len(fixes) == 2
    assert steps.take(10.2) == ({}, {"v": 2.5, "course": 90.0})        # the course goes with the speed


def test_dispatch_late_fix_is_used_one_step_late_and_warned_once(caplog: pytest.LogCaptureFixture) -> None:
    d, steps, _ = dispatcher()
    steps.take(20.0)
    with caplog.at_level(logging.WARNING, logger="tractionecu.service.dispatch"):
        d.on_fix(fix(19.99, arrival=20.02))
        d.on_fix(fix(19.995, arrival=20.03))
    assert steps.counts["late"] == 2
    assert len([r for r in caplog.records if "used one step late" in r.getMessage()]) == 1
    assert steps.take(20.01) == ({}, {"v": 2.5, "course": 90.0})


# ----------------------------------------------------------------------------- fix buffer
def test_fix_buffer_gives_the_latest_fix_while_the_gate_calls_it_fresh() -> None:
    buf = FixBuffer(GnssGate(max_age_s=0.5))
    assert buf.fix_at(1.0) is None
    buf.add(fix(1.0))
    buf.add(fix(1.1))
    assert buf.fix_at(0.95) is None                      # nothing at or before
    assert buf.fix_at(1.05).t == 1.0
    assert buf.fix_at(1.6).t == 1.1                      # exactly max_age_s old: still fresh
    assert buf.fix_at(1.7) is None                       # stale
    small = FixBuffer(GnssGate(), depth=2)
    for t in (1.0, 1.1, 1.2):
        small.add(fix(t))
    assert len(small) == 2 and small.fix_at(1.05) is None   # the oldest was dropped


# ----------------------------------------------------------------------------- network
class FakeLink:
    def __init__(self, is_open: bool = True) -> None:
        self.bus = object() if is_open else None
        self.sent: list[tuple[int, bytes]] = []

    def send(self, can_id: int, data: bytes) -> bool:
        self.sent.append((can_id, bytes(data)))
        return True


class FakeTime:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def network(link: FakeLink, **broadcast) -> tuple[Network, FakeTime]:
    mono = FakeTime()
    cfg = with_overrides(ServiceConfig(), broadcast=broadcast) if broadcast else ServiceConfig()
    return Network(cfg.broadcast, CODEC, ServiceClock(epoch0=1.7e9, monotonic=mono), link), mono


async def test_network_claims_once_started_then_broadcasts_after_250_ms() -> None:
    link = FakeLink()
    net, mono = network(link)
    net.on_bus_open()
    assert link.sent == []                               # not started: no claim yet
    await net.start()                                    # the bus is open already: claim now
    assert link.sent == [(0x18EEFF90, net.claimer.name_bytes)] and net.address == 0x90
    assert not net.broadcast(None) and net.stats["broadcast_skipped"] == 1
    mono.t += 0.3
    est = SimpleNamespace(mu=[0.4] * 4, slip=[0.05] * 4, rho_s=0.07, a=0.7, status=0, soil_class_index=1)
    assert net.broadcast(est)
    frames = link.sent[1:]
    assert [CODEC.message_for_id(cid).name for cid, _ in frames] == list(MESSAGES)
    assert all(cid & 0xFF == 0x90 for cid, _ in frames)
    _, soil = CODEC.decode(*frames[2])
    assert soil["SoilRollingResistance"] == CODEC.quantize("SoilRollingResistance", 0.07)
    link.sent.clear()
    assert net.broadcast(None)
    _, soil = CODEC.decode(*link.sent[2])
    assert int(soil["EstimateStatus"]) == NO_DATA_STATUS and math.isnan(soil["SoilRollingResistance"])
    assert net.stats["broadcasts"] == 2
    net.on_bus_open()                                    # the bus came back: claim again
    assert link.sent[-1] == (0x18EEFF90, net.claimer.name_bytes)
    n = len(link.sent)
    await net.stop()
    net.on_bus_open()                                    # stopped: silent
    assert len(link.sent) == n


async def test_network_listen_only_never_transmits() -> None:
    link = FakeLink()
    net, mono = network(link, enabled=False)
    await net.start()
    net.on_nm_frame(0x18EAFF33, b"\x00\xEE\x00")
    mono.t += 1.0
    assert not net.broadcast(None)
    assert link.sent == [] and net.address is None and net.describe_address() == "listen-only"
    assert net.stats["network_management"] == 1 and net.stats["broadcast_skipped"] == 1


async def test_network_answers_a_request_and_its_delayed_frame_is_cancelled_by_stop() -> None:
    request = (j1939.make_id(6, j1939.PGN_REQUEST, 0x33, j1939.ADDRESS_GLOBAL),
               j1939.request_data(j1939.PGN_ADDRESS_CLAIMED))
    for stop_first in (False, True):
        link = FakeLink()
        net, mono = network(link)
        await net.start()
        net.on_nm_frame(*request)                        # queued for after the next estimation step
        assert len(link.sent) == 1 and net.serve_requests() == 1
        assert link.sent[-1] == (0x18EEFF90, net.claimer.name_bytes) and len(link.sent) == 2
        net.claimer.state, net.claimer.address = ClaimState.CANNOT_CLAIM, None
        net.claimer.rng = random.Random(4)
        mono.t += 0.2                                    # past broadcast.request_answer_interval_s
        net.on_nm_frame(*request)                        # Cannot Claim, after a random delay of ≤ 153 ms
        assert net.serve_requests() == 1 and len(link.sent) == 2
        if stop_first:
            await net.stop()
        await asyncio.sleep(0.3)
        cannot = [c for c, _ in link.sent if c == 0x18EEFFFE]
        assert len(cannot) == (0 if stop_first else 1)


async def test_network_serves_requests_bounded_per_step_rate_limited_and_counts_the_rest() -> None:
    from tractionecu.service.network import REQUEST_QUEUE_FRAMES

    link = FakeLink()
    net, mono = network(link, requests_per_tick=4)
    await net.start()
    mono.t += 0.3                                        # claimed: may answer
    link.sent.clear()

    def request(sa: int, da: int, pgn: int) -> None:
        net.on_nm_frame(j1939.make_id(6, j1939.PGN_REQUEST, sa, da), j1939.request_data(pgn))

    request(0x33, 0x00, 0xFEEB)                          # not for us (no kernel filter here)
    for _ in range(50):
        request(0x33, 0x90, 0xFEEB)                      # one waits, 49 join it
    for pgn in range(0xFE00, 0xFE00 + REQUEST_QUEUE_FRAMES + 5):
        request(0x34, 0x90, pgn)                         # distinct: the queue fills, the rest is shed
    request(0x35, 0xFF, 0xFEEB)                          # the queue is full: shed as well
    st = net.stats
    assert st["requests_not_for_us"] == 1 and st["requests_coalesced"] == 49 and st["requests_shed"] == 7
    assert net.waiting() == REQUEST_QUEUE_FRAMES
    assert net.serve_requests() == 4 and net.waiting() == REQUEST_QUEUE_FRAMES - 4   # bounded per step
    while net.serve_requests():
        pass
    assert st["requests"] == REQUEST_QUEUE_FRAMES and st["requests_nacked"] == REQUEST_QUEUE_FRAMES
    nack = link.sent[0]
    assert nack[0] == 0x18E8FF90 and nack[1] == bytes([1, 0xFF, 0xFF, 0xFF, 0x33, 0xEB, 0xFE, 0x00])
    request(0x33, 0x90, 0xFEEB)                          # the same again within 0.1 s: not answered
    net.serve_requests()
    assert st["requests_rate_limited"] == 1 and len(link.sent) == REQUEST_QUEUE_FRAMES
    mono.t += 0.11
    request(0x33, 0x90, 0xFEEB)
    net.serve_requests()
    assert st["requests_nacked"] == REQUEST_QUEUE_FRAMES + 1
    assert (st["network_management"] == 1 + 50 + REQUEST_QUEUE_FRAMES + 5 + 1 + 2
            == st["requests_not_for_us"] + st["requests_coalesced"] + st["requests_shed"] + st["requests"])


# ----------------------------------------------------------------------------- estimation loop
def loop_part(estimator, **kw) -> tuple[EstimationLoop, StepAssembler]:
    steps = StepAssembler()
    est_loop = EstimationLoop(ServiceConfig(), ServiceClock(), steps, factory=lambda v, s: estimator, **kw)
    est_loop.build_estimator()
    return est_loop, steps


def test_loop_builds_the_estimator_for_the_configured_machine() -> None:
    built = []
    est_loop = EstimationLoop(ServiceConfig(), ServiceClock(), StepAssembler(),
                              factory=lambda v, s: built.append((v, s)) or StandIn())
    est = est_loop.build_estimator()
    assert isinstance(est, StandIn) and est_loop.estimator is est
    assert built[0][0] == VehicleParams() and est_loop.machine == built[0]


def test_loop_step_feeds_the_assembled_arguments() -> None:
    est = StandIn()
    est_loop, steps = loop_part(est)
    steps.push_signals(1.0, {f"WheelSpeed_{w}": 3.0 for w in WHEELS})
    steps.push_speed(1.0, 2.4)
    e = est_loop.step(1.005)
    assert e is not None and est_loop.last_estimate is e and est_loop.stats["steps"] == 1
    t, inputs, meas = est.calls[0]
    assert t == 1.005 and inputs == {} and set(meas) == {"omega", "v", "course"}
    assert math.isnan(meas["course"])                   # a speed pushed without a course: NaN, as replay passes it
    est_loop.step(1.015)
    assert est.calls[1][2] == {}                         # nothing new: nothing passed


def test_a_silent_bus_pauses_the_estimator_instead_of_integrating_held_torques() -> None:
    """The CAN bus went silent with the service running: every step predicted with the held drive torques and
    no measurement, and the page's speed grew by 0.3 m/s² without end (5326 m/s after 90 min).  As replay's
    grid has no step in a wheel-speed gap longer than GRID_MAX_GAP_S, the loop now steps nothing there and
    publishes a no-data estimate; the first step after the gap restarts the filter."""
    from tractionecu.estimation.estimator import NOT_CONVERGED, WHEEL_TIMEOUT, Estimator
    from tractionecu.pipeline.steps import GRID_MAX_GAP_S

    est_loop, steps = loop_part(Estimator(VehicleParams()))
    r = VehicleParams().r0_m

    def push(t: float) -> None:
        steps.push_signals(t, {**{f"WheelSpeed_{w}": 2.6 / r for w in WHEELS},
                               **{f"DriveTorque_{w}": 2500.0 for w in WHEELS},
                               "FrontAxleLoad": 25e3, "DraftForce": 8e3})
        if round(t * 100) % 10 == 0:
            steps.push_speed(t, 2.5)

    t = 0.0
    for k in range(500):                                 # 5 s of data at 100 Hz
        t = k / 100.0
        push(t)
        est_loop.step(t + 0.005)
    assert math.isfinite(est_loop.last_estimate.v)
    v_last = est_loop.last_estimate.v
    for k in range(500, 1500):                           # 10 s of silence
        e = est_loop.step(k / 100.0 + 0.005)            # (the smoother delivers the estimate of 60 ms before)
        if e.t - t > GRID_MAX_GAP_S:
            assert math.isnan(e.v) and e.status & WHEEL_TIMEOUT and e.status & NOT_CONVERGED and not e.valid
        else:
            assert abs(e.v - v_last) < 1.0                # predicted only for the 2 s a step may hold
    assert est_loop.stats["no_data_steps"] > 700
    for k in range(1500, 1700):                          # the data return: the filter restarts
        push(k / 100.0)
        e = est_loop.step(k / 100.0 + 0.005)
    assert est_loop.estimator.counters["gap_resets"] == 1 and math.isfinite(e.v) and abs(e.v - 2.5) < 0.5


async def test_a_stop_delivers_and_maps_what_the_smoother_still_held() -> None:
    """The smoother holds the last 0.05 s of estimates until the steps after them arrive: a stop dropped them (the
    page and the map ended 60 ms early).  The stop now flushes them: the last is the loop's last estimate and the
    map gets those due at its 10 Hz after the last one it was given."""
    from tractionecu.estimation.estimator import Estimator

    class MapStandIn:
        def __init__(self) -> None:
            self.added: list = []

        def add(self, e, fix) -> None:
            self.added.append(e)

        def discard_since(self, t: float) -> None:
            pass

    mp = MapStandIn()
    est_loop, steps = loop_part(Estimator(VehicleParams()), map_writer=mp)
    r = VehicleParams().r0_m
    t_last = 0.0
    for k in range(300):                                 # 3 s at 100 Hz
        t = k / 100.0
        steps.push_signals(t, {**{f"WheelSpeed_{w}": 2.6 / r for w in WHEELS},
                               **{f"DriveTorque_{w}": 2500.0 for w in WHEELS},
                               "FrontAxleLoad": 25e3, "DraftForce": 8e3})
        if k % 10 == 0:
            steps.push_speed(t, 2.5)
        t_last = t + 0.005
        est_loop.step(t_last)
    delivered = est_loop.last_estimate
    assert t_last - delivered.t == pytest.approx(0.06)    # six steps held
    est_loop._t_mapped = delivered.t - 0.05               # as if the loop had mapped the estimate 50 ms before
    await est_loop.stop()                                 # (the loop's task never started)
    assert est_loop.last_estimate.t == pytest.approx(t_last) and est_loop.last_estimate.transition is None
    assert [e.t for e in mp.added] == [pytest.approx(delivered.t + 0.05)]     # 0.1 s after the last mapped
    assert est_loop.stats["mapped_at_stop"] == 1
    assert est_loop.flush_smoother() == []                # nothing twice


def test_loop_step_counts_an_estimator_failure_and_resets_it() -> None:
    est = StandIn(fail_at=2)
    est_loop, _ = loop_part(est)
    assert est_loop.step(1.0) is not None
    assert est_loop.step(1.01) is None
    assert est_loop.step(1.02) is not None
    assert est_loop.stats["estimator_errors"] == 1 and est_loop.stats["steps"] == 2 and est.resets == 1


async def test_loop_idles_until_the_grid_is_phased_then_steps_on_it() -> None:
    sent: list = []
    est = StandIn()
    est_loop, steps = loop_part(est, broadcast=sent.append)
    await est_loop.start()
    try:
        deadline = asyncio.get_running_loop().time() + 10
        while est_loop.stats["idle_ticks"] < 3:
            assert asyncio.get_running_loop().time() < deadline
            await asyncio.sleep(0.01)
        assert est.calls == [] and sent and all(b is None for b in sent)   # "no estimate" broadcasts
        t_ws = est_loop.clock.now()
        steps.push_signals(t_ws, {f"WheelSpeed_{w}": 3.0 for w in WHEELS})
        while est_loop.stats["steps"] < 25:
            assert asyncio.get_running_loop().time() < deadline
            await asyncio.sleep(0.01)
    finally:
        await est_loop.stop()
    assert est_loop.grid_t0 == t_ws + GRID_MARGIN_S
    g0 = est_loop.grid_t0
    ts = [t for t, _, _ in est.calls]
    ks = [round((t - g0) * 100.0) for t in ts]            # steps on the grid g0 + k / rate, in order
    assert ks[0] == 0 and ks == sorted(set(ks))           # (a busy machine may skip steps, never repeat them)
    assert ts == [g0 + k / 100.0 for k in ks]
    assert est_loop.task is not None and est_loop.task.cancelled()


# ----------------------------------------------------------------------------- lifecycle
class Recorder:
    """A part that logs its start and stop; its stop may raise."""

    def __init__(self, name: str, log: list[str], fail_start: bool = False, fail_stop: bool = False) -> None:
        self.name = name
        self.log = log
        self.fail_start = fail_start
        self.fail_stop = fail_stop

    async def start(self) -> None:
        if self.fail_start:
            raise OSError(f"{self.name} cannot start")
        self.log.append("start " + self.name)

    async def stop(self) -> None:
        self.log.append("stop " + self.name)
        if self.fail_stop:
            raise RuntimeError(f"{self.name} failed to stop")


async def test_lifecycle_starts_in_order_and_stops_in_reverse_gathering_errors() -> None:
    log: list[str] = []
    lc = Lifecycle([Recorder("a", log), Recorder("b", log, fail_stop=True), Recorder("c", log),
                    Hook("d", start=lambda: log.append("start d"), stop=lambda: log.append("stop d"))])
    assert lc.names() == ["a", "b", "c", "d"]
    await lc.start()
    errors = await lc.stop()
    assert log == ["start a", "start b", "start c", "start d", "stop d", "stop c", "stop b", "stop a"]
    assert errors == ["b: RuntimeError('b failed to stop')"]
    assert lc.started == [] and await lc.stop() == []


async def test_lifecycle_a_failed_start_stops_only_what_was_started() -> None:
    log: list[str] = []
    lc = Lifecycle([Recorder("a", log), Recorder("b", log), Recorder("c", log, fail_start=True),
                    Recorder("d", log)])
    with pytest.raises(OSError, match="c cannot start"):
        await lc.start()
    assert await lc.stop() == []
    assert log == ["start a", "start b", "stop b", "stop a"]


async def test_lifecycle_starts_no_part_after_a_stop_is_asked() -> None:
    log: list[str] = []
    stop = asyncio.Event()
    lc = Lifecycle([Recorder("a", log), Hook("b", start=stop.set), Recorder("c", log)])
    await lc.start(stop)
    assert [p.name for p in lc.started] == ["a", "b"]
    assert await lc.stop() == [] and log == ["start a", "stop a"]


def test_lifecycle_rejects_a_name_declared_twice() -> None:
    with pytest.raises(ValueError, match="twice"):
        Lifecycle([Recorder("a", []), Recorder("a", [])])


async def test_lifecycle_lists_the_tasks_of_started_task_parts() -> None:
    class Forever(TaskPart):
        name = "forever"

        async def run(self) -> None:
            await asyncio.Event().wait()

    part = Forever()
    lc = Lifecycle([Hook("h"), part])
    assert lc.tasks() == []
    await lc.start()
    assert lc.tasks() == [("forever", part.task)]
    assert await lc.stop() == [] and part.task.cancelled() and lc.tasks() == []


async def test_device_task_closes_the_device_and_reports_one_that_does_not_stop() -> None:
    class Device:
        def __init__(self, obeys: bool) -> None:
            self.obeys = obeys
            self.closed = asyncio.Event()

        async def run(self) -> None:
            if self.obeys:
                await self.closed.wait()
            else:
                await asyncio.Event().wait()

        async def close(self) -> None:
            self.closed.set()

    good, bad = DeviceTask("good", Device(True)), DeviceTask("bad", Device(False), stop_timeout_s=0.05)
    lc = Lifecycle([good, bad])
    await lc.start()
    await asyncio.sleep(0)
    errors = await lc.stop()
    assert errors == ["bad: TimeoutError('did not stop within 0.05 s')"]
    assert good.task.done() and not good.task.cancelled() and bad.task.cancelled()


# ----------------------------------------------------------------------------- the service's order
def service_cfg(tmp_path: Path, **sections) -> ServiceConfig:
    base = {"can": {"interface": "virtual", "channel": f"parts-{uuid.uuid4().hex[:8]}"},
            "gps": {"source": "none"}, "service": {"state_dir": str(tmp_path / "state"), "status_interval_s": 0.1},
            "map": {"enabled": False}}
    for k, v in sections.items():
        base.setdefault(k, {}).update(v)
    return with_overrides(ServiceConfig(), **base)


def test_service_declares_its_parts_in_the_documented_order(tmp_path: Path) -> None:
    cfg = service_cfg(tmp_path, gps={"source": "serial", "port": str(tmp_path / "tty")}, map={"enabled": True})
    assert Service(cfg, env={}).lifecycle.names() == [
        "state", "estimator", "map", "can", "gps", "network", "warm-up", "estimation", "advice", "web", "status",
        "ready"]
    assert Service(service_cfg(tmp_path, advice={"enabled": False}, web={"enabled": False}),
                   env={}).lifecycle.names() == [
        "state", "estimator", "can", "network", "warm-up", "estimation", "status", "ready"]


async def test_a_part_added_to_the_service_starts_in_order_and_stops_in_reverse(tmp_path: Path,
                                                                                  caplog: pytest.LogCaptureFixture
                                                                                  ) -> None:
    log: list[str] = []

    class WithExtra(Service):
        def parts(self):
            parts = super().parts()
            i = [p.name for p in parts].index("network")
            return parts[:i] + [Recorder("extra", log, fail_stop=True)] + parts[i:]

    svc = WithExtra(service_cfg(tmp_path), env={}, estimator_factory=lambda v, s: StandIn(),
                    warm_up_estimator=False)
    for p in svc.lifecycle.parts:
        if p.name == "extra":
            continue

        def wrap(p=p, start=p.start, stop=p.stop):
            async def rec_start():
                log.append("start " + p.name)
                await start()

            async def rec_stop():
                log.append("stop " + p.name)
                await stop()

            p.start, p.stop = rec_start, rec_stop

        wrap()
    names = svc.lifecycle.names()
    assert names == ["state", "estimator", "can", "extra", "network", "warm-up", "estimation", "advice", "web",
                     "status", "ready"]
    stop = asyncio.Event()
    with caplog.at_level(logging.ERROR, logger="tractionecu.service.daemon"):
        task = asyncio.create_task(svc.run(stop))
        await asyncio.wait_for(svc.ready.wait(), 10)
        while svc.stats["steps"] + svc.stats["idle_ticks"] < 3:
            await asyncio.sleep(0.01)
        stop.set()
        rc = await asyncio.wait_for(task, 20)
    assert log == [f"start {n}" for n in names] + [f"stop {n}" for n in reversed(names)]
    assert rc == 1                                        # the failed stop is an error ...
    assert any("shutdown: extra: RuntimeError('extra failed to stop')" in r.getMessage() for r in caplog.records)
    assert svc.estimation.task.cancelled() and svc.can.bus is None   # ... and every other part was stopped


async def test_a_part_task_that_ends_by_itself_stops_the_service_with_an_error(tmp_path: Path) -> None:
    class Quits(TaskPart):
        name = "quits"

        async def run(self) -> None:
            await asyncio.sleep(0.05)
            raise RuntimeError("gave up")

    class WithQuitter(Service):
        def parts(self):
            return super().parts() + [Quits()]

    svc = WithQuitter(service_cfg(tmp_path), env={}, estimator_factory=lambda v, s: StandIn(),
                      warm_up_estimator=False)
    rc = await asyncio.wait_for(svc.run(asyncio.Event()), 20)
    assert rc == 1 and svc.can.bus is None and svc.estimation.task.cancelled()


async def test_a_stop_during_the_warm_up_does_not_wait_for_it(tmp_path: Path, monkeypatch) -> None:
    """A first start compiles the estimator's kernels for 30-45 s; a SIGTERM meanwhile waited for all of it
    (the warm-up's executor thread, then the parts after it), beyond systemd's TimeoutStopSec = 20 s."""
    import threading

    from tractionecu.service import loop as service_loop

    loop = asyncio.get_running_loop()
    compiling, release = asyncio.Event(), threading.Event()

    def slow_warm_up(*args) -> float:
        loop.call_soon_threadsafe(compiling.set)
        release.wait(60)
        return 60.0

    monkeypatch.setattr(service_loop, "warm_up", slow_warm_up)
    svc = Service(service_cfg(tmp_path), env={}, estimator_factory=lambda v, s: StandIn())
    stop = asyncio.Event()
    try:
        task = asyncio.create_task(svc.run(stop))
        await asyncio.wait_for(compiling.wait(), 20)
        stop.set()
        rc = await asyncio.wait_for(task, 10)
    finally:
        release.set()
    assert rc == 0
    assert svc.estimation.task is None and not svc.ready.is_set()       # nothing after the warm-up started
    assert svc.can.bus is None                                           # what had started was stopped


def test_status_lines_to_the_journal_come_once_a_minute() -> None:
    """Under systemd (standard output not a terminal) no status line was printed at all, though README says
    ``journalctl -u tractionecu -f`` shows them; a line a second would flood the journal."""
    import io

    from tractionecu.service.status import StatusReporter

    class Quiet:
        def status(self, text):
            self.last = text

    out = io.StringIO()
    n = iter(range(100))
    rep = StatusReporter(1.0, 1.0, lambda: {"steps": 1.0}, lambda: f"line {next(n)}", Quiet(), out, 60.0)
    for _ in range(5):
        rep.report()
    assert out.getvalue() == "line 0\n"            # the first at once, the next a minute later
    every = io.StringIO()
    rep = StatusReporter(1.0, 1.0, lambda: {}, lambda: "x", Quiet(), every)
    for _ in range(3):
        rep.report()
    assert every.getvalue() == "x\nx\nx\n"
