"""The names and defaults that the ``ltm`` parser shows (choices, defaults, limits in help texts).

They are copies of the library's own (named beside each), kept here so that building the parser
(``ltm --help``, and every command before its work starts) imports neither the library's numerics
nor NumPy, Zarr, xarray or Dask: the library modules that define them import those at the top.
``tests/cli/test_help.py`` checks that each copy equals its original.
"""

from __future__ import annotations

# ltmstore.synthetic.scenes.SCENES
SCENES = ("canvas", "icon", "relief")

# ltmstore.synthetic.raw.SHADING_NAMES
SHADINGS = ("ggx", "mismatched")

# the keys of ltmstore.solve.METHODS and ltmstore.solve.DEFAULT_METHOD
METHOD_NAMES = ("blend", "cs", "cubic", "hsh", "kernel", "lars", "omp", "physical", "ptm", "rbf",
                "svt")
DEFAULT_METHOD = "auto"

# ltmstore.stages.reconstruct.TARGET_RATIO and MIN_RATIO
TARGET_RATIO = 0.29
MIN_RATIO = 0.02

# ltmstore.core.transfer.CAPTURE, EXPOSURES and EV_LIMIT
CAPTURE = "capture"
EXPOSURES = ("capture", "auto")
EV_LIMIT = 20.0

# ltmstore.share.export.FORMATS, WEB_BASES, COLORS and HSH_ORDERS
FORMATS = ("ptm", "hsh", "relight")
WEB_BASES = ("bilinear", "ptm", "hsh")
COLORS = ("rgb", "lrgb")
HSH_ORDERS = (2, 3)

# ltmstore.share.relight_web.DEFAULT_QUALITY
DEFAULT_QUALITY = 95

# ltmstore.share.pca_web.PLANES and MAX_PCA_LOSS_DB
PLANES = (27, 36, 48)
PCA_MAX_LOSS_DB = 0.25

# ltmstore.share.light_grid.RESOLUTIONS and MAX_LOSS_DB
GRID_RESOLUTIONS = (16, 24, 32, 48, 64)
GRID_MAX_LOSS_DB = 0.25

# ltmstore.share.tiles.LAYOUTS and TILE_SIZE
LAYOUTS = ("image", "deepzoom")
TILE_SIZE = 256

# ltmstore.share.static_tiles.DEFAULT_URL and LAYOUTS
IIIF_URL = "http://127.0.0.1:8000"
TILED_LAYOUTS = ("iiif", "deepzoom")

# the names above, each with the library module and name it copies (for the test)
ORIGINALS = {
    "SCENES": ("ltmstore.synthetic.scenes", "SCENES"),
    "SHADINGS": ("ltmstore.synthetic.raw", "SHADING_NAMES"),
    "DEFAULT_METHOD": ("ltmstore.solve", "DEFAULT_METHOD"),
    "TARGET_RATIO": ("ltmstore.stages.reconstruct", "TARGET_RATIO"),
    "MIN_RATIO": ("ltmstore.stages.reconstruct", "MIN_RATIO"),
    "CAPTURE": ("ltmstore.core.transfer", "CAPTURE"),
    "EXPOSURES": ("ltmstore.core.transfer", "EXPOSURES"),
    "EV_LIMIT": ("ltmstore.core.transfer", "EV_LIMIT"),
    "FORMATS": ("ltmstore.share.export", "FORMATS"),
    "WEB_BASES": ("ltmstore.share.export", "WEB_BASES"),
    "COLORS": ("ltmstore.share.export", "COLORS"),
    "HSH_ORDERS": ("ltmstore.share.export", "HSH_ORDERS"),
    "DEFAULT_QUALITY": ("ltmstore.share.relight_web", "DEFAULT_QUALITY"),
    "GRID_RESOLUTIONS": ("ltmstore.share.light_grid", "RESOLUTIONS"),
    "GRID_MAX_LOSS_DB": ("ltmstore.share.light_grid", "MAX_LOSS_DB"),
    "PLANES": ("ltmstore.share.pca_web", "PLANES"),
    "PCA_MAX_LOSS_DB": ("ltmstore.share.pca_web", "MAX_PCA_LOSS_DB"),
    "LAYOUTS": ("ltmstore.share.tiles", "LAYOUTS"),
    "TILE_SIZE": ("ltmstore.share.tiles", "TILE_SIZE"),
    "IIIF_URL": ("ltmstore.share.static_tiles", "DEFAULT_URL"),
    "TILED_LAYOUTS": ("ltmstore.share.static_tiles", "LAYOUTS"),
}
