"""Journal cost against its length: journals of 10k, 100k and 1M rows (1M rows is about 500 days of a
2,000-parts-a-day line), and the time of what the service and the readers do with them. Prints a table;
asserts nothing.

Each row is a copy of a realistic cycle (the example measurement record, a solve result, timings, four
capture poses and four image paths: about 6 KB, as a `monoguide simulate` row), numbered on, with its images
"kept" only for the newest ``--kept`` cycles (the images cap of a real cell keeps ~2,000 cycles' images; the
older ones are marked pruned, as the service leaves them). The operations, each the median of ``--repeats``
runs on an opened journal (warm page cache; ``--cold`` drops the page cache before each run, as root):

- ``prune``: ``Journal.prune_images`` as the service calls it between cycles (nothing to delete);
- ``list``: ``Journal.last_cycles(20)`` (``monoguide journal list``);
- ``show``: ``Journal.cycle(n)`` and its intent, of a cycle in the middle (``monoguide journal show``);
- ``status``: the cycle counter and the last 5 cycles (``monoguide status``);
- ``export``: the first 100 rows by number (``monoguide journal export --to 100``);
- ``open``: opening the journal (``Journal(state_dir)``), as every command does;
- ``commit``: one intent and one cycle committed (the service's two commits per cycle).

    .venv/bin/python benchmarks/bench_journal.py                 # 10k, 100k, 1M rows (~7 GB in /tmp, ~5 min)
    .venv/bin/python benchmarks/bench_journal.py --rows 10000 100000 --dir /var/tmp/j
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sqlite3
import statistics
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

from monoguide.daemon.service import JOURNAL_FILE, CycleEntry, Journal

EXAMPLE_RECORD = Path(__file__).parents[1] / "examples" / "example-record.json"
BATCH = 5000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rows", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    parser.add_argument("--kept", type=int, default=2000, help="newest cycles whose images are kept")
    parser.add_argument("--repeats", type=int, default=11)
    parser.add_argument("--dir", type=Path, default=Path("/tmp/monoguide-bench-journal"))
    parser.add_argument("--cold", action="store_true", help="drop the page cache before every run (root)")
    parser.add_argument("--keep", action="store_true", help="keep the journals (reused by the next run)")
    args = parser.parse_args()
    results: dict[int, dict[str, float]] = {}
    for rows in args.rows:
        state_dir = args.dir / f"rows-{rows}"
        started = time.monotonic()
        if not _built(state_dir, rows):
            _build(state_dir, rows, args.kept)
        size = sum(f.stat().st_size for f in state_dir.glob(f"{JOURNAL_FILE}*"))
        print(f"journal of {rows:,} rows: {size / 1e9:.2f} GB, ready in {time.monotonic() - started:.0f} s",
              flush=True)
        results[rows] = _measure(state_dir, rows, args.repeats, args.cold)
        if not args.keep:
            shutil.rmtree(state_dir)
    _print(results)


def _measure(state_dir: Path, rows: int, repeats: int, cold: bool) -> dict[str, float]:
    journal = Journal(state_dir)
    middle = rows // 2
    operations: dict[str, Callable[[], object]] = {
        "prune": lambda: journal.prune_images(2_000_000_000, 30 * 86400.0, now=_T0 + 10.0 * rows),
        "list": lambda: journal.last_cycles(20),
        "show": lambda: (journal.cycle(middle), journal.intent(middle)),
        "status": lambda: (journal.cycle_counter(), journal.last_cycles(5)),
        "export": lambda: [journal.cycle(n) for n in range(1, 101)],
        "open": lambda: Journal(state_dir).close(),
    }
    timings: dict[str, float] = {}
    try:
        for name, operation in operations.items():
            samples = []
            for _ in range(repeats):
                if cold:
                    _drop_caches()
                start = time.perf_counter()
                operation()
                samples.append(time.perf_counter() - start)
            timings[name] = statistics.median(samples)
        samples = []
        for _ in range(repeats):
            number = journal.next_number()
            start = time.perf_counter()
            journal.commit_intent(number, number, (0.0,) * 6, [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0],
                                                               [0, 0, 0, 1.0]])
            journal.commit_cycle(_entry(number, []), number, intent_outcome=("acknowledged", "bench"))
            samples.append(time.perf_counter() - start)
        timings["commit"] = statistics.median(samples)
    finally:
        journal.close()
    return timings


def _print(results: dict[int, dict[str, float]]) -> None:
    sizes = list(results)
    names = list(next(iter(results.values())))
    header = f"{'operation':<10}" + "".join(f"{f'{n:,} rows':>16}" for n in sizes)
    if len(sizes) > 1:
        header += f"{f'{sizes[-1]:,} / {sizes[0]:,}':>22}"
    print()
    print("median wall time per operation, ms")
    print(header)
    for name in names:
        line = f"{name:<10}" + "".join(f"{results[n][name] * 1e3:>16.3f}" for n in sizes)
        if len(sizes) > 1:
            line += f"{results[sizes[-1]][name] / results[sizes[0]][name]:>21.2f}x"
        print(line)


# --- building a journal ----------------------------------------------------------------------------------------

_T0 = 1_790_000_000.0


def _entry(number: int, images: list[str]) -> CycleEntry:
    record = dict(json.loads(EXAMPLE_RECORD.read_text()), id=f"part-{number}")
    result = {"id": f"part-{number}", "status": "ok", "method": "ml", "rms_px": 0.05, "rotation_deg": 1.2,
              "grasp_shift_mm": 23.4, "sigma_rot_deg": 0.02, "sigma_trans_mm": 0.23,
              "base_offset_xyzabc": [12.5, -3.25, 0.75, 1.5, -0.5, 0.125],
              "T_s1_w": [[1.0, 0.0, 0.0, 1.0], [0.0, 1.0, 0.0, 2.0], [0.0, 0.0, 1.0, 3.0], [0.0, 0.0, 0.0, 1.0]]}
    pose = [[1.0, 0.0, 0.0, 1856.78], [0.0, 1.0, 0.0, 580.29], [0.0, 0.0, 1.0, 1241.9], [0.0, 0.0, 0.0, 1.0]]
    return CycleEntry(started_at=_T0 + 10.0 * number, finished_at=_T0 + 10.0 * number + 7.5, job=1,
                      part_tag=number % 65536, record=record, result=result,
                      timings_s={"robot_motion": 5.1, "exposure": 0.4, "hole_finding": 0.1, "solve": 0.09,
                                 "checks": 0.001, "offset_write": 0.02, "overhead": 0.05, "plc_journal": 0.01,
                                 "cycle": 7.6},
                      poses_at_capture=[pose] * 4, image_paths=images)


def _built(state_dir: Path, rows: int) -> bool:
    path = state_dir / JOURNAL_FILE
    if not path.is_file():
        return False
    with Journal(state_dir) as journal:
        return journal.cycle_counter() >= rows


def _build(state_dir: Path, rows: int, kept: int) -> None:
    """One committed row through the journal (the real schema and encoding), then copies of it by SQL."""
    if state_dir.exists():
        shutil.rmtree(state_dir)
    with Journal(state_dir) as journal:
        journal.commit_cycle(_entry(1, []))
    db = sqlite3.connect(state_dir / JOURNAL_FILE)
    db.execute("PRAGMA synchronous = OFF")
    template = db.execute("SELECT started_at, finished_at, job, part_tag, status, error_code, plc_code, "
                          "error_message, record_json, result_json, timings_json, poses_json FROM cycle").fetchone()
    db.execute("DELETE FROM cycle")
    first_kept = rows - kept + 1
    with db:
        for start in range(1, rows + 1, BATCH):
            batch = []
            for n in range(start, min(start + BATCH, rows + 1)):
                images = json.dumps([f"images/cycle-{n}/S{i}.png" for i in range(1, 5)])
                pruned = None if n >= first_kept else _T0 + 10.0 * n + 3600.0
                batch.append((n, _T0 + 10.0 * n, _T0 + 10.0 * n + 7.5, *template[2:3], n % 65536, *template[4:],
                              images, pruned))
            db.executemany("INSERT INTO cycle (number, started_at, finished_at, job, part_tag, status, error_code,"
                           " plc_code, error_message, record_json, result_json, timings_json, poses_json,"
                           " images_json, images_pruned_at) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                           batch)
            db.executemany("INSERT INTO offset_intent (cycle, sequence, offset_json, intended_at, outcome, cleared,"
                           " settled_at, detail) VALUES (?, ?, ?, ?, 'acknowledged', 0, ?, 'bench')",
                           [(row[0], row[0], '{"registers": [0, 0, 0, 0, 0, 0], "D_b": []}', row[1], row[2])
                            for row in batch])
    db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    db.close()


def _drop_caches() -> None:
    os.sync()
    subprocess.run(["sh", "-c", "echo 3 > /proc/sys/vm/drop_caches"], check=True)


if __name__ == "__main__":
    main()
