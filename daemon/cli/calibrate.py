"""`monoguide calibrate [STEP]`: the calibration wizard (docs/calibration.md, "monoguide calibrate").

Eight steps (:data:`~monoguide.daemon.calibrate.STEPS`; ``marks`` only in a cell with ``[[reference_marks]]``), each
measured on the cell with the laser tracker, the
robot and the camera while the person at the cell is told what to do; every finished step and every refusal goes
into the session file at once, so an interrupted wizard resumes at the first step not done. When all are done
the calibration is written into the cell config (the previous one kept) with a report. ``--sim`` calibrates the
simulated cell and prints each result's error against its truth. The wizard itself is the package
``monoguide.daemon.calibrate``; this module reads the options, wires the prompts and progress to the terminal
and ends the command as ``cli._policy`` says.

A cell of several part types (``[[parts]]``): the run without ``--job`` calibrates the cell-wide steps and the
first part type; ``--job N`` then calibrates part type N's own steps (part, sfi, verify, accuracy) in the session
``CELL.calibration/job-N/`` with the cell's intrinsics, cell frame and robot base, and writes its values and
``[calibration.parts.N]`` into the same cell config.

Exit status: 0 done (or nothing left to do), 1 a step refused or a device failed (the session keeps what was
done), 2 bad options, config or session, 130 interrupted (Ctrl-C, or end of input at a prompt). The line that
says why is ``CODE message`` on standard error (``CALIBRATION_DEGENERATE step 'cell' refused: ...``).
"""

from __future__ import annotations

import contextlib
import json
import sys
import tomllib
from collections.abc import Callable, Iterator
from dataclasses import fields
from pathlib import Path
from typing import Annotated, Any

import typer

from monoguide.daemon.calibrate import (
    CELL_METHODS,
    STEPS,
    CalibrationOptions,
    CalibrationRig,
    CalibrationSession,
    ConsoleOperator,
    accuracy_failed,
    describe,
    open_cell_rig,
    open_session,
    open_sim_rig,
    plan_steps,
    run_step,
    summary,
    write_session_calibration,
    write_session_report,
)
from monoguide.daemon.cli._console import say, stderr_console
from monoguide.daemon.cli._policy import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE, exit_status, fail, report
from monoguide.daemon.config import CELL_STEPS, CellConfig, load_cell_config, read_config_text
from monoguide.daemon.errors import CalibrationAborted, CalibrationSessionInvalid, CalibrationStepNotReady
from monoguide.daemon.packaged import is_packaged, sim_cell_config
from monoguide.drivers.errors import ConfigError
from monoguide.solver.errors import MonoguideError

OPTION_NAMES = tuple(f.name for f in fields(CalibrationOptions))


