"""ChArUco boards for phone tracking: ``ltm board``, the board spec, detection.

A board is printed and laid in the object plane (around or under the painting). Its JSON spec
(``ltm-board/1``) records everything detection and tracking need: the ArUco dictionary, the
square counts and sizes in metres, and the page it was laid out on. Board coordinates follow
OpenCV (``x`` along the squares to the right, ``y`` down the printed page, origin at the board's
top-left corner, ``z`` into the page); the illumination plane coordinates used by the rest of
ltmstore are centred on the board, ``r`` to the right, ``s`` up the page, ``z`` the height above
the board (:meth:`BoardSpec.to_plane`).
"""

from __future__ import annotations

import io
import json
import math
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm.auto import tqdm

from ltmstore.capture.acquisition import write_text_atomic
from ltmstore.core.errors import LtmError
from ltmstore.core.imagefile import write_bytes_atomic

FORMAT = "ltm-board/1"
PAPERS_MM = {  # portrait width, height
    "A0": (841, 1189), "A1": (594, 841), "A2": (420, 594), "A3": (297, 420),
    "A4": (210, 297), "A5": (148, 210), "letter": (215.9, 279.4),
}
DICTIONARIES = ("DICT_5X5_50", "DICT_5X5_100", "DICT_5X5_250", "DICT_5X5_1000")
MARGIN_MM = 10.0
DEFAULT_SQUARE_MM = 30.0
MARKER_FRACTION = 0.75  # marker side / square side
DEFAULT_DPI = 300
MIN_CORNERS = 6  # fewest ChArUco corners for a pose


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board laid out on a page.

    Attributes
    ----------
    squares : (int, int)
        Squares along ``x`` and ``y``.
    square_length, marker_length : float
        Side of a chessboard square and of an ArUco marker, metres.
    dictionary : str
        OpenCV predefined dictionary name, e.g. ``"DICT_5X5_250"``.
    page : (float, float)
        Page width and height, metres (the board is centred on it).
    """

    squares: tuple[int, int]
    square_length: float
    marker_length: float
    dictionary: str
    page: tuple[float, float]

    def __post_init__(self) -> None:
        nx, ny = self.squares
        if not (isinstance(nx, int) and isinstance(ny, int) and nx >= 2 and ny >= 2):
            raise LtmError(f"board squares {self.squares!r} must be two integers >= 2")
        if not (0 < self.marker_length < self.square_length):
            raise LtmError(f"board marker_length {self.marker_length!r} must be positive and "
                           f"smaller than square_length {self.square_length!r}")
        if self.dictionary not in DICTIONARIES:
            raise LtmError(f"board dictionary {self.dictionary!r} is not supported; expected "
                           f"one of {list(DICTIONARIES)}")
        capacity = _capacity(self.dictionary)
        if nx * ny // 2 > capacity:
            raise LtmError(f"board of {nx}x{ny} squares needs {nx * ny // 2} markers; "
                           f"{self.dictionary} has {capacity}")

    @property
    def size(self) -> tuple[float, float]:
        """Board width and height, metres."""
        return self.squares[0] * self.square_length, self.squares[1] * self.square_length

    def cv_board(self) -> cv2.aruco.CharucoBoard:
        """The OpenCV board object."""
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard(self.squares, self.square_length, self.marker_length,
                                      dictionary)

    def to_plane(self, xyz: np.ndarray) -> np.ndarray:
        """Board coordinates ``(..., 3)`` to plane coordinates ``(r, s, z)`` (board centred)."""
        xyz = np.asarray(xyz, dtype=np.float64)
        w, h = self.size
        return np.stack([xyz[..., 0] - w / 2, h / 2 - xyz[..., 1], -xyz[..., 2]], axis=-1)

    def from_plane(self, rsz: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`to_plane`."""
        rsz = np.asarray(rsz, dtype=np.float64)
        w, h = self.size
        return np.stack([rsz[..., 0] + w / 2, h / 2 - rsz[..., 1], -rsz[..., 2]], axis=-1)

    def to_json(self) -> dict:
        return {"format": FORMAT, "dictionary": self.dictionary, "squares": list(self.squares),
                "square_length": self.square_length, "marker_length": self.marker_length,
                "page": list(self.page), "size": list(self.size), "unit": "m",
                "coordinates": "plane r, s from the board centre (r right, s up the page), "
                               "z above the board"}

    @classmethod
    def from_json(cls, d: object, where: str = "board spec") -> BoardSpec:
        """Parse a spec dict; one-line :class:`LtmError` naming what is wrong."""
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            got = d.get("format") if isinstance(d, dict) else type(d).__name__
            raise LtmError(f"{where}: format {got!r} is not a board spec; expected {FORMAT!r} "
                           "(the JSON written by `ltm board`)")
        try:
            nx, ny = (int(v) for v in d["squares"])
            spec = cls(squares=(nx, ny), square_length=float(d["square_length"]),
                       marker_length=float(d["marker_length"]), dictionary=str(d["dictionary"]),
                       page=tuple(float(v) for v in d.get("page", (0.0, 0.0))))
        except (KeyError, TypeError, ValueError) as exc:
            raise LtmError(f"{where}: missing or malformed {exc}; expected keys dictionary, "
                           "squares [nx, ny], square_length, marker_length (metres)") from None
        except LtmError as exc:
            raise LtmError(f"{where}: {exc}") from None
        return spec


