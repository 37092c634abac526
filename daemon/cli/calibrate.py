"""`monoguide calibrate [STEP]`: the calibration wizard (docs/calibration.md, "monoguide calibrate").

Seven steps (:data:`~monoguide.daemon.calibrate._rig.STEPS`), each measured on the cell with the laser tracker,
the robot and the camera while the person at the cell is told what to do; every finished step and every
refusal goes into the session file at once, so an interrupted wizard resumes at the first step not done.
When all are done the calibration is written into the cell config (the previous one kept) with a report.
``--sim`` calibrates the simulated cell and prints each result's error against its truth.

Exit status: 0 done (or nothing left to do), 1 a step refused or a device failed (the session keeps what was
done), 2 bad options, config or session, 130 interrupted (Ctrl-C, or end of input at a prompt).
"""

from __future__ import annotations

import contextlib
import json
import sys
import tomllib
from collections.abc import Callable, Iterator
from dataclasses import fields
from importlib import metadata
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
    now_iso,
    open_session,
    run_accuracy,
    run_base,
    run_cell,
    run_intrinsics,
    run_part,
    run_sfi,
    run_verify,
    write_calibration,
    write_report,
)
from monoguide.daemon.config import CellConfig, load_cell_config
from monoguide.daemon.errors import CalibrationAborted, CalibrationSessionInvalid, CalibrationStepNotReady
from monoguide.drivers.errors import ConfigError
from monoguide.solver.errors import MonoguideError

EXIT_OK, EXIT_REFUSED, EXIT_CONFIG, EXIT_INTERRUPTED = 0, 1, 2, 130
STEP_FUNCTIONS: dict[str, Callable[[CalibrationRig, dict[str, dict[str, Any]]], dict[str, Any]]] = {
    "intrinsics": run_intrinsics, "cell": run_cell, "base": run_base, "part": run_part, "sfi": run_sfi,
    "verify": run_verify, "accuracy": run_accuracy}
SUMMARY_KEYS = ("base_mm", "base_deg", "sfi_mm_max", "sfi_deg_max", "focal_rel_error")
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
) -> None:
    """Calibrate the cell: intrinsics, cell frame, robot base, part, measuring poses, verification, accuracy."""
    cli = {"plate_images": plate_images, "base_poses": base_poses, "placements": placements, "visits": visits,
           "repeats": repeats, "accuracy_poses": accuracy_poses, "tolerance_mm": tolerance_mm,
           "tolerance_deg": tolerance_deg, "cell_method": cell_method}
    try:
        config_path, cfg, given = _check_invocation(step, from_step, config, sim, values, cli)
        work = Path(work_dir) if work_dir is not None else _default_work_dir(config_path)
        method = getattr(getattr(cfg, "cell_frame", None), "method", None)  # [cell_frame] method: a new session's
        session, options = open_session(work, config_path, sim, given, restart=restart,
                                        defaults={"cell_method": method} if method else {})
        to_run = plan_steps(session, step, from_step)
    except MonoguideError as exc:  # ConfigError, CalibrationSessionInvalid, CalibrationStepNotReady
        _err(f"error {exc.code}: {exc.message}")
        raise typer.Exit(EXIT_CONFIG) from exc
    code = EXIT_OK
    if to_run:
        try:
            with _open_rig(cfg, config_path, work, options, sim=sim, seed=seed, host=host, yes=yes) as rig:
                session.data["calibrated_config"] = str(rig.config_path)
                session.check_devices(_devices(rig))
                code = run_steps(rig, session, to_run, human=_human_sink(json_out))
        except CalibrationSessionInvalid as exc:
            _err(f"error {exc.code}: {exc.message}")
            code = EXIT_CONFIG
        except KeyboardInterrupt:
            _err(f"interrupted: the session keeps the {len(session.done())} step(s) done ({session.path}); "
                 "run the same command again to resume")
            code = EXIT_INTERRUPTED
        except MonoguideError as exc:  # opening a device
            _err(f"error {exc.code}: {exc.message}")
            code = EXIT_REFUSED
    elif "calibration_file" in session.data:
        _err(f"all {len(STEPS)} steps are done ({session.path}); --from STEP or --restart to redo")
    calibrated = Path(session.data.get("calibrated_config") or config_path)
    if (code == EXIT_OK and session.next_step() is None and "calibration_file" not in session.data
            and not write_results(session, calibrated, work, sim, accept)):
        code = EXIT_REFUSED
    if json_out:
        sys.stdout.write(json.dumps(summary(session)) + "\n")
        sys.stdout.flush()
    raise typer.Exit(code)


