"""The one line a command ends with on standard error, ``CODE message``: as printed, or as ``run`` and ``plant``
log it (a time stamp and the logger's name before the code)."""

from __future__ import annotations


def the_error_line(stderr: str, code_prefix: str) -> str:
    """The only non-blank line of ``stderr``, from its code (which starts with ``code_prefix``) on; fails the test
    when there are more lines (a traceback) or the code is not there."""
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1, stderr[-2000:]
    at = lines[0].find(code_prefix)
    assert at == 0 or (at > 0 and lines[0][:at].endswith(": ")), lines[0]
    return lines[0][at:]
