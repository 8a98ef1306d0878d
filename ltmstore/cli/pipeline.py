"""``ltm`` commands of the pipeline: demo, simulate, ingest, reconstruct, relight, compact,
evaluate, bench, info."""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

from ltmstore.cli.args import number, numbers, print_json
from ltmstore.cli.names import (
    CAPTURE,
    DEFAULT_METHOD,
    EV_LIMIT,
    EXPOSURES,
    IIIF_URL,
    METHOD_NAMES,
    MIN_RATIO,
    SCENES,
    SHADINGS,
    TARGET_RATIO,
    TILED_LAYOUTS,
)
from ltmstore.core.errors import LtmError, LtmWarning


class _Recorded:
    """`ltm evaluate --holdout-lights` without a number: the store's own (not a string, which
    argparse would pass through ``int``)."""

    def __repr__(self) -> str:
        return "RECORDED"


RECORDED = _Recorded()


def register(sub) -> None:
    """Add the pipeline's commands to the ``ltm`` subparsers ``sub``."""
    p = sub.add_parser("demo", help="simulate, ingest, reconstruct, relight and report",
                       description="Run the whole pipeline on a simulated acquisition as a "
                       "Prefect flow on a local Dask cluster; print SNR_Y and stage times. "
                       "Its previews (relit_*.png, relight.gif) are at the capture's exposure "
                       "(photometric, as ltm relight's default).")
    p.add_argument("--out", default="ltm-demo", help="output folder (default: %(default)s)")
    p.add_argument("--scene", default="relief", choices=SCENES,
                   help="simulated object (default: %(default)s)")
    p.add_argument("--size", type=int, default=96,
                   help="image side in pixels (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0,
                   help="random seed of the scene, the light path and the noise "
                   "(default: %(default)s)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out folder")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("simulate", help="write a simulated acquisition folder + truth.zarr",
                       description="Render a synthetic scene under a handheld light path and "
                       "write an acquisition folder (acquisition.json, video, poses.csv) that "
                       "`ltm ingest` reads, with truth.zarr, the true LTM, for `ltm evaluate "
                       "--truth`. With --raw: the two phones' raw videos instead, to make the "
                       "acquisition with ltm calibrate, ltm track and ltm sync.")
    p.add_argument("out", help="acquisition folder to create")
    p.add_argument("--scene", required=True, help=f"one of {', '.join(SCENES)}")
    p.add_argument("--path-density", type=number, default=None,
                   help="trajectory length per unit plane area (1/m)")
    p.add_argument("--seed", type=int, default=0,
                   help="random seed of the scene, the light path and the noise "
                   "(default: %(default)s)")
    p.add_argument("--lossy", action="store_true", help="mp4v .mp4 instead of lossless FFV1 .mkv")
    p.add_argument("--raw", action="store_true",
                   help="two-phone raw capture: phone A's video of the painting it lights, "
                   "video B, an unknown clock offset and no poses file (see ltm calibrate, "
                   "ltm track, ltm sync)")
    p.add_argument("--board", action="store_true",
                   help="with --raw: phone A films an A0 ChArUco board laid around the painting "
                   "(default: the painting alone, on a plain wall)")
    p.add_argument("--effects", default=None, metavar="all|none|LIST",
                   help="with --raw: phone effects at typical strength (default: all), none, or "
                   "a comma list of distortion, rolling-shutter, motion-blur, auto-exposure, "
                   "white-balance, ambient, led-falloff, h264")
    p.add_argument("--shading", default=None, choices=SHADINGS,
                   help="with --raw: the painting's physics, ggx (the renderer's own, what "
                   "the product's physical model assumes; the default) or mismatched (a "
                   "Beckmann lobe, a 2%% floor and a clear coat, which it does not)")
    p.add_argument("--size", type=int, default=128, help="image side in pixels")
    p.add_argument("--6d", dest="six_d", action="store_true",
                   help="6D: camera B moves over a view plane too (view_plane, p, q poses, "
                   "truth ltm (y, x, r, s, p, q))")
    p.add_argument("--overwrite", action="store_true", help="replace an existing OUT folder")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("ingest", help="acquisition folder -> store (frames, poses)",
                       description="Decode an acquisition folder (handheld light: "
                       "acquisition.json, camera B's video, poses.csv) into a new store: "
                       "linear luminance and chroma frames, light positions on the plane, "
                       "input hashes. A classic RTI capture (photographs and a .lp file) goes "
                       "to `ltm ingest-rti` instead.")
    p.add_argument("acquisition", help="folder with acquisition.json, video, poses.csv")
    p.add_argument("store", help="Zarr store to create")
    p.add_argument("--overwrite", action="store_true", help="replace an existing store")
    p.add_argument("--allow-dropped-frames", action="store_true",
                   help="leave out damaged or missing video frames (counted and reported) "
                   "instead of failing")
    p.add_argument("--exposure-locked", action="store_true",
                   help="camera B's exposure and white balance were locked: a drift of its "
                   "brightness that the video cannot measure is left uncorrected instead of "
                   "refused (a measured one is still corrected, auto exposure still refused)")
    p.add_argument("--keep-chroma", action="store_true",
                   help="keep every frame's chroma even when the colour does not change with "
                   "the light (then only a colour LTM forced with reconstruct --color reads it; "
                   "without this flag it is removed: two thirds of the per-frame bytes)")
    p.set_defaults(func=cmd_ingest)

    p = sub.add_parser("ingest-rti", help="classic RTI capture (images + .lp) -> store",
                       description="A far-light store: every light above the horizon is kept "
                       "as a direction (r = lx, s = ly); lights at or below it are skipped "
                       "with one warning line.")
    p.add_argument("lp", help="the .lp light file beside the images")
    p.add_argument("store", help="Zarr store to create")
    p.add_argument("--overwrite", action="store_true", help="replace an existing store")
    p.add_argument("--holdout-lights", type=int, metavar="EVERY",
                   help="leave out every EVERY-th light, as `ltm evaluate --holdout-lights` "
                   "does, list them (index, direction, image) and record them in the store "
                   "(`ltm info` lists them, `ltm evaluate --holdout-lights` scores them): "
                   "`ltm relight --direction` at one of them writes the image to compare with "
                   "its photograph")
    p.add_argument("--transfer", choices=("srgb", "linear"), default=None,
                   help="how the photographs' values encode light (default: what the files "
                   "say: a float TIFF or a raw photograph is linear, a PNG sRGB or gAMA chunk "
                   "or an ICC profile's tone curve; else srgb). Photographs are 8-bit, 16-bit "
                   "(PNG, TIFF; raw/DNG developed linear by LibRaw) or float (TIFF), one depth "
                   "per capture, kept at their precision")
    p.set_defaults(func=cmd_ingest_rti)

    p = sub.add_parser("reconstruct", help="resample onto a lattice and solve every pixel",
                       description="Bin the frames onto the lattice and reconstruct every "
                       "pixel's LTF by compressive sensing, over pixel tiles on Dask.")
    p.add_argument("store", help="store made by ltm ingest or ltm ingest-rti")
    grid = p.add_mutually_exclusive_group()
    grid.add_argument("--lattice", help="RxS cells over the plane, e.g. 32x32 (default: the "
                      f"finest lattice whose K/M reaches {TARGET_RATIO}, the paper's ratio)")
    grid.add_argument("--delta-rs", type=number, help="cell size in plane units")
    p.add_argument("--force", action="store_true",
                   help=f"run a --lattice or --delta-rs whose K/M (observed cells / cells) is "
                   f"below {MIN_RATIO}; refused otherwise, naming the lattice that reaches "
                   f"{TARGET_RATIO}. A lattice that cannot fit in memory or on the store's "
                   "disk is refused even so, naming its size")
    p.add_argument("--method", default=DEFAULT_METHOD, choices=["auto", *METHOD_NAMES],
                   help="solver (default: %(default)s: per pixel tile, the method and model "
                   "size with the lowest held-out error, physical among them where "
                   "acquisition.json declares the object's extent or the capture places it "
                   "(see ltm info: placement); lars is the slow per-pixel "
                   "reference). A far-light store takes auto, ptm, hsh, rbf or physical (the "
                   "surface model and its maps, see ltm maps)")
    p.add_argument("--scheduler", help="Dask scheduler address (default: a local cluster)")
    p.add_argument("--no-auto", action="store_true",
                   help="keep the method's default regularisation instead of choosing it per "
                   "tile by held-out error")
    p.add_argument("--color", choices=("auto", "on", "off"), default="auto",
                   help="also reconstruct Cb and Cr LTMs (a colour LTM); auto: when ingest "
                   "found that the chroma changes with the light (default: %(default)s)")
    p.add_argument("--tile", type=int, default=None,
                   help="pixel tile side (default: 32; 64 for a far-light store)")
    p.add_argument("--overwrite", action="store_true", help="recompute an existing ltm")
    p.add_argument("--no-light-major", action="store_true",
                   help="skip the light-major copy of the LTM: half the LTM bytes, but each "
                   "relit light reads every pixel tile (`ltm compact` adds the copy later)")
    p.add_argument("--form", choices=("auto", "dense", "factored"), default="auto",
                   help="dense: the LTM array and its light-major copy; factored: each tile "
                   "stores a basis over the lattice cells and per-pixel weights at the rank "
                   "its held-out error supports, no dense LTM ever written (a few "
                   "percent of the bytes, for captures whose dense LTM does not fit; "
                   "near-light 4D stores); auto: dense while its store would take at most "
                   "half the free disk, else factored, and then the decoded frames are "
                   "dropped as `ltm compact` drops them (default: %(default)s)")
    p.add_argument("--keep-frames", action="store_true",
                   help="keep the decoded frames where auto stores the factors for lack of "
                   "disk (reconstructing again then needs no new `ltm ingest`)")
    p.add_argument("--stage", choices=("classic", "all"), default="all",
                   help="a classic RTI capture (auto, physical) reconstructs in two recorded "
                   "stages: the classic fit (a complete, relightable store), then the surface "
                   "refinement. classic: the first only; `ltm reconstruct STORE` later (same "
                   "parameters) finishes the refinement, as it finishes one that was "
                   "interrupted (default: %(default)s)")
    p.set_defaults(func=cmd_reconstruct)

    p = sub.add_parser("relight", help="render the store under new point lights",
                       description="Relight any store: a near-light store (handheld LED) at "
                       "plane positions or directions, a far-light store (ingest-rti) at "
                       "directions or (lx, ly) positions in the unit disk. Lights far from "
                       "every captured one are extrapolated smoothly, with a warning. Images "
                       "are written at the capture's exposure (photometric, the default): a "
                       "light of the capture gives that photograph's (or, near lights, camera "
                       "B's video's) brightness, a dimmer light a dimmer image, --sum the sum "
                       "of the lights, clipped at white as in a camera.")
    p.add_argument("store", help="reconstructed store (ltm reconstruct)")
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--light", type=numbers("R,S"), action="append",
                       help="R,S light position in the store's coordinates (on the plane; "
                       "lx,ly for a far-light store); repeat to add lights")
    which.add_argument("--direction", type=numbers("LX,LY,LZ", "a direction"), action="append",
                       help="LX,LY,LZ direction towards the light (normalised; lz > 0); "
                       "repeat to add lights")
    p.add_argument("--view", type=numbers("P,Q"), default=None, metavar="P,Q",
                   help="6D stores: camera position on the view plane (default: its centre)")
    p.add_argument("-o", "--output", default=None,
                   help="image file (default: relit.png; --layout iiif or deepzoom: a folder, "
                   "relit). With several lights, one image per light: {i} in the name is the "
                   "light's number from 0 (relit-{i}.png), or without it -0, -1, ... before "
                   "the suffix (relit-0.png, relit-1.png)")
    p.add_argument("--sum", action="store_true",
                   help="several lights: one image lit by all of them together")
    p.add_argument("--exposure", choices=EXPOSURES, default=CAPTURE,
                   help="capture: the stored linear light as it is, at the capture's exposure; "
                   "auto: scaled so that the brightest 0.5%% of the pixels (of all the "
                   "images written) clip (default: %(default)s)")
    p.add_argument("--ev", type=number, default=0.0, metavar="STOPS",
                   help=f"stops added to --exposure: linear light times 2**STOPS, from "
                   f"{-EV_LIMIT:g} to {EV_LIMIT:g} (default: 0)")
    p.add_argument("--depth", default="8", metavar="8|16|float",
                   help="8: 8-bit images (default); 16: 16-bit PNG or TIFF in the capture's "
                   "transfer; float: float32 TIFF of linear light (times the exposure's gain, "
                   "not clipped)")
    p.add_argument("--layout", choices=("image", *TILED_LAYOUTS), default="image",
                   help="image: one image file per light (default); iiif: one folder per "
                   "light (-o names it), a static IIIF Image API 3.0 level-0 service "
                   "(info.json and 256 px JPEG tiles at every scale) that a plain web server "
                   "serves to OpenSeadragon, Mirador or OpenLIME, the tiles those of ltm "
                   "view's IIIF service; deepzoom: one folder per light holding a Deep Zoom "
                   "image (image.dzi, image_files/: 256 px JPEG tiles, levels down to 1 px) "
                   "for OpenSeadragon or OpenLIME's deepzoom1px layout")
    p.add_argument("--iiif-url", default=None, metavar="URL",
                   help="--layout iiif: where the folder's parent will be served; info.json's "
                   f"id is URL/FOLDER (default: {IIIF_URL}, what `python -m http.server` run "
                   "in the parent serves)")
    p.add_argument("--overwrite", action="store_true", help="replace existing image files")
    p.set_defaults(func=cmd_relight)

    p = sub.add_parser("compact", help="recompress a reconstructed store and drop its frames",
                       description="Rewrite the LTM losslessly compressed (or in float16 with "
                       "--precision float16: lossy, its SNR is measured and printed) with its "
                       "light-major copy for fast relighting, and drop the decoded frames "
                       "(reconstructing again then needs a new ingest). Atomic: a failure "
                       "leaves the store as it was. A far-light store keeps its frames (it "
                       "relights from them).")
    p.add_argument("store", help="reconstructed store, rewritten in place")
    p.add_argument("--precision", choices=("float32", "float16"), default="float32",
                   help="stored LTM precision (default: %(default)s, lossless)")
    p.add_argument("--form", choices=("dense", "factored"), default="dense",
                   help="dense: the LTM array; factored: per 32 x 32 pixel tile a basis over "
                   "the lattice cells and per-pixel weights, keeping the singular values above "
                   "the noise of the model's held-out error in that tile (lossy, "
                   "much smaller; its SNR against the dense float32 LTM is measured and "
                   "printed; relights from the factors) (default: %(default)s)")
    p.add_argument("--target-snr", type=number, default=None, metavar="DB",
                   help="factored form: instead, the least SNR in dB of every pixel tile "
                   "against the dense LTM")
    p.add_argument("--keep-frames", action="store_true", help="keep frames and frame_chroma")
    p.set_defaults(func=cmd_compact)

    p = sub.add_parser("evaluate", help="held-out error; SNR_Y, PSNR, error maps against a truth",
                       description="Held-out error from the data alone (observed cells left "
                       "out and predicted: works on real captures), and with --truth the "
                       "paper's SNR_Y, PSNR of relit images and per-pixel error maps.")
    p.add_argument("store", help="reconstructed store, or one made by ingest-rti with "
                   "--holdout-lights or --test-lights")
    p.add_argument("--truth", help="truth.zarr written by `ltm simulate`")
    p.add_argument("--maps", help="write the per-pixel error maps (needs --truth) to this PNG")
    p.add_argument("--method", help="method for the held-out test (default: the store's)")
    p.add_argument("--folds", type=int, default=5, help="held-out folds (default: %(default)s)")
    p.add_argument("--pixels", type=int, default=4096,
                   help="pixels sampled for the held-out test (default: %(default)s)")
    p.add_argument("--holdout-lights", type=int, nargs="?", const=RECORDED, metavar="EVERY",
                   help="a store made by ingest-rti: hide every EVERY-th light of its .lp, fit "
                   "the default pipeline and PTM, HSH2, HSH3, RBF, HSH3+RBF on the rest, and "
                   "score the relit images against the hidden photographs (PSNR, SSIM of "
                   "8-bit sRGB). Without EVERY: the lights `ingest-rti --holdout-lights` held "
                   "out of this store (an EVERY that differs is refused). Without the option, "
                   "evaluate runs the held-out cells test even on such a store, and says how "
                   "to score its held-out photographs")
    p.add_argument("--test-lights", metavar="TEST.lp",
                   help="a store made by ingest-rti: fit on all its lights, score at the lights "
                   "and photographs of this .lp (SynthRTI: dome/ then test/)")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("bench", help="every method: speed against accuracy, JSON and charts",
                       description="Sweep every method over scenes, path densities and lattice "
                       "sizes on simulated captures; write bench.json and PNG charts.")
    p.add_argument("--out", default="bench-out",
                   help="output folder (default: %(default)s, which git ignores; the published "
                   "results in bench/results are made by `python -m bench run bench`)")
    p.add_argument("--quick", action="store_true", help="a small sweep (a minute or two)")
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser("info", help="print a store's provenance",
                       description="Software version and commit, parameters, input sha256, "
                       "timings per stage and completion of a store (JSON).")
    p.add_argument("store", help="store to describe")
    p.add_argument("--raw", action="store_true", help="every group attribute as stored")
    p.set_defaults(func=cmd_info)


