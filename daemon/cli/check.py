"""``monoguide check --config CELL.toml``: the calibration check from the command line, with the service stopped.

What PLC job 65535 does inside the service (docs/plc-interface.md, "The check job"; ``daemon.cycle._check``), for
a person at the cell: put the first part type's reference part in its nest as taught, run the command; the robot
visits that part type's measuring poses, the camera measures the part (in a cell with reference marks: the marks
alone, no part needed), and it is compared with the calibration.
Nothing is written to the robot. The check is journaled in the state directory as a cycle of job 65535; a pass
clears a latched ``CALIBRATION_SUSPECT``, a failure latches it (``calibration-health.json``), as the service's own
check does. The service must not run meanwhile (it holds the devices and the journal): the state directory's lock
says so.

On the simulated cell (``[robot] backend`` ``sim-ur`` or ``sim-kuka``: the devices of a running ``monoguide
sim-cell``, found through its state file, ``--state-file`` or ``[sim] state_file``) the command puts the reference
part in its nest itself: it asks sim-cell for it (``robot reference-part``, through the command pipe the state file
names) before the robot moves; where sim-cell cannot be asked, it says which command to type into sim-cell's
standard input, and moves nothing. A real cell is not asked anything.

Every failure is one line on standard error, ``CODE message``. Exit status (``daemon/cli/_policy.py``): 0 passed, 1
failed (``CALIBRATION_SUSPECT`` and why), a device failed (``DEVICE_NOT_FOUND``: no sim-cell running, ...) or a
service runs on the state directory (``STATE_DIR_IN_USE``, as ``run`` says it), 2 bad options or config
(``STATE_DIR_INVALID``, ``CONFIG_...``).
"""

from __future__ import annotations

import json
import sys
import threading
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console

from monoguide.daemon.cli._console import say, stderr_console, stdout_console
from monoguide.daemon.cli._policy import EXIT_OK, exit_status, fail, report
from monoguide.daemon.config import CellConfig, load_cell_config, require_sections
from monoguide.daemon.errors import CycleAborted, StateDirInvalid
from monoguide.daemon.service import STATE_DIR_HELP, CycleEntry, Journal, ServiceLock, create_state_dir, state_dir
from monoguide.drivers.plc_registers import CHECK_JOB
from monoguide.solver.errors import CalibrationSuspect, MonoguideError

if TYPE_CHECKING:
    from monoguide.daemon.cycle._record import Measurement, Solution
    from monoguide.drivers.camera import Camera
    from monoguide.drivers.robot import Robot

def check(
    config: Annotated[Path, typer.Option("--config", "-c", help="the cell config (TOML)")],
    state_dir_: Annotated[Path | None, typer.Option("--state-dir", help=STATE_DIR_HELP)] = None,
    state_file: Annotated[Path | None, typer.Option(
        "--state-file", help="the simulated cell: sim-cell's state file (default: [sim] state_file)")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="the findings as one JSON object on standard output")
                        ] = False,
) -> None:
    """Check the calibration on the reference part, as taught (the service stopped): pass, or CALIBRATION_SUSPECT."""
    try:
        cfg = load_cell_config(config)
        require_sections(cfg, ("robot",), command="check")
        directory = state_dir(state_dir_)
        create_state_dir(directory)
        lock = ServiceLock(directory)
        try:
            lock.acquire()  # StateDirInUse: a service runs here (it has job 65535 for this)
        except OSError as exc:
            raise StateDirInvalid(f"state directory {directory}: cannot take its lock {lock.path}: "
                                  f"{exc.strerror or exc}") from None
    except MonoguideError as exc:
        fail(exc)
    try:
        code = _run(cfg, directory, state_file, json_out)
    except MonoguideError as exc:  # the journal cannot be opened or written
        fail(exc, "check")
    finally:
        lock.release()
    raise typer.Exit(code)


def _run(cfg: CellConfig, directory: Path, state_file: Path | None, json_out: bool) -> int:
    from monoguide.daemon.service._health import CalibrationHealth

    out = stderr_console() if json_out else stdout_console()  # --json: standard output is the JSON's
    health = CalibrationHealth(directory, cfg)
    started = time.time()
    with Journal(directory) as journal:
        number, at = journal.next_number(), datetime.now(UTC).isoformat(timespec="seconds")
        measurement, solution, found, error = _measure(cfg.for_job(cfg.jobs[0]), state_file, out)
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


def _measure(first: CellConfig, state_file: Path | None, out: Console
             ) -> tuple[Measurement | None, Solution | None, dict[str, Any] | None, MonoguideError | None]:
    """The check on part type ``first``'s measuring poses: (measurement, solution, findings, error); a device that
    cannot be found or opened, or a check that fails, is the error (journaled by the caller), never raised."""
    from monoguide.daemon.assembly import build_camera, build_robot, sim_state_file
    from monoguide.daemon.cycle import CycleRunner
    from monoguide.daemon.cycle._check import solve_and_check

    measurement: Measurement | None = None
    solution: Solution | None = None
    found: dict[str, Any] | None = None
    devices: list[Camera | Robot] = []
    try:
        camera = build_camera(first, state_file=state_file)
        devices.append(camera)
        robot = build_robot(first, state_file)
        devices.append(robot)
        camera.open()
        robot.open()
        with CycleRunner(first, camera, robot) as runner:
            say(out, f"check: job {first.job} ({first.part_name}), {len(first.measuring_poses)} measuring poses, "
                     + ("the reference marks alone" if runner.has_marks else
                        f"the reference part, {runner.checks.check_visits} visits"))
            assert first.robot is not None  # require_sections
            if first.robot.simulated and not runner.has_marks:  # the simulated cell presents it (before any move)
                from monoguide.daemon.simulate import present_reference_part

                say(out, present_reference_part(state_file or sim_state_file(first), first.job))
            abort = threading.Event()
            measurement = runner.measure(first.job, abort, lambda: CycleAborted("check aborted"),
                                         holes=not runner.has_marks)
            visits = 1 if runner.has_marks else runner.checks.check_visits
            more = [runner.measure(first.job, abort, lambda: CycleAborted("check aborted"))
                    for _ in range(visits - 1)]
            solution, found = solve_and_check(runner, measurement, *more)
    except MonoguideError as exc:
        return measurement, solution, found, exc
    finally:
        for device in reversed(devices):  # the robot, then the camera
            device.close()
    return measurement, solution, found, None
