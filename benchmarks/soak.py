"""Soak test of the service (issue 11): ``monoguide simulate``'s run for many cycles, watching the service.

Runs the simulated cell and ``monoguide run`` as on a line (``daemon/simulate/_run.py``) and samples the
service process from ``/proc`` after every cycle: resident memory, threads, open file descriptors. Prints
a table at every tenth of the run and the verdict against the targets: resident memory at most 300 MB and
flat (the last quarter's mean within 5 % of the first quarter's, after the first 5 % of warm-up), no
growth of threads or file descriptors, and the journal's size per cycle (SQLite file with its WAL, and the
kept images). Asserts nothing; not part of the test suite.

    .venv/bin/python benchmarks/soak.py                    # 2,000 cycles (hours: about 3-10 s a cycle)
    .venv/bin/python benchmarks/soak.py --cycles 40        # a short try
    .venv/bin/python benchmarks/soak.py --sharp --move-time 0.1   # 2,000 cycles in about an hour

``--sharp`` (no simulated defocus) and ``--move-time`` change only the simulator's cost per cycle (rendering,
robot motion); the service runs the same code either way.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import tempfile
from pathlib import Path
from typing import Any

from bench_cycle import HOST, cheaper_config

from monoguide.daemon.simulate import Progress, RunOptions, run_simulation

RSS_LIMIT_MB = 300.0
FLAT_TOLERANCE = 0.05
ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cycles", type=int, default=2000)
    parser.add_argument("--config", type=Path, default=ROOT / "config" / "sim-cell.toml")
    parser.add_argument("--host", default=None, help="loopback address for the robot and the PLC")
    parser.add_argument("--work-dir", type=Path, default=None, help="keep the run's files here")
    parser.add_argument("--sharp", action="store_true", help="no simulated defocus (faster rendering)")
    parser.add_argument("--move-time", type=float, default=None, help="[robot] sim_move_time_s (s per pose)")
    args = parser.parse_args()
    work = args.work_dir or Path(tempfile.mkdtemp(prefix="monoguide-soak-"))
    config = args.config
    if args.sharp or args.move_time is not None:
        config = sim_config(args.config, work, args.move_time, args.sharp)
    per_cycle: list[dict[str, float]] = []
    latest: dict[str, Any] = {}

    def on_part(done: int, total: int, record: dict[str, Any]) -> None:
        if latest:
            per_cycle.append({"cycle": float(done), **latest})
        if done % max(1, total // 10) == 0 or done == total:
            s = latest or {}
            print(f"cycle {done:>5}/{total}: rss {s.get('rss_mb', float('nan')):7.1f} MB, threads "
                  f"{s.get('threads', float('nan')):3.0f}, fds {s.get('fds', float('nan')):3.0f}", flush=True)

    def on_sample(sample: dict[str, float]) -> None:
        latest.update(sample)

    progress = Progress(part=on_part, note=lambda text: print(text, flush=True), sample=on_sample)
    try:
        result = run_simulation(RunOptions(config, work, args.cycles, host=args.host), progress)
        journal_bytes = sum(p.stat().st_size for p in result.cell.state_dir.glob("journal.sqlite3*"))
        image_bytes = sum(p.stat().st_size for p in (result.cell.state_dir / "images").rglob("*") if p.is_file())
        rows = len(result.journal_rows)
    finally:
        if args.work_dir is None:
            shutil.rmtree(work, ignore_errors=True)
    print()
    print(verdict(per_cycle, rows, journal_bytes, image_bytes))


def sim_config(path: Path, work: Path, move_time: float | None, sharp: bool) -> Path:
    """The cell config with the simulator's cost per cycle changed (defocus, robot motion)."""
    (work / "config").mkdir(parents=True, exist_ok=True)
    return cheaper_config(path, work / "config", move_time, sharp, HOST)


def verdict(per_cycle: list[dict[str, float]], rows: int, journal_bytes: int, image_bytes: int) -> str:
    """The table of the run's figures against the soak targets."""
    n = len(per_cycle)
    if n < 8:
        return f"too few cycles sampled ({n}) for a verdict"
    warm = max(1, n // 20)
    body = per_cycle[warm:]
    quarter = max(1, len(body) // 4)
    first, last = body[:quarter], body[-quarter:]
    rss_first = statistics.fmean(s["rss_mb"] for s in first)
    rss_last = statistics.fmean(s["rss_mb"] for s in last)
    rss_max = max(s["rss_mb"] for s in per_cycle)
    growth = (rss_last - rss_first) / rss_first
    lines = [
        f"{'figure':<46} {'value':>14} {'target':>16} {'met':>4}",
        _row("resident memory, max (MB)", f"{rss_max:.1f}", f"<= {RSS_LIMIT_MB:g}", rss_max <= RSS_LIMIT_MB),
        _row("resident memory, last vs first quarter", f"{100 * growth:+.1f} %", f"<= +{100 * FLAT_TOLERANCE:g} %",
             growth <= FLAT_TOLERANCE),
    ]
    for key, name in (("threads", "threads"), ("fds", "file descriptors")):
        a, b = max(s[key] for s in first), max(s[key] for s in last)
        lines.append(_row(f"{name}, max first -> last quarter", f"{a:.0f} -> {b:.0f}", "no growth", b <= a))
    lines.append(_row("journal bytes per cycle (SQLite + WAL)", f"{journal_bytes / max(rows, 1):.0f}", "stated", True))
    lines.append(_row("image bytes kept per cycle", f"{image_bytes / max(rows, 1):.0f}", "stated", True))
    lines.append(f"{n} cycles sampled, {rows} journal rows")
    return "\n".join(lines)


def _row(name: str, value: str, target: str, met: bool) -> str:
    return f"{name:<46} {value:>14} {target:>16} {'yes' if met else 'NO':>4}"


if __name__ == "__main__":
    main()
