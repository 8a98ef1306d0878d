"""16-bit and float RTI captures: ingested at their precision, with their transfer."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from dome_helpers import dome, flash, rendered, surface
from dome_helpers import write_capture as write_dome_capture
from ingest_helpers import DIRS, colour_map, gains

from ltmstore.core.dims import LUMA, rgb_to_ycbcr
from ltmstore.core.errors import LtmError
from ltmstore.core.imagefile import write_image
from ltmstore.core.store import open_store
from ltmstore.core.transfer import encode, linear_to_srgb
from ltmstore.stages.ingest_rti import ingest_rti
from ltmstore.stages.reconstruct import reconstruct
from ltmstore.stages.relight import relight

DARK = 0.03  # the scene of ingest_helpers at 3 % of its light: linear 0.004 to 0.027
# the smallest step of 8-bit sRGB in light (its linear segment): 1 / 255 / 12.92
STEP_8 = 1 / 255 / 12.92


def dark_scene() -> np.ndarray:
    """``(lights, H, W, 3)`` linear RGB: ingest_helpers' colour map, dark, at each light's
    gain."""
    return DARK * gains(len(DIRS))[:, None, None, None] * colour_map()[None]


def write_capture(folder, images, *, suffix=".png", depth=8, transfer="srgb", marks=None,
                  directions=DIRS):
    """A capture of linear ``images`` encoded in ``transfer`` at ``depth`` (``marks``: the
    PNG transfer mark of each image, or None)."""
    folder.mkdir()
    lines = [str(len(images))]
    for i, (image, d) in enumerate(zip(images, directions, strict=True)):
        name = f"im{i:02d}{suffix}"
        write_image(folder / name, encode(image, transfer, depth),
                    transfer=None if marks is None else marks[i])
        lines.append(f"{name} {d[0]} {d[1]} {d[2]}")
    (folder / "dirs.lp").write_text("\n".join(lines) + "\n")
    return folder / "dirs.lp"


def relit_at_capture_lights(store) -> np.ndarray:
    reconstruct(store, progress=False)
    ds = open_store(store)
    directions = np.column_stack([ds.pose_r, ds.pose_s, ds.pose_z])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return relight(ds, directions=directions, color=False).values


def test_a_16_bit_capture_keeps_the_precision_that_8_bits_lose(tmp_path):
    """A dark gradient relit at the capture's lights: from 16-bit PNGs within a tenth of 8-bit
    sRGB's smallest step of the truth (measured 1.6e-5 against a step of 3.0e-4), from 8-bit
    ones off by more than half that step (measured 4.4e-4)."""
    truth = rgb_to_ycbcr(dark_scene().astype(np.float32))[..., 0]
    error = {}
    for depth in (8, 16):
        lp = write_capture(tmp_path / f"c{depth}", dark_scene(), depth=depth)
        record = ingest_rti(lp, tmp_path / f"s{depth}.zarr", progress=False)
        assert record["n_frames"] == len(DIRS)
        assert open_store(tmp_path / f"s{depth}.zarr").attrs["acquisition"]["depth"] == \
            f"{depth}-bit"
        error[depth] = np.abs(relit_at_capture_lights(tmp_path / f"s{depth}.zarr") - truth).max()
    assert error[16] < STEP_8 / 10 < STEP_8 / 2 < error[8], error


def test_a_linear_16_bit_tiff_capture_ingests_the_ltm_of_its_srgb_png(tmp_path):
    """The dome surface of dome_helpers as 8-bit sRGB PNGs and as 16-bit linear TIFFs (no
    transfer mark: declared linear): the same frames within half a step of 8-bit sRGB at white
    (measured at most 0.0039, RMS 0.0008), the same chroma (0.0014) and, reconstructed, the
    same LTM (relative RMS 0.0025); the TIFFs' frames are the truth to float16's rounding."""
    energy = flash(len(dome()))
    png = write_dome_capture(tmp_path / "png", energy)
    linear = (rendered(surface(12 * 14), dome()) * energy[:, None, None]).reshape(-1, 12, 14, 3)
    tif = write_capture(tmp_path / "tif", linear, suffix=".tif", depth=16, transfer="linear",
                        directions=dome())
    ingest_rti(png, tmp_path / "png.zarr", progress=False)
    ingest_rti(tif, tmp_path / "tif.zarr", progress=False, transfer="linear")
    a, b = open_store(tmp_path / "png.zarr"), open_store(tmp_path / "tif.zarr")
    assert (a.attrs["acquisition"]["transfer"], b.attrs["acquisition"]["transfer"]) == \
        ("srgb", "linear")
    assert b.attrs["acquisition"]["transfer_source"] == "declared"
    truth = linear.clip(0, 1) @ np.asarray(LUMA, dtype=np.float32)
    # float16's rounding: 2^-11 of a value at most (measured 5.0e-4 with the 16-bit step)
    np.testing.assert_allclose(b.frames.values, truth, rtol=2.0**-11, atol=2e-5)
    difference = a.frames.values - b.frames.values
    assert np.abs(difference).max() < 0.0045 and np.sqrt(np.mean(difference**2)) < 0.0012
    assert np.abs(a.chroma.values - b.chroma.values).max() < 0.003
    for store in ("png.zarr", "tif.zarr"):
        reconstruct(tmp_path / store, progress=False)
    a, b = open_store(tmp_path / "png.zarr"), open_store(tmp_path / "tif.zarr")
    ltm_a, ltm_b = a.ltm.values, b.ltm.values
    assert np.sqrt(np.mean((ltm_a - ltm_b)**2) / np.mean(ltm_b**2)) < 0.005


def test_a_float_tiff_capture_is_linear_from_its_files(tmp_path):
    images = dark_scene() * 40  # up to 1.1: light beyond white kept
    lp = write_capture(tmp_path / "c", images, suffix=".tif", depth="float")
    ingest_rti(lp, tmp_path / "s.zarr", progress=False)
    ds = open_store(tmp_path / "s.zarr")
    acquisition = ds.attrs["acquisition"]
    assert (acquisition["transfer"], acquisition["depth"]) == ("linear", "float")
    assert acquisition["transfer_source"] == "the first image 'im00.tif': floating-point samples"
    truth = rgb_to_ycbcr(images.astype(np.float32))[..., 0]
    np.testing.assert_allclose(ds.frames.values, truth, rtol=2.0**-11, atol=0)


def test_a_float_capture_declared_srgb_is_decoded_by_the_srgb_curve(tmp_path):
    images = dark_scene() * 20
    coded = linear_to_srgb(images)  # sRGB code values held as floats
    lp = write_capture(tmp_path / "c", coded, suffix=".tif", depth="float", transfer="linear")
    ingest_rti(lp, tmp_path / "s.zarr", progress=False, transfer="srgb")
    ds = open_store(tmp_path / "s.zarr")
    truth = rgb_to_ycbcr(images.astype(np.float32))[..., 0]
    np.testing.assert_allclose(ds.frames.values, truth, rtol=2.0**-10, atol=1e-6)


def test_transfer_marks_of_the_files_are_read_and_recorded(tmp_path):
    marked = write_capture(tmp_path / "lin", dark_scene(), depth=16, transfer="linear",
                           marks=["linear"] * len(DIRS))
    ingest_rti(marked, tmp_path / "lin.zarr", progress=False)
    acquisition = open_store(tmp_path / "lin.zarr").attrs["acquisition"]
    assert acquisition["transfer"] == "linear"
    assert acquisition["transfer_source"] == "the first image 'im00.png': PNG gAMA 1"
    plain = write_capture(tmp_path / "plain", dark_scene(), suffix=".tif", depth=16)
    ingest_rti(plain, tmp_path / "plain.zarr", progress=False)
    acquisition = open_store(tmp_path / "plain.zarr").attrs["acquisition"]
    assert (acquisition["transfer"], acquisition["depth"]) == ("srgb", "16-bit")
    assert acquisition["transfer_source"].startswith("default (the first image 'im00.tif': no")


@pytest.mark.parametrize("first, other, match", [
    ("linear", "srgb", r"image 'im04.png' says its transfer is srgb \(PNG sRGB chunk\); the "
     r"capture's is linear \(the first image 'im00.png': PNG gAMA 1\): declare it"),
    (None, "linear", r"image 'im04.png' says its transfer is linear \(PNG gAMA 1\); the "
     r"capture's is srgb \(default"),
])
def test_mixed_transfers_are_refused_unless_declared(tmp_path, first, other, match):
    marks = [first] * len(DIRS)
    marks[4] = other
    lp = write_capture(tmp_path / "c", dark_scene(), marks=marks)
    with pytest.raises(LtmError, match=match):
        ingest_rti(lp, tmp_path / "s.zarr", progress=False)
    assert not (tmp_path / "s.zarr").exists()
    ingest_rti(lp, tmp_path / "s.zarr", progress=False, transfer="srgb")
    assert open_store(tmp_path / "s.zarr").attrs["acquisition"]["transfer_source"] == "declared"


def test_mixed_depths_are_refused_in_one_line(tmp_path, capsys):
    from ltmstore.cli import main

    lp = write_capture(tmp_path / "c", dark_scene(), depth=16)
    write_image(lp.parent / "im03.png", encode(dark_scene()[3], "srgb"))  # 8-bit
    assert main(["ingest-rti", str(lp), str(tmp_path / "s.zarr")]) == 2
    err = capsys.readouterr().err.splitlines()  # after the progress bar, one line
    assert "Traceback" not in str(err) and [line for line in err if "ltm:" in line] == err[-1:]
    assert "image 'im03.png' is 8-bit; expected 16-bit like the first image 'im00.png'" in err[-1]
    assert not (tmp_path / "s.zarr").exists()
    write_image(lp.parent / "im03.png", encode(dark_scene()[3], "srgb", 16))  # 16-bit again
    write_image(lp.parent / "im05.tif", encode(dark_scene()[5], "linear", "float"))
    (lp.parent / "dirs.lp").write_text(lp.read_text().replace("im05.png", "im05.tif"))
    with pytest.raises(LtmError, match="image 'im05.tif' is float; expected 16-bit"):
        ingest_rti(lp, tmp_path / "s.zarr", progress=False)


def test_cli_transfer_option(tmp_path, capsys):
    from ltmstore.cli import main

    lp = write_capture(tmp_path / "c", dark_scene(), suffix=".tif", depth=16, transfer="linear")
    assert main(["ingest-rti", str(lp), str(tmp_path / "s.zarr"), "--transfer", "linear"]) == 0
    assert open_store(tmp_path / "s.zarr").attrs["acquisition"]["transfer"] == "linear"
    with pytest.raises(SystemExit) as caught:
        main(["ingest-rti", str(lp), str(tmp_path / "t.zarr"), "--transfer", "gamma"])
    assert caught.value.code == 2
    assert "invalid choice: 'gamma'" in capsys.readouterr().err
    with pytest.raises(LtmError, match="transfer 'gamma' is unknown"):
        ingest_rti(lp, tmp_path / "t.zarr", progress=False, transfer="gamma")


def test_maps_at_16_bits_and_float_hold_the_8_bit_maps(tmp_path, capsys):
    """``ltm maps --depth``: the 16-bit images are the 8-bit ones 257 times finer (within half
    an 8-bit step), the float ones the linear values behind them (encoding them gives the
    8-bit images exactly), the normal map the same at every depth."""
    import cv2
    import tifffile

    from ltmstore.cli import main
    from ltmstore.share.maps import maps

    lp = write_dome_capture(tmp_path / "c", flash(len(dome())))
    store = tmp_path / "s.zarr"
    ingest_rti(lp, store, progress=False)
    reconstruct(store, method="physical", progress=False)
    light = np.array([[0.3, 0.2, 1.0]])
    maps(store, tmp_path / "m8", directions=light)
    maps(store, tmp_path / "mf", directions=light, depth="float")
    assert main(["maps", str(store), str(tmp_path / "m16"), "--direction", "0.3,0.2,1",
                 "--depth", "16"]) == 0
    capsys.readouterr()
    names = ("normal", "albedo", "specular", "roughness", "material_000")

    def png(folder, name):
        image = cv2.imread(str(tmp_path / folder / f"{name}.png"), cv2.IMREAD_UNCHANGED)
        return image[..., ::-1] if image.ndim == 3 else image

    eight = {name: png("m8", name) for name in names}
    sixteen = {name: png("m16", name) for name in names}
    floats = {name: tifffile.imread(tmp_path / "mf" / f"{name}.tif") for name in names}
    assert all(image.dtype == np.uint16 for image in sixteen.values())
    assert all(image.dtype == np.float32 for image in floats.values())
    np.testing.assert_array_equal(sixteen["normal"], eight["normal"])
    normal = np.round((floats["normal"].astype(np.float64) * 0.5 + 0.5).clip(0, 1) * 65535)
    np.testing.assert_array_equal(normal, eight["normal"])
    for name in ("albedo", "specular", "roughness", "material_000"):
        assert np.abs(sixteen[name] / 257 - eight[name]).max() <= 0.5 + 1e-3, name
    for name in ("albedo", "specular", "material_000"):
        np.testing.assert_array_equal(encode(floats[name], "srgb"), eight[name])
    np.testing.assert_allclose(floats["roughness"], eight["roughness"] / 255,
                               atol=0.5 / 255 + 1e-6)


# XYZ to linear sRGB (IEC 61966-2-1): as a DNG's ColorMatrix1, the camera's RGB is sRGB's
XYZ_TO_SRGB = (3.2406, -1.5372, -0.4986, -0.9689, 1.8758, 0.0415, 0.0557, -0.2040, 1.0570)
RAW_WHITE = 4095  # a 12-bit sensor


def write_dng(path, colour, shape=(32, 40)):
    """A minimal DNG (tifffile): an RGGB mosaic of the linear sRGB ``colour`` over ``shape``
    (LibRaw reads no raw under 22 pixels a side), white level 4095, neutral white balance."""
    import tifffile

    mosaic = np.empty(shape, np.uint16)
    for (y, x), channel in zip([(0, 0), (0, 1), (1, 0), (1, 1)], [0, 1, 1, 2], strict=True):
        mosaic[y::2, x::2] = np.round(colour[channel] * RAW_WHITE)
    tags = [(271, "s", 0, "ltmstore", True), (272, "s", 0, "test", True),
            (50706, "B", 4, (1, 4, 0, 0), True), (50708, "s", 0, "ltmstore test", True),
            (33421, "H", 2, (2, 2), True), (33422, "B", 4, (0, 1, 1, 2), True),
            (50717, "H", 1, RAW_WHITE, True), (50714, "H", 1, 0, True),
            (50721, "2i", 9, [v for m in XYZ_TO_SRGB for v in (round(m * 10000), 10000)], True),
            (50778, "H", 1, 21, True), (50728, "2I", 3, [1, 1] * 3, True)]
    tifffile.imwrite(path, mosaic, photometric=32803, extratags=tags)


def test_a_dng_capture_is_developed_linear_at_16_bits(tmp_path):
    """DNG photographs (rawpy, LibRaw): 16-bit linear sRGB, read as linear from the file;
    a flat colour comes back as the sensor held it (12 bits: within 1/4095 and float16)."""
    folder = tmp_path / "c"
    folder.mkdir()
    colour = np.array([0.6, 0.35, 0.2])
    lines = [str(len(DIRS))]
    for i, (d, g) in enumerate(zip(DIRS, gains(len(DIRS)), strict=True)):
        write_dng(folder / f"im{i:02d}.dng", g * colour)
        lines.append(f"im{i:02d}.dng {d[0]} {d[1]} {d[2]}")
    (folder / "dirs.lp").write_text("\n".join(lines) + "\n")
    ingest_rti(folder / "dirs.lp", tmp_path / "s.zarr", progress=False)
    ds = open_store(tmp_path / "s.zarr")
    acquisition = ds.attrs["acquisition"]
    assert (acquisition["transfer"], acquisition["depth"]) == ("linear", "16-bit")
    assert acquisition["transfer_source"] == \
        "the first image 'im00.dng': a raw photograph, developed linear"
    truth = gains(len(DIRS)) * float(np.asarray(LUMA) @ colour)
    np.testing.assert_allclose(ds.frames.values, truth[:, None, None] * np.ones((32, 40)),
                               rtol=2.0**-11, atol=1 / RAW_WHITE)


def test_a_damaged_raw_photograph_is_one_line(tmp_path):
    from ltmstore.capture.photographs import decode_image

    with pytest.raises(LtmError, match=r"image 'x.dng' cannot be decoded as a raw photograph "
                                       r"\(LibRaw\): "):
        decode_image(b"II*\x00" + bytes(200), "x.dng")
