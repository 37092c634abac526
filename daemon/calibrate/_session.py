"""The calibration wizard's session file: what was done, with which options, on which cell.

``<work dir>/calibration-session.json`` holds every finished step's result and every refusal; it is rewritten
atomically (a temporary file, then ``os.replace``) after each step, so an interrupted ``monoguide calibrate``
resumes at the first step not done. A session belongs to one cell config (and to ``--sim`` or not); the
options that shaped a step already done may not change under it (``--from STEP`` or ``--restart`` redo it).
A session file that cannot be read is an error naming it; it is never silently overwritten. The cell's session
does every step of the cell's config: one without ``[[reference_marks]]`` skips ``marks`` (``skipped``, looked
at each time the session is opened).

A cell of several part types calibrates the cell-wide steps (intrinsics, cell, base) and the first part type in
the cell's session; every other part type (``--job N``) in its own session, ``<work dir>/job-N/``, of the
part steps (part, sfi, verify, accuracy) only, which reads the cell-wide results from the cell's session.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, fields
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from monoguide.daemon.calibrate._rig import MARKS_STEP, REQUIRES, STEPS, CalibrationOptions, no_marks_message
from monoguide.daemon.config import CELL_STEPS, PART_STEPS, read_config_toml
from monoguide.daemon.errors import CalibrationSessionInvalid
from monoguide.drivers.atomic_file import write_atomic
from monoguide.drivers.errors import ConfigError
from monoguide.solver.errors import MonoguideError

SESSION_FILE = "calibration-session.json"
SESSION_FORMAT = "monoguide.calibration-session/1"

# the options that shape each step's result: changing one of them after the step is done would mix two sessions
OPTIONS_OF_STEP: dict[str, tuple[str, ...]] = {
    "intrinsics": ("plate_images",),
    "cell": ("cell_method",),
    "marks": ("marks_tolerance_mm",),
    "base": ("base_poses",),
    "part": (),
    "sfi": ("placements", "visits"),
    "verify": ("repeats",),
    "accuracy": ("accuracy_poses", "tolerance_mm", "tolerance_deg"),
}


def now_iso() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def options_from_dict(values: dict[str, Any]) -> CalibrationOptions:
    known = {f.name for f in fields(CalibrationOptions)}
    return CalibrationOptions(**{k: v for k, v in values.items() if k in known})


@dataclass
class CalibrationSession:
    """The session file's content (``data``, the JSON object of docs/calibration.md) and where it lives."""

    path: Path
    data: dict[str, Any]
    cell: CalibrationSession | None = None  # a part type's session (``data["job"]``): the cell's, for its cell steps

    @property
    def steps(self) -> tuple[str, ...]:
        """The steps this session does, in order: all of them but those its cell skips, or a part type's."""
        if self.cell is not None:
            return PART_STEPS
        skipped = self.skipped()
        return tuple(s for s in STEPS if s not in skipped)

    def skipped(self) -> dict[str, str]:
        """The steps of the wizard the cell's session does not do, with why (``marks`` of a cell without
        ``[[reference_marks]]``); none in a part type's session."""
        skipped = self.data.get("skipped") if self.cell is None else None
        return dict(skipped) if isinstance(skipped, dict) else {}

    @property
    def job(self) -> int | None:
        """The part type of a part type's session (``--job N``); None for the cell's session."""
        return self.data.get("job")

    # --- create / load -------------------------------------------------------------------------------

    @classmethod
    def create(cls, path: Path, config: Path, sim: bool, options: CalibrationOptions,
               devices: dict[str, str] | None = None, cell: CalibrationSession | None = None,
               job: int | None = None) -> CalibrationSession:
        """A new, empty session (written at once); with ``cell`` and ``job``, part type ``job``'s."""
        data = {"format": SESSION_FORMAT, "config": str(Path(config).resolve()), "sim": bool(sim),
                "started": now_iso(), "devices": dict(devices or {}), "options": options.as_dict(), "steps": {},
                "refused": {}}
        if cell is not None:
            data["job"] = int(job) if job is not None else None
        else:
            data["skipped"] = skipped_steps(config)
        session = cls(Path(path), data, cell)
        session.save()
        return session

    @classmethod
    def load(cls, path: Path) -> CalibrationSession | None:
        """The session at ``path``; ``None`` when there is none. Anything unreadable raises naming the file."""
        path = Path(path)
        try:
            text = path.read_text()
        except FileNotFoundError:
            return None
        except (OSError, UnicodeDecodeError) as exc:
            raise CalibrationSessionInvalid(f"{path}: cannot read the calibration session: {exc}") from exc
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise CalibrationSessionInvalid(
                f"{path}: the calibration session is corrupt ({exc}); move it away or run with --restart "
                "(it is kept as a .previous copy)") from exc
        if not isinstance(data, dict) or data.get("format") != SESSION_FORMAT:
            found = data.get("format") if isinstance(data, dict) else type(data).__name__
            raise CalibrationSessionInvalid(f"{path}: not a calibration session (format {found!r}, expected "
                                            f"{SESSION_FORMAT!r}); move it away or run with --restart")
        for key, kind in (("steps", dict), ("refused", dict), ("options", dict), ("config", str)):
            if not isinstance(data.get(key), kind):
                raise CalibrationSessionInvalid(f"{path}: the calibration session is corrupt: {key!r} missing or "
                                                f"not a {kind.__name__}; move it away or run with --restart")
        if not isinstance(data.get("skipped", {}), dict):
            raise CalibrationSessionInvalid(f"{path}: the calibration session is corrupt: 'skipped' is not a dict; "
                                            "move it away or run with --restart")
        unknown = sorted(set(data["steps"]) - set(STEPS))
        if unknown:
            raise CalibrationSessionInvalid(f"{path}: the calibration session names unknown step(s) "
                                            f"{', '.join(unknown)}")
        return cls(path, data)

    def check_matches(self, config: Path, sim: bool) -> None:
        """Refuse to go on with a session made for another config, or for ``--sim`` or not."""
        here = str(Path(config).resolve())
        if self.data["config"] != here:
            raise CalibrationSessionInvalid(f"{self.path}: this session calibrates {self.data['config']}, not {here}; "
                                            "use another --work-dir or --restart")
        if bool(self.data.get("sim")) != bool(sim):
            made = "with --sim" if self.data.get("sim") else "without --sim"
            raise CalibrationSessionInvalid(f"{self.path}: this session was made {made}; use another --work-dir or "
                                            "--restart")

    def check_devices(self, devices: dict[str, str]) -> None:
        """Refuse to go on with steps done with another camera, tracker or robot; record the devices (saved)."""
        stored = self.data.get("devices") or {}
        if self.done():
            for kind, name in devices.items():
                if stored.get(kind) and name and stored[kind] != name:
                    raise CalibrationSessionInvalid(
                        f"{self.path}: this session was made with the {kind} {stored[kind]!r}, now {name!r}; "
                        "--restart (or --from the first step that used it)")
        self.data["devices"] = {**stored, **devices}
        self.save()

    def merge_options(self, given: dict[str, Any]) -> CalibrationOptions:
        """The session's options with the explicitly ``given`` ones applied. An option that shaped a step already
        done may not change: that raises naming the option, its two values and the step."""
        stored = self.data.get("options", {})
        conflicts = []
        for step in self.done():
            for name in OPTIONS_OF_STEP.get(step, ()):
                if name in given and name in stored and given[name] != stored[name]:
                    conflicts.append(f"--{name.replace('_', '-')} {given[name]} (step '{step}' was done with "
                                     f"{stored[name]})")
        if conflicts:
            raise CalibrationSessionInvalid(f"{self.path}: options differ from the session's: {'; '.join(conflicts)}; "
                                            "redo those steps with --from STEP, or --restart")
        merged = {**stored, **given}
        options = options_from_dict(merged)
        self.data["options"] = options.as_dict()
        return options

    # --- steps ---------------------------------------------------------------------------------------

    def done(self) -> list[str]:
        """The steps of this session done, in the wizard's order."""
        return [s for s in self.steps if s in self.data["steps"]]

    def results(self) -> dict[str, dict[str, Any]]:
        """The results the steps read: this session's, and a part type's session's cell-wide ones (the marks'
        too: its verification measures with the surveyed marks)."""
        own = {s: self.data["steps"][s] for s in self.done()}
        if self.cell is None:
            return own
        return {**{s: r for s, r in self.cell.results().items() if s in (*CELL_STEPS, MARKS_STEP)}, **own}

    def next_step(self) -> str | None:
        """The first step not done (``None``: all done)."""
        return next((s for s in self.steps if s not in self.data["steps"]), None)

    def missing_for(self, step: str) -> list[str]:
        """The steps ``step`` needs that are not done (a part type's: the cell's session's too)."""
        results = self.results()
        return [s for s in REQUIRES[step] if s not in results]

    def forget(self, step: str) -> list[str]:
        """Drop ``step``'s result and those of the done steps that depend on it; returns the dropped names."""
        dropped = [s for s in self.steps if s in self.data["steps"] and (s == step or step in REQUIRES[s])]
        for s in dropped:
            del self.data["steps"][s]
        return dropped

    def forget_from(self, step: str) -> list[str]:
        """``--from STEP``: drop ``step`` and every later step (and what depends on them)."""
        dropped: list[str] = []
        for s in self.steps[self.steps.index(step):]:
            dropped += [d for d in self.forget(s) if d not in dropped]
        return dropped

    def record_result(self, step: str, result: dict[str, Any]) -> None:
        """Store a finished step (written at once) and clear an earlier refusal of it."""
        self.data["steps"][step] = {**result, "done": now_iso()}
        self.data["refused"].pop(step, None)
        self.save()

    def record_refusal(self, step: str, error: MonoguideError) -> None:
        """Store why a step refused (written at once); its earlier result, if any, is not kept."""
        self.data["steps"].pop(step, None)
        self.data["refused"][step] = {"code": error.code, "plc_code": error.plc_code, "message": str(error),
                                      "at": now_iso()}
        self.save()

    def save(self) -> None:
        """Write atomically: a reader (or a crash) sees the old file or the new one, never half of one."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(self.path, json.dumps(self.data, indent=1, allow_nan=True) + "\n", durable=True)


def skipped_steps(config: Path) -> dict[str, str]:
    """The steps the cell of ``config`` does not do, with why: ``marks`` without ``[[reference_marks]]``. A config
    that cannot be read skips nothing here (loading it says why)."""
    try:
        raw = read_config_toml(config)
    except ConfigError:
        return {}
    return {} if raw.get("reference_marks") else {MARKS_STEP: no_marks_message(str(config))}


def open_session(work_dir: Path, config: Path, sim: bool, given: dict[str, Any], *, restart: bool = False,
                 defaults: dict[str, Any] | None = None, job: int | None = None
                 ) -> tuple[CalibrationSession, CalibrationOptions]:
    """The session of ``work_dir`` to go on with (checked against the cell) and the options to use: the
    built-in defaults, then ``defaults`` (the cell config's; a new session only) or the session's, then ``given``.
    ``restart`` starts afresh, keeping the old file as ``<name>.previous``. With ``job``: part type ``job``'s
    session in ``work_dir/job-<job>/`` (the cell's session must exist: its cell-wide steps are read from it; a new
    part type's session starts from its options)."""
    cell = None
    path = Path(work_dir) / SESSION_FILE
    if job is not None:
        cell = CalibrationSession.load(path)
        if cell is None:
            raise CalibrationSessionInvalid(f"{path}: no calibration session of the cell: calibrate the cell (and its "
                                            f"first part type) without --job first, then --job {job}")
        cell.check_matches(config, sim)
        defaults = {**(defaults or {}), **cell.data.get("options", {})}
        path = Path(work_dir) / f"job-{job}" / SESSION_FILE
    if restart:
        if path.exists():
            os.replace(path, path.with_name(path.name + ".previous"))
        session = None
    else:
        session = CalibrationSession.load(path)
    if session is None:
        options = options_from_dict({**(defaults or {}), **given})
        return CalibrationSession.create(path, config, sim, options, cell=cell, job=job), options
    session.cell = cell
    session.check_matches(config, sim)
    if cell is None:  # the config may have gained or lost its marks since (or the session is older than the step)
        session.data["skipped"] = skipped_steps(config)
    if session.job != job:
        raise CalibrationSessionInvalid(f"{session.path}: this session calibrates job {session.job}, not {job}")
    options = session.merge_options(given)
    session.save()
    return session, options