def cmd_demo(a: argparse.Namespace) -> None:
    from flows.demo import run_demo

    run_demo(a.out, scene=a.scene, size=a.size, seed=a.seed, overwrite=a.overwrite)


def cmd_simulate(a: argparse.Namespace) -> None:
    if getattr(a, "raw", False):
        return cmd_simulate_raw(a)
    if (getattr(a, "board", False) or getattr(a, "effects", None) is not None
            or getattr(a, "shading", None) is not None):
        raise LtmError("--board, --effects and --shading describe a two-phone capture; "
                       "they need --raw")
    from ltmstore.synthetic.simulate import simulate_acquisition

    density = {} if a.path_density is None else {"path_density": a.path_density}
    summary = simulate_acquisition(a.out, scene=a.scene, seed=a.seed, lossy=a.lossy,
                                   size=a.size, overwrite=a.overwrite,
                                   view=getattr(a, "six_d", False), **density)
    print_json(summary)


def cmd_simulate_raw(a: argparse.Namespace) -> None:
    from ltmstore.core.paths import check_simulation_folder
    from ltmstore.synthetic.phone_effects import parse_effects
    from ltmstore.synthetic.raw import simulate_raw

    if getattr(a, "six_d", False) or a.lossy:
        raise LtmError("--raw simulates a 4D capture (H.264 or lossless videos: see --effects); "
                       "it cannot be combined with --6d or --lossy")
    effects = parse_effects("all" if a.effects is None else a.effects)
    density = {} if a.path_density is None else {"path_density": a.path_density}
    check_simulation_folder(a.out, a.overwrite)  # never a folder of someone else's files
    print_json(simulate_raw(a.out, scene=a.scene, seed=a.seed, size=a.size,
                            overwrite=a.overwrite, board=a.board, effects=effects,
                            shading=a.shading or "ggx", **density))


