"""The ``ltm`` command: parse, call the library, print. User mistakes never show a traceback."""

from __future__ import annotations

import argparse
import json
import os
import sys
import warnings
from pathlib import Path

from ltmstore.errors import LtmError

EPILOG = "Docs: README.md. Stores open with xarray.open_zarr(STORE, consolidated=False)."


def _numbers(names: str, unit: str = "plane units"):
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


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    return value


def _print_json(obj) -> None:
    print(json.dumps(obj, indent=2, default=str))


def _add_output(p: argparse.ArgumentParser, default: str, what: str) -> None:
    """``-o/--output`` (a file, ``default``) and ``--overwrite``."""
    p.add_argument("-o", "--output", default=default, help=f"{what} (default: %(default)s)")
    p.add_argument("--overwrite", action="store_true")


def _new_output(a: argparse.Namespace) -> Path:
    """``--output``, refused when it exists and ``--overwrite`` is not given."""
    out = Path(a.output)
    if out.exists() and not a.overwrite:
        raise LtmError(f"output {str(out)!r} already exists; pass --overwrite to replace it")
    return out


def cmd_simulate(a: argparse.Namespace) -> None:
    if getattr(a, "raw", False):
        return cmd_simulate_raw(a)
    from ltmstore.synthetic.simulate import simulate_acquisition

    density = {} if a.path_density is None else {"path_density": a.path_density}
    summary = simulate_acquisition(a.out, scene=a.scene, seed=a.seed, lossy=a.lossy,
                                   size=a.size, overwrite=a.overwrite,
                                   view=getattr(a, "six_d", False), **density)
    _print_json(summary)


def cmd_simulate_raw(a: argparse.Namespace) -> None:
    from ltmstore.synthetic.raw import simulate_raw

    if getattr(a, "six_d", False) or a.lossy:
        raise LtmError("--raw simulates a 4D capture with lossless videos; it cannot be "
                       "combined with --6d or --lossy")
    density = {} if a.path_density is None else {"path_density": a.path_density}
    _print_json(simulate_raw(a.out, scene=a.scene, seed=a.seed, size=a.size,
                             overwrite=a.overwrite, **density))


def cmd_board(a: argparse.Namespace) -> None:
    from ltmstore.board import board_spec, parse_squares, write_board

    squares = parse_squares(a.squares) if a.squares else None
    spec = board_spec(a.size, squares=squares, square_mm=a.square_mm)
    info = write_board(a.output, spec, dpi=a.dpi, overwrite=a.overwrite)
    print(f"wrote {info['image']} ({spec.squares[0]}x{spec.squares[1]} squares of "
          f"{spec.square_length * 1000:g} mm, {spec.dictionary}; print at 100 %) and "
          f"{info['spec']}")


def cmd_calibrate(a: argparse.Namespace) -> None:
    from ltmstore.board import load_board
    from ltmstore.calibrate import calibrate_video

    spec = load_board(a.board)
    out = _new_output(a)
    intr, report = calibrate_video(a.video, spec)
    intr.write(out, {"calibration": report})
    print(f"reprojection error {report['reprojection_rms_px']:.3f} px RMS over "
          f"{report['views_used']} views; focal {report['focal_px'][0]:.1f} px; wrote {out}")


def cmd_track(a: argparse.Namespace) -> None:
    from ltmstore.board import load_board
    from ltmstore.calibrate import load_intrinsics
    from ltmstore.track import TrackConfig, track

    spec = load_board(a.board)
    intr = load_intrinsics(a.intrinsics)
    config = TrackConfig(led_offset=a.led_offset, max_reprojection_px=a.max_reprojection,
                         max_tilt_deg=a.max_tilt, height=a.height)
    _print_json(track(a.video, spec, intr, a.output, config=config, overwrite=a.overwrite))


def cmd_sync(a: argparse.Namespace) -> None:
    from ltmstore.sync import sync_acquisition

    r = sync_acquisition(a.acquisition, max_offset=a.max_offset, overwrite=a.overwrite)
    print(f"time_offset {r['time_offset']:+.4f} s (+- {r['stderr_s'] * 1000:.1f} ms, "
          f"r2 {r['r2']:.3f}, contrast {r['contrast']:.2f}); wrote {r['acquisition']}")


