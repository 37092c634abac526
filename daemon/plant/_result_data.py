"""One result as OPC 40100-1 carries it — a ``ResultDataType`` of the published model (ResultId, JobId,
InternalRecipeId, InternalConfigurationId, ProductId, PartId, ResultState, IsPartial, IsSimulated, CreationTime,
ProcessingTimes, ResultContent) — and monoguide's own fields beside it (the base offset, the error, the quality):
one table for the ``ResultReadyEventType`` event, the result variables of ``ResultManagement/Results`` and the
result-access methods, so that none can disagree with another.

What a 40100 id is here: ``ResultId`` and ``JobId`` the cycle's number (one PLC TRIGGER is one job with one result),
``InternalRecipeId`` the job's ``job-<n>`` with its part name, ``ProductId`` the part name, ``PartId`` the part tag,
``InternalConfigurationId`` the cell config (its name, the calibration's date as version, the file's SHA-256).
A value the cycle does not have (the offset of a failed cycle, the quality of one that failed before its solve,
the DONE time before the service added it) is None: a Null field, a variable with ``BadNoDataAvailable``.
"""

from __future__ import annotations

import datetime
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from asyncua import ua

from monoguide.daemon.plant import _nodeset as mv
from monoguide.daemon.plant._nodeset import MachineVision
from monoguide.daemon.plant._results import CycleResult

RESULT_STATE_OK, RESULT_STATE_ERROR = 1, -1  # ResultState: > 0 a good result, < 0 a failed one (40100: system-defined)
SHA256 = "http://www.w3.org/2001/04/xmlenc#sha256"
# the fields of ResultDataType (and ResultReadyEventType, ResultType) the plant fills, in the published order
MACHINE_VISION_FIELDS = ("ResultId", "IsPartial", "IsSimulated", "ResultState", "PartId", "InternalRecipeId",
                         "ProductId", "InternalConfigurationId", "JobId", "CreationTime", "ProcessingTimes",
                         "ResultContent")


@dataclass(frozen=True)
class Configuration:
    """The cell config a result was made with, as InternalConfigurationId names it."""

    name: str
    version: str | None  # the calibration's date ([calibration] date), when the config has one
    sha256: bytes | None  # of the config file


@dataclass(frozen=True)
class ResultContext:
    """What a result's fields need beyond the journal row."""

    part_names: dict[int, str]
    simulated: bool
    configuration: Configuration = Configuration("cell", None, None)


@dataclass(frozen=True)
class OwnField:
    """One of monoguide's fields: its browse name (monoguide's namespace), OPC UA type and value."""

    name: str
    variant: ua.VariantType
    value: Callable[[CycleResult], Any]
    array: bool = False


V = ua.VariantType
OWN_FIELDS: tuple[OwnField, ...] = (
    OwnField("Job", V.UInt16, lambda r: r.job),
    OwnField("PartTag", V.UInt16, lambda r: r.part_tag),
    OwnField("Status", V.String, lambda r: r.status),
    OwnField("ErrorCode", V.String, lambda r: r.error_code or ""),
    OwnField("PlcCode", V.UInt16, lambda r: r.plc_code),
    OwnField("ErrorMessage", V.String, lambda r: r.error_message or ""),
    OwnField("BaseOffset", V.Double, lambda r: None if r.base_offset is None else list(r.base_offset), True),
    OwnField("RmsPx", V.Double, lambda r: r.rms_px),
    OwnField("SigmaPositionMm", V.Double, lambda r: r.sigma_mm),
    OwnField("SigmaRotationDeg", V.Double, lambda r: r.sigma_deg),
    OwnField("CycleTime", V.Double, lambda r: r.cycle_s),
    OwnField("OverheadTime", V.Double, lambda r: r.overhead_s),
)


def timestamp(seconds: float | None) -> datetime.datetime | None:
    return None if seconds is None else datetime.datetime.fromtimestamp(seconds, datetime.UTC)


def own_variant(field: OwnField, result: CycleResult | None) -> ua.Variant:
    value = None if result is None else field.value(result)
    if value is None:
        return ua.Variant(None, ua.VariantType.Null)
    return ua.Variant(value, field.variant, is_array=field.array)


def as_data_value(value: ua.Variant) -> ua.DataValue:
    """A variable's value: ``BadNoDataAvailable`` for a Null."""
    if value.VariantType == ua.VariantType.Null:
        return ua.DataValue(value, StatusCode=ua.StatusCode(ua.StatusCodes.BadNoDataAvailable))
    return ua.DataValue(value)