def cmd_ingest(a: argparse.Namespace) -> None:
    refuse_classic_capture(a.acquisition, a.store)
    from ltmstore.capture.video import codec_warning
    from ltmstore.stages.ingest import ingest

    record = ingest(a.acquisition, a.store, overwrite=a.overwrite,
                    allow_dropped=a.allow_dropped_frames, exposure_locked=a.exposure_locked,
                    keep_chroma=a.keep_chroma)
    print_json(record)
    if warning := codec_warning(record.get("video") or {}):
        print(f"ltm: warning: {warning}", file=sys.stderr)


def refuse_classic_capture(acquisition: str, store: str) -> None:
    """Point ``ltm ingest`` given a classic RTI capture (a ``.lp`` file, or a folder holding one
    and no acquisition.json) to ``ltm ingest-rti``, with the command to run."""
    import shlex

    path = Path(acquisition)
    try:
        if path.is_file() and path.suffix.lower() == ".lp":
            found = [path]
        elif path.is_dir() and not ((path / "acquisition.json").exists()
                                    or (path / "acquisition.json").is_symlink()):
            found = sorted(f for f in path.iterdir()
                           if f.suffix.lower() == ".lp" and f.is_file())
        else:
            return
    except OSError:  # unreadable: ingest names the problem
        return
    if not found:
        return
    what = (f"{str(path)!r} is a classic RTI light file" if found == [path] else
            f"{str(path)!r} holds a classic RTI capture ({found[0].name}) and no acquisition.json")
    others = "" if len(found) == 1 else (
        f" (it holds {len(found)} .lp files: {', '.join(f.name for f in found[:5])}"
        f"{', ...' if len(found) > 5 else ''})")
    raise LtmError(f"{what}: ltm ingest reads a handheld-light acquisition folder; use "
                   f"`ltm ingest-rti {shlex.quote(str(found[0]))} {shlex.quote(str(store))}`"
                   f"{others}")


