"""OPC 40100-1 as published, checked against the published file itself (node-opcua-nodesets' copy of the OPC
Foundation's Opc.Ua.MachineVision.NodeSet2.xml, read here with ElementTree, not by the server's loader): every node
of the model served with its node id and browse name; a client that knows only the published browse names finds the
VisionSystem, reads a result's JobId and fetches the result by id; the state machines' StateNumbers and transitions
as the file numbers them; the result-access methods against the seeded journal, HistoryRead of the result events;
the alarms as conditions with ConditionRefresh; and every method that would change the machine refused."""

from __future__ import annotations

import asyncio
import datetime
import time
import xml.etree.ElementTree as ElementTree
from pathlib import Path
from typing import Any

import pytest
from asyncua import Client, ua
from asyncua.ua.uaerrors import UaError
from helpers.plant_cells import PASSWORD, USER, PlantCell
from helpers.plant_clients import MACHINE_VISION, EventLog, connected, load_machine_vision_types, result_event_type
from helpers.plant_npm import machine_vision_nodeset

HOST, PORT = "127.0.84.1", 48401
UA = "{http://opcfoundation.org/UA/2011/03/UANodeSet.xsd}"


def _published() -> dict[int, tuple[str, str, ElementTree.Element]]:
    """Every node of the published file: its numeric id -> (browse name, node class tag, element); a browse name of
    the model's namespace as ``1:Name``, of OPC UA's as ``Name``."""
    root = ElementTree.parse(machine_vision_nodeset()).getroot()
    nodes = {}
    for element in root:
        if element.tag.startswith(f"{UA}UA") and element.get("NodeId", "").startswith("ns=1;i="):
            nodes[int(element.get("NodeId").split("=")[-1])] = (element.get("BrowseName"), element.tag[len(UA):],
                                                                element)
    return nodes


def _name(browse_name: str) -> str:
    return browse_name.split(":", 1)[-1]


def _value_of(nodes: dict[int, tuple[str, str, ElementTree.Element]], parent: int, child: str) -> int:
    """The value of ``parent``'s property ``child`` (a StateNumber, a TransitionNumber) as the file gives it."""
    for reference in nodes[parent][2].iter(f"{UA}Reference"):
        target = int(reference.text.split("=")[-1]) if reference.text.startswith("ns=1;") else None
        if reference.get("ReferenceType") == "HasProperty" and target in nodes and _name(nodes[target][0]) == child:
            return int("".join(nodes[target][2].find(f"{UA}Value").itertext()).strip())
    raise KeyError(f"{parent} has no {child}")


def _by_name(nodes: dict[int, tuple[str, str, ElementTree.Element]], name: str, parent_name: str) -> int:
    """The id of the node ``name`` that ``parent_name`` (a type) has as a component."""
    parent = next(i for i, (n, kind, _) in nodes.items() if _name(n) == parent_name and kind == "UAObjectType")
    for reference in nodes[parent][2].iter(f"{UA}Reference"):
        target = int(reference.text.split("=")[-1]) if reference.text.startswith("ns=1;") else None
        if reference.get("IsForward", "true") == "true" and target in nodes and _name(nodes[target][0]) == name:
            return target
    raise KeyError(f"{parent_name} has no {name}")


async def _session(plant_cell: PlantCell) -> Client:
    return await connected(plant_cell.url, plant_cell.client, user=USER, password=PASSWORD)


async def _vision_system(client: Client, mv: int) -> Any:
    """The VisionSystemType instance under Objects, found as a generic client finds it: by its type definition."""
    for child in await client.nodes.objects.get_children():
        if await child.read_type_definition() == ua.NodeId(1003, mv):
            return child
    raise AssertionError("no VisionSystemType instance under Objects")


async def _path(node: Any, mv: int, *names: str) -> Any:
    return await node.get_child([f"{mv}:{n}" if n[0] != "0" else n for n in names])