def run_steps(rig: CalibrationRig, session: CalibrationSession, steps: list[str],
              human: Callable[[str], None] | None = None) -> int:
    """Run ``steps`` in order on ``rig``, recording each result or refusal in ``session``; returns the exit
    status (0, 1 refused, 130 aborted at a prompt). ``KeyboardInterrupt`` passes through (the session is saved)."""
    human = human or (lambda line: print(line, flush=True))
    for step in steps:
        missing = session.missing_for(step)
        if missing:
            _err(f"step '{step}' needs {', '.join(missing)} first")
            return EXIT_REFUSED
        rig.progress(f"--- step '{step}' ({STEPS.index(step) + 1} of {len(STEPS)})")
        try:
            result = STEP_FUNCTIONS[step](rig, session.results())
        except CalibrationAborted as exc:
            _err(f"{exc.message} (the session keeps {len(session.done())} step(s) done)")
            return EXIT_INTERRUPTED
        except MonoguideError as exc:
            session.record_refusal(step, exc)
            _err(f"step '{step}' refused: {exc.code} (plc_code {exc.plc_code}): {exc.message}")
            return EXIT_REFUSED
        if rig.truth_errors is not None:
            result["truth_error"] = {k: float(v) for k, v in rig.truth_errors(step, result, session.results()).items()}
        session.record_result(step, result)
        for line in describe(step, session.data["steps"][step]):
            human(line)
    return EXIT_OK


def summary(session: CalibrationSession) -> dict[str, Any]:
    """The ``--json`` summary: every truth error of the steps done (``None`` where unknown: on a real cell),
    the steps done, the refusals, and where the calibration and the report went."""
    out: dict[str, Any] = dict.fromkeys(SUMMARY_KEYS)
    for result in session.results().values():
        out.update(result.get("truth_error") or {})
    out.update({"calibration_file": session.data.get("calibration_file"), "report": session.data.get("report"),
                "session": str(session.path), "sim": bool(session.data.get("sim")), "steps_done": session.done(),
                "refused": session.data.get("refused", {})})
    return out


def describe(step: str, r: dict[str, Any]) -> list[str]:
    """A short human summary of one step's result (and its truth error in --sim)."""
    if step == "intrinsics":
        c = r["camera"]
        line = (f"intrinsics: fx {c['fx']:.2f} fy {c['fy']:.2f} cx {c['cx']:.2f} cy {c['cy']:.2f} px, "
                f"k1 {c['k1']:.4g}; RMS {r['rms_px']:.3f} px; {len(r.get('per_image_rms_px', []))} of "
                f"{r.get('images')} images used")
        if r.get("rejected"):
            line += f" ({len(r['rejected'])} rejected)"
    elif step in ("cell", "part"):
        res = r.get("residuals_mm", {})
        worst = max(res, key=res.get) if res else "-"
        what = f"cell frame ({r.get('method')})" if step == "cell" else "part frame"
        line = f"{what}: RMS {r['rms_mm']:.3f} mm, largest {res.get(worst, 0.0):.3f} mm ({worst}), {len(res)} points"
    elif step == "base":
        line = (f"robot base: RMS {r['rms_mm']:.3f} mm over {len(r['residuals_mm'])} poses, largest "
                f"{max(r['residuals_mm']):.3f} mm; sigma {r['sigma_mm']:.4f} mm / {r['sigma_deg']:.5f} deg; SMR on "
                f"the flange at {', '.join(f'{v:.2f}' for v in r['smr_f'])} mm")
    elif step == "sfi":
        poses = r.get("poses", [])
        spread = max((p.get("spread_mm", 0.0) for p in poses), default=0.0)
        line = (f"measuring poses: {len(poses)} SFi, largest spread {spread:.3f} mm; camera on the flange spread "
                f"{_num(r, 'T_f_c_spread_mm', '.3f')} mm / {_num(r, 'T_f_c_spread_deg', '.4f')} deg")
    elif step == "verify":
        line = (f"verification: {r.get('n')} measurements, largest excursion {_num(r, 'max_mm', '.3f')} mm / "
                f"{_num(r, 'max_deg', '.4f')} deg; predicted sigma {_num(r, 'predicted_sigma_mm', '.3f')} mm / "
                f"{_num(r, 'predicted_sigma_deg', '.4f')} deg")
    else:
        verdict = {True: "PASSED", False: "FAILED"}.get(r.get("passed"), "no verdict")
        line = (f"accuracy: RMS dR {_num(r, 'rms_dR_deg', '.4f')} deg, dT {_num(r, 'rms_dT_mm', '.3f')} mm over "
                f"{len(r.get('rows', []))} poses: {verdict}")
    lines = [line]
    if r.get("truth_error"):
        lines.append("  error against the simulated truth: "
                     + ", ".join(f"{k} {v:.4g}" for k, v in r["truth_error"].items()))
    return lines


# --- private ------------------------------------------------------------------------------------


def _num(result: dict[str, Any], key: str, fmt: str) -> str:
    value = result.get(key)
    return format(value, fmt) if isinstance(value, (int, float)) else "?"


