"""Who may open a session on the OPC UA server, and what a session may do: read, browse and subscribe, nothing else.

- **The channel**: Sign & Encrypt only (Basic256Sha256, Aes256Sha256RsaPss); the ``None`` policy is never offered.
- **The client application**: its certificate must be in the trust list — the DER or PEM files of
  ``[plant] trusted_certificates`` (``<pki dir>/trusted``), pinned by their SHA-256 thumbprint, valid today — and
  the ApplicationUri the client gives must be its certificate's (``BadCertificateUriInvalid``). It is checked when
  the session is created and again, as the channel's certificate, when it is activated. The folder is read again at
  every session, so a certificate dropped in or removed counts from the next login on.
- **The identity**: a user of ``[[plant.users]]`` with the password its PBKDF2 hash was made from, or an X.509
  identity token whose certificate is in the trust list; anonymous only where ``[plant] anonymous = true`` (a
  loopback address only, `_settings`). A failed password check costs the same whether the user exists or not
  (:meth:`PlantUsers.spend`); which identities a session may present at all, over which channel, is ``_sessions``'.
- **What it may do** (:class:`ReadOnlyRules`): the services of reading, browsing, subscribing, reading history and
  calling — a Call only of the methods that read (``_sessions``). Write, HistoryUpdate and the node-management
  services are refused with ``BadUserAccessDenied`` whatever the node, and no variable is writable (``AccessLevel``
  CurrentRead).
"""

from __future__ import annotations

import hashlib
import hmac
import logging
import secrets
from pathlib import Path
from typing import Any

from asyncua import ua
from asyncua.common.utils import ServiceError
from asyncua.crypto.permission_rules import PermissionRuleset, User, UserRole
from cryptography import x509
from cryptography.hazmat.primitives.serialization import Encoding

from monoguide.daemon.plant._passwords import ITERATIONS, hash_password, iterations, verify_password
from monoguide.daemon.plant._pki import not_valid_now
from monoguide.daemon.plant._settings import PlantUser

log = logging.getLogger(__name__)

TOLD_MOST = 256  # untrusted certificates named in the log, each once; beyond, only counted (`_refusals`)

# the requests a session may make: reading, browsing, subscribing (OPC 10000-4 service sets), never writing
ALLOWED_REQUESTS = frozenset(ua.NodeId(getattr(ua.ObjectIds, f"{name}Request_Encoding_DefaultBinary")) for name in (
    "CreateSession", "CloseSession", "ActivateSession", "Read", "Browse", "BrowseNext", "GetEndpoints", "FindServers",
    "TranslateBrowsePathsToNodeIds", "RegisterNodes", "UnregisterNodes", "HistoryRead", "Call", "CreateSubscription",
    "ModifySubscription", "DeleteSubscriptions", "TransferSubscriptions", "SetPublishingMode", "Publish",
    "Republish", "CreateMonitoredItems", "ModifyMonitoredItems", "DeleteMonitoredItems", "SetMonitoringMode",
    "CloseSecureChannel",
))


