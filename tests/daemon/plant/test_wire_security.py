"""What an attacker on the plant network sends to ``monoguide plant``, from the wire (tests/helpers/plant_wire.py):
a session over a channel without security, a user name token without a name, security policies and modes not
served, bytes that are no OPC UA, an ApplicationUri not the certificate's, wrong passwords timed, a thousand idle
connections, half-sent metrics requests, more sessions and subscriptions than a client may hold, and failed logins
until the client must wait. One plant process, its limits made small, under the open-file limit of its unit."""

from __future__ import annotations

import asyncio
import contextlib
import os
import re
import resource
import selectors
import socket
import statistics
import time
import urllib.request
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from asyncua import ua
from asyncua.crypto.security_policies import (
    SecurityPolicyAes128Sha256RsaOaep,
    SecurityPolicyAes256Sha256RsaPss,
    SecurityPolicyBasic256Sha256,
)
from asyncua.ua.uaerrors import UaError
from helpers.plant_cells import PASSWORD, USER, StatusBeat, plant_file, seeded_entries, write_journal
from helpers.plant_clients import ClientIdentity, client_identity, connected, start_plant, trust
from helpers.plant_wire import (
    err_status,
    exchange,
    hello,
    idle_connections,
    nameless_user_token,
    open_request,
    session_over_plain_channel,
    status_name,
    timed_refusal,
)
from helpers.repository import SIM_CELL
from helpers.sim_processes import stop

from monoguide.daemon.plant import hash_password
from monoguide.daemon.plant._front import BACKLOG

HOST, PORT = "127.0.86.1", 48601
UNIT = Path(__file__).parents[3] / "systemd" / "monoguide-plant.service"
SYSTEMD_DEFAULT_NOFILE = 1024  # a unit without LimitNOFILE gets systemd's default soft limit
OPERATOR, OPERATOR_PASSWORD = "operator", "tulip gravel orbit"  # a hash of the default 600,000 iterations
LIMITS = {"max_connections": 40, "max_connections_per_client": 6, "max_sessions": 8, "max_sessions_per_client": 4,
          "max_subscriptions": 16, "max_subscriptions_per_client": 3, "hello_timeout_s": 1.0,
          "activation_timeout_s": 3.0, "login_failures": 12, "login_window_s": 30.0, "refusal_log_s": 1.0,
          "metrics_max_connections": 8, "metrics_max_connections_per_client": 4, "metrics_timeout_s": 1.0}


@dataclass
class Plant:
    url: str
    metrics_url: str
    pid: int
    client: ClientIdentity
    server_certificate: Path
    log: Path


def _unit_nofile() -> int:
    found = re.search(r"^LimitNOFILE=(\d+)", UNIT.read_text(), re.MULTILINE)
    return int(found.group(1)) if found else SYSTEMD_DEFAULT_NOFILE


@pytest.fixture(scope="module")
def plant(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Plant]:
    tmp = tmp_path_factory.mktemp("wire")
    state_dir = tmp / "state"
    write_journal(state_dir, seeded_entries(6, time.time() - 600.0))
    beat = StatusBeat(state_dir)
    client = client_identity(tmp / "clients", "scada-client")
    trust(client, state_dir / "plant" / "trusted")
    extra = "\n".join(f"{k} = {v}" for k, v in LIMITS.items()) + (
        f'\n[[plant.users]]\nname = "{OPERATOR}"\npassword_hash = "{hash_password(OPERATOR_PASSWORD)}"\n')
    log = tmp / "plant.log"
    process, line = start_plant(SIM_CELL, state_dir, plant_file(tmp / "plant.toml", HOST, PORT, extra), log,
                                nofile=_unit_nofile())
    try:
        yield Plant(line.split()[2], line.split()[4], process.pid, client,
                    state_dir / "plant" / "server-certificate.der", log)
    finally:
        stop(process)
        beat.stop()


def test_no_session_over_a_channel_without_security(plant: Plant) -> None:
    """CreateSession over a None channel, the client's endpoint check skipped, then an X.509 identity of a trusted
    certificate: refused at CreateSession, nothing read."""
    answer = asyncio.run(session_over_plain_channel(plant.url, plant.client))
    assert answer.refused is not None and answer.step == "session", answer


def test_a_user_name_token_needs_a_user_name(plant: Plant) -> None:
    answer = asyncio.run(nameless_user_token(plant.url, plant.client, "any password at all"))
    assert (answer.refused, answer.step) == ("BadIdentityTokenInvalid", "activation"), answer


