"""The two consoles every command prints to: results on standard output, errors on standard error.

On a terminal rich fits tables to its width; piped into a file or another program (no terminal) the
output is wide and plain, so a table never cuts a column (``BAD_IM…``) and ``grep`` sees whole lines.
"""

from __future__ import annotations

from rich.console import Console

PIPED_WIDTH = 400  # columns when not on a terminal: wide enough that no table of ours is cut


def stdout_console() -> Console:
    """Console for results: terminal width on a terminal, wide and without colour when piped."""
    return _console(stderr=False)


def stderr_console() -> Console:
    """Console for error lines and progress, on standard error."""
    return _console(stderr=True)


def _console(stderr: bool) -> Console:
    console = Console(stderr=stderr, highlight=False, soft_wrap=True)
    if console.is_terminal:
        return console
    return Console(stderr=stderr, highlight=False, soft_wrap=True, width=PIPED_WIDTH, no_color=True)


def say(console: Console, line: str) -> None:
    """One line as it is: no markup, no highlighting, never wrapped (a path or a code stays whole)."""
    console.print(line, markup=False, highlight=False, soft_wrap=True)
