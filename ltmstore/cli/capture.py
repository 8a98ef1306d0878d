"""``ltm`` commands that make an acquisition from two phones: board, calibrate, track, sync."""

from __future__ import annotations

import argparse

from ltmstore.cli.args import add_output, new_output, number, numbers, print_json
from ltmstore.core.errors import LtmError


def register(sub) -> None:
    """Add the capture commands to the ``ltm`` subparsers ``sub``."""
    p = sub.add_parser("board", help="write a printable ChArUco board and its JSON spec",
                       description="Write a ChArUco board page (PNG or PDF, true to scale) "
                       "and OUT.json, its spec for `ltm calibrate` and `ltm track`.")
    p.add_argument("output", help="OUT.png or OUT.pdf (the spec goes to OUT.json)")
    p.add_argument("--size", default="A4", help="paper: A0-A5, letter or WxHmm "
                   "(default: %(default)s, landscape)")
    p.add_argument("--squares", help="squares NXxNY (default: as many as fit)")
    p.add_argument("--square-mm", type=number, help="square side in mm (default: 30, or the "
                   "largest that fits --squares)")
    p.add_argument("--dpi", type=int, default=300, help="resolution (default: %(default)s)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing OUTPUT and its OUT.json")
    p.set_defaults(func=cmd_board)

    p = sub.add_parser("calibrate", help="phone A's camera intrinsics from a video of the board",
                       description="Detect the ChArUco board of `ltm board` in the frames of a "
                       "video filmed from varied angles and fit the camera's focal length, "
                       "principal point and lens distortion, choosing the simplest lens model "
                       "whose error on views left out of the fit is within 0.1 px of the best; "
                       "write them as JSON for `ltm track`, `ltm capture` and `ltm ingest`, "
                       "and print the reprojection error and the model.")
    p.add_argument("video", help="video of the board from varied angles")
    p.add_argument("--board", required=True, help="board spec JSON from `ltm board`")
    add_output(p, "intrinsics.json", "intrinsics file")
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("track", help="light positions (poses.csv) from phone A's video",
                       description="Find the board (--board) or the painting itself "
                       "(--painting, --painting-width) in every frame, estimate phone A's pose, "
                       "place the LED at its offset and write poses.csv (plane coordinates "
                       "from the board's or the painting's centre, frame times of video A) "
                       "plus poses.frames.csv with every frame's status.")
    p.add_argument("video", help="phone A's video")
    target = p.add_mutually_exclusive_group(required=True)
    target.add_argument("--board", help="board spec JSON from `ltm board`")
    target.add_argument("--painting", metavar="MAP", help="no board: a PNG/JPEG of the painting "
                        "front-on, cropped to its edges, or camera B's video of it")
    p.add_argument("--painting-width", type=number, metavar="W",
                   help="with --painting: the painting's width in metres (tape measure)")
    p.add_argument("--painting-intrinsics", metavar="JSON",
                   help="with --painting VIDEO: camera B's intrinsics (`ltm calibrate`), to undo "
                   "its lens distortion before the map is made")
    p.add_argument("--readout-ms", type=number, default=0.0, metavar="MS",
                   help="with --painting: phone A's rolling-shutter readout time, top row to "
                   "bottom row, ms (phones: 10-30; default: %(default)s, no correction: a "
                   "wrong value costs more frames than none)")
    p.add_argument("--shutter-ms", type=shutter_ms, default=None, metavar="MS|auto",
                   help="with --painting: phone A's open-shutter time, ms, for its motion blur "
                   "(0: sharp frames; default: auto, estimated from the fastest frames)")
    p.add_argument("--intrinsics", required=True, help="JSON from `ltm calibrate`")
    p.add_argument("--led-offset", type=numbers("DX,DY,DZ", "metres"), default=(0.0, 0.0, 0.0),
                   help="LED position from the camera, metres, camera axes (x right, y down, "
                   "z along the view), e.g. 0.012,0,0")
    p.add_argument("--height", type=number, help="plane height for the out-of-plane flag "
                   "(default: the median LED height)")
    p.add_argument("--max-reprojection", type=number, default=1.5,
                   help="largest RMS reprojection error, px at 1280 wide (default: %(default)s)")
    p.add_argument("--max-tilt", type=number, default=20.0,
                   help="largest tilt from the plane's normal, degrees (default: %(default)s)")
    add_output(p, "poses.csv", "poses file")
    p.set_defaults(func=cmd_track)

    p = sub.add_parser("sync", help="estimate the clock offset of poses and video B",
                       description="Correlate video B's brightness with the tracked light "
                       "path, and record time_offset with its confidence in acquisition.json "
                       "(the previous file is kept as acquisition.json.bak).")
    p.add_argument("acquisition", help="acquisition folder with poses.csv from `ltm track`")
    p.add_argument("--max-offset", type=number, default=3.0,
                   help="search +- this many seconds (default: %(default)s)")
    p.add_argument("--overwrite", action="store_true",
                   help="re-estimate a time_offset that acquisition.json already declares")
    p.set_defaults(func=cmd_sync)


