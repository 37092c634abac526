"""What every owner of a resource in this package is: a context manager that closes what it owns on the way out."""

from __future__ import annotations

from typing import Self


class Owner:
    """``with Owner(...) as owner:`` — :meth:`close` runs however the block ends (an error, Ctrl-C, a return)."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()