def cmd_ingest_rti(a: argparse.Namespace) -> None:
    from ltmstore.stages.ingest_rti import ingest_rti

    print_json(ingest_rti(a.lp, a.store, holdout_every=a.holdout_lights, overwrite=a.overwrite,
                          transfer=a.transfer))


def cmd_reconstruct(a: argparse.Namespace) -> None:
    from ltmstore.core.dims import parse_lattice
    from ltmstore.stages.reconstruct import reconstruct

    lattice = parse_lattice(a.lattice) if a.lattice else None
    info = reconstruct(a.store, scheduler=a.scheduler, lattice=lattice, delta_rs=a.delta_rs,
                       method=a.method, auto=not a.no_auto, tile=a.tile,
                       color={"auto": None, "on": True, "off": False}[a.color],
                       overwrite=a.overwrite, force=a.force,
                       light_major=not a.no_light_major, form=a.form,
                       keep_frames=a.keep_frames, stage=a.stage)
    density = info["path_density"]
    print(f"lattice {info['lattice']['shape']}  K/M {info['sampling_ratio']:.3f}  "
          + ("" if density is None else f"path density {density:.1f}/{plane_unit(a.store)}  ")
          + f"method {info['method']} {summary_of(info['methods_per_tile'])}  "
          + ("at each photograph's exposure  " if info.get("exposure_fitted") else "")
          + (f"surface model skipped (did not pay: ~{skipped:.0f} s saved)  "
             if (skipped := info["timings"].get("surface_skipped_s")) is not None else "")
          + f"resample {info['timings']['resample_s']:.1f} s  "
          f"solve {info['timings']['solve_s']:.1f} s" + placement_note(info.get("placement"))
          + (f"  factored: ranks {r['min']}-{r['max']}, mean {r['mean']:.1f}"
             if (r := info.get("ranks", {}).get("ltm")) else "") + form_note(info)
          + frames_note(info.get("frames_dropped")) + refinement_note(info))


