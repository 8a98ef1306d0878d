"""Read and validate an acquisition folder (ARCHITECTURE.md section 3.1).

Everything a user can get wrong in ``acquisition.json`` or ``poses.csv`` is reported as one
:class:`~ltmstore.core.errors.LtmError` whose one-line message names the file, the bad value and
what was expected. Input files are only ever read.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ltmstore.core.dims import Plane, check_range
from ltmstore.core.errors import LtmError
from ltmstore.core.imagefile import write_bytes_atomic

FORMAT = "ltm-acquisition/1"
TRANSFERS = ("srgb", "linear")
REQUIRED_KEYS = ("format", "video", "poses", "plane", "transfer")
POSE_COLUMNS = ("t", "r", "s", "z")
VIEW_COLUMNS = ("p", "q")
# Optional: phone A's LED axis (the direction its LED shines, phone A's optical axis), a unit
# vector in plane coordinates (z up from the object: -1 straight down), issue 63
AXIS_COLUMNS = ("axis_r", "axis_s", "axis_z")
AXIS_NORM_TOLERANCE = 0.01  # |norm - 1| accepted (a tracker's rounding), then normalised
MIN_POSES = 2
MAX_JSON_BYTES = 1024 * 1024  # acquisition.json is a few hundred bytes
PLANE_KEYS = {"r", "s", "height", "unit"}
# Written by `ltm capture` while a capture is under way; removed only after acquisition.json
INCOMPLETE_MARKER = "CAPTURE_INCOMPLETE"
# A number as written in a CSV file: ASCII digits only (float() also takes "1_0" and other
# scripts' digits, which no pose tracker writes).
DECIMAL = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?")


@dataclass(frozen=True)
class Acquisition:
    """A validated acquisition folder.

    Attributes
    ----------
    folder : Path
        The acquisition folder (resolved).
    video, poses : Path
        The video and pose files, inside ``folder``.
    plane : Plane
        The illumination plane rectangle and height.
    transfer : str
        ``"srgb"`` or ``"linear"``: how the video's 8-bit values encode light.
    time_offset : float
        Seconds added to the pose times to put them on the video's clock.
    view_plane : dict or None
        ``{"p": [min, max], "q": [min, max]}`` for 6D acquisitions.
    object_extent : dict or None
        ``{"x": [left, right], "y": [bottom, top]}``: the object-plane rectangle the (rectified)
        video frame shows, plane units (key ``object``), or, for a frame in any orientation on
        the plane (turned, mirrored), ``{"top_left": [r, s], "top_right": [r, s],
        "bottom_left": [r, s]}``, the plane positions of the frame's corners. It places every
        pixel under the near light, which the physical reflectance model needs.
    camera_calibration : Path or None
        Camera B's intrinsics file (key ``camera_calibration``, JSON written by
        ``ltm calibrate``): ingest undoes its lens distortion.
    raw : dict
        The parsed ``acquisition.json``.
    """

    folder: Path
    video: Path
    poses: Path
    plane: Plane
    transfer: str
    time_offset: float = 0.0
    view_plane: dict | None = None
    object_extent: dict | None = None
    camera_calibration: Path | None = None
    raw: dict = field(default_factory=dict, compare=False, repr=False)

    def sha256(self) -> dict[str, str]:
        """Hex SHA-256 of the video and the poses file, and of camera B's calibration when
        declared (raises :class:`OSError` on a read error, which may be transient)."""
        hashes = {"video": sha256_file(self.video), "poses": sha256_file(self.poses)}
        if self.camera_calibration is not None:
            hashes["camera_calibration"] = sha256_file(self.camera_calibration)
        return hashes


@dataclass(frozen=True)
class Poses:
    """Light (and camera) positions over time, as read from ``poses.csv``.

    Attributes
    ----------
    t : ndarray
        Times in seconds, strictly increasing.
    r, s, z : ndarray
        Light position on the plane and its height.
    p, q : ndarray or None
        Camera position on the view plane (6D acquisitions only).
    axis : ndarray (n, 3) or None
        The LED's axis, a unit vector in plane coordinates pointing down at the object
        (columns ``axis_r, axis_s, axis_z``; None where the file has none).
    """

    t: np.ndarray
    r: np.ndarray
    s: np.ndarray
    z: np.ndarray
    p: np.ndarray | None = None
    q: np.ndarray | None = None
    axis: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t)


def resolve_inside(folder: Path, name: object, what: str) -> Path:
    """Resolve ``name`` relative to ``folder``, refusing paths that leave it.

    Parameters
    ----------
    folder : Path
        The folder the path must stay in.
    name : object
        The path as written by the user (must be a non-empty relative path string).
    what : str
        Where the name comes from, for the error message (e.g. ``"acquisition.json 'video'"``).

    Returns
    -------
    Path
        The resolved path (symlinks followed); it may not exist.

    Raises
    ------
    LtmError
        If ``name`` is not a string, is absolute, or resolves outside ``folder``.
    """
    if not isinstance(name, str) or not name.strip():
        raise LtmError(f"{what} {name!r} must be a file name relative to {str(folder)!r}")
    if "\x00" in name:
        raise LtmError(f"{what} {name!r} holds a NUL character; expected a file name")
    if Path(name).is_absolute():
        raise LtmError(f"{what} {name!r} is an absolute path; expected a path relative to "
                       f"{str(folder)!r}")
    try:
        root = folder.resolve()
        path = (root / name).resolve()
    except (OSError, RuntimeError) as exc:  # a symlink loop, a name too long
        raise LtmError(f"{what} {name!r} cannot be resolved inside {str(folder)!r}: "
                       f"{getattr(exc, 'strerror', None) or exc}") from exc
    if not path.is_relative_to(root):
        raise LtmError(f"{what} {name!r} leaves the folder {str(folder)!r} (resolves to "
                       f"{str(path)!r}); expected a path inside it")
    return path


def is_file(path: Path) -> bool:
    """``path.is_file()``, False for names the system refuses (too long, not a folder...)."""
    try:
        return path.is_file()
    except (OSError, ValueError):
        return False


def sha256_file(path: Path, *, block: int = 1 << 20) -> str:
    """Hex SHA-256 of a file, read in blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(block):
            digest.update(chunk)
    return digest.hexdigest()


