"""The vcan guest works with the real parts: python-can's socketcan interface,
can-utils and iproute2 on a kernel vcan0.

Run with: tests/vcan/run-in-vcan.sh .venv/bin/python -m pytest -m vcan tests/vcan
"""

from __future__ import annotations

import os
import re
import select
import shutil
import socket
import subprocess
import time
from pathlib import Path

import can
import pytest

pytestmark = pytest.mark.vcan

CHANNEL = "vcan0"
RECV_TIMEOUT = 2.0

# A small candump -L recording: J1939 (29-bit) and 11-bit frames, DLC 0..8.
RECORDING = [
    (1700000000.000000, "18FF1080", "E803E803E803E803"),
    (1700000000.001000, "0CFE4980", "10270000A0860100"),
    (1700000000.002000, "123", "DEADBEEF"),
    (1700000000.003000, "18FEF100", ""),
    (1700000000.004000, "7FF", "01"),
    (1700000000.005000, "1CFF2280", "112233445566"),
    (1700000000.006000, "00000001", "FF"),
]


def frame_key(msg: can.Message) -> tuple[str, str]:
    """A message as candump writes it: (ID, DATA) in upper-case hex."""
    ident = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
    return ident, bytes(msg.data).hex().upper()


def need_tool(name: str) -> str:
    path = shutil.which(name)
    assert path, f"{name} not found on PATH (install it with tests/vcan/setup-uml.sh)"
    return path


def ip(*args: str) -> None:
    subprocess.run([need_tool("ip"), *args], check=True, capture_output=True, text=True)


def drain(bus: can.BusABC) -> None:
    while bus.recv(timeout=0) is not None:
        pass


def read_line(proc: subprocess.Popen[bytes], timeout: float) -> str:
    """One stdout line of proc, or AssertionError after timeout seconds."""
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout
    fd = proc.stdout.fileno()
    buf = b""
    while not buf.endswith(b"\n"):
        left = deadline - time.monotonic()
        ready, _, _ = select.select([fd], [], [], max(left, 0))
        assert ready, f"no line from {proc.args[0]} within {timeout}s (got {buf!r})"
        chunk = os.read(fd, 1)
        assert chunk, f"{proc.args[0]} closed its output (got {buf!r})"
        buf += chunk
    return buf.decode()


def test_socketcan_bus_opens() -> None:
    with can.Bus(interface="socketcan", channel=CHANNEL) as bus:
        assert CHANNEL in bus.channel_info
        assert bus.state == can.BusState.ACTIVE


def test_second_bus_receives_extended_frame() -> None:
    with (
        can.Bus(interface="socketcan", channel=CHANNEL) as tx,
        can.Bus(interface="socketcan", channel=CHANNEL) as rx,
    ):
        drain(rx)
        sent = can.Message(arbitration_id=0x18FF1080, is_extended_id=True, data=bytes(range(1, 9)))
        tx.send(sent)
        got = rx.recv(timeout=RECV_TIMEOUT)
        assert got is not None, "second bus received nothing"
        assert got.is_extended_id
        assert got.arbitration_id == 0x18FF1080
        assert got.dlc == 8
        assert bytes(got.data) == bytes(range(1, 9))
        assert got.channel == CHANNEL
        assert tx.recv(timeout=0.1) is None, "sender received its own frame"


