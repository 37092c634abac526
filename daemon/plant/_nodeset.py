"""OPC 40100-1 Machine Vision as the OPC Foundation publishes it: its NodeSet2 file
(``Opc.Ua.MachineVision.NodeSet2.xml``, model 1.0.0), loaded into the server at start from the path
``[plant] machine_vision_nodeset`` names (monoguide ships no copy of it: docs/opcua.md says where to get it).

The file is checked before it is imported — an XML file whose ``Model`` is ``http://opcfoundation.org/UA/MachineVision``
version 1.0.0 — and after: every node the plant binds to (:data:`BOUND`) must be there with its published browse
name, so a file of another version or a damaged one is refused at start (``PLANT_NODESET``), never served half.
"""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from asyncua import Client, Server, ua

from monoguide.daemon.errors import PlantNodeSetInvalid

MACHINE_VISION = "http://opcfoundation.org/UA/MachineVision"
MODEL_VERSION = "1.0.0"
MAX_BYTES = 16 * 1024 * 1024  # the published file is 0.8 MB
_UANODESET = "{http://opcfoundation.org/UA/2011/03/UANodeSet.xsd}"

# the published numeric ids (namespace MachineVision) of the types, declarations and data types the plant uses
VISION_SYSTEM_TYPE = 1003
CONFIGURATION_MANAGEMENT_TYPE, RECIPE_MANAGEMENT_TYPE, RESULT_MANAGEMENT_TYPE = 1006, 1004, 1007
SAFETY_STATE_MANAGEMENT_TYPE = 1009
RECIPE_FOLDER_TYPE, RESULT_FOLDER_TYPE, RECIPE_TYPE, RESULT_TYPE = 1008, 1016, 1002, 2002
VISION_STATE_MACHINE_TYPE, AUTOMATIC_MODE_STATE_MACHINE_TYPE = 1017, 1021
RESULT_READY_EVENT_TYPE, STATE_CHANGED_EVENT_TYPE = 1024, 1018
JOB_STARTED_EVENT_TYPE, READY_EVENT_TYPE, ERROR_EVENT_TYPE, ERROR_RESOLVED_EVENT_TYPE = 1013, 1023, 1019, 1020
SYSTEM_STATE_DECLARATION = 6049  # VisionSystemType's SystemState (a BaseDataVariable of SystemStateDescription)
RESULT_DATA, RESULT_ID, JOB_ID, CONFIGURATION_ID, CONFIGURATION_DATA = 3006, 3021, 3016, 3008, 3007
RECIPE_ID_INTERNAL, PRODUCT_ID, PART_ID, PROCESSING_TIMES, SYSTEM_STATE_DESCRIPTION = 3013, 3003, 3004, 3005, 3024

BOUND: dict[int, str] = {
    VISION_SYSTEM_TYPE: "VisionSystemType", CONFIGURATION_MANAGEMENT_TYPE: "ConfigurationManagementType",
    RECIPE_MANAGEMENT_TYPE: "RecipeManagementType", RESULT_MANAGEMENT_TYPE: "ResultManagementType",
    SAFETY_STATE_MANAGEMENT_TYPE: "SafetyStateManagementType", RECIPE_FOLDER_TYPE: "RecipeFolderType",
    RESULT_FOLDER_TYPE: "ResultFolderType", RECIPE_TYPE: "RecipeType", RESULT_TYPE: "ResultType",
    VISION_STATE_MACHINE_TYPE: "VisionStateMachineType",
    AUTOMATIC_MODE_STATE_MACHINE_TYPE: "VisionAutomaticModeStateMachineType",
    RESULT_READY_EVENT_TYPE: "ResultReadyEventType", STATE_CHANGED_EVENT_TYPE: "StateChangedEventType",
    JOB_STARTED_EVENT_TYPE: "JobStartedEventType", READY_EVENT_TYPE: "ReadyEventType",
    ERROR_EVENT_TYPE: "ErrorEventType", ERROR_RESOLVED_EVENT_TYPE: "ErrorResolvedEventType",
    SYSTEM_STATE_DECLARATION: "SystemState",
    RESULT_DATA: "ResultDataType", RESULT_ID: "ResultIdDataType", JOB_ID: "JobIdDataType",
    CONFIGURATION_ID: "ConfigurationIdDataType", CONFIGURATION_DATA: "ConfigurationDataType",
    RECIPE_ID_INTERNAL: "RecipeIdInternalDataType", PRODUCT_ID: "ProductIdDataType", PART_ID: "PartIdDataType",
    PROCESSING_TIMES: "ProcessingTimesDataType", SYSTEM_STATE_DESCRIPTION: "SystemStateDescriptionDataType",
}
RECIPE_ID_EXTERNAL = 3002
BINARY_ID_SUBTYPES = (CONFIGURATION_ID, RECIPE_ID_INTERNAL, RECIPE_ID_EXTERNAL)
DATA_TYPES = (RESULT_DATA, RESULT_ID, JOB_ID, CONFIGURATION_ID, CONFIGURATION_DATA, RECIPE_ID_INTERNAL, PRODUCT_ID,
              PART_ID, PROCESSING_TIMES, SYSTEM_STATE_DESCRIPTION)


