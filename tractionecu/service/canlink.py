"""The CAN link: python-can bus by interface name, own supervised receive loop.

python-can's ``Notifier`` can stop delivering silently when a driver raises
inside its thread or reader callback under asyncio (python-can #907, #1667,
#1912), so the service runs its own loop and supervises it:

* :meth:`CanLink.run` opens ``can.Bus(interface=..., channel=..., **options)``
  (off the event loop), attaches a reader and waits for it to fail; then it
  closes the bus and reopens it with a doubling backoff
  (``can.reopen_min_s`` .. ``can.reopen_max_s``) until it succeeds again;
  while a socketcan interface is missing from sysfs, its reappearance ends
  the wait at once.
  A vanished interface (``ip link del can0``, USB adapter unplugged) or one
  taken down thus costs only the frames sent while it was gone.
* Reader: if the bus has a file descriptor (socketcan), the event loop reads
  it directly (``loop.add_reader``) and drains at most
  :data:`MAX_BATCH` frames per wake-up.  Otherwise (``virtual``, vendor
  drivers) a thread blocks in ``bus.recv`` and hands frames to the loop
  through a bounded queue (``can.rx_queue_frames``; overflow is counted).
* Each frame goes to ``on_frame(t, msg)`` on the event-loop thread, ``t`` in
  service time: the driver's receive time (socketcan kernel time stamp, the
  clock candump writes) when ``can.timestamps`` says so, else the time it
  was read.  A driver stamp further than :data:`STAMP_TOLERANCE_S` from the
  service clock is replaced by the read time and counted.
* Nothing here raises into the caller: errors are counted in :attr:`stats`
  and logged (the first of a kind at WARNING, repeats at DEBUG).
"""

from __future__ import annotations

import asyncio
import collections
import logging
import os
import socket
import struct
import threading
from collections import Counter
from typing import Any, Callable

import can

from ..aio import wait_event
from ..counting import WarnOnce
from .clock import ServiceClock
from .config import CanConfig

log = logging.getLogger(__name__)

MAX_BATCH = 512
"""Frames read per event-loop wake-up before yielding to other callbacks."""
STAMP_TOLERANCE_S = 1.0
"""Largest accepted difference between a driver time stamp and the service clock [wall s]."""
THREAD_POLL_S = 0.1
"""Receive timeout of the reader thread, so it notices a close [s]."""
LINK_POLL_S = 0.1
"""While a socketcan interface is missing, how often sysfs is checked for it to come back [s]."""
LINK_SETTLE_S = 0.05
"""Pause between the interface appearing and the open attempt (``ip link set up`` follows ``add``) [s]."""

FrameHandler = Callable[[float, can.Message], None]

_CAN_HEADER = struct.Struct("=IB3x")          # struct can_frame / canfd_frame: can_id, len, pad
_TIMESPEC = struct.Struct("@ll")
_U32 = struct.Struct("=I")
_ANCILLARY = socket.CMSG_SPACE(_TIMESPEC.size) + socket.CMSG_SPACE(_U32.size)
_CANFD_MTU = 72
_EFF, _RTR, _ERR = 0x80000000, 0x40000000, 0x20000000
_SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)
try:
    from can.interfaces.socketcan.constants import SO_TIMESTAMPNS as _SO_TIMESTAMPNS
except ImportError:  # pragma: no cover - python-can layout changed
    _SO_TIMESTAMPNS = 35


