"""Worker processes keep their freed memory for the next sample or batch (glibc).

Touching fresh memory (a page fault per page) costs far more than refilling memory the
process already has, most of all on virtual machines (figures in the README's benchmarks,
"Dataset build" and "Loader"). glibc hands large freed blocks back to the OS: anything over
its mmap threshold (128 KiB at start, sliding up to the largest block freed) and the top of
the heap beyond twice that. A worker that allocates and frees tens of MB per sample or batch
thus faults them in again every time:

- a build sample allocates DEM windows, masks and chips; on a Dask worker, Dask sets
  ``MALLOC_TRIM_THRESHOLD_``, which also stops the sliding threshold;
- a DataLoader worker decodes a batch of 8 demo-sized samples into tens of MB of buffers.

:func:`reuse_freed_memory` raises the mmap threshold to glibc's maximum (32 MiB) and the
trim threshold to 256 MiB. It is called in worker processes only (build pool, Dask
workers, ``MarsPairsLoader`` workers), never in the caller's own process.
"""

from __future__ import annotations

import ctypes
import sys

_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # <malloc.h>
MMAP_THRESHOLD = 32 << 20
TRIM_THRESHOLD = 256 << 20


def reuse_freed_memory() -> bool:
    """Let this process's allocator keep and reuse freed blocks under 32 MiB; True if it
    did (glibc on Linux), False elsewhere (musl, macOS, Windows: nothing changes)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
    )
