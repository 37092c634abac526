"""Cycle benchmark (issue 10): where a measuring cycle spends its time. Prints a table; asserts nothing.

Starts ``monoguide sim-cell --no-plc --truth-log`` on the cell config (its robot on 127.0.4.200, its state
file in a temporary folder), builds the camera and the robot as the service does (daemon/assembly.py) and
runs N cycles of daemon/cycle/_runner.py: measure (robot motion, exposure = grab, hole finding in a worker thread
overlapping the next move), solve (with one perspective-correction iteration), check, write (the offset
acknowledged by the simulated controller). For each stage the median, min and max over the cycles, and the
overhead (the last frame in hand -> the offset acknowledged); then the grasp error from the truth log.

The simulated camera renders each 5 MP frame (with the lens's defocus when the config has one), so
"exposure" here is rendering time, not a real camera's; "robot motion" is ``[robot] sim_move_time_s`` per
pose plus the RTDE handshake.

    .venv/bin/python benchmarks/bench_cycle.py                      # 10 cycles of config/sim-cell.toml
    .venv/bin/python benchmarks/bench_cycle.py --cycles 3 --move-time 0.1 --sharp
    .venv/bin/python benchmarks/bench_cycle.py --cycles 12 --sharp --images --compare   # before/after

``--compare`` alternates, cycle by cycle in the same process, the code as it was before the speed-ups of
docs/cycle.md ("before": the whole ROI searched at full resolution on a full-frame grey copy, the offset's
acknowledgement polled every 10 ms, with ``--images`` the last PNG written before the solve) and as it is
("after"), and prints both medians and their ratio: the two see the same load.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from monoguide.daemon.assembly import build_camera, build_robot
from monoguide.daemon.config import load_cell_config
from monoguide.daemon.cycle import CycleRunner
from monoguide.daemon.cycle import _runner as cycle_module
from monoguide.daemon.errors import CycleAborted
from monoguide.drivers import robot as robot_module
from monoguide.solver import holes

STAGES = ("robot_motion", "exposure", "hole_finding", "solve", "checks", "offset_write", "overhead", "cycle")
HOST = "127.0.4.200"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=Path("config/sim-cell.toml"))
    parser.add_argument("--cycles", type=int, default=10)
    parser.add_argument("--move-time", type=float, default=None, help="[robot] sim_move_time_s (s per pose)")
    parser.add_argument("--sharp", action="store_true", help="no simulated defocus (faster rendering)")
    parser.add_argument("--images", action="store_true", help="also save each frame as PNG (as the service does)")
    parser.add_argument("--compare", action="store_true", help="alternate the code before / after the speed-ups")
    parser.add_argument("--host", default=HOST, help="loopback address of the simulated robot")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-cycle-") as folder:
        tmp = Path(folder)
        config_path = cheaper_config(args.config, tmp, args.move_time, args.sharp, args.host)
        truth_log = tmp / "truth.jsonl"
        with sim_cell(config_path, truth_log):
            timings = _run(config_path, args.cycles, tmp / "images" if args.images else None, args.compare)
        parts = [json.loads(line) for line in truth_log.read_text().splitlines()]
    if args.compare:
        _print_compare(timings[0::2], timings[1::2])
    else:
        _print(timings, parts)
    return 0


def cheaper_config(path: Path, tmp: Path, move_time: float | None, sharp: bool, host: str = HOST) -> Path:
    """The cell config with the simulator's cost changed (robot motion, defocus), the devices on ``host``."""
    lines = []
    for line in path.read_text().splitlines():
        key = line.split("=")[0].strip()
        if key == "host" and ("# where" in line or "# the simulated PLC" in line):
            line = f'host = "{host}"' if "# where" in line else f'host = "{host.rsplit(".", 1)[0]}.201"'
        elif key == "sim_move_time_s" and move_time is not None:
            line = f"sim_move_time_s = {move_time}"
        elif key == "aperture_mm" and sharp:
            line = "aperture_mm = 0.0"
        elif key == "state_file":
            continue
        lines.append(line)
        if line.strip() == "[sim]":
            lines.append(f'state_file = "{tmp / "state.json"}"')
    out = tmp / "cell.toml"
    out.write_text("\n".join(lines) + "\n")
    return out


