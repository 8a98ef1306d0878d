"""16-bit and float images: encoded, written and read back exactly, with their transfer."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image, ImageCms

from ltmstore.capture.photographs import decode_image, image_transfer
from ltmstore.core.errors import LtmError
from ltmstore.core.imagefile import check_image_path, write_image
from ltmstore.core.transfer import (
    check_depth,
    encode_images,
    exposure_gain,
    linear_to_srgb,
    transfer_lut,
)

RNG = np.random.default_rng(7)
LINEAR = (RNG.random((2, 9, 11, 3)) ** 3).astype(np.float32)  # dark-heavy, as photographs
LINEAR[0, 0, 0] = [0.0, 1.0, 2.5]  # black, white, beyond white


def old_encode_images(images, transfer, exposure="capture", ev=0.0):
    """``encode_images`` as it was before depths (the 8-bit reference, bit for bit)."""
    v = np.asarray(images) * np.float32(exposure_gain(images, exposure, ev))
    v = linear_to_srgb(v) if transfer == "srgb" else np.clip(v, 0, 1)
    return np.round(np.asarray(v) * 255).astype(np.uint8)


@pytest.mark.parametrize("transfer", ["srgb", "linear"])
@pytest.mark.parametrize("exposure, ev", [("capture", 0.0), ("capture", -1.5), ("auto", 0.5)])
def test_depth_8_is_bit_for_bit_as_before(transfer, exposure, ev):
    new = encode_images(LINEAR, transfer, exposure=exposure, ev=ev)
    assert new.dtype == np.uint8
    np.testing.assert_array_equal(new, old_encode_images(LINEAR, transfer, exposure, ev))
    np.testing.assert_array_equal(encode_images(LINEAR, transfer, exposure=exposure, ev=ev,
                                                depth=8), new)


@pytest.mark.parametrize("transfer", ["srgb", "linear"])
def test_depth_16_decodes_to_the_light_within_half_a_16_bit_step(transfer):
    codes = encode_images(LINEAR, transfer, depth="16")
    assert codes.dtype == np.uint16
    lut = transfer_lut(transfer, bits=16).astype(np.float64)
    back = lut[codes]
    inside = LINEAR.clip(0, 1)
    # the code is the nearest one: its light is within half a step (in light) of the truth
    below, above = lut[codes] - lut[np.maximum(codes, 1) - 1], lut[np.minimum(codes, 65534) + 1]
    step = np.maximum(below, above - lut[codes])
    assert (np.abs(back - inside) <= 0.5 * step * 1.01 + 1e-7).all()
    # 8 bits of the same light are 257 times coarser: every 8-bit code is the 16-bit one / 257
    eight = encode_images(LINEAR, transfer)
    assert np.abs(codes / 257.0 - eight).max() <= 0.5 + 1e-3


def test_depth_float_is_the_linear_light_times_the_gain():
    out = encode_images(LINEAR, "srgb", ev=1, depth="float")
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, LINEAR * np.float32(2.0))  # beyond white kept
    auto = encode_images(LINEAR, "linear", exposure="auto", depth="float")
    np.testing.assert_allclose(np.percentile(auto, 99.5), 1.0, rtol=1e-5)


@pytest.mark.parametrize("depth", [0, 12, "32", "half", True, None])
def test_unknown_depth_is_refused(depth):
    with pytest.raises(LtmError, match=r"depth .* is unknown; expected one of 8, 16, float"):
        check_depth(depth)


@pytest.mark.parametrize("suffix", [".png", ".tif", ".jpg"])
def test_8_bit_rgb_decodes_in_rgb_order_and_contiguous(tmp_path, suffix):
    """Channels in RGB order, and one contiguous array: a flipped view of OpenCV's BGR made
    every later pass over a large photograph copy it first."""
    image = np.zeros((9, 11, 3), dtype=np.uint8)
    image[..., 0], image[..., 2] = 200, 40  # red and blue apart, flat (JPEG keeps it)
    path = write_image(tmp_path / f"a{suffix}", image)
    back = decode_image(path.read_bytes(), path.name)
    assert back.dtype == np.uint8 and back.flags.c_contiguous
    np.testing.assert_allclose(back, image, atol=2)  # JPEG's rounding


@pytest.mark.parametrize("suffix", [".png", ".tif", ".tiff"])
def test_16_bit_rgb_written_and_read_back_exactly(tmp_path, suffix):
    image = RNG.integers(0, 65536, (9, 11, 3), dtype=np.uint16)
    path = write_image(tmp_path / f"a{suffix}", image)
    back = decode_image(path.read_bytes(), path.name)
    assert back.dtype == np.uint16
    np.testing.assert_array_equal(back, image)


def test_16_bit_grey_png_is_written_as_before(tmp_path):
    """The height map's 16-bit grey PNG still goes through imageio (same bytes as before)."""
    import imageio.v3 as iio

    grey = RNG.integers(0, 65536, (9, 11), dtype=np.uint16)
    path = write_image(tmp_path / "h.png", grey)
    assert path.read_bytes() == iio.imwrite("<bytes>", grey, extension=".png")