def cmd_ingest(a: argparse.Namespace) -> None:
    from ltmstore.ingest import ingest

    _print_json(ingest(a.acquisition, a.store, overwrite=a.overwrite))


def cmd_ingest_rti(a: argparse.Namespace) -> None:
    from ltmstore.rti import ingest_rti

    _print_json(ingest_rti(a.lp, a.store, height=a.height, extent=a.extent,
                           overwrite=a.overwrite))


def cmd_reconstruct(a: argparse.Namespace) -> None:
    from ltmstore.dims import parse_lattice
    from ltmstore.reconstruct import reconstruct

    lattice = parse_lattice(a.lattice) if a.lattice else None
    info = reconstruct(a.store, scheduler=a.scheduler, lattice=lattice, delta_rs=a.delta_rs,
                       method=a.method, auto=not a.no_auto, tile=a.tile,
                       color={"auto": None, "on": True, "off": False}[a.color],
                       overwrite=a.overwrite)
    print(f"lattice {info['lattice']['shape']}  K/M {info['sampling_ratio']:.3f}  "
          f"path density {info['path_density']:.1f}/unit  method {info['method']}  "
          f"resample {info['timings']['resample_s']:.1f} s  "
          f"solve {info['timings']['solve_s']:.1f} s")


def cmd_relight(a: argparse.Namespace) -> None:
    import imageio.v3 as iio
    import numpy as np

    from ltmstore.preview import encode_images
    from ltmstore.relight import LightClampWarning, relight
    from ltmstore.store import open_store

    ds = open_store(a.store)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", LightClampWarning)
        images = relight(ds, np.array(a.light), view=a.view).sum("light").values[None]
    for w in caught:
        print(f"ltm: warning: {w.message}", file=sys.stderr)
    transfer = ds.attrs.get("acquisition", {}).get("transfer", "srgb")
    out = _new_output(a)
    try:
        iio.imwrite(out, encode_images(images, transfer)[0])
    except (OSError, ValueError) as exc:
        raise LtmError(f"cannot write image {str(out)!r}: {exc}") from exc
    print(f"wrote {out}")


def cmd_evaluate(a: argparse.Namespace) -> None:
    from ltmstore.evaluate import compare_stores
    from ltmstore.heldout import heldout_store
    from ltmstore.store import open_store

    method = open_store(a.store).attrs["stages"].get("reconstruct", {}).get("method", "cs")
    report = {"heldout": heldout_store(a.store, method=a.method or method, folds=a.folds,
                                       max_pixels=a.pixels)}
    if a.truth:
        report["truth"] = compare_stores(a.store, a.truth, maps_png=a.maps)
    _print_json(report)


def cmd_bench(a: argparse.Namespace) -> None:
    from ltmstore import benchmark

    options = {"densities": (15.0, 27.0), "lattices": (16, 32), "size": 16} if a.quick else {}
    records = benchmark.run(progress=lambda line: print(line, flush=True), **options)
    result = benchmark.write(records, Path(a.out), command="ltm bench" + " --quick" * a.quick)
    for row in result["summary"]:
        print(f"{row['label']:<22s} {row['snr_db']:6.2f} dB  {row['ms_per_pixel']:9.3f} ms/pixel")
    print(f"wrote {a.out}/bench.json and charts: {', '.join(result['charts'].values())}")


def cmd_info(a: argparse.Namespace) -> None:
    from ltmstore.provenance import store_summary
    from ltmstore.store import open_group

    _print_json(open_group(a.store).attrs.asdict() if a.raw else store_summary(a.store))


def _archive_params(a: argparse.Namespace):
    from ltmstore.archive import ArchiveParams
    from ltmstore.dims import parse_lattice

    if a.tile < 1:
        raise LtmError(f"--tile {a.tile!r} must be a positive whole number of pixels")
    return ArchiveParams(lattice=parse_lattice(a.lattice) if a.lattice else None,
                         delta_rs=a.delta_rs, method=a.method, auto=not a.no_auto, tile=a.tile)


def _flow_params(a: argparse.Namespace) -> dict:
    p = _archive_params(a)
    return {"lattice": None if p.lattice is None else list(p.lattice), "delta_rs": p.delta_rs,
            "method": p.method, "auto": p.auto, "tile": p.tile,
            "max_concurrent": a.max_concurrent, "scheduler": a.scheduler}


