"""The plant interfaces' figures (issue 22): result-event latency, the cycle's overhead with and without 20 OPC UA
clients, the plant's memory over 10,000 cycles' events. Prints tables; asserts nothing.

``cycles``: ``monoguide sim-cell`` (its PLC plays parts without end), ``monoguide run --cycles N`` and ``monoguide
plant`` on one state directory, each its own process, and one asyncua client (Sign & Encrypt, a user) subscribed to
the result events from the start. 20 more clients alternate, in blocks of ``--block`` cycles, between subscribed
(each a subscription to the result events and one to the state) and not: with ``--toggle subscriptions`` (default)
their 20 sessions stay connected and only the subscriptions are made and deleted, so the blocks can be short and the
two conditions see the same load of the shared machine; with ``--toggle sessions`` the clients connect and
disconnect. A cycle counts for a condition when it started after the change to it was complete and its event
arrived before the next change began. Latency: the event's arrival at the client minus the row's ``finished_at``
(taken just before the journal's commit, so the commit's own fsync counts against the plant).

``memory``: ``monoguide plant`` on a journal replayed by the real ``Journal`` (``--events`` rows committed at
``--rate`` per second, each a realistic small row), one client subscribed counting the events; the plant's resident
memory (``/proc/<pid>/status`` VmRSS) after every tenth of them.

    .venv/bin/python benchmarks/bench_plant.py cycles --cycles 80 --block 2      # ~5 min
    .venv/bin/python benchmarks/bench_plant.py cycles --cycles 72 --block 12 --toggle sessions
    .venv/bin/python benchmarks/bench_plant.py memory --events 10000             # ~2 min
    .venv/bin/python benchmarks/bench_plant.py journal --rows 10000 100000 1000000   # ~7 GB in /tmp, ~6 min
    .venv/bin/python benchmarks/bench_plant.py browse                            # a session's browse tree

``journal``: what the plant's reader (``CellView``) costs on journals of 10k, 100k and 1M rows, built as
``bench_journal.py`` builds them (its journals are reused): its start (the newest N rows and the counts by outcome,
once) and one poll that finds one new row (the counter, the row by its number, the status file) — the poll is what
runs between cycles, and must not grow with the journal.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))

from bench_cycle import cheaper_config
from helpers.plant_cells import MANY_SESSIONS, PASSWORD, USER, plant_file, seeded_entries
from helpers.plant_clients import (
    NAMESPACE,
    client_identity,
    connected,
    load_machine_vision_types,
    start_plant,
    subscribe_results,
    trust,
    value,
)
from helpers.sim_processes import keep_reading, start_sim_cell, stop

from monoguide.daemon.service import Journal

ROBOT_HOST, PLANT_HOST, PLANT_PORT = "127.0.84.10", "127.0.84.20", 48401
EXTRA_CLIENTS = 20


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    cycles = sub.add_parser("cycles")
    cycles.add_argument("--cycles", type=int, default=60)
    cycles.add_argument("--block", type=int, default=2)
    cycles.add_argument("--toggle", choices=("subscriptions", "sessions"), default="subscriptions",
                        help="what comes and goes between blocks: the 20 clients' subscriptions (their sessions stay "
                             "connected) or the clients themselves")
    cycles.add_argument("--config", type=Path, default=Path("config/sim-cell.toml"))
    cycles.add_argument("--verbose", action="store_true", help="print the windows and each cycle's times")
    memory = sub.add_parser("memory")
    memory.add_argument("--events", type=int, default=10_000)
    memory.add_argument("--rate", type=float, default=100.0)
    sub.add_parser("browse", help="print what a client session browses (a seeded journal, a running status)")
    journal = sub.add_parser("journal")
    journal.add_argument("--rows", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    journal.add_argument("--dir", type=Path, default=Path("/tmp/monoguide-bench-journal"))
    journal.add_argument("--repeats", type=int, default=21)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-plant-") as tmp:
        if args.what == "cycles":
            asyncio.run(_cycles(Path(tmp), args.config, args.cycles, args.block, args.toggle))
        elif args.what == "browse":
            asyncio.run(_browse(Path(tmp)))
        elif args.what == "journal":
            _journal(args.dir, args.rows, args.repeats)
        else:
            asyncio.run(_memory(Path(tmp), args.events, args.rate))


# --- cycles: latency and overhead ---------------------------------------------------------------


async def _cycles(tmp: Path, config_path: Path, cycles: int, block: int, toggle: str) -> None:
    config = cheaper_config(config_path, tmp, 0.05, True, ROBOT_HOST)
    state_dir, clients = _state_dir(tmp)
    plant, line = start_plant(config, state_dir, plant_file(tmp / "plant.toml", PLANT_HOST, PLANT_PORT, MANY_SESSIONS),
                              tmp / "plant.log")
    url = line.split()[2]
    sim, _ = start_sim_cell(config)
    keep_reading(sim)
    windows: list[tuple[str, float, float]] = []  # (condition, from, to)
    try:
        watcher = await connected(url, clients[0], user=USER, password=PASSWORD)
        await load_machine_vision_types(watcher)
        log, _ = await subscribe_results(watcher)
        service = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "monoguide.daemon.cli", "run", "--config", str(config), "--state-dir",
            str(state_dir), "--cycles", str(cycles), stdout=asyncio.subprocess.DEVNULL,
            stderr=asyncio.subprocess.DEVNULL)
        extra = _ExtraClients(url, clients[1:], toggle)
        if toggle == "subscriptions":  # the 20 sessions stay connected; their subscriptions come and go
            await extra.connect()
        condition_from = time.time()
        while service.returncode is None:
            wanted = len(log.events) // block % 2 == 1  # blocks without, with, without, ... the extra clients
            if wanted != extra.on:
                windows.append(("with" if extra.on else "without", condition_from, time.time()))
                changing = time.monotonic()
                await (extra.stop() if extra.on else extra.start())
                print(f"{EXTRA_CLIENTS} clients' {toggle} {'on' if extra.on else 'off'} in "
                      f"{time.monotonic() - changing:.1f} s", flush=True)
                condition_from = time.time()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(service.wait(), 0.1)
        windows.append(("with" if extra.on else "without", condition_from, time.time()))
        await extra.close()
        await log.wait_for(cycles, 30.0)
        await watcher.disconnect()
    finally:
        stop(sim)
        stop(plant)
    with Journal(state_dir, read_only=True) as journal:
        rows = {row.number: row for row in journal.last_cycles(cycles + 10)}
    _print_cycles(log.events, rows, windows)


class _Ignored:
    """A subscription handler that drops what it is sent (the extra clients only load the server)."""

    def datachange_notification(self, *_: Any) -> None:
        pass

    def event_notification(self, *_: Any) -> None:
        pass

    def status_change_notification(self, *_: Any) -> None:
        pass


class _ExtraClients:
    """The 20 clients of the comparison: with ``toggle`` "sessions" each block connects and disconnects them (and
    their subscriptions), with "subscriptions" they stay connected and only their subscriptions (to the result events
    and to the state) are made and deleted."""

    def __init__(self, url: str, identities: list[Any], toggle: str) -> None:
        self.url, self.identities, self.toggle = url, identities, toggle
        self.sessions: list[Any] = []
        self.subscriptions: list[Any] = []

    @property
    def on(self) -> bool:
        return bool(self.subscriptions)

    async def connect(self) -> None:
        for identity in self.identities:
            self.sessions.append(await connected(self.url, identity, user=USER, password=PASSWORD))

    async def start(self) -> None:
        from asyncua import ua

        if self.toggle == "sessions":
            await self.connect()
        from asyncua.common.events import get_filter_from_event_type

        first = self.sessions[0]
        idx = await first.get_namespace_index(NAMESPACE)
        base_event = first.get_node(ua.NodeId(ua.ObjectIds.BaseEventType))
        event_type = await base_event.get_child(f"{idx}:ResultReadyEventType")
        event_filter = await get_filter_from_event_type([event_type])  # browsed once: the same filter for all 20
        machine = first.get_node(ua.NodeId("VisionSystem.VisionStateMachine", idx))
        current_state = (await machine.get_child("0:CurrentState")).nodeid
        for client in self.sessions:
            events = await client.create_subscription(50, _Ignored())
            await events.subscribe_events(client.get_node(ua.NodeId("VisionSystem", idx)), event_type.nodeid,
                                          evfilter=event_filter)
            state = await client.create_subscription(100, _Ignored())
            await state.subscribe_data_change(client.get_node(current_state))
            self.subscriptions += [events, state]

    async def stop(self) -> None:
        for subscription in self.subscriptions:
            await subscription.delete()
        self.subscriptions = []
        if self.toggle == "sessions":
            await self.close()

    async def close(self) -> None:
        for client in self.sessions:
            await client.disconnect()
        self.sessions, self.subscriptions = [], []


def _print_cycles(events: list[tuple[float, dict[str, Any]]], rows: dict[int, Any],
                  windows: list[tuple[str, float, float]]) -> None:
    latency: dict[str, list[float]] = {"all": [], "without": [], "with": []}
    overhead: dict[str, list[float]] = {"without": [], "with": []}
    cycle_time: dict[str, list[float]] = {"without": [], "with": []}
    for arrived, fields in events:
        row = rows[int(value(fields, "ResultId").Id)]
        latency["all"].append(arrived - row.finished_at)
        condition = next((c for c, start, end in windows if start <= row.started_at and arrived <= end), None)
        if condition is None or row.status != "ok":
            continue
        latency[condition].append(arrived - row.finished_at)
        overhead[condition].append(row.timings_s["overhead"])
        cycle_time[condition].append(row.timings_s.get("cycle", float("nan")))
    if "--verbose" in sys.argv:
        print(windows)
        print([(round(rows[int(value(f, "ResultId").Id)].started_at, 1), round(a, 1)) for a, f in events])
    every = sorted(latency["all"])
    print(f"\nresult event latency (client arrival - journal row), {len(every)} cycles, ms")
    print("| median | p90 | max | min |\n|---|---|---|---|")
    print(f"| {_ms(statistics.median(every))} | {_ms(every[int(0.9 * (len(every) - 1))])} | {_ms(every[-1])} |"
          f" {_ms(every[0])} |")
    print("\nlatency distribution: " + ", ".join(f"<= {b} ms: {sum(1 for v in every if v * 1000 <= b)}"
                                                 for b in (50, 100, 150, 200, 300, 500, 1000)))
    print(f"\n| cycles' medians | without ({len(overhead['without'])} cycles) | with {EXTRA_CLIENTS} clients "
          f"({len(overhead['with'])} cycles) | ratio |\n|---|---|---|---|")
    for name, table in (("overhead ms", overhead), ("cycle (trigger -> DONE) ms", cycle_time),
                        ("event latency ms", latency)):
        if not table["without"] or not table["with"]:
            print(f"| {name} | (no cycle) | (no cycle) | |")
            continue
        a, b = statistics.median(table["without"]), statistics.median(table["with"])
        print(f"| {name} | {_ms(a)} | {_ms(b)} | {b / a:.3f} |")


# --- memory over a replayed journal -------------------------------------------------------------


async def _memory(tmp: Path, events: int, rate: float) -> None:
    state_dir, clients = _state_dir(tmp, 1)
    with Journal(state_dir) as journal:  # the service's file exists before the plant starts, as in a cell
        journal.commit_cycle(seeded_entries(1, time.time())[0])
    plant, line = start_plant(Path("config/sim-cell.toml"), state_dir,
                              plant_file(tmp / "plant.toml", PLANT_HOST, PLANT_PORT + 10), tmp / "plant.log")
    samples: list[tuple[int, float]] = []
    try:
        client = await connected(line.split()[2], clients[0], user=USER, password=PASSWORD)
        await load_machine_vision_types(client)
        log, _ = await subscribe_results(client)
        samples.append((0, _rss_mb(plant.pid)))
        entries = seeded_entries(100, time.time())
        started = time.monotonic()
        with Journal(state_dir) as journal:
            for i in range(events):
                # in a thread: the fsync of every commit must not hold up the client's event loop
                await asyncio.to_thread(journal.commit_cycle, entries[i % len(entries)])
                if (i + 1) % max(1, events // 10) == 0:
                    await log.wait_for(i + 1, 60.0)
                    samples.append((i + 1, _rss_mb(plant.pid)))
                await asyncio.sleep(max(0.0, started + (i + 1) / rate - time.monotonic()))
        await log.wait_for(events, 60.0)
        await client.disconnect()
    finally:
        stop(plant)
    print(f"\nplant memory over {events:,} replayed cycles ({len(log.events):,} events received by the client)")
    print("| events | resident MB |\n|---|---|")
    for n, mb in samples:
        print(f"| {n:,} | {mb:.1f} |")
    quarter = max(1, len(samples) // 4)
    first = statistics.mean(m for _, m in samples[1:1 + quarter])
    last = statistics.mean(m for _, m in samples[-quarter:])
    print(f"\nlast quarter vs first quarter (after the first tenth): {100 * (last - first) / first:+.1f} %")


# --- a session's browse tree ------------------------------------------------------------------------


async def _browse(tmp: Path) -> None:
    from asyncua import ua
    from helpers.plant_cells import StatusBeat, write_journal

    state_dir, clients = _state_dir(tmp, 1)
    write_journal(state_dir, seeded_entries(12, time.time() - 600.0))
    beat = StatusBeat(state_dir)
    plant, line = start_plant(Path("config/sim-cell.toml"), state_dir,
                              plant_file(tmp / "plant.toml", PLANT_HOST, PLANT_PORT + 20), tmp / "plant.log")
    try:
        client = await connected(line.split()[2], clients[0], user=USER, password=PASSWORD)
        idx = await client.get_namespace_index(NAMESPACE)
        print(f"{line}\nObjects/VisionSystem (ns={idx}: {NAMESPACE})")
        await _tree(client.get_node(ua.NodeId("VisionSystem", idx)), 1)
        await client.disconnect()
    finally:
        stop(plant)
        beat.stop()


async def _tree(node: Any, depth: int) -> None:
    from asyncua import ua

    for child in await node.get_children():
        name = (await child.read_browse_name()).Name
        shown = ""
        if await child.read_node_class() == ua.NodeClass.Variable:
            data = await child.read_data_value(raise_on_bad_status=False)
            value = data.Value.Value if data.Value is not None else None
            text = value.Text if isinstance(value, ua.LocalizedText) else value
            shown = f" = {text!r}" if data.StatusCode.is_good() else f" [{data.StatusCode.name}]"
        print("  " * depth + name + shown)
        if name.startswith("Result") and name[6:].isdigit() and name != "Result01":
            continue  # Result02 .. ResultN: as Result01
        await _tree(child, depth + 1)


# --- the reader's cost against the journal's length -------------------------------------------------


def _journal(folder: Path, sizes: list[int], repeats: int) -> None:
    from bench_journal import _build, _built  # the same journals as bench_journal.py (--keep reuses them)

    from monoguide.daemon.plant._cell_view import CellView

    print("| rows | start ms (once) | poll, one new row ms (median) | poll max ms |\n|---|---|---|---|")
    for rows in sizes:
        state_dir = folder / f"rows-{rows}"
        if not _built(state_dir, rows):
            _build(state_dir, rows, 2000)
        entry = seeded_entries(1, time.time())[0]
        view = CellView(state_dir)
        started = time.perf_counter()
        view.start(10)
        start_ms = (time.perf_counter() - started) * 1000
        polls = []
        with Journal(state_dir) as journal:
            for _ in range(repeats):
                journal.commit_cycle(entry)
                began = time.perf_counter()
                found = view.poll(now=time.time() + 10.0)  # past the wait for the DONE timing: published at once
                polls.append((time.perf_counter() - began) * 1000)
                assert len(found.results) == 1
        view.close()
        print(f"| {rows:,} | {start_ms:.1f} | {statistics.median(polls):.2f} | {max(polls):.2f} |", flush=True)


# --- private ------------------------------------------------------------------------------------


def _state_dir(tmp: Path, count: int = EXTRA_CLIENTS + 1) -> tuple[Path, list[Any]]:
    state_dir = tmp / "state"
    state_dir.mkdir()
    clients = [client_identity(tmp / "clients", f"client-{i:02d}") for i in range(count)]
    for identity in clients:
        trust(identity, state_dir / "plant" / "trusted")
    return state_dir, clients


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _ms(seconds: float) -> str:
    return f"{seconds * 1000:.1f}"


if __name__ == "__main__":
    main()