def refinement_note(info: dict) -> str:
    """A far-light store's classic fit whose surface refinement is still to run."""
    if info.get("refinement") != "pending":
        return ""
    return ("  classic fit only: relightable, surface refinement pending (`ltm reconstruct "
            "STORE` with the same parameters finishes it)")


def form_note(info: dict) -> str:
    """Why ``--form auto`` stored the factors (empty where it stored the dense form)."""
    from ltmstore.stages.plan import size_text

    choice = info.get("form_choice") or {}
    if choice.get("form") != "factored" or "dense_estimate_bytes" not in choice:
        return ""
    return (f"  (factored: the dense form would store about "
            f"{size_text(choice['dense_estimate_bytes'])}, more than half of the "
            f"{size_text(choice['free_bytes'])} free)")


def frames_note(dropped: dict | None) -> str:
    """What dropping the decoded frames saved (empty where they were kept)."""
    from ltmstore.stages.plan import size_text

    if not dropped:
        return ""
    return (f"  frames dropped: store {size_text(dropped['bytes_before'])} -> "
            f"{size_text(dropped['bytes_after'])} (--keep-frames keeps them; reconstructing "
            "again needs a new ltm ingest)")


def placement_note(record: dict | None) -> str:
    """Where the surface model placed an object the acquisition did not declare, with the
    estimate's uncertainty (empty otherwise)."""
    if not record or record.get("source") != "estimated":
        return ""
    from ltmstore.stages.placement import describe

    return (f"  object estimated at {describe(record['extent'])} "
            f"(+-{record['estimate']['uncertainty_pixels']:.1f} px)")