def write_text_atomic(path: str | os.PathLike, text: str, *, what: str) -> None:
    """Write ``text`` to ``path`` through a temporary file beside it, moved into place: readers
    see the old file or the new one, never part of one, and a failure leaves no stray file.

    Raises :class:`LtmError` naming ``what`` (for example ``"poses"``) on a write error.
    """
    write_bytes_atomic(path, text.encode("utf-8"), what=what)


def load_acquisition(folder: str | os.PathLike) -> Acquisition:
    """Read and validate an acquisition folder.

    Parameters
    ----------
    folder : str or PathLike
        A folder holding ``acquisition.json``, the video and the poses file.

    Returns
    -------
    Acquisition
        The validated description (files are not opened beyond ``acquisition.json``).

    Raises
    ------
    LtmError
        With a one-line message for any missing or malformed part.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise LtmError(f"acquisition folder {str(folder)!r} does not exist or is not a folder")
    _refuse_incomplete(folder)
    meta_path = folder / "acquisition.json"
    resolve_inside(folder, meta_path.name, "acquisition file")  # a link may not leave it either
    meta = _read_json(meta_path)
    where = str(meta_path)
    missing = [k for k in REQUIRED_KEYS if k not in meta]
    if missing:
        raise LtmError(f"{where}: missing key(s) {missing}; expected keys {list(REQUIRED_KEYS)}")
    if meta["format"] != FORMAT:
        raise LtmError(f"{where}: format {meta['format']!r} is not supported; "
                       f"expected {FORMAT!r}")
    if meta["transfer"] not in TRANSFERS:
        raise LtmError(f"{where}: transfer {meta['transfer']!r} is unknown; "
                       f"expected one of {list(TRANSFERS)}")
    return Acquisition(
        folder=folder.resolve(),
        video=_existing_file(folder, meta["video"], f"{where}: video"),
        poses=_existing_file(folder, meta["poses"], f"{where}: poses"),
        plane=_plane(meta["plane"], where),
        transfer=meta["transfer"],
        time_offset=_time_offset(meta.get("time_offset", 0.0), where),
        view_plane=_view_plane(meta.get("view_plane"), where),
        object_extent=_object_extent(meta.get("object"), where),
        camera_calibration=(None if meta.get("camera_calibration") is None else _existing_file(
            folder, meta["camera_calibration"], f"{where}: camera_calibration")),
        raw=meta,
    )


def _refuse_incomplete(folder: Path) -> None:
    """A folder that ``ltm capture`` has not finished (it holds :data:`INCOMPLETE_MARKER`)."""
    marker = folder / INCOMPLETE_MARKER
    if not (marker.exists() or marker.is_symlink()):
        return
    try:
        text = marker.read_text(encoding="utf-8", errors="replace") if marker.is_file() else ""
    except OSError:
        text = ""
    why = " ".join(text[:300].split())
    raise LtmError(f"capture in {str(folder)!r} is incomplete: {why or 'the capture stopped'} "
                   f"(remove {INCOMPLETE_MARKER} only if you know the folder is whole)")


def _read_json(path: Path) -> dict:
    if not path.is_file():
        raise LtmError(f"acquisition folder {str(path.parent)!r} has no acquisition.json")
    if path.stat().st_size > MAX_JSON_BYTES:
        raise LtmError(f"{str(path)} is {path.stat().st_size} bytes; expected a small JSON file "
                       f"(at most {MAX_JSON_BYTES} bytes)")
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise LtmError(f"{str(path)} is not valid JSON: {exc.msg} at line {exc.lineno}, "
                       f"column {exc.colno}") from exc
    except UnicodeDecodeError as exc:
        raise LtmError(f"{str(path)} is not UTF-8 text: {exc.reason}") from exc
    except (ValueError, RecursionError) as exc:  # 5000-digit integers, nesting 100000 deep
        raise LtmError(f"{str(path)} is not a usable JSON object: "
                       f"{' '.join(str(exc).split()) or type(exc).__name__}") from exc
    if not isinstance(meta, dict):
        raise LtmError(f"{str(path)} holds a {type(meta).__name__}; expected a JSON object")
    return meta


def _existing_file(folder: Path, name: object, what: str) -> Path:
    path = resolve_inside(folder, name, what)
    if not is_file(path):
        raise LtmError(f"{what} file {name!r} does not exist in {str(folder)!r}")
    return path


def _plane(value: object, where: str) -> Plane:
    if not (isinstance(value, dict) and PLANE_KEYS - {"unit"} <= set(value) <= PLANE_KEYS
            and all(_is_range(value[k]) for k in "rs") and _is_number(value["height"])
            and isinstance(value.get("unit", "m"), str)):
        raise LtmError(f"{where}: plane {value!r} must look like "
                       "{'r': [min, max], 's': [min, max], 'height': h[, 'unit': 'm']} with "
                       "numbers (not strings) and no other key")
    try:
        plane = Plane.from_json(value)
    except LtmError as exc:
        raise LtmError(f"{where}: {exc}") from exc
    extent = (plane.r[1] - plane.r[0], plane.s[1] - plane.s[0])
    if not all(math.isfinite(e) and e > 0 for e in (*extent, plane.area)):
        raise LtmError(f"{where}: plane r {list(plane.r)}, s {list(plane.s)} spans a rectangle "
                       f"of size {list(extent)}; expected a finite, non-empty rectangle")
    return plane


def _is_number(value: object) -> bool:
    """A JSON number (not a boolean, not a string) that fits a double (``10**400`` does not)."""
    return (isinstance(value, int | float) and not isinstance(value, bool)
            and abs(value) <= sys.float_info.max)


def _is_range(value: object) -> bool:
    """A JSON ``[min, max]`` of numbers."""
    return isinstance(value, list) and len(value) == 2 and all(map(_is_number, value))


def _time_offset(value: object, where: str) -> float:
    if not _is_number(value) or not math.isfinite(value):
        raise LtmError(f"{where}: time_offset {value!r} must be a finite number of seconds")
    return float(value)


def _view_plane(value: object, where: str) -> dict | None:
    if value is None:
        return None
    ranges = None
    if isinstance(value, dict) and all(_is_range(value.get(k)) for k in VIEW_COLUMNS):
        ranges = {k: [float(value[k][0]), float(value[k][1])] for k in VIEW_COLUMNS}
    if ranges is None or not all(
        math.isfinite(lo) and math.isfinite(hi) and lo < hi for lo, hi in ranges.values()
    ):
        raise LtmError(f"{where}: view_plane {value!r} must look like "
                       "{'p': [min, max], 'q': [min, max]} with finite min < max")
    try:
        for k, (lo, hi) in ranges.items():
            check_range(f"view_plane {k}", lo, hi)
    except LtmError as exc:
        raise LtmError(f"{where}: {exc}") from None
    return ranges


OBJECT_CORNERS = ("top_left", "top_right", "bottom_left")  # ``object`` in any orientation


def _object_extent(value: object, where: str) -> dict | None:
    """``object``: ``{"x": [left, right], "y": [bottom, top]}`` (the frame's axes along ``r``
    and ``s``) or the plane positions of three of the frame's corners (any orientation)."""
    if value is None:
        return None
    keys = ("x", "y")
    if isinstance(value, dict) and set(value) == set(keys) \
            and all(_is_range(value[k]) for k in keys) \
            and all(0 < float(value[k][1]) - float(value[k][0]) < math.inf for k in keys):
        return {k: [float(value[k][0]), float(value[k][1])] for k in keys}
    if isinstance(value, dict) and set(value) == set(OBJECT_CORNERS) \
            and all(_is_range(value[k]) for k in OBJECT_CORNERS):
        (x0, y0), (x1, y1), (x2, y2) = ((float(a) for a in value[k]) for k in OBJECT_CORNERS)
        sides = (math.hypot(x1 - x0, y1 - y0), math.hypot(x2 - x0, y2 - y0))
        cross = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if all(0 < side < math.inf for side in sides) and abs(cross) > 1e-6 * sides[0] * sides[1]:
            return {k: [float(a) for a in value[k]] for k in OBJECT_CORNERS}
    raise LtmError(f"{where}: object {value!r} must look like {{'x': [left, right], 'y': "
                   "[bottom, top]} with min < max, a finite width (the frame's columns along r, "
                   "its rows down s), or in any orientation {'top_left': [r, s], 'top_right': "
                   "[r, s], 'bottom_left': [r, s]} (the frame's corners on the plane, not in a "
                   "line), with numbers")


