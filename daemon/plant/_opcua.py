"""The OPC UA server of ``monoguide plant``: asyncua's server with only Sign & Encrypt endpoints, the trust list
and the users of ``_access``, the sessions of ``_sessions``, behind the relay of ``_front`` (asyncua itself listens
on an ephemeral port of 127.0.0.1), and the ``VisionSystem`` of ``_address_space`` kept up to date from what the
:class:`~monoguide.daemon.plant._cell_view.CellView` reads.
"""

from __future__ import annotations

import logging
import socket
import time
from collections import deque
from pathlib import Path

from asyncua import Server, ua
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric import rsa

from monoguide.daemon.errors import PlantCertificateError, PlantListenFailed
from monoguide.daemon.plant._access import PlantUsers, ReadOnlyRules, TrustList
from monoguide.daemon.plant._address_space import (
    CellDescription,
    VisionSystemNodes,
    bad,
    build_address_space,
    device_nodes,
)
from monoguide.daemon.plant._cell_view import CellReading, health_level
from monoguide.daemon.plant._front import Front
from monoguide.daemon.plant._pki import ServerIdentity, server_identity
from monoguide.daemon.plant._refusals import Refusals
from monoguide.daemon.plant._result_fields import RESULT_FIELDS, data_value, timestamp, variant
from monoguide.daemon.plant._results import CycleResult
from monoguide.daemon.plant._sessions import PlantServer
from monoguide.daemon.plant._settings import PlantSettings
from monoguide.daemon.plant._states import vision_state

log = logging.getLogger(__name__)

SECURITY_POLICIES = (ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
                     ua.SecurityPolicyType.Aes256Sha256RsaPss_SignAndEncrypt)
ENDPOINT_PATH = "monoguide"
UPSTREAM_HOST = "127.0.0.1"  # where asyncua listens, on a port the system picks: only the relay connects there


def endpoint_url(host: str, port: int) -> str:
    return f"opc.tcp://{f'[{host}]' if ':' in host else host}:{port}/{ENDPOINT_PATH}"


