"""The OPC UA address space: the types of OPC 40100-1 that monoguide needs, modelled by hand with the
specification's browse names (the companion NodeSet is not shipped), and the one ``VisionSystem`` object.

```
Objects/VisionSystem                        VisionSystemType
  VisionStateMachine                        VisionStateMachineType (a FiniteStateMachineType)
    CurrentState (+ Id)                     Preoperational | Halted | Error | Operational
    AutomaticModeStateMachine               VisionAutomaticModeStateMachineType
      CurrentState (+ Id)                   Ready | SingleExecution (Bad_StateNotActive outside Operational)
  RecipeManagement/Recipes/Job<n>           RecipeType: RecipeId, JobNumber, PartName, CalibrationDate
  ResultManagement                          LastResultId
    Results/Result01 .. Result<N>           ResultType objects, Result01 the newest: the fields of _result_fields
  Service                                   State, Running, Since, Fault, CycleCounter, JournalBytes
  Devices/<name>                            Connected, LastErrorCode, LastErrorMessage (as status.json names them)
  CalibrationHealth                         CalibrationDate, CalibrationAge, HealthLevel (0 ok, 1 warning, 2 alarm)
```

Every variable is read-only (asyncua's default AccessLevel CurrentRead); the object has no methods. The
``ResultReadyEventType`` event (a BaseEventType with the result's fields as properties) is emitted by
``VisionSystem`` (its EventNotifier: SubscribeToEvents) once per finished cycle.
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass, field
from typing import Any

from asyncua import Node, Server, ua

from monoguide.daemon.plant._result_fields import RESULT_FIELDS, ResultContext, timestamp
from monoguide.daemon.plant._states import AUTOMATIC_STATES, TOP_STATES

NAMESPACE = "urn:monoguide:machinevision"  # the hand-made 40100 types and the instance (not the VDMA namespace)
SERVICE_VARIABLES = (("State", ua.VariantType.String), ("Running", ua.VariantType.Boolean),
                     ("Since", ua.VariantType.DateTime), ("Fault", ua.VariantType.String),
                     ("CycleCounter", ua.VariantType.UInt64), ("JournalBytes", ua.VariantType.UInt64))
DEVICE_VARIABLES = (("Connected", ua.VariantType.Boolean), ("LastErrorCode", ua.VariantType.String),
                    ("LastErrorMessage", ua.VariantType.String))


@dataclass(frozen=True)
class Recipe:
    job: int
    part_name: str


@dataclass(frozen=True)
class CellDescription:
    """What the address space shows of the cell's config."""

    name: str
    recipes: tuple[Recipe, ...]
    calibration_date: float | None  # Unix s from [calibration] date; None: the config does not say
    simulated: bool
    last_results: int

    @property
    def context(self) -> ResultContext:
        return ResultContext({r.job: r.part_name for r in self.recipes}, self.simulated)


@dataclass
class VisionSystemNodes:
    """The nodes the server writes while it runs."""

    idx: int
    vision_system: Node
    event_type: Node
    state: Node
    state_id: Node
    automatic: Node
    automatic_id: Node
    state_nodes: dict[str, ua.NodeId]  # state name -> its StateType node in the types
    last_result_id: Node
    results: list[dict[str, Node]]  # Result01 (newest) .. ResultN: field name -> variable
    service: dict[str, Node]
    devices_folder: Node
    devices: dict[str, dict[str, Node]] = field(default_factory=dict)
    calibration: dict[str, Node] = field(default_factory=dict)


