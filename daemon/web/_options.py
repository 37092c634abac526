"""How ``monoguide web`` is asked to serve: the state directory, the cell config, the address, who may look.

The rule of the address: loopback (``127.0.0.0/8``, ``::1``, ``localhost``) serves anyone on this machine; any
other address needs credentials (:class:`WebAuthRequired` otherwise, exit 2, nothing served), and without a
certificate it warns that they travel in clear text (put it behind a TLS reverse proxy, docs/operator-page.md).
"""

from __future__ import annotations

import ipaddress
from dataclasses import dataclass, field
from pathlib import Path

from monoguide.daemon.errors import WebAuthRequired, WebConfigError
from monoguide.daemon.web._auth import Credentials

DEFAULT_BIND = "127.0.0.1:8080"


@dataclass(frozen=True)
class WebOptions:
    state_dir: Path
    config: Path | None = None
    host: str = "127.0.0.1"
    port: int = 8080
    credentials: Credentials | None = None
    certfile: Path | None = None
    keyfile: Path | None = None
    warnings: tuple[str, ...] = field(default=())

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{'https' if self.certfile else 'http'}://{host}:{self.port}/"


def web_options(state_dir: Path, config: Path | None, bind: str, users_file: Path | None, token_file: Path | None,
                certfile: Path | None, keyfile: Path | None) -> WebOptions:
    """The options checked: the address parsed, the credentials read, the loopback rule kept."""
    host, port = parse_bind(bind)
    credentials = Credentials.load(users_file, token_file)
    if (certfile is None) != (keyfile is None):
        raise WebConfigError("--certfile and --keyfile go together (the certificate and its private key)")
    for given in (certfile, keyfile):
        if given is not None and not Path(given).is_file():
            raise WebConfigError(f"{given}: no such file")
    warnings = []
    if not is_loopback(host):
        if credentials is None:
            raise WebAuthRequired(f"--bind {bind}: not a loopback address, so anyone on the network could read the "
                                  "cell's page; give --users FILE (name:scrypt hash lines, monoguide web "
                                  "--hash-password) or --token-file FILE, or bind 127.0.0.1 behind a reverse proxy")
        if certfile is None:
            warnings.append(f"serving {host} without TLS: passwords and tokens cross the network in clear text; give "
                            "--certfile/--keyfile or put a TLS reverse proxy in front")
    return WebOptions(Path(state_dir), config, host, port, credentials, certfile, keyfile, tuple(warnings))


def parse_bind(bind: str) -> tuple[str, int]:
    """``HOST:PORT``, ``[V6]:PORT`` -> (host, port)."""
    text = bind.strip()
    if text.startswith("["):
        host, _, rest = text[1:].partition("]")
        port_text = rest[1:] if rest.startswith(":") else ""
    else:
        host, _, port_text = text.rpartition(":")
    if not host or not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
        raise WebConfigError(f"--bind {bind!r}: expected HOST:PORT (127.0.0.1:8080, [::1]:8080), a port 1-65535")
    return host, int(port_text)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
