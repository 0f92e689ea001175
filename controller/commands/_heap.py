"""The process heap: keep freed memory for the next array instead of returning it at once.

glibc's ``malloc`` gives a freed block at the top of the heap back to the kernel as soon as more
than its trim threshold is free, and serves blocks above its mmap threshold from fresh mappings.
Both thresholds start small (128 kB) and follow the largest block freed so far. A ray-traced
render or an HDR merge allocates and frees arrays of megabytes many times a second: each time
the heap shrinks and grows back, and the kernel zeroes every page again on first touch.
``heliocal sim errorset`` spent 2.3 of its 5.5 s of CPU in the kernel that way (1.1 million page
faults); with the thresholds below, 0.25 s (30,000 faults), the same images.

Fixed thresholds stop glibc's adjustment (``mallopt(3)``): blocks up to 32 MB (the largest
mmap threshold glibc accepts) come from the heap, and up to 128 MB of freed heap stays in
the process for the next allocation.
"""

from __future__ import annotations

import ctypes
import ctypes.util

M_TRIM_THRESHOLD = -1  # mallopt(3) parameter numbers, <malloc.h>
M_MMAP_THRESHOLD = -3
TRIM_THRESHOLD_B = 128 << 20
MMAP_THRESHOLD_B = 32 << 20


def keep_freed_memory() -> bool:
    """Set the thresholds (module docstring). False, and nothing changed, where the C library has
    no ``mallopt`` (not glibc) or refuses the mmap threshold (a 32-bit glibc caps it at 512 kB);
    the trim threshold, set second, glibc takes at any value."""
    name = ctypes.util.find_library("c")
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError, TypeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    # Either threshold fixed alone stops the adjustment of both and makes matters worse.
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_B) and mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_B))
