"""The one entry point, ``monoguide``. Each command lives in its own ``cmd_*`` module."""

from __future__ import annotations

from importlib import metadata
from typing import Annotated

import typer

from monoguide.daemon import cmd_detect, cmd_journal, cmd_plan, cmd_probe, cmd_run, cmd_simcell, cmd_solve, cmd_status
from monoguide.daemon.cmd_calibrate import calibrate
from monoguide.daemon.cmd_simulate import simulate

HELP = "Vision-guided robotics: measure a large part with a flange camera, write the robot's base offset."

app = typer.Typer(
    name="monoguide",
    help=HELP,
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
app.command("solve")(cmd_solve.solve)
app.command("plan")(cmd_plan.plan)
app.command("detect")(cmd_detect.detect)
app.command("probe")(cmd_probe.probe)
app.command("sim-cell")(cmd_simcell.sim_cell)
app.command("status")(cmd_status.status)
app.command("simulate")(simulate)
app.command("run")(cmd_run.run)
app.command("calibrate")(calibrate)
app.add_typer(cmd_journal.app, name="journal")


def _print_version(value: bool) -> None:
    if value:
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
