"""The wizard's sequence: which steps a run of ``monoguide calibrate`` does, and one step run into the session.

:func:`plan_steps` reads the session and the command's ``STEP`` / ``--from STEP`` (dropping what is redone);
:func:`run_step` runs one step on the rig and records its result, or its refusal, in the session at once, so
that an interrupted wizard resumes at the first step not done. The steps of a session are those of its cell: a
cell without ``[[reference_marks]]`` skips ``marks`` (and refuses it asked for by name), a part type's session
does only its own. Saying so to the user, and how the command ends, is the command's
(``monoguide.daemon.cli.calibrate``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from monoguide.daemon.calibrate._rig import CalibrationRig, quiet
from monoguide.daemon.calibrate._session import CalibrationSession
from monoguide.daemon.calibrate._steps_check import run_accuracy, run_verify
from monoguide.daemon.calibrate._steps_frames import run_base, run_cell, run_intrinsics, run_marks
from monoguide.daemon.calibrate._steps_part import run_part, run_sfi
from monoguide.daemon.errors import CalibrationAborted, CalibrationStepNotReady
from monoguide.drivers.errors import ConfigError
from monoguide.solver.errors import MonoguideError

StepFunction = Callable[[CalibrationRig, dict[str, dict[str, Any]]], dict[str, Any]]
STEP_FUNCTIONS: dict[str, StepFunction] = {
    "intrinsics": run_intrinsics, "cell": run_cell, "marks": run_marks, "base": run_base, "part": run_part,
    "sfi": run_sfi, "verify": run_verify, "accuracy": run_accuracy}


def plan_steps(session: CalibrationSession, step: str | None, from_step: str | None,
               note: Callable[[str], None] = quiet) -> list[str]:
    """The steps this run does: ``step`` alone (its prerequisites done, else :class:`CalibrationStepNotReady`),
    or every step not done, after dropping ``from_step`` and every later one. What it redoes or resumes goes to
    ``note``; the session is saved. A step this session does not do (``marks`` of a cell without
    ``[[reference_marks]]``, a cell step in a part type's session) is a :class:`ConfigError` saying why."""
    for name, value in (("STEP", step), ("--from", from_step)):
        if value is not None and value not in session.steps:
            raise not_a_step_of(session, name, value)
    if step is not None:
        missing = session.missing_for(step)
        if missing:
            raise CalibrationStepNotReady(f"step '{step}' needs {', '.join(missing)} done first "
                                          f"(monoguide calibrate {missing[0]} ...)")
        dropped = session.forget(step)
        if dropped:
            note(f"redoing {', '.join(dropped)}" + (" (they depend on it)" if len(dropped) > 1 else ""))
        session.data.pop("calibration_file", None)
        session.save()
        return [step]
    if from_step is not None:
        dropped = session.forget_from(from_step)
        if dropped:
            note(f"redoing {', '.join(dropped)}")
            session.data.pop("calibration_file", None)
        session.save()
    to_run = [s for s in session.steps if s not in session.data["steps"]]
    if to_run:
        session.data.pop("calibration_file", None)  # a step added to the cell since (its marks): written again
        for skipped, why in session.skipped().items():
            note(f"skipping step '{skipped}': {why}")
    done = len(session.done())
    if to_run and done:
        note(f"resuming at step '{to_run[0]}' ({done} of {len(session.steps)} done)")
    return to_run


def run_step(rig: CalibrationRig, session: CalibrationSession, step: str) -> dict[str, Any]:
    """Run ``step`` on ``rig`` with the session's earlier results; its result (with its error against the truth in
    ``--sim``) is recorded in the session and returned. A refusal (any :class:`MonoguideError`) is recorded and
    raised; not recorded: :class:`CalibrationStepNotReady` for a step whose prerequisites are not done,
    :class:`CalibrationAborted` (the person at the cell ended the wizard) and ``KeyboardInterrupt``."""
    if step not in session.steps:
        raise not_a_step_of(session, "STEP", step)
    missing = session.missing_for(step)
    if missing:
        raise CalibrationStepNotReady(f"needs {', '.join(missing)} done first")
    of_job = f" of job {session.job} ({rig.config.part_name})" if session.job is not None else ""
    rig.progress(f"--- step '{step}'{of_job} ({session.steps.index(step) + 1} of {len(session.steps)})")
    try:
        result = STEP_FUNCTIONS[step](rig, session.results())
    except CalibrationAborted:
        raise
    except MonoguideError as exc:
        session.record_refusal(step, exc)
        raise
    if rig.truth_errors is not None:
        result["truth_error"] = {k: float(v) for k, v in rig.truth_errors(step, result, session.results()).items()}
    session.record_result(step, result)
    return session.data["steps"][step]


def not_a_step_of(session: CalibrationSession, name: str, step: str) -> ConfigError:
    """Why ``step`` (given as ``name``: STEP or --from) is not one of ``session``'s steps."""
    if step in session.skipped():
        return ConfigError(f"{name} {step}: {session.skipped()[step]}")
    if session.cell is not None and step in STEP_FUNCTIONS:
        return ConfigError(f"{name} {step}: a step of the cell's session, done once for the cell: run it without "
                           "--job")
    return ConfigError(f"{name} {step!r}: not a step; the steps are {', '.join(session.steps)}")
