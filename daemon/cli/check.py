"""``monoguide check --config CELL.toml``: the calibration check from the command line, with the service stopped.

What PLC job 65535 does inside the service (docs/plc-interface.md, "The check job"; ``daemon.cycle._check``), for
a person at the cell: put the first part type's reference part in its nest as taught, run the command; the robot
visits that part type's measuring poses, the camera measures the part (in a cell with reference marks: the marks
alone, no part needed), and it is compared with the calibration.
Nothing is written to the robot. The check is journaled in the state directory as a cycle of job 65535; a pass
clears a latched ``CALIBRATION_SUSPECT``, a failure latches it (``calibration-health.json``), as the service's own
check does. The service must not run meanwhile (it holds the devices and the journal): the state directory's lock
says so.

Exit status: 0 passed, 1 failed (``CALIBRATION_SUSPECT`` and why) or a device failed, 2 bad options or config, or a
service running on the state directory.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated

import typer

from monoguide.daemon.cli._console import say, stderr_console, stdout_console
from monoguide.daemon.cli._policy import EXIT_OK, EXIT_USAGE, exit_status, fail, report
from monoguide.daemon.config import CellConfig, load_cell_config, require_sections
from monoguide.daemon.errors import CycleAborted
from monoguide.daemon.service import STATE_DIR_HELP, CycleEntry, Journal, ServiceLock, state_dir
from monoguide.drivers.plc_registers import CHECK_JOB
from monoguide.solver.errors import CalibrationSuspect, MonoguideError


def check(
    config: Annotated[Path, typer.Option("--config", "-c", help="the cell config (TOML)")],
    state_dir_: Annotated[Path | None, typer.Option("--state-dir", help=STATE_DIR_HELP)] = None,
    json_out: Annotated[bool, typer.Option("--json", help="the findings as one JSON object on standard output")
                        ] = False,
) -> None:
    """Check the calibration on the reference part, as taught (the service stopped): pass, or CALIBRATION_SUSPECT."""
    try:
        cfg = load_cell_config(config)
        require_sections(cfg, ("robot",), command="check")
        directory = state_dir(state_dir_)
        directory.mkdir(parents=True, exist_ok=True)
        lock = ServiceLock(directory)
        lock.acquire()  # StateDirInUse: a service runs here (it has job 65535 for this)
    except MonoguideError as exc:
        fail(exc, status=EXIT_USAGE)
    try:
        code = _run(cfg, directory, json_out)
    finally:
        lock.release()
    raise typer.Exit(code)


def _run(cfg: CellConfig, directory: Path, json_out: bool) -> int:
    from monoguide.daemon.assembly import build_camera, build_robot
    from monoguide.daemon.cycle import CycleRunner
    from monoguide.daemon.cycle._check import solve_and_check
    from monoguide.daemon.service._health import CalibrationHealth

    out = stderr_console() if json_out else stdout_console()  # --json: standard output is the JSON's
    first = cfg.for_job(cfg.jobs[0])
    health = CalibrationHealth(directory, cfg)
    started = time.time()
    found, error, measurement, solution = None, None, None, None
    camera, robot = build_camera(first), build_robot(first)
    with Journal(directory) as journal:
        number, at = journal.next_number(), datetime.now(UTC).isoformat(timespec="seconds")
        try:
            camera.open()
            robot.open()
            with CycleRunner(first, camera, robot) as runner:
                say(out, f"check: job {first.job} ({first.part_name}), {len(first.measuring_poses)} measuring poses, "
                         + ("the reference marks alone" if runner.has_marks else
                            f"the reference part, {runner.checks.check_visits} visits"))
                abort = threading.Event()
                measurement = runner.measure(first.job, abort, lambda: CycleAborted("check aborted"),
                                             holes=not runner.has_marks)
                visits = 1 if runner.has_marks else runner.checks.check_visits
                more = [runner.measure(first.job, abort, lambda: CycleAborted("check aborted"))
                        for _ in range(visits - 1)]
                solution, found = solve_and_check(runner, measurement, *more)
        except MonoguideError as exc:
            error = exc
        finally:
            for device in (robot, camera):
                device.close()
        journal.commit_cycle(CycleEntry(
            started_at=started, finished_at=time.time(), job=CHECK_JOB, part_tag=0,
            record=None if measurement is None else measurement.record,
            result=None if error is not None or solution is None else solution.result, error=error))
    if isinstance(error, CalibrationSuspect):
        health.latch(error, number, at, CHECK_JOB)
    elif error is None and found is not None:
        health.clear(f"a passing check (monoguide check, cycle {number}: {found['summary']})")
    if json_out:
        sys.stdout.write(json.dumps({"cycle": number, "passed": error is None, "check": found,
                                     "error": None if error is None else error.as_dict()}) + "\n")
    if error is not None:
        report(error, "check failed")
        return exit_status(error)
    assert found is not None
    if found["method"] == "marks":
        views = ", ".join(f"{name} {v['mm']:.3f} mm / {v['deg']:.4f} deg" for name, v in found["views"].items())
    else:
        views = ", ".join(f"{name} {v['px']:.2f} px" for name, v in found["views"].items())
    say(out, f"check passed (cycle {number}): {found['summary']}; views: {views}")
    return EXIT_OK