def cmd_archive_status(a: argparse.Namespace) -> None:
    from ltmstore.archive import archive_status, format_status

    entries = archive_status(a.root, _archive_params(a))
    if a.json:
        _print_json([e.to_json() for e in entries])
    else:
        print(format_status(entries))


def cmd_archive_run(a: argparse.Namespace) -> None:
    params = _flow_params(a)  # bad options fail before Prefect is imported
    from flows.archive import reprocess_archive

    rows = reprocess_archive(a.root, **params)
    for r in rows:
        km = "" if r["K/M"] is None else f"K/M {r['K/M']:.3f}"
        print(f"{r['acquisition']:<24s} {r['status']:<12s} {km} {r['reason']}".rstrip())
    failed = [r["acquisition"] for r in rows if r["status"] == "failed"]
    if failed:
        raise LtmError(f"{len(failed)} of {len(rows)} acquisition(s) failed: {failed}; "
                       "see ltm archive status")


def cmd_archive_serve(a: argparse.Namespace) -> None:
    params = _flow_params(a)
    from flows.archive import serve_archive

    serve_archive(a.root, cron=a.cron, name=a.name, parameters=params)


def cmd_demo(a: argparse.Namespace) -> None:
    from flows.demo import run_demo

    run_demo(a.out, scene=a.scene, size=a.size, seed=a.seed, overwrite=a.overwrite)


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``ltm: error: ...``, exit 2)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    from ltmstore.solve import DEFAULT_METHOD, METHODS
    from ltmstore.synthetic.scenes import SCENES

    parser = _Parser(
        prog="ltm", description="Relightable photographs from handheld light transport "
        "acquisition: simulate, ingest, reconstruct (compressive sensing on Dask), relight.",
        epilog=EPILOG)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                parser_class=_Parser)

    p = sub.add_parser("demo", help="simulate, ingest, reconstruct, relight and report",
                       description="Run the whole pipeline on a simulated acquisition as a "
                       "Prefect flow on a local Dask cluster; print SNR_Y and stage times.")
    p.add_argument("--out", default="ltm-demo", help="output folder (default: %(default)s)")
    p.add_argument("--scene", default="relief", choices=SCENES)
    p.add_argument("--size", type=int, default=96,
                   help="image side in pixels (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out folder")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("simulate", help="write a simulated acquisition folder + truth.zarr")
    p.add_argument("out", help="acquisition folder to create")
    p.add_argument("--scene", required=True, help=f"one of {', '.join(SCENES)}")
    p.add_argument("--path-density", type=_number, default=None,
                   help="trajectory length per unit plane area (1/m)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--lossy", action="store_true", help="mp4v .mp4 instead of lossless FFV1 .mkv")
    p.add_argument("--raw", action="store_true",
                   help="two-phone raw capture: phone A's video of a ChArUco board, video B, "
                   "an unknown clock offset and no poses file (see ltm track, ltm sync)")
    p.add_argument("--size", type=int, default=128, help="image side in pixels")
    p.add_argument("--6d", dest="six_d", action="store_true",
                   help="6D: camera B moves over a view plane too (view_plane, p, q poses, "
                   "truth ltm (y, x, r, s, p, q))")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("ingest", help="acquisition folder -> store (frames, poses)")
    p.add_argument("acquisition", help="folder with acquisition.json, video, poses.csv")
    p.add_argument("store", help="Zarr store to create")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=cmd_ingest)

    p = sub.add_parser("ingest-rti", help="classic RTI capture (images + .lp) -> store")
    p.add_argument("lp", help="the .lp light file beside the images")
    p.add_argument("store", help="Zarr store to create")
    p.add_argument("--height", type=_number, default=1.0,
                   help="illumination plane height (default: %(default)s)")
    p.add_argument("--extent", type=_number, default=None,
                   help="half-side of the square plane (default: 2 x height)")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=cmd_ingest_rti)

    p = sub.add_parser("reconstruct", help="resample onto a lattice and solve every pixel",
                       description="Bin the frames onto the lattice and reconstruct every "
                       "pixel's LTF by compressive sensing, over pixel tiles on Dask.")
    p.add_argument("store")
    grid = p.add_mutually_exclusive_group()
    grid.add_argument("--lattice", help="RxS cells over the plane, e.g. 32x32")
    grid.add_argument("--delta-rs", type=_number, help="cell size in plane units")
    p.add_argument("--method", default=DEFAULT_METHOD, choices=sorted(METHODS),
                   help="solver (default: %(default)s; lars is the slow per-pixel reference)")
    p.add_argument("--scheduler", help="Dask scheduler address (default: a local cluster)")
    p.add_argument("--no-auto", action="store_true",
                   help="keep the method's default regularisation instead of choosing it per "
                   "tile by held-out error")
    p.add_argument("--color", choices=("auto", "on", "off"), default="auto",
                   help="also reconstruct Cb and Cr LTMs (a colour LTM); auto: when ingest "
                   "found that the chroma changes with the light (default: %(default)s)")
    p.add_argument("--tile", type=int, default=32, help="pixel tile side (default: %(default)s)")
    p.add_argument("--overwrite", action="store_true", help="recompute an existing ltm")
    p.set_defaults(func=cmd_reconstruct)

    p = sub.add_parser("relight", help="render the store under new point lights")
    p.add_argument("store")
    p.add_argument("--light", type=_numbers("R,S"), action="append", required=True,
                   help="R,S light position on the plane; repeat to add lights")
    p.add_argument("--view", type=_numbers("P,Q"), default=None, metavar="P,Q",
                   help="6D stores: camera position on the view plane (default: its centre)")
    _add_output(p, "relit.png", "image file")
    p.set_defaults(func=cmd_relight)

    p = sub.add_parser("evaluate", help="held-out error; SNR_Y, PSNR, error maps against a truth",
                       description="Held-out error from the data alone (observed cells left "
                       "out and predicted: works on real captures), and with --truth the "
                       "paper's SNR_Y, PSNR of relit images and per-pixel error maps.")
    p.add_argument("store")
    p.add_argument("--truth", help="truth.zarr written by `ltm simulate`")
    p.add_argument("--maps", help="write the per-pixel error maps (needs --truth) to this PNG")
    p.add_argument("--method", help="method for the held-out test (default: the store's)")
    p.add_argument("--folds", type=int, default=5, help="held-out folds (default: %(default)s)")
    p.add_argument("--pixels", type=int, default=4096,
                   help="pixels sampled for the held-out test (default: %(default)s)")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("bench", help="every method: speed against accuracy, JSON and charts",
                       description="Sweep every method over scenes, path densities and lattice "
                       "sizes on simulated captures; write bench.json and PNG charts.")
    p.add_argument("--out", default="bench/results", help="output folder (default: %(default)s)")
    p.add_argument("--quick", action="store_true", help="a small sweep (a minute or two)")
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser("board", help="write a printable ChArUco board and its JSON spec",
                       description="Write a ChArUco board page (PNG or PDF, true to scale) "
                       "and OUT.json, its spec for `ltm calibrate` and `ltm track`.")
    p.add_argument("output", help="OUT.png or OUT.pdf (the spec goes to OUT.json)")
    p.add_argument("--size", default="A4", help="paper: A0-A5, letter or WxHmm "
                   "(default: %(default)s, landscape)")
    p.add_argument("--squares", help="squares NXxNY (default: as many as fit)")
    p.add_argument("--square-mm", type=_number, help="square side in mm (default: 30, or the "
                   "largest that fits --squares)")
    p.add_argument("--dpi", type=int, default=300, help="resolution (default: %(default)s)")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=cmd_board)

    p = sub.add_parser("calibrate", help="phone A's camera intrinsics from a video of the board")
    p.add_argument("video", help="video of the board from varied angles")
    p.add_argument("--board", required=True, help="board spec JSON from `ltm board`")
    _add_output(p, "intrinsics.json", "intrinsics file")
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("track", help="light positions (poses.csv) from phone A's video",
                       description="Detect the board in every frame, estimate phone A's pose, "
                       "place the LED at its offset and write poses.csv (plane coordinates "
                       "from the board centre, frame times of video A) plus "
                       "poses.frames.csv with every frame's status.")
    p.add_argument("video", help="phone A's video")
    p.add_argument("--board", required=True, help="board spec JSON from `ltm board`")
    p.add_argument("--intrinsics", required=True, help="JSON from `ltm calibrate`")
    p.add_argument("--led-offset", type=_numbers("DX,DY,DZ", "metres"), default=(0.0, 0.0, 0.0),
                   help="LED position from the camera, metres, camera axes (x right, y down, "
                   "z along the view), e.g. 0.012,0,0")
    p.add_argument("--height", type=_number, help="plane height for the out-of-plane flag "
                   "(default: the median LED height)")
    p.add_argument("--max-reprojection", type=_number, default=1.5,
                   help="largest RMS reprojection error, px at 1280 wide (default: %(default)s)")
    p.add_argument("--max-tilt", type=_number, default=20.0,
                   help="largest tilt from the board normal, degrees (default: %(default)s)")
    _add_output(p, "poses.csv", "poses file")
    p.set_defaults(func=cmd_track)

    p = sub.add_parser("sync", help="estimate the clock offset of poses and video B",
                       description="Correlate video B's brightness with the tracked light "
                       "path, and record time_offset with its confidence in acquisition.json "
                       "(the previous file is kept as acquisition.json.bak).")
    p.add_argument("acquisition", help="acquisition folder with poses.csv from `ltm track`")
    p.add_argument("--max-offset", type=_number, default=3.0,
                   help="search +- this many seconds (default: %(default)s)")
    p.add_argument("--overwrite", action="store_true",
                   help="re-estimate a time_offset that acquisition.json already declares")
    p.set_defaults(func=cmd_sync)

    p = sub.add_parser("info", help="print a store's provenance",
                       description="Software version and commit, parameters, input sha256, "
                       "timings per stage and completion of a store (JSON).")
    p.add_argument("store")
    p.add_argument("--raw", action="store_true", help="every group attribute as stored")
    p.set_defaults(func=cmd_info)

    _add_archive(sub, DEFAULT_METHOD, METHODS)
    return parser


