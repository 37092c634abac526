"""`monoguide plan` (placeholder until its issue lands)."""

from __future__ import annotations

import typer


def plan() -> None:
    """Not built yet."""
    typer.echo("not built yet", err=True)
    raise typer.Exit(2)
