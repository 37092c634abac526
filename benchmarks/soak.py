"""Soak of the service with failures: ``monoguide simulate``'s run for many cycles, one part in ten failing, watching
the service. Prints a table; asserts nothing; not part of the test suite.

Runs the simulated cell and ``monoguide run`` as on a line (``daemon/simulate/_run.py``), with ``--fail-every``
(default 10) parts meeting a one-grab camera failure (black, occluded in turn: the cycle fails in its hole finding,
HOLE_NOT_FOUND / LOW_CONTRAST, the costliest way a cycle fails), and samples the service process from ``/proc``
after every part: resident memory, threads, open file descriptors. Prints a line at every tenth of the run, then the
figures at the start and at the end of the run against the targets: resident memory at most 300 MB and flat (the
last quarter's mean within 5 % of the first quarter's, after the first 5 % of warm-up, and at most 1 MB more per
100 failed cycles run between them), no growth of threads or file descriptors (medians of the quarters),
the cycle time (the journal's ``cycle`` timing, trigger -> DONE) at the start and the end, and the journal's size
per cycle (SQLite file with its WAL, and the kept images). With ``--work-dir`` the samples are kept in
``soak-samples.csv``.

    .venv/bin/python benchmarks/soak.py                    # 2,000 cycles (hours: about 3-10 s a cycle)
    .venv/bin/python benchmarks/soak.py --cycles 200 --sharp --move-time 0.05    # a short try (~15 min)
    .venv/bin/python benchmarks/soak.py --sharp --move-time 0.1   # 2,000 cycles in about an hour or two
    .venv/bin/python benchmarks/soak.py --fail-every 0     # no failures

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

from monoguide.daemon.service import JournalRow
from monoguide.daemon.simulate import Progress, RunOptions, run_simulation

RSS_LIMIT_MB = 300.0
FLAT_TOLERANCE = 0.05
MB_PER_100_FAILED = 1.0
ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cycles", type=int, default=2000)
    parser.add_argument("--fail-every", type=int, default=10, help="one part in N fails (0: none)")
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
        result = run_simulation(RunOptions(config, work, args.cycles, host=args.host, fail_every=args.fail_every),
                                progress)
        journal_bytes = sum(p.stat().st_size for p in result.cell.state_dir.glob("journal.sqlite3*"))
        image_bytes = sum(p.stat().st_size for p in (result.cell.state_dir / "images").rglob("*") if p.is_file())
        rows = result.journal_rows
    finally:
        if args.work_dir is None:
            shutil.rmtree(work, ignore_errors=True)
    if args.work_dir is not None:  # the samples, for a plot or another verdict
        with open(args.work_dir / "soak-samples.csv", "w") as out:
            out.write("cycle,status,rss_mb,threads,fds\n")
            for sample in per_cycle:
                k = int(sample["cycle"])
                status = rows[k - 1].status if 1 <= k <= len(rows) else ""
                out.write(f"{k},{status},{sample['rss_mb']:.3f},{sample['threads']:.0f},{sample['fds']:.0f}\n")
    print()
    print(verdict(per_cycle, rows, journal_bytes, image_bytes))


def sim_config(path: Path, work: Path, move_time: float | None, sharp: bool) -> Path:
    """The cell config with the simulator's cost per cycle changed (defocus, robot motion)."""
    (work / "config").mkdir(parents=True, exist_ok=True)
    return cheaper_config(path, work / "config", move_time, sharp, HOST)


def verdict(per_cycle: list[dict[str, float]], rows: list[JournalRow], journal_bytes: int, image_bytes: int) -> str:
    """The table of the run's figures at its start and end against the soak targets."""
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
    failed = [r for r in rows if r.status == "error"]
    # the growth from the first quarter's middle to the last quarter's, per 100 failed cycles run between them (the
    # journal's own growth, SQLite's page cache filling up to its 2 MB, the simulated camera's buffers: all counted)
    span = (first[len(first) // 2]["cycle"], last[len(last) // 2]["cycle"])
    failed_between = sum(1 for k, r in enumerate(rows, 1) if r.status == "error" and span[0] < k <= span[1])
    per_100 = 100 * (rss_last - rss_first) / failed_between if failed_between else float("nan")
    cycle_s = [r.timings_s.get("cycle") for r in rows]
    times = [t for t in cycle_s if isinstance(t, float)]
    q = max(1, len(times) // 4)
    lines = [
        f"{'figure':<48} {'start':>10} {'end':>10} {'target':>16} {'met':>4}",
        _row("resident memory, mean of the quarter (MB)", f"{rss_first:.1f}", f"{rss_last:.1f}",
             f"<= +{100 * FLAT_TOLERANCE:g} %", growth <= FLAT_TOLERANCE),
        _row("resident memory, max (MB)", "", f"{rss_max:.1f}", f"<= {RSS_LIMIT_MB:g}", rss_max <= RSS_LIMIT_MB),
        _row("growth per 100 failed cycles (MB)", "", f"{per_100:+.2f}",
             f"<= {MB_PER_100_FAILED:g}", not per_100 > MB_PER_100_FAILED),
    ]
    for key, name in (("threads", "threads, median of the quarter"),
                      ("fds", "file descriptors, median of the quarter")):
        a, b = statistics.median(s[key] for s in first), statistics.median(s[key] for s in last)
        top = max(s[key] for s in per_cycle)
        lines.append(_row(name + f" (max {top:.0f})", f"{a:.0f}", f"{b:.0f}", "no growth", b <= a))
    if times:
        a, b = statistics.median(times[:q]), statistics.median(times[-q:])
        lines.append(_row("cycle time, median of the quarter (s)", f"{a:.2f}", f"{b:.2f}", "flat (stated)", True))
    lines.append(_row("journal bytes per cycle (SQLite + WAL)", "", f"{journal_bytes / max(len(rows), 1):.0f}",
                      "stated", True))
    lines.append(_row("image bytes kept per cycle", "", f"{image_bytes / max(len(rows), 1):.0f}", "stated", True))
    codes: dict[str, int] = {}
    for r in failed:
        codes[r.error_code or "?"] = codes.get(r.error_code or "?", 0) + 1
    lines.append(f"{n} cycles sampled, {len(rows)} journal rows, {len(failed)} failed "
                 f"({', '.join(f'{c} {k}' for c, k in sorted(codes.items())) or 'none'}); the growth is over the "
                 f"{failed_between} failed cycles between the quarters' middles "
                 f"(cycles {span[0]:.0f} -> {span[1]:.0f})")
    return "\n".join(lines)


def _row(name: str, start: str, end: str, target: str, met: bool) -> str:
    return f"{name:<48} {start:>10} {end:>10} {target:>16} {'yes' if met else 'NO':>4}"


if __name__ == "__main__":
    main()