class PlantOpcUa:
    """The server and the nodes it writes; :meth:`start` listens, :meth:`stop` closes it."""

    def __init__(self, settings: PlantSettings, state_dir: Path, cell: CellDescription, refusals: Refusals) -> None:
        self.settings, self.state_dir, self.cell = settings, state_dir, cell
        self.url = endpoint_url(settings.opcua_host, settings.opcua_port)
        self.application_uri = f"urn:monoguide:plant:{socket.gethostname()}"
        self.trust = TrustList(settings.trust_dir(state_dir))
        self.front = Front(settings.opcua_host, settings.opcua_port, settings.limits, refusals)
        self.server = Server(iserver=PlantServer(PlantUsers(settings.users, self.trust), self.front, settings.limits,
                                                 refusals))
        self.nodes: VisionSystemNodes | None = None
        self.newest: deque[CycleResult] = deque(maxlen=settings.last_results)
        self._event = None
        self._shown: dict[str, object] = {}  # what was last written, so an unchanged value is not written again

    async def start(self) -> ServerIdentity:
        s = self.settings
        identity = server_identity(s.pki(self.state_dir), self.application_uri, s.opcua_host)
        server = self.server
        await server.init()
        server.set_endpoint(self.url)
        server.set_server_name(f"monoguide plant {self.cell.name}")
        await server.set_application_uri(self.application_uri)
        server.product_uri = "urn:monoguide"
        server.manufacturer_name = "monoguide"
        server.allow_remote_admin(False)
        server.set_security_policy(list(SECURITY_POLICIES), permission_ruleset=ReadOnlyRules())
        tokens: list[type] = [ua.UserNameIdentityToken, ua.X509IdentityToken]
        if s.anonymous:
            tokens.append(ua.AnonymousIdentityToken)
        server.set_identity_tokens(tokens)
        await server.load_certificate(str(identity.certificate), format="der")
        await server.load_private_key(str(identity.private_key), format="pem")
        server.set_certificate_validator(self.trust.validate)  # type: ignore[arg-type]
        server.socket_address = (UPSTREAM_HOST, 0)
        server.set_match_discovery_client_ip(False)  # endpoints name the plant's address, not the relay's socket
        self.nodes = await build_address_space(server, self.cell)
        self._event = await server.get_event_generator(self.nodes.event_type, self.nodes.vision_system)
        try:
            await server.start()
        except OSError as exc:
            raise PlantListenFailed(f"OPC UA {UPSTREAM_HOST} (the server behind {self.url}): cannot listen: "
                                    f"{exc}") from exc
        assert server.bserver is not None
        await self.front.start((UPSTREAM_HOST, server.bserver.port), _private_key(identity))
        return identity

    async def stop(self) -> None:
        await self.front.stop()
        if self.server.bserver is not None:
            await self.server.stop()

    async def show(self, reading: CellReading) -> None:
        """The state, the service's and devices' variables and the newest results; an event per new result."""
        nodes = self.nodes
        assert nodes is not None and self._event is not None
        status = reading.status
        state = vision_state(status.state if status else "stopped", reading.running)
        await self._set(nodes.state, ua.DataValue(ua.Variant(ua.LocalizedText(state.top),
                                                             ua.VariantType.LocalizedText)))
        await self._set(nodes.state_id, ua.DataValue(ua.Variant(nodes.state_nodes[state.top], ua.VariantType.NodeId)))
        if state.automatic is None:
            await self._set(nodes.automatic, bad(ua.StatusCodes.BadStateNotActive))
            await self._set(nodes.automatic_id, bad(ua.StatusCodes.BadStateNotActive))
        else:
            await self._set(nodes.automatic, ua.DataValue(ua.Variant(ua.LocalizedText(state.automatic),
                                                                     ua.VariantType.LocalizedText)))
            await self._set(nodes.automatic_id, ua.DataValue(ua.Variant(nodes.state_nodes[state.automatic],
                                                                        ua.VariantType.NodeId)))
        await self._service(reading)
        for result in reading.results:
            await self.announce(result)
        if reading.results:
            await self._show_results()
        date = self.cell.calibration_date
        if date is not None:
            await self._set(nodes.calibration["CalibrationAge"],
                            ua.DataValue(ua.Variant(float(round(time.time() - date)), ua.VariantType.Double)))
        else:
            await self._set(nodes.calibration["CalibrationAge"], bad(ua.StatusCodes.BadNoDataAvailable))
        level = health_level(reading)
        await self._set(nodes.calibration["HealthLevel"], bad(ua.StatusCodes.BadNoDataAvailable) if level is None
                        else ua.DataValue(ua.Variant(level, ua.VariantType.Double)))

    async def seed(self, newest_first: list[CycleResult]) -> None:
        """The results the journal held at start (newest first), shown without events."""
        for result in reversed(newest_first):
            self.newest.appendleft(result)
        await self._show_results()

    async def announce(self, result: CycleResult) -> None:
        """One ResultReadyEventType event for ``result``; it becomes Result01."""
        assert self._event is not None
        event = self._event.event
        for f in RESULT_FIELDS:
            setattr(event, f.name, variant(f, result, self.cell.context).Value)
        event.Severity = 100 if result.ok else 500
        message = f"cycle {result.cycle} {result.status}" + (f" {result.error_code}" if result.error_code else "")
        await self._event.trigger(time_attr=timestamp(result.committed_at), message=message)
        self.newest.appendleft(result)

    # --- private ------------------------------------------------------------------------------------

    async def _show_results(self) -> None:
        nodes = self.nodes
        assert nodes is not None
        for slot, variables in enumerate(nodes.results):
            result = self.newest[slot] if slot < len(self.newest) else None
            for f in RESULT_FIELDS:
                await self.server.write_attribute_value(variables[f.name].nodeid,
                                                        data_value(f, result, self.cell.context))
        if self.newest:
            await self._set(nodes.last_result_id, ua.DataValue(ua.Variant(self.newest[0].cycle, ua.VariantType.UInt64)))

    async def _service(self, reading: CellReading) -> None:
        nodes = self.nodes
        assert nodes is not None
        status = reading.status
        v = ua.VariantType
        values = {
            "State": ua.Variant(status.state if status else "not running", v.String),
            "Running": ua.Variant(reading.running, v.Boolean),
            "Since": ua.Variant(timestamp(status.since), v.DateTime) if status else None,
            "Fault": ua.Variant((status.fault or {}).get("code", "") if status else "", v.String),
            "CycleCounter": ua.Variant(reading.counter, v.UInt64) if reading.counter is not None else None,
            "JournalBytes": ua.Variant(reading.journal_bytes, v.UInt64),
        }
        for name, value in values.items():
            await self._set(nodes.service[name], bad(ua.StatusCodes.BadNoDataAvailable) if value is None
                            else ua.DataValue(value))
        for name, device in (status.devices if status else {}).items():
            variables = await device_nodes(nodes, name)
            error = device.last_error or {}
            await self._set(variables["Connected"], ua.DataValue(ua.Variant(device.connected and reading.running,
                                                                            v.Boolean)))
            await self._set(variables["LastErrorCode"], ua.DataValue(ua.Variant(str(error.get("code", "")), v.String)))
            await self._set(variables["LastErrorMessage"],
                            ua.DataValue(ua.Variant(str(error.get("message", "")), v.String)))

    async def _set(self, node: object, value: ua.DataValue, *, force: bool = False) -> None:
        """Write ``value`` unless it is what the node shows already (a data change only when something changed)."""
        nodeid = node.nodeid  # type: ignore[attr-defined]
        key = nodeid.to_string()
        shown = (value.Value, value.StatusCode)
        if not force and self._shown.get(key) == shown:
            return
        self._shown[key] = shown
        await self.server.write_attribute_value(nodeid, value)


def _private_key(identity: ServerIdentity) -> rsa.RSAPrivateKey:
    try:
        key = serialization.load_pem_private_key(identity.private_key.read_bytes(), password=None)
    except (OSError, ValueError) as exc:
        raise PlantCertificateError(f"{identity.private_key}: cannot read the server's key: {exc}") from exc
    if not isinstance(key, rsa.RSAPrivateKey):
        raise PlantCertificateError(f"{identity.private_key}: not an RSA key (OPC UA's policies need one)")
    return key
