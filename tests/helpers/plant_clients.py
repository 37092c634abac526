"""The real asyncua client against ``monoguide plant``: client application certificates made for a test (trusted by
copying them into the plant's trust list, or not), a connected session with a security policy and an identity,
the result events collected with the time each arrived, and the plant started as its own process."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import resource
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from asyncua import Client, ua
from asyncua.crypto import cert_gen
from asyncua.crypto.security_policies import SecurityPolicyAes256Sha256RsaPss, SecurityPolicyBasic256Sha256
from cryptography import x509
from cryptography.hazmat.primitives import serialization
from cryptography.x509.oid import ExtendedKeyUsageOID

NAMESPACE = "urn:monoguide"  # monoguide's own nodes and the instance's node ids
MACHINE_VISION = "http://opcfoundation.org/UA/MachineVision"
RESULT_READY_EVENT_TYPE = 1024  # the published ResultReadyEventType (namespace MachineVision)
POLICIES = {"Basic256Sha256": SecurityPolicyBasic256Sha256, "Aes256Sha256RsaPss": SecurityPolicyAes256Sha256RsaPss}
START_S = 60.0


@dataclass(frozen=True)
class ClientIdentity:
    certificate: Path
    key: Path
    application_uri: str


def client_identity(folder: Path, name: str) -> ClientIdentity:
    """A self-signed client application certificate and its key, as a plant's SCADA client would make them."""
    folder.mkdir(parents=True, exist_ok=True)
    uri = f"urn:test:{name}"
    key = cert_gen.generate_private_key()
    cert = cert_gen.generate_self_signed_app_certificate(
        key, name, {}, [x509.UniformResourceIdentifier(uri), x509.DNSName(socket.gethostname())],
        [ExtendedKeyUsageOID.CLIENT_AUTH], days=30)
    cert_path, key_path = folder / f"{name}.der", folder / f"{name}-key.pem"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.DER))
    key_path.write_bytes(cert_gen.dump_private_key_as_pem(key))
    return ClientIdentity(cert_path, key_path, uri)


def trust(identity: ClientIdentity, trust_dir: Path) -> None:
    trust_dir.mkdir(parents=True, exist_ok=True)
    (trust_dir / identity.certificate.name).write_bytes(identity.certificate.read_bytes())


async def connected(url: str, identity: ClientIdentity | None, *, user: str | None = None,
                    password: str | None = None, policy: str = "Basic256Sha256",
                    mode: ua.MessageSecurityMode = ua.MessageSecurityMode.SignAndEncrypt,
                    x509_identity: bool = False, timeout_s: float = 10.0, application_uri: str | None = None) -> Client:
    """A connected client (the caller disconnects it); raises what the server refused with. ``application_uri``:
    the one the client says it has (default: its certificate's)."""
    client = Client(url, timeout=timeout_s)
    client.application_uri = application_uri or (identity.application_uri if identity else "urn:test:none")
    if identity is not None:
        await client.set_security(POLICIES[policy], str(identity.certificate), str(identity.key), mode=mode)
        if x509_identity:
            await client.load_client_certificate(str(identity.certificate))
            await client.load_private_key(str(identity.key))
    if user is not None:
        client.set_user(user)
        client.set_password(password or "")
    await client.connect()
    return client


@dataclass
class EventLog:
    """asyncua's subscription handler: each event's fields with its arrival time (Unix s)."""

    events: list[tuple[float, dict[str, Any]]] = field(default_factory=list)
    arrived: asyncio.Event = field(default_factory=asyncio.Event)
    status_changes: list[Any] = field(default_factory=list)

    def event_notification(self, event: Any) -> None:
        self.events.append((time.time(), event.get_event_props_as_fields_dict()))
        self.arrived.set()

    def status_change_notification(self, status: Any) -> None:
        """The server ended the subscription (BadTimeout: its lifetime ran out without a publish request)."""
        self.status_changes.append(status)
        self.arrived.set()

    async def wait_for(self, count: int, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while len(self.events) < count:
            self.arrived.clear()
            left = deadline - time.monotonic()
            if left <= 0 or self.status_changes:
                raise TimeoutError(f"{len(self.events)} of {count} events after {timeout_s} s (status changes: "
                                   f"{self.status_changes})")
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.arrived.wait(), left)


def value(fields: dict[str, Any], name: str) -> Any:
    return fields[name].Value if name in fields else None


async def subscribe_results(client: Client) -> tuple[EventLog, Any]:
    """Subscribed to the result events of VisionSystem: monoguide's subtype of the published ResultReadyEventType,
    with both's fields."""
    idx = await client.get_namespace_index(NAMESPACE)
    vision_system = client.get_node(ua.NodeId("VisionSystem", idx))
    event_type = await result_event_type(client)
    log = EventLog()
    subscription = await client.create_subscription(50, log)
    await subscription.subscribe_events(vision_system, event_type)
    return log, subscription


async def result_event_type(client: Client) -> Any:
    idx, mv = await client.get_namespace_index(NAMESPACE), await client.get_namespace_index(MACHINE_VISION)
    published = client.get_node(ua.NodeId(RESULT_READY_EVENT_TYPE, mv))
    return await published.get_child(f"{idx}:MonoguideResultReadyEventType")


async def load_machine_vision_types(client: Client) -> int:
    """The published structures as classes (ResultDataType, ...), for decoding; returns MachineVision's namespace
    index. asyncua's client makes none for a structure that adds no field to its supertype (and so none for
    ResultDataType, which has three of them): the plant's own registration fills them in, then the rest loads."""
    from monoguide.daemon.plant._nodeset import register_structure_subtypes

    mv = await client.get_namespace_index(MACHINE_VISION)
    quiet = logging.getLogger("asyncua.common.structures104")
    level = quiet.level
    quiet.setLevel(logging.CRITICAL)  # the first load says, per structure it cannot make yet, what it misses
    try:
        await client.load_data_type_definitions()
        await register_structure_subtypes(client, mv)
        await client.load_data_type_definitions(overwrite_existing=True)
    finally:
        quiet.setLevel(level)
    return mv


def start_plant(config: Path, state_dir: Path, plant_config: Path | None, log: Path,
                timeout_s: float = START_S, nofile: int | None = None) -> tuple[subprocess.Popen[str], str]:
    """``monoguide plant`` as its own process (its log into ``log``); returns it and its ``plant: ...`` line once it
    serves. ``nofile``: its soft limit of open files (as a unit's ``LimitNOFILE`` sets it). Stop it with
    ``helpers.sim_processes.stop``."""
    command = [sys.executable, "-m", "monoguide.daemon.cli", "plant", "--config", str(config), "--state-dir",
               str(state_dir)]
    if plant_config is not None:
        command += ["--plant-config", str(plant_config)]
    with log.open("w") as err:
        process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=err, stdin=subprocess.DEVNULL, text=True,
                                   preexec_fn=None if nofile is None else lambda: _limit_files(nofile))
    assert process.stdout is not None
    watchdog = threading.Timer(timeout_s, process.kill)
    watchdog.start()
    try:
        line = process.stdout.readline()
    finally:
        watchdog.cancel()
    if not line.startswith("plant: "):
        process.kill()
        process.wait(10)
        pytest.fail(f"monoguide plant did not start: {line!r} {log.read_text()[-3000:]}")
    return process, line.strip()


def _limit_files(nofile: int) -> None:
    hard = resource.getrlimit(resource.RLIMIT_NOFILE)[1]
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(nofile, hard), hard))
