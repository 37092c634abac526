"""The operator page's costs (`monoguide web`), measured against the running server. Prints tables; asserts
nothing.

``latency``: two servers in this run, one on a journal of ``--rows`` cycles (default 1,000,000, built as
benchmarks/bench_journal.py builds them: the real schema and a realistic row, copied by SQL; one cycle in a
thousand turned into an error, jobs 1..3) and its peer on 10,000 rows; the requests alternate between the two,
and each line is the median of ``--repeats`` answers (the whole answer read, one connection per request as a
browser's first visit): *Now* (the page and its JSON), *Cycles* (the first page, filtered by status, error
code, job, a day's window far back, a page deep down), *One cycle* (the page, and the page with its 4 views'
5 MP previews and hole squares: the journal's newest cycle, with 4 images of 2456 x 2058 px on disk).

``cycle``: the simulated cell and the service (``monoguide simulate``'s run, sharp frames) with ``monoguide web``
on its state directory; five pollers asking for ``/now.json`` once a second, as five open *Now* pages do, are on
for one cycle and off for the next, in turn; the medians of the cycles' overhead (the last frame in hand -> the
offset acknowledged) and of the whole cycle (trigger -> DONE) with and without them.

``index``: the service's open of the journal without the filters' four indexes (made then, once) and with them.

``memory``: ``--requests`` requests (every page, previews, squares, a chart in fifty) to one server from two
clients; the server's resident memory sampled every 100 requests; the growth from the first quarter's mean to
the last's.

    .venv/bin/python benchmarks/bench_web.py                         # all three (~10 min, ~6 GB in /tmp)
    .venv/bin/python benchmarks/bench_web.py latency --rows 100000 --keep
    .venv/bin/python benchmarks/bench_web.py cycle --cycles 16
    .venv/bin/python benchmarks/bench_web.py memory --requests 10000
    .venv/bin/python benchmarks/bench_web.py index --keep     # the service's first open after an upgrade
"""

from __future__ import annotations

import argparse
import http.client
import json
import shutil
import signal
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
import bench_journal  # the journal builder beside this script

from monoguide.daemon.service import JOURNAL_FILE, Journal
from monoguide.daemon.simulate import Progress, RunOptions, run_simulation

ROOT = Path(__file__).parents[1]
SIM_CELL = ROOT / "config" / "sim-cell.toml"
HOSTS = {"big": ("127.0.31.1", 8311), "peer": ("127.0.31.2", 8312), "cell": ("127.0.31.3", 8313),
         "memory": ("127.0.31.4", 8314)}
PEER_ROWS = 10_000
POLLERS, POLL_S = 5, 1.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("what", nargs="*", default=["latency", "cycle", "memory"],
                        choices=["latency", "cycle", "memory", "index"])
    parser.add_argument("--rows", type=int, default=1_000_000)
    parser.add_argument("--repeats", type=int, default=21)
    parser.add_argument("--cycles", type=int, default=16, help="cycle: cycles of the simulated cell")
    parser.add_argument("--requests", type=int, default=10_000, help="memory: requests in all")
    parser.add_argument("--dir", type=Path, default=Path("/tmp/monoguide-bench-web"))
    parser.add_argument("--keep", action="store_true", help="keep the journals (reused by the next run)")
    args = parser.parse_args()
    args.dir.mkdir(parents=True, exist_ok=True)
    try:
        if "index" in args.what:
            _index(_journal(args.dir, args.rows), args.rows)
        if "latency" in args.what or "memory" in args.what:
            big, peer = _journal(args.dir, args.rows), _journal(args.dir, PEER_ROWS)
        if "latency" in args.what:
            _latency(big, peer, args.rows, args.repeats)
        if "cycle" in args.what:
            _cycle(args.cycles)
        if "memory" in args.what:
            _memory(peer, args.requests)
    finally:
        if not args.keep and set(args.what) & {"latency", "memory", "index"}:  # `cycle` alone builds no journal
            shutil.rmtree(args.dir, ignore_errors=True)


# --- latency --------------------------------------------------------------------------------------------------


