"""ltmstore: relightable photographs from handheld light transport acquisition."""

from importlib.metadata import PackageNotFoundError, version

from ltmstore.errors import LtmError
from ltmstore.relight import relight
from ltmstore.store import open_store

try:
    __version__ = version("ltmstore")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

__all__ = ["LtmError", "__version__", "open_store", "relight"]
