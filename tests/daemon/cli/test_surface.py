"""Nothing a user types changes meaning: every command, subcommand, option and argument of the previous release
(0.1.0 before the daemon became packages by feature) is still there, with the same flags, kind and whether it is
required. The ground truth is that release's surface, dumped from its own installed CLI into
``data/cli_surface_0.1.0.json``; what has been added since is listed here by name."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import typer

from monoguide.daemon.cli import app

PREVIOUS = json.loads((Path(__file__).parent / "data" / "cli_surface_0.1.0.json").read_text())
ADDED = {  # a new command (all of it), new options of a command
    "init": None, "web": None, "plant": None, "health": None, "check": None, "run": {"clear_status"},
    "sim-cell": {"part_types"},
    "simulate": {"jobs", "web", "marks", "fail_every"}, "journal list": {"job"}, "calibrate": {"job"},
}


def _surface() -> dict[str, list[dict[str, Any]]]:
    out: dict[str, list[dict[str, Any]]] = {}

    def walk(command: Any, path: list[str]) -> None:
        out[" ".join(path) or "monoguide"] = [
            {"name": p.name, "opts": sorted([*p.opts, *getattr(p, "secondary_opts", [])]),
             "kind": "argument" if "Argument" in type(p).__name__ else "option",
             "flag": bool(getattr(p, "is_flag", False)), "multiple": bool(getattr(p, "multiple", False)),
             "required": bool(p.required)} for p in command.params]
        if hasattr(command, "list_commands"):
            for name in command.list_commands(None):
                walk(command.get_command(None, name), [*path, name])

    walk(typer.main.get_command(app), [])
    return out


def test_every_command_and_option_of_the_previous_release_is_still_there_as_it_was() -> None:
    now = _surface()
    for command, params in PREVIOUS.items():
        assert command in now, f"the command {command!r} is gone"
        current = {p["name"]: p for p in now[command]}
        for param in params:
            assert current.get(param["name"]) == param, (command, param, current.get(param["name"]))


def test_what_was_added_is_only_what_is_listed() -> None:
    now = _surface()
    assert set(now) - set(PREVIOUS) == {name for name, options in ADDED.items() if options is None}
    for command, params in now.items():
        if command in PREVIOUS:
            added = {p["name"] for p in params} - {p["name"] for p in PREVIOUS[command]}
            assert added == (ADDED.get(command) or set()), (command, added)


def test_the_check_sees_a_removed_option() -> None:
    now = _surface()
    now["run"] = [p for p in now["run"] if p["name"] != "cycles"]
    missing = [p for p in PREVIOUS["run"] if p not in now["run"]]
    assert [p["name"] for p in missing] == ["cycles"]