def _latency(big: Path, peer: Path, rows: int, repeats: int) -> None:
    newest = {d: _newest(d) for d in (big, peer)}
    paths: dict[str, Callable[[Path], list[str]]] = {
        "Now (page)": lambda d: ["/"],
        "Now (/now.json)": lambda d: ["/now.json"],
        "Cycles: first page": lambda d: ["/cycles"],
        "Cycles: status=error": lambda d: ["/cycles?status=error"],
        "Cycles: code=HOLE_NOT_FOUND": lambda d: ["/cycles?code=HOLE_NOT_FOUND"],
        "Cycles: job=2": lambda d: ["/cycles?job=2"],
        "Cycles: a day, far back": lambda d: [f"/cycles?from={_day(d, 0.1)}&to={_day(d, 0.1, 1)}"],
        "Cycles: page at the middle": lambda d: [f"/cycles?before={newest[d] // 2}"],
        "One cycle (page)": lambda d: [f"/cycles/{newest[d]}"],
        "One cycle + 1 view's images": lambda d: [f"/cycles/{newest[d]}", f"/cycles/{newest[d]}/views/1/preview.jpg",
                                                  f"/cycles/{newest[d]}/views/1/holes/0.png"],
        "One cycle + 4 views' images": lambda d: [f"/cycles/{newest[d]}"] + [
            f"/cycles/{newest[d]}/views/{v}/{kind}" for v in range(1, 5)
            for kind in ("preview.jpg", f"holes/{v - 1}.png")],
    }
    urls = {name: {d: make(d) for d in (big, peer)} for name, make in paths.items()}
    times: dict[str, dict[Path, list[float]]] = {name: {big: [], peer: []} for name in paths}
    with _server(big, "big"), _server(peer, "peer"):
        for name in paths:  # warm: the page cache and the server's first imports
            for d in (big, peer):
                _get_all(_where(d, big), urls[name][d])
        for _ in range(repeats):
            for name in paths:
                for d in (big, peer):
                    start = time.perf_counter()
                    _get_all(_where(d, big), urls[name][d])
                    times[name][d].append(time.perf_counter() - start)
    print()
    print(f"median answer time, ms ({repeats} requests each; the two servers alternate)")
    print(f"{'request':<30}{f'{rows:,} rows':>16}{f'{PEER_ROWS:,} rows':>16}{'ratio':>9}{'target':>10}")
    for name in paths:
        a, b = statistics.median(times[name][big]) * 1e3, statistics.median(times[name][peer]) * 1e3
        target = ("<= 500" if name.startswith("One cycle + 1") else "" if name.startswith("One cycle")
                  else "<= 200")
        print(f"{name:<30}{a:>16.1f}{b:>16.1f}{a / b:>8.2f}x{target:>10}")
    print("(One cycle + 4 views: the page, then each view's preview and hole square one after another; a browser "
          "loads them in parallel)")


def _where(d: Path, big: Path) -> tuple[str, int]:
    return HOSTS["big"] if d == big else HOSTS["peer"]


def _day(d: Path, fraction: float, days: int = 0) -> str:
    with Journal(d, read_only=True) as journal:
        first, last = journal.cycle(1).finished_at, journal.cycle(journal.cycle_counter()).finished_at
    t = first + fraction * (last - first) + days * 86400.0
    return time.strftime("%Y-%m-%dT%H:%M", time.localtime(t))


def _newest(d: Path) -> int:
    with Journal(d, read_only=True) as journal:
        return journal.cycle_counter()


# --- the filters' indexes created on a journal written before them ------------------------------------------


