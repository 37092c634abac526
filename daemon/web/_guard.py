"""The rules every request passes before a page sees it, as one ASGI middleware: read-only (GET and HEAD, nothing
else), a bounded request line, the Host header one of this server's names (no DNS rebinding onto loopback),
credentials when they are configured; and the headers every answer carries (a Content-Security-Policy without
inline script or style, no framing, no sniffing, no referrer).
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any

from monoguide.daemon.web._auth import Credentials

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
App = Callable[[Scope, Receive, Send], Awaitable[None]]

MAX_PATH, MAX_QUERY = 1024, 1024  # bytes: every page's URL is far shorter
CSP = ("default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self'; connect-src 'self'; "
       "base-uri 'none'; form-action 'self'; frame-ancestors 'none'")
HEADERS = [
    (b"content-security-policy", CSP.encode()),
    (b"x-content-type-options", b"nosniff"),
    (b"x-frame-options", b"DENY"),
    (b"referrer-policy", b"no-referrer"),
    (b"cross-origin-opener-policy", b"same-origin"),
    (b"cross-origin-resource-policy", b"same-origin"),
]


class Guard:
    """Wraps the page's app; ``hosts``: the Host names accepted (None: any, for a wildcard address)."""

    def __init__(self, app: App, credentials: Credentials | None, hosts: set[str] | None) -> None:
        self.app, self.credentials, self.hosts = app, credentials, hosts

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":  # lifespan: the server's own start and stop
            await self.app(scope, receive, send)
            return

        async def with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                message["headers"] = [*message.get("headers", []), *HEADERS]
            await send(message)

        refusal = self._refusal(scope)
        if refusal is not None:
            status, text, extra = refusal
            await with_headers({"type": "http.response.start", "status": status,
                                "headers": [(b"content-type", b"text/plain; charset=utf-8"), *extra]})
            await send({"type": "http.response.body", "body": text.encode()})
            return
        await self.app(scope, receive, with_headers)

    def _refusal(self, scope: Scope) -> tuple[int, str, list[tuple[bytes, bytes]]] | None:
        if scope["method"] not in ("GET", "HEAD"):
            return 405, "405 the operator page is read-only: GET and HEAD only\n", [(b"allow", b"GET, HEAD")]
        if len(scope.get("raw_path") or scope["path"].encode()) > MAX_PATH or len(scope["query_string"]) > MAX_QUERY:
            return 414, "414 request line too long\n", []
        headers = dict(scope["headers"])
        if self.hosts is not None and _host_name(headers.get(b"host", b"").decode("latin-1")) not in self.hosts:
            return 421, "421 not a name of this server\n", []
        if self.credentials is not None:
            authorization = headers.get(b"authorization", b"").decode("latin-1")
            client = scope["client"][0] if scope.get("client") else None
            if authorization and self.credentials.waiting(client) and not self.credentials.remembered(authorization):
                return 429, "429 too many failed logins from this address: wait a minute\n", [
                    (b"retry-after", b"60")]
            if self.credentials.allows(authorization, client) is None:
                challenge = b'Basic realm="monoguide", charset="UTF-8"' if self.credentials.users else b"Bearer"
                return 401, "401 credentials needed\n", [(b"www-authenticate", challenge)]
        return None


def _host_name(host: str) -> str:
    """``name:port`` or ``[v6]:port`` -> the name, lower case."""
    host = host.strip().lower()
    if host.startswith("["):
        return host[1:].partition("]")[0]
    return host.rpartition(":")[0] if host.count(":") == 1 else host
