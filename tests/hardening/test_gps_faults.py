"""The GNSS reader on a real pty (pyserial): the port closed and reopened, binary UBX
mixed into the NMEA, sentences cut mid-line.  Rejects are counted, nothing raises,
and accepted fixes resume."""

from __future__ import annotations

import asyncio
import os
import random
import struct
import tty
from datetime import datetime, timedelta, timezone
from pathlib import Path

from tractionecu.gnss import nmea
from tractionecu.service.clock import ServiceClock
from tractionecu.service.config import GpsConfig
from tractionecu.service.gps import GpsReader


class Pty:
    """A pty whose slave is reachable through a stable symlink (the 'device')."""

    def __init__(self, link: Path) -> None:
        self.link = link
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        if link.is_symlink():
            link.unlink()
        link.symlink_to(os.ttyname(self.slave))

    def write(self, data: bytes) -> None:
        os.write(self.master, data)

    def close(self) -> None:
        os.close(self.master)
        os.close(self.slave)


def epoch(utc: datetime) -> bytes:
    lat, lon = 47.88 + 1e-6 * utc.second, -110.55
    lines = [nmea.format_gga(utc, lat, lon, 4, 14, 0.7, 850.0), nmea.format_rmc(utc, lat, lon, 2.5, 90.0),
             nmea.format_vtg(2.5, 90.0)]
    return ("\r\n".join(lines) + "\r\n").encode()


def ubx(cls: int, mid: int, payload: bytes) -> bytes:
    body = bytes([cls, mid]) + struct.pack("<H", len(payload)) + payload
    a = b = 0
    for x in body:
        a = (a + x) & 0xFF
        b = (b + a) & 0xFF
    return b"\xb5\x62" + body + bytes([a, b])


async def until(pred, timeout: float = 10.0) -> None:
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while not pred():
        assert loop.time() < end, "condition not reached in time"
        await asyncio.sleep(0.01)


class Reader:
    def __init__(self, tmp: Path) -> None:
        self.port = tmp / "ttyGNSS"
        self.pty = Pty(self.port)
        self.samples: list = []
        cfg = GpsConfig(port=str(self.port), reopen_min_s=0.02, reopen_max_s=0.1)
        self.r = GpsReader(cfg, self.samples.append, ServiceClock())
        self.task: asyncio.Task | None = None
        self.utc = datetime.now(timezone.utc).replace(microsecond=0)

    def next_epoch(self) -> bytes:
        """The epoch of now (10 Hz grid), as a receiver sends it."""
        now = datetime.now(timezone.utc)
        now = now.replace(microsecond=now.microsecond // 100000 * 100000)
        self.utc = max(now, self.utc + timedelta(milliseconds=100))
        return epoch(self.utc)

    async def epochs(self, n: int) -> None:
        """n good epochs at 10 Hz."""
        for _ in range(n):
            self.pty.write(self.next_epoch())
            await asyncio.sleep(0.1)

    async def __aenter__(self) -> Reader:
        self.task = asyncio.create_task(self.r.run())
        await asyncio.wait_for(self.r.is_open.wait(), 10)
        return self

    async def __aexit__(self, *exc) -> None:
        await self.r.close()
        assert self.task is not None
        await asyncio.wait_for(self.task, 10)
        self.pty.close()


async def test_pty_closed_and_reopened_fixes_resume(tmp_path: Path) -> None:
    async with Reader(tmp_path) as rd:
        await rd.epochs(5)
        await until(lambda: len(rd.samples) >= 4)
        rd.pty.write(rd.next_epoch()[:30])              # the cable goes mid-sentence
        rd.pty.close()                                  # receiver unplugged
        await until(lambda: rd.r.stats["link_failures"] >= 1)
        assert not rd.r.is_open.is_set()
        await asyncio.sleep(0.3)                        # gone for a while: reopen attempts fail
        assert rd.r.stats["open_failures"] >= 1
        n = len(rd.samples)
        rd.pty = Pty(rd.port)                           # plugged in again (a new pty behind the same name)
        await asyncio.wait_for(rd.r.is_open.wait(), 10)
        await rd.epochs(5)
        await until(lambda: len(rd.samples) >= n + 4)
        assert rd.task is not None and not rd.task.done()
        st = dict(rd.r.stats)
    assert st["opens"] == 2 and st["link_failures"] == 1, st


async def test_ubx_binary_and_cut_sentences_are_counted_and_fixes_resume(tmp_path: Path) -> None:
    rng = random.Random(7)
    async with Reader(tmp_path) as rd:
        await rd.epochs(1)
        await until(lambda: len(rd.samples) >= 1)
        n0 = len(rd.samples)
        good = 0
        for k in range(100):
            kind = k % 5
            if kind == 0:       # UBX NAV-PVT-like binary, with random payload (may contain \n)
                rd.pty.write(ubx(0x01, 0x07, bytes(rng.randrange(256) for _ in range(92))))
            elif kind == 1:     # an epoch whose first sentence is cut mid-line (the rest lost)
                e = rd.next_epoch()
                rd.pty.write(e[: rng.randrange(5, 60)] + b"\r\n")
                await asyncio.sleep(0.1)
            elif kind == 2:     # UBX glued to the front of a sentence
                rd.pty.write(ubx(0x05, 0x01, b"\x06\x01") + b"$GNGGA,123\r\n")
            elif kind == 3:     # pure noise, no newline for a long time (overlong)
                rd.pty.write(bytes(rng.randrange(256) for _ in range(300)) + b"\n")
            else:
                await rd.epochs(1)
                good += 1
        await rd.epochs(5)
        good += 5
        await until(lambda: len(rd.samples) - n0 >= good)
        st = dict(rd.r.stats)
        assert rd.task is not None and not rd.task.done()
    rejected = sum(v for k, v in st.items() if k.startswith("rejected_"))
    print(f"\nGPS hostile stream: {st}")
    assert rejected >= 60, st                      # each bad line is counted, none raises
    assert st["rejected_overlong"] >= 1
    assert st.get("link_failures", 0) == 0, st
