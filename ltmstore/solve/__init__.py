"""Reconstruction methods: one module each, one signature.

Every method is ``solve(samples, *, ndim, **params) -> ndarray`` over a batch of LTFs of shape
``(n, *lattice)`` with NaN where a cell was not observed, returning float32 of the same shape.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ltmstore.errors import LtmError
from ltmstore.solve import cs, lars

Method = Callable[..., np.ndarray]

METHODS: dict[str, Method] = {"cs": cs.solve, "lars": lars.solve}
DEFAULT_METHOD = "cs"


def get_method(name: str) -> Method:
    """The solver called ``name``, or a clear error listing the known ones."""
    try:
        return METHODS[name]
    except KeyError:
        raise LtmError(
            f"unknown method {name!r}; expected one of {', '.join(sorted(METHODS))}"
        ) from None
