"""OPC UA TCP as the plant's front door reads it (OPC 10000-6, 7.1 and 6.7): each chunk's 8-byte header, the
Hello, the OpenSecureChannel's security policy (in clear in its asymmetric header) and its security mode (in its
body, which the server's key decrypts), the service a request on an unsecured channel asks for, and the ERR message
that refuses a connection. Bytes in, findings out; no sockets here (``_front`` has them).

Each check raises :class:`Refused` with the status code the ERR message carries and a short reason for the log.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from asyncua import ua
from asyncua.common.utils import Buffer, NotEnoughData
from asyncua.ua.ua_binary import nodeid_from_binary, struct_from_binary, uatcp_to_binary
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.asymmetric import padding, rsa

HEADER_BYTES = 8
MAX_CHUNK_BYTES = 65535  # the server's receive buffer (asyncua's TransportLimits), said in its Acknowledge
HELLO_MAX_BYTES = 8 + 24 + 4096  # the five numbers and an endpoint URL of at most 4096 bytes (Part 6: the limit)
NONE_POLICY = "http://opcfoundation.org/UA/SecurityPolicy#None"
# the policies served (asyncua's URIs) -> the OAEP hash of their asymmetric encryption (Part 7's profiles)
POLICIES: dict[str, hashes.HashAlgorithm] = {
    "http://opcfoundation.org/UA/SecurityPolicy#Basic256Sha256": hashes.SHA1(),
    "http://opcfoundation.org/UA/SecurityPolicy#Aes256_Sha256_RsaPss": hashes.SHA256(),
}
# what a channel without security may ask for: discovery, nothing that opens a session (Part 4, 5.4)
DISCOVERY_REQUESTS = frozenset(getattr(ua.ObjectIds, f"{name}Request_Encoding_DefaultBinary") for name in (
    "GetEndpoints", "FindServers", "FindServersOnNetwork"))
_CLIENT_TYPES = (b"HEL", b"OPN", b"MSG", b"CLO")
_CHUNK_TYPES = (b"F", b"C", b"A")
_OPN_BLOCKS = 4  # the mode lies within the first bytes of the body: at most this many RSA blocks are decrypted


class Refused(Exception):
    """A connection refused: ``status`` (a ``ua.StatusCodes`` value) goes into the ERR message, ``reason`` to the
    log (a fixed phrase: the log counts refusals by it)."""

    def __init__(self, status: int, reason: str) -> None:
        super().__init__(reason)
        self.status = status
        self.reason = reason


@dataclass(frozen=True)
class ChunkHeader:
    kind: bytes  # HEL, OPN, MSG, CLO
    chunk: bytes  # F (final), C (one more follows), A (abort)
    size: int  # of the whole chunk, header included


def chunk_header(data: bytes, *, first: bool) -> ChunkHeader:
    """The header of a chunk from a client (its first 8 bytes); ``first``: the connection's first, which must be a
    Hello."""
    kind, chunk, size = struct.unpack("<3scI", data[:HEADER_BYTES])
    if kind not in _CLIENT_TYPES or chunk not in _CHUNK_TYPES:
        raise Refused(ua.StatusCodes.BadTcpMessageTypeInvalid, "not an OPC UA TCP message")
    if first and kind != b"HEL":
        raise Refused(ua.StatusCodes.BadTcpMessageTypeInvalid, "not a Hello first")
    if not first and kind == b"HEL":
        raise Refused(ua.StatusCodes.BadTcpMessageTypeInvalid, "a second Hello")
    least = HEADER_BYTES + (24 if kind == b"HEL" else 4)  # five numbers and a string length; a channel id
    most = HELLO_MAX_BYTES if kind == b"HEL" else MAX_CHUNK_BYTES
    if size < least:
        raise Refused(ua.StatusCodes.BadTcpMessageTypeInvalid, "a message shorter than its header")
    if size > most:
        raise Refused(ua.StatusCodes.BadTcpMessageTooLarge, "a message larger than the server's buffer")
    return ChunkHeader(kind, chunk, size)


def check_hello(chunk: bytes) -> None:
    try:
        hello = struct_from_binary(ua.Hello, Buffer(chunk, HEADER_BYTES))
    except (NotEnoughData, UnicodeDecodeError, struct.error):
        raise Refused(ua.StatusCodes.BadTcpMessageTypeInvalid, "a malformed Hello") from None
    if hello.ReceiveBufferSize < 8192 or hello.SendBufferSize < 8192:  # Part 6: at least 8192 bytes
        raise Refused(ua.StatusCodes.BadTcpMessageTypeInvalid, "a Hello with buffers under 8192 bytes")


def open_policy(chunk: bytes) -> tuple[str, int]:
    """The security policy URI an OpenSecureChannel chunk asks for, and where its encrypted part starts."""
    if chunk[3:4] != b"F":
        raise Refused(ua.StatusCodes.BadTcpMessageTypeInvalid, "an OpenSecureChannel in more than one chunk")
    buffer = Buffer(chunk, HEADER_BYTES + 4)  # the secure channel id follows the header
    try:
        header = struct_from_binary(ua.AsymmetricAlgorithmHeader, buffer)
    except (NotEnoughData, UnicodeDecodeError, struct.error):
        raise Refused(ua.StatusCodes.BadTcpMessageTypeInvalid, "a malformed OpenSecureChannel") from None
    policy = header.SecurityPolicyURI or ""
    if policy != NONE_POLICY and policy not in POLICIES:
        raise Refused(ua.StatusCodes.BadSecurityPolicyRejected, "a security policy not served")
    return policy, len(chunk) - len(buffer)


def open_mode(chunk: bytes, start: int, policy: str, key: rsa.RSAPrivateKey) -> ua.MessageSecurityMode:
    """The security mode an OpenSecureChannel under ``policy`` (not None) asks for: its first blocks decrypted with
    the server's ``key``. asyncua checks the rest (the signature, the nonce); this only reads the mode."""
    block = key.key_size // 8
    oaep = padding.OAEP(mgf=padding.MGF1(POLICIES[policy]), algorithm=POLICIES[policy], label=None)
    encrypted = chunk[start:]
    if not encrypted or len(encrypted) % block:
        raise Refused(ua.StatusCodes.BadSecurityChecksFailed, "an OpenSecureChannel not encrypted for this server")
    plain = b""
    for at in range(0, min(len(encrypted), _OPN_BLOCKS * block), block):
        try:
            plain += key.decrypt(encrypted[at:at + block], oaep)
        except ValueError:
            raise Refused(ua.StatusCodes.BadSecurityChecksFailed,
                          "an OpenSecureChannel not encrypted for this server") from None
        try:
            request = struct_from_binary(ua.OpenSecureChannelRequest, Buffer(plain, 8))  # after the sequence header
        except (NotEnoughData, UnicodeDecodeError, struct.error):
            continue  # the mode lies in the next block
        return request.Parameters.SecurityMode
    raise Refused(ua.StatusCodes.BadSecurityChecksFailed, "a malformed OpenSecureChannel")


