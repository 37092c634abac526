"""``monoguide web``: the operator page, its own process reading the service's state directory (docs/operator-page.md).

Exit status (``daemon/cli/_policy.py``): 0 stopped by SIGTERM or SIGINT; 2 a usage error (a bad ``--bind``, a
non-loopback address without credentials: ``WEB_AUTH_REQUIRED``, an unreadable users file, a bad config);
1 the server could not listen (``WEB_SERVER_FAILED``).
"""

from __future__ import annotations

import getpass
import logging
import sys
from pathlib import Path
from typing import Annotated

import typer

from monoguide.daemon.cli._policy import fail, reporting_errors
from monoguide.daemon.errors import WebCredentialsInvalid
from monoguide.daemon.service import STATE_DIR_HELP, state_dir
from monoguide.daemon.web import DEFAULT_BIND, hash_password, serve, web_options

LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


def web(
    state_dir_option: Annotated[str | None, typer.Option("--state-dir", help=STATE_DIR_HELP)] = None,
    config: Annotated[Path | None, typer.Option(
        "--config", help="The cell config: hole names, rims, search regions, the calibration.")] = None,
    bind: Annotated[str, typer.Option("--bind", help="HOST:PORT to listen on; beyond loopback --users or "
                                                     "--token-file is required.")] = DEFAULT_BIND,
    users: Annotated[Path | None, typer.Option(
        "--users", help="A file of NAME:scrypt$... lines (see --hash-password): the browser asks for them.")] = None,
    token_file: Annotated[Path | None, typer.Option(
        "--token-file", help="A file of bearer tokens, one a line (Authorization: Bearer TOKEN).")] = None,
    certfile: Annotated[Path | None, typer.Option("--certfile", help="Serve HTTPS with this certificate.")] = None,
    keyfile: Annotated[Path | None, typer.Option("--keyfile", help="... and its private key (PEM).")] = None,
    hash_password_flag: Annotated[bool, typer.Option(
        "--hash-password", help="Read a password (twice) and print its scrypt hash for a --users line; serve "
                                "nothing.")] = False,
) -> None:
    """Serve the operator page: the cell's state now, its cycles with their images, trends, calibration.

    Read-only: it reads the journal and status.json of the state directory and changes nothing. Exit status:
    0 stopped by SIGTERM or SIGINT, 2 a usage error, 1 the server could not listen."""
    if hash_password_flag:
        _print_hash()
        return
    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT, stream=sys.stderr, force=True)
    options = reporting_errors(lambda: web_options(state_dir(state_dir_option), config, bind, users, token_file,
                                                   certfile, keyfile))
    reporting_errors(lambda: serve(options))


def _print_hash() -> None:
    if sys.stdin.isatty():
        first, second = getpass.getpass("password: "), getpass.getpass("again: ")
    else:
        first = second = sys.stdin.readline().rstrip("\n")
    if not first or first != second:
        fail(WebCredentialsInvalid("the two passwords differ, or none was given"))
    sys.stdout.write(hash_password(first) + "\n")