async def build_address_space(server: Server, cell: CellDescription) -> VisionSystemNodes:
    idx = await server.register_namespace(NAMESPACE)
    types = await _types(server, idx)
    objects = server.nodes.objects
    vs = await objects.add_object(ua.NodeId("VisionSystem", idx), ua.QualifiedName("VisionSystem", idx),
                                  objecttype=types["VisionSystemType"].nodeid)
    await vs.write_attribute(ua.AttributeIds.DisplayName, ua.DataValue(ua.LocalizedText(f"VisionSystem {cell.name}")))
    machine = await vs.add_object(ua.NodeId("VisionSystem.VisionStateMachine", idx),
                                  ua.QualifiedName("VisionStateMachine", idx),
                                  objecttype=types["VisionStateMachineType"].nodeid)
    automatic = await machine.add_object(ua.NodeId("VisionSystem.VisionStateMachine.AutomaticModeStateMachine", idx),
                                         ua.QualifiedName("AutomaticModeStateMachine", idx),
                                         objecttype=types["VisionAutomaticModeStateMachineType"].nodeid)
    state, state_id = await _current_state(machine)
    auto_state, auto_id = await _current_state(automatic)

    recipes = await _object(vs, idx, "RecipeManagement", types["RecipeManagementType"])
    folder = await _folder(recipes, idx, "Recipes")
    for recipe in cell.recipes:
        job = await _object(folder, idx, f"Job{recipe.job}", types["RecipeType"])
        await _variable(job, idx, "RecipeId", f"job-{recipe.job}", ua.VariantType.String)
        await _variable(job, idx, "JobNumber", recipe.job, ua.VariantType.UInt16)
        await _variable(job, idx, "PartName", recipe.part_name, ua.VariantType.String)
        date = await _variable(job, idx, "CalibrationDate", None, ua.VariantType.DateTime)
        await _write(server, date, _date_value(cell.calibration_date))

    management = await _object(vs, idx, "ResultManagement", types["ResultManagementType"])
    last_id = await _variable(management, idx, "LastResultId", 0, ua.VariantType.UInt64)
    results_folder = await _folder(management, idx, "Results")
    results = []
    for slot in range(cell.last_results):
        result = await _object(results_folder, idx, f"Result{slot + 1:02d}", types["ResultType"])
        results.append({f.name: await _variable(result, idx, f.name, None, f.variant, array=f.array)
                        for f in RESULT_FIELDS})

    service_object = await _object(vs, idx, "Service", None)
    service = {name: await _variable(service_object, idx, name, None, kind) for name, kind in SERVICE_VARIABLES}
    devices = await _folder(vs, idx, "Devices")
    health = await _object(vs, idx, "CalibrationHealth", None)
    calibration = {name: await _variable(health, idx, name, None, kind) for name, kind in (
        ("CalibrationDate", ua.VariantType.DateTime), ("CalibrationAge", ua.VariantType.Double),
        ("HealthLevel", ua.VariantType.Double))}
    await _write(server, calibration["CalibrationDate"], _date_value(cell.calibration_date))
    await _write(server, calibration["HealthLevel"], bad(ua.StatusCodes.BadNoDataAvailable))

    event_type = await server.create_custom_event_type(
        idx, "ResultReadyEventType", ua.ObjectIds.BaseEventType, [(f.name, f.variant) for f in RESULT_FIELDS])
    offset = await event_type.get_child(ua.QualifiedName("BaseOffset", idx))
    await offset.write_attribute(ua.AttributeIds.ValueRank, ua.DataValue(ua.Variant(1, ua.VariantType.Int32)))
    state_nodes = {name: types[name].nodeid for name in (*TOP_STATES, *AUTOMATIC_STATES)}
    return VisionSystemNodes(idx, vs, event_type, state, state_id, auto_state, auto_id, state_nodes, last_id, results,
                             service, devices, calibration=calibration)


async def device_nodes(nodes: VisionSystemNodes, name: str) -> dict[str, Node]:
    """The variables of device ``name`` (made when status.json first names it)."""
    if name not in nodes.devices:
        device = await _object(nodes.devices_folder, nodes.idx, name, None)
        nodes.devices[name] = {key: await _variable(device, nodes.idx, key, None, kind)
                               for key, kind in DEVICE_VARIABLES}
    return nodes.devices[name]


def bad(code: int) -> ua.DataValue:
    return ua.DataValue(ua.Variant(None, ua.VariantType.Null), StatusCode=ua.StatusCode(code))


