"""The cell's alarms as OPC UA conditions (OPC 10000-9): ``AlarmConditionType`` instances under
``VisionSystem/Alarms``, their state variables kept as the service's status says, an event on every change, emitted
by the ``Server`` object (where alarm clients subscribe) and kept for ``ConditionRefresh`` while it is retained.

| alarm | active while | acknowledged by |
|---|---|---|
| ``CalibrationSuspect`` | the residual's alarm is latched (``CALIBRATION_SUSPECT``) | ``monoguide health --clear`` |
| ``CalibrationTrend`` | the residual's trend is above its warning level, not latched | itself: its trend falls |
| ``Fault`` | the service is in ``fault`` | the PLC's FAULT_RESET (the service leaves ``fault``) |
| ``DeviceLost_<name>`` | the running service holds no connection to the device | itself: the device is back |

An alarm is acknowledged only by what ends its cause, never from OPC UA: Acknowledge, Confirm, Enable, Disable and
AddComment are refused (``BadUserAccessDenied``, ``_access``). Active is therefore always unacknowledged, and an
alarm goes back to normal (inactive, acknowledged, not retained) in one event. While no service runs the alarms
keep the state they had: nothing is known then.
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass

from asyncua import Node, Server, ua
from asyncua.common.instantiate_util import instantiate
from asyncua.server.event_generator import EventGenerator

from monoguide.daemon.plant._address_space import VisionSystemNodes, device_nodes
from monoguide.daemon.plant._cell_view import CellReading


@dataclass(frozen=True)
class AlarmKind:
    severity: int  # OPC UA's 1-1000
    condition_class: int  # an ObjectIds ...ConditionClassType


CALIBRATION_SUSPECT = AlarmKind(800, ua.ObjectIds.MaintenanceConditionClassType)
CALIBRATION_TREND = AlarmKind(400, ua.ObjectIds.MaintenanceConditionClassType)
FAULT = AlarmKind(900, ua.ObjectIds.SystemConditionClassType)
DEVICE_LOST = AlarmKind(700, ua.ObjectIds.SystemConditionClassType)


class Alarm:
    """One condition: its node, its event, and whether it is active."""

    def __init__(self, server: Server, node: Node, source: Node, source_name: str, kind: AlarmKind,
                 generator: EventGenerator) -> None:
        self.server, self.node, self.source, self.kind, self.generator = server, node, source, kind, generator
        self.name = node.nodeid.Identifier.rsplit(".", 1)[-1]
        self.source_name = source_name
        self.active: bool | None = None  # None: never shown

    async def show(self, active: bool, message: str) -> None:
        if active == self.active:
            return
        self.active = active
        now = datetime.datetime.now(datetime.UTC)
        states = {
            "EnabledState": ua.LocalizedText("Enabled"), "EnabledState/Id": True,
            "ActiveState": ua.LocalizedText("Active" if active else "Inactive"), "ActiveState/Id": active,
            "AckedState": ua.LocalizedText("Unacknowledged" if active else "Acknowledged"), "AckedState/Id": not active,
            "Retain": active,
        }
        event = self.generator.event
        for name, value in states.items():
            setattr(event, name, value)
        event.NodeId = self.node.nodeid  # the ConditionId: what ConditionRefresh and a client's alarm list key on
        event.ConditionName = self.name
        event.ConditionClassId = ua.NodeId(self.kind.condition_class)
        event.SourceNode, event.SourceName = self.source.nodeid, self.source_name
        event.Severity = event.LastSeverity = self.kind.severity
        event.Quality = ua.StatusCode(ua.StatusCodes.Good)
        event.BranchId = ua.NodeId()
        event.ClientUserId = "monoguide"
        for name, value in states.items():
            await self._write(name, value)
        await self._write("Retain", active)
        await self._write("Severity", ua.Variant(self.kind.severity, ua.VariantType.UInt16))
        await self._write("Message", ua.LocalizedText(message))
        await self.generator.trigger(time_attr=now, message=message)

    async def _write(self, path: str, value: object) -> None:
        node = self.node
        for part in path.split("/"):
            node = await node.get_child(f"0:{part}")
        variant = value if isinstance(value, ua.Variant) else ua.Variant(value)
        await self.server.write_attribute_value(node.nodeid, ua.DataValue(variant))


class Alarms:
    """The cell's alarms; :meth:`show` after every reading."""

    def __init__(self, server: Server, nodes: VisionSystemNodes) -> None:
        self.server, self.nodes = server, nodes
        self.alarms: dict[str, Alarm] = {}

    async def start(self) -> None:
        vs = self.nodes.vision_system
        for name, kind in (("CalibrationSuspect", CALIBRATION_SUSPECT), ("CalibrationTrend", CALIBRATION_TREND),
                           ("Fault", FAULT)):
            await self._alarm(name, kind, vs, "VisionSystem")

    async def show(self, reading: CellReading) -> None:
        status = reading.status
        if status is None or not reading.running:
            return
        health = status.calibration_health if isinstance(status.calibration_health, dict) else {}
        latched = bool(health.get("latched"))
        await self.alarms["CalibrationSuspect"].show(
            latched, "CALIBRATION_SUSPECT: the calibration's residual alarm is latched; check the cell, then "
            "monoguide health --clear" if latched else "the calibration's residual alarm was cleared")
        trend = bool(health.get("warning")) and not latched
        await self.alarms["CalibrationTrend"].show(
            trend, "CALIBRATION_WARNING: the residual's trend is above its warning level" if trend
            else "the residual's trend is within its warning level")
        fault = status.state == "fault"
        code = (status.fault or {}).get("code", "") if fault else ""
        await self.alarms["Fault"].show(fault, f"the service is in FAULT: {code}; FAULT_RESET from the PLC" if fault
                                        else "the service left FAULT")
        for name, device in status.devices.items():
            if f"DeviceLost_{name}" not in self.alarms:
                source = await self._device(name)
                await self._alarm(f"DeviceLost_{name}", DEVICE_LOST, source, name)
            error = device.last_error or {}
            await self.alarms[f"DeviceLost_{name}"].show(
                not device.connected, f"device {name} lost: {error.get('code', '')} {error.get('message', '')}".strip()
                if not device.connected else f"device {name} connected")

    async def _device(self, name: str) -> Node:
        await device_nodes(self.nodes, name)
        return self.server.get_node(ua.NodeId(f"{self.nodes.devices_folder.nodeid.Identifier}.{name}",
                                              self.nodes.idx))

    async def _alarm(self, name: str, kind: AlarmKind, source: Node, source_name: str) -> Alarm:
        folder = self.nodes.alarms_folder
        made = await instantiate(folder, self.server.get_node(ua.NodeId(ua.ObjectIds.AlarmConditionType)),
                                 nodeid=ua.NodeId(f"{folder.nodeid.Identifier}.{name}", self.nodes.idx),
                                 bname=ua.QualifiedName(name, self.nodes.idx), instantiate_optional=False)
        node = made[0]
        await source.add_reference(node.nodeid, ua.ObjectIds.HasCondition)
        generator = await self.server.get_event_generator(ua.ObjectIds.AlarmConditionType, ua.ObjectIds.Server)
        alarm = Alarm(self.server, node, source, source_name, kind, generator)
        self.alarms[name] = alarm
        return alarm
