"""The metrics endpoint's server: asyncio on the plant's own loop, one short exchange per connection.

``GET /metrics`` (or ``HEAD``) answers Prometheus' text format (``Connection: close``); anything else is 404 or 405.
Nothing waits for long: the TLS handshake and the request's headers must arrive within ``[plant]
metrics_timeout_s`` (else the connection is closed: no thread, no socket held), headers beyond 8 KiB are 431, and at
most ``metrics_max_connections`` connections are open at once, ``metrics_max_connections_per_client`` from one
address (503 beyond). With ``[plant.metrics_web] basic_auth_users`` a request needs a good Basic header (401; after
``login_failures`` failed ones within ``login_window_s`` from one address, 429 until the window passes).
"""

from __future__ import annotations

import asyncio
import contextlib

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest

from monoguide.daemon.errors import PlantListenFailed
from monoguide.daemon.plant._listener import Listener
from monoguide.daemon.plant._logins import LoginGate
from monoguide.daemon.plant._metrics_access import BasicAuth, MetricsAccess
from monoguide.daemon.plant._refusals import Refusals
from monoguide.daemon.plant._settings import PlantLimits

HEAD_BYTES = 8192
PATH = "/metrics"


class MetricsEndpoint:
    """:meth:`start` listens (returns the URL), :meth:`stop` closes every connection."""

    def __init__(self, registry: CollectorRegistry, access: MetricsAccess, limits: PlantLimits,
                 refusals: Refusals) -> None:
        self.registry, self.access, self.limits, self.refusals = registry, access, limits, refusals
        self.auth = BasicAuth(access.users) if access.users else None
        self.logins = LoginGate(limits.login_failures, limits.login_window_s)
        self.listener = Listener(limits.metrics_connections, limits.metrics_connections_per_client,
                                 ("metrics_max_connections", "metrics_max_connections_per_client"))

    async def start(self, host: str, port: int) -> str:
        scheme = "https" if self.access.tls else "http"
        tls = self.access.ssl_context()
        try:
            await self.listener.listen(host, port, self._exchange, self._busy, limit=HEAD_BYTES, ssl=tls, backlog=64,
                                       ssl_handshake_timeout=self.limits.metrics_timeout_s if tls else None)
        except OSError as exc:
            raise PlantListenFailed(f"metrics {scheme}://{host}:{port}{PATH}: cannot listen: {exc}") from exc
        return f"{scheme}://{f'[{host}]' if ':' in host else host}:{port}{PATH}"

    async def stop(self) -> None:
        await self.listener.stop()

    # --- private ------------------------------------------------------------------------------------

    async def _busy(self, writer: asyncio.StreamWriter, client: str, reason: str) -> None:
        self.refusals.refuse("metrics", reason, client)
        await self._answer(writer, 503, b"503 too many connections\n")

    async def _exchange(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, client: str) -> None:
        try:
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), self.limits.metrics_timeout_s)
        except TimeoutError:
            self.refusals.refuse("metrics", "no request within metrics_timeout_s", client)
            return
        except asyncio.LimitOverrunError:
            await self._answer(writer, 431, b"431 request headers too large\n")
            return
        lines = head.decode("latin-1").split("\r\n")
        method, _, rest = lines[0].partition(" ")
        path = rest.partition(" ")[0].partition("?")[0]
        headers = {k.strip().lower(): v.strip() for k, _, v in (line.partition(":") for line in lines[1:] if line)}
        if method not in ("GET", "HEAD"):
            await self._answer(writer, 405, b"405 GET or HEAD only\n", [("Allow", "GET, HEAD")])
            return
        if path != PATH:
            await self._answer(writer, 404, b"404 the metrics are at /metrics\n")
            return
        if self.auth is not None and not await self._authorized(headers.get("authorization", ""), client, writer):
            return
        body = generate_latest(self.registry)
        await self._answer(writer, 200, body, [("Content-Type", CONTENT_TYPE_LATEST)], head_only=method == "HEAD")

    async def _authorized(self, authorization: str, client: str, writer: asyncio.StreamWriter) -> bool:
        assert self.auth is not None
        if authorization and self.auth.remembered(authorization) is not None:
            return True
        if self.logins.waiting(client):
            self.refusals.refuse("metrics", "login_failures reached", client)
            await self._answer(writer, 429, b"429 too many failed logins: wait\n",
                               [("Retry-After", f"{self.limits.login_window_s:.0f}")])
            return False
        if await asyncio.to_thread(self.auth.check, authorization) is not None:
            return True
        self.logins.failed(client)
        self.refusals.refuse("metrics", "missing or wrong credentials", client)
        await self._answer(writer, 401, b"401 credentials needed\n",
                           [("WWW-Authenticate", 'Basic realm="monoguide metrics", charset="UTF-8"')])
        return False

    async def _answer(self, writer: asyncio.StreamWriter, status: int, body: bytes,
                      headers: list[tuple[str, str]] | None = None, *, head_only: bool = False) -> None:
        reason = {200: "OK", 401: "Unauthorized", 404: "Not Found", 405: "Method Not Allowed", 429: "Too Many Requests",
                  431: "Request Header Fields Too Large", 503: "Service Unavailable"}[status]
        lines = [f"HTTP/1.1 {status} {reason}", f"Content-Length: {len(body)}", "Connection: close",
                 *(f"{k}: {v}" for k, v in headers or [("Content-Type", "text/plain; charset=utf-8")])]
        writer.write(("\r\n".join(lines) + "\r\n\r\n").encode("latin-1") + (b"" if head_only else body))
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(writer.drain(), self.limits.metrics_timeout_s)
