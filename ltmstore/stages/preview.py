"""Preview images of a reconstructed store: relit PNGs and an animated GIF, at the capture's
exposure (photometric, as ``ltm relight``) unless told otherwise."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ltmstore.core.dims import Plane
from ltmstore.core.imagefile import write_image
from ltmstore.core.paths import check_output
from ltmstore.core.store import open_store
from ltmstore.core.transfer import CAPTURE, check_exposure, encode_images
from ltmstore.stages.relight import relight


def circle_path(plane: Plane, n: int, *, radius: float = 0.8) -> np.ndarray:
    """``n`` light positions on a circle of ``radius`` (fraction of the half-sides)."""
    angle = np.linspace(0, 2 * np.pi, n, endpoint=False)
    rc, sc = np.mean(plane.r), np.mean(plane.s)
    hr, hs = (plane.r[1] - plane.r[0]) / 2, (plane.s[1] - plane.s[0]) / 2
    return np.column_stack([rc + radius * hr * np.cos(angle), sc + radius * hs * np.sin(angle)])


def render_previews(store, out_dir, *, n_frames: int = 24, fps: float = 12,
                    exposure: str = CAPTURE, ev: float = 0.0) -> dict:
    """Write relit PNGs (centre and four corners) and ``relight.gif`` (a circling light).

    Parameters
    ----------
    store : path-like or xarray.Dataset
        A reconstructed near-light store.
    out_dir : path-like
        Folder for ``relit_{centre,left,right,top,bottom}.png`` and ``relight.gif`` (never
        the store, a folder in it or one holding it: :func:`ltmstore.core.paths.check_output`).
    n_frames, fps : int, float
        Frames of the circling light and their rate.
    exposure : {"capture", "auto"}
        ``capture`` (default): every image at the capture's exposure (photometric: a light far
        out gives a darker image); ``auto``: all images scaled by one factor so that the
        brightest 0.5 % of their pixels clip (:func:`ltmstore.core.transfer.encode_images`).
    ev : float
        Stops added to ``exposure``.

    Returns
    -------
    dict
        The paths written.
    """
    check_exposure(exposure, ev)
    check_output(out_dir, (store,))  # a Dataset given: no path to check
    ds = open_store(store)
    acq = ds.attrs["acquisition"]
    plane, transfer = Plane.from_json(acq["plane"]), acq.get("transfer", "srgb")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rc, sc = np.mean(plane.r), np.mean(plane.s)
    hr, hs = (plane.r[1] - plane.r[0]) / 2, (plane.s[1] - plane.s[0]) / 2
    stills = {"centre": (rc, sc), "left": (rc - 0.7 * hr, sc), "right": (rc + 0.7 * hr, sc),
              "top": (rc, sc + 0.7 * hs), "bottom": (rc, sc - 0.7 * hs)}
    path = circle_path(plane, n_frames)
    lights = np.vstack([list(stills.values()), path])
    images = encode_images(relight(ds, lights).values, transfer, exposure=exposure, ev=ev)
    written = {}
    for (name, _), image in zip(stills.items(), images, strict=False):
        written[name] = out_dir / f"relit_{name}.png"
        write_image(written[name], image)
    written["gif"] = out_dir / "relight.gif"
    write_image(written["gif"], images[len(stills):], what="GIF", duration=1000 / fps, loop=0)
    return {k: str(v) for k, v in written.items()}
