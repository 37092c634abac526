"""The two published state machines of the VisionSystem kept in step with the service's state (``_states``):
``CurrentState`` with its ``Id`` (the state of the machine's type) and ``Number`` (its StateNumber),
``LastTransition`` with its ``Id``, ``Number`` (TransitionNumber) and ``TransitionTime``, and an event per
transition as the published model says it has one: ``StateChangedEventType`` for each, ``JobStartedEventType`` when
a job starts (Ready to SingleExecution), ``ReadyEventType`` when it ends, ``ErrorEventType`` into Error from
Preoperational, ``ErrorResolvedEventType`` out of Error into Operational.
"""

from __future__ import annotations

import datetime
from typing import Any

from asyncua import Node, Server, ua

from monoguide.daemon.plant import _nodeset as mv
from monoguide.daemon.plant._address_space import MachineNodes, VisionSystemNodes, bad
from monoguide.daemon.plant._states import AUTOMATIC_TRANSITIONS, TOP_TRANSITIONS, VisionState, transitions

SEVERITY = 200  # a state change is news, not an alarm (the alarms are _alarms')
# the published transitions with an event beyond StateChangedEventType (their HasEffect references)
EFFECTS = {"ReadyToSingleExecutionAuto": mv.JOB_STARTED_EVENT_TYPE, "SingleExecutionToReadyAuto": mv.READY_EVENT_TYPE,
           "PreoperationalToErrorAuto": mv.ERROR_EVENT_TYPE, "ErrorToOperationalAuto": mv.ERROR_RESOLVED_EVENT_TYPE}


class VisionStates:
    """What the machines show; :meth:`show` moves them to the service's state."""

    def __init__(self, server: Server, nodes: VisionSystemNodes) -> None:
        self.server, self.nodes = server, nodes
        self.shown: VisionState | None = None
        self.job_id: str | None = None  # the job running (SingleExecution): the cycle the journal numbers next
        self._events: dict[int, Any] = {}

    async def start(self) -> None:
        for number in (mv.STATE_CHANGED_EVENT_TYPE, *EFFECTS.values()):
            self._events[number] = await self.server.get_event_generator(self.nodes.model.node_id(number),
                                                                         self.nodes.vision_system)

    async def show(self, state: VisionState, next_job: str | None) -> None:
        """Show ``state``; ``next_job``: the id the next job will have (the journal's counter plus one)."""
        before = self.shown
        if before is None:
            await self._state(self.nodes.top, state.top)
            await self._state(self.nodes.automatic, state.automatic)
        elif before != state:
            now = datetime.datetime.now(datetime.UTC)
            if state.top != before.top:
                for name, source, target in transitions(before.top, state.top, TOP_TRANSITIONS):
                    await self._state(self.nodes.top, target)
                    await self._transition(self.nodes.top, name, source, target, now)
                await self._state(self.nodes.automatic, state.automatic)
            elif state.automatic != before.automatic and before.automatic and state.automatic:
                if state.automatic == "SingleExecution":
                    self.job_id = next_job
                for name, source, target in transitions(before.automatic, state.automatic, AUTOMATIC_TRANSITIONS):
                    await self._state(self.nodes.automatic, target)
                    await self._transition(self.nodes.automatic, name, source, target, now)
        self.shown = state

    async def _state(self, machine: MachineNodes, name: str | None) -> None:
        if name is None:  # the sub-machine outside Operational
            for node in (machine.current, machine.current_id, machine.current_number):
                await self._write(node, bad(ua.StatusCodes.BadStateNotActive))
            return
        nodeid, number = machine.states[name]
        await self._write(machine.current, ua.DataValue(ua.Variant(ua.LocalizedText(name),
                                                                   ua.VariantType.LocalizedText)))
        await self._write(machine.current_id, ua.DataValue(ua.Variant(nodeid, ua.VariantType.NodeId)))
        await self._write(machine.current_number, ua.DataValue(ua.Variant(number, ua.VariantType.UInt32)))

    async def _transition(self, machine: MachineNodes, name: str, source: str, target: str,
                          now: datetime.datetime) -> None:
        nodeid, number = machine.transitions[name]
        await self._write(machine.last, ua.DataValue(ua.Variant(ua.LocalizedText(name), ua.VariantType.LocalizedText)))
        await self._write(machine.last_id, ua.DataValue(ua.Variant(nodeid, ua.VariantType.NodeId)))
        await self._write(machine.last_number, ua.DataValue(ua.Variant(number, ua.VariantType.UInt32)))
        await self._write(machine.last_time, ua.DataValue(ua.Variant(now, ua.VariantType.DateTime)))
        changed = self._events[mv.STATE_CHANGED_EVENT_TYPE]
        event = changed.event
        def node(value: ua.NodeId) -> ua.Variant:  # the Ids are BaseDataType fields: a Variant holding the NodeId
            return ua.Variant(value, ua.VariantType.NodeId)

        for field, value in (("Transition", ua.LocalizedText(name)), ("Transition/Id", node(nodeid)),
                             ("FromState", ua.LocalizedText(source)), ("FromState/Id", node(machine.states[source][0])),
                             ("ToState", ua.LocalizedText(target)), ("ToState/Id", node(machine.states[target][0]))):
            setattr(event, field, value)
        event.Severity = SEVERITY
        await changed.trigger(time_attr=now, message=f"{source} to {target} ({name})")
        if name in EFFECTS:
            effect = self._events[EFFECTS[name]]
            if name in ("ReadyToSingleExecutionAuto", "SingleExecutionToReadyAuto"):
                effect.event.JobId = None if self.job_id is None else self.nodes.model.make(mv.JOB_ID, Id=self.job_id)
            effect.event.Severity = SEVERITY
            await effect.trigger(time_attr=now, message=f"{name}: {source} to {target}")

    async def _write(self, node: Node, value: ua.DataValue) -> None:
        await self.server.write_attribute_value(node.nodeid, value)
