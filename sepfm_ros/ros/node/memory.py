"""Keep the node's resident memory flat under a stream of images of many sizes.

Measured on a stream of malformed images (random sizes up to a few MB, test_robustness_live.py),
two native effects grew the node by ~60 MB while the Python heap stayed flat:

- glibc's malloc raises its mmap threshold every time a large block is freed (up to 32 MB), so
  later image buffers come from the heap arenas instead of their own mappings, and the freed
  blocks stay resident as fragmentation. :func:`configure_malloc` fixes the thresholds (which
  also turns that adjustment off): every block >= 16 MiB is its own mapping, returned to the
  system on free, and a free heap top beyond 64 MiB is returned at once (the rest with every
  diagnostics report, :func:`release_free_memory`). Smaller fixed thresholds made every frame
  buffer a fresh mapping, page-faulted and zeroed again on every pair: at glibc's initial
  128 KiB each 640x480 image, pyramid level and Hough image (node at 30 Hz, templeRing: 4.5-5.6
  ms of system time per pair, 2.0 at 1 MiB; node CPU per pair 22.7 -> 17.6 ms); at 1 MiB a
  1920x1080 bgr8 frame (6.2 MB) and its grey image (2.1 MB): a 1080p camera at 30 Hz got 28 %
  of its pairs answered at 142 ms of node CPU per pair, at 16 / 64 MiB 75 % at 46 ms
  (bench_node). The fuzz streams' growth stays small: 10,000 Images +10.4 MB, 3,000
  CompressedImages +6.6 MB (+6.7 and +3.0 at 1 MiB; test_robustness_live allows 50).
- rmw_fastrtps gives every subscription a history whose payload buffers are preallocated and
  grown to the largest sample seen, and never shrink; with a reliable keep-all input the pool
  holds as many buffers as samples ever waited at once. :func:`sepfm_ros.ros.node.dds.configure_dds`
  has Fast DDS allocate a payload per sample and free it when the sample is taken (DYNAMIC
  history); publication mode and publishers' history stay rmw_fastrtps's defaults.

:func:`release_free_memory` (called with every diagnostics report) hands freed heap pages back.
All of it is best effort: a no-op outside glibc, and user Fast DDS configuration wins.
"""

from __future__ import annotations

import ctypes
import ctypes.util

# glibc's mallopt parameters (malloc.h)
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 16 * 1024 * 1024  # blocks from here on get their own mapping (see above)
TRIM_THRESHOLD_BYTES = 64 * 1024 * 1024  # a free heap top beyond this is returned at once


def _load_libc():
    """glibc's malloc_trim and mallopt, or None (another C library)."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim, mallopt = libc.malloc_trim, libc.mallopt
    except (OSError, AttributeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return trim, mallopt


_LIBC = _load_libc()


def configure_malloc() -> bool:
    """Fix glibc's mmap and trim thresholds (process-wide); False when not on glibc.

    Call it early, before images flow. Large buffers (>= 16 MiB: a 4K bgr8 frame, not a 1080p
    one) then get their own mapping and go back to the system when freed, whatever sizes came
    before; smaller ones are reused from the heap.
    """
    if _LIBC is None:
        return False
    _, mallopt = _LIBC
    ok = mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) == 1
    return mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES) == 1 and ok


def release_free_memory() -> None:
    """Return freed heap memory to the system (glibc only; a no-op elsewhere)."""
    if _LIBC is not None:
        _LIBC[0](0)