def plane_unit(store: str) -> str:
    """The unit of the store's light plane (``m`` unless its acquisition says otherwise): a path
    density is a length per area of it, 1/unit."""
    from ltmstore.core.store import open_group

    plane = open_group(store, mode="r").attrs.get("acquisition", {}).get("plane", {})
    return str(plane.get("unit", "m"))


def summary_of(chosen: dict) -> str:
    """``(name: tiles, ...)`` of the choices per tile, most frequent first."""
    top = sorted(chosen.items(), key=lambda kv: -kv[1])
    return "(" + ", ".join(f"{k}: {v}" for k, v in top[:4]) + (", ..." if len(top) > 4 else "") \
        + " tiles)" if top else ""


def cmd_relight(a: argparse.Namespace) -> None:
    import numpy as np

    from ltmstore.core.imagefile import write_image
    from ltmstore.core.store import open_store, refinement_note, refinement_pending
    from ltmstore.core.transfer import check_depth, check_exposure
    from ltmstore.stages.relight import LightClampWarning, encoded_images, relight

    check_exposure(a.exposure, a.ev)
    depth = check_depth(a.depth)
    ds = open_store(a.store)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", LightClampWarning)
        warnings.simplefilter("always", LtmWarning)
        lights = None if a.light is None else np.array(a.light)
        directions = None if a.direction is None else np.array(a.direction)
        images = relight(ds, lights, directions=directions, view=a.view)  # lazy: checks only
        tiled = a.layout != "image"
        if tiled and depth != 8:
            raise LtmError(f"--layout {a.layout} writes 8-bit JPEG tiles; --depth {a.depth} "
                           "goes with --layout image")
        if a.layout != "iiif" and a.iiif_url is not None:
            raise LtmError("--iiif-url goes with --layout iiif")
        if a.output is None:
            a.output = "relit" if tiled else "relit.png"
        outputs = image_paths(a.output, images.sizes["light"], combined=a.sum,
                              overwrite=a.overwrite, inputs=(a.store,), depth=depth,
                              folder=tiled)
        if len(outputs) == 1:
            images = images.sum("light").expand_dims("light")
    for w in caught:
        print(f"ltm: warning: {w.message}", file=sys.stderr)
    if refinement_pending(ds.attrs):
        print(refinement_note(a.store), file=sys.stderr)
    transfer = ds.attrs.get("acquisition", {}).get("transfer", "srgb")
    if tiled:
        from ltmstore.share.static_tiles import write_folders

        for out, info in write_folders(images, outputs, layout=a.layout, transfer=transfer,
                                       exposure=a.exposure, ev=a.ev, url=a.iiif_url or IIIF_URL,
                                       overwrite=a.overwrite, inputs=(a.store,)):
            kind = (f"IIIF id {info['id']}" if a.layout == "iiif"
                    else f"{info['levels']} levels; open {out}/image.dzi")
            print(f"wrote {out}/ ({info['tiles']} tiles; {kind})")
        return
    for out, image in zip(outputs, encoded_images(images, transfer, exposure=a.exposure,
                                                  ev=a.ev, depth=depth), strict=True):
        # whole or not at all: a full disk leaves no file; a 16-bit PNG says its transfer
        write_image(out, image, transfer=transfer if depth == 16 else None)
        print(f"wrote {out}")


