"""ltmstore: relightable photographs from handheld light transport acquisition.

The package is laid out as the pipeline runs; imports point down the list:

* :mod:`ltmstore.core`: dims and the lattice, the store, provenance, errors, operators;
* :mod:`ltmstore.capture`: what makes an acquisition (phone board, calibration, tracking, sync,
  registration, video decoding, acquisition folders and ``.lp`` captures);
* :mod:`ltmstore.solve`: one module per reconstruction method, one signature;
* :mod:`ltmstore.stages`: ingest -> resample -> reconstruct -> relight (+ previews);
* :mod:`ltmstore.synthetic`: ground-truth scenes and simulated acquisitions;
* :mod:`ltmstore.judge`: SNR, held-out error, the speed-accuracy benchmark;
* :mod:`ltmstore.share`: what leaves the store for other tools;
* :mod:`ltmstore.archive` and :mod:`ltmstore.cli` on top.
"""

from __future__ import annotations

import importlib

from ltmstore.core.errors import LtmError

# The public names load on first use (PEP 562), so that ``import ltmstore.X`` and the ``ltm``
# command pay only for what they use: ``relight`` alone pulls in xarray and the solvers.
_LAZY = {"open_store": "ltmstore.core.store", "relight": "ltmstore.stages.relight"}

__all__ = ["LtmError", "__version__", "open_store", "relight"]


def __getattr__(name: str):
    if name == "__version__":
        from ltmstore.core.provenance import version

        value = version()
    elif name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
    else:
        raise AttributeError(f"module 'ltmstore' has no attribute {name!r}")
    globals()[name] = value  # once loaded, a plain attribute
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
