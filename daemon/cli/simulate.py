"""`monoguide simulate`: the whole simulated cell and the service in one command (docs/simulate.md).

The same code path as a line: ``monoguide sim-cell`` (simulated PLC, robot controller with the part supply,
tracker) and ``monoguide run`` (the service, with the simulated camera) as child processes over the real
transports, N cycles, then the grasp error from the cell's truth log, the time split from the service's
journal, errors by code, and the service's resident memory. Exit status (``daemon/cli/_policy.py``): 0 when the
run completed (the targets are printed, a benchmark: missing one is not a failure), 1 when the run itself failed
or an offset was written for a failed cycle, 2 on a config error, 130 when interrupted; a failure is one line,
``CODE message``, last on standard error.
"""

from __future__ import annotations

import json
import shlex
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn
from rich.progress import Progress as RichProgress

from monoguide.daemon.cli._console import say, stderr_console, stdout_console
from monoguide.daemon.cli._options import job_numbers
from monoguide.daemon.cli._policy import EXIT_INTERRUPTED, fail
from monoguide.daemon.cli._policy import report as report_error
from monoguide.daemon.cli._web_child import hold_until_interrupted, start_web_page
from monoguide.daemon.errors import SimulateError
from monoguide.daemon.simulate import (
    Progress,
    RunOptions,
    RunResult,
    Targets,
    cycles_needed_for_faults,
    join_cycles,
    predicted_grasp_sigma,
    render,
    run_simulation,
    summarize,
    write_report,
)
from monoguide.drivers.errors import ConfigError
from monoguide.solver.errors import MonoguideError

DEFAULT_CYCLES = 24  # about a minute on the simulated roof cell
MAX_CYCLE_ROWS = 60  # the human per-cycle table is left out for longer runs (--json and --report have it)


def default_config() -> Path:
    """The simulated paper roof cell that monoguide ships (``config/sim-cell.toml``, wherever it is installed)."""
    from monoguide.daemon.packaged import sim_cell_config

    return sim_cell_config()


def simulate(
    cycles: Annotated[int, typer.Option("--cycles", "-n", min=1, help="parts the line plays")] = DEFAULT_CYCLES,
    seed: Annotated[int | None, typer.Option("--seed", help="[sim] seed: the parts and the robot's noise")] = None,
    robot: Annotated[str | None, typer.Option("--robot", help="ur or kuka (the simulated controller)")] = None,
    perfect_robot: Annotated[bool, typer.Option("--perfect-robot", help="no repeatability noise")] = False,
    faults: Annotated[
        bool, typer.Option("--faults", help="inject each device and PLC fault in turn, among good cycles, then the "
                                            "calibration faults, each for a few parts")
    ] = False,
    fault: Annotated[
        list[str] | None, typer.Option("--fault", help="with --faults: only this one, e.g. 'robot stall', or a "
                                                       "calibration fault, e.g. 'camera bump 0.1 0' (repeatable)")
    ] = None,
    fail_every: Annotated[int, typer.Option(
        "--fail-every", min=0, help="one part in N meets a one-grab camera failure (black, occluded in turn; 0: none): "
                                    "a line's everyday refusals, the service's memory over them")] = 0,
    config: Annotated[Path | None, typer.Option("--config", "-c", help="simulated cell config (TOML)")] = None,
    marks: Annotated[bool, typer.Option(
        "--marks", help="the simulated roof cell with fixed reference marks (sim-cell-marks.toml)")] = False,
    calibration: Annotated[Path | None, typer.Option(
        "--calibration", help="the service uses this file's calibration values (monoguide calibrate's output); "
                              "the simulated cell keeps --config's")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="one JSON object per cycle, then the summary")] = False,
    report: Annotated[Path | None, typer.Option("--report", help="write report.md and PNG plots here")] = None,
    host: Annotated[
        str | None, typer.Option("--host", help="loopback address for the robot and the PLC (default: a free one)")
    ] = None,
    work_dir: Annotated[
        Path | None, typer.Option("--work-dir", help="keep the run's config, journal, truth log and logs here")
    ] = None,
    jobs: Annotated[str | None, typer.Option(
        "--jobs", help="the part types the line brings, in turn, e.g. 1,2 (default: every job of the config)")] = None,
    web: Annotated[str | None, typer.Option(
        "--web", help="HOST:PORT: the operator page on the run (monoguide web), kept up after it until Ctrl-C")] = None,
) -> None:
    """Run the simulated cell and the service for N cycles; report grasp error, time split, errors, memory."""
    err = stderr_console()
    if robot is not None and robot not in ("ur", "kuka"):
        fail(ConfigError(f"--robot {robot!r}: expected ur or kuka"))
    if marks and config is not None:
        fail(ConfigError(f"--marks with --config {config}: --marks is the shipped cell with reference marks; give one"))
    if marks:
        from monoguide.daemon.packaged import sim_cell_marks_config

        config = sim_cell_marks_config()
    names = tuple(" ".join(f.replace(":", " ").split()) for f in fault or ())
    faults = faults or bool(names)
    try:
        needed = cycles_needed_for_faults(names) if faults else 0
    except ConfigError as error:
        fail(error)
    if cycles < needed:
        say(err, f"--faults: {cycles} cycles are too few for each fault between good cycles; running {needed}")
        cycles = needed
    work = Path(work_dir) if work_dir is not None else Path(tempfile.mkdtemp(prefix="monoguide-simulate-"))
    keep = work_dir is not None
    options = RunOptions(config or default_config(), work, cycles, seed, robot, perfect_robot, faults, host, names,
                         calibration, _job_numbers(jobs), fail_every)
    page = start_web_page(web, work / "state", options.config)  # --web: the page, until the command ends
    try:
        with _progress(err, cycles) as progress:
            result = run_simulation(options, progress)
    except KeyboardInterrupt:
        say(err, f"interrupted: the service and the simulated cell are stopped; files in {work}")
        raise typer.Exit(EXIT_INTERRUPTED) from None
    except ConfigError as error:
        _cleanup(work, keep)
        fail(error)
    except MonoguideError as error:
        say(err, f"the run's files (config, logs, journal, truth log) are kept in {work}")
        fail(error)
    cycles_out, summary = _summary(result, perfect_robot)
    if json_out:
        for c in cycles_out:
            sys.stdout.write(json.dumps(c) + "\n")
        sys.stdout.write(json.dumps(summary) + "\n")
        sys.stdout.flush()
    else:
        render(stdout_console(), cycles_out, summary, every_cycle=len(cycles_out) <= MAX_CYCLE_ROWS)
    if report is not None:
        command = "monoguide simulate " + shlex.join(sys.argv[2:] if len(sys.argv) > 2 else [])
        files = write_report(report, cycles_out, summary, command)
        say(err, f"report: {files[0]}")
    verdict = "met" if summary["targets_met"] else "NOT all met (see the targets table)"
    say(err, f"{summary['cycles']} cycles in {summary['elapsed_s']:g} s; targets {verdict}")
    if summary["offsets_written_on_failure"]:
        fail(SimulateError(f"{summary['offsets_written_on_failure']} offsets were written for failed cycles; "
                           f"files kept in {work}"))
    hold_until_interrupted(page)
    _cleanup(work, keep)


