"""``drivers/atomic_file.py``: a file is replaced whole or not at all.

Ground truth is the file system itself: what a separate reader process reads while the file is replaced, the
bytes and the permission bits left on disk, the directory's listing after a failure.
"""

from __future__ import annotations

import errno
import json
import os
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from monoguide.drivers import atomic_file
from monoguide.drivers.atomic_file import write_atomic

# Reads the file in a loop until told to stop (or 60 s pass) and counts the reads that are not one whole
# version: each version is SIZE copies of one byte, so a half-written file is short or mixed.
READER = """
import json, sys, time
from pathlib import Path
path, stop, ready, size = Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3]), int(sys.argv[4])
reads = torn = 0
versions = set()
deadline = time.monotonic() + 60.0
while time.monotonic() < deadline:
    data = path.read_bytes()
    reads += 1
    if len(data) != size or data.count(data[:1]) != size:
        torn += 1
    else:
        versions.add(data[0])
    ready.touch()
    if stop.exists():
        break
print(json.dumps({"reads": reads, "torn": torn, "versions": len(versions)}))
"""
SIZE = 1 << 20  # 1 MiB: many pages, so a plain write is seen half-done
REPLACEMENTS = 80


def _listing(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir())


def _reader(tmp_path: Path, target: Path) -> tuple[subprocess.Popen[str], Path, Path]:
    stop, ready = tmp_path / "stop", tmp_path / "ready"
    reader = subprocess.Popen([sys.executable, "-c", READER, str(target), str(stop), str(ready), str(SIZE)],
                              stdout=subprocess.PIPE, text=True)
    return reader, stop, ready


def _result(reader: subprocess.Popen[str]) -> dict[str, int]:
    out, _ = reader.communicate(timeout=90)
    assert reader.returncode == 0
    return json.loads(out)


def test_text_and_bytes_are_written_and_read_back(tmp_path: Path) -> None:
    target = tmp_path / "cell.toml"
    assert write_atomic(target, "name = \"é\"\n") == target
    assert target.read_bytes() == "name = \"é\"\n".encode()
    write_atomic(str(target), b"\x00\x01binary")
    assert target.read_bytes() == b"\x00\x01binary"
    write_atomic(target, "ü", encoding="latin-1")
    assert target.read_bytes() == b"\xfc"
    assert _listing(tmp_path) == ["cell.toml"]


def test_a_new_file_gets_the_umask_mode_a_replaced_one_keeps_its_own(tmp_path: Path) -> None:
    old_umask = os.umask(0o027)
    try:
        new = write_atomic(tmp_path / "new.json", "{}")
        assert stat.S_IMODE(new.stat().st_mode) == 0o640  # 0o666 less the umask, as open() creates it
        kept = tmp_path / "kept.json"
        kept.write_text("{}")
        kept.chmod(0o604)
        write_atomic(kept, "[]")
        assert stat.S_IMODE(kept.stat().st_mode) == 0o604 and kept.read_text() == "[]"
        given = write_atomic(tmp_path / "given.json", "{}", mode=0o666)  # exactly that, umask or not
        assert stat.S_IMODE(given.stat().st_mode) == 0o666
    finally:
        os.umask(old_umask)


def test_a_value_that_cannot_be_encoded_leaves_the_old_file_and_no_temporary_file(tmp_path: Path) -> None:
    target = tmp_path / "status.json"
    target.write_text("old")
    with pytest.raises(UnicodeEncodeError):
        write_atomic(target, "half a surrogate \ud800 cannot be UTF-8")
    assert target.read_text() == "old" and _listing(tmp_path) == ["status.json"]


