"""The service's memory kept flat: glibc's allocator tuned at start, and what a cycle freed given back after it
(docs/cycle.md, Memory)."""

from __future__ import annotations

_M_MMAP_THRESHOLD, _M_ARENA_MAX = -3, -8  # glibc mallopt(3) parameters
MMAP_THRESHOLD_BYTES = 1 << 20
MALLOC_ARENAS = 2


def tune_malloc() -> bool:
    """Keep the service's resident memory flat (docs/cycle.md, Memory): at most ``MALLOC_ARENAS`` glibc
    arenas and a fixed mmap threshold of 1 MiB, so every frame-sized buffer (5 MB images, their grey copies)
    is mmapped and returned to the system when freed. Without it glibc raises its mmap threshold after the
    first large free and keeps later frames in per-thread arenas that fragment: the service grew from
    ~250 to over 500 MB in 30 cycles. The same as ``MALLOC_ARENA_MAX=2 MALLOC_MMAP_THRESHOLD_=1048576`` in
    the environment; call it once at start. False when the C library is not glibc (nothing changed)."""
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(_M_ARENA_MAX, MALLOC_ARENAS)) & bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES))


def trim_malloc() -> bool:
    """Give what a cycle freed back to the system now (glibc's ``malloc_trim(0)``: the free pages of every arena,
    also those amid the heap), so that the resident memory follows what the service holds, cycle after cycle,
    rather than what an arena kept from a busy frame. A few milliseconds, after the PLC was told; False when the C
    library is not glibc."""
    try:
        import ctypes

        return bool(ctypes.CDLL(None).malloc_trim(0))
    except (OSError, AttributeError):
        return False
