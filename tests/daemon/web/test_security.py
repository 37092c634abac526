"""The page's security rules against a real ``monoguide web`` process: read-only, nothing from a URL becomes a
path, bounded requests, the Host header, credentials (missing, wrong, right), loopback unless credentials are
configured, the headers every answer carries, and a journal that is missing, corrupt or being written (a clear
page, the process keeps serving)."""

from __future__ import annotations

import contextlib
import hashlib
import http.client
import os
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from helpers.web_pages import Prepared, prepare_state, request, web_process

from monoguide.daemon.service import CycleEntry, Journal
from monoguide.daemon.web import hash_password

HOST, PORT = "127.0.22.1", 8221


@pytest.fixture(scope="module")
def prepared(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Prepared]:
    state = prepare_state(tmp_path_factory.mktemp("security") / "state", cycles=8)
    with web_process(state.state_dir, HOST, PORT):
        yield state


PAGES = ["/", "/now.json", "/cycles", "/cycles/3", "/cycles/3/views/1/preview.jpg", "/cycles/3/record.json",
         "/trends", "/calibration", "/static/style.css", "/no-such-page", "/cycles/999"]


@pytest.mark.parametrize("method", ["POST", "PUT", "DELETE", "PATCH", "OPTIONS"])
@pytest.mark.parametrize("path", ["/", "/cycles/3", "/cycles/3/record.json", "/static/style.css"])
def test_only_get_and_head_are_answered(prepared: Prepared, method: str, path: str) -> None:
    before = (prepared.state_dir / "journal.sqlite3").read_bytes()
    answer = request(HOST, PORT, path, method=method, headers={"content-length": "0"})
    assert answer.status == 405 and answer.headers["allow"] == "GET, HEAD"
    assert (prepared.state_dir / "journal.sqlite3").read_bytes() == before


@pytest.mark.parametrize("path", [
    "/static/../../../../../../etc/passwd", "/static/%2e%2e/%2e%2e/%2e%2e/%2e%2e/%2e%2e/etc/passwd",
    "/static/..%2f..%2f..%2f..%2f..%2f..%2fetc%2fpasswd", "/cycles/3/views/..%2f..%2f..%2fetc%2fpasswd/image.png",
    "/cycles/3/views/1/..%2f..%2f..%2f..%2fetc%2fpasswd", "/calibration/figures/..%2f..%2fetc%2fpasswd.png",
    "/cycles/..%2f..%2fetc%2fpasswd", "/static/%252e%252e/%252e%252e/etc/passwd", "/static//etc/passwd"])
def test_path_traversal_serves_nothing(prepared: Prepared, path: str) -> None:
    answer = request(HOST, PORT, path)
    assert answer.status in (400, 404), (path, answer.status)
    assert b"root:" not in answer.body


def test_a_very_long_query_or_path_is_refused(prepared: Prepared) -> None:
    assert request(HOST, PORT, "/cycles?code=" + "A" * 5000).status == 414
    assert request(HOST, PORT, "/cycles/" + "1" * 3000).status == 414
    assert request(HOST, PORT, "/cycles/" + "9" * 40).status == 404  # a number beyond SQLite's integers
    # 200 kB of headers: h11 stops reading at 16 kB and answers 400, or drops the connection mid-send
    with contextlib.suppress(ConnectionResetError):
        assert request(HOST, PORT, "/", headers={"x-long": "x" * 200_000}).status in (400, 431)
    assert request(HOST, PORT, "/now.json").status == 200  # still serving


def test_a_foreign_host_name_is_refused(prepared: Prepared) -> None:
    assert request(HOST, PORT, "/now.json", headers={"host": "evil.example"}).status == 421
    assert request(HOST, PORT, "/now.json", headers={"host": f"localhost:{PORT}"}).status == 200


@pytest.mark.parametrize("path", PAGES)
def test_every_answer_carries_the_security_headers(prepared: Prepared, path: str) -> None:
    answer = request(HOST, PORT, path)
    csp = answer.headers["content-security-policy"]
    assert "default-src 'none'" in csp and "script-src 'self'" in csp and "'unsafe-inline'" not in csp
    assert answer.headers["x-content-type-options"] == "nosniff"
    assert answer.headers["x-frame-options"] == "DENY"
    if answer.headers["content-type"].startswith("text/html"):
        html = answer.text
        assert not re.search(r"<script(?![^>]*\bsrc=)", html), "inline script"
        assert not re.search(r"\s(style|on[a-z]+)=", html), "inline style or handler"