def test_every_published_node_is_served_with_its_id_and_browse_name(plant_cell: PlantCell) -> None:
    published = _published()
    assert len(published) > 700  # the whole model, not a few nodes

    async def run() -> None:
        client = await _session(plant_cell)
        try:
            mv = await client.get_namespace_index(MACHINE_VISION)
            ids = sorted(published)
            read = ua.ReadParameters(NodesToRead=[ua.ReadValueId(NodeId=ua.NodeId(i, mv),
                                                                 AttributeId=ua.AttributeIds.BrowseName) for i in ids])
            values = await client.uaclient.read(read)
            served = {i: (v.Value.Value.Name, v.Value.Value.NamespaceIndex) if v.Value else None
                      for i, v in zip(ids, values, strict=True)}
            expected = {i: (_name(published[i][0]), mv if published[i][0].startswith("1:") else 0) for i in ids}
            wrong = {i: (expected[i], served[i]) for i in ids if served[i] != expected[i]}
            assert not wrong, f"{len(wrong)} of {len(ids)} published nodes not served as published: {wrong}"
        finally:
            await client.disconnect()

    asyncio.run(run())


def test_a_generic_client_binds_by_the_published_names_and_reads_a_result_by_id(plant_cell: PlantCell) -> None:
    """Only the published namespace and browse names: Result01's JobId, then GetResultById of its ResultId gives
    the seeded journal's newest cycle."""
    newest = len(plant_cell.seeded)
    entry = plant_cell.seeded[newest - 1]

    async def run() -> None:
        client = await _session(plant_cell)
        try:
            mv = await load_machine_vision_types(client)
            vs = await _vision_system(client, mv)
            results = await _path(vs, mv, "ResultManagement", "Results")
            newest_result = await results.get_child(f"{await client.get_namespace_index('urn:monoguide')}:Result01")
            assert await newest_result.read_type_definition() == ua.NodeId(2002, mv)  # ResultType
            job_id = await (await newest_result.get_child(f"{mv}:JobId")).read_value()
            result_id = await (await newest_result.get_child(f"{mv}:ResultId")).read_value()
            assert (job_id.Id, result_id.Id) == (str(newest), str(newest))
            _, result, error = await (await _path(vs, mv, "ResultManagement")).call_method(
                f"{mv}:GetResultById", ua.Variant(result_id), ua.Variant(1000, ua.VariantType.Int32))
            assert error == 0 and result.ResultId.Id == str(newest) and result.JobId.Id == str(newest)
            assert result.ResultState == (1 if entry.error is None else -1)
            assert result.PartId.Id == str(entry.part_tag) and result.InternalRecipeId.Id == "job-1"
            assert result.InternalConfigurationId.Id == "paper roof cell (simulated)"
            assert result.ProcessingTimes.StartTime.timestamp() == pytest.approx(entry.started_at, abs=1e-3)
            assert result.ProcessingTimes.EndTime.timestamp() == pytest.approx(
                entry.started_at + entry.timings_s["cycle"], abs=1e-3)
            assert result.ProcessingTimes.AcquisitionDuration == pytest.approx(1000 * (0.4 + 1.2))
            assert result.CreationTime.timestamp() == pytest.approx(entry.finished_at, abs=1e-3)
            good = plant_cell.seeded[newest - 2]  # the one before: a good cycle with an offset
            _, earlier, _ = await (await _path(vs, mv, "ResultManagement")).call_method(
                f"{mv}:GetResultById", ua.Variant(ua.ResultIdDataType(Id=str(newest - 1))),
                ua.Variant(0, ua.VariantType.Int32))
            assert earlier.ResultContent[0].Value == pytest.approx(good.result["base_offset_xyzabc"])
            *_, missing = await (await _path(vs, mv, "ResultManagement")).call_method(
                f"{mv}:GetResultById", ua.Variant(ua.ResultIdDataType(Id="999999")),
                ua.Variant(0, ua.VariantType.Int32))
            assert missing == -1
        finally:
            await client.disconnect()

    asyncio.run(run())