@pytest.mark.parametrize(("policy", "mode", "status"), [
    (SecurityPolicyBasic256Sha256, ua.MessageSecurityMode.Sign, "BadSecurityModeRejected"),
    (SecurityPolicyAes256Sha256RsaPss, ua.MessageSecurityMode.Sign, "BadSecurityModeRejected"),
    (SecurityPolicyAes128Sha256RsaOaep, ua.MessageSecurityMode.SignAndEncrypt, "BadSecurityPolicyRejected"),
])
def test_a_policy_or_mode_not_served_gets_an_err_message(plant: Plant, policy: type, mode: ua.MessageSecurityMode,
                                                        status: str) -> None:
    started = time.monotonic()
    reply, closed = exchange(plant.url, hello(plant.url) + open_request(policy, mode, plant.client,
                                                                        plant.server_certificate))
    assert status_name(err_status(reply)) == status and closed, reply[:80]
    assert time.monotonic() - started < 2.0


@pytest.mark.parametrize(("sent", "status"), [
    (b"GET / HTTP/1.1\r\nHost: plant\r\n\r\n", "BadTcpMessageTypeInvalid"),
    (bytes(range(256)) * 4, "BadTcpMessageTypeInvalid"),
    (b"HELF\x0c\x00\x00\x00\x00\x00\x00\x00", "BadTcpMessageTypeInvalid"),  # a Hello shorter than its fields
    (b"MSGF\x20\x00\x00\x00" + bytes(24), "BadTcpMessageTypeInvalid"),  # no Hello first
    (b"HELF\xff\xff\xff\x7f", "BadTcpMessageTooLarge"),
])
def test_bytes_that_are_no_opc_ua_get_an_err_message(plant: Plant, sent: bytes, status: str) -> None:
    reply, closed = exchange(plant.url, sent)
    assert status_name(err_status(reply)) == status and closed, reply[:80]


def test_an_application_uri_other_than_the_certificate_s_is_refused(plant: Plant) -> None:
    answer = asyncio.run(timed_refusal(connected(plant.url, plant.client, user=USER, password=PASSWORD, timeout_s=5,
                                                 application_uri="urn:test:someone-else")))
    assert answer.refused == "BadCertificateUriInvalid", answer


def test_a_wrong_password_costs_the_same_for_a_user_and_a_stranger(plant: Plant) -> None:
    """A user of 600,000 iterations, a user of 100,000 and a name of nobody, each with wrong passwords: the plant
    spends the same processor time on each refusal (within a quarter of one PBKDF2 check; before, a stranger was
    refused without one). Processor time, not the time the client waits, so that a loaded machine does not blur it;
    the waits are printed."""
    cpu: dict[str, float] = {}
    waits: dict[str, float] = {}
    attempts = 3

    async def run() -> None:
        for name in (OPERATOR, USER, "nobody"):
            used, seconds = _cpu_s(plant.pid), []
            for _ in range(attempts):
                answer = await timed_refusal(connected(plant.url, plant.client, user=name, password="wrong",
                                                       timeout_s=10))
                assert answer.refused == "BadUserAccessDenied", answer
                seconds.append(answer.seconds)
            cpu[name] = (_cpu_s(plant.pid) - used) / attempts
            waits[name] = statistics.median(seconds)

    asyncio.run(run())
    started = time.process_time()
    hash_password("a check's cost")
    check_s = time.process_time() - started
    print(f"failed logins: plant CPU s each {cpu}, the client's wait (median s) {waits}; one check {check_s:.3f} s")
    assert abs(cpu[OPERATOR] - cpu["nobody"]) < 0.25 * check_s, cpu
    assert abs(cpu[USER] - cpu["nobody"]) < 0.25 * check_s, cpu