# --- private ------------------------------------------------------------------------------------


def _job_numbers(text: str | None) -> tuple[int, ...]:
    try:
        return job_numbers("--jobs", text)
    except ConfigError as error:
        fail(error)


def _summary(result: RunResult, perfect_robot: bool) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The run's cycles (one per part the line played) and its summary, with the run's settings."""
    cycles = join_cycles(result.plc_records, result.journal_rows, result.truth, result.faults)
    repeatability = _repeatability(result)
    jobs = {}
    for job in dict.fromkeys(result.cell.jobs):  # each part type judged against its own prediction
        predicted = _prediction(result, repeatability, job)
        jobs[job] = Targets.for_run(perfect_robot, predicted["sigma_mm"], predicted["sigma_deg"],
                                    predicted.get("variances_mm2"), predicted.get("variances_deg2"))
    summary = summarize(cycles, result.truth, result.journal_rows, result.faults, result.rss,
                        Targets.for_run(perfect_robot), result.logged_codes, jobs)
    summary.update({"seed": _seed(result.cell.data), "robot": result.cell.data["robot"]["backend"],
                    "perfect_robot": perfect_robot, **repeatability, "calibration": result.cell.calibration,
                    "elapsed_s": round(result.elapsed_s, 1), "service_exit": result.service_exit})
    return cycles, summary


def _repeatability(result: RunResult) -> dict[str, float]:
    """The simulated robot's repeatability (per axis at the flange), the share its reported pose sees, and the
    rest, which the service cannot correct: a camera pose error per view."""
    sim = result.cell.data["sim"]
    mm, deg = float(sim.get("repeatability_mm", 0.05)), float(sim.get("repeatability_deg", 0.01))
    seen = float(sim.get("reported_repeatability_fraction", 0.0))
    return {"repeatability_mm": mm, "repeatability_deg": deg, "reported_repeatability_fraction": seen,
            "unseen_repeatability_mm": (1.0 - seen) * mm, "unseen_repeatability_deg": (1.0 - seen) * deg}


def _prediction(result: RunResult, repeatability: dict[str, float], job: int) -> dict[str, float | None]:
    """The layout's predicted sigma at the grasp point for a part type of the run's cell and the repeatability
    nobody sees."""
    try:
        return predicted_grasp_sigma(result.cell.config, repeatability["unseen_repeatability_mm"],
                                     repeatability["unseen_repeatability_deg"], job)
    except MonoguideError as error:
        report_error(error, "no predicted sigma for this layout (the grasp target is the paper's 0.5 mm)")
        return {"sigma_mm": None, "sigma_deg": None}


def _seed(data: dict[str, Any]) -> int | None:
    return data.get("sim", {}).get("seed")


def _cleanup(work: Path, keep: bool) -> None:
    if not keep:
        shutil.rmtree(work, ignore_errors=True)


class _progress:  # noqa: N801 - used as a context manager like a function
    """A rich progress bar on a terminal's standard error; plain lines when standard error is not a terminal."""

    def __init__(self, err: Any, total: int) -> None:
        self.err, self.total = err, total
        self.bar: RichProgress | None = None
        self.task: Any = None

    def __enter__(self) -> Progress:
        if self.err.is_terminal:
            self.bar = RichProgress(TextColumn("cycles"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                                    TextColumn("{task.description}"), console=self.err, transient=False)
            self.bar.start()
            self.task = self.bar.add_task("starting", total=self.total)
        return Progress(part=self._part, note=self._note)

    def __exit__(self, *_exc: object) -> None:
        if self.bar is not None:
            self.bar.stop()

    def _part(self, done: int, total: int, record: dict[str, Any]) -> None:
        outcome = _describe(record)
        if self.bar is not None:
            self.bar.update(self.task, completed=done, description=outcome)
        else:
            say(self.err, f"cycle {done}/{total}: {outcome}")

    def _note(self, text: str) -> None:
        say(self.bar.console if self.bar is not None else self.err, text)


def _describe(record: dict[str, Any]) -> str:
    if record.get("result_ok"):
        return "ok"
    code = record.get("error_code")
    outcome = record.get("outcome")
    text = f"error (PLC code {code})" if code else "no result"
    return text if outcome in (None, "acknowledged") else f"{text}; line: {outcome}"
