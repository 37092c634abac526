"""``monoguide simulate --web``: the README's main job with the operator page up — the page answers during the
run, shows every cycle the journal holds once it is over, stays up until Ctrl-C, and goes with the command."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import pytest
from helpers.web_pages import request

pytestmark = [pytest.mark.slow, pytest.mark.timeout(400)]

WEB_HOST, WEB_PORT, CELL_HOST = "127.0.25.1", 8251, "127.0.25.10"


def test_simulate_keeps_the_page_up_until_ctrl_c(tmp_path) -> None:
    work = tmp_path / "work"
    run = subprocess.Popen([sys.executable, "-m", "monoguide.daemon.cli", "simulate", "--cycles", "2", "--host",
                            CELL_HOST, "--work-dir", str(work), "--web", f"{WEB_HOST}:{WEB_PORT}"],
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    try:
        answered_during_run = False
        deadline = time.monotonic() + 300
        while True:
            assert run.poll() is None, run.stderr.read()
            assert time.monotonic() < deadline, lines
            line = run.stderr.readline()
            lines.append(line.strip())
            if "operator page stays up" in line:
                break
            if not answered_during_run and "starting the service" in line:
                time.sleep(1.0)
                answered_during_run = request(WEB_HOST, WEB_PORT, "/now.json").status == 200
        assert answered_during_run, lines
        facts = json.loads(request(WEB_HOST, WEB_PORT, "/now.json").body)
        assert facts["journal"]["cycle_counter"] == 2 and facts["service"]["state"] == "stopped"
        assert request(WEB_HOST, WEB_PORT, "/cycles").text.count('data-cycle="') == 2
        time.sleep(1.0)
        assert run.poll() is None  # still holding the page
        run.send_signal(signal.SIGINT)
        assert run.wait(30) == 0
        with pytest.raises(OSError):
            request(WEB_HOST, WEB_PORT, "/now.json", timeout_s=2.0)  # the page went with the command
    finally:
        if run.poll() is None:
            run.kill()
            run.wait(10)
