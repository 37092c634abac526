"""`monoguide plant` as a command: how it ends when it cannot serve (exit 1, one `CODE message` line), a bad plant
file (exit 2, the key named), and the password hash it prints for a [[plant.users]] entry."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

from helpers.plant_cells import plant_file
from helpers.repository import SIM_CELL

from monoguide.daemon.plant import verify_password

HOST, PORT = "127.0.85.1", 48501


def _plant(state_dir: Path, plant_toml: Path | None, *more: str,
           stdin: str | None = None) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "monoguide.daemon.cli", "plant", "--config", str(SIM_CELL), "--state-dir",
               str(state_dir), *more]
    if plant_toml is not None:
        command += ["--plant-config", str(plant_toml)]
    return subprocess.run(command, capture_output=True, text=True, timeout=90, input=stdin)


def _last_line(done: subprocess.CompletedProcess[str]) -> str:
    return done.stderr.strip().splitlines()[-1].split(": ", 1)[-1]


def test_a_key_readable_by_others_is_refused(tmp_path: Path) -> None:
    state_dir = tmp_path / "state"
    state_dir.mkdir()
    pki = state_dir / "plant"
    pki.mkdir(mode=0o700)
    (pki / "server-certificate.der").write_bytes(b"")  # both present: nothing is made
    key = pki / "server-key.pem"
    key.write_text("-----BEGIN PRIVATE KEY-----\n")
    os.chmod(key, 0o644)
    done = _plant(state_dir, plant_file(tmp_path / "plant.toml", HOST, PORT))
    assert done.returncode == 1, done.stderr
    assert _last_line(done).startswith("PLANT_CERTIFICATE ") and "readable by others (mode 644)" in done.stderr


def test_a_port_in_use_ends_it(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind((HOST, PORT + 11))  # the metrics port of this plant file
        taken.listen()
        done = _plant(tmp_path / "state", plant_file(tmp_path / "plant.toml", HOST, PORT + 10))
    assert done.returncode == 1, done.stderr
    assert _last_line(done).startswith(f"PLANT_LISTEN_FAILED metrics http://{HOST}:{PORT + 11}/metrics")


def test_a_bad_plant_file_names_the_key(tmp_path: Path) -> None:
    plant_toml = tmp_path / "plant.toml"
    plant_toml.write_text('[plant]\nopcua_prot = 4840\n')
    done = _plant(tmp_path / "state", plant_toml)
    assert done.returncode == 2
    assert _last_line(done) == (f"CONFIG_UNKNOWN_KEY {plant_toml}: [plant].opcua_prot: unknown key; "
                                "did you mean opcua_port?")
    plant_toml.write_text('[plant]\n[[plant.users]]\nname = "scada"\npassword_hash = "secret"\n')
    done = _plant(tmp_path / "state", plant_toml)
    assert done.returncode == 2 and "password_hash: expected pbkdf2_sha256$" in done.stderr


def test_the_password_hash_it_prints(tmp_path: Path) -> None:
    done = _plant(tmp_path, None, "--hash-password", stdin="correct horse\n")
    assert done.returncode == 0, done.stderr
    stored = done.stdout.strip()
    assert stored.startswith("pbkdf2_sha256$600000$") and "correct horse" not in stored
    assert verify_password("correct horse", stored) and not verify_password("correct hors", stored)


def test_the_bcrypt_hash_it_prints_for_the_metrics(tmp_path: Path) -> None:
    import bcrypt

    done = _plant(tmp_path, None, "--hash-password", "--bcrypt", stdin="scrape me\n")
    assert done.returncode == 0, done.stderr
    stored = done.stdout.strip()
    assert stored.startswith("$2b$10$") and len(stored) == 60
    assert bcrypt.checkpw(b"scrape me", stored.encode()) and not bcrypt.checkpw(b"scrape m", stored.encode())
