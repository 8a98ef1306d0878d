"""Giving a process's freed memory back to the system between tasks, and frames as they go.

A local cluster's workers run with glibc's own memory thresholds (see
:data:`ltmstore.core.cluster.PRE_SPAWN_UNSET`: a tile's temporaries stay in the heap instead of
being mapped afresh, which is faster). Freed heap pages then stay resident: a worker carried its
tiles' heap from one tile into the next and into the light-major copy, where each band adds
hundreds of MB. The heap is trimmed after each pixel tile and around each band of the copy (a
few milliseconds each; a tile's solve costs the same with it, within 5 %).

Decoding a video is the other way round: each frame's buffers (a 4K frame's RGB codes are 25 MB)
are allocated and freed once per frame. glibc maps an allocation that large on its own, but
freeing one raises its threshold to that size (up to 32 MB), so the next frames' buffers come
from the heap, where they can stay: ``ltm ingest`` of a 4K video at 700 Mbit/s grew its heap
by about 130 MB a second while it scanned the video, to 14-23 GB, in 3 of 3 runs of
``bench/scale_4k.py`` (never when run alone). :func:`map_large_buffers` fixes the threshold;
every :class:`~ltmstore.capture.video.VideoReader` sets it.
"""

from __future__ import annotations

import ctypes
import functools


@functools.cache
def _glibc(name: str):
    """The C library's function ``name`` (glibc's ``malloc_trim``, ``mallopt``), or None where
    it has none (macOS, Windows, musl)."""
    try:
        return getattr(ctypes.CDLL(None), name)
    except (AttributeError, OSError, TypeError):
        return None


def trim() -> bool:
    """Return the free pages of this process's heap to the system.

    Returns
    -------
    bool
        Whether the C library could trim (glibc); False where there is nothing to call.
    """
    function = _glibc("malloc_trim")
    if function is None:
        return False
    function(0)
    return True


M_MMAP_THRESHOLD = -3  # glibc's mallopt parameter
LARGE_BUFFER = 4 * 1024**2  # bytes: a 1080p frame's RGB codes are 6 MB, a 4K frame's 25 MB


def map_large_buffers(threshold: int = LARGE_BUFFER) -> bool:
    """Have glibc map every allocation of ``threshold`` bytes or more on its own and unmap it
    when it is freed, for the rest of the process (a fixed threshold: glibc no longer raises it
    as such buffers are freed).

    Returns
    -------
    bool
        Whether the C library took the setting (glibc); False where there is none.
    """
    mallopt = _glibc("mallopt")
    return mallopt is not None and bool(mallopt(M_MMAP_THRESHOLD, int(threshold)))
