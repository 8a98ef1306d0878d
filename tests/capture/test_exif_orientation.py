"""A photograph with an EXIF orientation tag in a classic capture (issue 64 item 7).

The ``.lp`` directions are given in the frame the photographs were taken in, the camera
sensor's: every image is read as its pixels are stored, whatever its EXIF orientation, so a
tagged photograph among untagged ones is neither turned (square) nor refused (not square), and
one warning line names the files whose tag was ignored.
"""

from __future__ import annotations

import io
import warnings

import numpy as np
import pytest
from ingest_helpers import write_capture
from PIL import Image

from ltmstore.capture.photographs import OrientationWarning, decode_image, image_orientation
from ltmstore.cli import main
from ltmstore.core.store import open_store
from ltmstore.judge.photos import load_photos
from ltmstore.stages.ingest_rti import ingest_rti

ROTATED = 6  # EXIF: turn 90 degrees clockwise to display


def encoded(rgb: np.ndarray, fmt: str, orientation: int | None = None) -> bytes:
    """``rgb`` as a JPEG or PNG file's bytes, with an EXIF orientation tag when given."""
    exif = Image.Exif()
    if orientation is not None:
        exif[0x0112] = orientation
    out = io.BytesIO()
    options = {"quality": 95} if fmt == "JPEG" else {}
    Image.fromarray(rgb).save(out, format=fmt, exif=exif, **options)
    return out.getvalue()


def pattern(h: int, w: int) -> np.ndarray:
    """An image whose every turn or mirror differs from it."""
    y, x = np.mgrid[:h, :w]
    return np.stack([(x * 40) % 256, (y * 25) % 256, (x * y * 7) % 256], -1).astype(np.uint8)


@pytest.mark.parametrize("shape", [(8, 8), (6, 10)], ids=["square", "landscape"])
@pytest.mark.parametrize("fmt", ["PNG", "JPEG"])
def test_pixels_are_read_as_stored(fmt, shape):
    rgb = pattern(*shape)
    tagged, plain = encoded(rgb, fmt, ROTATED), encoded(rgb, fmt)
    assert image_orientation(tagged, "t") == ROTATED and image_orientation(plain, "p") == 1
    out = decode_image(tagged, "t")
    assert out.shape == rgb.shape
    np.testing.assert_array_equal(out, decode_image(plain, "p"))
    if fmt == "PNG":  # lossless: exactly the stored pixels
        np.testing.assert_array_equal(out, rgb)


def tag_one(lp, name: str = "im04.png") -> None:
    """Rewrite one image of the capture beside ``lp`` with EXIF orientation 6, same pixels."""
    path = lp.parent / name
    rgb = np.asarray(Image.open(path).convert("RGB"))
    path.write_bytes(encoded(rgb, "PNG", ROTATED))


def test_ingest_reads_a_tagged_photograph_as_stored_and_says_so(tmp_path):
    lp = write_capture(tmp_path / "cap")  # 6 x 5 images: a turned one would be refused
    ingest_rti(lp, tmp_path / "plain.zarr", progress=False)
    tag_one(lp)
    with pytest.warns(OrientationWarning) as caught:
        ingest_rti(lp, tmp_path / "tagged.zarr", progress=False)
    assert len(caught) == 1
    assert "1 of 11 image(s) carry an EXIF orientation tag, ignored: 'im04.png' (6)" in str(
        caught[0].message)
    plain, tagged = open_store(tmp_path / "plain.zarr"), open_store(tmp_path / "tagged.zarr")
    for name in plain.data_vars:
        if "t" in plain[name].dims:
            np.testing.assert_array_equal(tagged[name].values, plain[name].values)


def test_load_photos_says_so_once_and_untagged_captures_say_nothing(tmp_path):
    lp = write_capture(tmp_path / "cap")
    with warnings.catch_warnings():
        warnings.simplefilter("error", OrientationWarning)
        _, before = load_photos(lp)
    tag_one(lp, "im00.png")
    tag_one(lp, "im09.png")
    with pytest.warns(OrientationWarning, match=r"2 of 11 image\(s\).*'im00.png' \(6\), "
                      r"'im09.png' \(6\); every image is read as stored") as caught:
        _, after = load_photos(lp)
    assert len(caught) == 1
    np.testing.assert_array_equal(after, before)


def test_cli_warning_is_one_line(tmp_path, capsys):
    lp = write_capture(tmp_path / "cap")
    tag_one(lp)
    assert main(["ingest-rti", str(lp), str(tmp_path / "s.zarr")]) == 0
    lines = [line for line in capsys.readouterr().err.splitlines() if "EXIF" in line]
    assert len(lines) == 1 and lines[0].startswith("ltm: warning: 1 of 11 image(s)")
    assert "'im04.png'" in lines[0]