def calibrate(
    step: Annotated[str | None, typer.Argument(help=f"one step ({', '.join(STEPS)}); default: all, resuming")] = None,
    config: Annotated[Path | None, typer.Option("--config", "-c", help="the cell config (TOML) to calibrate")] = None,
    work_dir: Annotated[Path | None, typer.Option("--work-dir", help="session, report (default CELL.calibration/)")
                        ] = None,
    yes: Annotated[bool, typer.Option("--yes", "-y", help="do not wait for Enter at the prompts")] = False,
    sim: Annotated[bool, typer.Option("--sim", help="calibrate the simulated cell (CELL is its truth)")] = False,
    seed: Annotated[int, typer.Option("--seed", help="--sim: the perturbation's and the noise's seed")] = 1,
    host: Annotated[str | None, typer.Option("--host", help="--sim: loopback address (default: a free one)")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="the last line of output is a JSON summary")] = False,
    restart: Annotated[bool, typer.Option("--restart", help="start a new session (the old one kept .previous)")
                       ] = False,
    from_step: Annotated[str | None, typer.Option("--from", help="redo this step and every later one")] = None,
    values: Annotated[Path | None, typer.Option("--values", help="option values from a TOML or JSON file")] = None,
    plate_images: Annotated[int | None, typer.Option(help="intrinsics: plate images [12]")] = None,
    base_poses: Annotated[int | None, typer.Option(help="robot base: calibration poses 1..N [24]")] = None,
    placements: Annotated[int | None, typer.Option(help="SFi: target placements per measuring pose [10]")] = None,
    visits: Annotated[int | None, typer.Option(help="SFi: robot visits per placement [4]")] = None,
    repeats: Annotated[int | None, typer.Option(help="verify: measurements of the reference part [5]")] = None,
    accuracy_poses: Annotated[int | None, typer.Option(help="accuracy: part poses [5]")] = None,
    tolerance_mm: Annotated[float | None, typer.Option(help="accuracy verdict: dT tolerance, mm [0.5]")] = None,
    tolerance_deg: Annotated[float | None, typer.Option(help="accuracy verdict: dR tolerance, deg [0.05]")] = None,
    cell_method: Annotated[
        str | None, typer.Option(help="cell frame: best-fit or 3-2-1 [the config's cell_frame method]")
    ] = None,
    accept: Annotated[bool, typer.Option("--accept", help="write the calibration even though the accuracy "
                                         "validation failed (its verdict stays in the provenance)")] = False,
    job: Annotated[int | None, typer.Option("--job", help="a part type's steps (part, sfi, verify, accuracy) of a "
                                            "cell of [[parts]]; the cell-wide steps are the run without --job's")
                   ] = None,
) -> None:
    """Calibrate the cell: intrinsics, cell frame, robot base, part, measuring poses, verification, accuracy."""
    cli = {"plate_images": plate_images, "base_poses": base_poses, "placements": placements, "visits": visits,
           "repeats": repeats, "accuracy_poses": accuracy_poses, "tolerance_mm": tolerance_mm,
           "tolerance_deg": tolerance_deg, "cell_method": cell_method}
    try:
        config_path, cfg, given = _check_invocation(step, from_step, config, sim, values, cli)
        job = _check_job(cfg, job, step, from_step)
        work = Path(work_dir) if work_dir is not None else _default_work_dir(config_path)
        method = getattr(getattr(cfg, "cell_frame", None), "method", None)  # [cell_frame] method: a new session's
        session, options = open_session(work, config_path, sim, given, restart=restart,
                                        defaults={"cell_method": method} if method else {}, job=job)
        if job is not None:
            cfg = cfg.for_job(job)
            session.data["part_name"] = cfg.part_name
            _check_cell_steps(session)
        to_run = plan_steps(session, step, from_step, note=_note)
    except MonoguideError as exc:  # ConfigError, CalibrationSessionInvalid, CalibrationStepNotReady
        fail(exc, status=EXIT_USAGE)
    code = EXIT_OK
    if to_run:
        try:
            with _open_rig(cfg, config_path, session, options, sim=sim, seed=seed, host=host, yes=yes) as rig:
                session.data["calibrated_config"] = str(rig.config_path)
                session.check_devices(rig.devices())
                code = run_steps(rig, session, to_run, human=_human_sink(json_out))
        except CalibrationSessionInvalid as exc:
            report(exc)
            code = EXIT_USAGE
        except KeyboardInterrupt:
            report(CalibrationAborted(f"interrupted: the session keeps the {len(session.done())} step(s) done "
                                      f"({session.path}); run the same command again to resume"))
            code = EXIT_INTERRUPTED
        except MonoguideError as exc:  # opening a device
            report(exc)
            code = exit_status(exc)
    elif "calibration_file" in session.data:
        _note(f"all {len(session.steps)} steps are done ({session.path}); --from STEP or --restart to redo")
    calibrated = Path(session.data.get("calibrated_config") or config_path)
    if (code == EXIT_OK and session.next_step() is None and "calibration_file" not in session.data
            and not write_results(session, calibrated, session.path.parent, sim, accept)):
        code = EXIT_FAILED
    if json_out:
        sys.stdout.write(json.dumps(summary(session)) + "\n")
        sys.stdout.flush()
    raise typer.Exit(code)


def run_steps(rig: CalibrationRig, session: CalibrationSession, steps: list[str],
              human: Callable[[str], None] | None = None) -> int:
    """Run ``steps`` in order on ``rig``, each recorded in ``session`` (:func:`run_step`), each result's summary
    to ``human`` (default standard output); returns the exit status: 0, 1 at the first refusal, 130 aborted at a
    prompt. ``KeyboardInterrupt`` passes through (the session is saved)."""
    human = human or _print
    for step in steps:
        try:
            result = run_step(rig, session, step)
        except CalibrationAborted as exc:
            report(CalibrationAborted(f"{exc.message} (the session keeps {len(session.done())} step(s) done)"))
            return EXIT_INTERRUPTED
        except MonoguideError as exc:
            report(exc, f"step '{step}' refused")
            return EXIT_FAILED
        for line in describe(step, result):
            human(line)
    return EXIT_OK


def write_results(session: CalibrationSession, calibrated_config: Path, work: Path, sim: bool,
                  accept: bool = False) -> bool:
    """The calibration into the cell config and the report beside the session; False when the calibration was
    not written (the session keeps every result; running the command again retries). A failed accuracy
    validation keeps the calibration out of the cell config unless ``accept``; the report is written."""
    ok = True
    try:
        if accept and accuracy_failed(session):
            _note("the accuracy validation FAILED; writing the calibration anyway (--accept)")
        _note(f"calibration written into {write_session_calibration(session, calibrated_config, sim, accept)}")
    except MonoguideError as exc:
        report(exc, f"the calibration was not written into {calibrated_config}")
        ok = False
    try:
        _note(f"report: {write_session_report(session, work)}")
    except MonoguideError as exc:
        report(exc, "no report")
    session.save()
    return ok


# --- private ------------------------------------------------------------------------------------


def _note(line: str) -> None:
    """A line of progress or a note on standard error (prompts, progress and errors all go there)."""
    say(stderr_console(), line)


def _print(line: str) -> None:
    print(line, flush=True)


def _human_sink(json_out: bool) -> Callable[[str], None]:
    """Step summaries on standard output, or on standard error when standard output is for --json."""
    return _note if json_out else _print


