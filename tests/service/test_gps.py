"""NMEA from a serial port: strict parsing, gating, epochs, and pyserial on a real pty with unplug/replug."""

from __future__ import annotations

import asyncio
import os
import tty
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest

from tractionecu.gnss import nmea
from tractionecu.service.clock import ServiceClock
from tractionecu.service.config import GpsConfig
from tractionecu.gnss.utc import utc_epoch
from tractionecu.service.gps import GpsReader, GpsSample, NmeaStream

FIXTURE = Path(__file__).resolve().parents[1] / "data" / "nmea" / "mixed.nmea"
T0 = datetime(2026, 7, 10, 8, 0, 0, tzinfo=timezone.utc)


def epoch(utc: datetime, *, quality: int = 2, hdop: float = 0.9, speed: float = 2.5, talker: str = "GN",
          valid: bool = True, rmc: bool = True) -> list[str]:
    lat, lon = 47.88, -110.55
    out = [nmea.format_gga(utc, lat, lon, quality, 12, hdop, 850.0, talker=talker)]
    if rmc:
        out.append(nmea.format_rmc(utc, lat, lon, speed, 90.0, valid, talker=talker))
    out.append(nmea.format_vtg(speed, 90.0, talker=talker))
    return out


def feed_lines(stream: NmeaStream, lines: list[str], t: float) -> None:
    stream.feed(("\r\n".join(lines) + "\r\n").encode("ascii"), t)


def collect(cfg: GpsConfig | None = None) -> tuple[NmeaStream, list[GpsSample]]:
    got: list[GpsSample] = []
    return NmeaStream(cfg or GpsConfig(), got.append), got


def test_epoch_is_handed_on_after_its_last_sentence_with_its_utc_time() -> None:
    s, got = collect()
    utc = T0 + timedelta(seconds=0.1)
    feed_lines(s, epoch(utc), utc.timestamp() + 0.03)
    assert len(got) == 1, "GGA+RMC+VTG epoch waits for the next epoch"
    g = got[0]
    assert g.t == utc_epoch(utc.date(), 8 * 3600 + 0.1)
    assert g.speed_mps == pytest.approx(2.5, abs=1e-3)
    assert g.fix_quality == 2 and g.hdop == 0.9
    assert g.lat_deg == pytest.approx(47.88) and g.lon_deg == pytest.approx(-110.55)
    assert s.stats["accepted"] == 1 and s.stats["time_from_arrival"] == 0


def test_receiver_without_rmc_learns_its_epoch() -> None:
    s, got = collect()
    for i in range(4):
        utc = T0 + timedelta(seconds=0.1 * i)
        feed_lines(s, epoch(utc, rmc=False), utc.timestamp())
    # the first epoch closes when the second starts; from then on the GGA+VTG set is known
    # and each epoch is handed on at its own last sentence
    assert len(got) == 4
    assert [round(g.t - got[0].t, 3) for g in got] == [0.0, 0.1, 0.2, 0.3]


@pytest.mark.parametrize(
    "kw, cfg, reason",
    [
        ({"quality": 0}, GpsConfig(), "gated_fix_quality"),
        ({"hdop": 9.5}, GpsConfig(), "gated_hdop"),
        ({"valid": False}, GpsConfig(), "gated_invalid"),
        ({"quality": 2}, GpsConfig(min_fix_quality=4), "gated_fix_quality"),
        ({"hdop": 1.5}, GpsConfig(max_hdop=1.2), "gated_hdop"),
    ],
)
def test_gating(kw: dict, cfg: GpsConfig, reason: str) -> None:
    s, got = collect(cfg)
    feed_lines(s, epoch(T0, **kw), T0.timestamp())
    feed_lines(s, epoch(T0 + timedelta(seconds=0.1), quality=4, hdop=0.5), T0.timestamp() + 0.1)  # a good one
    assert s.stats[reason] == 1
    assert [g.t for g in got] == [T0.timestamp() + 0.1]


def test_any_talker() -> None:
    s, got = collect()
    for i, talker in enumerate(("GP", "GN", "GL", "GA", "GB")):
        utc = T0 + timedelta(seconds=0.1 * i)
        feed_lines(s, epoch(utc, talker=talker), utc.timestamp())
    assert len(got) == 5


def test_bad_lines_are_counted_never_raised() -> None:
    s, got = collect()
    s.feed(FIXTURE.read_bytes(), T0.timestamp())
    st = s.stats
    assert st["rejected_bad_checksum"] == 1
    assert st["rejected_missing_checksum"] == 1
    assert st["rejected_garbage"] == 1
    assert st["rejected_bad_field"] == 1
    assert st["ignored"] == 1                        # GSV: valid, not used
    s.feed(b"\x00\xff\xfe" * 100 + b"\n", 0.0)      # binary noise, longer than any NMEA line
    s.feed(b"$GPGGA" + b"9" * 500, 0.0)             # never terminated
    assert st["rejected_overlong"] == 2
    n = len(got)
    feed_lines(s, epoch(T0 + timedelta(seconds=5)), T0.timestamp() + 5)
    assert len(got) == n + 1, "the stream recovers after garbage"


