"""`monoguide status`: the service's status file and the journal's last cycles, stale or dead services named."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

from typer.testing import CliRunner

from monoguide.daemon.cli import app
from monoguide.daemon.service import (
    STATUS_FILE,
    CycleEntry,
    DeviceStatus,
    Journal,
    ServiceStatus,
    read_status,
    write_status,
)


def _status(directory: Path, **changes) -> ServiceStatus:
    now = time.time()
    fields = {"state": "measuring", "since": now - 3, "pid": os.getpid(), "updated_at": now, "heartbeat_s": 1.0,
              "devices": {"camera": DeviceStatus(True), "robot": DeviceStatus(False, {"code": "DEVICE_TIMEOUT",
                                                                                      "message": "no answer"})},
              "last_result": {"cycle": 2, "status": "ok"}}
    status = ServiceStatus(**{**fields, **changes})
    write_status(directory, status)
    return status


def _run(directory: Path, *args: str):
    return CliRunner().invoke(app, ["status", "--state-dir", str(directory), *args])


def test_running_service_with_journal(tmp_path: Path) -> None:
    with Journal(tmp_path) as journal:
        for n in range(1, 4):
            journal.commit_cycle(CycleEntry(started_at=1e9 + n, finished_at=1e9 + n + 2, job=1, part_tag=n,
                                            result={"status": "ok", "rms_px": n / 10}))
    written = _status(tmp_path)
    assert read_status(tmp_path) == written and [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    run = _run(tmp_path, "--json", "--last", "2")
    assert run.exit_code == 0, run.output
    report = json.loads(run.stdout)
    assert report["service"]["running"] and report["service"]["status"]["state"] == "measuring"
    assert report["journal"]["cycle_counter"] == 3
    assert [c["number"] for c in report["journal"]["last_cycles"]] == [2, 3]
    run = _run(tmp_path)
    assert run.exit_code == 0, run.output
    assert f"running (pid {os.getpid()})" in run.stdout
    assert "robot: NOT connected, last error DEVICE_TIMEOUT" in run.stdout
    assert "journal: 3 cycles" in run.stdout


def test_dead_pid_stale_file_and_stopped_say_no_service_running(tmp_path: Path) -> None:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    _status(tmp_path, pid=child.pid)
    run = _run(tmp_path)
    assert run.exit_code == 3 and f"no service running (pid {child.pid} is gone" in run.stdout
    _status(tmp_path, updated_at=time.time() - 30)
    run = _run(tmp_path)
    assert run.exit_code == 3 and "status file stale" in run.stdout
    _status(tmp_path, state="stopped")
    assert _run(tmp_path).exit_code == 3


def test_empty_missing_and_corrupt(tmp_path: Path) -> None:
    run = _run(tmp_path)
    assert run.exit_code == 3 and "no service running (no status file)" in run.stdout and "no journal" in run.stdout
    run = _run(tmp_path / "absent")
    assert run.exit_code == 1 and run.stderr.startswith("STATE_DIR_MISSING")
    (tmp_path / STATUS_FILE).write_text('{"format": "monoguide.status/1", "state": "dancing"}')
    run = _run(tmp_path)
    assert run.exit_code == 1 and run.stderr.startswith("SERVICE_STATUS_INVALID") and "dancing" in run.stderr
    _status(tmp_path)
    (tmp_path / "journal.sqlite3").write_bytes(b"not a database " * 100)
    run = _run(tmp_path, "--json")
    assert run.exit_code == 1 and run.stderr.startswith("JOURNAL_NOT_A_DATABASE")
    assert json.loads(run.stdout)["journal"]["error"]["code"] == "JOURNAL_NOT_A_DATABASE"


def test_last_result_reads_as_words_and_a_clock_time(tmp_path: Path) -> None:
    finished = time.mktime((2026, 11, 23, 14, 2, 31, 0, 0, -1))
    _status(tmp_path, last_result={"cycle": 12, "status": "ok", "job": 1, "part_tag": 7, "error_code": None,
                                   "finished_at": finished})
    run = _run(tmp_path)
    assert run.exit_code == 0, run.output
    assert "last result: cycle 12 ok, job 1, part tag 7, finished 2026-11-23 14:02:31" in run.stdout
    assert "None" not in run.stdout
    _status(tmp_path, last_result={"cycle": 13, "status": "error", "error_code": "PLC_TRIGGER_DROPPED"})
    assert "last result: cycle 13 error PLC_TRIGGER_DROPPED" in _run(tmp_path).stdout
    _status(tmp_path, last_result={"cycle": 14, "status": "ok", "job": 2, "part": "hood", "part_tag": 8,
                                   "finished_at": finished})
    shown = _run(tmp_path).stdout
    assert "last result: cycle 14 ok, job 2, part hood, part tag 8, finished 2026-11-23 14:02:31" in shown