def cmd_board(a: argparse.Namespace) -> None:
    from ltmstore.capture.board import board_spec, parse_squares, write_board

    squares = parse_squares(a.squares) if a.squares else None
    spec = board_spec(a.size, squares=squares, square_mm=a.square_mm)
    check_board_pixels(spec.page, a.dpi)
    info = write_board(a.output, spec, dpi=a.dpi, overwrite=a.overwrite)
    print(f"wrote {info['image']} ({spec.squares[0]}x{spec.squares[1]} squares of "
          f"{spec.square_length * 1000:g} mm, {spec.dictionary}; print at 100 %) and "
          f"{info['spec']}")


BOARD_MAX_PIXELS = 2_000_000_000  # an A0 page at 1,200 dpi is 1.9e9 pixels (1.8 GiB, 8-bit)


def check_board_pixels(page: tuple[float, float], dpi: int) -> None:
    """Refuse a ``--dpi`` that is not positive, or that makes the page (``(width, height)`` in
    metres) more than :data:`BOARD_MAX_PIXELS` pixels, before anything is drawn."""
    pixels = (page[0] * dpi / 0.0254) * (page[1] * dpi / 0.0254)
    if dpi < 1 or pixels > BOARD_MAX_PIXELS:
        most = int((BOARD_MAX_PIXELS / (page[0] * page[1])) ** 0.5 * 0.0254)
        raise LtmError(f"--dpi {dpi} must be from 1 to {most} for this "
                       f"{page[0] * 1000:g} x {page[1] * 1000:g} mm page (at most "
                       f"{BOARD_MAX_PIXELS:,} pixels)")


def cmd_calibrate(a: argparse.Namespace) -> None:
    from ltmstore.capture.board import load_board
    from ltmstore.capture.calibrate import calibrate_video

    spec = load_board(a.board)
    out = new_output(a, inputs=(a.video, a.board))
    intr, report = calibrate_video(a.video, spec)
    intr.write(out, {"calibration": report})
    held = report["heldout_rms_px"]
    print(f"reprojection error {report['reprojection_rms_px']:.3f} px RMS over "
          f"{report['views_used']} views; lens model {report['lens_model']} (held-out "
          f"{'n/a' if held is None else f'{held:.3f} px RMS'}); focal "
          f"{report['focal_px'][0]:.1f} px; wrote {out}")


def shutter_ms(text: str) -> float | None:
    """``--shutter-ms``: ``auto`` (None) or 0-100 ms."""
    if text == "auto":
        return None
    value = number(text)
    if not 0 <= value <= 100:
        raise argparse.ArgumentTypeError(f"{text!r} must be auto or 0-100 ms (phones: 4-33)")
    return value


def cmd_track(a: argparse.Namespace) -> None:
    from ltmstore.capture.board import load_board
    from ltmstore.capture.calibrate import load_intrinsics
    from ltmstore.capture.painting_track import PaintingMap, check_width, track_painting
    from ltmstore.capture.track import TrackConfig, refuse_existing, track
    from ltmstore.core.errors import LtmError

    if a.painting is None and a.painting_width is not None:
        raise LtmError("--painting-width goes with --painting (boardless tracking); the board "
                       "gives its own scale")
    if a.painting is not None and a.painting_width is None:
        raise LtmError("--painting needs --painting-width W, the painting's width in metres")
    if a.painting is None and a.painting_intrinsics is not None:
        raise LtmError("--painting-intrinsics goes with --painting VIDEO (camera B's video as "
                       "the map)")
    width = check_width(a.painting_width) if a.painting is not None else None
    if not 0 <= a.readout_ms <= 100:
        raise LtmError(f"--readout-ms {a.readout_ms:g} must be 0-100 ms (phones: 10-30)")
    # the files only the command knows (track itself checks the video)
    refuse_existing(a.output, a.overwrite,
                    inputs=(a.board, a.intrinsics, a.painting, a.painting_intrinsics))
    intr = load_intrinsics(a.intrinsics)
    config = TrackConfig(led_offset=a.led_offset, max_reprojection_px=a.max_reprojection,
                         max_tilt_deg=a.max_tilt, height=a.height)
    if a.painting is not None:
        intr_b = load_intrinsics(a.painting_intrinsics) if a.painting_intrinsics else None
        painting = PaintingMap.load(a.painting, width, intr_b)
        shutter_s = None if a.shutter_ms is None else a.shutter_ms / 1000
        print_json(track_painting(a.video, painting, intr, a.output, config=config,
                                  readout_s=a.readout_ms / 1000, shutter_s=shutter_s,
                                  overwrite=a.overwrite))
        return
    spec = load_board(a.board)
    print_json(track(a.video, spec, intr, a.output, config=config, overwrite=a.overwrite))


def cmd_sync(a: argparse.Namespace) -> None:
    from ltmstore.capture.sync import sync_acquisition

    r = sync_acquisition(a.acquisition, max_offset=a.max_offset, overwrite=a.overwrite)
    beam = (f"; the LED's cos^k beam divided out, k {r['beam_exponent']:.2f} +- "
            f"{r['beam_stderr']:.2f}" if r["beam_exponent"] else "")
    print(f"time_offset {r['time_offset']:+.4f} s (+- {r['stderr_s'] * 1000:.1f} ms, "
          f"r2 {r['r2']:.3f}, contrast {r['contrast']:.2f}{beam}); wrote {r['acquisition']}")