def test_the_result_list_filtered_by_state_and_recipe(plant_cell: PlantCell) -> None:
    failed = [n for n, e in enumerate(plant_cell.seeded, 1) if e.error is not None][::-1]

    async def run() -> None:
        client = await _session(plant_cell)
        try:
            mv = await load_machine_vision_types(client)
            management = await _path(await _vision_system(client, mv), mv, "ResultManagement")
            none = ua.Variant(None, ua.VariantType.ExtensionObject)

            async def listed(state: int, recipe: Any, most: int, start: int = 0) -> tuple[bool, list[str]]:
                complete, count, _, found, error = await management.call_method(
                    f"{mv}:GetResultListFiltered", ua.Variant(state, ua.VariantType.Int32), none, none, none,
                    recipe, none, none, none, none, ua.Variant(most, ua.VariantType.UInt32),
                    ua.Variant(start, ua.VariantType.UInt32), ua.Variant(0, ua.VariantType.Int32))
                assert error == 0 and count == len(found or [])
                return complete, [r.ResultId.Id for r in found or []]

            assert await listed(-1, none, 10) == (True, [str(n) for n in failed])
            assert await listed(-1, none, 1, 1) == (False, [str(failed[1])])
            job1 = ua.Variant(ua.RecipeIdInternalDataType(Id="job-1"))
            assert (await listed(1, job1, 3))[1] == ["11", "10", "9"]
            assert await listed(0, ua.Variant(ua.RecipeIdInternalDataType(Id="job-7")), 3) == (True, [])
        finally:
            await client.disconnect()

    asyncio.run(run())


def test_history_read_gives_the_missed_result_events(plant_cell: PlantCell) -> None:
    """A client that was away reads the result events of a time window from the journal, oldest first, in pages."""
    seeded = plant_cell.seeded

    async def run() -> None:
        client = await _session(plant_cell)
        try:
            mv = await load_machine_vision_types(client)
            vs = await _vision_system(client, mv)
            event_type = await result_event_type(client)
            start = datetime.datetime.fromtimestamp(seeded[2].finished_at - 0.5, datetime.UTC)
            end = datetime.datetime.fromtimestamp(seeded[8].finished_at + 0.5, datetime.UTC)
            events = await vs.read_event_history(start, end, 0, [event_type])  # asyncua follows the pages
            assert [e.ResultId.Id for e in events] == [str(n) for n in range(3, 10)]
            assert events[0].Time.timestamp() == pytest.approx(seeded[2].finished_at, abs=1e-3)
            assert [e.ErrorCode for e in events] == [e.error.code if e.error else "" for e in seeded[2:9]]
            assert [e.ResultState for e in events] == [-1 if e.error else 1 for e in seeded[2:9]]
            paged = await vs.read_event_history(start, end, 2, [event_type])
            assert [e.ResultId.Id for e in paged] == ["3", "4"]
            backward = await vs.read_event_history(end, start, 3, [event_type])
            assert [e.ResultId.Id for e in backward] == ["9", "8", "7"]
        finally:
            await client.disconnect()

    asyncio.run(run())


