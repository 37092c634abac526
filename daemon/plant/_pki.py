"""The OPC UA server's own certificate and key, created on first start in the PKI directory (``<state dir>/plant``
unless ``[plant] pki_dir`` says otherwise): a self-signed application instance certificate (RSA 2048, SHA-256,
10 years) whose subject alternative names carry the application URI and the host it is offered on; the key is
written with mode 0600 in a directory of mode 0700, never readable by anyone but the service's user.

A plant's OPC UA client trusts the server by this certificate: its thumbprint (SHA-1, as OPC UA clients show it)
is logged at every start (:func:`thumbprint`).
"""

from __future__ import annotations

import datetime
import hashlib
import ipaddress
import os
import socket
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import serialization
from cryptography.x509.oid import ExtendedKeyUsageOID

from monoguide.daemon.errors import PlantCertificateError

CERTIFICATE_FILE = "server-certificate.der"
KEY_FILE = "server-key.pem"
VALID_DAYS = 3650


@dataclass(frozen=True)
class ServerIdentity:
    certificate: Path
    private_key: Path
    created: bool  # made on this start
    thumbprint_sha1: str
    thumbprint_sha256: str


def server_identity(pki_dir: Path, application_uri: str, host: str) -> ServerIdentity:
    """The server's certificate and key in ``pki_dir``, made (with the directory) when they are not there yet."""
    certificate, key = pki_dir / CERTIFICATE_FILE, pki_dir / KEY_FILE
    created = False
    try:
        if not certificate.exists() or not key.exists():
            _create(pki_dir, certificate, key, application_uri, host)
            created = True
        if key.stat().st_mode & 0o077:
            raise PlantCertificateError(f"{key}: readable by others (mode {key.stat().st_mode & 0o777:o}); the "
                                        "server's key must be mode 0600 — chmod 600 it, or delete both files to "
                                        "make new ones (every client must then trust the new certificate)")
        der = certificate.read_bytes()
        x509.load_der_x509_certificate(der)
    except OSError as exc:
        raise PlantCertificateError(f"{pki_dir}: cannot create or read the server's certificate: {exc}") from exc
    except ValueError as exc:
        raise PlantCertificateError(f"{certificate}: not a DER certificate ({exc}); delete it and {KEY_FILE} "
                                    "to make new ones") from exc
    return ServerIdentity(certificate, key, created, thumbprint(der, "sha1"), thumbprint(der, "sha256"))


def thumbprint(der: bytes, algorithm: str = "sha1") -> str:
    """``AB:CD:...``: the hash of the DER certificate, as OPC UA clients show a certificate's thumbprint."""
    return ":".join(f"{b:02X}" for b in hashlib.new(algorithm, der).digest())


# --- private ------------------------------------------------------------------------------------


def _create(pki_dir: Path, certificate: Path, key_path: Path, application_uri: str, host: str) -> None:
    from asyncua.crypto import cert_gen  # only on the first start

    pki_dir.mkdir(parents=True, exist_ok=True, mode=0o700)
    os.chmod(pki_dir, 0o700)
    key = cert_gen.generate_private_key()
    names: list[x509.GeneralName] = [x509.UniformResourceIdentifier(application_uri),
                                     x509.DNSName(socket.gethostname())]
    try:
        names.append(x509.IPAddress(ipaddress.ip_address(host)))
    except ValueError:
        names.append(x509.DNSName(host))
    cert = cert_gen.generate_self_signed_app_certificate(
        key, f"monoguide plant {socket.gethostname()}", {"organizationName": "monoguide"}, names,
        [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH], days=VALID_DAYS)
    pem = cert_gen.dump_private_key_as_pem(key)
    descriptor = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(descriptor, "wb") as out:
        out.write(pem)
    certificate.write_bytes(cert.public_bytes(serialization.Encoding.DER))


def not_valid_now(cert: x509.Certificate) -> bool:
    now = datetime.datetime.now(datetime.UTC)
    return not cert.not_valid_before_utc <= now <= cert.not_valid_after_utc
