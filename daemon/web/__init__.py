"""The operator page, ``monoguide web``: the cell in a browser — the service's state now, every cycle with its
images and what was found, trends, calibration — served by a process of its own that only reads the state
directory (docs/operator-page.md).

The pages' facts (``_now``, ``_cycles``, ``_cycle`` with ``_overlay``, ``_trends``, ``_calibration``) come from
one reader of the state directory (``_source``); ``_app`` routes them, ``_guard`` holds the rules every request
passes (read-only, bounded, credentials), ``_server`` runs uvicorn. The server's libraries load only when the
command runs.
"""

from __future__ import annotations

from monoguide.daemon.web._auth import Credentials, hash_password
from monoguide.daemon.web._options import DEFAULT_BIND, WebOptions, is_loopback, parse_bind, web_options

__all__ = ["DEFAULT_BIND", "Credentials", "WebOptions", "hash_password", "is_loopback", "parse_bind", "serve",
           "web_options"]


def serve(options: WebOptions) -> None:
    """Serve the page until SIGTERM or SIGINT (``_server.serve``)."""
    from monoguide.daemon.web._server import serve as run

    run(options)
