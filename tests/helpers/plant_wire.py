"""Clients that do what a well-behaved OPC UA client never does, against ``monoguide plant``: what an attacker on the
plant network sends. Each probe returns what the server answered (an ERR message's status, a service result), so a
test asserts the answer whatever stack sent the request; the probes here use asyncua's client for the services
(its public ``uaclient`` requests, which skip the checks its ``Client.connect`` makes) and plain sockets with
messages built from asyncua's public ``ua`` types for the bytes. A second stack adds its own probes of the same
names and answers.
"""

from __future__ import annotations

import contextlib
import socket
import struct
import time
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlparse

from asyncua import Client, ua
from asyncua.common.connection import SecureConnection, TransportLimits
from asyncua.crypto.security_policies import SecurityPolicy, SecurityPolicyBasic256Sha256
from asyncua.ua.ua_binary import struct_to_binary, uatcp_to_binary
from asyncua.ua.uaerrors import UaError
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import padding, rsa

from helpers.plant_clients import NAMESPACE, ClientIdentity

RSA_SHA256 = "http://www.w3.org/2001/04/xmldsig-more#rsa-sha256"


@dataclass(frozen=True)
class Answer:
    """What a probe got: ``refused`` the status code's name the server refused with (None: not refused),
    ``step`` where (``channel``, ``session``, ``activation``, ``read``), ``value`` what a read returned,
    ``seconds`` how long the refusal took to arrive."""

    refused: str | None
    step: str
    value: object = None
    seconds: float = 0.0


def hello(url: str) -> bytes:
    return uatcp_to_binary(ua.MessageType.Hello, ua.Hello(EndpointUrl=url, ReceiveBufferSize=65535,
                                                         SendBufferSize=65535, MaxMessageSize=0, MaxChunkCount=0))


def open_request(policy: type[SecurityPolicy], mode: ua.MessageSecurityMode, identity: ClientIdentity,
                 server_certificate: Path) -> bytes:
    """An OpenSecureChannel under ``policy`` in ``mode``, signed and encrypted as that policy says (asyncua's public
    ``SecureConnection`` and policy classes make the chunk)."""
    server = x509.load_der_x509_certificate(server_certificate.read_bytes())
    mine = x509.load_der_x509_certificate(identity.certificate.read_bytes())
    key = serialization.load_pem_private_key(identity.key.read_bytes(), password=None)
    secure = policy(server, mine, key, mode)
    request = ua.OpenSecureChannelRequest(Parameters=ua.OpenSecureChannelParameters(
        RequestType=ua.SecurityTokenRequestType.Issue, SecurityMode=mode, RequestedLifetime=600_000,
        ClientNonce=b"\x02" * max(32, secure.secure_channel_nonce_length)))
    connection = SecureConnection(secure, TransportLimits(65535, 65535, 0, 0))
    return connection.message_to_binary(struct_to_binary(request), message_type=ua.MessageType.SecureOpen,
                                        request_id=1)


def err_status(data: bytes) -> int | None:
    """The status code of the ERR message among the messages ``data`` holds (an ACK may come first); None when
    there is none."""
    at = 0
    while len(data) - at >= 12:
        kind, size = data[at:at + 3], struct.unpack("<I", data[at + 4:at + 8])[0]
        if kind == b"ERR":
            return struct.unpack("<I", data[at + 8:at + 12])[0]
        if size < 8:
            return None
        at += size
    return None


def status_name(code: int | None) -> str | None:
    return None if code is None else ua.StatusCode(code).name


def exchange(url: str, data: bytes, *, source: str | None = None, timeout_s: float = 3.0) -> tuple[bytes, bool]:
    """Send ``data`` on a new connection (from ``source``, an address of this host); what came back within
    ``timeout_s``, and whether the server closed the connection by then."""
    target = urlparse(url)
    with socket.create_connection((target.hostname, target.port), timeout=timeout_s,
                                  source_address=(source, 0) if source else None) as sock:
        sock.sendall(data)
        got, deadline = b"", time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            sock.settimeout(max(0.01, deadline - time.monotonic()))
            try:
                chunk = sock.recv(65536)
            except TimeoutError:
                return got, False
            except ConnectionResetError:
                return got, True
            if not chunk:
                return got, True
            got += chunk
        return got, False


def idle_connections(url: str, count: int, source: str) -> list[socket.socket]:
    """``count`` connections from ``source`` that send nothing (the caller closes them)."""
    target = urlparse(url)
    sockets = []
    for _ in range(count):
        sock = socket.socket()
        sock.bind((source, 0))
        sock.setblocking(False)
        with contextlib.suppress(BlockingIOError):
            sock.connect((target.hostname, target.port))
        sockets.append(sock)
    return sockets


async def session_over_plain_channel(url: str, identity: ClientIdentity) -> Answer:
    """A channel of the None policy, CreateSession with the trusted client's certificate (the endpoint check of
    asyncua's ``Client.create_session`` skipped), ActivateSession with an X.509 identity token of that certificate,
    then a read of the result counter."""
    client = Client(url, timeout=5)
    step = "channel"
    started = time.monotonic()
    try:
        await client.connect_socket()
        await client.send_hello()
        await client.open_secure_channel()
        step = "session"
        created = await client.uaclient.create_session(_session_parameters(url, identity))
        step = "activation"
        token = ua.X509IdentityToken(PolicyId="certificate", CertificateData=identity.certificate.read_bytes())
        await client.uaclient.activate_session(ua.ActivateSessionParameters(
            UserIdentityToken=token, UserTokenSignature=_signature(identity, created)))
        step = "read"
        return Answer(None, step, await _result_counter(client))
    except (UaError, OSError, TimeoutError, ConnectionError) as error:
        return Answer(_refusal(error), step, seconds=time.monotonic() - started)
    finally:
        with contextlib.suppress(Exception):
            client.disconnect_socket()


