"""The wizard's sequence: which steps a run of ``monoguide calibrate`` does, and one step run into the session.

:func:`plan_steps` reads the session and the command's ``STEP`` / ``--from STEP`` (dropping what is redone);
:func:`run_step` runs one step on the rig and records its result, or its refusal, in the session at once, so
that an interrupted wizard resumes at the first step not done. Saying so to the user, and how the command ends,
is the command's (``monoguide.daemon.cli.calibrate``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from monoguide.daemon.calibrate._rig import CalibrationRig, quiet
from monoguide.daemon.calibrate._session import CalibrationSession
from monoguide.daemon.calibrate._steps_check import run_accuracy, run_verify
from monoguide.daemon.calibrate._steps_frames import run_base, run_cell, run_intrinsics
from monoguide.daemon.calibrate._steps_part import run_part, run_sfi
from monoguide.daemon.errors import CalibrationAborted, CalibrationStepNotReady
from monoguide.solver.errors import MonoguideError

StepFunction = Callable[[CalibrationRig, dict[str, dict[str, Any]]], dict[str, Any]]
STEP_FUNCTIONS: dict[str, StepFunction] = {
    "intrinsics": run_intrinsics, "cell": run_cell, "base": run_base, "part": run_part, "sfi": run_sfi,
    "verify": run_verify, "accuracy": run_accuracy}


def plan_steps(session: CalibrationSession, step: str | None, from_step: str | None,
               note: Callable[[str], None] = quiet) -> list[str]:
    """The steps this run does: ``step`` alone (its prerequisites done, else :class:`CalibrationStepNotReady`),
    or every step not done, after dropping ``from_step`` and every later one. What it redoes or resumes goes to
    ``note``; the session is saved."""
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
    done = len(session.done())
    if to_run and done:
        note(f"resuming at step '{to_run[0]}' ({done} of {len(session.steps)} done)")
    return to_run


def run_step(rig: CalibrationRig, session: CalibrationSession, step: str) -> dict[str, Any]:
    """Run ``step`` on ``rig`` with the session's earlier results; its result (with its error against the truth in
    ``--sim``) is recorded in the session and returned. A refusal (any :class:`MonoguideError`) is recorded and
    raised; not recorded: :class:`CalibrationStepNotReady` for a step whose prerequisites are not done,
    :class:`CalibrationAborted` (the person at the cell ended the wizard) and ``KeyboardInterrupt``."""
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
