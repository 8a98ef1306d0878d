"""Giving a process's freed memory back to the system between tasks.

A local cluster's workers run with glibc's own memory thresholds (see
:data:`ltmstore.core.cluster.PRE_SPAWN_UNSET`: a tile's temporaries stay in the heap instead of
being mapped afresh, which is faster). Freed heap pages then stay resident, and a worker carries
its pixel tiles' heap into the light-major copy, where each band adds hundreds of MB. The copy
trims the heap around each band (a few milliseconds each). The tiles do not: with a trim after
every tile (the next tile's temporaries then mapped afresh) Notre Dame-b's solve took 442-450 s
in two runs, against 346-418 s in four without.
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
