"""The read-only in-cab page: aiohttp on the daemon's event loop, updates pushed over a WebSocket.

Routes (GET and HEAD only; nothing writes, nothing names a file):

===============  ==========================================================
``/``            the page (``static/index.html``)
``/static/X``    one of the page's assets, looked up by name in the table
                 loaded from this package at start-up (:data:`ASSETS`);
                 any other name is 404, whatever it contains
``/state.json``  the last update as JSON
``/ws``          the WebSocket: the full state once (built with the next
                 update), then one update every ``1 / web.update_hz``
                 seconds; what a viewer sends is ignored
===============  ==========================================================

Work off the estimation path.  The page's work runs in the daemon's event
loop, between the estimation loop's steps, never inside one, and right
after a broadcast step (``trigger``), a whole broadcast period before the
next broadcast: the pusher
builds one update (the service's :meth:`snapshot` callable, the map's new
cells) and serialises it once for every viewer; each viewer has its own
bounded queue (``web.queue_updates``) and sender task, and a viewer whose
queue is full (a slow or stalled viewer) is dropped, never buffered.  A
viewer that connects gets the full state (the whole live map) built by the
pusher with its next update, once for all the viewers that connected since:
built in the connect handler, each reload rebuilt and serialised the whole
map inside the loop (≈ 0.1 s for 30 000 cells), and eight viewers
reconnecting every 2 s held the estimation loop up to 1.6 s.  At
most ``web.max_viewers`` viewers at once.  A port that cannot be bound is
logged and counted (``bind_failed``): the daemon goes on estimating without
its page.  The part is not one of the service's watched tasks: the page
stopping never stops the estimation (its pusher logs and counts its own
errors and goes on).
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections import Counter
from importlib import resources
from typing import Any, Callable

from ..aio import cancel_and_wait, wait_event
from ..jsonsafe import json_safe

from aiohttp import WSMsgType, web

log = logging.getLogger(__name__)

ASSETS = {
    "index.html": "text/html; charset=utf-8",
    "page.js": "text/javascript; charset=utf-8",
    "page.css": "text/css; charset=utf-8",
}
"""The page's assets (``tractionecu/web/static``) and their content types; nothing else is served."""

SECURITY_HEADERS = {
    "Content-Security-Policy": "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
                               "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-store",
}


def load_assets() -> dict[str, tuple[bytes, str]]:
    """Read :data:`ASSETS` from the package (once, at start-up)."""
    root = resources.files("tractionecu.web") / "static"
    return {name: ((root / name).read_bytes(), ctype) for name, ctype in ASSETS.items()}


class _BadRequests(logging.Filter):
    """aiohttp's server logs every malformed request at ERROR with a traceback (50 requests with an oversized
    header wrote 35 KB of log).  Counted in the part's ``stats["bad_requests"]``; the first is logged as one
    line, the others not."""

    def __init__(self, stats: Counter[str]) -> None:
        super().__init__()
        self.stats = stats

    def filter(self, record: logging.LogRecord) -> bool:
        self.stats["bad_requests"] += 1
        if self.stats["bad_requests"] > 1:
            return False
        exc = record.exc_info[1] if record.exc_info else None
        record.msg = "in-cab page: a malformed request refused (%s); later ones are counted (bad_requests), not logged"
        record.args = (repr(exc) if exc is not None else record.getMessage(),)
        record.exc_info = None
        record.exc_text = None
        record.levelno, record.levelname = logging.WARNING, "WARNING"
        return True


class Viewer:
    """One WebSocket viewer: its bounded queue and sender task."""

    def __init__(self, ws: web.WebSocketResponse, maxsize: int) -> None:
        self.ws = ws
        self.queue: asyncio.Queue[str] = asyncio.Queue(maxsize=maxsize)
        self.sender: asyncio.Task[None] | None = None
        self.sent = 0
        self.needs_full = True
        """The viewer has not had the full state yet (the pusher sends it with its next update)."""