def _index(state_dir: Path, rows: int) -> None:
    """The service's open of a journal without the filters' indexes (they are made then) against its open of the
    same journal with them."""
    names = ("cycle_status", "cycle_error_code", "cycle_job", "cycle_finished")
    with_them = []
    for _ in range(3):
        start = time.perf_counter()
        Journal(state_dir).close()
        with_them.append(time.perf_counter() - start)
    db = sqlite3.connect(state_dir / JOURNAL_FILE)
    for name in names:
        db.execute(f"DROP INDEX {name}")
    db.commit()
    db.close()
    start = time.perf_counter()
    Journal(state_dir).close()
    making = time.perf_counter() - start
    print()
    print(f"the service's open of a {rows:,}-row journal, s")
    print(f"{'with the filters indexes':<40}{statistics.median(with_them):>10.3f}")
    print(f"{'without them (they are made)':<40}{making:>10.3f}")


# --- the cycle with and without pollers -----------------------------------------------------------------------


def _cycle(cycles: int) -> None:
    work = Path(tempfile.mkdtemp(prefix="monoguide-bench-web-cycle-"))
    config = _sharp_config(work)
    polling = threading.Event()
    stop = threading.Event()
    served = [0]
    on_at_start: dict[int, bool] = {}

    def poller() -> None:
        host, port = HOSTS["cell"]
        while not stop.is_set():
            if polling.is_set():
                try:
                    _get(host, port, "/now.json")
                    served[0] += 1
                except OSError:
                    pass
            stop.wait(POLL_S)

    def part(done: int, total: int, record: dict) -> None:
        on = done % 2 == 1  # cycle 1 without, 2 with, 3 without, ...
        on_at_start[done + 1] = on
        polling.set() if on else polling.clear()

    on_at_start[1] = False
    threads = [threading.Thread(target=poller, daemon=True) for _ in range(POLLERS)]
    for t in threads:
        t.start()
    try:
        with _server(work / "state", "cell"):
            result = run_simulation(RunOptions(config, work, cycles, host="127.0.31.20"),
                                    Progress(part=part, note=lambda text: None))
    finally:
        stop.set()
        shutil.rmtree(work, ignore_errors=True)
    rows = [r for r in result.journal_rows if r.status == "ok" and r.number > 1]  # the first warms up
    groups = {on: [r for r in rows if on_at_start.get(r.number) is on] for on in (False, True)}
    print()
    print(f"the cycle with {POLLERS} Now pages polling once a second vs none ({cycles} cycles in turn, "
          f"{served[0]} polls answered; medians, ms)")
    print(f"{'stage':<34}{'no page':>12}{f'{POLLERS} pages':>12}{'ratio':>9}")
    for stage, label in (("overhead", "overhead (last frame -> ack)"), ("cycle", "cycle (trigger -> DONE)"),
                         ("hole_finding", "hole finding (4 views)"), ("solve", "solve")):
        off = statistics.median(r.timings_s[stage] for r in groups[False]) * 1e3
        on = statistics.median(r.timings_s[stage] for r in groups[True]) * 1e3
        print(f"{label:<34}{off:>12.1f}{on:>12.1f}{on / off:>8.2f}x")
    print(f"(cycles: {len(groups[False])} without, {len(groups[True])} with)")


def _sharp_config(work: Path) -> Path:
    """config/sim-cell.toml with sharp frames (no defocus): each 5 MP frame rendered ~5 times faster."""
    text = SIM_CELL.read_text()
    assert text.count("aperture_mm = 1.4867") == 1
    path = work / "cell.toml"
    work.mkdir(parents=True, exist_ok=True)
    path.write_text(text.replace("aperture_mm = 1.4867", "aperture_mm = 0.0"))
    return path


# --- memory ---------------------------------------------------------------------------------------------------