def load_poses(path: str | os.PathLike, *, min_samples: int = MIN_POSES) -> Poses:
    """Read and validate ``poses.csv`` (header ``t,r,s,z[,p,q][,axis_r,axis_s,axis_z]``).

    The optional ``axis_r, axis_s, axis_z`` give phone A's LED axis at each row: a unit vector
    (to :data:`AXIS_NORM_TOLERANCE`; normalised) in plane coordinates, pointing down at the
    object (``axis_z < 0``).

    Parameters
    ----------
    path : str or PathLike
        The poses file.
    min_samples : int, default 2
        The fewest rows accepted.

    Returns
    -------
    Poses
        Arrays of float64, one entry per row.

    Raises
    ------
    LtmError
        If the header is wrong, a value is not a finite number (naming its line), the times are
        not strictly increasing (naming the first offending line), an axis is not a unit vector
        pointing down at the object (naming its line) or there are too few rows.
    """
    path = Path(path)
    header, lines, rows = _read_csv(path)
    cols = np.asarray(rows, dtype=np.float64).reshape(-1, len(header))
    if len(cols) < min_samples:
        raise LtmError(f"{str(path)}: {len(cols)} pose sample(s); expected at least {min_samples}")
    steps = np.diff(cols[:, 0])
    if (steps <= 0).any():
        i = int(np.argmax(steps <= 0)) + 1
        now, before = float(cols[i, 0]), float(cols[i - 1, 0])
        raise LtmError(f"{str(path)} line {lines[i]}: time {now!r} does not come after "
                       f"{before!r}; expected strictly increasing times")
    values = dict(zip(header, cols.T, strict=True))
    if AXIS_COLUMNS[0] in values:
        values["axis"] = _axis(path, lines, np.column_stack([values.pop(k) for k in AXIS_COLUMNS]))
    return Poses(**values)