def test_lines_split_across_reads() -> None:
    s, got = collect()
    data = ("\r\n".join(epoch(T0)) + "\r\n").encode()
    for i in range(0, len(data), 7):
        s.feed(data[i:i + 7], T0.timestamp())
    assert len(got) == 1 and s.stats["lines"] == 3


def test_host_clock_off_utc_uses_arrival_time() -> None:
    s, got = collect(GpsConfig(latency_s=0.05))
    arrival = T0.timestamp() + 3 * 3600.0      # host clock three hours off
    feed_lines(s, epoch(T0), arrival)
    assert got[0].t == pytest.approx(arrival - 0.05)
    assert s.stats["time_from_arrival"] == 1


def test_epoch_going_back_in_time_is_dropped() -> None:
    s, got = collect()
    feed_lines(s, epoch(T0 + timedelta(seconds=0.3)), T0.timestamp() + 0.3)
    feed_lines(s, epoch(T0 + timedelta(seconds=0.2)), T0.timestamp() + 0.35)
    assert len(got) == 1 and s.stats["gated_repeated"] == 1


# ---------------------------------------------------------------- real pyserial on a pty
class Pty:
    """A pseudo-terminal whose slave is reachable through a fixed symlink (the 'port')."""

    def __init__(self, link: Path) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        if link.is_symlink():
            link.unlink()
        link.symlink_to(os.ttyname(self.slave))

    def write(self, lines: list[str]) -> None:
        os.write(self.master, ("\r\n".join(lines) + "\r\n").encode())

    def unplug(self) -> None:
        os.close(self.slave)
        os.close(self.master)


async def _until(pred, timeout: float = 10.0) -> None:
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while not pred():
        assert loop.time() < end, "condition not reached in time"
        await asyncio.sleep(0.01)


async def test_serial_reader_on_a_pty_survives_unplug(tmp_path: Path) -> None:
    port = tmp_path / "ttyGNSS"
    got: list[GpsSample] = []
    clock = ServiceClock(epoch0=T0.timestamp())
    reader = GpsReader(GpsConfig(port=str(port), reopen_min_s=0.02, reopen_max_s=0.05), got.append, clock)
    task = asyncio.create_task(reader.run())
    try:
        await asyncio.sleep(0.1)
        assert not reader.is_open.is_set() and reader.stats["open_failures"] >= 1   # no device yet
        dev = Pty(port)
        await asyncio.wait_for(reader.is_open.wait(), 10)
        dev.write(epoch(T0))
        await _until(lambda: len(got) == 1)

        dev.unplug()
        await _until(lambda: reader.stats["link_failures"] == 1)
        dev = Pty(port)
        await _until(lambda: reader.stats["opens"] == 2)
        utc = T0 + timedelta(seconds=0.1)
        dev.write(epoch(utc))
        await _until(lambda: len(got) == 2)
        assert got[1].t == utc.timestamp()
        dev.unplug()
    finally:
        await reader.close()
        await asyncio.wait_for(task, 10)
    assert not reader.is_open.is_set()


async def test_a_close_during_the_reopen_backoff_ends_the_reader_at_once(tmp_path: Path) -> None:
    """A GNSS port that does not exist, retried every 30 s: SIGTERM waited out the backoff's sleep, the
    device task overran its 5 s stop limit and the service exited 1 after 5.1 s."""
    reader = GpsReader(GpsConfig(port=str(tmp_path / "ttyNOPE"), reopen_min_s=30.0, reopen_max_s=60.0),
                       lambda s: None, ServiceClock())
    task = asyncio.create_task(reader.run())
    await _until(lambda: reader.stats["open_failures"] >= 1)
    loop = asyncio.get_running_loop()
    t0 = loop.time()
    await reader.close()
    await asyncio.wait_for(task, 2.0)
    assert loop.time() - t0 < 1.0


def test_sentences_glued_by_a_lost_line_break_are_each_read() -> None:
    """A lost CR/LF glues two sentences into one line ('$GNGGA,…*hh$GNRMC,…*hh'): the line was refused as
    garbage and the epoch lost; each sentence is judged on its own now, and the split is counted."""
    s, got = collect()
    ref, got_ref = collect()
    for i in range(4):
        utc = T0 + timedelta(seconds=0.1 * i)
        lines = epoch(utc)
        feed_lines(ref, lines, utc.timestamp())
        feed_lines(s, [lines[0] + lines[1], lines[2]], utc.timestamp())
    assert [g.t for g in got] == [g.t for g in got_ref] and len(got) == 4
    assert [g.speed_mps for g in got] == [g.speed_mps for g in got_ref]
    assert s.stats["split_lines"] == 4 and not any(k.startswith("rejected_") and v for k, v in s.stats.items())
    # a glued line whose second sentence is damaged: the first still counts, the second is refused
    bad, got_bad = collect()
    utc = T0
    lines = epoch(utc)
    feed_lines(bad, [lines[0] + lines[1][:-1] + "0", lines[2]], utc.timestamp())
    assert bad.stats["rejected_bad_checksum"] == 1 and bad.stats["split_lines"] == 1