def _memory(state_dir: Path, requests: int) -> None:
    n = _newest(state_dir)
    mix = ["/", "/now.json", "/cycles", "/cycles?status=error", f"/cycles/{n}", f"/cycles/{n}/views/1/preview.jpg",
           f"/cycles/{n}/views/2/holes/1.png", f"/cycles?before={n // 2}", f"/cycles/{n // 3}", "/calibration",
           "/cycles/999999999", "/static/style.css"]
    samples: list[float] = []
    done = [0]
    lock = threading.Lock()
    with _server(state_dir, "memory") as process:
        def client(k: int) -> None:
            host, port = HOSTS["memory"]
            i = k
            while True:
                with lock:
                    if done[0] >= requests:
                        return
                    done[0] += 1
                    count = done[0]
                    if count % 100 == 0:
                        samples.append(_rss_mb(process.pid))
                path = "/trends/quality.png?last=200" if count % 50 == 0 else mix[i % len(mix)]
                _get(host, port, path)
                i += 2

        started = time.monotonic()
        clients = [threading.Thread(target=client, args=(k,)) for k in range(2)]
        for c in clients:
            c.start()
        for c in clients:
            c.join()
        elapsed = time.monotonic() - started
    q = max(1, len(samples) // 4)
    first, last = statistics.mean(samples[:q]), statistics.mean(samples[-q:])
    print()
    print(f"memory of monoguide web over {requests:,} requests ({elapsed:.0f} s, two clients)")
    print(f"{'resident MB, first quarter':<32}{first:>10.1f}")
    print(f"{'resident MB, last quarter':<32}{last:>10.1f}")
    print(f"{'resident MB, max':<32}{max(samples):>10.1f}")
    print(f"{'growth, last vs first quarter':<32}{100 * (last - first) / first:>9.1f} %   (target <= 5 %)")


# --- shared ---------------------------------------------------------------------------------------------------


def _journal(folder: Path, rows: int) -> Path:
    """A state directory with a journal of ``rows`` cycles (built once, kept with --keep), one in a thousand an
    error, jobs 1..3, and the newest cycle's four 5 MP images on disk."""
    state = folder / f"rows-{rows}"
    if not bench_journal._built(state, rows):
        started = time.monotonic()
        bench_journal._build(state, rows, kept=2000)
        db = sqlite3.connect(state / JOURNAL_FILE)
        with db:
            db.execute("UPDATE cycle SET status = 'error', error_code = 'HOLE_NOT_FOUND', plc_code = 301, "
                       "error_message = 'S2, P2: no hole within 90 px', result_json = NULL WHERE number % 1000 = 7")
            db.execute("UPDATE cycle SET job = 1 + number % 3")
        db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        db.close()
        print(f"journal of {rows:,} rows built in {time.monotonic() - started:.0f} s", flush=True)
    n = _newest(state)
    record = json.loads(bench_journal.EXAMPLE_RECORD.read_text())
    for view, observation in enumerate(record["observations"]):
        path = state / "images" / f"cycle-{n}" / f"S{view + 1}.png"
        if not path.is_file():
            image = np.full((record["camera"]["height"], record["camera"]["width"]), 170, np.uint8)
            u, v = observation["pixel"]
            cv2.circle(image, (round(u * 256), round(v * 256)), 28 * 256, 30, -1, cv2.LINE_AA, 8)
            noise = np.random.default_rng(view).normal(0, 3, image.shape)
            image = np.clip(image + noise, 0, 255).astype(np.uint8)  # a frame's noise: PNG as large as a camera's
            path.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(path), image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    return state


@contextmanager
def _server(state_dir: Path, name: str) -> Iterator[subprocess.Popen[str]]:
    host, port = HOSTS[name]
    process = subprocess.Popen([sys.executable, "-m", "monoguide.daemon.cli", "web", "--state-dir", str(state_dir),
                                "--config", str(SIM_CELL), "--bind", f"{host}:{port}"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, text=True)
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                _get(host, port, "/static/style.css")
                break
            except OSError:
                if time.monotonic() > deadline or process.poll() is not None:
                    raise RuntimeError(f"monoguide web on {host}:{port} did not start") from None
                time.sleep(0.2)
        yield process
    finally:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(15)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(5)


def _get(host: str, port: int, path: str) -> int:
    connection = http.client.HTTPConnection(host, port, timeout=30)
    try:
        connection.request("GET", path)
        answer = connection.getresponse()
        answer.read()
        return answer.status
    finally:
        connection.close()


def _get_all(where: tuple[str, int], paths: list[str]) -> None:
    for path in paths:
        status = _get(*where, path)
        if status != 200:
            raise RuntimeError(f"{path}: {status}")


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


if __name__ == "__main__":
    main()