class TrustList:
    """The client certificates the server trusts: every ``*.der``, ``*.pem``, ``*.crt`` file of one folder."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self._told: set[str] = set()  # the untrusted certificates already named in the log (each once)

    def subject(self, der: bytes) -> str | None:
        """The common name of the trusted, currently valid certificate ``der``; None when it is not trusted."""
        pinned = self._load()
        cert = pinned.get(hashlib.sha256(der).hexdigest())
        if cert is None or not_valid_now(cert):
            return None
        names = cert.subject.get_attributes_for_oid(x509.NameOID.COMMON_NAME)
        return str(names[0].value) if names else "certificate"

    async def validate(self, cert: x509.Certificate, description: ua.ApplicationDescription) -> None:
        """asyncua's certificate validator (at CreateSession): ``BadCertificateUntrusted`` unless trusted,
        ``BadCertificateUriInvalid`` unless the client's ApplicationUri is one of its certificate's URIs."""
        der = cert.public_bytes(Encoding.DER)
        if self.subject(der) is None:
            thumbprint = hashlib.sha256(der).hexdigest()
            if thumbprint not in self._told and len(self._told) < TOLD_MOST:
                self._told.add(thumbprint)
                log.warning("OPC UA: client certificate %r (SHA-256 %s) is not in the trust list %s: copy it there "
                            "to let that client in", cert.subject.rfc4514_string(), thumbprint, self.folder)
            raise ServiceError(ua.StatusCodes.BadCertificateUntrusted)
        if description.ApplicationUri not in application_uris(cert):
            raise ServiceError(ua.StatusCodes.BadCertificateUriInvalid)

    def _load(self) -> dict[str, x509.Certificate]:
        found: dict[str, x509.Certificate] = {}
        if not self.folder.is_dir():
            return found
        for path in sorted(self.folder.iterdir()):
            if path.suffix.lower() not in (".der", ".pem", ".crt"):
                continue
            try:
                data = path.read_bytes()
                cert = (x509.load_pem_x509_certificate(data) if data.lstrip().startswith(b"-----")
                        else x509.load_der_x509_certificate(data))
            except (OSError, ValueError) as exc:
                log.warning("OPC UA trust list: %s skipped: not a certificate (%s)", path, exc)
                continue
            found[hashlib.sha256(cert.public_bytes(Encoding.DER)).hexdigest()] = cert
        return found


def application_uris(cert: x509.Certificate) -> list[str]:
    """The URIs of the certificate's subject alternative name (an application instance certificate has one)."""
    try:
        names = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return []
    return names.get_values_for_type(x509.UniformResourceIdentifier)


class PlantUsers:
    """asyncua's user manager: a session's identity checked against ``[[plant.users]]`` and the trust list."""

    def __init__(self, users: tuple[PlantUser, ...], trust: TrustList) -> None:
        self.users = {user.name: user for user in users}
        self.trust = trust
        # every failed password check costs one PBKDF2 of the most iterations any user's hash has: a name that is
        # no user's is checked against a stand-in hash, a user's hash with fewer iterations is topped up
        self.iterations = max((iterations(u.password_hash) for u in users), default=ITERATIONS)
        self._stand_in = hash_password(secrets.token_hex(16), iterations=self.iterations)
        # user -> HMAC of the password last verified for it, under a key of this process only: the same client
        # logging in again (20 sessions of one SCADA user) costs an HMAC, not the PBKDF2 that holds up the server's
        # loop for ~0.3 s; a wrong password always costs the full PBKDF2
        self._key = secrets.token_bytes(32)
        self._verified: dict[str, bytes] = {}

    def get_user(self, iserver: Any, username: str | None = None, password: str | None = None,
                 certificate: Any = None) -> User | None:
        """``certificate``: the channel's (user name and anonymous tokens) or the X.509 token's certificate."""
        if certificate is None or self.trust.subject(bytes(certificate)) is None:
            return None  # refused before any name is looked at: nothing to tell about the users
        if username is None:  # an X.509 identity (trusted above), or anonymous where the settings allow it
            return User(role=UserRole.User, name=self.trust.subject(bytes(certificate)))
        user = self.users.get(username)
        if user is None or password is None:
            self.spend()
            return None
        if not self._password_ok(user, password):
            self.spend(self.iterations - iterations(user.password_hash))
            return None
        return User(role=UserRole.User, name=username)

    def spend(self, rounds: int | None = None) -> None:
        """The cost of a failed password check, for a failure that had none to make (``rounds`` PBKDF2 iterations;
        default: a whole check)."""
        if rounds is None:
            verify_password("", self._stand_in)
        elif rounds > 0:
            hashlib.pbkdf2_hmac("sha256", b"", b"monoguide", rounds)

    def _password_ok(self, user: PlantUser, password: str) -> bool:
        seal = hmac.new(self._key, f"{user.password_hash}\0{password}".encode(), hashlib.sha256).digest()
        if hmac.compare_digest(self._verified.get(user.name, b""), seal):
            return True
        if not verify_password(password, user.password_hash):
            return False
        self._verified[user.name] = seal
        return True


class ReadOnlyRules(PermissionRuleset):
    """Every session may read, browse, subscribe and call (the session checks which method); no request that writes is
    let through."""

    def check_validity(self, user: User, action_type_id: ua.NodeId, body: Any) -> bool:
        return action_type_id in ALLOWED_REQUESTS
