"""systemd's notification protocol, hand-written: one datagram per message to ``$NOTIFY_SOCKET``.

As systemd's own ``man/notify-selfcontained-example.py``: no libsystemd, a few lines over an AF_UNIX
datagram socket. ``READY=1`` after the devices connect, ``WATCHDOG=1`` at :func:`watchdog_interval_s`
while the cycle is healthy, ``STATUS=`` the state and the last result, ``STOPPING=1`` on SIGTERM.
Without ``$NOTIFY_SOCKET`` (run by hand, in tests) every call is a silent no-op.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Mapping

from monoguide.daemon.errors import NotifySocketInvalid

log = logging.getLogger(__name__)


class Notifier:
    """Sends notifications to the service manager named by ``environ`` (default ``os.environ``)."""

    def __init__(self, environ: Mapping[str, str] | None = None) -> None:
        address = (os.environ if environ is None else environ).get("NOTIFY_SOCKET", "")
        self.address = _socket_address(address) if address else None

    @property
    def enabled(self) -> bool:
        return self.address is not None

    def ready(self, status: str = "") -> bool:
        return self.send("READY=1" + (f"\nSTATUS={_one_line(status)}" if status else ""))

    def watchdog(self) -> bool:
        return self.send("WATCHDOG=1")

    def status(self, text: str) -> bool:
        return self.send(f"STATUS={_one_line(text)}")

    def stopping(self) -> bool:
        return self.send("STOPPING=1")

    def send(self, message: str) -> bool:
        """Send one message; True when it left. A failure is logged, never raised: a missed ping is the
        watchdog's business, and the service must not die of its supervisor restarting. Never blocks: a
        receiver whose queue is full (not reading) loses the message rather than stopping the service's loop."""
        if self.address is None:
            return False
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC | socket.SOCK_NONBLOCK) as sock:
                sock.connect(self.address)
                sock.sendall(message.encode())
        except OSError as exc:
            log.warning("sd_notify %r to %r failed: %s", message, self.address, exc)
            return False
        return True


def watchdog_interval_s(environ: Mapping[str, str] | None = None, pid: int | None = None) -> float | None:
    """Seconds between ``WATCHDOG=1`` pings: half of ``$WATCHDOG_USEC``, as sd_watchdog_enabled(3) advises.

    None when no watchdog is asked for, or when ``$WATCHDOG_PID`` names another process (it was meant for
    a parent). A value that is not a positive whole number is ignored with a warning, as systemd does.
    """
    environ = os.environ if environ is None else environ
    usec = environ.get("WATCHDOG_USEC")
    if not usec:
        return None
    watchdog_pid = environ.get("WATCHDOG_PID")
    if watchdog_pid and watchdog_pid != str(os.getpid() if pid is None else pid):
        return None
    if not usec.isdigit() or int(usec) == 0:
        log.warning("WATCHDOG_USEC=%r is not a positive number of microseconds; no watchdog pings", usec)
        return None
    return int(usec) / 2e6


def _socket_address(address: str) -> str:
    if address.startswith("@"):  # abstract namespace: a leading NUL byte instead of the '@'
        return "\0" + address[1:]
    if address.startswith("/"):
        return address
    raise NotifySocketInvalid(f"NOTIFY_SOCKET={address!r}: neither an absolute path nor an abstract name (@...)")


def _one_line(text: str) -> str:
    return " ".join(text.split("\n"))  # a newline would start a new KEY=VALUE assignment