class WebPart:
    """The ``web`` part (module doc).

    Parameters
    ----------
    cfg:
        :class:`~tractionecu.service.config.WebConfig`.
    snapshot:
        ``snapshot() -> dict``: the state to show (called ``update_hz`` times a second).
    live_map:
        :class:`~tractionecu.service.advice.LiveMap` (None: no map).
    on_listening:
        Called with the page's address once it listens.
    trigger:
        An event the estimation loop sets after each broadcast step: updates are built right after one
        (None: on a timer).
    """

    name = "web"

    def __init__(self, cfg: Any, snapshot: Callable[[], dict[str, Any]], live_map: Any = None,
                 on_listening: Callable[[str], Any] | None = None, trigger: asyncio.Event | None = None) -> None:
        self.task: asyncio.Task[None] | None = None
        self.on_listening = on_listening
        self.trigger = trigger
        self.cfg = cfg
        self.snapshot = snapshot
        self.map = live_map
        self.viewers: set[Viewer] = set()
        self.stats: Counter[str] = Counter()
        self.runner: web.AppRunner | None = None
        self.address: str | None = None
        self.last_json = "{}"
        self.last_build_s = 0.0
        self.max_build_s = 0.0
        self.build_s_total = 0.0
        self.cpu_s = 0.0
        """CPU time of building the updates and sending them to the viewers [s] (the event loop's thread)."""
        self._assets: dict[str, tuple[bytes, str]] = {}

    # ------------------------------------------------------------ app
    def app(self) -> web.Application:
        app = web.Application(client_max_size=1024)
        app.router.add_get("/", self._index)
        app.router.add_get("/static/{name}", self._static)
        app.router.add_get("/state.json", self._state)
        app.router.add_get("/ws", self._ws)
        return app

    def _headers(self, ctype: str) -> dict[str, str]:
        return {"Content-Type": ctype, **SECURITY_HEADERS}

    async def _index(self, request: web.Request) -> web.Response:
        body, ctype = self._assets["index.html"]
        self.stats["pages"] += 1
        return web.Response(body=body, headers=self._headers(ctype))

    async def _static(self, request: web.Request) -> web.Response:
        item = self._assets.get(request.match_info.get("name", ""))
        if item is None or request.match_info["name"] == "index.html":
            self.stats["not_found"] += 1
            raise web.HTTPNotFound()
        return web.Response(body=item[0], headers=self._headers(item[1]))

    async def _state(self, request: web.Request) -> web.Response:
        return web.Response(text=self.last_json, headers=self._headers("application/json"))

    async def _ws(self, request: web.Request) -> web.StreamResponse:
        if len(self.viewers) >= self.cfg.max_viewers:
            self.stats["viewers_refused"] += 1
            raise web.HTTPServiceUnavailable(text="too many viewers")
        ws = web.WebSocketResponse(heartbeat=10.0, max_msg_size=1024)
        await ws.prepare(request)
        v = Viewer(ws, self.cfg.queue_updates)      # its full state comes with the next update (module doc)
        self.viewers.add(v)
        self.stats["viewers_connected"] += 1
        v.sender = asyncio.create_task(self._send_loop(v), name="web-viewer")
        try:
            async for msg in ws:        # read-only: what a viewer sends is dropped
                if msg.type in (WSMsgType.ERROR, WSMsgType.CLOSE):
                    break
                self.stats["viewer_messages_ignored"] += 1
        finally:
            self._drop(v, "closed")
        return ws

    async def _send_loop(self, v: Viewer) -> None:
        try:
            while True:
                text = await v.queue.get()
                c0 = time.thread_time()
                await v.ws.send_str(text)
                self.cpu_s += time.thread_time() - c0
                v.sent += 1
        except asyncio.CancelledError:
            raise
        except Exception:               # the connection went away: the reader ends it
            self.stats["send_errors"] += 1
            self._drop(v, "send failed")

    def _drop(self, v: Viewer, why: str) -> None:
        if v not in self.viewers:
            return
        self.viewers.discard(v)
        if v.sender is not None and v.sender is not asyncio.current_task():
            v.sender.cancel()
        if not v.ws.closed:
            asyncio.ensure_future(v.ws.close())
        log.debug("web: viewer dropped (%s)", why)

    # ------------------------------------------------------------ updates
    def full_state(self) -> str:
        """The state for a new viewer: the last update with the whole map."""
        state = json.loads(self.last_json) if self.last_json != "{}" else json_safe(self.snapshot())
        if self.map is not None:
            state["map"] = self._map_part(self.map.cells(), full=True)
        state["kind"] = "full"
        return json.dumps(state, allow_nan=False, separators=(",", ":"))

    def _map_part(self, cells: list[Any], full: bool) -> dict[str, Any]:
        m = self.map
        return {"cell_m": m.cell_m, "fields": list(m.FIELDS), "cells": cells, "full": full,
                "track": m.track[-400:] if full else m.track[-20:], "dropped": m.dropped}

    def build(self) -> str:
        """One update as JSON (module doc)."""
        t0 = time.perf_counter()
        c0 = time.thread_time()
        state = json_safe(self.snapshot())
        state["viewers"] = len(self.viewers)
        state["kind"] = "update"
        if self.map is not None:
            state["map"] = self._map_part(self.map.take_changed(), full=False)
        text = json.dumps(state, allow_nan=False, separators=(",", ":"))
        if self.map is not None:        # /state.json and new viewers: the state without the map delta
            state.pop("map")
            self.last_json = json.dumps(state, allow_nan=False, separators=(",", ":"))
        else:
            self.last_json = text
        dt = time.perf_counter() - t0
        self.cpu_s += time.thread_time() - c0
        self.last_build_s = dt
        self.build_s_total += dt
        self.max_build_s = max(self.max_build_s, dt)
        return text

    def push(self, text: str) -> None:
        """Queue one update for every viewer, the full state (built once) for those that have not had it; a
        viewer whose queue is full is dropped."""
        full = None
        for v in list(self.viewers):
            out = text
            if v.needs_full:
                if full is None:
                    try:
                        full = self.full_state()
                        self.stats["full_states"] += 1
                    except Exception as e:  # a snapshot that fails must not leave the viewer half set up
                        self.stats["snapshot_errors"] += 1
                        log.warning("web: the full state for new viewers failed: %r", e)
                        full = ""
                if not full:
                    self._drop(v, "no full state")
                    continue
                out = full
                v.needs_full = False
            try:
                v.queue.put_nowait(out)
            except asyncio.QueueFull:
                self.stats["viewers_dropped_slow"] += 1
                self._drop(v, "too slow")
        self.stats["updates"] += 1

    async def run(self) -> None:
        loop = asyncio.get_running_loop()
        period = 1.0 / self.cfg.update_hz
        nxt = loop.time()
        while True:
            nxt += period
            if self.trigger is not None:
                # wake after a broadcast step of the estimation loop once the period is (nearly) over
                while True:
                    if not await wait_event(self.trigger, period):
                        self.stats["untriggered"] += 1
                        break
                    self.trigger.clear()
                    if loop.time() >= nxt - 0.25 * period:
                        break
            else:
                await asyncio.sleep(max(nxt - loop.time(), 0.0))
            if loop.time() - nxt > period:
                nxt = loop.time()
            try:
                text = self.build()
            except Exception as e:       # the page must never take the daemon down
                self.stats["snapshot_errors"] += 1
                if self.stats["snapshot_errors"] == 1:
                    log.exception("web: building an update failed: %r", e)
                continue
            self.push(text)

    # ------------------------------------------------------------ lifecycle
    async def start(self) -> None:
        self._assets = load_assets()
        self._bad_requests = _BadRequests(self.stats)
        logging.getLogger("aiohttp.server").addFilter(self._bad_requests)
        runner = web.AppRunner(self.app(), access_log=None, handle_signals=False)
        await runner.setup()
        site = web.TCPSite(runner, self.cfg.host, self.cfg.port, reuse_address=True)
        try:
            await site.start()
        except OSError as e:
            self.stats["bind_failed"] += 1
            log.error("in-cab page not served: cannot listen on %s:%d: %s", self.cfg.host, self.cfg.port, e)
            await runner.cleanup()
            return
        self.runner = runner
        port = self.cfg.port
        server = getattr(site, "_server", None)
        if server is not None and server.sockets:
            port = server.sockets[0].getsockname()[1]
        host = self.cfg.host if ":" not in self.cfg.host else f"[{self.cfg.host}]"
        self.address = f"http://{host}:{port}/"
        log.info("in-cab page at %s", self.address)
        if self.on_listening is not None:
            self.on_listening(self.address)
        self.task = asyncio.create_task(self.run(), name=self.name)

    async def stop(self) -> None:
        try:
            await cancel_and_wait(self.task)
        finally:
            self.task = None
            for v in list(self.viewers):
                self._drop(v, "service stopping")
            if self.runner is not None:
                await self.runner.cleanup()
                self.runner = None
            if getattr(self, "_bad_requests", None) is not None:
                logging.getLogger("aiohttp.server").removeFilter(self._bad_requests)
                self._bad_requests = None