async def nameless_user_token(url: str, identity: ClientIdentity, password: str) -> Answer:
    """Over Sign & Encrypt with the trusted client's certificate: ActivateSession with a user name token whose
    UserName is null and ``password``, then a read."""
    client = Client(url, timeout=5)
    client.application_uri = identity.application_uri
    await client.set_security(SecurityPolicyBasic256Sha256, str(identity.certificate), str(identity.key),
                              mode=ua.MessageSecurityMode.SignAndEncrypt)
    step = "channel"
    try:
        await client.connect_socket()
        await client.send_hello()
        await client.open_secure_channel()
        step = "session"
        created = await client.create_session()
        step = "activation"
        policy = client.security_policy
        signed = policy.asymmetric_cryptography.signature(policy.peer_certificate + created.ServerNonce)
        proof = ua.SignatureData(policy.AsymmetricSignatureURI, signed)
        token = ua.UserNameIdentityToken(PolicyId="username", UserName=None, Password=password.encode())
        await client.uaclient.activate_session(ua.ActivateSessionParameters(ClientSignature=proof,
                                                                            UserIdentityToken=token))
        step = "read"
        return Answer(None, step, await _result_counter(client))
    except (UaError, OSError, TimeoutError, ConnectionError) as error:
        return Answer(_refusal(error), step)
    finally:
        with contextlib.suppress(Exception):
            await client.close_session()
        with contextlib.suppress(Exception):
            client.disconnect_socket()


async def timed_refusal(connect: object) -> Answer:
    """``await connect`` (a coroutine that connects and must be refused): the refusal's name and how long it took."""
    started = time.monotonic()
    try:
        client = await connect  # type: ignore[misc]
    except (UaError, OSError, TimeoutError, ConnectionError) as error:
        return Answer(_refusal(error), "connect", seconds=time.monotonic() - started)
    await client.disconnect()
    return Answer(None, "connect", seconds=time.monotonic() - started)


# --- private ------------------------------------------------------------------------------------


def _session_parameters(url: str, identity: ClientIdentity) -> ua.CreateSessionParameters:
    description = ua.ApplicationDescription(ApplicationUri=identity.application_uri, ApplicationName=ua.LocalizedText(
        "probe"), ApplicationType=ua.ApplicationType.Client)
    return ua.CreateSessionParameters(ClientDescription=description, EndpointUrl=url, SessionName="probe",
                                      ClientNonce=b"\x01" * 32, ClientCertificate=identity.certificate.read_bytes(),
                                      RequestedSessionTimeout=60_000)


def _signature(identity: ClientIdentity, created: ua.CreateSessionResult) -> ua.SignatureData:
    """The X.509 token's proof: the server's certificate and nonce signed with the client's key (RSA-SHA256)."""
    key = serialization.load_pem_private_key(identity.key.read_bytes(), password=None)
    assert isinstance(key, rsa.RSAPrivateKey)
    # over a channel without security a server may leave its certificate out of the answer: its endpoints have it
    server = created.ServerCertificate or next(e.ServerCertificate for e in created.ServerEndpoints)
    signed = key.sign(server + (created.ServerNonce or b""), padding.PKCS1v15(), hashes.SHA256())
    return ua.SignatureData(RSA_SHA256, signed)


async def _result_counter(client: Client) -> object:
    idx = await client.get_namespace_index(NAMESPACE)
    read = ua.ReadParameters(NodesToRead=[ua.ReadValueId(NodeId=ua.NodeId("VisionSystem.Service.CycleCounter", idx),
                                                             AttributeId=ua.AttributeIds.Value)])
    values = await client.uaclient.read(read)
    return values[0].Value.Value


def _refusal(error: BaseException) -> str:
    """A status code's name (``BadUserAccessDenied``), or what ended the wait (``TimeoutError``, ...)."""
    return type(error).__name__


def node_probe(probe: str, url: str, identity: ClientIdentity, user: str, password: str,
               timeout_s: float = 60.0) -> Answer:
    """A probe of the second stack (node-opcua's client, tests/helpers/plant_node/probe.mjs): ``results`` (bind by
    the published browse names, read Result01's JobId, GetResultById; refused for an untrusted certificate) and
    ``wrong-password``. Its answer in the shape of this module's."""
    import json
    import shutil
    import subprocess

    from cryptography.hazmat.primitives.serialization import Encoding

    from helpers.plant_npm import TOOLS, npm_tools

    folder = npm_tools()
    pem = identity.certificate.with_suffix(".pem")
    pem.write_bytes(x509.load_der_x509_certificate(identity.certificate.read_bytes()).public_bytes(Encoding.PEM))
    script = shutil.copy(TOOLS / "probe.mjs", folder / "probe.mjs")  # beside node_modules: ES modules resolve there
    done = subprocess.run(["node", str(script), probe, url, str(pem), str(identity.key), user, password],
                          cwd=folder, capture_output=True, text=True, timeout=timeout_s,
                          env={"PATH": "/usr/local/bin:/usr/bin:/bin", "HOME": str(folder)})
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    assert lines, f"node probe {probe}: no answer ({done.returncode}): {done.stdout[-2000:]} {done.stderr[-2000:]}"
    said = json.loads(lines[-1])
    return Answer(said["refused"], said["step"], said["value"])