def _axis(path: Path, lines: list[int], axis: np.ndarray) -> np.ndarray:
    """The LED axes ``(n, 3)`` normalised, or a one-line error naming the first bad row."""
    norm = np.linalg.norm(axis, axis=1)
    bad = (np.abs(norm - 1) > AXIS_NORM_TOLERANCE) | (axis[:, 2] >= 0)
    if bad.any():
        i = int(np.argmax(bad))
        shown = ", ".join(f"{v:g}" for v in axis[i])
        raise LtmError(f"{str(path)} line {lines[i]}: LED axis ({shown}) must be a unit vector "
                       f"(length {norm[i]:.3g}) pointing down at the object (axis_z < 0)")
    return axis / norm[:, None]


def _read_csv(path: Path) -> tuple[list[str], list[int], list[list[float]]]:
    """Header, file line numbers and finite values of every non-blank row."""
    expected = [",".join(POSE_COLUMNS + extra) for extra in
                ((), VIEW_COLUMNS, AXIS_COLUMNS, VIEW_COLUMNS + AXIS_COLUMNS)]
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:  # a BOM is dropped
            reader = csv.reader(fh)
            header = [h.strip() for h in next(reader, [])]
            if ",".join(header) not in expected:
                raise LtmError(f"{str(path)}: header {','.join(header)!r} must be "
                               f"{expected[0]!r} or {expected[1]!r}, optionally followed by "
                               f"{','.join(AXIS_COLUMNS)!r}")
            lines, rows = [], []
            for row in reader:
                if any(v.strip() for v in row):
                    lines.append(reader.line_num)
                    rows.append(_parse_row(path, reader.line_num, header, row))
    except csv.Error as exc:  # a field over csv.field_size_limit(), a stray NUL
        raise LtmError(f"{str(path)} line {reader.line_num}: {exc}; expected comma-separated "
                       "numbers") from None
    except OSError as exc:
        raise LtmError(f"poses file {str(path)!r} cannot be read: {exc.strerror}") from exc
    except UnicodeDecodeError as exc:
        raise LtmError(f"poses file {str(path)!r} is not UTF-8 text: {exc.reason}") from exc
    return header, lines, rows


def _parse_row(path: Path, line: int, header: list[str], row: list[str]) -> list[float]:
    if len(row) != len(header):
        raise LtmError(f"{str(path)} line {line}: {len(row)} value(s); expected {len(header)} "
                       f"({','.join(header)})")
    values = []
    for name, text in zip(header, row, strict=True):
        value = float(text) if DECIMAL.fullmatch(text.strip()) else math.nan
        if not math.isfinite(value):
            raise LtmError(f"{str(path)} line {line}: {name} = {text.strip()!r} is not a finite "
                           "number (ASCII decimal digits, e.g. -0.25 or 1e-3)")
        values.append(value)
    return values