def test_a_thousand_idle_connections_take_nothing_down(plant: Plant) -> None:
    """1,000 connections that say nothing from ten addresses and 20 half-sent metrics requests from an eleventh:
    refused beyond the limits (an ERR BadTcpServerTooBusy, a 503), the rest closed after hello_timeout_s (an ERR
    BadTimeout) and metrics_timeout_s; meanwhile the plant's descriptors stay far below its unit's LimitNOFILE, its
    threads do not grow and a scrape is answered; after it a client is served; the log says it in a few lines."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, max(soft, 4096)), hard))
    lines_before = len(plant.log.read_text().splitlines())
    fds_before, threads_before = _fds(plant.pid), _threads(plant.pid)
    flood = [s for n in range(10) for s in idle_connections(plant.url, 100, f"127.0.86.{101 + n}")]
    slow = idle_connections(plant.metrics_url, 20, "127.0.86.120")
    try:
        for sock in slow:
            _send_when_connected(sock, b"GET /metrics HTTP/1.1\r\nHost: plant\r\n")  # never the blank line
        peak = {"fds": 0, "threads": 0}

        def sample() -> None:
            peak["fds"], peak["threads"] = max(peak["fds"], _fds(plant.pid)), max(peak["threads"],
                                                                                  _threads(plant.pid))

        sample()
        with urllib.request.urlopen(plant.metrics_url, timeout=5) as answer:  # the metrics answer meanwhile
            assert answer.status == 200
        got = _until_closed(flood + slow, 10.0, sample)
        open_still = [s for s in flood + slow if s not in got]
        assert not open_still, f"{len(open_still)} connections still open after hello_timeout_s, metrics_timeout_s"
        answers = [status_name(err_status(got[s])) for s in flood]
        assert answers.count("BadTcpServerTooBusy") >= len(flood) - LIMITS["max_connections"], answers[:5]
        assert set(answers) <= {"BadTcpServerTooBusy", "BadTimeout"}, set(answers)

        async def read() -> object:
            client = await connected(plant.url, plant.client, user=OPERATOR, password=OPERATOR_PASSWORD)
            try:
                return await client.get_node(ua.NodeId(ua.ObjectIds.Server_ServerStatus_State)).read_value()
            finally:
                await client.disconnect()

        assert asyncio.run(read()) == ua.ServerState.Running
    finally:
        for sock in flood + slow:
            sock.close()
    print(f"plant descriptors {fds_before} before, at most {peak['fds']} with 1,000 idle connections (LimitNOFILE "
          f"{_unit_nofile()}); threads {threads_before} -> at most {peak['threads']}")
    # a burst is accepted as it comes (at most the listening backlog at once) and refused; what is held is bounded by
    # the limits: three descriptors for each relayed connection, one for each metrics connection
    held = 3 * LIMITS["max_connections"] + LIMITS["metrics_max_connections"]
    assert peak["fds"] <= fds_before + BACKLOG + held + 8
    assert peak["fds"] < _unit_nofile() // 4
    assert peak["threads"] <= threads_before + 2
    new = plant.log.read_text().splitlines()[lines_before:]
    assert any("max_connections_per_client reached" in line for line in new), new[-10:]
    assert len(new) <= 16, new[:20]


def test_sessions_and_subscriptions_per_client_are_limited(plant: Plant) -> None:
    async def run() -> None:
        sessions = [await connected(plant.url, plant.client, user=USER, password=PASSWORD)
                    for _ in range(LIMITS["max_sessions_per_client"])]
        try:
            with pytest.raises(UaError) as refused:
                await connected(plant.url, plant.client, user=USER, password=PASSWORD, timeout_s=5)
            assert type(refused.value).__name__ == "BadTooManySessions"
            for _ in range(LIMITS["max_subscriptions_per_client"]):
                await sessions[0].create_subscription(500, None)
            with pytest.raises(UaError) as refused:
                await sessions[1].create_subscription(500, None)  # another session, the same client
            assert type(refused.value).__name__ == "BadTooManySubscriptions"
        finally:
            for session in sessions:
                await session.disconnect()

    asyncio.run(run())


def test_failed_logins_make_a_client_wait(plant: Plant) -> None:
    """After login_failures failed logins within login_window_s, even the right password is refused (last in the
    module: 127.0.0.1 then waits out the window)."""
    async def run() -> None:
        for _ in range(LIMITS["login_failures"]):
            answer = await timed_refusal(connected(plant.url, plant.client, user=USER, password="wrong",
                                                   timeout_s=10))
            assert answer.refused == "BadUserAccessDenied", answer
        answer = await timed_refusal(connected(plant.url, plant.client, user=USER, password=PASSWORD, timeout_s=10))
        assert answer.refused == "BadUserAccessDenied", answer

    asyncio.run(run())
    deadline = time.monotonic() + 3 * LIMITS["refusal_log_s"]
    while "login_failures reached" not in plant.log.read_text() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert "login_failures reached" in plant.log.read_text()


# --- private ------------------------------------------------------------------------------------


def _until_closed(socks: list[socket.socket], timeout_s: float,
                  sample: Callable[[], None]) -> dict[socket.socket, bytes]:
    """What each socket received until the server closed it (those still open after ``timeout_s`` are missing);
    ``sample`` is called every 0.2 s meanwhile."""
    got: dict[socket.socket, bytes] = {}
    data: dict[socket.socket, bytes] = dict.fromkeys(socks, b"")
    with selectors.DefaultSelector() as selector:
        for sock in socks:
            sock.setblocking(False)
            selector.register(sock, selectors.EVENT_READ)
        deadline = time.monotonic() + timeout_s
        while len(got) < len(socks) and time.monotonic() < deadline:
            for key, _ in selector.select(0.2):
                sock = key.fileobj
                assert isinstance(sock, socket.socket)
                try:
                    chunk = sock.recv(65536)
                except (BlockingIOError, InterruptedError):
                    continue
                except OSError:
                    chunk = b""
                if chunk:
                    data[sock] += chunk
                else:
                    got[sock] = data[sock]
                    selector.unregister(sock)
            sample()
    return got


def _cpu_s(pid: int) -> float:
    """The process's user and system time so far (/proc/PID/stat, fields 14 and 15)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _fds(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


def _threads(pid: int) -> int:
    status = Path(f"/proc/{pid}/status").read_text()
    return int(re.search(r"^Threads:\s+(\d+)", status, re.MULTILINE).group(1))  # type: ignore[union-attr]


def _send_when_connected(sock: socket.socket, data: bytes) -> None:
    sock.settimeout(5)
    with contextlib.suppress(OSError):  # refused at once (503 and closed)
        sock.sendall(data)