class SocketcanReader:
    """Reads frames from the raw socket of a python-can ``socketcan`` bus, without waiting.

    * one ``recvmsg`` per frame on the non-blocking socket;
    * the frame time is the kernel's receive time (``SO_TIMESTAMPNS``, enabled
      by python-can) truncated to microseconds, the value ``candump -L``
      prints, so a capture replayed offline has the daemon's exact times;
    * ``SO_RCVBUF`` is raised to ``rx_buffer_bytes`` (the kernel caps it at
      ``net.core.rmem_max``) so a process that is not scheduled for a while
      loses nothing, and ``SO_RXQ_OVFL`` makes the kernel report frames it
      dropped anyway: :attr:`dropped` (cumulative).
    """

    def __init__(self, sock: socket.socket, channel: str, rx_buffer_bytes: int) -> None:
        self.sock = sock
        self.channel = channel
        self.dropped = 0
        sock.setblocking(False)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rx_buffer_bytes)
        except OSError as e:
            log.warning("CAN %s: cannot set SO_RCVBUF to %d: %s", channel, rx_buffer_bytes, e)
        try:
            sock.setsockopt(socket.SOL_SOCKET, _SO_RXQ_OVFL, 1)
        except OSError as e:
            log.debug("CAN %s: no SO_RXQ_OVFL: %s", channel, e)
        self.rcvbuf = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)

    def read(self) -> can.Message | None:
        """One frame, or None if none is waiting.  Raises :class:`can.CanOperationError`
        on a socket error (``ENETDOWN``, ``ENODEV`` when the interface goes away)."""
        try:
            cf, anc, _flags, _addr = self.sock.recvmsg(_CANFD_MTU, _ANCILLARY)
        except (BlockingIOError, InterruptedError):
            return None
        except OSError as e:
            raise can.CanOperationError(f"Error receiving: {e.strerror}", e.errno) from e
        can_id, length = _CAN_HEADER.unpack_from(cf)
        ts = 0.0
        for level, kind, data in anc:
            if level != socket.SOL_SOCKET:
                continue
            if kind == _SO_TIMESTAMPNS:
                sec, nsec = _TIMESPEC.unpack_from(data)
                ts = float(f"{sec}.{nsec // 1000:06d}")
            elif kind == _SO_RXQ_OVFL and len(data) >= 4:
                self.dropped = _U32.unpack_from(data)[0]
        ext = bool(can_id & _EFF)
        return can.Message(
            timestamp=ts,
            arbitration_id=can_id & (0x1FFFFFFF if ext else 0x7FF),
            is_extended_id=ext,
            is_remote_frame=bool(can_id & _RTR),
            is_error_frame=bool(can_id & _ERR),
            is_fd=len(cf) == _CANFD_MTU,
            dlc=length,
            data=cf[8:8 + length],
            channel=self.channel,
            check=False,
        )