def test_credentials_missing_wrong_and_right(tmp_path: Path, prepared: Prepared) -> None:
    users = tmp_path / "users"
    users.write_text(f"# the line's people\nmaintainer:{hash_password('roof cell 7')}\n")
    tokens = tmp_path / "tokens"
    tokens.write_text("0123456789abcdef0123\n")
    host, port = "127.0.22.2", 8222
    with web_process(prepared.state_dir, host, port, "--users", str(users), "--token-file", str(tokens)):
        missing = request(host, port, "/cycles")
        assert missing.status == 401 and missing.headers["www-authenticate"].startswith("Basic")
        assert "cycle" not in missing.text.lower().replace("credentials", "")
        wrong = _basic("maintainer", "roof cell 8")
        assert request(host, port, "/cycles", headers={"authorization": wrong}).status == 401
        assert request(host, port, "/cycles", headers={"authorization": _basic("nobody", "roof cell 7")}).status == 401
        assert request(host, port, "/cycles", headers={"authorization": "Basic !!!not-base64"}).status == 401
        assert request(host, port, "/cycles", headers={"authorization": "Bearer 0123456789abcdef0124"}).status == 401
        assert request(host, port, "/static/style.css").status == 401  # nothing is served without them
        right = request(host, port, "/cycles", headers={"authorization": _basic("maintainer", "roof cell 7")})
        assert right.status == 200 and 'data-cycle="8"' in right.text
        assert request(host, port, "/now.json", headers={"authorization": "Bearer 0123456789abcdef0123"}).status == 200


@pytest.mark.parametrize(("options", "code"), [
    (["--bind", "0.0.0.0:8223"], "WEB_AUTH_REQUIRED"),
    (["--bind", "[::]:8223"], "WEB_AUTH_REQUIRED"),
    (["--bind", "127.0.22.3:http"], "WEB_CONFIG_INVALID"),
    (["--bind", "127.0.22.3:8223", "--users", "/nonexistent/users"], "WEB_CREDENTIALS_INVALID"),
    (["--bind", "127.0.22.3:8223", "--certfile", "/nonexistent/cert.pem"], "WEB_CONFIG_INVALID"),
])
def test_refused_starts_exit_2_naming_the_code(tmp_path: Path, options: list[str], code: str) -> None:
    done = subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", "web", "--state-dir", str(tmp_path),
                           *options], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines()[-1].startswith(code + " "), done.stderr


def test_a_bad_users_line_is_named(tmp_path: Path) -> None:
    users = tmp_path / "users"
    users.write_text("maintainer:plaintext-password\n")
    done = subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", "web", "--state-dir", str(tmp_path),
                           "--bind", "0.0.0.0:8224", "--users", str(users)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "WEB_CREDENTIALS_INVALID" in done.stderr and "line 1" in done.stderr


