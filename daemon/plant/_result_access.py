"""The result-access methods of ``ResultManagement`` (OPC 40100-1): GetResultById, GetResultComponentsById and
GetResultListFiltered, answered from the journal (every result it holds, not only the newest N).

Ids are the cycle numbers (``_result_data``): GetResultById with ResultId ``"37"`` returns cycle 37. A result the
journal does not hold is answered with ``Error`` -1 and an empty result (40100: a negative Error is the
application's). ``Timeout`` is not waited on: a result is in the journal or it is not. ``ResultHandle`` is 0:
nothing is held for the client, there is nothing to release (ReleaseResultHandle is not served).

GetResultListFiltered filters by ``ResultState`` (> 0 good results, < 0 failed ones, 0 any), ``InternalRecipeId``
(``job-<n>``), ``ProductId`` (the part name), ``PartId`` (the part tag), ``JobId``, ``InternalConfigurationId`` (the
cell config's name); a filter monoguide has no value for (MeasId, the external ids) given non-empty matches nothing.
Newest first, from ``StartIndex``, at most ``MaxResults`` (at most :data:`MAX_LIST`; 0: that many).
"""

from __future__ import annotations

from typing import Any

from asyncua import Server, ua

from monoguide.daemon.plant._address_space import VisionSystemNodes
from monoguide.daemon.plant._journal_reader import JournalReader
from monoguide.daemon.plant._result_data import ResultShapes
from monoguide.daemon.plant._results import CycleResult, cycle_result
from monoguide.daemon.service import CycleQuery, Journal

NOT_FOUND = -1  # Error: no result of that id in the journal
MAX_LIST = 100  # results in one GetResultListFiltered answer
SCAN_ROWS = 2000  # rows looked at for one list (newest first) when a filter the journal cannot index is given
METHODS = ("GetResultById", "GetResultComponentsById", "GetResultListFiltered")
V = ua.VariantType


