"""Who may look at the page when it listens beyond loopback: users with scrypt password hashes, or bearer tokens.

The users file has one ``name:scrypt$n$r$p$salt$hash`` line per person (``monoguide web --hash-password`` makes
the part after the colon; salt and hash in base64), ``#`` comments and blank lines allowed; the browser asks for
name and password (HTTP Basic). A token file has one token per line, sent as ``Authorization: Bearer TOKEN`` (a
script, a plant system). scrypt is the standard library's (``hashlib.scrypt``, RFC 7914); a good Basic header is
remembered (its SHA-256, at most ``REMEMBERED`` of them) so that the page's images and its polling do not pay the
KDF on every request. Every comparison takes the same time whatever matched (``hmac.compare_digest``), and every
failed Basic header costs one scrypt check whatever failed: a name that is no user's, or a header that is no
name and password, is checked against a stand-in hash of the dearest parameters the users file has. After
:data:`FAILURES` failed headers within :data:`WINDOW_S` from one client address, :meth:`Credentials.waiting` says
so and the page answers 429 without a check until the oldest failure has left the window (a header proved before
still passes).
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import hmac
import os
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

from monoguide.daemon.config import read_config_text
from monoguide.daemon.errors import WebCredentialsInvalid
from monoguide.drivers.errors import ConfigError

SCRYPT_N, SCRYPT_R, SCRYPT_P = 2**14, 8, 1  # ~50 ms and 16 MB a check: the usual interactive cost
REMEMBERED = 64
FAILURES, WINDOW_S = 5, 60.0  # failed logins of one client address within the window before it must wait
CLIENTS_KEPT = 4096  # addresses whose failures are remembered, the oldest forgotten first


def hash_password(password: str, salt: bytes | None = None) -> str:
    """``scrypt$n$r$p$salt$hash`` for ``password`` (a fresh 16-byte salt unless given)."""
    salt = os.urandom(16) if salt is None else salt
    digest = hashlib.scrypt(password.encode(), salt=salt, n=SCRYPT_N, r=SCRYPT_R, p=SCRYPT_P, dklen=32)
    return f"scrypt${SCRYPT_N}${SCRYPT_R}${SCRYPT_P}${_b64(salt)}${_b64(digest)}"


@dataclass
class Credentials:
    """Who may look: user name -> password hash, and bearer tokens (either may be empty, not both)."""

    users: dict[str, str] = field(default_factory=dict)
    tokens: tuple[str, ...] = ()
    _remembered: dict[bytes, str] = field(default_factory=dict, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    _failed: dict[str, deque[float]] = field(default_factory=dict, repr=False)  # client address -> failure times
    _stand_in: str = field(default="", repr=False)

    @classmethod
    def load(cls, users_file: Path | None, token_file: Path | None) -> Credentials | None:
        """The credentials of the files given (None when neither is)."""
        if users_file is None and token_file is None:
            return None
        users = _read_users(users_file) if users_file is not None else {}
        tokens = _read_tokens(token_file) if token_file is not None else ()
        return cls(users, tokens)

    def waiting(self, client: str | None) -> bool:
        """Whether ``client`` (an address) has had :data:`FAILURES` failed logins within :data:`WINDOW_S`."""
        with self._lock:
            times = self._failed.get(client or "")
            while times and time.monotonic() - times[0] > WINDOW_S:
                times.popleft()
            return times is not None and len(times) >= FAILURES

    def remembered(self, authorization: str) -> bool:
        """Whether ``authorization`` is a Basic header proved before (it passes while its address waits)."""
        value = authorization.partition(" ")[2].strip()
        with self._lock:
            return hashlib.sha256(value.encode()).digest() in self._remembered

    def allows(self, authorization: str | None, client: str | None = None) -> str | None:
        """The name of whom ``authorization`` (the request's header) proves, else None; a wrong header counts as a
        failed login of ``client`` (the request's address)."""
        name = self._proves(authorization)
        if name is None and authorization:
            with self._lock:
                if client not in self._failed and len(self._failed) >= CLIENTS_KEPT:
                    self._failed.pop(next(iter(self._failed)))
                self._failed.setdefault(client or "", deque(maxlen=FAILURES)).append(time.monotonic())
        return name

    def _proves(self, authorization: str | None) -> str | None:
        if not authorization:
            return None
        scheme, _, value = authorization.partition(" ")
        scheme, value = scheme.lower(), value.strip()
        if scheme == "bearer" and self.tokens:
            matched = [hmac.compare_digest(value.encode(), t.encode()) for t in self.tokens]
            return "token" if any(matched) else None
        if scheme == "basic" and self.users:
            return self._basic(value)
        return None

    def _basic(self, value: str) -> str | None:
        key = hashlib.sha256(value.encode()).digest()
        with self._lock:
            if key in self._remembered:
                return self._remembered[key]
        try:
            name, _, password = base64.b64decode(value, validate=True).decode().partition(":")
        except (binascii.Error, UnicodeDecodeError):
            name, password = "", ""
        stored = self.users.get(name)
        if not _verify(password, stored or self._dearest()) or stored is None:
            return None
        with self._lock:
            if len(self._remembered) >= REMEMBERED:
                self._remembered.pop(next(iter(self._remembered)))
            self._remembered[key] = name
        return name


    def _dearest(self) -> str:
        """The stand-in hash an unknown name is checked against: of the dearest scrypt parameters of the users."""
        if not self._stand_in:
            n, r, p = max(tuple(int(v) for v in stored.split("$")[1:4]) for stored in self.users.values())
            salt = os.urandom(16)
            digest = hashlib.scrypt(os.urandom(16), salt=salt, n=n, r=r, p=p, maxmem=256 * 2**20, dklen=32)
            self._stand_in = f"scrypt${n}${r}${p}${_b64(salt)}${_b64(digest)}"
        return self._stand_in


# --- private ------------------------------------------------------------------------------------


def _verify(password: str, stored: str) -> bool:
    _, n, r, p, salt, digest = stored.split("$")
    got = hashlib.scrypt(password.encode(), salt=base64.b64decode(salt), n=int(n), r=int(r), p=int(p),
                         maxmem=256 * 2**20, dklen=len(base64.b64decode(digest)))
    return hmac.compare_digest(got, base64.b64decode(digest))


def _read_users(path: Path) -> dict[str, str]:
    users: dict[str, str] = {}
    for number, line in _lines(path):
        name, colon, stored = line.partition(":")
        parts = stored.split("$")
        where = f"users file {path} line {number}"
        if not colon or not name or len(parts) != 6 or parts[0] != "scrypt":
            raise WebCredentialsInvalid(f"{where}: expected NAME:scrypt$n$r$p$salt$hash (monoguide web "
                                        "--hash-password makes the part after the colon)")
        try:
            n, r, p = (int(v) for v in parts[1:4])
            base64.b64decode(parts[4], validate=True), base64.b64decode(parts[5], validate=True)
        except (ValueError, binascii.Error) as exc:
            raise WebCredentialsInvalid(f"{where}: {exc}") from None
        if n < 2**10 or n & (n - 1) or not 1 <= r <= 32 or not 1 <= p <= 16:
            raise WebCredentialsInvalid(f"{where}: scrypt parameters n={n} r={r} p={p} out of range (n a power of "
                                        "two >= 1024, r 1..32, p 1..16)")
        if name in users:
            raise WebCredentialsInvalid(f"{where}: user {name!r} given twice")
        users[name] = stored
    if not users:
        raise WebCredentialsInvalid(f"users file {path}: no user in it")
    return users


def _read_tokens(path: Path) -> tuple[str, ...]:
    tokens = []
    for number, line in _lines(path):
        if len(line) < 16 or any(c.isspace() for c in line):
            raise WebCredentialsInvalid(f"token file {path} line {number}: a token is at least 16 characters "
                                        "without spaces")
        tokens.append(line)
    if not tokens:
        raise WebCredentialsInvalid(f"token file {path}: no token in it")
    return tuple(tokens)


def _lines(path: Path) -> list[tuple[int, str]]:
    try:  # a regular file under the size limit, as every file monoguide reads (a FIFO would hang the page)
        text = read_config_text(path, "credentials file")
    except ConfigError as exc:
        raise WebCredentialsInvalid(f"{path}: cannot read: {exc.message}") from None
    return [(n, line.strip()) for n, line in enumerate(text.splitlines(), 1)
            if line.strip() and not line.strip().startswith("#")]


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode()
