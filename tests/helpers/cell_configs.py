"""Copies of config/sim-cell.toml written for a test: on the test's own loopback addresses, with the PLC section
a test plays against, with the measuring poses straight down (as before they were planned)."""

from __future__ import annotations

import re
from collections.abc import Iterable
from pathlib import Path

from helpers.repository import SIM_CELL, SINGLE_PART_SIM_CELL
from monoguide.daemon.config import load_cell_config
from monoguide.solver.frames import compose
from monoguide.solver.planning import look_at_poses


def cell_config(tmp_path: Path, robot_host: str, plc_host: str | None = None, *, sharp: bool = False,
                state_file: Path | None = None, more: Iterable[tuple[str, str]] = (), extra: str = "",
                name: str = "cell.toml", source: Path = SIM_CELL) -> Path:
    """config/sim-cell.toml (or ``source``, another simulated cell) with the robot on ``robot_host`` and the PLC on
    ``plc_host`` (default: the next address), quick robot moves; ``sharp``: no defocus blur (each rendering ~5 times
    faster, for tests whose subject is not the hole finder's blur tolerance); ``state_file`` into ``[sim]``; ``more``
    further exact one-time replacements; ``extra`` appended (further sections)."""
    if plc_host is None:
        prefix, last = robot_host.rsplit(".", 1)
        plc_host = f"{prefix}.{int(last) + 1}"
    replacements = [('host = "127.0.0.1"  # where', f'host = "{robot_host}"  # where'),
                    ('host = "127.0.0.1"  # the simulated PLC', f'host = "{plc_host}"  # the simulated PLC'),
                    ("sim_move_time_s = 0.5", "sim_move_time_s = 0.05")]
    if sharp:
        replacements.append(("aperture_mm = 1.4867", "aperture_mm = 0.0"))
    if state_file is not None:
        replacements.append(("[sim]\n", f'[sim]\nstate_file = "{state_file}"\n'))
    text = source.read_text()
    for old, new in (*replacements, *more):
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    path = tmp_path / name
    path.write_text(text + extra)
    return path


def plc_cell_config(tmp_path: Path, host: str, port: int, heartbeat_timeout_s: float = 1.0,
                    ack_timeout_s: float = 2.0, extra: str = "") -> Path:
    """config/sim-cell.toml with its ``[plc]`` section replaced: the PLC at ``host``:``port`` with these timeouts
    (the service's PLC link against a PLC the test plays); ``extra`` appended (further sections)."""
    text = SIM_CELL.read_text()
    text = re.sub(r"\[plc\].*?(?=\n\[sim\])", f"[plc]\nhost = \"{host}\"\nport = {port}\nheartbeat_timeout_s = "
                  f"{heartbeat_timeout_s}\nack_timeout_s = {ack_timeout_s}\ntimeout_s = 0.5\n", text, flags=re.S)
    path = tmp_path / "cell.toml"
    path.write_text(text + extra)
    return path


def straight_down_cell(tmp_path: Path, extra: str = "") -> Path:
    """The simulated cell with the pre-issue-8 measuring poses (straight down from 650 mm, holes a quarter
    from the edge), written by hand; ``extra`` replaces the [layout] table's depth of field, say."""
    text = SINGLE_PART_SIM_CELL.read_text()  # its poses name the holes they see
    config = load_cell_config(SINGLE_PART_SIM_CELL)
    poses = [compose(config.reference.T_cf_w0, T) for T in
             look_at_poses(config.part.points_w, config.camera.intrinsics, 650.0)]
    start, end = text.index("[[measuring_poses]]"), text.index("[tracker]")
    blocks = ""
    for i, T in enumerate(poses):
        rows = ",\n".join("    [" + ", ".join(f"{v:.12f}" for v in row) + "]" for row in T)
        blocks += f'[[measuring_poses]]\nname = "S{i + 1}"\npoints = [{i}]\nT_cf_si = [\n{rows},\n]\n\n'
    text = text[:start] + blocks + text[end:]
    if extra:
        text = re.sub(r"depth_of_field_mm = \[[^\]]*\]", extra, text)
    path = tmp_path / "cell.toml"
    path.write_text(text)
    return path
