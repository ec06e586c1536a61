"""Start-up and shutdown of the daemon's parts, in one declared order.

The model is aiohttp's ``AppRunner``/``BaseSite``: the service declares one
list of parts (:meth:`tractionecu.service.daemon.Service.parts`), each with
``async start()`` and ``async stop()``.  :meth:`Lifecycle.start` starts them
in that order; a part whose start raises ends start-up there (the error
propagates, the part itself is not stopped).  :meth:`Lifecycle.stop` stops
every part that was started, in reverse order, each one even when a stop
before it raised, and returns the errors as ``"<name>: <error>"``.

Kinds of part:

* :class:`Hook`: one or two plain callables (write the state directory,
  build the estimator, warm it up);
* :class:`TaskPart`: one asyncio task that runs as long as the service (the
  estimation loop, the status line); stopping cancels it;
* :class:`DeviceTask`: a device reader's supervisor task
  (:class:`~.canlink.CanLink`, :class:`~.gps.GpsReader`); stopping closes the
  device, then waits up to :data:`DEVICE_STOP_TIMEOUT_S` for its task.

The tasks of started :class:`TaskPart` parts are listed by
:meth:`Lifecycle.tasks`: such a task that ends by itself is a fault, and the
service stops (and systemd restarts it).
"""

from __future__ import annotations

import asyncio
import inspect
import logging
from typing import Any, Awaitable, Callable, Iterable, Protocol

from ..aio import cancel_and_wait

log = logging.getLogger(__name__)

DEVICE_STOP_TIMEOUT_S = 5.0
"""How long a device reader may take to end after its device was closed [s]."""


class Part(Protocol):
    """What the lifecycle starts and stops."""

    name: str

    async def start(self) -> None: ...

    async def stop(self) -> None: ...


async def _call(fn: Callable[[], Any] | None) -> None:
    if fn is None:
        return
    res = fn()
    if inspect.isawaitable(res):
        await res


class Hook:
    """A part made of callables: ``start`` and ``stop`` (either may be None; either may be async)."""

    def __init__(self, name: str, start: Callable[[], Any] | None = None,
                 stop: Callable[[], Any] | None = None) -> None:
        self.name = name
        self._start = start
        self._stop = stop

    async def start(self) -> None:
        await _call(self._start)

    async def stop(self) -> None:
        await _call(self._stop)

    def __repr__(self) -> str:
        return f"Hook({self.name!r})"


class TaskPart:
    """A part whose work is one asyncio task running :meth:`run` until the part is stopped."""

    name = "task"

    def __init__(self) -> None:
        self.task: asyncio.Task[Any] | None = None

    async def run(self) -> None:
        raise NotImplementedError

    async def start(self) -> None:
        self.task = asyncio.create_task(self.run(), name=self.name)

    async def stop(self) -> None:
        """Cancel the task (one that already ended was reported when it ended)."""
        await cancel_and_wait(self.task)


class Device(Protocol):
    """A supervised device reader: ``run()`` reads and reopens until ``close()``."""

    def run(self) -> Awaitable[None]: ...

    def close(self) -> Awaitable[None]: ...


class DeviceTask(TaskPart):
    """The supervisor task of a device reader (module doc)."""

    def __init__(self, name: str, device: Device, stop_timeout_s: float = DEVICE_STOP_TIMEOUT_S) -> None:
        super().__init__()
        self.name = name
        self.device = device
        self.stop_timeout_s = stop_timeout_s

    async def run(self) -> None:
        await self.device.run()

    async def stop(self) -> None:
        await self.device.close()
        t = self.task
        if t is None or t.done():
            return
        await asyncio.wait({t}, timeout=self.stop_timeout_s)
        if not t.done():
            await cancel_and_wait(t)
            raise TimeoutError(f"did not stop within {self.stop_timeout_s:g} s")
        if not t.cancelled():
            t.exception()


class Lifecycle:
    """Start parts in order, stop the started ones in reverse (module doc).

    Attributes
    ----------
    parts:
        The declared parts, in start-up order.
    started:
        The parts started so far, in start-up order.
    """

    def __init__(self, parts: Iterable[Part]) -> None:
        self.parts: list[Part] = list(parts)
        names = [p.name for p in self.parts]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"parts named twice: {dup}")
        self.started: list[Part] = []

    def names(self) -> list[str]:
        """The names of the declared parts, in start-up order."""
        return [p.name for p in self.parts]

    def __getitem__(self, name: str) -> Part:
        for p in self.parts:
            if p.name == name:
                return p
        raise KeyError(name)

    async def start(self, stop: asyncio.Event | None = None) -> None:
        """Start every part in order; the first error ends start-up (call :meth:`stop` after it).  Once
        ``stop`` is set (a SIGTERM while a part was starting) no further part is started."""
        for p in self.parts:
            if p in self.started:
                continue
            if stop is not None and stop.is_set():
                log.info("stop asked during start-up: %s and the parts after it not started", p.name)
                return
            log.debug("starting %s", p.name)
            await p.start()
            self.started.append(p)

    async def stop(self) -> list[str]:
        """Stop the started parts in reverse order; returns ``"<name>: <error>"`` for each stop that failed."""
        errors: list[str] = []
        while self.started:
            p = self.started.pop()
            log.debug("stopping %s", p.name)
            try:
                await p.stop()
            except Exception as e:
                errors.append(f"{p.name}: {e!r}")
        return errors

    def tasks(self) -> list[tuple[str, asyncio.Task[Any]]]:
        """``(name, task)`` of each started :class:`TaskPart` (tasks that must not end by themselves)."""
        return [(p.name, p.task) for p in self.started if isinstance(p, TaskPart) and p.task is not None]
