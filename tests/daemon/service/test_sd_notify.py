"""sd_notify: real AF_UNIX datagram sockets (a path and an abstract name) receive exactly systemd's messages."""

from __future__ import annotations

import os
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from monoguide.daemon.errors import NotifySocketInvalid
from monoguide.daemon.service import Notifier, watchdog_interval_s


@pytest.fixture
def path_socket(tmp_path: Path) -> Iterator[tuple[socket.socket, str]]:
    path = tmp_path / "notify"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.bind(str(path))
        sock.settimeout(2)
        yield sock, str(path)


@pytest.fixture
def abstract_socket() -> Iterator[tuple[socket.socket, str]]:
    name = f"monoguide-test-notify-{os.getpid()}"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.bind("\0" + name)
        sock.settimeout(2)
        yield sock, "@" + name


def _received(sock: socket.socket) -> str:
    return sock.recv(4096).decode()


@pytest.mark.parametrize("which", ["path_socket", "abstract_socket"])
def test_each_message_arrives_as_one_datagram(which: str, request: pytest.FixtureRequest) -> None:
    sock, address = request.getfixturevalue(which)
    notifier = Notifier({"NOTIFY_SOCKET": address})
    assert notifier.enabled
    assert notifier.ready("idle, devices connected")
    assert _received(sock) == "READY=1\nSTATUS=idle, devices connected"
    assert notifier.watchdog()
    assert _received(sock) == "WATCHDOG=1"
    assert notifier.status("idle; last cycle 41: ERROR\nDEVICE_TIMEOUT")
    assert _received(sock) == "STATUS=idle; last cycle 41: ERROR DEVICE_TIMEOUT"  # one line, one assignment
    assert notifier.stopping()
    assert _received(sock) == "STOPPING=1"


def test_without_notify_socket_nothing_is_sent(path_socket: tuple[socket.socket, str]) -> None:
    sock, _ = path_socket
    notifier = Notifier({})
    assert not notifier.enabled
    assert not notifier.ready() and not notifier.watchdog() and not notifier.status("idle")
    sock.settimeout(0.05)
    with pytest.raises(TimeoutError):
        sock.recv(4096)


def test_a_vanished_socket_is_logged_not_raised(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    notifier = Notifier({"NOTIFY_SOCKET": str(tmp_path / "gone")})
    assert notifier.watchdog() is False
    assert "sd_notify 'WATCHDOG=1'" in caplog.text and "gone" in caplog.text


def test_an_address_that_is_neither_path_nor_abstract_is_refused() -> None:
    with pytest.raises(NotifySocketInvalid, match="NOTIFY_SOCKET='vsock:2:1234'"):
        Notifier({"NOTIFY_SOCKET": "vsock:2:1234"})


@pytest.mark.parametrize(
    ("environ", "expected"),
    [
        ({}, None),
        ({"WATCHDOG_USEC": "30000000"}, 15.0),
        ({"WATCHDOG_USEC": "30000000", "WATCHDOG_PID": "4242"}, 15.0),
        ({"WATCHDOG_USEC": "30000000", "WATCHDOG_PID": "4243"}, None),  # meant for another process
        ({"WATCHDOG_USEC": "0"}, None),
        ({"WATCHDOG_USEC": "soon"}, None),
        ({"WATCHDOG_USEC": "500"}, 0.00025),
    ],
)
def test_watchdog_interval_is_half_watchdog_usec_for_this_process(environ: dict, expected: float | None) -> None:
    assert watchdog_interval_s(environ, pid=4242) == expected


def test_watchdog_interval_defaults_to_this_process(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("WATCHDOG_USEC", "4000000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    assert watchdog_interval_s() == 2.0


def test_a_receiver_that_does_not_read_never_blocks_the_service(path_socket: tuple[socket.socket, str],
                                                                 caplog: pytest.LogCaptureFixture) -> None:
    """A notify socket whose queue is full (nobody reading) loses messages, logged, and never holds the caller:
    200 sends return at once (the kernel queues about 10 datagrams), and reading again resumes delivery."""
    import time

    sock, address = path_socket
    notifier = Notifier({"NOTIFY_SOCKET": address})
    start = time.monotonic()
    sent = [notifier.watchdog() for _ in range(200)]
    assert time.monotonic() - start < 2.0
    assert sent[0] is True and sent.count(False) > 0 and "Resource temporarily unavailable" in caplog.text
    queued = sent.count(True)
    assert [_received(sock) for _ in range(queued)] == ["WATCHDOG=1"] * queued
    assert notifier.status("idle") is True and _received(sock) == "STATUS=idle"
