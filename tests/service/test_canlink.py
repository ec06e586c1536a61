"""The supervised CAN link: python-can virtual bus, reopen with backoff, fd reader, bounded queue."""

from __future__ import annotations

import asyncio
import os
import queue
import uuid

import can
import pytest

from tractionecu.service.canlink import CanLink
from tractionecu.service.clock import ServiceClock
from tractionecu.service.config import CanConfig

FAST = {"reopen_min_s": 0.01, "reopen_max_s": 0.05}


async def _until(pred, timeout: float = 10.0) -> None:
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while not pred():
        assert loop.time() < end, "condition not reached in time"
        await asyncio.sleep(0.005)


def _channel() -> str:
    return f"test-{uuid.uuid4().hex[:8]}"


async def test_virtual_bus_receive_and_send() -> None:
    ch = _channel()
    got: list[tuple[float, can.Message]] = []
    link = CanLink(CanConfig(interface="virtual", channel=ch, **FAST), lambda t, m: got.append((t, m)), ServiceClock())
    task = asyncio.create_task(link.run())
    peer = can.Bus(interface="virtual", channel=ch)
    try:
        await asyncio.wait_for(link.is_open.wait(), 5)
        for i in range(20):
            peer.send(can.Message(arbitration_id=0x18FF1080, data=bytes([i] * 8)))
        await _until(lambda: len(got) == 20)
        assert [m.data[0] for _, m in got] == list(range(20))
        assert link.send(0x18FF2090, b"\x01\x02")
        echo = peer.recv(timeout=2)
        assert echo is not None and echo.arbitration_id == 0x18FF2090 and echo.is_extended_id
        assert link.stats["rx_frames"] == 20 and link.stats["tx_frames"] == 1
    finally:
        peer.shutdown()
        await link.close()
        await asyncio.wait_for(task, 5)
    assert not link.send(0x18FF2090, b"")
    assert link.stats["tx_not_open"] == 1


class FlakyFactory:
    """Fails to open N times, then opens a virtual bus whose recv fails once after K frames."""

    def __init__(self, fail_opens: int, fail_after: int | None = None) -> None:
        self.fail_opens = fail_opens
        self.fail_after = fail_after
        self.calls = 0

    def __call__(self, **kw) -> can.BusABC:
        self.calls += 1
        if self.calls <= self.fail_opens:
            raise can.CanInterfaceNotImplementedError("No such device")  # what a missing can0 looks like
        bus = can.Bus(interface="virtual", channel=kw["channel"])
        if self.fail_after is not None and self.calls == self.fail_opens + 1:
            real_recv = bus.recv
            seen = [0]

            def recv(timeout=None):
                msg = real_recv(timeout)
                if msg is not None:
                    seen[0] += 1
                    if seen[0] > self.fail_after:
                        raise can.CanOperationError("Error receiving: No such device or address", 6)
                return msg

            bus.recv = recv  # type: ignore[method-assign]
        return bus


async def test_reopens_until_the_interface_appears_and_after_it_fails() -> None:
    ch = _channel()
    factory = FlakyFactory(fail_opens=3, fail_after=5)
    got: list[can.Message] = []
    opened = []
    link = CanLink(CanConfig(interface="virtual", channel=ch, **FAST), lambda t, m: got.append(m), ServiceClock(),
                   bus_factory=factory, on_open=lambda: opened.append(1))
    task = asyncio.create_task(link.run())
    peer = can.Bus(interface="virtual", channel=ch)
    try:
        await asyncio.wait_for(link.is_open.wait(), 5)
        assert link.stats["open_failures"] == 3
        for i in range(6):
            peer.send(can.Message(arbitration_id=0x100 + i, is_extended_id=False))
        await _until(lambda: link.stats["link_failures"] == 1)
        await _until(lambda: link.stats["opens"] == 2)
        peer.send(can.Message(arbitration_id=0x1FF, is_extended_id=False))
        await _until(lambda: any(m.arbitration_id == 0x1FF for m in got))
        assert len(opened) == 2
        assert "No such device" in link.last_error
    finally:
        peer.shutdown()
        await link.close()
        await asyncio.wait_for(task, 5)


class PipeBus(can.BusABC):
    """A bus with a file descriptor (like socketcan): readable when frames are queued."""

    def __init__(self, channel: str = "pipe", **kw) -> None:
        self.r, self.w = os.pipe()
        os.set_blocking(self.r, False)
        self.q: queue.SimpleQueue[can.Message | Exception] = queue.SimpleQueue()
        super().__init__(channel=channel)

    def put(self, item: can.Message | Exception) -> None:
        self.q.put(item)
        os.write(self.w, b"x")

    def fileno(self) -> int:
        return self.r

    def _recv_internal(self, timeout):
        try:
            item = self.q.get_nowait()
        except queue.Empty:
            return None, False
        os.read(self.r, 1)
        if isinstance(item, Exception):
            raise item
        return item, False

    def send(self, msg, timeout=None) -> None:
        raise can.CanOperationError("Transmit buffer full")

    def shutdown(self) -> None:
        super().shutdown()
        for fd in (self.r, self.w):
            try:
                os.close(fd)
            except OSError:
                pass


