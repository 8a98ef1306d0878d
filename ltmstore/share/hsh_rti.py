"""HSH RTI files (``.rti``, ``#HSH1.2``): RTIViewer's hemispherical-harmonics format.

Layout (readers checked: RTIViewer ``Hsh::loadData`` with the universal-RTI branch, the one
``.rti`` files take; Relight ``LRti::loadHSH``; writer checked: Relight
``RtiBuilder::saveUniversal``): text lines ``#HSH1.2``, ``3`` (the RTI type: HSH), ``width
height 3`` (colour channels), ``terms 2 1`` (basis terms, basis type, bytes per element); then
``terms`` little-endian float32 scales and ``terms`` float32 biases; then, row by row from the
top of the image and pixel by pixel, the red terms' bytes, the green ones, the blue ones. A
byte ``c`` means ``a = (c / 255) * scale + bias``; the relit value is ``sum_k a_k H_k(theta,
phi)`` in ``[0, 1]`` display units (:func:`ltmstore.share.bases.hsh_terms`).
"""

from __future__ import annotations

import os

import numpy as np

from ltmstore.share.quantize import codes, term_range


def write(path: str | os.PathLike, coef: np.ndarray) -> None:
    """Write ``#HSH1.2`` from coefficients ``(y, x, terms, 3)`` in ``[0, 1]`` display units,
    rows top first."""
    lo, hi = term_range(coef, term_axis=2)
    scale = hi - lo
    c = codes(coef, lo, scale / 255, term_axis=2)
    height, width, terms = coef.shape[:3]
    header = f"#HSH1.2\n3\n{width} {height} 3\n{terms} 2 1\n".encode("ascii")
    with open(path, "wb") as f:
        f.write(header)
        f.write(scale.astype("<f4").tobytes())
        f.write(lo.astype("<f4").tobytes())
        f.write(np.ascontiguousarray(np.swapaxes(c, 2, 3)).tobytes())  # (y, x, channel, term)