# --- private ------------------------------------------------------------------------------------

_DEFAULTS: dict[ua.VariantType, Any] = {
    ua.VariantType.String: "", ua.VariantType.Boolean: False, ua.VariantType.UInt64: 0, ua.VariantType.UInt16: 0,
    ua.VariantType.Int32: 0, ua.VariantType.Double: 0.0,
    ua.VariantType.DateTime: datetime.datetime(1601, 1, 1, tzinfo=datetime.UTC)}
_DATA_TYPES = {kind: ua.NodeId(getattr(ua.ObjectIds, kind.name)) for kind in (
    ua.VariantType.String, ua.VariantType.Boolean, ua.VariantType.DateTime, ua.VariantType.UInt64,
    ua.VariantType.UInt16, ua.VariantType.Int32, ua.VariantType.Double)}


async def _types(server: Server, idx: int) -> dict[str, Node]:
    base = server.get_node(ua.NodeId(ua.ObjectIds.BaseObjectType))
    machine = server.get_node(ua.NodeId(ua.ObjectIds.FiniteStateMachineType))
    state_type = ua.NodeId(ua.ObjectIds.StateType)
    types = {name: await base.add_object_type(ua.NodeId(name, idx), ua.QualifiedName(name, idx)) for name in (
        "VisionSystemType", "RecipeManagementType", "RecipeType", "ResultManagementType", "ResultType")}
    for name, states in (("VisionStateMachineType", TOP_STATES), ("VisionAutomaticModeStateMachineType",
                                                                  AUTOMATIC_STATES)):
        machine_type = await machine.add_object_type(ua.NodeId(name, idx), ua.QualifiedName(name, idx))
        types[name] = machine_type
        for state in states:  # the states are the type's components, not the instance's (OPC 10000-16)
            types[state] = await machine_type.add_object(ua.NodeId(f"{name}.{state}", idx),
                                                         ua.QualifiedName(state, idx), objecttype=state_type)
    return types


async def _current_state(machine: Node) -> tuple[Node, Node]:
    current = await machine.get_child("0:CurrentState")
    return current, await current.get_child("0:Id")


async def _object(parent: Node, idx: int, name: str, object_type: Node | None) -> Node:
    kind = None if object_type is None else object_type.nodeid
    return await parent.add_object(_child_id(parent, idx, name), ua.QualifiedName(name, idx), objecttype=kind)


async def _folder(parent: Node, idx: int, name: str) -> Node:
    return await parent.add_folder(_child_id(parent, idx, name), ua.QualifiedName(name, idx))


def _child_id(parent: Node, idx: int, name: str) -> ua.NodeId:
    """``ns=<idx>;s=VisionSystem.ResultManagement.Results.Result01``: the browse path, readable in any client."""
    return ua.NodeId(f"{parent.nodeid.Identifier}.{name}", idx)


async def _variable(parent: Node, idx: int, name: str, value: Any, kind: ua.VariantType, *,
                    array: bool = False) -> Node:
    initial = _DEFAULTS[kind] if value is None else value  # asyncua types a variable by its first value
    if array:
        initial = [initial]  # a one-dimensional array (ValueRank 1), as the base offset's six numbers
    node = await parent.add_variable(_child_id(parent, idx, name), ua.QualifiedName(name, idx),
                                     ua.Variant(initial, kind), kind, datatype=_DATA_TYPES[kind])
    if array:
        await node.write_attribute(ua.AttributeIds.ValueRank, ua.DataValue(ua.Variant(1, ua.VariantType.Int32)))
    if value is None:
        await node.write_value(bad(ua.StatusCodes.BadWaitingForInitialData))
    return node


async def _write(server: Server, node: Node, value: ua.DataValue) -> None:
    await server.write_attribute_value(node.nodeid, value)


def _date_value(seconds: float | None) -> ua.DataValue:
    if seconds is None:
        return bad(ua.StatusCodes.BadNoDataAvailable)
    return ua.DataValue(ua.Variant(timestamp(seconds), ua.VariantType.DateTime))
