"""Giving a process's freed memory back to the system between tasks.

A local cluster's workers run with glibc's own memory thresholds (see
:data:`ltmstore.core.cluster.PRE_SPAWN_UNSET`: a tile's temporaries stay in the heap instead of
being mapped afresh, which is faster). Freed heap pages then stay resident: a worker carried its
tiles' heap from one tile into the next and into the light-major copy, where each band adds
hundreds of MB. The heap is trimmed after each pixel tile and around each band of the copy (a
few milliseconds each; a tile's solve costs the same with it, within 5 %).
"""

from __future__ import annotations

import ctypes
import functools


@functools.cache
def _malloc_trim():
    """glibc's ``malloc_trim``, or None where the C library has none (macOS, Windows, musl)."""
    try:
        return ctypes.CDLL(None).malloc_trim
    except (AttributeError, OSError, TypeError):
        return None


def trim() -> bool:
    """Return the free pages of this process's heap to the system.

    Returns
    -------
    bool
        Whether the C library could trim (glibc); False where there is nothing to call.
    """
    function = _malloc_trim()
    if function is None:
        return False
    function(0)
    return True
