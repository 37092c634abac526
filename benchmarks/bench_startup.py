"""How long each command takes to start and answer: the median of ``--repeats`` runs of the installed
``monoguide`` (a process each, as a user or a script runs it), beside two peers measured in the same run: the bare
interpreter and an interpreter that only imports the CLI framework (typer and rich), which every command pays
for. Prints a table; asserts nothing.

Commands: ``--version``; ``status`` and ``journal list`` on a state directory with a journal of ``--rows`` cycles
(no service running: ``status`` exits 3); ``solve`` of the example record; ``detect`` of a rendered hole image.
``solve`` and ``detect`` load numpy, SciPy and OpenCV: their figure is what those cost.

    .venv/bin/python benchmarks/bench_startup.py
    .venv/bin/python benchmarks/bench_startup.py --repeats 20
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).parents[1]
MONOGUIDE = Path(sys.executable).parent / "monoguide"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--rows", type=int, default=1000, help="cycles in the journal status and list read")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="monoguide-bench-startup-") as tmp:
        state_dir, image = _journal(Path(tmp), args.rows), _image(Path(tmp))
        runs = {
            "python (bare interpreter)": [sys.executable, "-c", "pass"],
            "python -c 'import typer, rich' (the CLI's floor)": [
                sys.executable, "-c", "import typer, rich.console, typer.core"],
            "monoguide --version": [str(MONOGUIDE), "--version"],
            "monoguide status": [str(MONOGUIDE), "status", "--state-dir", str(state_dir)],
            "monoguide journal list": [str(MONOGUIDE), "journal", "list", "--state-dir", str(state_dir)],
            "monoguide solve example-record.json": [str(MONOGUIDE), "solve",
                                                    str(ROOT / "examples" / "example-record.json")],
            "monoguide detect one image": [str(MONOGUIDE), "detect", str(image)],
        }
        medians = {}
        for name, argv in runs.items():
            samples = []
            for _ in range(args.repeats):
                start = time.perf_counter()
                subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False, cwd=tmp)
                samples.append(time.perf_counter() - start)
            medians[name] = statistics.median(samples)
    floor = medians["python -c 'import typer, rich' (the CLI's floor)"]
    print(f"median wall time of {args.repeats} runs each (s); the journal holds {args.rows} cycles")
    print(f"{'command':<52}{'median s':>10}{'over the CLI floor s':>22}")
    for name, seconds in medians.items():
        print(f"{name:<52}{seconds:>10.3f}{seconds - floor:>22.3f}")


def _journal(tmp: Path, rows: int) -> Path:
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bench_journal import _build

    state_dir = tmp / "state"
    _build(state_dir, rows, kept=min(rows, 100))
    return state_dir


def _image(tmp: Path) -> Path:
    import cv2
    import numpy as np

    image = np.full((600, 800), 200, np.uint8)
    cv2.circle(image, (400, 300), 30, 30, -1)
    path = tmp / "hole.png"
    cv2.imwrite(str(path), image)
    return path


if __name__ == "__main__":
    main()
