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

from ltmstore.core.errors import LtmError
from ltmstore.core.provenance import version
from ltmstore.core.store import open_store
from ltmstore.stages.relight import relight

__version__ = version()

__all__ = ["LtmError", "__version__", "open_store", "relight"]
