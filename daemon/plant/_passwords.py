"""Password hashes for the ``[[plant.users]]`` of the plant file: PBKDF2-HMAC-SHA256 (standard library), stored as
``pbkdf2_sha256$<iterations>$<salt, base64>$<hash, base64>`` — never the password itself.

``monoguide plant --hash-password`` prints one for a password read from standard input.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import secrets

SCHEME = "pbkdf2_sha256"
ITERATIONS = 600_000  # OWASP's figure for PBKDF2-HMAC-SHA256 (2023); a login takes ~0.3 s on the cell PC
MIN_ITERATIONS = 100_000


def hash_password(password: str, *, iterations: int = ITERATIONS, salt: bytes | None = None) -> str:
    """The stored form of ``password`` (a new random salt unless one is given)."""
    salt = secrets.token_bytes(16) if salt is None else salt
    digest = hashlib.pbkdf2_hmac("sha256", password.encode("utf-8"), salt, iterations)
    return f"{SCHEME}${iterations}${_b64(salt)}${_b64(digest)}"


def hash_problem(stored: str) -> str | None:
    """Why ``stored`` is not a hash :func:`verify_password` can check; None when it is one."""
    parts = stored.split("$")
    if len(parts) != 4 or parts[0] != SCHEME:
        return f"expected {SCHEME}$<iterations>$<salt>$<hash> (monoguide plant --hash-password prints one)"
    if not parts[1].isdigit() or int(parts[1]) < MIN_ITERATIONS:
        return f"iterations {parts[1]!r}: expected a whole number of at least {MIN_ITERATIONS}"
    try:
        salt, digest = base64.b64decode(parts[2], validate=True), base64.b64decode(parts[3], validate=True)
    except ValueError:
        return "salt or hash is not base64"
    if len(salt) < 8 or len(digest) != 32:
        return "salt shorter than 8 bytes or a hash that is not 32 bytes"
    return None


def iterations(stored: str) -> int:
    """The PBKDF2 iterations of a checked hash (:func:`hash_problem` None)."""
    return int(stored.split("$")[1])


def verify_password(password: str, stored: str) -> bool:
    """Whether ``password`` is the one ``stored`` was made from (a constant-time comparison)."""
    if hash_problem(stored) is not None:
        return False
    _, iterations, salt, digest = stored.split("$")
    found = hashlib.pbkdf2_hmac("sha256", password.encode("utf-8"), base64.b64decode(salt), int(iterations))
    return hmac.compare_digest(found, base64.b64decode(digest))


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode("ascii")
