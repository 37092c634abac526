"""The one entry point, ``monoguide``: each command is loaded only when it runs.

The commands live in their own modules (``cmd_*``); this table names them, so that ``monoguide --version`` and
``monoguide status`` start without importing OpenCV, SciPy or the device libraries that other commands need.
"""

from __future__ import annotations

import importlib
from typing import Annotated, Any

import typer
from typer.core import TyperGroup

HELP = "Vision-guided robotics: measure a large part with a flange camera, write the robot's base offset."

# name -> (module, attribute, one line of help for `monoguide --help`); the attribute is a command function or a
# Typer app of subcommands
COMMANDS: dict[str, tuple[str, str, str]] = {
    "solve": ("monoguide.daemon.cli.solve", "solve", "Solve measurement records: part pose, base offset, uncertainty."),
    "plan": ("monoguide.daemon.cli.plan", "plan", "Plan the cell's measuring poses, or show the paper's Fig. 5 map."),
    "detect": ("monoguide.daemon.cli.detect", "detect", "Sub-pixel hole centres in an image."),
    "probe": ("monoguide.daemon.cli.probe", "probe", "Connect to a device, print its identity, try it once."),
    "sim-cell": ("monoguide.daemon.cli.simcell", "sim_cell", "Run the simulated cell's devices until stopped."),
    "status": ("monoguide.daemon.cli.status", "status", "What the running service is doing."),
    "simulate": ("monoguide.daemon.cli.simulate", "simulate",
                 "The simulated cell and the service together for N cycles: grasp error, times."),
    "run": ("monoguide.daemon.cli.run", "run", "The service: the PLC handshake driving the measuring cycle."),
    "calibrate": ("monoguide.daemon.cli.calibrate", "calibrate", "The calibration wizard of the cell."),
    "init": ("monoguide.daemon.cli.init", "init", "Write a starting cell config and the robot programs."),
    "journal": ("monoguide.daemon.cli.journal", "app", "Past cycles from the journal: list, show, resolve, export."),
    "plant": ("monoguide.daemon.cli.plant", "plant", "The cell to the plant: OPC UA (Machine Vision) and Prometheus."),
    "web": ("monoguide.daemon.cli.web", "web", "The operator page: the cell in a browser, read-only."),
    "health": ("monoguide.daemon.cli.health", "health", "How well the calibration still fits: trend, residuals."),
    "check": ("monoguide.daemon.cli.check", "check", "Check the calibration on the reference part (service stopped)."),
}


class LazyCommands(TyperGroup):
    """A group whose commands are imported when they are called (or their own --help is asked for)."""

    def list_commands(self, ctx: Any) -> list[str]:
        return list(COMMANDS)

    def get_command(self, ctx: Any, name: str) -> Any:
        if name not in COMMANDS:
            return None
        module, attribute, _ = COMMANDS[name]
        target: Any = getattr(importlib.import_module(module), attribute)
        if isinstance(target, typer.Typer):
            group = typer.main.get_command(target)
            group.name = name
            return group
        single = typer.Typer(add_completion=False, pretty_exceptions_enable=False)
        single.command(name)(target)
        command = typer.main.get_command(single)
        command.name = name
        return command

    def format_commands(self, ctx: Any, formatter: Any) -> None:
        with formatter.section("Commands"):
            formatter.write_dl([(name, short) for name, (_, _, short) in COMMANDS.items()])


app = typer.Typer(
    name="monoguide",
    help=HELP,
    cls=LazyCommands,
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


def _print_version(value: bool) -> None:
    if value:
        from importlib import metadata

        typer.echo(f"monoguide {metadata.version('monoguide')}")
        raise typer.Exit()


@app.callback(help=HELP)
def _options(
    version: Annotated[
        bool, typer.Option("--version", callback=_print_version, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    """Options that come before the command."""


def main() -> None:
    app()


if __name__ == "__main__":
    main()
