"""Argument types and output helpers shared by the ``ltm`` command groups."""

from __future__ import annotations

import argparse
import json
import math
import numbers as _numbers
import re
from pathlib import Path

from ltmstore.core.errors import LtmError


def numbers(names: str, unit: str = "plane units"):
    """An argparse type for comma-separated numbers, e.g. ``R,S``, ``P,Q`` or ``DX,DY,DZ``."""
    count = len(names.split(","))

    def parse(text: str) -> tuple[float, ...]:
        try:
            values = tuple(float(v) for v in text.split(","))
        except ValueError:
            values = ()
        if len(values) != count:
            raise argparse.ArgumentTypeError(f"{text!r} must look like {names} ({unit})")
        return values
    return parse


# Options whose values are numbers that may start with a minus (``--light -0.1,0``, ``--ev -1``).
SIGNED_OPTIONS = ("--light", "--direction", "--view", "--ev", "--plane", "--led-offset")
_SIGNED_VALUE = re.compile(r"^-[0-9.]")


def join_signed_values(argv: list[str], options=SIGNED_OPTIONS) -> list[str]:
    """``[..., "--light", "-0.1,0"]`` becomes ``[..., "--light=-0.1,0"]``, so that argparse does
    not read the negative value as an option (it reads only plain negative numbers so)."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        if argv[i] in options and i + 1 < len(argv) and _SIGNED_VALUE.match(argv[i + 1]):
            out.append(f"{argv[i]}={argv[i + 1]}")
            i += 2
        else:
            out.append(argv[i])
            i += 1
    return out


def number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    return value


def print_json(obj) -> None:
    """Print ``obj`` as strict JSON: NaN and infinities become ``null``."""
    print(json.dumps(_finite(obj), indent=2, default=str, allow_nan=False))


def _finite(obj):
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    # NumPy registers its floats as numbers.Real: no NumPy import here (the parser is built
    # without it); an integer is always finite
    if (isinstance(obj, _numbers.Real) and not isinstance(obj, _numbers.Integral)
            and not math.isfinite(obj)):
        return None
    return obj


def add_output(p: argparse.ArgumentParser, default: str, what: str) -> None:
    """``-o/--output`` (a file, ``default``) and ``--overwrite``."""
    p.add_argument("-o", "--output", default=default, help=f"{what} (default: %(default)s)")
    p.add_argument("--overwrite", action="store_true", help=f"replace an existing {what}")


def new_output(a: argparse.Namespace, inputs: tuple = ()) -> Path:
    """``--output``, refused when it exists and ``--overwrite`` is not given, or when it is,
    lies in or holds one of ``inputs`` (:func:`ltmstore.core.paths.check_output`)."""
    from ltmstore.core.paths import check_output

    check_output(a.output, inputs)
    out = Path(a.output)
    if out.exists() and not a.overwrite:
        raise LtmError(f"output {str(out)!r} already exists; pass --overwrite to replace it")
    return out
