"""ChArUco board pages and specs (``ltm board``), and calibration input errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pipeline_helpers import one_line_error, run_ltm

from ltmstore.capture.board import (
    BoardDetector,
    BoardSpec,
    board_image,
    board_spec,
    load_board,
    paper_size,
    parse_squares,
    write_board,
)
from ltmstore.core.errors import LtmError


def test_default_a4_board_fits_the_page():
    spec = board_spec("A4")
    assert spec.squares == (9, 6) and spec.square_length == pytest.approx(0.03)
    assert spec.dictionary == "DICT_5X5_50"
    w, h = spec.size
    assert w <= 0.297 - 0.02 and h <= 0.21 - 0.02
    assert spec.marker_length == pytest.approx(0.0225)


def test_squares_given_take_the_largest_square_that_fits():
    spec = board_spec("A3", squares=(10, 7))
    assert spec.squares == (10, 7)
    assert spec.square_length == pytest.approx(0.0395)  # 277 mm / 7 inside the margins


def test_big_boards_pick_a_bigger_dictionary():
    assert board_spec("A0").dictionary == "DICT_5X5_1000"


def test_detection_finds_every_corner_of_the_rendered_board():
    spec = board_spec("A4")
    image = np.pad(board_image(spec, 4000), 40, constant_values=255)
    obj, img, ids = BoardDetector(spec).detect(image)
    assert len(ids) == (spec.squares[0] - 1) * (spec.squares[1] - 1)
    # board point (x, y) is at pixel (x * 4000 - 0.5 + 40, ...)
    np.testing.assert_allclose(img, obj[:, :2] * 4000 - 0.5 + 40, atol=0.3)


def test_to_plane_is_centred_with_s_up_and_z_above():
    spec = board_spec("A4")
    w, h = spec.size
    rsz = spec.to_plane(np.array([[w / 2, h / 2, 0.0], [w, 0.0, -0.3]]))
    np.testing.assert_allclose(rsz, [[0, 0, 0], [w / 2, h / 2, 0.3]], atol=1e-12)
    np.testing.assert_allclose(spec.from_plane(rsz), [[w / 2, h / 2, 0], [w, 0, -0.3]],
                               atol=1e-12)


@pytest.mark.parametrize("suffix", [".png", ".pdf"])
def test_write_board_writes_page_and_spec(tmp_path, suffix):
    spec = board_spec("A5")
    info = write_board(tmp_path / f"b{suffix}", spec, dpi=100)
    assert (tmp_path / f"b{suffix}").stat().st_size > 1000
    assert load_board(info["spec"]) == spec
    with pytest.raises(LtmError, match="already exists; pass --overwrite"):
        write_board(tmp_path / f"b{suffix}", spec)


def test_png_is_true_to_scale(tmp_path):
    from PIL import Image

    write_board(tmp_path / "b.png", board_spec("A4"), dpi=100)
    with Image.open(tmp_path / "b.png") as im:
        assert im.size == (round(0.297 / 0.0254 * 100), round(0.21 / 0.0254 * 100))
        assert round(im.info["dpi"][0]) == 100


@pytest.mark.parametrize(("call", "pattern"), [
    (lambda: paper_size("B7"), "--size 'B7' must be one of"),
    (lambda: parse_squares("9by6"), "--squares '9by6' must look like NXxNY"),
    (lambda: board_spec("A5", squares=(40, 30), square_mm=30), "do not fit"),
    (lambda: board_spec("A0", square_mm=10), r"need \d+ markers; expected at most 1000"),
    (lambda: BoardSpec((5, 4), 0.03, 0.04, "DICT_5X5_50", (0.2, 0.2)), "marker_length"),
    (lambda: BoardSpec.from_json({"format": "x"}), "not a board spec"),
    (lambda: BoardSpec.from_json({"format": "ltm-board/1", "squares": [5]}), "malformed"),
])
def test_bad_board_arguments(call, pattern):
    with pytest.raises(LtmError, match=pattern):
        call()


def test_load_board_missing_or_not_json(tmp_path):
    with pytest.raises(LtmError, match="does not exist; expected the JSON written by"):
        load_board(tmp_path / "nope.json")
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(LtmError, match="is not valid JSON"):
        load_board(tmp_path / "bad.json")


def test_cli_board_and_its_errors(tmp_path):
    proc = run_ltm("board", tmp_path / "board.pdf", "--size", "A4", "--squares", "7x5")
    assert proc.returncode == 0, proc.stderr
    spec = json.loads((tmp_path / "board.json").read_text())
    assert spec["squares"] == [7, 5] and spec["format"] == "ltm-board/1"
    one_line_error(run_ltm("board", tmp_path / "board.pdf"), "already exists")
    with pytest.raises(LtmError, match="must end in .png or .pdf"):
        write_board(tmp_path / "b.jpg", board_spec("A4"))


def test_calibrate_errors(tmp_path):
    from ltmstore.capture.calibrate import calibrate_video
    from ltmstore.synthetic.writer import write_video

    write_board(tmp_path / "b.png", board_spec("A4"), dpi=50)
    write_video(tmp_path / "blank.mkv", [np.full((60, 80, 3), 128, np.uint8)] * 3)
    one_line_error(run_ltm("calibrate", tmp_path / "blank.mkv", "--board", tmp_path / "b.json",
                           "-o", tmp_path / "i.json"), "found in 0 of 3 frames")
    assert not (tmp_path / "i.json").exists()
    with pytest.raises(LtmError, match="does not exist"):
        calibrate_video(tmp_path / "none.mkv", board_spec("A4"), progress=False)


@pytest.mark.parametrize("command", ["board", "calibrate", "track", "sync", "simulate"])
def test_two_phone_commands_have_help(command, capsys):
    from ltmstore.cli import build_parser

    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args([command, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "usage: ltm" in out and ("--raw" in out if command == "simulate" else True)