def plain_request(chunk: bytes) -> int:
    """The request type (its binary encoding id) of a message on a channel without security, whose body is
    readable; a chunk of a longer message is refused (discovery requests fit in one)."""
    if chunk[3:4] != b"F":
        raise Refused(ua.StatusCodes.BadSecurityModeInsufficient, "a long request on a channel without security")
    try:
        nodeid = nodeid_from_binary(Buffer(chunk, HEADER_BYTES + 4 + 4 + 8))  # channel id, token id, sequence header
    except (NotEnoughData, UnicodeDecodeError, struct.error):
        raise Refused(ua.StatusCodes.BadDecodingError, "a malformed request") from None
    if nodeid.NamespaceIndex != 0 or not isinstance(nodeid.Identifier, int):
        raise Refused(ua.StatusCodes.BadServiceUnsupported, "an unknown request")
    if nodeid.Identifier not in DISCOVERY_REQUESTS:
        raise Refused(ua.StatusCodes.BadSecurityModeInsufficient, "a session over a channel without security")
    return nodeid.Identifier


def error_message(status: int, reason: str) -> bytes:
    """The ERR message that refuses a connection (Part 6, 7.1.2.5): the server closes it right after."""
    return uatcp_to_binary(ua.MessageType.Error, ua.ErrorMessage(ua.StatusCode(status), reason))