@contextlib.contextmanager
def sim_cell(config_path: Path, truth_log: Path, *options: str) -> Iterator[None]:
    """``monoguide sim-cell --no-plc`` on the config (its truth log at ``truth_log``) while the block runs."""
    process = subprocess.Popen([sys.executable, "-m", "monoguide.daemon.cli", "sim-cell", "--config", str(config_path),
                                "--no-plc", "--truth-log", str(truth_log), *options],
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        _wait_started(process)
        yield
    finally:
        process.send_signal(signal.SIGTERM)
        process.wait(15)
        assert process.stdout is not None
        process.stdout.close()


def _wait_started(process: subprocess.Popen[str]) -> None:
    assert process.stdout is not None
    watchdog = threading.Timer(60.0, process.kill)
    watchdog.start()
    try:
        while True:
            line = process.stdout.readline()
            if not line:
                raise SystemExit("sim-cell did not start")
            if line.startswith("state file"):
                return
    finally:
        watchdog.cancel()


def _run(config_path: Path, cycles: int, images: Path | None, compare: bool = False) -> list[dict[str, float]]:
    config = load_cell_config(config_path)
    camera, robot = build_camera(config), build_robot(config)
    camera.open()
    robot.open()
    out = []
    try:
        runner = CycleRunner(config, camera, robot, images)
        for n in range(cycles):
            before = compare and n % 2 == 0
            _set_before(before)
            start = time.monotonic()
            measurement = runner.measure(1, threading.Event(), lambda: CycleAborted("benchmark stopped"))
            if before:
                cycle_module.wait_images(measurement.images)  # the PNGs were written by the finder, in line
            solution = runner.solve(measurement)
            runner.check(measurement, solution)
            runner.write(solution)
            measurement.timings_s["cycle"] = time.monotonic() - start
            out.append(dict(measurement.timings_s))
            print(f"cycle {n + 1}: {measurement.timings_s['cycle']:.2f} s, rms {solution.quality[0]:.3f} px",
                  file=sys.stderr)
    finally:
        _set_before(False)
        robot.close()
        camera.close()
    return out


_AFTER = (holes._coarse_locate, holes._grey_window, robot_module.ACK_POLL_S)


def _set_before(before: bool) -> None:
    """Switch the speed-ups of docs/cycle.md off (``before``) or on."""
    if before:
        holes._coarse_locate = lambda *args, **kwargs: None  # type: ignore[assignment]
        holes._grey_window = lambda image, roi, r, bit_depth: holes.as_grey(image, bit_depth)  # type: ignore
        robot_module.ACK_POLL_S = robot_module.POLL_S
    else:
        holes._coarse_locate, holes._grey_window, robot_module.ACK_POLL_S = _AFTER


def _print_compare(before: list[dict[str, float]], after: list[dict[str, float]]) -> None:
    print(f"{'stage (median ms)':<18} {'before':>9} {'after':>9} {'after/before':>13}")
    for stage in (*STAGES, "compute"):
        a = [_stage(t, stage) * 1e3 for t in before if stage in t or stage == "compute"]
        b = [_stage(t, stage) * 1e3 for t in after if stage in t or stage == "compute"]
        if a and b:
            ma, mb = statistics.median(a), statistics.median(b)
            print(f"{stage:<18} {ma:>9.1f} {mb:>9.1f} {mb / ma if ma else float('nan'):>13.2f}")
    print(f"{len(before)} cycles before, {len(after)} after, alternating; compute = hole_finding + solve + checks "
          f"+ offset_write")


def _stage(t: dict[str, float], stage: str) -> float:
    if stage == "compute":
        return sum(t.get(k, 0.0) for k in ("hole_finding", "solve", "checks", "offset_write"))
    return t[stage]


def _print(timings: list[dict[str, float]], parts: list[dict]) -> None:
    print(f"{'stage':<14} {'median ms':>10} {'min ms':>9} {'max ms':>9}")
    for stage in STAGES:
        values = [t[stage] * 1e3 for t in timings if stage in t]
        if values:
            print(f"{stage:<14} {statistics.median(values):>10.1f} {min(values):>9.1f} {max(values):>9.1f}")
    errors = np.array([(p["grasp_error_mm"], p["grasp_error_deg"]) for p in parts if p["grasp_error_mm"] is not None])
    if len(errors):
        print(f"grasp error over {len(errors)} parts: median {np.median(errors[:, 0]):.3f} mm / "
              f"{np.median(errors[:, 1]):.4f} deg, max {errors[:, 0].max():.3f} mm / {errors[:, 1].max():.4f} deg")
    print("robot_motion, exposure: sums over the poses; hole_finding: worker time, overlapping the next move; "
          "overhead: last frame -> offset acknowledged; cycle: measure start -> offset acknowledged")


if __name__ == "__main__":
    sys.exit(main())
