"""``monoguide simulate``: the run's configs, the run itself, its summary and its report (docs/simulate.md).
"""

from __future__ import annotations

from monoguide.daemon.simulate._config import derive_config, dumps_toml, predicted_grasp_sigma
from monoguide.daemon.simulate._report import write_report
from monoguide.daemon.simulate._run import (
    Progress,
    RunOptions,
    RunResult,
    cycles_needed_for_faults,
    dies_with_us,
    fault_plan,
    run_simulation,
    sample_process,
)
from monoguide.daemon.simulate._summary import InjectedFault, Targets, join_cycles, read_truth_log, render, summarize

__all__ = [
    "InjectedFault", "Progress", "RunOptions", "RunResult", "Targets", "cycles_needed_for_faults",
    "derive_config", "dies_with_us", "dumps_toml", "fault_plan", "join_cycles", "predicted_grasp_sigma",
    "read_truth_log", "render", "run_simulation", "sample_process", "summarize", "write_report",
]
