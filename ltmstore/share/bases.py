"""Light-direction bases exactly as the reference readers evaluate them.

Each function takes unit light directions ``(n, 3)`` and returns ``(n, B)`` basis values in the
order the format stores its coefficients:

* :func:`ptm_terms`: PTM 1.2 (Malzbender et al. 2001; HP Labs ``PtmFormat12``, RTIViewer's
  ``evalPoly``): ``(u^2, v^2, uv, u, v, 1)`` with ``(u, v)`` the direction's x and y.
* :func:`relight_ptm_terms`: the same polynomial in Relight's web order ``(1, u, v, u^2, uv,
  v^2)`` (Relight ``Rti::lightWeightsPtm``, ``relight-core.js`` ``computeLightWeightsPtm``,
  OpenLIME ``PTM.lightWeights``).
* :func:`hsh_terms`: hemispherical harmonics as RTIViewer's ``getHSH`` (and Relight's
  ``lightWeightsHsh``, ``relight-core.js``, OpenLIME ``HSH.lightWeights``) evaluate them:
  ``theta = acos(z)``, ``phi = atan2(y, x)``; 4, 9 or 16 terms.
"""

from __future__ import annotations

from math import pi, sqrt

import numpy as np

from ltmstore.core.errors import LtmError

HSH_TERMS = {1: 4, 2: 9, 3: 16}  # order (highest degree) -> number of terms


def ptm_terms(directions: np.ndarray) -> np.ndarray:
    """PTM 1.2 terms ``(u^2, v^2, uv, u, v, 1)``, shape ``(n, 6)``."""
    u, v = directions[:, 0], directions[:, 1]
    return np.column_stack([u * u, v * v, u * v, u, v, np.ones_like(u)])


def relight_ptm_terms(directions: np.ndarray) -> np.ndarray:
    """Relight's PTM order ``(1, u, v, u^2, uv, v^2)``, shape ``(n, 6)``."""
    u, v = directions[:, 0], directions[:, 1]
    return np.column_stack([np.ones_like(u), u, v, u * u, u * v, v * v])


def hsh_terms(directions: np.ndarray, order: int) -> np.ndarray:
    """HSH terms of ``order`` 1, 2 or 3 (4, 9 or 16 terms), RTIViewer's order and signs."""
    if order not in HSH_TERMS:
        raise LtmError(f"hsh order {order!r} must be 1, 2 or 3 (4, 9 or 16 terms)")
    phi = np.arctan2(directions[:, 1], directions[:, 0])
    ct = np.cos(np.arccos(np.clip(directions[:, 2], 0.0, 1.0)))
    ct2 = ct * ct
    st = np.sqrt(np.maximum(ct - ct2, 0.0))  # sqrt(cos t - cos^2 t)
    cp, sp = np.cos(phi), np.sin(phi)
    terms = [np.full_like(ct, 1 / sqrt(2 * pi)),
             sqrt(6 / pi) * cp * st,
             sqrt(3 / (2 * pi)) * (2 * ct - 1),
             sqrt(6 / pi) * st * sp]
    if order >= 2:
        terms += [sqrt(30 / pi) * np.cos(2 * phi) * (ct2 - ct),
                  sqrt(30 / pi) * cp * (2 * ct - 1) * st,
                  sqrt(5 / (2 * pi)) * (1 - 6 * ct + 6 * ct2),
                  sqrt(30 / pi) * (2 * ct - 1) * st * sp,
                  sqrt(30 / pi) * (ct2 - ct) * np.sin(2 * phi)]
    if order >= 3:
        poly = 1 - 5 * ct + 5 * ct2
        terms += [2 * sqrt(35 / pi) * np.cos(3 * phi) * st ** 3,
                  sqrt(210 / pi) * np.cos(2 * phi) * (2 * ct - 1) * (ct2 - ct),
                  2 * sqrt(21 / pi) * cp * st * poly,
                  sqrt(7 / (2 * pi)) * (-1 + 12 * ct - 30 * ct2 + 20 * ct2 * ct),
                  2 * sqrt(21 / pi) * st * poly * sp,
                  sqrt(210 / pi) * (2 * ct - 1) * (ct2 - ct) * np.sin(2 * phi),
                  2 * sqrt(35 / pi) * st ** 3 * np.sin(3 * phi)]
    return np.column_stack(terms)
