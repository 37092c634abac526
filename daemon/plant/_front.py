"""The OPC UA port as the plant network meets it: a small TCP relay of monoguide's own in front of asyncua's server,
which listens on an ephemeral port of 127.0.0.1 only.

Why a relay: asyncua (2.1) has no hook before a session exists. It counts connections in total but not per client;
it answers a security policy or mode it does not serve, and bytes that are no OPC UA, with silence (the client waits
out its own timeout); and it opens a session on a channel without security. The relay reads what OPC UA TCP puts in
clear (``_wire``): it refuses, with an ERR message and closing the connection,

- a connection beyond ``max_connections_per_client`` from one address or ``max_connections`` in all
  (``BadTcpServerTooBusy``);
- no Hello, or no OpenSecureChannel after it, within ``hello_timeout_s`` (``BadTimeout``);
- a first message that is not a Hello, a message type or chunk type that does not exist, a chunk larger than the
  server's buffer (``BadTcpMessageTypeInvalid``, ``BadTcpMessageTooLarge``);
- a security policy other than None, Basic256Sha256 and Aes256Sha256RsaPss (``BadSecurityPolicyRejected``), a mode
  other than SignAndEncrypt (``BadSecurityModeRejected``: read from the OpenSecureChannel's body with the server's
  key);
- on a channel of the None policy (which discovery needs), any request but GetEndpoints and FindServers
  (``BadSecurityModeInsufficient``): no session is ever created over it.

Everything else is relayed unchanged both ways. asyncua sees each client as the relay's socket; :meth:`Front.client_of`
tells which address that is, so that sessions and subscriptions are counted per client (``_sessions``), and a
connection that did not come through the relay has no client and gets no session. Each relayed connection costs three
file descriptors (the client's, the relay's to asyncua, asyncua's).
"""

from __future__ import annotations

import asyncio
import logging

from asyncua import ua
from cryptography.hazmat.primitives.asymmetric import rsa

from monoguide.daemon.errors import PlantListenFailed
from monoguide.daemon.plant._listener import Listener
from monoguide.daemon.plant._refusals import Refusals
from monoguide.daemon.plant._settings import PlantLimits
from monoguide.daemon.plant._wire import (
    HEADER_BYTES,
    NONE_POLICY,
    Refused,
    check_hello,
    chunk_header,
    error_message,
    open_mode,
    open_policy,
    plain_request,
)

log = logging.getLogger(__name__)

RELAY_BYTES = 65536
BACKLOG = 1024  # connections the kernel holds until accepted: a flood is accepted and refused, not dropped unseen
Peer = tuple[str, int]


class Front:
    """Listens on the OPC UA endpoint's address; :meth:`start` once asyncua listens on ``upstream``."""

    def __init__(self, host: str, port: int, limits: PlantLimits, refusals: Refusals) -> None:
        self.host, self.port, self.limits, self.refusals = host, port, limits, refusals
        self.upstream: Peer | None = None
        self.key: rsa.RSAPrivateKey | None = None  # the server's: it reads an OpenSecureChannel's mode
        self.clients: dict[Peer, str] = {}  # the relay's socket to asyncua (asyncua's peer name) -> the client's IP
        self.listener = Listener(limits.connections, limits.connections_per_client,
                                 ("max_connections", "max_connections_per_client"))

    def client_of(self, peer: object) -> str | None:
        """The client's IP address behind asyncua's peer ``peer``; None for a connection not made by the relay."""
        return self.clients.get(peer) if isinstance(peer, tuple) else None  # type: ignore[call-overload]

    async def start(self, upstream: Peer, key: rsa.RSAPrivateKey) -> None:
        self.upstream, self.key = upstream, key
        try:
            await self.listener.listen(self.host, self.port, self._connection, self._busy, limit=RELAY_BYTES,
                                       backlog=BACKLOG)
        except OSError as exc:
            raise PlantListenFailed(f"OPC UA opc.tcp://{self.host}:{self.port}: cannot listen: {exc}") from exc

    async def stop(self) -> None:
        await self.listener.stop()

    # --- private ------------------------------------------------------------------------------------

    async def _busy(self, writer: asyncio.StreamWriter, client: str, reason: str) -> None:
        self.refusals.refuse("opcua", reason, client)
        writer.write(error_message(ua.StatusCodes.BadTcpServerTooBusy, reason))

    async def _connection(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, client: str) -> None:
        try:
            await self._relay(reader, writer, client)
        except Refused as refused:
            self.refusals.refuse("opcua", refused.reason, client)
            writer.write(error_message(refused.status, refused.reason))

    async def _relay(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, client: str) -> None:
        hello = await self._chunk(reader, first=True, timeout_s=self.limits.hello_timeout_s, what="no Hello")
        check_hello(hello)
        assert self.upstream is not None
        up_reader, up_writer = await asyncio.open_connection(*self.upstream, limit=RELAY_BYTES)
        local = up_writer.get_extra_info("sockname")
        self.clients[local] = client
        try:
            up_writer.write(hello)
            back = asyncio.create_task(self._back(up_reader, writer))
            forth = asyncio.create_task(self._forth(reader, up_writer))
            done, pending = await asyncio.wait({back, forth}, return_when=asyncio.FIRST_COMPLETED)
            for task in pending:
                task.cancel()
            await asyncio.gather(*pending, return_exceptions=True)
            for task in done:
                task.result()  # a Refused from the client's side is the connection's end
        finally:
            self.clients.pop(local, None)
            up_writer.close()

    async def _forth(self, reader: asyncio.StreamReader, upstream: asyncio.StreamWriter) -> None:
        """Client -> asyncua, chunk by chunk, each one checked."""
        policy: str | None = None
        while True:
            first_open = policy is None
            chunk = await self._chunk(reader, first=False, what="no OpenSecureChannel",
                                      timeout_s=self.limits.hello_timeout_s if first_open else None)
            kind = chunk[:3]
            if kind == b"OPN":
                asked, start = open_policy(chunk)
                assert self.key is not None
                if asked != NONE_POLICY and open_mode(chunk, start, asked, self.key) != \
                        ua.MessageSecurityMode.SignAndEncrypt:
                    raise Refused(ua.StatusCodes.BadSecurityModeRejected, "a security mode other than SignAndEncrypt")
                if policy is not None and asked != policy:
                    raise Refused(ua.StatusCodes.BadSecurityPolicyRejected, "a renewal under another policy")
                policy = asked
            elif policy is None:
                raise Refused(ua.StatusCodes.BadTcpMessageTypeInvalid, "a message before OpenSecureChannel")
            elif kind == b"MSG" and policy == NONE_POLICY:
                plain_request(chunk)
            upstream.write(chunk)
            await upstream.drain()

    async def _back(self, up_reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """asyncua -> client, as it comes."""
        while data := await up_reader.read(RELAY_BYTES):
            writer.write(data)
            await writer.drain()

    async def _chunk(self, reader: asyncio.StreamReader, *, first: bool, what: str,
                     timeout_s: float | None) -> bytes:
        async def read() -> bytes:
            head = await reader.readexactly(HEADER_BYTES)
            header = chunk_header(head, first=first)
            return head + await reader.readexactly(header.size - HEADER_BYTES)

        if timeout_s is None:
            return await read()
        try:
            return await asyncio.wait_for(read(), timeout_s)
        except TimeoutError:
            raise Refused(ua.StatusCodes.BadTimeout, f"{what} within hello_timeout_s") from None