class CanLink:
    """A supervised python-can bus.

    Parameters
    ----------
    cfg:
        The ``[can]`` table.
    on_frame:
        Called on the event-loop thread with ``(t, msg)`` for each received
        frame; exceptions it raises are counted (``handler_errors``) and
        logged, never propagated.
    clock:
        Service clock for time stamps.
    bus_factory:
        Builds the bus (default ``can.Bus``); tests pass a fake.
    extra_bus_kwargs:
        Added to the ``can.Bus`` call (e.g. ``preserve_timestamps`` for the
        simulator's virtual bus).
    on_open:
        Called on the event-loop thread each time the bus has been (re)opened
        (the daemon claims its address again).

    Attributes
    ----------
    stats:
        ``rx_frames``, ``tx_frames``, ``tx_errors``, ``tx_not_open``,
        ``opens``, ``open_failures``, ``link_failures``, ``rx_overflow``,
        ``rx_kernel_dropped`` (socketcan: frames the kernel dropped, buffer full),
        ``stamp_fallback``, ``handler_errors``, ``silence_reopens``,
        ``filter_updates`` and ``filter_errors`` (:meth:`set_filters`).
    is_open:
        An :class:`asyncio.Event` set while the bus is open.
    """

    def __init__(self, cfg: CanConfig, on_frame: FrameHandler, clock: ServiceClock, *,
                 bus_factory: Callable[..., can.BusABC] | None = None,
                 extra_bus_kwargs: dict[str, Any] | None = None,
                 on_open: Callable[[], None] | None = None) -> None:
        self.cfg = cfg
        self.on_open = on_open
        self.on_frame = on_frame
        self.clock = clock
        self.bus_factory = bus_factory or can.Bus
        self.extra_bus_kwargs = dict(extra_bus_kwargs or {})
        self.stats: Counter[str] = Counter()
        self.bus: can.BusABC | None = None
        self.is_open = asyncio.Event()
        self.last_error: str = ""
        self.last_rx_mono = 0.0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._fd: int | None = None
        self._failed: asyncio.Future[str] | None = None
        self._closing = False
        self._closed = asyncio.Event()     # wakes a backoff at close
        self._thread: threading.Thread | None = None
        self._thread_stop: threading.Event | None = None
        self._queue: collections.deque[tuple[float, can.Message]] = collections.deque()
        self._wake_pending = False
        self._use_kernel_stamps = cfg.kernel_timestamps
        self._warn_once = WarnOnce(log)
        self._read_one: Callable[[], can.Message | None] = lambda: None
        self._sc_reader: SocketcanReader | None = None
        self._dropped_base = 0

    # ------------------------------------------------------------ supervisor
    async def run(self) -> None:
        """Open, read, and reopen after failures until :meth:`close`."""
        self._loop = asyncio.get_running_loop()
        backoff = self.cfg.reopen_min_s
        desc = f"{self.cfg.interface}:{self.cfg.channel}"
        while not self._closing:
            try:
                bus = await self._loop.run_in_executor(None, self._open)
            except asyncio.CancelledError:
                raise
            except Exception as e:  # python-can raises CanError, OSError, ValueError, ImportError ...
                self.stats["open_failures"] += 1
                self.last_error = f"open: {e}"
                self._warn_once("open", "CAN %s: cannot open (%s); retrying every ≤ %.1f s",
                                desc, e, self.cfg.reopen_max_s)
                await self._backoff(backoff)
                backoff = min(2 * backoff, self.cfg.reopen_max_s)
                continue
            if self._closing:
                bus.shutdown()
                break
            backoff = self.cfg.reopen_min_s
            self.stats["opens"] += 1
            if self.stats["opens"] > 1:
                log.warning("CAN %s: open again", desc)
            else:
                log.info("CAN %s: open", desc)
            self._warn_once.forget("open")
            reason = await self._serve(bus)
            if self._closing:
                break
            self.stats["link_failures"] += 1
            self.last_error = reason
            self._warn_once("link", "CAN %s: lost (%s); reopening", desc, reason)
            await self._backoff(backoff)
            backoff = min(2 * backoff, self.cfg.reopen_max_s)

    def _link_present(self) -> bool | None:
        """socketcan: whether the network interface exists (from sysfs); None for other interfaces."""
        if self.cfg.interface != "socketcan":
            return None
        return os.path.exists(f"/sys/class/net/{self.cfg.channel}")

    async def _backoff(self, seconds: float) -> None:
        """Wait before the next open attempt; for socketcan, stop waiting as soon as a missing
        interface appears (``ip link add``, adapter plugged in), so recovery does not wait for the
        backoff to run out."""
        present = self._link_present()
        if present is None or present:
            await wait_event(self._closed, seconds)
            return
        loop = asyncio.get_running_loop()
        end = loop.time() + seconds
        while (left := end - loop.time()) > 0 and not self._closing:
            await wait_event(self._closed, min(LINK_POLL_S, left))
            if self._link_present():
                self.stats["link_appeared"] += 1
                await asyncio.sleep(LINK_SETTLE_S)
                return

    def _open(self) -> can.BusABC:
        return self.bus_factory(interface=self.cfg.interface, channel=self.cfg.channel,
                                **self.cfg.options, **self.extra_bus_kwargs)

    async def _serve(self, bus: can.BusABC) -> str:
        """Read ``bus`` until it fails; returns the reason.  Closes the bus."""
        loop = self._loop
        assert loop is not None
        self._failed = loop.create_future()
        self.bus = bus
        self.last_rx_mono = loop.time()
        try:
            fd = bus.fileno()
        except (NotImplementedError, AttributeError, OSError):
            fd = -1
        if isinstance(fd, int) and fd >= 0:
            self._fd = fd
            self._read_one = self._raw_reader(bus)
            loop.add_reader(fd, self._on_readable)
        else:
            self._start_thread(bus)
        self.is_open.set()
        if self.on_open is not None:
            try:
                self.on_open()
            except Exception as e:
                self.stats["handler_errors"] += 1
                log.warning("CAN open handler failed: %r", e)
        try:
            while True:
                silence = self.cfg.silence_reopen_s
                timeout = None if silence <= 0 else self.clock.wall(silence) / 4
                done, _ = await asyncio.wait({self._failed}, timeout=timeout)
                if done:
                    return self._failed.result()
                if loop.time() - self.last_rx_mono > self.clock.wall(silence):
                    self.stats["silence_reopens"] += 1
                    return f"no frame for {silence:g} s"
        finally:
            self.is_open.clear()
            self._detach()
            self.bus = None
            try:
                await loop.run_in_executor(None, bus.shutdown)
            except Exception as e:  # a vanished device may fail to close
                log.debug("CAN shutdown: %s", e)

    def _fail(self, reason: str) -> None:
        if self._failed is not None and not self._failed.done():
            self._failed.set_result(reason)

    def _detach(self) -> None:
        if self._fd is not None and self._loop is not None:
            self._loop.remove_reader(self._fd)
            self._fd = None
        if self._thread_stop is not None:
            self._thread_stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2 * THREAD_POLL_S + 1.0)
            self._thread = None
            self._thread_stop = None
        self.drain()

    async def close(self) -> None:
        """Stop reading and close the bus (also ends a wait before the next open)."""
        self._closing = True
        self._closed.set()
        self._fail("closed")

    # ------------------------------------------------------------ receive
    def _stamp(self, msg: can.Message, t_read: float) -> float:
        if self._use_kernel_stamps and msg.timestamp:
            ts = float(msg.timestamp)
            if abs(ts - t_read) <= STAMP_TOLERANCE_S * self.clock.speed:
                return ts
            self.stats["stamp_fallback"] += 1
            self._warn_once("stamp", "CAN frame time stamp %.3f is %.3f s off the service clock; using "
                            "the read time", ts, ts - t_read)
        return t_read

    def _deliver(self, t: float, msg: can.Message) -> None:
        self.stats["rx_frames"] += 1
        try:
            self.on_frame(t, msg)
        except Exception as e:  # never let one bad frame stop the reader
            self.stats["handler_errors"] += 1
            self._warn_once("handler", "CAN frame handler failed on %s: %r", msg, e)

    def _raw_reader(self, bus: can.BusABC) -> Callable[[], can.Message | None]:
        """A function reading one frame or None without waiting.

        socketcan: :class:`SocketcanReader` on the bus's socket (one ``recvmsg``
        per frame where ``bus.recv(timeout=0)`` adds a ``select``; candump's
        microsecond times; kernel drop counter).  Other interfaces:
        ``bus.recv(timeout=0)``.
        """
        sock = getattr(bus, "socket", None)
        # python-can filters in software when the kernel refused the filters: keep its recv() then
        kernel_filtered = bool(getattr(bus, "_is_filtered", False)) or not getattr(bus, "filters", None)
        if self.cfg.interface == "socketcan" and isinstance(sock, socket.socket) and kernel_filtered:
            reader = SocketcanReader(sock, self.cfg.channel, self.cfg.rx_buffer_bytes)
            self._sc_reader = reader
            self._dropped_base = self.stats["rx_kernel_dropped"]
            log.info("CAN %s: receive buffer %d bytes", self.cfg.channel, reader.rcvbuf)
            return reader.read
        self._sc_reader = None
        return lambda: bus.recv(timeout=0)

    def _on_readable(self) -> None:
        bus = self.bus
        if bus is None:
            return
        read = self._read_one
        for _ in range(MAX_BATCH):
            try:
                msg = read()
            except Exception as e:  # CanOperationError on ENETDOWN / ENODEV ...
                if self._fd is not None and self._loop is not None:
                    self._loop.remove_reader(self._fd)
                    self._fd = None
                self._fail(f"receive: {e}")
                return
            if msg is None:
                break
            t = self.clock.now()
            self.last_rx_mono = self._loop.time() if self._loop else 0.0
            self._deliver(self._stamp(msg, t), msg)
        sc = self._sc_reader
        if sc is not None and self._dropped_base + sc.dropped > self.stats["rx_kernel_dropped"]:
            new = self._dropped_base + sc.dropped - self.stats["rx_kernel_dropped"]
            self.stats["rx_kernel_dropped"] += new
            self._warn_once("dropped", "CAN %s: the kernel dropped %d frame(s): receive buffer full (%d bytes; "
                            "raise can.rx_buffer_bytes and net.core.rmem_max)", self.cfg.channel, new, sc.rcvbuf)

    def _start_thread(self, bus: can.BusABC) -> None:
        stop = threading.Event()
        self._thread_stop = stop
        loop = self._loop
        q = self._queue
        maxlen = self.cfg.rx_queue_frames

        def reader() -> None:
            while not stop.is_set():
                try:
                    msg = bus.recv(timeout=THREAD_POLL_S)
                except Exception as e:
                    if not stop.is_set():
                        loop.call_soon_threadsafe(self._fail, f"receive: {e}")  # type: ignore[union-attr]
                    return
                if msg is None:
                    continue
                if len(q) >= maxlen:
                    self.stats["rx_overflow"] += 1
                    continue
                q.append((self.clock.now(), msg))
                if not self._wake_pending:
                    self._wake_pending = True
                    try:
                        loop.call_soon_threadsafe(self.drain)  # type: ignore[union-attr]
                    except RuntimeError:  # loop closed
                        return

        self._thread = threading.Thread(target=reader, name=f"can-rx-{self.cfg.channel}", daemon=True)
        self._thread.start()

    def drain(self) -> int:
        """Process every frame already received (call before an estimator step).  Returns the count.

        With a file descriptor this reads the device (system calls); see :meth:`drain_queued`.
        """
        if self._fd is not None:
            before = self.stats["rx_frames"]
            self._on_readable()
            return self.stats["rx_frames"] - before
        return self.drain_queued()

    def drain_queued(self) -> int:
        """Process the frames a reader thread has queued (no system call; 0 on the fd path)."""
        self._wake_pending = False
        q = self._queue
        n = 0
        while q:
            t, msg = q.popleft()
            n += 1
            if self._loop is not None:
                self.last_rx_mono = self._loop.time()
            self._deliver(self._stamp(msg, t), msg)
        return n

    # ------------------------------------------------------------ filters
    def set_filters(self, filters: list[dict[str, Any]] | None) -> None:
        """Replace the receive filters: on the open bus now (python-can ``set_filters``; socketcan
        sets them in the kernel) and at every later open.  Counted as ``filter_updates``; a bus
        that refuses them keeps its old ones (``filter_errors``, logged once)."""
        self.extra_bus_kwargs["can_filters"] = filters
        bus = self.bus
        if bus is None:
            return
        try:
            bus.set_filters(filters)
        except Exception as e:  # a driver without filter support
            self.stats["filter_errors"] += 1
            self._warn_once("filters", "CAN %s: cannot set receive filters: %r", self.cfg.channel, e)
            return
        self.stats["filter_updates"] += 1

    # ------------------------------------------------------------ transmit
    def send(self, can_id: int, data: bytes) -> bool:
        """Send one 29-bit frame without blocking; False (and counted) if it cannot go out."""
        bus = self.bus
        if bus is None:
            self.stats["tx_not_open"] += 1
            return False
        msg = can.Message(arbitration_id=can_id, is_extended_id=True, data=data)
        try:
            bus.send(msg, timeout=0)
        except Exception as e:  # CanOperationError: buffer full, ENETDOWN, ENODEV ...
            self.stats["tx_errors"] += 1
            self.last_error = f"send: {e}"
            self._warn_once("send", "CAN send failed: %s", e)
            return False
        self.stats["tx_frames"] += 1
        return True
