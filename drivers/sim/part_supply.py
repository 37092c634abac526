"""The simulated cell's part supply, run by the simulated robot controller (``docs/probe.md``).

Every cycle starts with a new part: when the first measuring pose of the next part's type is requested (S1 for
the roof), the part in the cell is replaced by part ``n + 1`` (but the reference part of ``robot reference-part``,
which stays until it is grasped: a check job's every visit finds it), deviated from its type's reference by a draw
inside its envelope (:func:`monoguide.solver.envelope.draw_deviation`: the envelope's one definition, per axis
and in total about the type's point ``about_w``; the limits ``[sim.deviation]``'s unless the type gives its
own) seeded with ``([sim] seed, PART_STREAM, n + 1)`` — the same config gives the same
parts in the same order, whatever else was drawn. The types come in the order of ``sim-cell --part-types``
(default: the first part type only); a PLC that asks for another job than the part on the line gets a cell with
the last part still in it. The controller applies offsets to it and scores them; its truth file carries the part's
``T_cf_w`` so that the simulated camera in another process sees the same part
(:func:`monoguide.drivers.sim.robot_motion.follow_truth`).

A part's line in the truth log (JSON lines) is written when its first offset is applied (the robot grasps
it), else when it leaves the cell without one (the next part arrives, or the controller stops) with
``offset_written`` ``null``. Offsets are the six numbers of PLC registers 16–27: x, y, z mm and A, B, C deg
(Z-Y'-X'') in the robot base frame. The part the spec file gives (part 0, before the first S1 request) is
not supplied and not logged.
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path
from typing import Any

import numpy as np

from monoguide.solver.envelope import DeviationEnvelope, draw_deviation
from monoguide.solver.frames import T_to_kuka_frame, compose, invert

log = logging.getLogger("monoguide.sim.parts")

PART_STREAM = 0x50415254  # "PART": the supply's own random stream, apart from the robot's repeatability draws


class PartSupply:
    """Presents seeded deviated parts and writes one truth-log line per part (``log_path``; None: no log).

    ``supply`` (the spec file's ``part_supply``): ``T_cf_b``, ``T_cf_w0``, the envelope's point ``about_w`` (or
    ``centre_w``, its older name), ``translation_mm``, ``rotation_deg`` (+- per axis), optionally ``total_mm``,
    ``total_deg`` (default: the norms); each of ``types`` may give its own of these envelope keys.
    """

    def __init__(self, seed: int, supply: dict[str, Any], T_b_g0: np.ndarray, log_path: Path | None) -> None:
        self.seed = seed
        self.reference_next = False  # the next part is the reference part, as taught (``robot reference-part``)
        self.reference = False  # the current part is
        self.T_cf_b = np.asarray(supply["T_cf_b"], dtype=float)
        self.T_cf_w0 = np.asarray(supply["T_cf_w0"], dtype=float)
        self.supply = supply
        self.types = {int(t["job"]): t for t in supply.get("types", [])}  # type: ignore[attr-defined]
        self.sequence = tuple(int(j) for j in supply.get("sequence", [1]))  # type: ignore[attr-defined]
        if bad := [j for j in self.sequence if self.types and j not in self.types]:
            raise ValueError(f"part types {bad}: not among the cell's ({sorted(self.types)})")
        self.job = self.sequence[0]  # the type of the part in the cell
        self.T_b_w0_type = None if not self.types else np.asarray(self.types[self.job]["T_b_w0"], dtype=float)
        self.T_b_g0_type = None if not self.types else np.asarray(self.types[self.job]["T_b_g0"], dtype=float)
        self.T_b_w0 = compose(invert(self.T_cf_b), self.T_cf_w0)
        self.T_b_g0 = np.asarray(T_b_g0, dtype=float)
        self.log_path = log_path
        self.part = 0
        self.T_cf_w = self.T_cf_w0.copy()
        self._logged = True  # part 0 is not the supply's
        if log_path is not None:
            log_path.write_text("")  # a new run: its parts start again at 1

    @classmethod
    def from_spec_file(cls, spec_path: Path, log_path: Path | None) -> PartSupply:
        data = json.loads(Path(spec_path).read_text())
        if "part_supply" not in data:
            raise ValueError(f"{spec_path}: no part_supply section (written by SimCell.write_robot_spec)")
        return cls(int(data["seed"]), data["part_supply"], np.asarray(data["T_b_g0"], dtype=float), log_path)

    @property
    def T_b_w(self) -> np.ndarray:
        """The current part in the robot base frame."""
        return compose(invert(self.T_cf_b), self.T_cf_w)

    @property
    def reference_state(self) -> str | None:
        """Where the reference part is (``robot reference-part``): ``"in the cell"`` (it lies there until grasped:
        every visit finds it), ``"next"`` (the next part to arrive is it), or None (neither)."""
        if self.reference and not self._logged:
            return "in the cell"
        return "next" if self.reference_next else None

    @property
    def next_job(self) -> int:
        """The type of the part that arrives next."""
        return self.sequence[self.part % len(self.sequence)]

    def starts_cycle(self, pose_number: int) -> bool:
        """A request of this pose brings the next part: the first measuring pose of its type."""
        first = self.types[self.next_job]["first_pose"] if self.types else 1
        return pose_number == first

    def arrive(self) -> np.ndarray:
        """The current part leaves, the next one arrives; returns its true pose in the robot base frame. The reference
        part stays in its nest until the robot grasps it (an offset applied): a check job visits the measuring poses
        several times, and every visit finds it where it lay."""
        if self.reference and not self._logged:
            log.info("part %d (the reference part) stays for another visit", self.part)
            return self.T_b_w
        self.close()
        self.job = self.next_job if self.types else self.job
        self.part += 1
        T_cf_w0, kind = self.T_cf_w0, self.supply
        if self.types:
            kind = self.types[self.job]
            T_cf_w0 = np.asarray(kind["T_cf_w0"], dtype=float)
            self.T_b_w0_type = np.asarray(kind["T_b_w0"], dtype=float)
            self.T_b_g0_type = np.asarray(kind["T_b_g0"], dtype=float)
        self.T_b_w0 = compose(invert(self.T_cf_b), T_cf_w0)
        rng = np.random.default_rng([self.seed, PART_STREAM, self.part])
        self.T_cf_w = compose(T_cf_w0, draw_deviation(rng, supply_envelope(kind, self.supply), np.zeros((1, 3))))
        self.reference, self.reference_next = self.reference_next, False
        if self.reference:
            self.T_cf_w = T_cf_w0.copy()
        self._logged = False
        log.info("part %d (type %d%s) arrives", self.part, self.job, ", the reference part" if self.reference else "")
        return self.T_b_w

    def offset_applied(self, part: int, D_b: np.ndarray, grasp_error_mm: float, grasp_error_deg: float) -> None:
        """The robot applied ``D_b`` to part ``part``: the first one for the current part is its line."""
        if part != self.part or self._logged:
            return
        self._write_line(D_b, grasp_error_mm, grasp_error_deg)

    def close(self) -> None:
        """The current part leaves without an offset (unless it had one): its line, with ``null``s."""
        if not self._logged:
            self._write_line(None, None, None)

    def _write_line(self, D_b: np.ndarray | None, error_mm: float | None, error_deg: float | None) -> None:
        self._logged = True
        if self.log_path is None:
            return
        line = {
            "part": self.part,
            "part_type": self.job,
            **({"reference": True} if self.reference else {}),
            "T_cf_w": self.T_cf_w.tolist(),
            "offset_ideal": list(T_to_kuka_frame(compose(self.T_b_w, invert(self.T_b_w0)))),
            "offset_written": None if D_b is None else list(T_to_kuka_frame(D_b)),
            "grasp_error_mm": error_mm,
            "grasp_error_deg": error_deg,
        }
        with self.log_path.open("a") as f:
            f.write(json.dumps(line) + "\n")


def supply_envelope(kind: dict[str, Any], supply: dict[str, Any]) -> DeviationEnvelope:
    """The envelope a part type ``kind`` is drawn inside: its own keys, else the supply's; its point given (the
    supply does not know the part's holes)."""
    def key(name: str, *older: str) -> Any:
        return next((d[k] for d in (kind, supply) for k in (name, *older) if d.get(k) is not None), None)

    about_w = key("about_w", "centre_w")
    if about_w is None:
        raise ValueError("part_supply: no about_w (the envelope's point in the part frame)")
    return DeviationEnvelope(tuple(key("translation_mm")), tuple(key("rotation_deg")), tuple(about_w),
                             key("total_mm"), key("total_deg"))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The controllers' part-supply options."""
    parser.add_argument("--part-supply", action="store_true",
                        help="present a new seeded deviated part at every request of measuring pose 1")
    parser.add_argument("--truth-log", type=Path, default=None,
                        help="with --part-supply: one JSON line per part (its true pose, offsets, grasp error)")


def from_arguments(args: argparse.Namespace) -> PartSupply | None:
    return PartSupply.from_spec_file(args.spec, args.truth_log) if args.part_supply else None
