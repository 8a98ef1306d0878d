"""ltmstore: relightable photographs from handheld light transport acquisition."""

from importlib.metadata import PackageNotFoundError, version

from ltmstore.errors import LtmError

try:
    __version__ = version("ltmstore")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

__all__ = ["LtmError", "__version__"]