def test_canplayer_frames_seen_by_candump_and_python_can(tmp_path: Path) -> None:
    canplayer = need_tool("canplayer")
    candump = need_tool("candump")
    log = tmp_path / "recording.log"
    log.write_text("".join(f"({t:.6f}) can0 {i}#{d}\n" for t, i, d in RECORDING))
    expected = [(i, d) for _, i, d in RECORDING]
    sync = can.Message(arbitration_id=0x1FFFFFFF, is_extended_id=True, data=b"\xaa")
    sync_key = frame_key(sync)
    assert sync_key not in expected

    with (
        can.Bus(interface="socketcan", channel=CHANNEL) as rx,
        can.Bus(interface="socketcan", channel=CHANNEL) as tx,
    ):
        drain(rx)
        with subprocess.Popen(
            [candump, "-L", CHANNEL],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
        ) as dump:
            try:
                # candump has no readiness signal: send sync frames until it shows
                # one, so no frame of the recording goes out before it listens.
                for _ in range(50):
                    tx.send(sync)
                    ready, _, _ = select.select([dump.stdout], [], [], 0.1)
                    if ready:
                        break
                assert read_line(dump, RECV_TIMEOUT).split()[1:] == [CHANNEL, "1FFFFFFF#AA"]

                played = subprocess.run(
                    [canplayer, "-I", str(log), f"{CHANNEL}=can0"],
                    capture_output=True,
                    text=True,
                    timeout=30,
                )
                assert played.returncode == 0, played.stderr

                seen_by_candump: list[tuple[str, str]] = []
                while len(seen_by_candump) < len(RECORDING):
                    line = read_line(dump, RECV_TIMEOUT)
                    stamp, iface, frame = line.split()
                    assert re.fullmatch(r"\(\d+\.\d{6}\)", stamp), line
                    assert iface == CHANNEL, line
                    ident, data = frame.split("#")
                    if (ident, data) != sync_key:
                        seen_by_candump.append((ident, data))
            finally:
                dump.kill()

        seen_by_python: list[tuple[str, str]] = []
        while len(seen_by_python) < len(RECORDING):
            got = rx.recv(timeout=RECV_TIMEOUT)
            assert got is not None, f"python-can got only {seen_by_python}"
            assert got.channel == CHANNEL
            if frame_key(got) != sync_key:
                seen_by_python.append(frame_key(got))
        assert rx.recv(timeout=0.1) is None, "python-can got more frames than were played"

    assert seen_by_candump == expected
    assert seen_by_python == expected


def test_vcan0_delete_and_recreate() -> None:
    try:
        ip("link", "del", CHANNEL)
        assert not os.path.exists(f"/sys/class/net/{CHANNEL}")
        with socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW) as sock:
            with pytest.raises(OSError):
                sock.bind((CHANNEL,))
    finally:
        if not os.path.exists(f"/sys/class/net/{CHANNEL}"):
            ip("link", "add", "dev", CHANNEL, "type", "vcan")
        ip("link", "set", CHANNEL, "up")

    with (
        can.Bus(interface="socketcan", channel=CHANNEL) as tx,
        can.Bus(interface="socketcan", channel=CHANNEL) as rx,
    ):
        drain(rx)
        tx.send(can.Message(arbitration_id=0x0CFE4980, is_extended_id=True, data=b"\x01\x02"))
        got = rx.recv(timeout=RECV_TIMEOUT)
        assert got is not None, "no frame on the re-created vcan0"
        assert frame_key(got) == ("0CFE4980", "0102")


def test_kernel_filters_pass_the_owners_11_bit_identifiers() -> None:
    """The service's kernel filters (``pgn_filters``) with an owner's 11-bit identifier (a CANedge GNSS speed
    on 0x007): the kernel passes that standard frame and the contract's PGNs, and drops another 11-bit
    identifier and a 29-bit frame with the same number."""
    from tractionecu.bus.dbc import default_codec
    from tractionecu.service.daemon import pgn_filters

    filters = pgn_filters(default_codec().pgns(), 0x90, [0x007])
    with (
        can.Bus(interface="socketcan", channel=CHANNEL) as tx,
        can.Bus(interface="socketcan", channel=CHANNEL, can_filters=filters) as rx,
    ):
        drain(rx)
        sent = [can.Message(arbitration_id=0x009, is_extended_id=False, data=bytes(8)),
                can.Message(arbitration_id=0x00000007, is_extended_id=True, data=bytes(5)),
                can.Message(arbitration_id=0x007, is_extended_id=False, data=bytes([1, 2, 3, 4, 5])),
                can.Message(arbitration_id=0x18FF1080, is_extended_id=True, data=bytes(8))]
        for m in sent:
            tx.send(m)
        got = []
        while (m := rx.recv(timeout=0.5)) is not None:
            got.append(frame_key(m))
        assert got == [("007", "0102030405"), ("18FF1080", "0000000000000000")]