@pytest.mark.parametrize("suffix", [".tif", ".tiff"])
def test_float_tiff_written_and_read_back_exactly(tmp_path, suffix):
    image = (LINEAR[0] * 3).astype(np.float32)
    image[1, 2] = [1e-8, 65504.0, 1e6]  # tiny, half's top, far beyond
    path = write_image(tmp_path / f"a{suffix}", image)
    back = decode_image(path.read_bytes(), path.name)
    assert back.dtype == np.float32
    np.testing.assert_array_equal(back, image)
    assert image_transfer(path.read_bytes(), back.dtype) == ("linear",
                                                             "floating-point samples")


def test_grey_and_planar_float_tiffs_read_as_rgb(tmp_path):
    import tifffile

    grey = LINEAR[0, ..., 0]
    tifffile.imwrite(tmp_path / "g.tif", grey)
    tifffile.imwrite(tmp_path / "p.tif", np.moveaxis(LINEAR[1], -1, 0), planarconfig="separate",
                     photometric="rgb")
    tifffile.imwrite(tmp_path / "d.tif", LINEAR[1].astype(np.float64), photometric="rgb")
    tifffile.imwrite(tmp_path / "h.tif", LINEAR[1].astype(np.float16), photometric="rgb")
    read = {name: decode_image((tmp_path / name).read_bytes(), name)
            for name in ("g.tif", "p.tif", "d.tif", "h.tif")}
    np.testing.assert_array_equal(read["g.tif"], np.repeat(grey[..., None], 3, axis=2))
    np.testing.assert_array_equal(read["p.tif"], LINEAR[1])
    np.testing.assert_array_equal(read["d.tif"], LINEAR[1])
    np.testing.assert_array_equal(read["h.tif"], LINEAR[1].astype(np.float16))
    assert all(image.dtype == np.float32 for image in read.values())


def test_non_finite_and_32_bit_integer_images_are_refused(tmp_path):
    import tifffile

    bad = LINEAR[0].copy()
    bad[3, 4, 1] = np.nan
    tifffile.imwrite(tmp_path / "nan.tif", bad, photometric="rgb")
    with pytest.raises(LtmError, match="'nan.tif' holds NaN or infinite values"):
        decode_image((tmp_path / "nan.tif").read_bytes(), "nan.tif")
    tifffile.imwrite(tmp_path / "u32.tif", np.zeros((4, 4, 3), np.uint32), photometric="rgb")
    with pytest.raises(LtmError, match="'u32.tif' holds uint32 samples; expected 8- or 16-bit"):
        decode_image((tmp_path / "u32.tif").read_bytes(), "u32.tif")


