"""Job switch benchmark (part types): does changing the job between cycles cost anything? Prints a table; asserts
nothing.

Starts ``monoguide sim-cell --no-plc`` on the cell config with ``--part-types`` set to the benchmark's sequence of
jobs, builds the camera and the robot as the service does (daemon/assembly.py) and runs the cycles as the
service's cycle task does: the job picks its runner (``Runners.for_devices``, one per part type, built the first
time its job comes), then measure, solve, check, write. The sequence interleaves blocks of the same job (1, 1, 1,
1) with blocks of alternating jobs (1, 2, 1, 2), so that both see the same machine load; the overhead (last frame
-> offset acknowledged) and the whole cycle of job 1 are compared between a job-1 cycle after a job-1 cycle
("single") and one right after a job-2 cycle ("after a switch"), and the ratio printed.

    .venv/bin/python benchmarks/bench_job_switch.py                  # 4 rounds of 8 cycles, sharp frames
    .venv/bin/python benchmarks/bench_job_switch.py --rounds 6 --host 127.0.4.210
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

from bench_cycle import cheaper_config, sim_cell

from monoguide.daemon.assembly import build_camera, build_robot
from monoguide.daemon.config import load_cell_config
from monoguide.daemon.cycle import CycleRunner
from monoguide.daemon.errors import CycleAborted
from monoguide.daemon.service._cycle_task import Runners

BLOCK = (1, 1, 1, 1, 1, 2, 1, 2)  # a round: four of job 1, then two switches to job 2 and back


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=Path("config/sim-cell.toml"))
    parser.add_argument("--rounds", type=int, default=4, help=f"rounds of {len(BLOCK)} cycles ({BLOCK})")
    parser.add_argument("--host", default="127.0.4.210", help="loopback address of the simulated robot")
    args = parser.parse_args()
    jobs = BLOCK * args.rounds
    with tempfile.TemporaryDirectory(prefix="bench-jobs-") as folder:
        tmp = Path(folder)
        config_path = cheaper_config(args.config, tmp, 0.05, True, args.host)
        truth_log = tmp / "truth.jsonl"
        with sim_cell(config_path, truth_log, "--part-types", ",".join(map(str, jobs))):
            timings = _run(config_path, jobs)
        parts = [json.loads(line) for line in truth_log.read_text().splitlines()]
    _print(jobs, timings, parts)
    return 0


def _run(config_path: Path, jobs: tuple[int, ...]) -> list[dict[str, float]]:
    config = load_cell_config(config_path)
    camera, robot = build_camera(config), build_robot(config)
    camera.open()
    robot.open()
    runners = Runners(config, lambda cfg, cam, rob, images: CycleRunner(cfg, cam, rob, images))
    out = []
    try:
        for n, job in enumerate(jobs):
            start = time.monotonic()
            runner = runners.for_devices(job, camera, robot, None)
            picked = time.monotonic() - start
            measurement = runner.measure(job, threading.Event(), lambda: CycleAborted("benchmark stopped"))
            solution = runner.solve(measurement)
            runner.check(measurement, solution)
            runner.write(solution)
            measurement.timings_s["cycle"] = time.monotonic() - start
            measurement.timings_s["runner_lookup"] = picked
            out.append(dict(measurement.timings_s))
            print(f"cycle {n + 1} job {job}: {measurement.timings_s['cycle']:.2f} s, overhead "
                  f"{measurement.timings_s['overhead'] * 1e3:.1f} ms, runner {picked * 1e3:.3f} ms", file=sys.stderr)
    finally:
        runners.close()
        robot.close()
        camera.close()
    return out


def _print(jobs: tuple[int, ...], timings: list[dict[str, float]], parts: list[dict]) -> None:
    groups: dict[str, list[dict[str, float]]] = {"job 1, single": [], "job 1, after a switch": [], "job 2": []}
    for n, (job, t) in enumerate(zip(jobs, timings, strict=True)):
        if n < len(BLOCK):
            continue  # the first round builds each runner once: not what a running line pays
        if job == 2:
            groups["job 2"].append(t)
        else:
            groups["job 1, after a switch" if jobs[n - 1] == 2 else "job 1, single"].append(t)
    print(f"{'cycles (median ms)':<24} {'n':>3} {'overhead':>9} {'cycle':>9} {'runner lookup':>14}")
    medians = {}
    for name, group in groups.items():
        overhead = statistics.median(t["overhead"] * 1e3 for t in group)
        cycle = statistics.median(t["cycle"] * 1e3 for t in group)
        lookup = statistics.median(t["runner_lookup"] * 1e3 for t in group)
        medians[name] = (overhead, cycle)
        print(f"{name:<24} {len(group):>3} {overhead:>9.1f} {cycle:>9.1f} {lookup:>14.4f}")
    single, switched = medians["job 1, single"], medians["job 1, after a switch"]
    print(f"after a switch / single: overhead {switched[0] / single[0]:.2f}, cycle {switched[1] / single[1]:.2f} "
          f"(the first round, where each runner is built, left out)")
    ok = [p for p in parts if p.get("grasp_error_mm") is not None]
    by_type = {job: [p["grasp_error_mm"] for p in ok if p.get("part_type") == job] for job in (1, 2)}
    print("grasp error max: " + ", ".join(f"job {job} {max(e):.3f} mm over {len(e)}" for job, e in by_type.items()
                                         if e))


if __name__ == "__main__":
    sys.exit(main())
