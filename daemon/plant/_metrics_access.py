"""Who may scrape the metrics: ``[plant.metrics_web]`` of the plant file, in the shape of the Prometheus
exporter-toolkit's web configuration file (the one node_exporter's ``--web.config.file`` reads), as a TOML table::

    [plant.metrics_web.tls_server_config]
    cert_file = "/etc/monoguide/metrics.crt"     # PEM; relative paths are relative to the plant file
    key_file = "/etc/monoguide/metrics.key"

    [plant.metrics_web.basic_auth_users]
    prometheus = "$2y$10$..."                    # bcrypt, as the toolkit takes them (htpasswd -nBC 10 "")

Both or neither may be given on loopback; off loopback both are required (``_settings``). A Basic header is checked
with bcrypt in a worker thread; a good one is remembered (its SHA-256, at most :data:`REMEMBERED`) so that a scrape
every 15 s does not pay bcrypt each time. An unknown user name costs a bcrypt check of the same cost as a known one.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import re
import ssl
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import bcrypt

from monoguide.drivers.errors import ConfigError

REMEMBERED = 16
BCRYPT_BYTES = 72  # bcrypt reads no more of a password; a longer one is refused (as Go's bcrypt refuses it)
BCRYPT = re.compile(r"^\$2[aby]\$(\d\d)\$[./A-Za-z0-9]{53}$")  # the toolkit's accepted form (Go's x/crypto/bcrypt)


@dataclass(frozen=True)
class MetricsAccess:
    """``cert_file`` and ``key_file`` both or neither; ``users``: name -> bcrypt hash (empty: no authentication)."""

    cert_file: Path | None = None
    key_file: Path | None = None
    users: dict[str, str] = field(default_factory=dict)

    @property
    def tls(self) -> bool:
        return self.cert_file is not None

    @property
    def complete(self) -> bool:
        """TLS and basic authentication both: what a non-loopback metrics_host needs."""
        return self.tls and bool(self.users)

    def ssl_context(self) -> ssl.SSLContext | None:
        """The server's TLS context (TLS 1.2 or later); None without ``tls_server_config``. Raises a
        :class:`ConfigError` naming the files when they do not load."""
        if self.cert_file is None or self.key_file is None:
            return None
        context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        context.minimum_version = ssl.TLSVersion.TLSv1_2
        try:
            context.load_cert_chain(self.cert_file, self.key_file)
        except (OSError, ssl.SSLError) as exc:
            raise ConfigError(f"[plant.metrics_web.tls_server_config] cert_file = {str(self.cert_file)!r}, key_file = "
                              f"{str(self.key_file)!r}: cannot load them ({exc})") from None
        return context


class BasicAuth:
    """The check of a request's ``Authorization`` header against :attr:`MetricsAccess.users`."""

    def __init__(self, users: dict[str, str]) -> None:
        self.users = users
        cost = max((int(BCRYPT.match(h).group(1)) for h in users.values() if BCRYPT.match(h)), default=10)
        self._stand_in = bcrypt.hashpw(b"no such user", bcrypt.gensalt(cost))  # what an unknown name is checked against
        self._remembered: dict[bytes, str] = {}

    def remembered(self, authorization: str) -> str | None:
        """The user of a header seen good before (no bcrypt): None when it was not."""
        return self._remembered.get(hashlib.sha256(authorization.encode()).digest())

    def check(self, authorization: str) -> str | None:
        """The user whom ``authorization`` (``Basic base64(name:password)``) proves, else None: one bcrypt check
        whatever is wrong with it (run it in a worker thread)."""
        name, password = _basic(authorization)
        stored = self.users.get(name or "")
        secret = password.encode()
        good = bcrypt.checkpw(secret[:BCRYPT_BYTES], stored.encode() if stored else self._stand_in)
        if not good or stored is None or name is None or len(secret) > BCRYPT_BYTES:
            return None
        key = hashlib.sha256(authorization.encode()).digest()
        if len(self._remembered) >= REMEMBERED:
            self._remembered.pop(next(iter(self._remembered)))
        self._remembered[key] = name
        return name


def read_metrics_access(path: Path, where: str, raw: Any) -> MetricsAccess:
    """``[plant.metrics_web]`` of the plant file ``path``; raises a :class:`ConfigError` naming the key."""
    where = f"{where}.metrics_web"
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: expected a table with tls_server_config and basic_auth_users")
    _known(where, raw, ("tls_server_config", "basic_auth_users"))
    cert_file = key_file = None
    if "tls_server_config" in raw:
        tls = raw["tls_server_config"]
        at = f"{where}.tls_server_config"
        if not isinstance(tls, dict):
            raise ConfigError(f"{at}: expected a table with cert_file and key_file")
        _known(at, tls, ("cert_file", "key_file"))
        cert_file, key_file = (_file(path, at, tls, key) for key in ("cert_file", "key_file"))
    users = raw.get("basic_auth_users", {})
    if not isinstance(users, dict):
        raise ConfigError(f"{where}.basic_auth_users: expected a table of user = \"bcrypt hash\"")
    for name, stored in users.items():
        if not isinstance(stored, str) or not BCRYPT.match(stored):
            raise ConfigError(f"{where}.basic_auth_users.{name}: expected a bcrypt hash ($2y$10$ and 53 characters: "
                              "htpasswd -nBC 10 \"\" or monoguide plant --hash-password --bcrypt), not the password")
    return MetricsAccess(cert_file, key_file, dict(users))


# --- private ------------------------------------------------------------------------------------


def _basic(authorization: str) -> tuple[str | None, str]:
    scheme, _, value = authorization.partition(" ")
    if scheme.lower() != "basic":
        return None, ""
    try:
        name, colon, password = base64.b64decode(value.strip(), validate=True).decode().partition(":")
    except (binascii.Error, UnicodeDecodeError):
        return None, ""
    return (name if colon else None), password


def _known(where: str, table: dict[str, Any], keys: tuple[str, ...]) -> None:
    for key in table:
        if key not in keys:
            raise ConfigError(f"{where}.{key}: unknown key; known: {', '.join(keys)}")


def _file(path: Path, where: str, table: dict[str, Any], key: str) -> Path:
    value = table.get(key)
    if not isinstance(value, str) or not value.strip():
        raise ConfigError(f"{where}.{key} = {value!r}: expected a PEM file (tls_server_config needs cert_file and "
                          "key_file)")
    found = Path(value)
    return found if found.is_absolute() else path.parent / found