class ResultAccess:
    """The three methods, linked to the instance's method nodes by :meth:`start`."""

    def __init__(self, server: Server, nodes: VisionSystemNodes, shapes: ResultShapes, reader: JournalReader) -> None:
        self.server, self.nodes, self.shapes, self.reader = server, nodes, shapes, reader
        self.method_ids: dict[str, ua.NodeId] = {}

    async def start(self) -> None:
        for name, callback in (("GetResultById", self.get_result_by_id),
                               ("GetResultComponentsById", self.get_result_components_by_id),
                               ("GetResultListFiltered", self.get_result_list_filtered)):
            node = await self.nodes.result_management.get_child(f"{self.nodes.model.idx}:{name}")
            self.server.link_method(node, callback)
            self.method_ids[name] = node.nodeid

    async def get_result_by_id(self, parent: ua.NodeId, result_id: ua.Variant, timeout: ua.Variant) -> list[ua.Variant]:
        result = await self._by_id(result_id.Value)
        if result is None:
            return [_handle(), ua.Variant(None, V.ExtensionObject), ua.Variant(NOT_FOUND, V.Int32)]
        return [_handle(), ua.Variant(self.shapes.data(result)), ua.Variant(0, V.Int32)]

    async def get_result_components_by_id(self, parent: ua.NodeId, result_id: ua.Variant,
                                          timeout: ua.Variant) -> list[ua.Variant]:
        result = await self._by_id(result_id.Value)
        none = ua.Variant(None, V.ExtensionObject)
        if result is None:
            return [ua.Variant(False, V.Boolean), _handle(), ua.Variant(False, V.Boolean), ua.Variant(False, V.Boolean),
                    ua.Variant(0, V.Int32), none, none, none, none, none, none, none, none,
                    ua.Variant(None, V.DateTime), none, ua.Variant([], V.Variant, is_array=True),
                    ua.Variant(NOT_FOUND, V.Int32)]
        f = self.shapes.fields(result)
        return [ua.Variant(False, V.Boolean), _handle(), f["IsPartial"], f["IsSimulated"], f["ResultState"], none,
                _or_none(f["PartId"]), none, f["InternalRecipeId"], _or_none(f["ProductId"]), none,
                f["InternalConfigurationId"], f["JobId"], f["CreationTime"], f["ProcessingTimes"], f["ResultContent"],
                ua.Variant(0, V.Int32)]

    async def get_result_list_filtered(self, parent: ua.NodeId, *arguments: ua.Variant) -> list[ua.Variant]:
        (state, meas_id, part_id, external_recipe, internal_recipe, external_configuration, internal_configuration,
         product_id, job_id, max_results, start_index, _timeout) = (a.Value for a in arguments)
        asked = min(int(max_results or MAX_LIST), MAX_LIST)
        start = int(start_index or 0)
        if _given(meas_id) or _given(external_recipe) or _given(external_configuration) or (
                _given(internal_configuration) and internal_configuration.Id != self.shapes.context.configuration.name):
            return self._list([], complete=True)
        job = self._job(internal_recipe, product_id)
        if job == -1:
            return self._list([], complete=True)
        status = None if not state else "ok" if int(state) > 0 else "error"
        tag = _number(part_id.Id) if _given(part_id) else None
        cycle = _number(job_id.Id) if _given(job_id) else None

        def matching(journal: Journal) -> list[CycleResult]:
            if cycle is not None:
                rows = [journal.cycle(cycle)] if cycle > 0 and journal.has_cycle(cycle) else []
            else:
                rows, before = [], 0
                while len(rows) < SCAN_ROWS:
                    page = journal.find_cycles(CycleQuery(status=status, job=job, before=before, limit=500))
                    rows += page
                    if len(page) < 500 or (tag is None and len(rows) >= start + asked + 1):
                        break
                    before = page[-1].number
            found = [cycle_result(row) for row in rows]
            return [r for r in found if (tag is None or r.part_tag == tag) and (status is None or r.status == status)
                    and (job is None or r.job == job)]

        results = await self.reader.read(matching) or []
        page = results[start:start + asked]
        return self._list(page, complete=start + asked >= len(results))

    # --- private ------------------------------------------------------------------------------------

    def _list(self, results: list[CycleResult], *, complete: bool) -> list[ua.Variant]:
        return [ua.Variant(complete, V.Boolean), ua.Variant(len(results), V.UInt32), _handle(),
                ua.Variant([self.shapes.data(r) for r in results], V.ExtensionObject, is_array=True),
                ua.Variant(0, V.Int32)]

    def _job(self, recipe: Any, product: Any) -> int | None:
        """The job a recipe or product filter names; None: no such filter; -1: one that names no job."""
        job = None
        if _given(recipe):
            text = str(recipe.Id)
            job = _number(text[4:]) if text.startswith("job-") else None
            if job is None:
                return -1
        if _given(product):
            named = [j for j, name in self.shapes.context.part_names.items() if name == product.Id]
            if not named or (job is not None and job != named[0]):
                return -1
            job = named[0]
        return job

    async def _by_id(self, result_id: Any) -> CycleResult | None:
        number = _number(getattr(result_id, "Id", None))
        if number is None or number < 1:
            return None

        def one(journal: Journal) -> CycleResult | None:
            return cycle_result(journal.cycle(number)) if journal.has_cycle(number) else None

        return await self.reader.read(one)


def _handle() -> ua.Variant:
    return ua.Variant(0, V.UInt32)


def _or_none(value: ua.Variant) -> ua.Variant:
    return ua.Variant(None, V.ExtensionObject) if value.VariantType == V.Null else value


def _given(identifier: Any) -> bool:
    """Whether an id filter was given: a structure with a non-empty Id."""
    return identifier is not None and bool(getattr(identifier, "Id", None))


def _number(text: object) -> int | None:
    try:
        return int(str(text).strip())
    except ValueError:
        return None
