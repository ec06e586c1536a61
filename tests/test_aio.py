"""Waits that a cancellation always ends (``tractionecu.aio``).

Regression: ``asyncio.wait_for(trigger.wait(), timeout)`` on Python 3.10/3.11 swallowed the cancellation
of the in-cab page's task when the estimation loop set the trigger in the same pass of the loop as the
service's stop cancelled it; ``WebPart.stop`` then waited for ever and the daemon ignored SIGTERM.
"""

from __future__ import annotations

import asyncio

import pytest

from tractionecu.aio import cancel_and_wait, wait_event


async def _waiter(ev: asyncio.Event, hits: list[int]) -> None:
    while True:
        if await wait_event(ev, 1.0):
            ev.clear()
            hits.append(1)


async def test_a_cancel_in_the_same_pass_as_the_trigger_ends_the_task():
    ev = asyncio.Event()
    hits: list[int] = []
    task = asyncio.create_task(_waiter(ev, hits))
    await asyncio.sleep(0.01)
    ev.set()                       # the trigger and the cancel in one pass of the loop
    task.cancel()
    await asyncio.wait({task}, timeout=2.0)
    assert task.done() and task.cancelled()


async def test_wait_event_times_out_and_returns_at_once_when_set():
    ev = asyncio.Event()
    assert await wait_event(ev, 0.01) is False
    ev.set()
    assert await wait_event(ev, 10.0) is True


async def test_cancel_and_wait_cancels_a_task_that_swallows_the_first_cancel():
    swallowed = []

    async def stubborn() -> None:
        try:
            await asyncio.sleep(10)
        except asyncio.CancelledError:
            swallowed.append(1)    # as wait_for did: go on as if nothing happened
        await asyncio.sleep(10)

    task = asyncio.create_task(stubborn())
    await asyncio.sleep(0.01)
    await cancel_and_wait(task, timeout_s=2.0)
    assert task.cancelled() and swallowed == [1]


async def test_cancel_and_wait_gives_up_after_its_time_limit():
    deaf = [True]

    async def ignores_cancels() -> None:
        while True:
            try:
                await asyncio.sleep(10)
            except asyncio.CancelledError:
                if not deaf[0]:
                    raise

    task = asyncio.create_task(ignores_cancels())
    await asyncio.sleep(0.01)
    with pytest.raises(TimeoutError, match="did not end within"):
        await cancel_and_wait(task, timeout_s=0.3)
    assert not task.done()
    deaf[0] = False                # let the test's loop close
    await cancel_and_wait(task, timeout_s=2.0)


async def test_the_page_stops_when_a_broadcast_step_coincides_with_the_stop():
    from tractionecu.service.config import WebConfig
    from tractionecu.web.server import WebPart

    trig = asyncio.Event()
    web = WebPart(WebConfig(port=0), snapshot=lambda: {"t": 0.0}, trigger=trig)
    await web.start()
    await asyncio.sleep(0.2)
    trig.set()
    await asyncio.wait_for(asyncio.shield(web.stop()), timeout=5.0)
    assert web.task is None and web.runner is None