def _add_archive(sub, default_method: str, methods) -> None:
    archive = sub.add_parser("archive", help="status, run and scheduled reprocessing of an archive",
                             description="An archive is a ROOT folder of acquisition folders, "
                             "each with its store NAME.zarr beside it (README: Archives).")
    verbs = archive.add_subparsers(dest="verb", required=True, metavar="VERB",
                                   parser_class=_Parser)

    def common(p) -> None:
        p.add_argument("root", help="archive root folder")
        grid = p.add_mutually_exclusive_group()
        grid.add_argument("--lattice", help="RxS cells over the plane (default: automatic)")
        grid.add_argument("--delta-rs", type=_number, help="cell size in plane units")
        p.add_argument("--method", default=default_method, choices=sorted(methods))
        p.add_argument("--no-auto", action="store_true", help="fixed default regularisation")
        p.add_argument("--tile", type=int, default=32, help="pixel tile side (default: 32)")

    def running(p) -> None:
        p.add_argument("--max-concurrent", type=int, default=2,
                       help="acquisitions processed at once (default: %(default)s)")
        p.add_argument("--scheduler", help="Dask scheduler address (default: a local cluster)")

    p = verbs.add_parser("status", help="new / stale / failed / up to date, sizes, timings")
    common(p)
    p.add_argument("--json", action="store_true", help="JSON instead of a table")
    p.set_defaults(func=cmd_archive_status)

    p = verbs.add_parser("run", help="reprocess new, stale and failed acquisitions once",
                         description="Run the reprocess-archive Prefect flow once (a temporary "
                         "Prefect server starts when PREFECT_API_URL is not set).")
    common(p)
    running(p)
    p.set_defaults(func=cmd_archive_run)

    p = verbs.add_parser("serve", help="serve reprocess-archive on a cron schedule",
                         description="Serve the reprocess-archive flow as a deployment with a "
                         "cron schedule against the Prefect server of PREFECT_API_URL, or one "
                         "started here with `prefect server start` on 127.0.0.1.")
    common(p)
    running(p)
    p.add_argument("--cron", required=True, help='cron schedule, e.g. "0 2 * * *"')
    p.add_argument("--name", default="archive", help="deployment name (default: %(default)s)")
    p.set_defaults(func=cmd_archive_serve)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``ltm`` console script."""
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "warning")  # cluster chatter off
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # FFmpeg quiet: our errors say it
    os.environ.setdefault("OPENCV_LOG_LEVEL", "OFF")
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except LtmError as exc:
        print(f"ltm: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("ltm: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