async def test_fd_reader_path_stamps_and_recovers() -> None:
    buses: list[PipeBus] = []

    def factory(**kw):
        buses.append(PipeBus())
        return buses[-1]

    got: list[tuple[float, can.Message]] = []
    clock = ServiceClock()
    cfg = CanConfig(interface="socketcan", channel="pipe0", **FAST)   # "auto" -> driver time stamps
    link = CanLink(cfg, lambda t, m: got.append((t, m)), clock, bus_factory=factory)
    task = asyncio.create_task(link.run())
    try:
        await asyncio.wait_for(link.is_open.wait(), 5)
        stamp = clock.now() - 0.2
        buses[0].put(can.Message(timestamp=stamp, arbitration_id=1))
        buses[0].put(can.Message(timestamp=stamp + 3600.0, arbitration_id=2))   # a clock far off: fall back
        await _until(lambda: len(got) == 2)
        assert got[0][0] == stamp
        assert abs(got[1][0] - clock.now()) < 1.0 and link.stats["stamp_fallback"] == 1
        assert not link.send(0x18FF2090, b"")
        assert link.stats["tx_errors"] == 1
        buses[0].put(can.CanOperationError("Error receiving: Network is down", 100))
        await _until(lambda: link.stats["opens"] == 2)
        buses[1].put(can.Message(timestamp=clock.now(), arbitration_id=3))
        await _until(lambda: len(got) == 3)
    finally:
        await link.close()
        await asyncio.wait_for(task, 5)


async def test_bounded_queue_and_handler_errors_do_not_stop_the_reader() -> None:
    ch = _channel()
    calls = []

    def handler(t, m):
        calls.append(m)
        if m.arbitration_id == 0x666:
            raise ValueError("boom")

    cfg = CanConfig(interface="virtual", channel=ch, rx_queue_frames=16, **FAST)
    link = CanLink(cfg, handler, ServiceClock())
    task = asyncio.create_task(link.run())
    peer = can.Bus(interface="virtual", channel=ch)
    try:
        await asyncio.wait_for(link.is_open.wait(), 5)
        peer.send(can.Message(arbitration_id=0x666, is_extended_id=False))
        peer.send(can.Message(arbitration_id=0x001, is_extended_id=False))
        await _until(lambda: len(calls) == 2)
        assert link.stats["handler_errors"] == 1
        # block the event loop while 200 frames arrive: the queue keeps 16, drops and counts the rest
        import time
        for i in range(200):
            peer.send(can.Message(arbitration_id=0x100, is_extended_id=False))
        time.sleep(0.5)
        await _until(lambda: link.stats["rx_frames"] + link.stats["rx_overflow"] == 202)
        assert link.stats["rx_overflow"] > 0
        assert len(link._queue) == 0
    finally:
        peer.shutdown()
        await link.close()
        await asyncio.wait_for(task, 5)


@pytest.mark.parametrize("silence", [0.2])
async def test_silence_reopen(silence: float) -> None:
    cfg = CanConfig(interface="virtual", channel=_channel(), silence_reopen_s=silence, **FAST)
    link = CanLink(cfg, lambda t, m: None, ServiceClock())
    task = asyncio.create_task(link.run())
    try:
        await _until(lambda: link.stats["opens"] >= 2)
        assert link.stats["silence_reopens"] >= 1
    finally:
        await link.close()
        await asyncio.wait_for(task, 5)


async def test_a_close_during_the_reopen_backoff_ends_the_link_at_once() -> None:
    """An interface that is there but cannot be opened, retried every 30 s: the backoff slept on after
    close() and the device task overran its stop limit."""
    def factory(**kw):
        raise can.CanError("adapter busy")

    link = CanLink(CanConfig(interface="virtual", channel="busy0", reopen_min_s=30.0, reopen_max_s=60.0),
                   lambda t, m: None, ServiceClock(), bus_factory=factory)
    task = asyncio.create_task(link.run())
    loop = asyncio.get_running_loop()
    end = loop.time() + 5.0
    while link.stats["open_failures"] < 1:
        assert loop.time() < end
        await asyncio.sleep(0.01)
    t0 = loop.time()
    await link.close()
    await asyncio.wait_for(task, 2.0)
    assert loop.time() - t0 < 1.0