def test_an_address_in_use_is_web_server_failed(prepared: Prepared) -> None:
    done = subprocess.run([sys.executable, "-m", "monoguide.daemon.cli", "web", "--state-dir",
                           str(prepared.state_dir), "--bind", f"{HOST}:{PORT}"], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 1 and done.stderr.strip().splitlines()[-1].startswith("WEB_SERVER_FAILED ")


def test_a_missing_then_corrupt_then_good_journal(tmp_path: Path) -> None:
    state = tmp_path / "state"
    state.mkdir()
    host, port = "127.0.22.4", 8225
    with web_process(state, host, port) as process:
        missing = request(host, port, "/cycles")
        assert missing.status == 503 and "JOURNAL_MISSING" in missing.text
        assert request(host, port, "/").status == 200  # Now says so, and keeps refreshing
        (state / "journal.sqlite3").write_bytes(b"this is not SQLite at all, " * 200)
        corrupt = request(host, port, "/cycles")
        assert corrupt.status == 503 and "JOURNAL_NOT_A_DATABASE" in corrupt.text
        assert "JOURNAL_NOT_A_DATABASE" in request(host, port, "/now.json").text
        (state / "journal.sqlite3").unlink()
        with Journal(state) as journal:
            journal.commit_cycle(CycleEntry(1.0, 2.0, 1, 7, result={"rms_px": 0.1}))
        good = request(host, port, "/cycles")
        assert good.status == 200 and 'data-cycle="1"' in good.text
        assert process.poll() is None


WRITER = """
import sys, time
from monoguide.daemon.service import CycleEntry, Journal
with Journal(sys.argv[1]) as journal:
    for n in range(int(sys.argv[2])):
        journal.commit_cycle(CycleEntry(time.time(), time.time(), 1, n, result={"rms_px": 0.1}))
        time.sleep(0.01)
"""


def test_a_journal_being_written(tmp_path: Path) -> None:
    """Opened while no service wrote it (immutable), then written by another process: every answer is good, the
    counter never goes back, and the page sees every cycle committed."""
    state = tmp_path / "state"
    with Journal(state) as journal:
        journal.commit_cycle(CycleEntry(1.0, 2.0, 1, 0, result={}))
    host, port = "127.0.22.5", 8226
    with web_process(state, host, port):
        assert request(host, port, "/cycles").status == 200
        writer = subprocess.Popen([sys.executable, "-c", WRITER, str(state), "150"])
        counters = []
        try:
            while writer.poll() is None:
                answer = request(host, port, "/now.json")
                assert answer.status == 200, answer.text
                counters.append(__import__("json").loads(answer.body)["journal"]["cycle_counter"])
                assert request(host, port, "/cycles?limit=20").status == 200
        finally:
            writer.wait(60)
        assert writer.returncode == 0
        assert counters == sorted(counters) and len(set(counters)) > 3
        time.sleep(0.1)
        final = __import__("json").loads(request(host, port, "/now.json").body)["journal"]["cycle_counter"]
        assert final == 151


def _basic(name: str, password: str) -> str:
    import base64

    return "Basic " + base64.b64encode(f"{name}:{password}".encode()).decode()


def test_https_with_a_given_certificate(tmp_path: Path, prepared: Prepared) -> None:
    """--certfile/--keyfile: the page over TLS (a self-signed certificate made here by openssl), nothing in clear."""
    import shutil
    import ssl

    if shutil.which("openssl") is None:
        pytest.fail("openssl is needed to make the test's certificate")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key), "-out",
                    str(cert), "-days", "2", "-subj", "/CN=127.0.22.6"], check=True, capture_output=True)
    host, port = "127.0.22.6", 8227
    process = subprocess.Popen([sys.executable, "-m", "monoguide.daemon.cli", "web", "--state-dir",
                                str(prepared.state_dir), "--bind", f"{host}:{port}", "--certfile", str(cert),
                                "--keyfile", str(key)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        context = ssl.create_default_context(cafile=str(cert))
        context.check_hostname = False
        deadline = time.monotonic() + 30
        while True:
            try:
                connection = http.client.HTTPSConnection(host, port, timeout=5, context=context)
                connection.request("GET", "/now.json")
                answer = connection.getresponse()
                assert answer.status == 200 and b"cycle_counter" in answer.read()
                connection.close()
                break
            except (ConnectionRefusedError, ssl.SSLError):
                assert time.monotonic() < deadline, "no TLS answer"
                time.sleep(0.2)
        with pytest.raises((http.client.HTTPException, ConnectionError, OSError)):
            plain = request(host, port, "/now.json", timeout_s=5)
            assert plain.status != 200  # a plain-HTTP request gets no page
    finally:
        process.terminate()
        process.wait(15)


def test_a_failed_login_costs_the_same_and_an_address_that_keeps_failing_waits(tmp_path: Path,
                                                                               prepared: Prepared) -> None:
    """A wrong password of a user, a name of nobody and a header that is no name and password: the page spends
    the same processor time on each (one scrypt check; before, only a user's name got one). Five failed logins from
    one address within a minute: that address gets 429 even with the right password, a header it proved before
    still passes, another address is not held up."""
    users = tmp_path / "users"
    users.write_text(f"maintainer:{hash_password('roof cell 7')}\nplanner:{hash_password('beam 12')}\n")
    host, port = "127.0.22.7", 8228
    with web_process(prepared.state_dir, host, port, "--users", str(users)) as process:
        def get(authorization: str, source: str) -> int:
            connection = http.client.HTTPConnection(host, port, timeout=10, source_address=(source, 0))
            try:
                connection.request("GET", "/now.json", headers={"authorization": authorization})
                answer = connection.getresponse()
                answer.read()
                return answer.status
            finally:
                connection.close()

        cpu: dict[str, float] = {}
        for n, (kind, header) in enumerate((("user", _basic("maintainer", "wrong")),
                                            ("nobody", _basic("nobody", "wrong")),
                                            ("garbage", "Basic " + "QUFB" * 8))):
            used = _cpu_s(process.pid)
            for attempt in range(4):
                assert get(header, f"127.0.22.{100 + 10 * n + attempt}") == 401
            cpu[kind] = (_cpu_s(process.pid) - used) / 4
        started = time.process_time()
        hashlib.scrypt(b"x", salt=b"0" * 16, n=2**14, r=8, p=1, dklen=32)
        check_s = time.process_time() - started
        print(f"failed logins, the page's CPU s each: {cpu}; one scrypt check {check_s:.3f} s")
        assert abs(cpu["user"] - cpu["nobody"]) < 0.5 * check_s and abs(cpu["user"] - cpu["garbage"]) < 0.5 * check_s

        right, source = _basic("maintainer", "roof cell 7"), "127.0.22.150"
        assert get(right, source) == 200
        for _ in range(5):
            assert get(_basic("maintainer", "guess"), source) == 401
        assert get(_basic("planner", "beam 12"), source) == 429  # right, but this address must wait
        assert get(right, source) == 200  # proved before: still good
        assert get(_basic("planner", "beam 12"), "127.0.22.151") == 200


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
