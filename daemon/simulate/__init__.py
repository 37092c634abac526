"""The simulated cell and the simulated run: ``monoguide sim-cell`` (the cell's device processes, its state file,
its fault channel, the grasp relay) and ``monoguide simulate`` (that cell and the service together: the run's
configs, the run itself, its witnesses, summary and report) — docs/simulate.md, docs/probe.md.

Modules, each one job: ``_state_claim`` (one sim-cell per state file), ``_devices`` (the device processes),
``_fault_channel`` (fault commands on sim-cell's standard input), ``_cell`` (the running cell), ``_requests`` (a
command for a running sim-cell from another process); ``_config`` (the run's derived configs), ``_children`` (the
run's child processes), ``_fault_plan`` (which faults a run injects, and when), ``_sampling`` (the service's memory
from ``/proc``), ``_run`` (the run), ``_witnesses`` (what the line, the journal and the truth log say, joined per
part), ``_summary``, ``_render`` (the tables), ``_report`` (``report.md`` and its plots); ``_owner`` (what each of
them that holds a process, a pipe, a thread or a file is: a context manager that closes it).
"""

from __future__ import annotations

from monoguide.daemon.simulate._cell import SimulatedCell
from monoguide.daemon.simulate._children import dies_with_us
from monoguide.daemon.simulate._config import DerivedCell, derive_config, dumps_toml, predicted_grasp_sigma
from monoguide.daemon.simulate._fault_channel import FAULT_COMMANDS, ROBOT_ACTIONS
from monoguide.daemon.simulate._fault_plan import FAULT_PLAN, InjectedFault, cycles_needed_for_faults, fault_plan
from monoguide.daemon.simulate._render import render
from monoguide.daemon.simulate._report import write_report
from monoguide.daemon.simulate._requests import present_reference_part, send_command
from monoguide.daemon.simulate._run import Progress, RunOptions, RunResult, run_simulation
from monoguide.daemon.simulate._sampling import sample_process
from monoguide.daemon.simulate._summary import Targets, summarize
from monoguide.daemon.simulate._witnesses import join_cycles, read_truth_log

__all__ = [
    "FAULT_COMMANDS", "FAULT_PLAN", "ROBOT_ACTIONS", "DerivedCell", "InjectedFault", "Progress", "RunOptions",
    "RunResult", "SimulatedCell", "Targets", "cycles_needed_for_faults", "derive_config", "dies_with_us",
    "dumps_toml", "fault_plan", "join_cycles", "predicted_grasp_sigma", "present_reference_part", "read_truth_log",
    "render", "run_simulation", "sample_process", "send_command", "summarize", "write_report",
]
