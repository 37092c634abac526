"""The OPC UA server of ``monoguide plant``: asyncua's server with only Sign & Encrypt endpoints, the trust list
and the users of ``_access``, the sessions of ``_sessions``, behind the relay of ``_front`` (asyncua itself listens
on an ephemeral port of 127.0.0.1); the published Machine Vision model (``_nodeset``) and its ``VisionSystem``
(``_address_space``) kept up to date from what the :class:`~monoguide.daemon.plant._cell_view.CellView` reads: the
state machines (``_machine_states``), the alarms (``_alarms``), the results, their methods (``_result_access``) and
their history (``_history``).
"""

from __future__ import annotations

import logging
import socket
import time
from collections import deque
from pathlib import Path
from typing import Any

from asyncua import Server, ua
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric import rsa

from monoguide.daemon.errors import PlantCertificateError, PlantListenFailed, PlantNodeSetInvalid
from monoguide.daemon.plant import _nodeset as mv
from monoguide.daemon.plant._access import PlantUsers, ReadOnlyRules, TrustList
from monoguide.daemon.plant._address_space import (
    HISTORY_AND_EVENTS,
    CellDescription,
    VisionSystemNodes,
    bad,
    build_address_space,
    device_nodes,
)
from monoguide.daemon.plant._alarms import Alarms
from monoguide.daemon.plant._cell_view import CellReading, health_level
from monoguide.daemon.plant._front import Front
from monoguide.daemon.plant._history import JournalEventHistory
from monoguide.daemon.plant._journal_reader import JournalReader
from monoguide.daemon.plant._machine_states import VisionStates
from monoguide.daemon.plant._nodeset import load_machine_vision
from monoguide.daemon.plant._pki import ServerIdentity, server_identity
from monoguide.daemon.plant._refusals import Refusals
from monoguide.daemon.plant._result_access import ResultAccess
from monoguide.daemon.plant._result_data import (
    MACHINE_VISION_FIELDS,
    OWN_FIELDS,
    ResultShapes,
    as_data_value,
    fill_result_event,
    own_variant,
    result_message,
    timestamp,
)
from monoguide.daemon.plant._results import CycleResult
from monoguide.daemon.plant._sessions import PlantServer
from monoguide.daemon.plant._settings import PlantSettings
from monoguide.daemon.plant._states import vision_state

log = logging.getLogger(__name__)

SECURITY_POLICIES = (ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt,
                     ua.SecurityPolicyType.Aes256Sha256RsaPss_SignAndEncrypt)
ENDPOINT_PATH = "monoguide"
UPSTREAM_HOST = "127.0.0.1"  # where asyncua listens, on a port the system picks: only the relay connects there
# SystemStateDescription's State (40100, after SEMI E10): the service's state as the plant's OEE sees it
SYSTEM_STATES = {"Operational": 2, "Preoperational": 2, "Error": 5, "Halted": 6}  # SBY, SBY, UDT, NST
PRODUCTIVE = 1  # PRD: a job is running (SingleExecution)


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
        self.iserver = PlantServer(PlantUsers(settings.users, self.trust), self.front, settings.limits, refusals)
        self.server = Server(iserver=self.iserver)
        self.reader = JournalReader(state_dir)
        self.nodes: VisionSystemNodes | None = None
        self.shapes: ResultShapes | None = None
        self.states: VisionStates | None = None
        self.alarms: Alarms | None = None
        self.newest: deque[CycleResult] = deque(maxlen=settings.last_results)
        self._event: Any = None
        self._shown: dict[str, object] = {}  # what was last written, so an unchanged value is not written again

    async def start(self) -> ServerIdentity:
        s = self.settings
        if s.machine_vision_nodeset is None:
            raise PlantNodeSetInvalid("[plant] machine_vision_nodeset: missing; the OPC UA server is built from the "
                                      "OPC Foundation's Opc.Ua.MachineVision.NodeSet2.xml (docs/opcua.md)")
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
        model = await load_machine_vision(server, s.machine_vision_nodeset)
        nodes = self.nodes = await build_address_space(server, model, self.cell)
        shapes = self.shapes = ResultShapes(model, self.cell.context)
        self._event = await server.get_event_generator(nodes.event_type, nodes.vision_system)
        self.states = VisionStates(server, nodes)
        await self.states.start()
        self.alarms = Alarms(server, nodes)
        await self.alarms.start()
        access = ResultAccess(server, nodes, shapes, self.reader)
        await access.start()
        self.iserver.callable_methods.update(access.method_ids.values())
        server.iserver.history_manager.set_storage(JournalEventHistory(
            self.reader, shapes, (nodes.vision_system.nodeid, ua.NodeId(ua.ObjectIds.Server)), self._event.event))
        # the event generators set VisionSystem's notifier to events only; its history is read too
        await nodes.vision_system.write_attribute(ua.AttributeIds.EventNotifier, ua.DataValue(ua.Variant(
            HISTORY_AND_EVENTS, ua.VariantType.Byte)))
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
        self.reader.close()

    async def show(self, reading: CellReading) -> None:
        """The states, the alarms, the service's and devices' variables and the newest results; an event per new
        result."""
        nodes, states, alarms = self.nodes, self.states, self.alarms
        assert nodes is not None and states is not None and alarms is not None
        status = reading.status
        state = vision_state(status.state if status else "stopped", reading.running)
        await states.show(state, None if reading.counter is None else str(reading.counter + 1))
        system = PRODUCTIVE if state.automatic == "SingleExecution" else SYSTEM_STATES[state.top]
        await self._set(nodes.system_state, ua.DataValue(ua.Variant(nodes.model.make(
            mv.SYSTEM_STATE_DESCRIPTION, State=system, StateDescription=status.state if status else "not running"))))
        await self._service(reading)
        await alarms.show(reading)
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
        """One ResultReadyEventType event (monoguide's subtype) for ``result``; it becomes Result01."""
        assert self._event is not None and self.shapes is not None
        fill_result_event(self._event.event, result, self.shapes)
        await self._event.trigger(time_attr=timestamp(result.committed_at), message=result_message(result))
        self.newest.appendleft(result)

    # --- private ------------------------------------------------------------------------------------

    async def _show_results(self) -> None:
        nodes, shapes = self.nodes, self.shapes
        assert nodes is not None and shapes is not None
        write = self.server.write_attribute_value
        for slot, (variable, children) in enumerate(nodes.results):
            result = self.newest[slot] if slot < len(self.newest) else None
            if result is None:
                await write(variable.nodeid, bad(ua.StatusCodes.BadNoDataAvailable))
                for child in children.values():
                    await write(child.nodeid, bad(ua.StatusCodes.BadNoDataAvailable))
                continue
            await write(variable.nodeid, ua.DataValue(ua.Variant(shapes.data(result))))
            fields = shapes.fields(result)
            for name in MACHINE_VISION_FIELDS:
                await write(children[name].nodeid, as_data_value(fields[name]))
            for f in OWN_FIELDS:
                await write(children[f.name].nodeid, as_data_value(own_variant(f, result)))

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

    async def _set(self, node: Any, value: ua.DataValue) -> None:
        """Write ``value`` unless it is what the node shows already (a data change only when something changed)."""
        nodeid = node.nodeid
        key = nodeid.to_string()
        shown = (value.Value, value.StatusCode)
        if self._shown.get(key) == shown:
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
