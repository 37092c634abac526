"""One finished cycle as the plant sees it: a journal row (docs/journal.md) read into the fields that the OPC UA
result variables and events and the metrics show."""

from __future__ import annotations

from dataclasses import dataclass

from monoguide.daemon.service import JournalRow

OFFSET_AXES = ("x", "y", "z", "a", "b", "c")  # mm, mm, mm, deg, deg, deg: PLC registers 16-27


@dataclass(frozen=True)
class CycleResult:
    """``base_offset``: what the robot got (x y z mm, A B C deg), only for a good cycle — a failed one wrote
    nothing; the quality figures when the solve got that far. Times are Unix seconds, durations seconds."""

    cycle: int  # the result id: the journal's cycle number (PLC register 13)
    job: int | None
    part_tag: int | None
    ok: bool
    error_code: str | None
    plc_code: int
    error_message: str | None
    base_offset: tuple[float, ...] | None
    rms_px: float | None
    sigma_mm: float | None
    sigma_deg: float | None
    triggered_at: float  # the cycle's start (TRIGGER seen)
    committed_at: float  # the journal row's time (just before its commit)
    done_at: float | None  # DONE shown to the PLC: the start plus the `cycle` timing, once the service added it
    cycle_s: float | None  # trigger -> DONE
    overhead_s: float | None  # the last frame in hand -> the offset acknowledged
    acquisition_s: float | None  # robot motion + exposure, summed over the views
    processing_s: float | None  # hole finding + solve + checks

    @property
    def status(self) -> str:
        return "ok" if self.ok else "error"


def cycle_result(row: JournalRow) -> CycleResult:
    result = row.result or {}
    timings = row.timings_s
    offset = result.get("base_offset_xyzabc") if row.status == "ok" else None
    cycle_s = timings.get("cycle")
    return CycleResult(
        cycle=row.number, job=row.job, part_tag=row.part_tag, ok=row.status == "ok", error_code=row.error_code,
        plc_code=row.plc_code, error_message=row.error_message,
        base_offset=None if offset is None else tuple(float(v) for v in offset),
        rms_px=_number(result.get("rms_px")), sigma_mm=_number(result.get("sigma_trans_mm")),
        sigma_deg=_number(result.get("sigma_rot_deg")),
        triggered_at=row.started_at, committed_at=row.finished_at,
        done_at=None if cycle_s is None else row.started_at + cycle_s, cycle_s=cycle_s,
        overhead_s=timings.get("overhead"),
        acquisition_s=_sum(timings, ("robot_motion", "exposure")),
        processing_s=_sum(timings, ("hole_finding", "solve", "checks")),
    )


def amended(row: JournalRow) -> bool:
    """Whether the service has added the timings known only after DONE (docs/journal.md)."""
    return "cycle" in row.timings_s


def _number(value: object) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def _sum(timings: dict[str, float], keys: tuple[str, ...]) -> float | None:
    found = [timings[k] for k in keys if k in timings]
    return sum(found) if found else None
