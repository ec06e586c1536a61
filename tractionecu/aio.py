"""Two asyncio waits that a cancellation always ends, on every supported Python.

``asyncio.wait_for(event.wait(), timeout)`` swallows a cancellation on Python
3.10 and 3.11 when the inner wait completes in the same pass of the loop as the
cancel (CPython gh-86296, fixed in 3.12): the task goes on as if nothing had
happened.  A part of the service that waits for a trigger the estimation loop
sets ten times a second hit it at shutdown, and the stop that awaited the
cancelled task waited for ever (the daemon then ignored SIGTERM until systemd
killed it).  :func:`wait_event` waits through :func:`asyncio.wait`, which never
swallows the caller's cancellation; :func:`cancel_and_wait` cancels a task until
it has ended, within a time limit.
"""

from __future__ import annotations

import asyncio
from typing import Any

STOP_TIMEOUT_S = 5.0
"""How long :func:`cancel_and_wait` waits for a cancelled task to end [s]."""


async def wait_event(event: asyncio.Event, timeout: float | None) -> bool:
    """Wait until ``event`` is set or ``timeout`` [s] passed; True if it was set.  A cancellation of the
    caller always propagates."""
    if event.is_set():
        return True
    waiter = asyncio.ensure_future(event.wait())
    try:
        await asyncio.wait({waiter}, timeout=timeout)
    finally:
        if not waiter.done():
            waiter.cancel()
    return event.is_set()


async def cancel_and_wait(task: asyncio.Task[Any] | None, timeout_s: float = STOP_TIMEOUT_S) -> None:
    """Cancel ``task`` and wait until it has ended, cancelling it again while it runs on (a cancellation
    it swallowed); :class:`TimeoutError` after ``timeout_s`` [s].  A task that ended with an error has it
    retrieved (it was reported where the task's end is watched)."""
    if task is None:
        return
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout_s
    while not task.done():
        left = deadline - loop.time()
        if left <= 0:
            raise TimeoutError(f"task {task.get_name()} did not end within {timeout_s:g} s of its cancellation")
        task.cancel()
        await asyncio.wait({task}, timeout=min(left, 0.2))
    if not task.cancelled():
        task.exception()