def test_the_state_machines_number_their_states_and_transitions_as_published(plant_cell: PlantCell) -> None:
    """A cycle starting (idle -> measuring) and ending: ReadyToSingleExecutionAuto and back, each with its published
    TransitionNumber, a StateChangedEventType, and the JobStartedEventType / ReadyEventType the model names."""
    nodes = _published()
    numbers = {name: _value_of(nodes, _by_name(nodes, name, "VisionAutomaticModeStateMachineType"), "TransitionNumber")
               for name in ("ReadyToSingleExecutionAuto", "SingleExecutionToReadyAuto")}
    operational = _value_of(nodes, _by_name(nodes, "Operational", "VisionStateMachineType"), "StateNumber")
    executing = _value_of(nodes, _by_name(nodes, "SingleExecution", "VisionAutomaticModeStateMachineType"),
                          "StateNumber")
    assert plant_cell.beat is not None

    async def run() -> None:
        client = await _session(plant_cell)
        try:
            mv = await load_machine_vision_types(client)
            vs = await _vision_system(client, mv)
            machine = await _path(vs, mv, "VisionStateMachine")
            automatic = await _path(machine, mv, "AutomaticModeStateMachine")
            assert await (await _path(machine, mv, "0:CurrentState", "0:Number")).read_value() == operational
            log = EventLog()
            subscription = await client.create_subscription(50, log)
            for event_type in (1018, 1013, 1023):  # StateChanged, JobStarted, Ready: one monitored item each
                await subscription.subscribe_events(vs, client.get_node(ua.NodeId(event_type, mv)))
            plant_cell.beat.state = "measuring"
            await log.wait_for(2, 10.0)
            plant_cell.beat.state = "idle"
            await log.wait_for(4, 10.0)
            kinds = [(e["EventType"].Value.Identifier, e.get("Transition").Value.Text if "Transition" in e else None)
                     for _, e in log.events]
            assert kinds == [(1018, "ReadyToSingleExecutionAuto"), (1013, None), (1018, "SingleExecutionToReadyAuto"),
                             (1023, None)], kinds
            job = [e["JobId"].Value.Id for _, e in log.events if e["EventType"].Value.Identifier in (1013, 1023)]
            assert job == [str(len(plant_cell.seeded) + 1)] * 2  # the job the journal numbers next, start and end
            last = await _path(automatic, mv, "0:LastTransition")
            assert (await last.read_value()).Text == "SingleExecutionToReadyAuto"
            assert await (await last.get_child("0:Number")).read_value() == numbers["SingleExecutionToReadyAuto"]
            plant_cell.beat.state = "measuring"
            await log.wait_for(6, 10.0)
            assert await (await _path(automatic, mv, "0:CurrentState", "0:Number")).read_value() == executing
            plant_cell.beat.state = "idle"
            await log.wait_for(8, 10.0)
        finally:
            plant_cell.beat.state = "idle"
            await client.disconnect()

    asyncio.run(run())


def test_a_latched_calibration_suspect_is_an_alarm_refreshed_on_request(plant_cell: PlantCell) -> None:
    """The latch raises CalibrationSuspect (active, unacknowledged) to a client subscribed to the Server's events;
    a later client's ConditionRefresh returns it; `health --clear` (the latch gone) acknowledges it."""
    assert plant_cell.beat is not None

    async def run() -> None:
        client = await _session(plant_cell)
        late = await _session(plant_cell)
        try:
            alarm_type = client.get_node(ua.NodeId(ua.ObjectIds.AlarmConditionType))
            log = EventLog()
            subscription = await client.create_subscription(50, log)
            await subscription.subscribe_events(client.nodes.server, alarm_type)
            plant_cell.beat.health = {"latched": True, "warning": True}
            await log.wait_for(1, 10.0)
            raised = log.events[-1][1]
            assert raised["ConditionName"].Value == "CalibrationSuspect"
            assert raised["ActiveState/Id"].Value is True and raised["AckedState/Id"].Value is False
            assert raised["Retain"].Value is True and raised["Severity"].Value == 800
            # a client that subscribes later sees nothing until it asks for a refresh
            late_log = EventLog()
            late_subscription = await late.create_subscription(50, late_log)
            await late_subscription.subscribe_events(late.nodes.server, [
                late.get_node(ua.NodeId(ua.ObjectIds.AlarmConditionType)),
                late.get_node(ua.NodeId(ua.ObjectIds.RefreshStartEventType)),
                late.get_node(ua.NodeId(ua.ObjectIds.RefreshEndEventType))])
            condition_type = late.get_node(ua.NodeId(ua.ObjectIds.ConditionType))
            with pytest.raises(UaError) as refused:  # another session's subscription
                await condition_type.call_method("0:ConditionRefresh", ua.Variant(subscription.subscription_id,
                                                                                  ua.VariantType.UInt32))
            assert type(refused.value).__name__ == "BadSubscriptionIdInvalid"
            await condition_type.call_method("0:ConditionRefresh", ua.Variant(late_subscription.subscription_id,
                                                                              ua.VariantType.UInt32))
            await late_log.wait_for(3, 10.0)
            kinds = [e["EventType"].Value for _, e in late_log.events]
            assert kinds[0] == ua.NodeId(ua.ObjectIds.RefreshStartEventType)
            assert kinds[-1] == ua.NodeId(ua.ObjectIds.RefreshEndEventType)
            refreshed = {e["ConditionName"].Value for _, e in late_log.events if "ConditionName" in e
                         and e["ConditionName"].Value}
            assert refreshed == {"CalibrationSuspect", "DeviceLost_robot"}  # the status file: the robot is gone
            # Acknowledge from OPC UA is refused: only health --clear acknowledges
            alarm = late.get_node(ua.NodeId("VisionSystem.Alarms.CalibrationSuspect",
                                            await late.get_namespace_index("urn:monoguide")))
            with pytest.raises(UaError) as refused:
                await alarm.call_method("0:Acknowledge", ua.Variant(raised["EventId"].Value, ua.VariantType.ByteString),
                                        ua.Variant(ua.LocalizedText("seen"), ua.VariantType.LocalizedText))
            assert type(refused.value).__name__ == "BadUserAccessDenied"
            count = len(log.events)
            plant_cell.beat.health = {"latched": False, "warning": False}
            await log.wait_for(count + 1, 10.0)
            cleared = [e for _, e in log.events[count:] if e["ConditionName"].Value == "CalibrationSuspect"][-1]
            assert cleared["ActiveState/Id"].Value is False and cleared["AckedState/Id"].Value is True
            assert cleared["Retain"].Value is False
        finally:
            plant_cell.beat.health = None
            await late.disconnect()
            await client.disconnect()

    asyncio.run(run())


