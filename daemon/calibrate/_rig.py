"""The calibration wizard's rig: the opened devices, the person at the cell, the options, the steps.

Every step of ``monoguide calibrate`` is a function ``run_<step>(rig, earlier) -> dict`` over a
:class:`CalibrationRig`; the rig is the same for a real cell and for ``--sim`` (only its operator and its
``truth_errors`` differ). The operator is asked to do things by a fixed list of actions (:data:`ACTIONS`);
the console operator prints the instruction and waits for Enter, the simulated one acts on the simulated cell.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Protocol, TextIO

from monoguide.daemon.config import CALIBRATION_STEPS, CellConfig
from monoguide.daemon.errors import CalibrationAborted
from monoguide.drivers.camera import Camera
from monoguide.drivers.robot import Robot
from monoguide.drivers.tracker import LaserTracker

# The actions the wizard asks of the operator and their detail keywords (the complete list):
SHOW_PLATE = "show_plate"  # k: int, n: int -- hold/put the circle plate at position k of n (0-based k) in view
CLEAR_VIEW = "clear_view"  # take the plate / target out of the camera's view
PLACE_SMR = "place_smr"  # nest: str -- put the SMR in tracker nest `nest` ("B1", "P3", "T2.4", a mark's "S1-M2")
MOUNT_FLANGE_SMR = "mount_flange_smr"  # fit the SMR tool on the robot flange (nest "TCP")
UNMOUNT_FLANGE_SMR = "unmount_flange_smr"
PLACE_TARGET = "place_target"  # pose: int, placement: int -- the target under the cell's pose index `pose`
# (0-based: its robot pose number - 1)
REMOVE_TARGET = "remove_target"  # pose: int
PLACE_PART = "place_part"  # part: "reference" | int k >= 1 (a part in a new pose k, for the accuracy validation)

ACTIONS = (
    SHOW_PLATE,
    CLEAR_VIEW,
    PLACE_SMR,
    MOUNT_FLANGE_SMR,
    UNMOUNT_FLANGE_SMR,
    PLACE_TARGET,
    REMOVE_TARGET,
    PLACE_PART,
)

STEPS = CALIBRATION_STEPS  # intrinsics, cell, marks, base, part, sfi, verify, accuracy
MARKS_STEP = "marks"  # only on a cell with [[reference_marks]]: a cell without them skips it

# What each step needs done before it (direct and indirect, so a check needs no closure).
REQUIRES: dict[str, tuple[str, ...]] = {
    "intrinsics": (),
    "cell": (),
    "marks": ("cell",),
    "base": ("cell",),
    "part": ("cell",),
    "sfi": ("intrinsics", "cell"),
    "verify": ("intrinsics", "cell", "base", "part", "sfi"),
    "accuracy": ("intrinsics", "cell", "base", "part", "sfi", "verify"),
}


class Operator(Protocol):
    """What the wizard asks the person at the cell to do. The console operator prints `instruction` and waits for
    Enter (or not, with --yes); the simulated one performs `action` on the simulated cell."""

    def ask(self, action: str, instruction: str, **detail: Any) -> None: ...


@dataclass
class CalibrationOptions:
    """The counts and tolerances of the wizard (each a command-line option and a key of ``--values``)."""

    plate_images: int = 12
    base_poses: int = 24  # robot calibration poses 1..N (wire pose numbers 101..100+N)
    placements: int = 10  # SFi: target placements per measuring pose
    visits: int = 4  # SFi: robot visits per placement
    repeats: int = 5  # verification: measurements of the reference part
    accuracy_poses: int = 5  # Table 3: part poses
    tolerance_mm: float = 0.5  # Table 3 verdict (the paper's requirement)
    tolerance_deg: float = 0.05
    cell_method: str = "best-fit"  # or "3-2-1"
    marks_tolerance_mm: float = 5.0  # marks: a mark measured farther from its nominal position_cf is refused

    def as_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass
class CalibrationRig:
    """The opened devices of the cell being calibrated, the operator, the options and the progress sink."""

    config: CellConfig  # the cell config being calibrated; its calibration values are only NOMINAL
    config_path: Path  # (starting guesses), never assumed true
    tracker: LaserTracker  # opened; measure_point(nest=...) returns the point in the TRACKER's frame
    robot: Robot  # opened; drivers.robot port (+ move_to_calibration_pose)
    camera: Camera  # opened, configured
    operator: Operator
    options: CalibrationOptions
    progress: Callable[[str], None]  # one line of progress for the user (stderr)
    truth_errors: Callable[..., dict[str, float]] | None = None
    # --sim only: truth_errors(step, step_result, earlier_results) -> {"base_mm": ..., ...}; None on a real cell
    sim: bool = False

    def devices(self) -> dict[str, str]:
        """Each device's identity as "vendor model serial" by kind (the session checks them, the provenance names
        them); a device that does not say who it is is left out."""
        out = {}
        for kind, device in (("camera", self.camera), ("tracker", self.tracker), ("robot", self.robot)):
            ident = getattr(device, "identity", None)
            if ident is not None:
                out[kind] = " ".join(str(getattr(ident, k, "")) for k in ("vendor", "model", "serial")).strip()
        return out


def no_marks_message(where: str) -> str:
    """Why a cell without reference marks has no ``marks`` step (``where``: its config)."""
    return (f"{where} has no [[reference_marks]] (the cell's fixed reference marks the marks step surveys, "
            "docs/cell-config.md): there are none to survey")


def quiet(_line: str) -> None:
    """A progress sink that says nothing."""
    return None


class ConsoleOperator:
    """Prints each instruction and waits for Enter (``yes``: does not wait). End of input is the user aborting."""

    def __init__(self, yes: bool, stream: TextIO | None = None, read: Callable[[str], str] = input) -> None:
        self.yes = yes
        self.stream = stream if stream is not None else sys.stderr
        self.read = read

    def ask(self, action: str, instruction: str, **detail: Any) -> None:
        if action not in ACTIONS:
            raise ValueError(f"unknown operator action {action!r}; known: {', '.join(ACTIONS)}")
        if self.yes:
            print(f"> {instruction}", file=self.stream, flush=True)
            return
        print(f"> {instruction}, press Enter", file=self.stream, flush=True)
        try:
            self.read("")
        except EOFError:
            raise CalibrationAborted(
                f"aborted at the prompt {instruction!r} (end of input); run the command again to resume"
            ) from None
