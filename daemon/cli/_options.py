"""Option values the commands share the reading of."""

from __future__ import annotations

from monoguide.drivers.errors import ConfigError

MAX_JOB = 65535  # the PLC's job number (register 1) is a uint16; 0 is no job


def job_numbers(option: str, text: str | None) -> tuple[int, ...]:
    """``--jobs 1,2,2``: the job numbers in order (empty without the option); :class:`ConfigError` naming the
    option and the value otherwise."""
    if text is None:
        return ()
    try:
        jobs = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"{option} {text!r}: expected job numbers separated by commas, e.g. 1,2,2,1") from None
    if bad := [job for job in jobs if not 1 <= job <= MAX_JOB]:
        raise ConfigError(f"{option} {text!r}: {bad}: job numbers run from 1 to {MAX_JOB}")
    return jobs
