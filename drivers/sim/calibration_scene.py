"""The simulated person at the cell for ``monoguide calibrate --sim``: does what the wizard asks, on the truth.

:class:`SimOperator` answers the wizard's operator protocol (``ask(action, instruction, **detail)``, the actions
of ``daemon/calibrate/_rig.py``; structural, so the simulator does not import the daemon) by changing the
simulated cell's :class:`~monoguide.drivers.sim.cell.SimScene`, which the in-process simulated camera renders,
and by rewriting the simulated tracker's targets file (the tracker process re-reads it), so that the tracker
measures the nests where the scene has them:

- ``show_plate`` k of n: the circle plate held in front of the camera at the k-th of n well-spread poses
  (:func:`~monoguide.drivers.sim.target_renderer.plate_camera_poses`, seeded with (seed, n));
- ``clear_view``: the plate and every target taken away;
- ``place_smr`` nest: the tracker's beam on that nest: a benchmark (``cell``), a featured hole (``part``), a
  target's nest (``sfi``) or a reference mark's hidden-point nest, named by the mark (``marks``: the SMR's centre
  at the mark's centre, :meth:`~monoguide.drivers.sim.cell.SimCell.smr_positions`);
- ``mount_flange_smr`` / ``unmount_flange_smr``: the SMR on the flange tool (tracker nest ``TCP``, following
  the simulated robot through its truth file) or not;
- ``place_target`` pose i, placement j: target i put down near its place under measuring pose i, a little
  differently for each placement (:func:`~monoguide.drivers.sim.target_renderer.place_target`, seeded with
  (seed, i, j)); ``remove_target`` pose i: taken away;
- ``place_part`` "reference" | k: the reference part as taught, or part k deviated within the cell's
  ``[sim.deviation]`` (seeded with (seed, k)).

Every action is logged (``self.log``, and the ``monoguide.sim.operator`` logger). The operator is the targets
file's only writer while the wizard runs (sim-cell writes it once, before its tracker starts).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

import numpy as np

from monoguide.drivers.sim.cell import FLANGE_NEST, SimCell, SimScene, deviated_part
from monoguide.drivers.sim.target_renderer import place_target, plate_camera_poses

log = logging.getLogger("monoguide.sim.operator")

ACTIONS = ("show_plate", "clear_view", "place_smr", "mount_flange_smr", "unmount_flange_smr", "place_target",
           "remove_target", "place_part")
PLATE_DISTANCE_MM = 650.0  # the plate held about this far in front of the camera (in the lens's depth of field)
PLATE_STREAM, TARGET_STREAM, PART_STREAM = 0x504C4154, 0x54524754, 0x50415254  # "PLAT" "TRGT" "PART"
TARGET_SHIFT_MM, TARGET_TURN_DEG = 30.0, 5.0  # how differently a target is put down at each placement


class SimOperator:
    """Performs the wizard's requests on ``cell`` (its scene) and the tracker's targets file ``targets``
    (None: no tracker process to tell); ``robot_truth``: the simulated controller's truth file, which the
    flange SMR follows. ``seed`` seeds every draw (plate poses, target placements, parts)."""

    def __init__(self, cell: SimCell, targets: str | os.PathLike[str] | None = None,
                 robot_truth: str | os.PathLike[str] | None = None, seed: int = 1) -> None:
        self.cell = cell
        self.targets = Path(targets) if targets is not None else None
        self.robot_truth = Path(robot_truth) if robot_truth is not None else None
        self.seed = seed
        self.log: list[tuple[str, dict[str, Any]]] = []
        if cell.scene is None:
            cell.scene = SimScene(part=cell.spec.T_cf_w0.copy(), beam_on=next(iter(cell.spec.benchmarks_cf), None))
        self.scene: SimScene = cell.scene
        if self.scene.part is not None:
            cell.set_part_pose(self.scene.part)
        self._plate_poses: dict[int, list[np.ndarray]] = {}
        self._write_targets()

    def ask(self, action: str, instruction: str, **detail: Any) -> None:
        """Do what the person at the cell would; ``ValueError`` for an action or detail it does not know."""
        if action not in ACTIONS:
            raise ValueError(f"unknown operator action {action!r}; known: {', '.join(ACTIONS)}")
        self.log.append((action, dict(detail)))
        log.info("%s %s: %s", action, detail, instruction)
        getattr(self, f"_{action}")(**detail)

    # --- the actions -------------------------------------------------------------------------------

    def _show_plate(self, k: int, n: int) -> None:
        if not 0 <= k < n:
            raise ValueError(f"show_plate: position k={k} of n={n} (0 <= k < n)")
        if n not in self._plate_poses:
            plate = self.scene.plate
            rng = np.random.default_rng([self.seed, PLATE_STREAM, n])
            self._plate_poses[n] = plate_camera_poses(plate.centre(), PLATE_DISTANCE_MM, n, rng)
        self.scene.T_c_plate = self._plate_poses[n][k]

    def _clear_view(self) -> None:
        self.scene.T_c_plate = None
        if self.scene.targets:
            self.scene.targets.clear()
            self._write_targets()

    def _place_smr(self, nest: str) -> None:
        self.scene.beam_on = str(nest)
        if nest == FLANGE_NEST and not self.scene.flange_smr:
            log.warning("place_smr %s: the SMR tool is not on the flange (mount_flange_smr first)", nest)
        elif nest != FLANGE_NEST and nest not in self.cell.smr_positions():  # the tracker will say so too
            log.warning("place_smr %s: the simulated cell has no such nest", nest)
        self._write_targets()

    def _mount_flange_smr(self) -> None:
        self.scene.flange_smr = True
        self._write_targets()

    def _unmount_flange_smr(self) -> None:
        self.scene.flange_smr = False
        if self.scene.beam_on == FLANGE_NEST:
            self.scene.beam_on = None
        self._write_targets()

    def _place_target(self, pose: int, placement: int) -> None:
        targets = self.cell.spec.targets
        if not 0 <= pose < len(targets):
            raise ValueError(f"place_target: measuring pose {pose} has no calibration target "
                             f"(the simulated cell has {len(targets)})")
        rng = np.random.default_rng([self.seed, TARGET_STREAM, pose, placement])
        self.scene.targets[pose] = place_target(targets[pose].T_cf_t, rng, TARGET_SHIFT_MM, TARGET_TURN_DEG)
        self._write_targets()

    def _remove_target(self, pose: int) -> None:
        if self.scene.targets.pop(pose, None) is not None:
            self._write_targets()

    def _place_part(self, part: str | int) -> None:
        s = self.cell.spec
        if part == "reference":
            T_cf_w = s.T_cf_w0.copy()
        elif isinstance(part, int) and not isinstance(part, bool) and part >= 1:
            rng = np.random.default_rng([self.seed, PART_STREAM, part])
            T_cf_w = deviated_part(rng, s.T_cf_w0, s.points_w.mean(axis=0), s.deviation_translation_mm,
                                   s.deviation_rotation_deg)
        else:
            raise ValueError(f"place_part: part {part!r}: 'reference' or a number >= 1")
        self.scene.part = T_cf_w
        self.cell.set_part_pose(T_cf_w)
        self._write_targets()

    # --- private -----------------------------------------------------------------------------------

    def _write_targets(self) -> None:
        if self.targets is not None:
            self.cell.write_tracker_targets(self.targets, robot_truth=self.robot_truth)
