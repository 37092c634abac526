"""The page's server: uvicorn on the one address asked for, the guard in front of the application, until SIGTERM
or SIGINT. The socket is bound here first, so that an address in use or not this machine's is a
:class:`WebServerFailed` naming it (exit 1), not a log line of uvicorn's."""

from __future__ import annotations

import logging
import socket

import uvicorn

from monoguide.daemon.errors import WebServerFailed
from monoguide.daemon.web._app import build_app
from monoguide.daemon.web._guard import Guard
from monoguide.daemon.web._options import WebOptions, is_loopback
from monoguide.daemon.web._source import StateSource

log = logging.getLogger("monoguide.web")
LOOPBACK_NAMES = {"localhost", "127.0.0.1", "::1"}
MAX_CONNECTIONS = 64  # beyond: 503 at once, the cell PC's memory stays the page's
KEEP_ALIVE_S = 5


def serve(options: WebOptions) -> None:
    """Serve the page until stopped (SIGTERM, SIGINT): returns then."""
    source = StateSource(options.state_dir, options.config)
    try:
        listening = _bind(options.host, options.port)
        # loopback: only this machine's names in the Host header (a web page elsewhere cannot rebind its name
        # onto 127.0.0.1 and read the cell); beyond loopback credentials guard it and any name the plant uses goes
        hosts = {options.host.lower(), *LOOPBACK_NAMES} if is_loopback(options.host) else None
        app = Guard(build_app(source), options.credentials, hosts)
        config = uvicorn.Config(app, log_level="warning", access_log=False, server_header=False, lifespan="off",
                                limit_concurrency=MAX_CONNECTIONS, timeout_keep_alive=KEEP_ALIVE_S,
                                ssl_certfile=options.certfile, ssl_keyfile=options.keyfile)
        for warning in options.warnings:
            log.warning("%s", warning)
        log.info("operator page on %s (state directory %s, read-only%s)", options.url, options.state_dir,
                 ", credentials required" if options.credentials else "")
        server = uvicorn.Server(config)
        server.run(sockets=[listening])
        listening.close()
    finally:
        source.close()


def _bind(host: str, port: int) -> socket.socket:
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as exc:
        raise WebServerFailed(f"--bind {host}:{port}: {exc.strerror}") from None
    family, kind, proto, _, address = infos[0]
    listening = socket.socket(family, kind, proto)
    listening.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        listening.bind(address)
        listening.listen(128)
    except OSError as exc:
        listening.close()
        raise WebServerFailed(f"cannot listen on {host}:{port}: {exc.strerror}") from None
    listening.set_inheritable(True)
    return listening
