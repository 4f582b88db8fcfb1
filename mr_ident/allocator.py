# SPDX-License-Identifier: Apache-2.0
"""Process-wide memory allocator setting for mr_ident's programs.

The LPM works on blocks of bins with temporaries of 1-10 MB. glibc's malloc serves
such sizes with fresh ``mmap`` pages (and returns them on ``free``) until its dynamic
threshold adapts, and the thread arenas keep trimming: every block then pays page
faults and kernel zeroing, and an identification takes longer, by how much depending on
the allocation history of the process (measured: docs/benchmarks.md, "Choices in the
code"). :func:`keep_freed_memory` fixes
the thresholds so that freed blocks are reused, and keeps one arena for all threads:
with an arena per thread, a block freed on one thread is not reused by the next (every
identification runs its bins, its transforms and its PFG on fresh worker threads), and the
paper-size identification held 363 MB instead of 250 MB, at the same speed (the large
blocks are few, so the threads hardly wait for the one arena's lock). It changes the whole
process, so the library never calls it; the console scripts (``mr-ident``,
``mr-ident-node``) and the benchmarks do, and an application embedding mr_ident may.
"""

from __future__ import annotations

import ctypes
import ctypes.util

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_M_ARENA_MAX = -8
#: Allocations up to this size come from the heap (glibc's largest allowed value).
MMAP_THRESHOLD = 32 << 20
#: Free memory at the top of a heap kept, not returned to the system.
TRIM_THRESHOLD = 512 << 20
#: malloc arenas: one, shared by every thread.
ARENA_MAX = 1


def keep_freed_memory() -> bool:
    """Set glibc's mmap and trim thresholds and its arenas (see the module docstring).

    Returns True when set; False where there is no glibc ``mallopt`` (no change).
    The resident size then stays at its peak instead of shrinking after each estimate.
    """
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    return all(
        bool(mallopt(option, value))
        for option, value in (
            (_M_MMAP_THRESHOLD, MMAP_THRESHOLD),
            (_M_TRIM_THRESHOLD, TRIM_THRESHOLD),
            (_M_ARENA_MAX, ARENA_MAX),
        )
    )
