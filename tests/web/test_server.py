"""The in-cab page's server: read-only routes, assets from the package only, bounded viewers."""

from __future__ import annotations

import asyncio
import json
import math

import pytest
from aiohttp.test_utils import TestClient, TestServer

from tractionecu.service.advice import LiveMap
from tractionecu.service.config import WebConfig
from tractionecu.jsonsafe import json_safe
from tractionecu.web.server import ASSETS, SECURITY_HEADERS, WebPart, load_assets


def part(**kw) -> WebPart:
    state = {"n": 0}

    def snapshot():
        state["n"] += 1
        return {"t": float(state["n"]), "efficiency": {"eta": math.nan, "s_star": 0.08}, "advice": []}

    m = LiveMap()
    m.add(47.88, -110.55, {"a": 0.7, "eta": 0.75})
    w = WebPart(WebConfig(**{"port": 0, "update_hz": 5.0, **kw}), snapshot, m)
    w._assets = load_assets()
    return w


async def client(w: WebPart) -> TestClient:
    c = TestClient(TestServer(w.app()))
    await c.start_server()
    return c


def test_every_asset_is_in_the_package() -> None:
    assets = load_assets()
    assert set(assets) == set(ASSETS) and all(len(b) > 100 for b, _ in assets.values())
    html = assets["index.html"][0].decode()
    # nothing from the internet: every script and style is one of ours
    assert "http://" not in html and "https://" not in html and "/static/page.js" in html


async def test_read_only_routes_and_no_paths_from_the_request() -> None:
    w = part()
    c = await client(w)
    try:
        r = await c.get("/")
        assert r.status == 200 and "tractionecu" in await r.text()
        for k, v in SECURITY_HEADERS.items():
            assert r.headers[k] == v
        r = await c.get("/static/page.js")
        assert r.status == 200 and r.headers["Content-Type"].startswith("text/javascript")
        for bad in ("/static/..%2F..%2Fpyproject.toml", "/static/server.py", "/static/%2Fetc%2Fpasswd",
                    "/static/../server.py", "/server.py", "/static/index.html"):
            assert (await c.get(bad)).status == 404, bad
        for method in ("POST", "PUT", "DELETE", "PATCH"):
            for path in ("/", "/ws", "/state.json", "/static/page.js"):
                assert (await c.request(method, path)).status == 405, (method, path)
    finally:
        await c.close()


async def test_viewers_get_the_full_state_then_updates() -> None:
    w = part()
    c = await client(w)
    try:
        ws = await c.ws_connect("/ws")
        await asyncio.sleep(0.05)
        w.push(w.build())                        # the full state comes with the next update
        first = json.loads((await ws.receive(timeout=5)).data)
        assert first["kind"] == "full" and first["map"]["full"] and len(first["map"]["cells"]) == 1
        w.push(w.build())
        upd = json.loads((await ws.receive(timeout=5)).data)
        assert upd["kind"] == "update" and upd["viewers"] == 1 and upd["efficiency"]["eta"] is None
        await ws.send_str("anything")            # ignored: the page is read-only
        w.push(w.build())
        assert json.loads((await ws.receive(timeout=5)).data)["t"] > upd["t"]
        r = await c.get("/state.json")
        assert json.loads(await r.text())["efficiency"]["s_star"] == 0.08
        await ws.close()
    finally:
        await c.close()


async def test_viewers_connecting_between_two_updates_share_one_full_state() -> None:
    """Each connect built and serialised the whole live map in the connect handler, inside the event loop:
    eight viewers reconnecting every 2 s held the estimation loop up to 1.6 s and the watchdog went unfed."""
    w = part()
    c = await client(w)
    try:
        socks = [await c.ws_connect("/ws") for _ in range(5)]
        await asyncio.sleep(0.05)
        assert w.stats["full_states"] == 0                 # nothing built in the connect handler
        w.push(w.build())
        firsts = [json.loads((await ws.receive(timeout=5)).data) for ws in socks]
        assert all(f["kind"] == "full" for f in firsts) and w.stats["full_states"] == 1
        w.push(w.build())
        nxt = [json.loads((await ws.receive(timeout=5)).data) for ws in socks]
        assert all(u["kind"] == "update" for u in nxt)
        assert w.stats["full_states"] == 1
        for ws in socks:
            await ws.close()
    finally:
        await c.close()


async def test_a_slow_viewer_is_dropped_not_buffered() -> None:
    w = part(queue_updates=2)
    c = await client(w)
    try:
        ws = await c.ws_connect("/ws")
        await asyncio.sleep(0.05)
        (v,) = w.viewers
        v.sender.cancel()                     # a viewer that reads nothing: its queue fills
        await asyncio.sleep(0)
        for _ in range(5):
            w.push(w.build())
        assert w.viewers == set() and w.stats["viewers_dropped_slow"] == 1
        assert v.queue.qsize() <= 2
        await ws.close()
    finally:
        await c.close()


async def test_too_many_viewers_are_refused() -> None:
    w = part(max_viewers=1)
    c = await client(w)
    try:
        ws = await c.ws_connect("/ws")
        with pytest.raises(Exception):
            await c.ws_connect("/ws")
        assert w.stats["viewers_refused"] == 1
        await ws.close()
    finally:
        await c.close()


async def test_a_port_in_use_leaves_the_service_without_its_page() -> None:
    a = part()
    await a.start()
    try:
        port = int(a.address.rsplit(":", 1)[1].strip("/"))
        b = part(port=port)
        b.cfg = WebConfig(port=port, update_hz=5.0)
        await b.start()
        assert b.address is None and b.stats["bind_failed"] == 1 and b.task is None
        await b.stop()
    finally:
        await a.stop()


def test_clean_makes_json_safe() -> None:
    import numpy as np

    assert json_safe({"a": math.nan, "b": [1.0, math.inf], "c": np.array([0.5, np.nan])}) == {
        "a": None, "b": [1.0, None], "c": [0.5, None]}


def test_live_map_cells_and_changes() -> None:
    m = LiveMap(cell_m=3.0)
    m.add(47.88, -110.55, {"eta": 0.7})
    m.add(47.88, -110.55, {"eta": 0.8})
    m.add(47.8801, -110.55, {"eta": 0.6})        # 11 m north
    assert len(m.cells()) == 2
    ch = m.take_changed()
    assert sorted(c[2 + m.FIELDS.index("eta")] for c in ch) == [0.6, 0.75]
    assert m.take_changed() == []


async def test_malformed_requests_are_counted_not_logged_with_a_traceback_each(caplog) -> None:
    """Each request with an oversized header wrote an ERROR with a full traceback (50 requests, 35 KB of log)."""
    import logging

    w = part()
    await w.start()
    try:
        host, port = "127.0.0.1", int(w.address.rsplit(":", 1)[1].strip("/"))
        caplog.set_level(logging.DEBUG, logger="aiohttp.server")
        for _ in range(5):
            r, wr = await asyncio.open_connection(host, port)
            wr.write(b"GET / HTTP/1.1\r\nHost: x\r\nX-Big: " + b"a" * 20000 + b"\r\n\r\n")
            await wr.drain()
            await r.read(200)
            wr.close()
        await asyncio.sleep(0.05)
        recs = [x for x in caplog.records if x.name == "aiohttp.server"]
        assert w.stats["bad_requests"] == 5 and len(recs) == 1
        assert recs[0].levelno == logging.WARNING and recs[0].exc_info is None
        assert "malformed request refused" in recs[0].getMessage()
    finally:
        await w.stop()
