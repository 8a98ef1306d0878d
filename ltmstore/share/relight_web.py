"""Relight's web format: ``info.json`` and coefficient planes ``plane_<j>.jpg``, as OpenLIME
and Relight's own ``relight-core.js`` read them.

Layout (writer checked: Relight ``RtiBuilder::saveJSON``/``save``; readers: ``relight-core.js``
``loadInfo`` + ``rgbFrag``, OpenLIME ``ShaderRTI`` with ``RGB.render``): colour space ``rgb``;
``nplanes = 3 * terms``; image ``plane_<j>.jpg`` holds term ``j`` of red, green and blue in its
three channels; ``materials[0].scale`` and ``.bias`` hold one value per plane (index
``3 j + channel``), and a texel ``t`` in ``[0, 1]`` means ``(t - bias) * scale``. The relit
colour is ``sum_j w_j(light) * value_j`` in display units; ``"colorprofile": "sRGB"`` tells
OpenLIME that those are sRGB-encoded. Bases: ``ptm`` (Relight's order ``1, u, v, u^2, uv,
v^2``) and ``hsh`` (9 terms: the web readers evaluate order 2 only). JPEG planes are written
without chroma subsampling (each channel is a different coefficient).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
from PIL import Image

from ltmstore.share.quantize import codes, term_range

DEFAULT_QUALITY = 95


def write(folder: str | os.PathLike, coef: np.ndarray, basis: str, *,
          quality: int = DEFAULT_QUALITY) -> None:
    """Write ``info.json`` and the planes of coefficients ``(y, x, terms, 3)`` (display units,
    rows top first) into the existing empty ``folder``."""
    folder = Path(folder)
    lo, hi = term_range(coef, term_axis=2)
    scale = hi - lo
    c = codes(coef, lo, scale / 255, term_axis=2)
    height, width, terms = coef.shape[:3]
    for j in range(terms):
        Image.fromarray(np.ascontiguousarray(c[:, :, j, :])).save(
            folder / f"plane_{j}.jpg", quality=int(quality), subsampling=0)
    info = {"width": width, "height": height, "format": "jpg", "type": basis,
            "colorspace": "rgb", "nplanes": 3 * terms, "quality": int(quality),
            "colorprofile": "sRGB",
            "materials": [{"scale": np.repeat(scale, 3).tolist(),
                           "bias": np.repeat(-lo / scale, 3).tolist()}]}
    (folder / "info.json").write_text(json.dumps(info, indent=1))
