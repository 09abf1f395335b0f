"""Keep freed memory in the process for the next batch instead of handing it back at once.

Every batch of rays, colours and passed segments is a fresh NumPy array of 0.1 to a few MiB.
glibc serves blocks that size from new memory maps (and re-maps a block as big as the last one
freed: its adaptive threshold admits only bigger ones to the heap) and trims freed heap tops,
so each batch touched every page anew: on this project's 2-core VM a page fault costs about
2 us, and tetra's eye rays took 16 ms a frame to fault in against 1.7 ms to compute (6,637
faults a frame; 0 with the heap kept). Production renderers bring their own allocator; here
the C library's own knobs do: blocks up to 32 MiB come from the heap, and up to 256 MiB of
freed heap stays mapped for reuse.
"""

import ctypes
import platform

M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # glibc's mallopt parameters (malloc.h)
MMAP_ABOVE = 32 << 20  # the largest threshold glibc accepts on 64-bit (HEAP_MAX_SIZE / 2)
TRIM_ABOVE = 256 << 20

_done = False


def keep_freed_memory() -> bool:
    """Set the thresholds once per process (glibc only; elsewhere nothing changes). Returns
    whether they are set."""
    global _done
    if _done:
        return True
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    libc = _libc()
    _done = bool(libc.mallopt(M_MMAP_THRESHOLD, MMAP_ABOVE)) and bool(
        libc.mallopt(M_TRIM_THRESHOLD, TRIM_ABOVE)
    )
    return _done


def give_back() -> bool:
    """Return the freed memory the heap keeps (`keep_freed_memory`) to the system, as a node
    does once a render is over: kept for the next batch while a render runs, it is not for
    the idle hours after (glibc's malloc_trim; elsewhere nothing). Returns whether any was."""
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    return bool(_libc().malloc_trim(0))


def _libc():
    """The C library this process runs on: its own symbols (ctypes.util.find_library would
    run ldconfig in a subprocess, 3 ms of every render's start, to find the same one)."""
    return ctypes.CDLL(None)
