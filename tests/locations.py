"""Where the tests find the checkout and the development captures beside it."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent  # the checkout
SHARED_DATA = ROOT.parent / "shared" / "data"  # the development captures (not in the repo)
