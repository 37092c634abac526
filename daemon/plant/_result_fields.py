"""The fields of one result, as both the ``ResultReadyEventType`` event and each result object of
``ResultManagement/Results`` carry them: browse name, OPC UA type, and the value read from a :class:`CycleResult`.

One table for both, so that the event and the variables can never disagree. A value that a cycle does not have (the
offset of a failed cycle, the quality of one that failed before its solve, the DONE time before the service added
it) is None: a Null field in the event, a variable with the status ``BadNoDataAvailable``. Names follow OPC 40100-1's
``ResultDataType`` and ``ProcessingTimesDataType`` where they have one (``ResultId``, ``PartId``, ``ProductId``,
``InternalRecipeId``, ``ResultState``, ``IsPartial``, ``IsSimulated``, ``CreationTime``, ``StartTime``, ``EndTime``,
``AcquisitionDuration``, ``ProcessingDuration``); the rest are monoguide's (docs/opcua.md).
"""

from __future__ import annotations

import datetime
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from asyncua import ua

from monoguide.daemon.plant._results import CycleResult

RESULT_STATE_OK, RESULT_STATE_ERROR = 1, -1  # ResultState: > 0 a good result, < 0 a failed one (40100: system-defined)


@dataclass(frozen=True)
class ResultContext:
    """What a result's fields need beyond the journal row: the part names of the jobs, whether the cell is simulated."""

    part_names: dict[int, str]
    simulated: bool


@dataclass(frozen=True)
class ResultField:
    name: str
    variant: ua.VariantType
    value: Callable[[CycleResult, ResultContext], Any]
    array: bool = False


def timestamp(seconds: float | None) -> datetime.datetime | None:
    return None if seconds is None else datetime.datetime.fromtimestamp(seconds, datetime.UTC)


def _ms(seconds: float | None) -> float | None:
    return None if seconds is None else seconds * 1000.0


V = ua.VariantType
RESULT_FIELDS: tuple[ResultField, ...] = (
    ResultField("ResultId", V.UInt64, lambda r, _: r.cycle),
    ResultField("Job", V.UInt16, lambda r, _: r.job),
    ResultField("InternalRecipeId", V.String, lambda r, _: None if r.job is None else f"job-{r.job}"),
    ResultField("ProductId", V.String, lambda r, c: None if r.job is None else c.part_names.get(r.job)),
    ResultField("PartId", V.String, lambda r, _: None if r.part_tag is None else str(r.part_tag)),
    ResultField("PartTag", V.UInt16, lambda r, _: r.part_tag),
    ResultField("ResultState", V.Int32, lambda r, _: RESULT_STATE_OK if r.ok else RESULT_STATE_ERROR),
    ResultField("Status", V.String, lambda r, _: r.status),
    ResultField("ErrorCode", V.String, lambda r, _: r.error_code or ""),
    ResultField("PlcCode", V.UInt16, lambda r, _: r.plc_code),
    ResultField("ErrorMessage", V.String, lambda r, _: r.error_message or ""),
    ResultField("BaseOffset", V.Double, lambda r, _: None if r.base_offset is None else list(r.base_offset), True),
    ResultField("RmsPx", V.Double, lambda r, _: r.rms_px),
    ResultField("SigmaPositionMm", V.Double, lambda r, _: r.sigma_mm),
    ResultField("SigmaRotationDeg", V.Double, lambda r, _: r.sigma_deg),
    ResultField("IsPartial", V.Boolean, lambda r, _: False),
    ResultField("IsSimulated", V.Boolean, lambda r, c: c.simulated),
    ResultField("CreationTime", V.DateTime, lambda r, _: timestamp(r.committed_at)),
    ResultField("StartTime", V.DateTime, lambda r, _: timestamp(r.triggered_at)),
    ResultField("EndTime", V.DateTime, lambda r, _: timestamp(r.done_at)),
    ResultField("CycleTime", V.Double, lambda r, _: r.cycle_s),
    ResultField("OverheadTime", V.Double, lambda r, _: r.overhead_s),
    ResultField("AcquisitionDuration", V.Double, lambda r, _: _ms(r.acquisition_s)),
    ResultField("ProcessingDuration", V.Double, lambda r, _: _ms(r.processing_s)),
)


def variant(field: ResultField, result: CycleResult | None, context: ResultContext) -> ua.Variant:
    """The field's value as a Variant (Null when the result has none)."""
    value = None if result is None else field.value(result, context)
    if value is None:
        return ua.Variant(None, ua.VariantType.Null)
    return ua.Variant(value, field.variant, is_array=field.array)


def data_value(field: ResultField, result: CycleResult | None, context: ResultContext) -> ua.DataValue:
    """The field's value for a variable: ``BadNoDataAvailable`` when the result has none."""
    value = variant(field, result, context)
    if value.VariantType == ua.VariantType.Null:
        return ua.DataValue(ua.Variant(None, ua.VariantType.Null), StatusCode=ua.StatusCode(
            ua.StatusCodes.BadNoDataAvailable))
    return ua.DataValue(value)
