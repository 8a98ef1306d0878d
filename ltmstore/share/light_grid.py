"""The web export's octahedral light grid, its resolution chosen by what it costs the relit images.

A viewer of Relight's ``bilinear`` format draws the light between the four grid nodes around it,
so a highlight sharper than the nodes' spacing is drawn as two faint ones. With the nodes' exact
relit images (no PCA, no JPEG) at the held-out lights, against the held-out photographs
(``ltm relight`` 35.78 dB on loewenkopf, 39.17 dB on SynthRTI's ``multi-obj1-material1``), the
grid alone scores 35.09 / 35.73 dB on loewenkopf at 16 / 32 nodes a side, and 35.75 / 37.49 /
38.06 / 38.61 dB on SynthRTI at 16 / 32 / 48 / 64. ``ltm export`` therefore takes the smallest
resolution of :data:`RESOLUTIONS` whose grid costs at most :data:`MAX_LOSS_DB` there, among those
whose relighting stays within :data:`NODE_PIXELS` (pixels times nodes: each node is the store
relit whole). The choice is made on a central window of the image (at most
:data:`WINDOW` pixels a side), relit only at the nodes around the checkpoints' lights.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ltmstore.share.fidelity import Checkpoints, central_window, display_images, psnr

RESOLUTIONS = (16, 24, 32, 48, 64)  # nodes a side, tried in this order
MAX_LOSS_DB = 0.25  # the most the grid may cost against the held-out photographs
MIN_DB_VS_STORE = 50.0  # without held-out photographs: the grid's least PSNR against ltm relight
NODE_PIXELS = 2**28  # pixels x grid nodes the export may relight (0.1 MP at 48: 88 s here)
WINDOW = 512  # side of the window the choice is made on, in pixels at most
MIN_ELEVATION_Z = 0.02  # grid nodes on the horizon are relit a hair above it


def node_weights(directions: np.ndarray, resolution: int) -> np.ndarray:
    """Bilinear weights ``(n, R^2)`` of the grid nodes (node ``(i, j)`` at column ``i + j R``)
    at unit light ``directions (n, 3)``, as the viewers compute them (OpenLIME ``setLight`` +
    ``BLN.lightWeights``): the direction moved onto the unit disk, then the octahedral map
    turned by 45 degrees."""
    d = np.asarray(directions, np.float64)
    x, y = d[:, 0].copy(), d[:, 1].copy()
    r = np.hypot(x, y)
    shrink = np.where(r > 1, 1 / np.maximum(r, 1e-300), 1.0)  # to the unit disk
    x, y = x * shrink, y * shrink
    z = np.sqrt(np.maximum(0.0, 1 - x * x - y * y))
    s = np.abs(x) + np.abs(y) + z
    u = ((x + y) / s + 1) / 2 * (resolution - 1)
    v = ((y - x) / s + 1) / 2 * (resolution - 1)
    su = np.clip(np.floor(u), 0, resolution - 2).astype(int)
    sv = np.clip(np.floor(v), 0, resolution - 2).astype(int)
    du, dv = u - su, v - sv
    w = np.zeros((len(d), resolution * resolution))
    rows = np.arange(len(d))
    for (i, j), weight in (((0, 0), (1 - du) * (1 - dv)), ((1, 0), du * (1 - dv)),
                           ((0, 1), (1 - du) * dv), ((1, 1), du * dv)):
        np.add.at(w, (rows, su + i + (sv + j) * resolution), weight)
    return w


def grid_directions(resolution: int) -> np.ndarray:
    """Unit light directions ``(R^2, 3)`` of the grid nodes, node ``(i, j)`` at row ``i + j R``
    (the order of Relight's and OpenLIME's ``basePixelOffset``)."""
    t = np.linspace(-1.0, 1.0, resolution)
    x, y = np.meshgrid(t, t, indexing="xy")  # x varies along a row: index i + j R
    lx, ly = (x - y) / 2, (x + y) / 2
    lz = np.maximum(1 - np.abs(lx) - np.abs(ly), MIN_ELEVATION_Z)
    d = np.column_stack([lx.ravel(), ly.ravel(), lz.ravel()])
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def window(shape: tuple[int, int]) -> tuple[slice, slice]:
    """Rows and columns of the central window of an image of ``shape (y, x)``."""
    return central_window(shape, WINDOW)


def choose(relit: Callable[[np.ndarray], np.ndarray], check: Checkpoints,
           shape: tuple[int, int]) -> tuple[int, dict]:
    """The smallest affordable resolution whose grid costs at most :data:`MAX_LOSS_DB`.

    Parameters
    ----------
    relit : callable
        Display values ``(n, y, x, 3)`` in ``[0, 1]`` of the store's :func:`window` relit at
        unit directions ``(n, 3)``.
    check : Checkpoints
        The lights the choice is judged at, with ``ltm relight``'s images (and the held-out
        photographs) there.
    shape : tuple of int
        The image's ``(y, x)``: the resolutions affordable are those within
        :data:`NODE_PIXELS`.

    Returns
    -------
    resolution : int
        Nodes a side: the largest affordable where none is within the bound.
    record : dict
        ``resolution``, ``max_loss_db`` and ``loss_db``: each resolution tried and what its grid
        cost at the checkpoints, in dB against the held-out photographs (without them,
        ``db_vs_store``: its PSNR against ``ltm relight``, at least :data:`MIN_DB_VS_STORE`).
    """
    pixels = shape[0] * shape[1]
    affordable = [r for r in RESOLUTIONS if r == RESOLUTIONS[0] or pixels * r * r <= NODE_PIXELS]
    wy, wx = window(shape)
    store = check.store[:, wy, wx]
    photos = None if check.photos is None else check.photos[:, wy, wx]
    key = "loss_db" if photos is not None else "db_vs_store"
    record: dict = {key: {}}
    for resolution in affordable:
        weights = node_weights(check.directions, resolution)
        used = np.flatnonzero(weights.any(axis=0))
        nodes = relit(grid_directions(resolution)[used])
        images = display_images(np.einsum("ln,nyxc->lyxc", weights[:, used], nodes))
        if photos is not None:
            score = round(psnr(store, photos) - psnr(images, photos), 3)
            good = score <= MAX_LOSS_DB
        else:
            score = round(psnr(images, store), 2)
            good = score >= MIN_DB_VS_STORE
        record[key][resolution] = score
        if good:
            break
    record["resolution"] = resolution
    record["max_loss_db" if photos is not None else "min_db_vs_store"] = (
        MAX_LOSS_DB if photos is not None else MIN_DB_VS_STORE)
    return resolution, record