def _default_work_dir(config_path: Path) -> Path:
    """``CELL.calibration/`` beside the config; for the shipped simulated cell (``--sim`` without --config),
    in the working directory: nothing is ever written beside an installed package's files."""
    folder = config_path.stem + ".calibration"
    return Path(folder) if is_packaged(config_path) else config_path.with_name(folder)


def _check_invocation(step: str | None, from_step: str | None, config: Path | None, sim: bool,
                      values: Path | None, cli: dict[str, Any]) -> tuple[Path, CellConfig, dict[str, Any]]:
    for name, value in (("STEP", step), ("--from", from_step)):
        if value is not None and value not in STEPS:
            raise ConfigError(f"{name} {value!r}: not a step; the steps are {', '.join(STEPS)}")
    if step is not None and from_step is not None:
        raise ConfigError("give a STEP or --from STEP, not both")
    if config is None:
        if not sim:
            raise ConfigError("--config CELL.toml is required (the cell config to calibrate)")
        config = sim_cell_config()
    cfg = load_cell_config(config)
    given = {**_read_values(values), **{k: v for k, v in cli.items() if v is not None}}
    _check_options(given)
    return Path(config), cfg, given


def _check_job(cfg: CellConfig, job: int | None, step: str | None, from_step: str | None) -> int | None:
    """``--job N``: a part type of the cell other than the first (whose steps are the cell's session's), asked only
    for its own steps; None for the cell's session."""
    if job is None:
        return None
    cfg.for_job(job)  # ConfigError naming the cell's jobs
    for name, value in (("STEP", step), ("--from", from_step)):
        if value in CELL_STEPS:
            raise ConfigError(f"{name} {value}: a cell-wide step ({', '.join(CELL_STEPS)}), done once for the cell: "
                              "run it without --job")
    if job == cfg.jobs[0]:
        _note(f"job {job} ({cfg.for_job(job).part_name}) is the cell's first part type: it is calibrated with the "
              "cell, in the session without --job")
        return None
    return job


def _check_cell_steps(session: CalibrationSession) -> None:
    """A part type's session needs the cell's session to have done the cell-wide steps (and opened the cell)."""
    assert session.cell is not None
    missing = [s for s in CELL_STEPS if s not in session.cell.data["steps"]]
    if missing or "calibrated_config" not in session.cell.data:
        raise CalibrationStepNotReady(f"job {session.job}: the cell-wide step(s) {', '.join(missing or CELL_STEPS)} "
                                      f"are not done in the cell's session {session.cell.path}: run "
                                      f"`monoguide calibrate {missing[0] if missing else ''}` without --job first")


def _read_values(path: Path | None) -> dict[str, Any]:
    """``--values FILE``: option values (TOML or JSON, keys as the options' names, ``-`` or ``_``)."""
    if path is None:
        return {}
    text = read_config_text(path, "file of option values", label=f"--values {path}")  # regular, at most 4 MiB
    try:
        data = json.loads(text) if Path(path).suffix.lower() == ".json" else tomllib.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError(f"--values {path}: cannot read it: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"--values {path}: expected a table of option values")
    out = {}
    for key, value in data.items():
        name = str(key).replace("-", "_")
        if name not in OPTION_NAMES:
            raise ConfigError(f"--values {path}: unknown option {key!r}; known: "
                              f"{', '.join(n.replace('_', '-') for n in OPTION_NAMES)}")
        out[name] = value
    return out


def _check_options(given: dict[str, Any]) -> None:
    defaults = CalibrationOptions()
    for name, value in given.items():
        flag = f"--{name.replace('_', '-')}"
        kind = type(getattr(defaults, name))
        if kind is str:
            if value not in CELL_METHODS:
                raise ConfigError(f"{flag} {value!r}: expected one of {', '.join(CELL_METHODS)}")
        elif isinstance(value, bool) or not isinstance(value, (int, float)) or (kind is int and value != int(value)):
            raise ConfigError(f"{flag} {value!r}: expected {'an integer' if kind is int else 'a number'}")
        elif value <= 0:
            raise ConfigError(f"{flag} {value}: must be positive")
        else:
            given[name] = kind(value)


@contextlib.contextmanager
def _open_rig(cfg: CellConfig, config_path: Path, session: CalibrationSession, options: CalibrationOptions, *,
              sim: bool, seed: int, host: str | None, yes: bool) -> Iterator[CalibrationRig]:
    """The simulated cell's rig (``--sim``: its own operator) or the real cell's, with the console operator; a
    part type's session calibrates the config of the cell's session, as its part type sees it."""
    if sim:
        calibrating = Path(session.cell.data["calibrated_config"]) if session.cell is not None else None
        with open_sim_rig(config_path, session.path.parent, options, seed=seed, host=host, progress=_note,
                          job=session.job, calibrating=calibrating) as rig:
            yield rig
    else:
        with open_cell_rig(cfg, config_path, options, ConsoleOperator(yes), _note) as rig:
            yield rig