def image_paths(pattern: str, n: int, *, combined: bool, overwrite: bool,
                inputs: tuple = (), depth: int | str = 8, folder: bool = False) -> list[Path]:
    """The images (or, ``folder``, folders) of ``n`` lights: one (``combined``, or one
    light), else one per light named by ``pattern`` with ``{i}`` (or ``-i`` before the
    suffix); existing ones refused unless ``overwrite``; a missing parent folder, a suffix that
    names no image format (an image) or a path in one of ``inputs`` (the store) refused; the
    suffix must hold images of ``depth``."""
    from ltmstore.core.imagefile import check_image_path
    from ltmstore.share.atomic import check_output

    if not folder:
        check_image_path(pattern, depth)
    if combined and n > 1:
        paths = [Path(pattern.replace("{i}", "sum"))]
    elif "{i}" in pattern or n == 1:
        paths = [Path(pattern.replace("{i}", str(i))) for i in range(n)]
    else:
        base = Path(pattern)
        paths = [base.with_name(f"{base.stem}-{i}{base.suffix}") for i in range(n)]
    return [check_output(p, overwrite, inputs) for p in paths]


def cmd_compact(a: argparse.Namespace) -> None:
    from ltmstore.stages.compact import compact

    info = compact(a.store, precision=a.precision, keep_frames=a.keep_frames, form=a.form,
                   target_db=a.target_snr)
    mb = 1e6
    ranks = info.get("ranks", {}).get("ltm", {})
    form = (f" factored (ranks {ranks['min']}-{ranks['max']}, mean {ranks['mean']:.1f}, per "
            f"{info['tile']} x {info['tile']} tile, {info['factor_bytes'] / 1e6:.1f} MB in place "
            f"of {info['dense_bytes'] / 1e6:.1f} MB)" if a.form == "factored" else "")
    stored = "ltm factored as ltm reconstruct stored it" if info["form"] != a.form else (
        f"ltm{form} {info['precision']}" + (f" (SNR {info['snr_db']:.1f} dB against float32)"
                                            if info["snr_db"] is not None else " (lossless)"))
    what = [stored,
            "frames dropped" if info["frames_dropped"] else
            f"frames kept{': ' + info['frames_kept_reason'] if info['frames_kept_reason'] else ''}"]
    print(f"{a.store}: {info['bytes_before'] / mb:.1f} MB -> {info['bytes_after'] / mb:.1f} MB; "
          + "; ".join(what))


