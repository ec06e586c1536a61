"""sd_notify over a real Unix datagram socket, path and abstract ('@') forms."""

from __future__ import annotations

import os
import socket
import uuid
from pathlib import Path

import pytest

from tractionecu.service.notify import Notifier, socket_address, watchdog_interval


def _server(addr: str) -> socket.socket:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    s.bind(addr)
    s.settimeout(2.0)
    return s


def test_socket_address_forms() -> None:
    assert socket_address("/run/systemd/notify") == "/run/systemd/notify"
    assert socket_address("@foo/bar") == "\0foo/bar"
    assert socket_address("") is None
    assert socket_address(None) is None
    assert socket_address("vsock:2:1234") is None
    assert socket_address("relative/path") is None


@pytest.mark.parametrize("abstract", [False, True])
def test_messages_arrive(tmp_path: Path, abstract: bool) -> None:
    if abstract:
        name = f"tractionecu-test-{uuid.uuid4().hex}"
        srv, env_value = _server("\0" + name), "@" + name
    else:
        path = str(tmp_path / "notify")
        srv, env_value = _server(path), path
    with srv:
        n = Notifier({"NOTIFY_SOCKET": env_value})
        assert n.enabled
        assert n.ready("CAN can0 open")
        assert srv.recv(4096) == b"READY=1\nSTATUS=CAN can0 open"
        assert n.status("line one\nline two")
        assert srv.recv(4096) == b"STATUS=line one line two"
        assert n.watchdog()
        assert srv.recv(4096) == b"WATCHDOG=1"
        assert n.stopping()
        assert srv.recv(4096) == b"STOPPING=1"
        assert n.sent == 4 and n.errors == 0
        n.close()


def test_without_systemd_is_a_no_op() -> None:
    n = Notifier({})
    assert not n.enabled
    assert not n.ready() and not n.watchdog()
    assert n.errors == 0


def test_unreachable_socket_is_counted_not_raised(tmp_path: Path) -> None:
    n = Notifier({"NOTIFY_SOCKET": str(tmp_path / "nobody-listens")})
    assert not n.status("x")
    assert not n.status("y")
    assert n.errors == 2


def test_watchdog_interval() -> None:
    assert watchdog_interval({}) is None
    assert watchdog_interval({"WATCHDOG_USEC": "5000000"}) == 5.0
    me = os.getpid()
    assert watchdog_interval({"WATCHDOG_USEC": "5000000", "WATCHDOG_PID": str(me)}) == 5.0
    assert watchdog_interval({"WATCHDOG_USEC": "5000000", "WATCHDOG_PID": str(me + 1)}) is None
    assert watchdog_interval({"WATCHDOG_USEC": "0"}) is None
    assert watchdog_interval({"WATCHDOG_USEC": "junk"}) is None
