"""The OPC UA address space: the published OPC 40100-1 model (``_nodeset``) and one instance of its
``VisionSystemType``, with monoguide's own nodes in a namespace of its own (:data:`NAMESPACE`) beside it.

```
Objects/VisionSystem                        MV VisionSystemType (node ids ns=<urn:monoguide>;s=<browse path>)
  MV:VisionStateMachine                     VisionStateMachineType: CurrentState (Id, Number), LastTransition
    MV:AutomaticModeStateMachine            VisionAutomaticModeStateMachineType: CurrentState, LastTransition
  MV:ConfigurationManagement                ActiveConfiguration (the cell config)
  MV:RecipeManagement/MV:Recipes/Job<n>     RecipeType: InternalId, IsPrepared, LastModified (+ JobNumber, PartName)
  MV:ResultManagement                       GetResultById, GetResultComponentsById, GetResultListFiltered
    MV:Results/Result01 .. Result<N>        ResultType variables (ResultDataType), Result01 the newest
  MV:SafetyStateManagement                  VisionSafetyTriggered false, VisionSafetyInformation ""
  MV:SystemState                            SystemStateDescriptionDataType
  Service, Devices/<name>, CalibrationHealth, Alarms/...   monoguide's own (ns urn:monoguide)
```

"MV:" is the browse names' namespace ``http://opcfoundation.org/UA/MachineVision``; every node of the instance has a
string id, its browse path from ``VisionSystem``. Every variable is read-only (AccessLevel CurrentRead).
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass, field
from typing import Any

from asyncua import Node, Server, ua
from asyncua.common.instantiate_util import instantiate

from monoguide.daemon.plant import _nodeset as mv
from monoguide.daemon.plant._nodeset import MachineVision
from monoguide.daemon.plant._result_data import (
    MACHINE_VISION_FIELDS,
    OWN_FIELDS,
    Configuration,
    ResultContext,
    configuration_id,
    recipe_id,
    timestamp,
)
from monoguide.daemon.plant._states import AUTOMATIC_STATES, TOP_STATES

NAMESPACE = "urn:monoguide"  # monoguide's own nodes and the instance's node ids
SERVICE_VARIABLES = (("State", ua.VariantType.String), ("Running", ua.VariantType.Boolean),
                     ("Since", ua.VariantType.DateTime), ("Fault", ua.VariantType.String),
                     ("CycleCounter", ua.VariantType.UInt64), ("JournalBytes", ua.VariantType.UInt64))
DEVICE_VARIABLES = (("Connected", ua.VariantType.Boolean), ("LastErrorCode", ua.VariantType.String),
                    ("LastErrorMessage", ua.VariantType.String))
HISTORY_AND_EVENTS = (1 << ua.EventNotifier.SubscribeToEvents) | (1 << ua.EventNotifier.HistoryRead)  # bit offsets


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
    configuration: Configuration = field(default_factory=lambda: Configuration("cell", None, None))
    config_modified: float | None = None  # the config file's mtime (RecipeType LastModified)

    @property
    def context(self) -> ResultContext:
        return ResultContext({r.job: r.part_name for r in self.recipes}, self.simulated, self.configuration)


@dataclass
class MachineNodes:
    """A state machine's variables and its type's states and transitions (their NodeIds and numbers)."""

    current: Node
    current_id: Node
    current_number: Node
    last: Node
    last_id: Node
    last_number: Node
    last_time: Node
    states: dict[str, tuple[ua.NodeId, int]]
    transitions: dict[str, tuple[ua.NodeId, int]]


@dataclass
class VisionSystemNodes:
    """The nodes the server writes while it runs."""

    idx: int
    model: MachineVision
    vision_system: Node
    result_management: Node
    top: MachineNodes
    automatic: MachineNodes
    system_state: Node
    results: list[tuple[Node, dict[str, Node]]]  # Result01 (newest) .. ResultN: the variable, its children by name
    service: dict[str, Node]
    devices_folder: Node
    alarms_folder: Node
    devices: dict[str, dict[str, Node]] = field(default_factory=dict)
    calibration: dict[str, Node] = field(default_factory=dict)
    event_type: ua.NodeId = field(default_factory=ua.NodeId)  # monoguide's subtype of ResultReadyEventType


async def build_address_space(server: Server, model: MachineVision, cell: CellDescription) -> VisionSystemNodes:
    idx = await server.register_namespace(NAMESPACE)
    m = model.idx
    vs_id = ua.NodeId("VisionSystem", idx)
    await _instance(server.nodes.objects, model, mv.VISION_SYSTEM_TYPE, vs_id, ua.QualifiedName("VisionSystem", idx))
    vs = server.get_node(vs_id)
    await vs.write_attribute(ua.AttributeIds.DisplayName, ua.DataValue(ua.LocalizedText(f"VisionSystem {cell.name}")))
    await vs.write_attribute(ua.AttributeIds.EventNotifier, ua.DataValue(ua.Variant(HISTORY_AND_EVENTS,
                                                                                    ua.VariantType.Byte)))
    machine = await vs.get_child(f"{m}:VisionStateMachine")
    automatic = await _part(machine, model, mv.AUTOMATIC_MODE_STATE_MACHINE_TYPE, "AutomaticModeStateMachine")
    top_nodes = await _machine(server, machine, model, mv.VISION_STATE_MACHINE_TYPE, TOP_STATES)
    automatic_nodes = await _machine(server, automatic, model, mv.AUTOMATIC_MODE_STATE_MACHINE_TYPE, AUTOMATIC_STATES)

    configuration = await _part(vs, model, mv.CONFIGURATION_MANAGEMENT_TYPE, "ConfigurationManagement")
    active = await configuration.get_child(f"{m}:ActiveConfiguration")
    await _write(server, active, ua.DataValue(ua.Variant(model.make(
        mv.CONFIGURATION_DATA, HasTransferableDataOnFile=False, InternalId=configuration_id(model, cell.configuration),
        LastModified=timestamp(cell.config_modified) or datetime.datetime(1601, 1, 1, tzinfo=datetime.UTC)))))
    recipes = await _part(vs, model, mv.RECIPE_MANAGEMENT_TYPE, "RecipeManagement")
    recipe_folder = await _part(recipes, model, mv.RECIPE_FOLDER_TYPE, "Recipes")
    for recipe in cell.recipes:
        job = await _part(recipe_folder, model, mv.RECIPE_TYPE, f"Job{recipe.job}", idx)
        await _write(server, await job.get_child(f"{m}:InternalId"),
                     ua.DataValue(ua.Variant(recipe_id(model, recipe.job, recipe.part_name))))
        await _write(server, await job.get_child(f"{m}:IsPrepared"), ua.DataValue(ua.Variant(True)))
        await _write(server, await job.get_child(f"{m}:LastModified"), _date_value(cell.config_modified))
        await _variable(job, idx, "JobNumber", recipe.job, ua.VariantType.UInt16)
        await _variable(job, idx, "PartName", recipe.part_name, ua.VariantType.String)
        await _write(server, await _variable(job, idx, "CalibrationDate", None, ua.VariantType.DateTime),
                     _date_value(cell.calibration_date))

    management = await _part(vs, model, mv.RESULT_MANAGEMENT_TYPE, "ResultManagement")
    results_folder = await _part(management, model, mv.RESULT_FOLDER_TYPE, "Results")
    results = []
    for slot in range(cell.last_results):
        name = f"Result{slot + 1:02d}"
        variable = await _part(results_folder, model, mv.RESULT_TYPE, name, idx, optional=True)
        children = {n: await variable.get_child(f"{m}:{n}") for n in MACHINE_VISION_FIELDS}
        for f in OWN_FIELDS:
            children[f.name] = await _variable(variable, idx, f.name, None, f.variant, array=f.array)
        await variable.write_value(bad(ua.StatusCodes.BadWaitingForInitialData))
        results.append((variable, children))

    safety = await _part(vs, model, mv.SAFETY_STATE_MANAGEMENT_TYPE, "SafetyStateManagement")
    await _write(server, await safety.get_child(f"{m}:VisionSafetyTriggered"), ua.DataValue(ua.Variant(False)))
    await _write(server, await safety.get_child(f"{m}:VisionSafetyInformation"), ua.DataValue(ua.Variant("")))
    system_state = await vs.add_variable(ua.NodeId("VisionSystem.SystemState", idx), ua.QualifiedName("SystemState", m),
                                         ua.Variant(None, ua.VariantType.Null),
                                         datatype=model.node_id(mv.SYSTEM_STATE_DESCRIPTION))

    service_object = await _object(vs, idx, "Service")
    service = {name: await _variable(service_object, idx, name, None, kind) for name, kind in SERVICE_VARIABLES}
    devices = await _folder(vs, idx, "Devices")
    alarms = await _folder(vs, idx, "Alarms")
    health = await _object(vs, idx, "CalibrationHealth")
    calibration = {name: await _variable(health, idx, name, None, kind) for name, kind in (
        ("CalibrationDate", ua.VariantType.DateTime), ("CalibrationAge", ua.VariantType.Double),
        ("HealthLevel", ua.VariantType.Double))}
    await _write(server, calibration["CalibrationDate"], _date_value(cell.calibration_date))
    await _write(server, calibration["HealthLevel"], bad(ua.StatusCodes.BadNoDataAvailable))

    event_type = await server.create_custom_event_type(
        idx, "MonoguideResultReadyEventType", model.node_id(mv.RESULT_READY_EVENT_TYPE),
        [(f.name, f.variant) for f in OWN_FIELDS])
    offset = await event_type.get_child(ua.QualifiedName("BaseOffset", idx))
    await offset.write_attribute(ua.AttributeIds.ValueRank, ua.DataValue(ua.Variant(1, ua.VariantType.Int32)))
    return VisionSystemNodes(idx, model, vs, management, top_nodes, automatic_nodes, system_state, results, service,
                             devices, alarms, calibration=calibration, event_type=event_type.nodeid)


async def device_nodes(nodes: VisionSystemNodes, name: str) -> dict[str, Node]:
    """The variables of device ``name`` (made when status.json first names it)."""
    if name not in nodes.devices:
        device = await _object(nodes.devices_folder, nodes.idx, name)
        nodes.devices[name] = {key: await _variable(device, nodes.idx, key, None, kind)
                               for key, kind in DEVICE_VARIABLES}
    return nodes.devices[name]


def bad(code: int) -> ua.DataValue:
    return ua.DataValue(ua.Variant(None, ua.VariantType.Null), StatusCode=ua.StatusCode(code))


# --- private ------------------------------------------------------------------------------------

_DEFAULTS: dict[ua.VariantType, Any] = {
    ua.VariantType.String: "", ua.VariantType.Boolean: False, ua.VariantType.UInt64: 0, ua.VariantType.UInt16: 0,
    ua.VariantType.UInt32: 0, ua.VariantType.Int32: 0, ua.VariantType.Double: 0.0,
    ua.VariantType.DateTime: datetime.datetime(1601, 1, 1, tzinfo=datetime.UTC)}
_DATA_TYPES = {kind: ua.NodeId(getattr(ua.ObjectIds, kind.name)) for kind in (
    ua.VariantType.String, ua.VariantType.Boolean, ua.VariantType.DateTime, ua.VariantType.UInt64,
    ua.VariantType.UInt16, ua.VariantType.UInt32, ua.VariantType.Int32, ua.VariantType.Double)}


async def _instance(parent: Node, model: MachineVision, type_number: int, nodeid: ua.NodeId, name: ua.QualifiedName,
                    *, optional: bool = False) -> Node:
    """An instance of the published type ``type_number``: its mandatory children (all with ``optional``)."""
    made = await instantiate(parent, Node(parent.session, model.node_id(type_number)), nodeid=nodeid, bname=name,
                             instantiate_optional=optional)
    return made[0]


async def _part(parent: Node, model: MachineVision, type_number: int, name: str, idx: int | None = None, *,
                optional: bool = False) -> Node:
    """A child ``name`` of ``parent`` of the published type: browse name in MachineVision's namespace (an optional
    part of the parent's type), or in monoguide's (``idx``: a named instance, Job1, Result01)."""
    browse = ua.QualifiedName(name, model.idx if idx is None else idx)
    return await _instance(parent, model, type_number, _child_id(parent, parent.nodeid.NamespaceIndex, name), browse,
                           optional=optional)


async def _machine(server: Server, machine: Node, model: MachineVision, type_number: int,
                   names: tuple[str, ...]) -> MachineNodes:
    """The machine's CurrentState with Id and Number, a LastTransition (Id, Number, TransitionTime) and its type's
    states and transitions as published (their StateNumber, TransitionNumber)."""
    idx = machine.nodeid.NamespaceIndex
    machine_type = server.get_node(model.node_id(type_number))
    states, transitions = {}, {}
    for child in await machine_type.get_children(refs=ua.ObjectIds.HasComponent):
        definition = await child.read_type_definition()
        name = (await child.read_browse_name()).Name
        if definition == ua.NodeId(ua.ObjectIds.StateType) and name in names:
            states[name] = (child.nodeid, int(await (await child.get_child("0:StateNumber")).read_value()))
        elif definition == ua.NodeId(ua.ObjectIds.TransitionType):
            transitions[name] = (child.nodeid, int(await (await child.get_child("0:TransitionNumber")).read_value()))
    current = await machine.get_child("0:CurrentState")
    number = await _variable(current, idx, "Number", None, ua.VariantType.UInt32, browse_ns=0, prop=True)
    last = await machine.add_variable(_child_id(machine, idx, "LastTransition"), ua.QualifiedName("LastTransition", 0),
                                      ua.Variant(ua.LocalizedText(""), ua.VariantType.LocalizedText),
                                      varianttype=ua.VariantType.LocalizedText,
                                      datatype=ua.NodeId(ua.ObjectIds.LocalizedText))
    await last.add_reference(ua.NodeId(ua.ObjectIds.FiniteTransitionVariableType), ua.ObjectIds.HasTypeDefinition)
    last_id = await _variable(last, idx, "Id", None, ua.VariantType.NodeId, browse_ns=0, prop=True)
    last_number = await _variable(last, idx, "Number", None, ua.VariantType.UInt32, browse_ns=0, prop=True)
    last_time = await _variable(last, idx, "TransitionTime", None, ua.VariantType.DateTime, browse_ns=0, prop=True)
    return MachineNodes(current, await current.get_child("0:Id"), number, last, last_id, last_number, last_time,
                        states, transitions)


async def _object(parent: Node, idx: int, name: str) -> Node:
    return await parent.add_object(_child_id(parent, idx, name), ua.QualifiedName(name, idx))


async def _folder(parent: Node, idx: int, name: str) -> Node:
    return await parent.add_folder(_child_id(parent, idx, name), ua.QualifiedName(name, idx))


def _child_id(parent: Node, idx: int, name: str) -> ua.NodeId:
    """``ns=<idx>;s=VisionSystem.ResultManagement.Results.Result01``: the browse path, readable in any client."""
    return ua.NodeId(f"{parent.nodeid.Identifier}.{name}", idx)


async def _variable(parent: Node, idx: int, name: str, value: Any, kind: ua.VariantType, *, array: bool = False,
                    browse_ns: int | None = None, prop: bool = False) -> Node:
    initial = _DEFAULTS.get(kind) if value is None else value  # asyncua types a variable by its first value
    if kind == ua.VariantType.NodeId and initial is None:
        initial = ua.NodeId()
    if array:
        initial = [initial]  # a one-dimensional array (ValueRank 1), as the base offset's six numbers
    browse = ua.QualifiedName(name, idx if browse_ns is None else browse_ns)
    datatype = _DATA_TYPES.get(kind, ua.NodeId(ua.ObjectIds.NodeId))
    add = parent.add_property if prop else parent.add_variable
    node = await add(_child_id(parent, idx, name), browse, ua.Variant(initial, kind), kind, datatype=datatype)
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