def recipe_id(model: MachineVision, job: int, part_name: str | None) -> Any:
    """RecipeIdInternalDataType of job ``job``: ``job-<n>``, described by its part type's name."""
    return model.make(mv.RECIPE_ID_INTERNAL, Id=f"job-{job}",
                      Description=None if part_name is None else ua.LocalizedText(part_name))


def configuration_id(model: MachineVision, configuration: Configuration) -> Any:
    return model.make(mv.CONFIGURATION_ID, Id=configuration.name, Version=configuration.version,
                      Hash=configuration.sha256, HashAlgorithm=SHA256 if configuration.sha256 else None)


class ResultShapes:
    """A :class:`CycleResult` as the published structures of ``model``."""

    def __init__(self, model: MachineVision, context: ResultContext) -> None:
        self.model, self.context = model, context

    def fields(self, result: CycleResult) -> dict[str, ua.Variant]:
        """The 40100 fields (:data:`MACHINE_VISION_FIELDS`) as Variants; Null where the result has none."""
        m, r, c = self.model, result, self.context
        part_name = None if r.job is None else c.part_names.get(r.job)
        values: dict[str, Any] = {
            "ResultId": m.make(mv.RESULT_ID, Id=str(r.cycle)),
            "IsPartial": ua.Variant(False, V.Boolean),
            "IsSimulated": ua.Variant(c.simulated, V.Boolean),
            "ResultState": ua.Variant(RESULT_STATE_OK if r.ok else RESULT_STATE_ERROR, V.Int32),
            "PartId": None if r.part_tag is None else m.make(mv.PART_ID, Id=str(r.part_tag)),
            "InternalRecipeId": recipe_id(m, r.job or 0, part_name),
            "ProductId": None if part_name is None else m.make(mv.PRODUCT_ID, Id=part_name),
            "InternalConfigurationId": configuration_id(m, c.configuration),
            "JobId": m.make(mv.JOB_ID, Id=str(r.cycle)),
            "CreationTime": ua.Variant(timestamp(r.committed_at), V.DateTime),
            "ProcessingTimes": m.make(
                mv.PROCESSING_TIMES, StartTime=timestamp(r.triggered_at),
                EndTime=timestamp(r.done_at if r.done_at is not None else r.committed_at),
                AcquisitionDuration=_ms(r.acquisition_s), ProcessingDuration=_ms(r.processing_s)),
            "ResultContent": self._content(r),
        }
        return {name: value if isinstance(value, ua.Variant) else ua.Variant(value) for name, value in values.items()}

    def data(self, result: CycleResult) -> Any:
        """The whole ``ResultDataType``."""
        fields = self.fields(result)
        content = fields["ResultContent"].Value
        return self.model.make(
            mv.RESULT_DATA, ResultId=fields["ResultId"].Value, HasTransferableDataOnFile=False,
            IsPartial=fields["IsPartial"].Value, IsSimulated=fields["IsSimulated"].Value,
            ResultState=fields["ResultState"].Value, PartId=fields["PartId"].Value,
            InternalRecipeId=fields["InternalRecipeId"].Value, ProductId=fields["ProductId"].Value,
            InternalConfigurationId=fields["InternalConfigurationId"].Value, JobId=fields["JobId"].Value,
            CreationTime=fields["CreationTime"].Value, ProcessingTimes=fields["ProcessingTimes"].Value,
            ResultContent=content)

    @staticmethod
    def _content(result: CycleResult) -> ua.Variant:
        """ResultContent: the base offset (x, y, z mm, A, B, C deg) of a good cycle, one Variant; none of a failed."""
        if result.base_offset is None:
            return ua.Variant([], V.Variant, is_array=True)
        return ua.Variant([ua.Variant(list(result.base_offset), V.Double, is_array=True)], V.Variant, is_array=True)


def _ms(seconds: float | None) -> float | None:
    return None if seconds is None else seconds * 1000.0


def result_message(result: CycleResult) -> str:
    return f"cycle {result.cycle} {result.status}" + (f" {result.error_code}" if result.error_code else "")


def fill_result_event(event: Any, result: CycleResult, shapes: ResultShapes) -> None:
    """Set the fields of a (monoguide's) ResultReadyEventType event: the 40100 ones, monoguide's, its Severity
    (100 a good result, 500 a failed one) and Time (the journal row's)."""
    for name, value in shapes.fields(result).items():
        setattr(event, name, value.Value)
        if value.VariantType != ua.VariantType.Null:  # asyncua types a field by its declaration's value: some have none
            event.data_types[name] = value.VariantType
    for field in OWN_FIELDS:
        setattr(event, field.name, own_variant(field, result).Value)
    event.Severity = 100 if result.ok else 500
    event.Time = timestamp(result.committed_at)
