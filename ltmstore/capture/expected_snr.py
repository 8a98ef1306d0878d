"""The SNR to expect from a capture at a given sampling ratio ``K / M``, shown while capturing.

The relation is the project's own measurement on simulated handheld captures, not a model:
``bench/results/auto_handheld_mismatched.json``, made by
``python bench/auto_handheld.py --shading mismatched`` (2026-11-24): SNR_Y of the default
reconstruction (``--method auto``) against the truth, three scenes (canvas, icon, relief) at three
path densities on the 32 x 32 lattice, rendered with physics the reflectance model does not
assume (Beckmann lobe, cos^2 LED, ambient floor, clear coat). The expected value is the mean over
the scenes, interpolated linearly in ``K / M``; the spread is their standard deviation (the scene
matters more than the coverage). Outside the measured ``K / M`` range the nearest measured value
is given and :attr:`ExpectedSnr.measured` is False.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SOURCE = "bench/results/auto_handheld_mismatched.json"
COMMAND = "python bench/auto_handheld.py --shading mismatched"
RATIOS = (0.171875, 0.2958984375, 0.4150390625)  # K/M of the three path densities 15, 27, 45
SNR_DB = {  # scene -> SNR_Y (dB) of `auto` at each of RATIOS, rounded to 0.01 dB
    "canvas": (32.00, 33.12, 32.60),
    "icon": (16.09, 18.03, 20.50),
    "relief": (25.26, 28.99, 28.21),
}


@dataclass(frozen=True)
class ExpectedSnr:
    """Expected SNR_Y at one ``K / M``.

    Attributes
    ----------
    db : float
        Mean over the measured scenes.
    spread_db : float
        Standard deviation over the scenes.
    measured : bool
        ``K / M`` lies inside the measured range (otherwise the nearest end's values).
    """

    db: float
    spread_db: float
    measured: bool


def expected_snr(k_over_m: float) -> ExpectedSnr:
    """The SNR_Y to expect at sampling ratio ``k_over_m`` (see the module docstring).

    Parameters
    ----------
    k_over_m : float
        Observed cells over lattice cells.

    Returns
    -------
    ExpectedSnr
    """
    table = np.array(list(SNR_DB.values()))  # (scenes, ratios)
    at = np.array([np.interp(k_over_m, RATIOS, row) for row in table])
    return ExpectedSnr(db=float(at.mean()), spread_db=float(at.std()),
                       measured=RATIOS[0] <= k_over_m <= RATIOS[-1])


def source() -> dict:
    """Where the relation comes from, for the page and the capture's record."""
    return {"file": SOURCE, "command": COMMAND, "k_over_m": list(RATIOS),
            "snr_db": {k: list(v) for k, v in SNR_DB.items()}}
