"""What a calibration fault costs today (issue 20, "Why" and item 5). Prints a table; asserts nothing.

For each fault, one ``monoguide simulate --json --jobs 1`` (the roof, the issue's cell) as a subprocess, each on its
own loopback address and work directory: no fault (``--cycles N``), and each calibration fault of sim-cell
(``--fault F --cycles N+2``: a good part, the fault on the next N parts, cleared, a good part;
docs/simulate.md, "--faults"). Per fault: the cycles under it that were ok, those refused (with their codes), the
grasp error RMS / max of the ok ones from the truth log (mm), and the ok ones beyond the paper's 0.5 mm — the
confident wrong answers. ``--files`` adds the camera bumps the issue's way too: the service on a calibration file
whose ``T_f_c`` and ``T_cf_si`` were right-multiplied by the bump's inverse (benchmarks/make_bumped_calibration.py),
``--calibration FILE --cycles N`` (every cycle bumped).

    .venv/bin/python benchmarks/bench_calibration_faults.py                 # 8 cycles per fault, seed 5: minutes
    .venv/bin/python benchmarks/bench_calibration_faults.py --cycles 4 --files
    .venv/bin/python benchmarks/bench_calibration_faults.py --config config/sim-cell-marks.toml   # with marks
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from make_bumped_calibration import SIM_CELL, bumped_calibration

REPO = Path(__file__).parents[1]
MONOGUIDE = [sys.executable, "-m", "monoguide.daemon.cli"]
REQUIREMENT_MM = 0.5
HOST_BASE = 10  # 127.0.33.10 and up: each run its own robot and PLC address
RUN_TIMEOUT_S = 1800.0

# (what the table calls it, the sim-cell command; None: no fault)
FAULTS: tuple[tuple[str, str | None], ...] = (
    ("no fault", None),
    ("camera bump 1 mm along x", "camera bump 0 1 x"),
    ("camera bump 0.1 deg about x", "camera bump 0.1 0 x"),
    ("camera bump 0.3 deg about y", "camera bump 0.3 0 y"),
    ("camera focal +0.5 %", "camera focal 0.5"),
    ("pose drift 1 0.3 mm 0.05 deg", "pose drift 1 0.3 0.05"),
)
BUMP_FILES = (("bump file 1 mm along x", 0.0, 1.0, "x"), ("bump file 0.1 deg about x", 0.1, 0.0, "x"),
              ("bump file 0.3 deg about y", 0.3, 0.0, "y"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=8, help="cycles under each fault (default 8)")
    parser.add_argument("--seed", type=int, default=5, help="[sim] seed of every run (default 5)")
    parser.add_argument("--files", action="store_true", help="also the camera bumps as calibration files")
    parser.add_argument("--config", type=Path, default=None, help="the simulated cell (default config/sim-cell.toml; "
                        "config/sim-cell-marks.toml: with reference marks)")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-calibration-faults-") as tmp:
        work = Path(tmp)
        runs: list[tuple[str, list[str], str | None]] = []
        for name, fault in FAULTS:
            extra = ["--cycles", str(args.cycles)] if fault is None else [
                "--fault", fault, "--cycles", str(args.cycles + 2)]
            runs.append((name, extra, fault))
        if args.files:
            for name, deg, mm, axis in BUMP_FILES:
                path = work / f"bumped-{deg:g}-{mm:g}-{axis}.toml"
                path.write_text(bumped_calibration((args.config or SIM_CELL).read_text(), deg, mm, axis))
                runs.append((name, ["--calibration", str(path), "--cycles", str(args.cycles)], None))
        for n, (name, extra, fault) in enumerate(runs):
            config = [] if args.config is None else ["--config", str(args.config.resolve())]
            command = [*MONOGUIDE, "simulate", "--json", "--jobs", "1", "--seed", str(args.seed), *config, "--host",
                       f"127.0.33.{HOST_BASE + n}", "--work-dir", str(work / f"run-{n}"), *extra]
            print(f"running: monoguide {shlex.join(command[3:])}", file=sys.stderr, flush=True)
            started = time.monotonic()
            rows.append((name, _outcome(_run(command), fault), time.monotonic() - started))
    _print_table(rows, args)


def _run(command: list[str]) -> list[dict[str, Any]]:
    done = subprocess.run(command, capture_output=True, text=True, cwd=REPO, timeout=RUN_TIMEOUT_S)
    if done.returncode != 0:
        sys.exit(f"monoguide simulate exited {done.returncode}: {done.stderr.strip().splitlines()[-1:]}")
    return [json.loads(line) for line in done.stdout.splitlines() if line.strip()]


def _outcome(lines: list[dict[str, Any]], fault: str | None) -> dict[str, Any]:
    """Cycles ok, refused (codes), the grasp errors of the ok ones: under the fault, or over the run."""
    summary = lines[-1]
    if fault is not None:
        (injected,) = summary["faults"]
        return {"cycles": len(injected["cycles"]), "ok": injected["ok"], "refused": injected["refused"],
                "mm": injected["grasp_errors_mm"], "deg": injected["grasp_errors_deg"]}
    cycles = [c for c in lines[:-1] if not c.get("summary")]
    ok = [c for c in cycles if c["status"] == "ok"]
    refused: dict[str, int] = {}
    for c in cycles:
        if c["status"] != "ok":
            code = c["error_code"] or f"PLC_CODE_{c['plc_code']}"
            refused[code] = refused.get(code, 0) + 1
    return {"cycles": len(cycles), "ok": len(ok), "refused": refused,
            "mm": [c["grasp_error_mm"] for c in ok if c["grasp_error_mm"] is not None],
            "deg": [c["grasp_error_deg"] for c in ok if c["grasp_error_deg"] is not None]}


def _print_table(rows: list[tuple[str, dict[str, Any], float]], args: argparse.Namespace) -> None:
    print(f"monoguide simulate --jobs 1 (the roof) on {args.config or 'config/sim-cell.toml'}, seed {args.seed}, "
          f"{args.cycles} cycles under each fault; grasp error from the truth log")
    header = (f"{'fault':<30} {'cycles ok':>10} {'refused (codes)':<52} {'grasp RMS / max, mm':>20} "
              f"{'ok > 0.5 mm':>12} {'run s':>6}")
    print(header)
    print("-" * len(header))
    for name, o, seconds in rows:
        codes = ", ".join(f"{n} {code}" for code, n in sorted(o["refused"].items()))
        refused = f"{sum(o['refused'].values())}" + (f" ({codes})" if codes else "")
        grasp = f"{_rms(o['mm']):.3f} / {max(o['mm']):.3f}" if o["mm"] else "-"
        beyond = sum(v > REQUIREMENT_MM for v in o["mm"])
        print(f"{name:<30} {o['ok']:>4} of {o['cycles']:<3} {refused:<52} {grasp:>20} {beyond:>12} "
              f"{seconds:>6.0f}")


def _rms(values: list[float]) -> float:
    return math.sqrt(sum(v * v for v in values) / len(values))


if __name__ == "__main__":
    main()