def test_a_full_disk_or_a_failed_replace_leaves_the_old_file_and_no_temporary_file(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "session.json"
    target.write_text("old")

    def disk_full(fd: int) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    with monkeypatch.context() as patch:
        patch.setattr(atomic_file.os, "fsync", disk_full)
        with pytest.raises(OSError, match="No space left"):
            write_atomic(target, "new" * 100_000)
    assert target.read_text() == "old" and _listing(tmp_path) == ["session.json"]

    occupied = tmp_path / "a directory"  # os.replace cannot put a file over a directory
    occupied.mkdir()
    with pytest.raises(IsADirectoryError):
        write_atomic(occupied, "new")
    assert _listing(tmp_path) == ["a directory", "session.json"] and not list(occupied.iterdir())

    with pytest.raises(FileNotFoundError):  # a directory that is not there: nothing can be created
        write_atomic(tmp_path / "missing" / "state.json", "new")
    assert _listing(tmp_path) == ["a directory", "session.json"]


def test_before_replace_sees_the_whole_new_file_and_can_refuse_it(tmp_path: Path) -> None:
    target = tmp_path / "cell.toml"
    target.write_text("old")
    seen: list[tuple[Path, str]] = []

    def refuse(written: Path) -> None:
        seen.append((written, written.read_text()))
        raise ValueError("does not load")

    with pytest.raises(ValueError, match="does not load"):
        write_atomic(target, "new text", before_replace=refuse)
    assert seen and seen[0][1] == "new text" and seen[0][0].parent == tmp_path and seen[0][0] != target
    assert target.read_text() == "old" and _listing(tmp_path) == ["cell.toml"]
    write_atomic(target, "accepted", before_replace=lambda written: seen.append((written, written.read_text())))
    assert seen[-1][1] == "accepted" and target.read_text() == "accepted" and _listing(tmp_path) == ["cell.toml"]


def test_durable_also_syncs_the_directory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    synced: list[tuple[bool, int]] = []  # (a directory?, inode) per fsync
    real_fsync = os.fsync

    def spy(fd: int) -> None:
        info = os.fstat(fd)
        synced.append((stat.S_ISDIR(info.st_mode), info.st_ino))
        real_fsync(fd)

    monkeypatch.setattr(atomic_file.os, "fsync", spy)
    target = write_atomic(tmp_path / "a.json", "1")
    assert synced == [(False, target.stat().st_ino)]  # the file's own data, always
    synced.clear()
    target = write_atomic(tmp_path / "a.json", "2", durable=True)
    assert synced == [(False, target.stat().st_ino), (True, tmp_path.stat().st_ino)]


def test_writers_at_the_same_time_never_share_a_temporary_file(tmp_path: Path) -> None:
    target = tmp_path / "status.json"
    errors: list[BaseException] = []

    def writer(k: int) -> None:
        try:
            for i in range(25):
                write_atomic(target, json.dumps({"writer": k, "i": i}) * 50)
        except BaseException as exc:  # every failure is reported below
            errors.append(exc)

    threads = [threading.Thread(target=writer, args=(k,)) for k in range(6)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=60)
    assert not errors and _listing(tmp_path) == ["status.json"]
    last = target.read_text()
    assert last == last[: len(last) // 50] * 50  # one writer's whole text


def test_a_reader_never_sees_half_a_file_while_it_is_replaced_many_times(tmp_path: Path) -> None:
    target = tmp_path / "large.bin"
    write_atomic(target, bytes([0]) * SIZE)
    reader, stop, ready = _reader(tmp_path, target)
    deadline = time.monotonic() + 30
    while not ready.exists() and time.monotonic() < deadline:
        time.sleep(0.01)
    for k in range(1, REPLACEMENTS + 1):
        write_atomic(target, bytes([k % 251]) * SIZE)
    stop.touch()
    result = _result(reader)
    assert result["torn"] == 0
    assert result["reads"] >= 20 and result["versions"] >= 3, result  # it did read while the file was replaced
    assert _listing(tmp_path) == ["large.bin", "ready", "stop"]


def test_the_reader_does_see_a_half_written_file(tmp_path: Path) -> None:
    """The reader above can fail: given a file cut half-way through a write, it counts one torn read."""
    torn = tmp_path / "torn.bin"
    torn.write_bytes(bytes([1]) * (SIZE // 2) + bytes([2]) * (SIZE // 2))
    reader, stop, _ = _reader(tmp_path, torn)
    stop.touch()
    assert _result(reader)["torn"] >= 1
    torn.write_bytes(bytes([1]) * (SIZE // 2))
    reader, _, _ = _reader(tmp_path, torn)
    assert _result(reader)["torn"] >= 1