def _capacity(dictionary: str) -> int:
    """Markers in a predefined dictionary: ``"DICT_5X5_250"`` -> 250."""
    return int(dictionary.rsplit("_", 1)[1])


def read_spec_json(path: str | os.PathLike, *, what: str, written_by: str) -> object:
    """Parse a JSON file written by an ``ltm`` command (a board spec, intrinsics).

    Raises
    ------
    LtmError
        If the file is missing or not valid JSON, naming ``what`` and the command
        ``written_by`` that writes it.
    """
    path = Path(path)
    expected = f"expected the JSON written by `{written_by}`"
    if not path.is_file():
        raise LtmError(f"{what} {str(path)!r} does not exist; {expected}")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, RecursionError) as exc:  # not JSON, not UTF-8, absurd numbers or nesting
        raise LtmError(f"{what} {str(path)!r} is malformed (it is not valid JSON: "
                       f"{' '.join(str(exc).split())}); {expected}") from None


def load_board(path: str | os.PathLike) -> BoardSpec:
    """Read a board spec JSON written by :func:`write_board`."""
    path = Path(path)
    data = read_spec_json(path, what="board spec", written_by="ltm board")
    return BoardSpec.from_json(data, str(path))


def paper_size(size: str) -> tuple[float, float]:
    """Landscape page ``(width, height)`` in metres from ``"A4"``, ``"letter"`` or ``"WxHmm"``."""
    key = {k.lower(): k for k in PAPERS_MM}.get(size.strip().lower())
    if key is not None:
        h, w = PAPERS_MM[key]
    else:
        m = re.fullmatch(r"\s*([0-9.]+)\s*x\s*([0-9.]+)\s*mm\s*", size)
        if not m:
            raise LtmError(f"--size {size!r} must be one of {', '.join(PAPERS_MM)} or WxHmm "
                           "(e.g. 600x400mm)")
        w, h = float(m.group(1)), float(m.group(2))
    w, h = max(w, h), min(w, h)
    if h <= 2 * MARGIN_MM + 20:
        raise LtmError(f"--size {size!r} is too small for a board; expected at least "
                       f"{2 * MARGIN_MM + 20:.0f} mm a side")
    return w / 1000, h / 1000


def parse_squares(text: str) -> tuple[int, int]:
    """``"9x6"`` -> ``(9, 6)``."""
    m = re.fullmatch(r"\s*(\d+)\s*x\s*(\d+)\s*", text or "")
    if not m or min(int(m.group(1)), int(m.group(2))) < 2:
        raise LtmError(f"--squares {text!r} must look like NXxNY with counts >= 2, e.g. 9x6")
    return int(m.group(1)), int(m.group(2))