def cmd_evaluate(a: argparse.Namespace) -> None:
    from ltmstore.core.store import open_store

    if a.holdout_lights is not None or a.test_lights is not None:
        return cmd_evaluate_photos(a)
    import shlex

    from ltmstore.judge.evaluate import compare_stores
    from ltmstore.judge.heldout import heldout_store

    stages = open_store(a.store).attrs["stages"]
    if held := stages.get("ingest", {}).get("held_out"):
        print(f"ltm: note: {a.store} holds out {len(held)} photographs (ingest-rti "
              f"--holdout-lights {stages['ingest'].get('holdout_every')}): `ltm evaluate "
              f"{shlex.quote(str(a.store))} --holdout-lights` scores them", file=sys.stderr)
    method = stages.get("reconstruct", {}).get("method", "cs")
    report = {"heldout": heldout_store(a.store, method=a.method or method, folds=a.folds,
                                       max_pixels=a.pixels)}
    if a.truth:
        report["truth"] = compare_stores(a.store, a.truth, maps_png=a.maps)
    print_json(report)


def cmd_evaluate_photos(a: argparse.Namespace) -> None:
    from ltmstore.core.store import open_group
    from ltmstore.judge.photos import heldout_photos

    if a.holdout_lights is not None and a.test_lights is not None:
        raise LtmError("give either --holdout-lights or --test-lights, not both")
    attrs = open_group(a.store).attrs
    lp = attrs.get("acquisition", {}).get("lp_path")
    if lp is None:
        raise LtmError(f"store {a.store!r} records no .lp file: held-out photographs need a "
                       "store made by `ltm ingest-rti` (this version)")
    every = a.holdout_lights
    if every is not None:
        every = recorded_holdout(a.store, attrs.get("stages", {}).get("ingest", {}), lp, every)
    report = heldout_photos(lp, every=every, test_lp=a.test_lights)
    for name, row in report["methods"].items():
        print(f"{name:>8s}  PSNR {row['mean_psnr']:6.2f} dB  SSIM {row['mean_ssim']:.3f}",
              file=sys.stderr)
    print_json(report)


def recorded_holdout(store: str, ingest: dict, lp: str, every: int | _Recorded) -> int:
    """The ``--holdout-lights`` to score: the one ``ingest-rti`` recorded in the store when
    ``every`` is :data:`RECORDED` (refused when none is) or agrees with it; a store without the
    record takes any ``every``. Refused too when the ``.lp`` file no longer hides the recorded
    photographs (it changed since the ingest)."""
    import numpy as np

    from ltmstore.capture.lp import LpWarning, hidden_lights, read_lp

    recorded = ingest.get("holdout_every") if ingest.get("held_out") else None
    if recorded is None:
        if every is RECORDED:
            raise LtmError(f"store {store!r} records no held-out lights (ingested without "
                           "--holdout-lights): give their number, --holdout-lights EVERY")
        return int(every)
    if every is not RECORDED and every != recorded:
        raise LtmError(f"--holdout-lights {every} disagrees with the store {store!r}, ingested "
                       f"with --holdout-lights {recorded}: give {recorded} or no number")
    with warnings.catch_warnings():  # heldout_photos reads it again and warns once
        warnings.simplefilter("ignore", LpWarning)
        names, _ = read_lp(lp)
    hidden = [names[i] for i in np.flatnonzero(hidden_lights(len(names), recorded))] \
        if recorded <= len(names) else []
    if hidden != [light["image"] for light in ingest["held_out"]]:
        raise LtmError(f"{lp} no longer lists the photographs store {store!r} holds out "
                       f"({ingest['held_out'][0]['image']!r}, ...): it changed since "
                       "`ltm ingest-rti`; ingest it again")
    return int(recorded)


def cmd_bench(a: argparse.Namespace) -> None:
    from ltmstore.judge import benchmark

    options = {"densities": (15.0, 27.0), "lattices": (16, 32), "size": 16} if a.quick else {}
    records = benchmark.run(progress=lambda line: print(line, flush=True), **options)
    result = benchmark.write(records, Path(a.out), command="ltm bench" + " --quick" * a.quick)
    for row in result["summary"]:
        print(f"{row['label']:<22s} {row['snr_db']:6.2f} dB  {row['ms_per_pixel']:9.3f} ms/pixel")
    print(f"wrote {a.out}/bench.json and charts: {', '.join(result['charts'].values())}")


def cmd_info(a: argparse.Namespace) -> None:
    from ltmstore.core.store import open_group, store_summary

    print_json(open_group(a.store).attrs.asdict() if a.raw else store_summary(a.store))