def _err(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def _human_sink(json_out: bool) -> Callable[[str], None]:
    """Step summaries on standard output, or on standard error when standard output is for --json."""
    return _err if json_out else (lambda line: print(line, flush=True))


def _default_work_dir(config_path: Path) -> Path:
    """``CELL.calibration/`` beside the config; for the shipped simulated cell (``--sim`` without --config),
    in the working directory: nothing is ever written beside an installed package's files."""
    from monoguide.daemon.packaged import is_packaged

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
        from monoguide.daemon.cli.simulate import default_config

        config = default_config()
    cfg = load_cell_config(config)
    given = {**_read_values(values), **{k: v for k, v in cli.items() if v is not None}}
    _check_options(given)
    return Path(config), cfg, given


def _read_values(path: Path | None) -> dict[str, Any]:
    """``--values FILE``: option values (TOML or JSON, keys as the options' names, ``-`` or ``_``)."""
    if path is None:
        return {}
    try:
        text = Path(path).read_text()
        data = json.loads(text) if Path(path).suffix.lower() == ".json" else tomllib.loads(text)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
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


def plan_steps(session: CalibrationSession, step: str | None, from_step: str | None) -> list[str]:
    """The steps this run does (and the notes on what it redoes or resumes)."""
    if step is not None:
        missing = session.missing_for(step)
        if missing:
            raise CalibrationStepNotReady(f"step '{step}' needs {', '.join(missing)} done first "
                                          f"(monoguide calibrate {missing[0]} ...)")
        dropped = session.forget(step)
        if dropped:
            _err(f"redoing {', '.join(dropped)}" + (" (they depend on it)" if len(dropped) > 1 else ""))
        session.data.pop("calibration_file", None)
        session.save()
        return [step]
    if from_step is not None:
        dropped = session.forget_from(from_step)
        if dropped:
            _err(f"redoing {', '.join(dropped)}")
            session.data.pop("calibration_file", None)
        session.save()
    to_run = [s for s in STEPS if s not in session.data["steps"]]
    done = len(session.done())
    if to_run and done:
        _err(f"resuming at step '{to_run[0]}' ({done} of {len(STEPS)} done)")
    return to_run


@contextlib.contextmanager
def _open_rig(cfg: CellConfig, config_path: Path, work: Path, options: CalibrationOptions, *, sim: bool, seed: int,
              host: str | None, yes: bool) -> Iterator[CalibrationRig]:
    if sim:
        from monoguide.daemon.calibrate import open_sim_rig  # only --sim needs it (it starts sim-cell

        with open_sim_rig(config_path, work, options, seed=seed, host=host, progress=_err) as rig:
            yield rig
        return
    from monoguide.daemon.assembly import build_camera, build_robot, build_tracker, camera_settings

    with contextlib.ExitStack() as stack:
        tracker = build_tracker(cfg)
        tracker.open()
        stack.callback(tracker.close)
        robot = build_robot(cfg)
        robot.open()
        stack.callback(robot.close)
        camera = build_camera(cfg)
        camera.open()
        stack.callback(camera.close)
        camera.configure(camera_settings(cfg))
        yield CalibrationRig(cfg, config_path, tracker, robot, camera, ConsoleOperator(yes), options, _err)


def _devices(rig: CalibrationRig) -> dict[str, str]:
    out = {}
    for kind, device in (("camera", rig.camera), ("tracker", rig.tracker), ("robot", rig.robot)):
        ident = getattr(device, "identity", None)
        if ident is not None:
            out[kind] = " ".join(str(getattr(ident, k, "")) for k in ("vendor", "model", "serial")).strip()
    return out


def write_results(session: CalibrationSession, calibrated_config: Path, work: Path, sim: bool,
                  accept: bool = False) -> bool:
    """The calibration into the cell config and the report beside the session; False when the
    calibration was not written (the session keeps every result; running the command again retries). A failed
    accuracy validation keeps the calibration out of the cell config unless ``accept``; the report is written."""
    provenance = {"date": now_iso(), "session": str(session.path), "wizard_version": metadata.version("monoguide"),
                  "devices": session.data.get("devices", {}), "sim": sim}
    ok = True
    failed = session.results().get("accuracy", {}).get("passed") is False
    if failed and not accept:
        _err(f"the accuracy validation FAILED: the calibration was NOT written into {calibrated_config} (the "
             f"session keeps it). Look at the report, redo a step (--from STEP), or write it anyway with --accept")
        ok = False
    else:
        if failed:
            _err("the accuracy validation FAILED; writing the calibration anyway (--accept)")
        ok = _write_calibration(session, calibrated_config, provenance)
    try:
        session.data["report"] = str(write_report(work, session.data))
        _err(f"report: {session.data['report']}")
    except MonoguideError as exc:
        _err(f"error {exc.code}: no report: {exc.message}")
    session.save()
    return ok


def _write_calibration(session: CalibrationSession, calibrated_config: Path, provenance: dict[str, Any]) -> bool:
    try:
        session.data["calibration_file"] = str(write_calibration(calibrated_config, session.results(), provenance))
        _err(f"calibration written into {session.data['calibration_file']}")
    except MonoguideError as exc:
        _err(f"error {exc.code}: the calibration was not written into {calibrated_config}: {exc.message}")
        return False
    return True