@pytest.mark.parametrize("depth, good, bad, match", [
    (8, [".png", ".jpg", ".tif", ".gif"], [".exr", ".txt"], "expected an image file ending"),
    (16, [".png", ".PNG", ".tif", ".tiff"], [".jpg", ".webp", ".gif", ".exr"],
     "expected a 16-bit image file ending in .png, .tif, .tiff"),
    ("float", [".tif", ".tiff"], [".png", ".jpg", ".exr"],
     "expected a float32 image file ending in .tif, .tiff"),
])
def test_check_image_path_knows_what_each_depth_writes_to(depth, good, bad, match):
    for suffix in good:
        check_image_path(f"out/a{suffix}", depth)
    for suffix in bad:
        with pytest.raises(LtmError, match=match) as caught:
            check_image_path(f"out/a{suffix}", depth)
        assert "\n" not in str(caught.value)


def test_write_image_refuses_a_format_that_cannot_hold_the_depth(tmp_path):
    with pytest.raises(LtmError, match="'.*a.jpg' has suffix '.jpg'; expected a 16-bit image"):
        write_image(tmp_path / "a.jpg", np.zeros((4, 4, 3), np.uint16))
    with pytest.raises(LtmError, match="expected a float32 image file ending in .tif"):
        write_image(tmp_path / "a.png", np.zeros((4, 4, 3), np.float32))
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("transfer", ["srgb", "linear"])
def test_png_transfer_marks_are_read_back(tmp_path, dtype, transfer):
    image = np.full((4, 5, 3), 100, dtype=dtype)
    path = write_image(tmp_path / "a.png", image, transfer=transfer)
    data = path.read_bytes()
    said, source = image_transfer(data, dtype)
    assert said == transfer
    assert source == ("PNG sRGB chunk" if transfer == "srgb" else "PNG gAMA 1")
    np.testing.assert_array_equal(decode_image(data, "a.png"), image)  # pixels untouched
    unmarked = write_image(tmp_path / "b.png", image).read_bytes()
    assert image_transfer(unmarked, dtype) == (None, "no sRGB, ICC or gAMA mark")


def srgb_profile() -> bytes:
    return ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes()


def linear_profile() -> bytes:
    """The sRGB profile with its parametric tone curves made the identity (type 3 with
    g = a = c = 1, b = d = 0)."""
    import struct

    profile = bytearray(srgb_profile())
    count = struct.unpack(">I", profile[128:132])[0]
    for i in range(count):
        sig, offset, _ = struct.unpack(">4sII", profile[132 + 12 * i:144 + 12 * i])
        if sig in (b"rTRC", b"gTRC", b"bTRC"):
            assert profile[offset:offset + 4] == b"para"
            profile[offset + 12:offset + 32] = struct.pack(">5i", 65536, 65536, 0, 65536, 0)
    return bytes(profile)


@pytest.mark.parametrize("fmt", ["PNG", "JPEG", "TIFF"])
def test_icc_profile_tone_curves_are_read(fmt):
    image = Image.fromarray(RNG.integers(0, 256, (6, 7, 3), dtype=np.uint8))
    said = {}
    for name, profile in (("srgb", srgb_profile()), ("linear", linear_profile())):
        out = io.BytesIO()
        image.save(out, fmt, icc_profile=profile)
        said[name] = image_transfer(out.getvalue(), np.dtype(np.uint8))
    assert said["srgb"] == ("srgb", "ICC profile 'sRGB built-in'")
    assert said["linear"] == ("linear", "ICC profile 'sRGB built-in'")


@pytest.mark.parametrize("gamma, expected", [(1.0, "linear"), (0.45455, "srgb"), (1 / 1.8, None)])
def test_png_gamma_chunk(gamma, expected):
    out = io.BytesIO()
    Image.fromarray(np.zeros((3, 3, 3), np.uint8)).save(out, "PNG")
    from ltmstore.core.imagefile import _png_chunk

    data = out.getvalue()
    data = data[:33] + _png_chunk(b"gAMA", int(round(gamma * 100000)).to_bytes(4, "big")) \
        + data[33:]
    said, source = image_transfer(data, np.dtype(np.uint8))
    assert said == expected and source.startswith("PNG gAMA")
    if expected is None:
        assert source.endswith("a tone curve neither sRGB nor linear")
