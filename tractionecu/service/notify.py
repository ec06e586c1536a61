"""systemd's service notification protocol (``sd_notify(3)``), in a few lines.

systemd passes a ``Type=notify`` service the address of a Unix datagram
socket in ``$NOTIFY_SOCKET``.  The service sends newline-separated
``KEY=VALUE`` assignments, one datagram per notification:

- ``READY=1`` when start-up is complete (here: CAN bus and GPS port open);
- ``STATUS=...`` a one-line status that ``systemctl status`` shows;
- ``WATCHDOG=1`` a keep-alive, at least every ``$WATCHDOG_USEC`` µs when the
  unit has ``WatchdogSec=``; systemd kills and restarts a service that
  misses it (``Restart=on-failure``);
- ``STOPPING=1`` when shutting down.

Address forms (as libsystemd's ``sd_notify``): an absolute path, or an
abstract-namespace socket written with a leading ``@`` (the ``@`` becomes a
NUL byte).  ``vsock:`` addresses (systemd ≥ 253, for virtual machines) are
not supported and are reported once.  Without ``$NOTIFY_SOCKET`` (not run by
systemd) every call is a cheap no-op.

This replaces the unmaintained ``sdnotify`` / ``systemd-python`` packages
for the three messages the service needs.
"""

from __future__ import annotations

import logging
import os
import socket
from typing import Mapping

log = logging.getLogger(__name__)


def socket_address(value: str | None) -> str | None:
    """The ``connect()`` address for a ``$NOTIFY_SOCKET`` value, or None if unusable.

    ``"/run/systemd/notify"`` stays as is; ``"@name"`` becomes ``"\\0name"``
    (Linux abstract namespace).  Anything else (empty, relative, ``vsock:``)
    gives None.
    """
    if not value:
        return None
    if value.startswith("@"):
        return "\0" + value[1:]
    if value.startswith("/"):
        return value
    return None


def watchdog_interval(env: Mapping[str, str] | None = None, pid: int | None = None) -> float | None:
    """The watchdog period [s] systemd expects for this process, or None.

    From ``$WATCHDOG_USEC``; ignored if ``$WATCHDOG_PID`` is set to another
    process (as ``sd_watchdog_enabled(3)`` does).  Send ``WATCHDOG=1`` at
    half this period or more often.
    """
    env = os.environ if env is None else env
    usec = env.get("WATCHDOG_USEC")
    if not usec:
        return None
    wpid = env.get("WATCHDOG_PID")
    if wpid:
        try:
            if int(wpid) != (os.getpid() if pid is None else pid):
                return None
        except ValueError:
            return None
    try:
        v = int(usec)
    except ValueError:
        return None
    return v / 1e6 if v > 0 else None


class Notifier:
    """Send notifications to ``$NOTIFY_SOCKET`` (no-op without it).

    Parameters
    ----------
    env:
        Environment to read ``NOTIFY_SOCKET`` from (default ``os.environ``).

    Sending never raises: a failure is logged once and counted in
    :attr:`errors`.  The socket is connected once and kept.
    """

    def __init__(self, env: Mapping[str, str] | None = None) -> None:
        env = os.environ if env is None else env
        raw = env.get("NOTIFY_SOCKET")
        self.address = socket_address(raw)
        self.errors = 0
        self.sent = 0
        self._sock: socket.socket | None = None
        if raw and self.address is None:
            log.warning("NOTIFY_SOCKET=%r: unsupported address form, notifications disabled", raw)

    @property
    def enabled(self) -> bool:
        """True when running under systemd with a usable notify socket."""
        return self.address is not None

    def notify(self, *assignments: str) -> bool:
        """Send ``KEY=VALUE`` assignments in one datagram; True if sent."""
        if self.address is None:
            return False
        msg = "\n".join(a.replace("\n", " ") for a in assignments).encode("utf-8", "replace")
        try:
            if self._sock is None:
                s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
                s.setblocking(False)
                try:
                    s.connect(self.address)
                except OSError:
                    s.close()
                    raise
                self._sock = s
            self._sock.send(msg)
        except OSError as e:
            self.errors += 1
            if self.errors == 1:
                log.warning("sd_notify to %r failed: %s", self.address.replace("\0", "@"), e)
            self.close()
            return False
        self.sent += 1
        return True

    def ready(self, status: str | None = None) -> bool:
        """``READY=1`` (with an optional ``STATUS=``)."""
        return self.notify("READY=1", *([f"STATUS={status}"] if status else []))

    def status(self, text: str) -> bool:
        """``STATUS=text``."""
        return self.notify(f"STATUS={text}")

    def watchdog(self) -> bool:
        """``WATCHDOG=1``."""
        return self.notify("WATCHDOG=1")

    def stopping(self) -> bool:
        """``STOPPING=1``."""
        return self.notify("STOPPING=1")

    def close(self) -> None:
        """Close the socket (the next notification reconnects)."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None