def board_spec(size: str = "A4", squares: tuple[int, int] | None = None,
               square_mm: float | None = None) -> BoardSpec:
    """Lay out a ChArUco board on a landscape page.

    Parameters
    ----------
    size : str
        Paper name (``A0`` ... ``A5``, ``letter``) or ``WxHmm``.
    squares : (int, int), optional
        Square counts; default: as many squares of ``square_mm`` as fit inside the margins.
    square_mm : float, optional
        Square side in mm (default 30, or the largest that fits ``squares``).

    Returns
    -------
    BoardSpec
        With the smallest 5x5 dictionary holding enough markers.
    """
    w, h = paper_size(size)
    aw, ah = w - 2 * MARGIN_MM / 1000, h - 2 * MARGIN_MM / 1000
    if squares is None:
        sq = (square_mm or DEFAULT_SQUARE_MM) / 1000
        squares = (int(aw // sq), int(ah // sq))
        if min(squares) < 2:
            raise LtmError(f"squares of {sq * 1000:g} mm do not fit a {size} page; expected "
                           "a smaller square size")
    else:
        fit = min(aw / squares[0], ah / squares[1])
        sq = fit if square_mm is None else square_mm / 1000
        if sq > fit + 1e-9:
            raise LtmError(f"{squares[0]}x{squares[1]} squares of {sq * 1000:g} mm do not fit "
                           f"a {size} page ({aw * 1000:.0f}x{ah * 1000:.0f} mm inside margins)")
    sq = math.floor(sq * 1e4) / 1e4  # a tenth of a millimetre
    markers = squares[0] * squares[1] // 2
    dictionary = next((d for d in DICTIONARIES if _capacity(d) >= markers), None)
    if dictionary is None:
        raise LtmError(f"{squares[0]}x{squares[1]} squares need {markers} markers; expected "
                       "at most 1000 (use fewer or larger squares)")
    return BoardSpec(squares=tuple(squares), square_length=sq,
                     marker_length=round(sq * MARKER_FRACTION, 6), dictionary=dictionary,
                     page=(w, h))


def board_image(spec: BoardSpec, px_per_m: float) -> np.ndarray:
    """The board alone, uint8 grey, at ``px_per_m`` (board corner ``(x, y)`` is at pixel
    ``(x * px_per_m - 0.5, y * px_per_m - 0.5)``)."""
    w, h = (round(v * px_per_m) for v in spec.size)
    return spec.cv_board().generateImage((w, h), marginSize=0, borderBits=1)


def page_image(spec: BoardSpec, dpi: int = DEFAULT_DPI) -> np.ndarray:
    """The printable page: white, the board centred, uint8 grey."""
    ppm = dpi / 0.0254
    page = np.full((round(spec.page[1] * ppm), round(spec.page[0] * ppm)), 255, np.uint8)
    board = board_image(spec, ppm)
    y0 = (page.shape[0] - board.shape[0]) // 2
    x0 = (page.shape[1] - board.shape[1]) // 2
    page[y0:y0 + board.shape[0], x0:x0 + board.shape[1]] = board
    return page


def write_board(out: str | os.PathLike, spec: BoardSpec, *, dpi: int = DEFAULT_DPI,
                overwrite: bool = False) -> dict:
    """Write the printable page (PNG or PDF, true to scale at ``dpi``) and its spec JSON beside.

    Returns
    -------
    dict
        ``image``, ``spec`` (paths) and the spec's fields.
    """
    from PIL import Image

    out = Path(out)
    if out.suffix.lower() not in (".png", ".pdf"):
        raise LtmError(f"board output {str(out)!r} must end in .png or .pdf")
    spec_path = out.with_suffix(".json")
    for path in (out, spec_path):
        if path.exists() and not overwrite:
            raise LtmError(f"output {str(path)!r} already exists; pass --overwrite to replace it")
    image, encoded = Image.fromarray(page_image(spec, dpi)), io.BytesIO()
    if out.suffix.lower() == ".pdf":
        image.save(encoded, "PDF", resolution=float(dpi))
    else:
        image.save(encoded, "PNG", dpi=(dpi, dpi))
    write_bytes_atomic(out, encoded.getvalue(), what="board")  # whole or not at all
    write_text_atomic(spec_path, json.dumps(spec.to_json(), indent=2) + "\n", what="board spec")
    return {"image": str(out), "spec": str(spec_path), "dpi": dpi, **spec.to_json()}


class BoardDetector:
    """Find a board's ChArUco corners in grey images and match them to board points."""

    def __init__(self, spec: BoardSpec) -> None:
        self.spec = spec
        self.board = spec.cv_board()
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        self._detector = cv2.aruco.CharucoDetector(self.board, cv2.aruco.CharucoParameters(),
                                                   params)

    def detect(self, gray: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Corners of one image.

        Returns
        -------
        object_points : ndarray (n, 3) float32
            Board coordinates, metres.
        image_points : ndarray (n, 2) float32
            Pixel positions.
        ids : ndarray (n,) int
            ChArUco corner ids (``n`` may be 0).
        """
        corners, ids, _, _ = self._detector.detectBoard(gray)
        if ids is None or len(ids) == 0:
            empty = np.empty((0, 3), np.float32)
            return empty, empty[:, :2], np.empty(0, int)
        obj, img = self.board.matchImagePoints(corners, ids)
        return obj.reshape(-1, 3), img.reshape(-1, 2), ids.ravel()


def video_frames(path: str | os.PathLike, *, what: str = "video", progress: bool = False,
                 desc: str | None = None) -> Iterator[tuple[int, float, np.ndarray]]:
    """Yield ``(index, time_s, grey uint8)`` for each frame of a video, with its timestamp.

    Times come from the container (``CAP_PROP_POS_MSEC``, so variable frame rates are kept)
    and fall back to ``index / fps`` where the container gives none or they do not increase.
    With ``progress``, a bar named ``desc`` counts the frames against the container's count.

    Raises
    ------
    LtmError
        If the file is missing, cannot be opened or yields no frame.
    """
    path = Path(path)
    if not path.is_file():
        raise LtmError(f"{what} {str(path)!r} does not exist")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise LtmError(f"{what} {str(path)!r} cannot be opened by OpenCV (not a video, or an "
                       "unsupported codec; expected e.g. FFV1 .mkv or mp4v .mp4)")
    fps = float(cap.get(cv2.CAP_PROP_FPS)) or 30.0
    count = int(max(cap.get(cv2.CAP_PROP_FRAME_COUNT), 0))
    bar = tqdm(total=count or None, disable=not progress, desc=desc, unit="frame")
    last = -math.inf
    n = 0
    try:
        while True:
            ok, bgr = cap.read()
            if not ok or bgr is None:
                break
            t = float(cap.get(cv2.CAP_PROP_POS_MSEC)) / 1000
            if not (math.isfinite(t) and t > last) or (n > 0 and t == 0):
                t = n / fps
            last = t
            gray = bgr if bgr.ndim == 2 else cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
            yield n, t, gray
            n += 1
            bar.update()
    finally:
        bar.close()
        cap.release()
    if n == 0:
        raise LtmError(f"{what} {str(path)!r} yields no frames")