@pytest.mark.parametrize(("path", "method", "arguments"), [
    (("VisionStateMachine",), "Halt", ()),
    (("VisionStateMachine",), "Reset", ()),
    (("VisionStateMachine", "AutomaticModeStateMachine"), "StartSingleJob", ()),
    (("RecipeManagement",), "PrepareRecipe", ()),
    (("ConfigurationManagement",), "ActivateConfiguration", ()),
    (("SafetyStateManagement",), "ReportSafetyState", ()),
])
def test_the_methods_that_change_the_machine_are_refused(plant_cell: PlantCell, path: tuple[str, ...], method: str,
                                                         arguments: tuple[Any, ...]) -> None:
    async def run() -> None:
        client = await _session(plant_cell)
        try:
            mv = await client.get_namespace_index(MACHINE_VISION)
            node = await _path(await _vision_system(client, mv), mv, *path)
            with pytest.raises(UaError) as refused:
                await node.call_method(f"{mv}:{method}", *arguments)
            assert type(refused.value).__name__ == "BadUserAccessDenied"
        finally:
            await client.disconnect()

    asyncio.run(run())


def test_a_nodeset_that_is_not_the_published_model_is_refused(tmp_path: Path) -> None:
    import subprocess
    import sys

    from helpers.plant_cells import plant_file
    from helpers.repository import SIM_CELL

    other = tmp_path / "Other.NodeSet2.xml"
    other.write_text(machine_vision_nodeset().read_text().replace('Version="1.0.0"', 'Version="0.9.0"', 1))
    plant_toml = plant_file(tmp_path / "plant.toml", "127.0.84.9", 48491)
    plant_toml.write_text(plant_toml.read_text().replace(str(machine_vision_nodeset()), str(other)))
    started = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", "plant", "--config", str(SIM_CELL),
                           "--state-dir", str(tmp_path / "state"), "--plant-config", str(plant_toml)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr[-2000:]
    assert f"PLANT_NODESET {other}: models [('{MACHINE_VISION}', '0.9.0')]" in done.stderr
    assert time.monotonic() - started < 60