@dataclass(frozen=True)
class MachineVision:
    """The imported model: its namespace index in this server and the classes asyncua made of its structures."""

    idx: int
    path: Path
    structures: dict[int, type]  # published data type id -> its class (ResultDataType, ...)

    def node_id(self, number: int) -> ua.NodeId:
        return ua.NodeId(number, self.idx)

    def make(self, number: int, **fields: Any) -> Any:
        """A value of the published structure ``number`` (:data:`RESULT_DATA`, ...)."""
        return self.structures[number](**fields)


def check_nodeset_file(path: Path) -> None:
    """Refuse (``PLANT_NODESET``) anything but the published Machine Vision model, version 1.0.0, before importing."""
    try:
        if not path.is_file():
            raise PlantNodeSetInvalid(f"{path}: [plant] machine_vision_nodeset: no such file (the OPC Foundation's "
                                      "Opc.Ua.MachineVision.NodeSet2.xml; docs/opcua.md says where to get it)")
        if path.stat().st_size > MAX_BYTES:
            raise PlantNodeSetInvalid(f"{path}: {path.stat().st_size} bytes, more than the {MAX_BYTES} a NodeSet2 "
                                      "file of the Machine Vision model can have")
        models = [(m.get("ModelUri"), m.get("Version")) for m in _models(path)]
    except OSError as exc:
        raise PlantNodeSetInvalid(f"{path}: cannot read it: {exc}") from exc
    if (MACHINE_VISION, MODEL_VERSION) not in models:
        raise PlantNodeSetInvalid(f"{path}: models {models}: expected {MACHINE_VISION} version {MODEL_VERSION} "
                                  "(Opc.Ua.MachineVision.NodeSet2.xml as the OPC Foundation publishes it)")


async def load_machine_vision(server: Server, path: Path) -> MachineVision:
    """Import the file into ``server`` (before it starts) and check the nodes the plant binds to."""
    check_nodeset_file(path)
    try:
        await server.import_xml(str(path))
    except (ValueError, KeyError, ua.UaError, ElementTree.ParseError) as exc:
        raise PlantNodeSetInvalid(f"{path}: cannot import it: {exc}") from exc
    idx = await server.get_namespace_index(MACHINE_VISION)
    for number, name in BOUND.items():
        try:
            found = (await server.get_node(ua.NodeId(number, idx)).read_browse_name()).Name
        except ua.UaError:
            found = None
        if found != name:
            raise PlantNodeSetInvalid(f"{path}: node ns={idx};i={number} is {found!r}, expected {name!r} (the "
                                      "published Machine Vision model 1.0.0)")
    await register_structure_subtypes(server, idx)
    structures = {n: ua.extension_objects_by_datatype[ua.NodeId(n, idx)] for n in DATA_TYPES
                  if ua.NodeId(n, idx) in ua.extension_objects_by_datatype}
    if len(structures) != len(DATA_TYPES):
        raise PlantNodeSetInvalid(f"{path}: its structures were not all made by the import "
                                  f"({sorted(BOUND[n] for n in DATA_TYPES if n not in structures)} missing)")
    return MachineVision(idx, path, structures)


async def register_structure_subtypes(server: Server | Client, idx: int) -> None:
    """The structures of the model that add no field to their supertype (ConfigurationIdDataType,
    RecipeIdInternalDataType, RecipeIdExternalDataType of BinaryIdBaseDataType): asyncua makes no class of their own
    for them (its import, and a client's ``load_data_type_definitions``, which then cannot decode ResultDataType),
    so their values would go out under the supertype's encoding; a subclass registered under each one's own
    encoding id sends and reads them as what they are. A client of the tests calls it too."""
    for number in BINARY_ID_SUBTYPES:
        if ua.NodeId(number, idx) not in ua.extension_objects_by_datatype:
            await _register_subtype(server, ua.NodeId(number, idx))


async def _register_subtype(server: Server | Client, datatype: ua.NodeId) -> None:
    node = server.get_node(datatype)
    supertypes = await node.get_referenced_nodes(refs=ua.ObjectIds.HasSubtype, direction=ua.BrowseDirection.Inverse)
    base = ua.extension_objects_by_datatype.get(supertypes[0].nodeid) if supertypes else None
    encodings = [e for e in await node.get_referenced_nodes(refs=ua.ObjectIds.HasEncoding)
                 if (await e.read_browse_name()).Name == "Default Binary"]
    if base is None or not encodings:
        return
    name = (await node.read_browse_name()).Name
    ua.register_extension_object(name, encodings[0].nodeid, type(name, (base,), {"data_type": datatype}), datatype)


def _models(path: Path) -> list[ElementTree.Element]:
    """The ``Model`` elements of the file's ``Models``, read without parsing the 0.8 MB that follow."""
    found: list[ElementTree.Element] = []
    try:
        for _event, element in ElementTree.iterparse(path, events=("end",)):
            if element.tag == f"{_UANODESET}Model":
                found.append(element)
            elif element.tag == f"{_UANODESET}Models" or element.tag == f"{_UANODESET}Aliases":
                break
    except ElementTree.ParseError as exc:
        raise PlantNodeSetInvalid(f"{path}: not a NodeSet2 XML file: {exc}") from exc
    return found
