"""``ltm`` commands that share a store with other tools and people: export, maps, view."""

from __future__ import annotations

import argparse

from ltmstore.cli.args import number, numbers
from ltmstore.cli.names import (
    COLORS,
    DEFAULT_QUALITY,
    FORMATS,
    GRID_MAX_LOSS_DB,
    GRID_RESOLUTIONS,
    HSH_ORDERS,
    LAYOUTS,
    PCA_MAX_LOSS_DB,
    PLANES,
    TILE_SIZE,
    WEB_BASES,
)


def register(sub) -> None:
    """Add the sharing commands to the ``ltm`` subparsers ``sub``."""
    p = sub.add_parser("export", help="write a .ptm, .rti or Relight web folder (RTIViewer, "
                       "OpenLIME)",
                       description="Write the store as PTM 1.2 (.ptm) or HSH RTI (.rti) for "
                       "RTIViewer, or Relight's web format (a folder with info.json and "
                       "plane_<j>.jpg, for OpenLIME). PTM and HSH are fitted per pixel to the "
                       "store's colours at the lattice cells' light directions; the web "
                       "format's default basis, bilinear, carries the store's own relighting "
                       "(relit on Relight's octahedral grid of lights, PCA planes). Values are "
                       "display sRGB at the capture's exposure, as ltm relight writes them. "
                       "Prints what the format loses: its PSNR at the capture's held-out "
                       "lights (ingest-rti --holdout-lights) against the photographs and "
                       "ltm relight, else against ltm relight at the capture's lights. With "
                       "--layout deepzoom the web format's planes are DeepZoom pyramids "
                       "(plane_<j>.dzi, plane_<j>_files/) that OpenLIME reads tile by tile.")
    p.add_argument("store", help="reconstructed store (ltm reconstruct)")
    p.add_argument("output", help="OUT.ptm, OUT.rti, or a folder for --format relight")
    p.add_argument("--format", dest="fmt", required=True, choices=FORMATS,
                   help="ptm: PTM 1.2 (.ptm); hsh: HSH RTI (.rti); relight: Relight's web "
                   "format (a folder, for OpenLIME)")
    p.add_argument("--order", type=int, default=3, choices=HSH_ORDERS,
                   help="hsh: 2 (9 terms) or 3 (16 terms) (default: %(default)s)")
    p.add_argument("--basis", default=WEB_BASES[0], choices=WEB_BASES,
                   help="relight: the basis of the web format: bilinear (the store's "
                   "relighting, PCA-compressed), or ptm / hsh fitted to it (default: "
                   "%(default)s)")
    p.add_argument("--resolution", type=_auto_int, default="auto",
                   help="relight bilinear: light grid nodes per side, 4-64, or auto: the "
                   f"smallest of {', '.join(map(str, GRID_RESOLUTIONS))} whose grid costs at most "
                   f"{GRID_MAX_LOSS_DB} dB against the held-out photographs (the viewer draws a "
                   "light between the four nodes around it), among those whose relighting is "
                   "affordable at the image's size (default: %(default)s)")
    p.add_argument("--planes", type=_auto_int, default="auto",
                   help="relight bilinear: PCA planes, a multiple of 3 up to 48, or auto: the "
                   f"fewest of {', '.join(map(str, PLANES))} whose PCA costs at most "
                   f"{PCA_MAX_LOSS_DB} dB against the held-out photographs, else {PLANES[0]} "
                   "(default: %(default)s)")
    p.add_argument("--color", default="rgb", choices=COLORS,
                   help="ptm: a polynomial per channel (rgb) or luminance times colour (lrgb) "
                   "(default: %(default)s)")
    p.add_argument("--quality", type=_auto_int, default="auto",
                   help="relight: JPEG quality of the planes, 1-100, or auto: for the bilinear "
                   "basis the lowest of 95, 97, 98 and 100 whose JPEG costs at most 0.5 dB "
                   "against ltm relight at the lights the fidelity line scores (else "
                   f"{DEFAULT_QUALITY}) (default: %(default)s)")
    p.add_argument("--layout", default=LAYOUTS[0], choices=LAYOUTS,
                   help="relight: the planes as whole JPEGs (image), or as DeepZoom pyramids "
                   "(deepzoom: plane_<j>.dzi and plane_<j>_files/, tiles a viewer reads as "
                   "it zooms; OpenLIME's layout 'deepzoom') (default: %(default)s)")
    p.add_argument("--tile-size", type=int, default=TILE_SIZE,
                   help="relight --layout deepzoom: tile side in pixels (default: "
                   "%(default)s)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing OUTPUT")
    p.set_defaults(func=cmd_export)
    register_maps(sub)
    register_view(sub)


def _auto_int(text: str) -> int | None:
    """``--quality``, ``--resolution`` and ``--planes``: ``auto`` (None) or a whole number."""
    if text == "auto":
        return None
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected auto or a whole number") from None


def cmd_export(a: argparse.Namespace) -> None:
    from ltmstore.share.export import export

    r = export(a.store, a.output, fmt=a.fmt, order=a.order, basis=a.basis, color=a.color,
               quality=a.quality, overwrite=a.overwrite, resolution=a.resolution,
               planes=a.planes, layout=a.layout, tile_size=a.tile_size)
    print(f"wrote {r['path']} ({r['format']}, {r['basis']} basis, {r['terms']} terms, "
          f"{r['width']}x{r['height']} px, from {r['directions']} light directions; "
          f"white = {r['white']:.4g} linear)")
    if r["layout"] != "image":
        print(f"{r['layout']} layout: {r['levels']} levels of {r['tile_size']} px tiles, "
              f"{r['tiles']} tiles")
    if "jpeg" in r:
        tried = ", ".join(f"{q}: {v:.2f}" for q, v in r["jpeg"]["loss_db"].items())
        print(f"planes JPEG quality {r['quality']} (auto; dB the JPEG costs against ltm "
              f"relight: {tried})")
    if "grid" in r:
        grid = r["grid"]
        if "loss_db" in grid:
            tried = ", ".join(f"{n}: {v:.2f}" for n, v in grid["loss_db"].items())
            what = "dB the grid costs against the held-out photographs"
        else:
            tried = ", ".join(f"{n}: {v:.1f}" for n, v in grid["db_vs_store"].items())
            what = "its dB against ltm relight"
        print(f"light grid {grid['resolution']} x {grid['resolution']} nodes (auto; {what}: "
              f"{tried})")
    if "pca" in r:
        tried = ", ".join(f"{n}: {v:.2f}" for n, v in r["pca"]["loss_db"].items())
        print(f"{r['terms']} PCA planes (auto; dB the PCA costs against the held-out "
              f"photographs: {tried})")
    if "fidelity" in r:
        print(r["fidelity"]["text"])


def register_maps(sub) -> None:
    """Add ``ltm maps`` to the ``ltm`` subparsers ``sub``."""
    p = sub.add_parser("maps", help="the surface model's normal, albedo, specular and roughness "
                       "maps as PNG; relit with the material changed",
                       description="Write the surface maps of a far-light store reconstructed "
                       "with the surface model (ltm ingest-rti, then ltm reconstruct --method "
                       "physical) into a new folder: normal.png (16-bit RGB, (n + 1) / 2 with "
                       "R = x right, G = y up, B = z towards the camera), albedo.png and "
                       "specular.png (8-bit sRGB, the 99.5th percentile white), roughness.png "
                       "(8-bit grey, the lobe's alpha). With --direction, also "
                       "material_000.png, ... : "
                       "the model relit at each direction with the diffuse albedo and the "
                       "specular lobe scaled (RTI viewers' specular enhancement), at the "
                       "albedo map's exposure. Exposure: these images are scaled for display "
                       "(each map to its own white, the material images to the albedo map's), "
                       "not written at the capture's exposure as ltm relight's are. With "
                       "--height and --mesh, the normals integrated into a height map and "
                       "meshes in mm.")
    p.add_argument("store", help="far-light store reconstructed with --method physical")
    p.add_argument("output", metavar="OUT_DIR", help="folder to create")
    p.add_argument("--direction", type=numbers("LX,LY,LZ", "a direction"), action="append",
                   metavar="LX,LY,LZ", help="direction towards the light (normalised; lz > 0) "
                   "of a material image, as in ltm relight; repeat to add lights")
    p.add_argument("--diffuse", type=number, default=None, metavar="D",
                   help="scale of the diffuse albedo in the material images (default: 1)")
    p.add_argument("--specular", type=number, default=None, metavar="S",
                   help="scale of the specular lobe in the material images: 0 diffuse only, "
                   "3 enhanced (default: 1)")
    p.add_argument("--height", action="store_true",
                   help="also integrate the normals into height.png (16-bit, lowest 0, "
                   "highest 65535) and height.json (its range in pixels, and mm)")
    p.add_argument("--mesh", action="store_true",
                   help="also write the height as height.ply and height.obj meshes in mm "
                   "(needs --pixel-size or --object-width; implies --height)")
    p.add_argument("--integration", default="poisson", choices=("poisson", "fc", "bilateral"),
                   help="poisson: least squares (DCT); fc: Frankot-Chellappa (Fourier, mirror "
                   "padding); bilateral: bilateral normal integration, which keeps a relief's "
                   "occluding edges as steps (iterative, hundreds of times slower) (default: "
                   "%(default)s)")
    scale = p.add_mutually_exclusive_group()
    scale.add_argument("--pixel-size", type=number, default=None, metavar="MM",
                       help="the size of a pixel on the object, mm")
    scale.add_argument("--object-width", type=number, default=None, metavar="MM",
                       help="the width of the store's image on the object, mm")
    p.add_argument("--mesh-step", type=int, default=None, metavar="PX",
                   help="mesh vertices every PX pixels (default: the smallest step keeping "
                   "at most a million vertices)")
    p.add_argument("--depth", choices=("8", "16", "float"), default="8",
                   help="the maps' and material images' precision: 8 (as above), 16 (every "
                   "image 16-bit PNG, same encodings) or float (float32 TIFF, .tif: the linear "
                   "values behind the 8-bit images, unclipped; the normal n in [-1, 1]); the "
                   "height map is 16-bit at every depth (default: %(default)s)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing OUT_DIR")
    p.set_defaults(func=cmd_maps)


def cmd_maps(a: argparse.Namespace) -> None:
    from ltmstore.core.errors import LtmError
    from ltmstore.share.maps import maps

    if a.direction is None and (a.diffuse, a.specular) != (None, None):
        raise LtmError("--diffuse and --specular scale the material images: add --direction "
                       "LX,LY,LZ")
    r = maps(a.store, a.output, directions=a.direction,
             diffuse=1.0 if a.diffuse is None else a.diffuse,
             specular=1.0 if a.specular is None else a.specular, overwrite=a.overwrite,
             height=a.height, mesh=a.mesh, integration=a.integration, pixel_mm=a.pixel_size,
             object_width_mm=a.object_width, mesh_step=a.mesh_step, depth=a.depth)
    print(f"wrote {r['path']} ({', '.join(r['files'])}; {r['width']}x{r['height']} px)")
    if r["relief"] is not None:
        mm = r["relief"].get("range_mm")
        print(f"ltm maps: height range {r['relief']['range_px']:.4g} px"
              + ("" if mm is None else f" = {mm:.4g} mm") + f" ({r['relief']['integration']})")


def register_view(sub) -> None:
    """Add ``ltm view`` to the ``ltm`` subparsers ``sub``."""
    p = sub.add_parser("view", help="an interactive page on 127.0.0.1: the light follows the "
                       "pointer",
                       description="Serve a page on this machine only (127.0.0.1) where the "
                       "store is relit with the light under the pointer: zoom and pan, point or "
                       "area light, the view of a 6D store, the expected_error map. The page "
                       "asks for the part of the image on the screen at the screen's "
                       "resolution, so a huge store is read where it is shown. Prints the "
                       "URL; Ctrl-C stops. Each light is also an IIIF Image API 3.0 image "
                       "service any tiled viewer opens: URL/iiif/LIGHT/info.json, tiles "
                       "URL/iiif/LIGHT/REGION/SIZE/0/default.png|jpg, LIGHT being R,S (as "
                       "ltm relight --light) or LX,LY,LZ (--direction), optionally with ;ev=E "
                       "(stops) and ;view=P,Q (6D), e.g. /iiif/0.1,-0.05;ev=1/full/max/0/"
                       "default.png. A tile reads and relights only its region.")
    p.add_argument("store", help="reconstructed store (ltm reconstruct)")
    p.add_argument("--port", type=int, default=0, help="port (default: a free one)")
    p.add_argument("--host", default="127.0.0.1",
                   help="loopback address to bind: 127.0.0.1, localhost or ::1 (default: "
                   "%(default)s); the page is never served to other machines")
    p.add_argument("--open", action="store_true", help="open the page in a web browser")
    p.set_defaults(func=cmd_view)


def cmd_view(a: argparse.Namespace) -> None:
    import os
    import sys
    import webbrowser

    from ltmstore.share.view import check_host, make_server

    check_host(a.host)
    server = make_server(a.store, host=a.host, port=a.port)
    try:  # a Ctrl-C right after the URL is shown stops as cleanly as a later one
        print(f"ltm view: serving {a.store} at {server.url} (Ctrl-C to stop)", flush=True)
        if a.open:
            webbrowser.open(server.url)
        server.serve_forever()
    except KeyboardInterrupt:
        server.server_close()
        print("ltm view: stopped", file=sys.stderr, flush=True)
        sys.stdout.flush()
        # now: the interpreter's exit would wait for the renders in flight (Dask's worker
        # threads are joined at exit: 3 s on a 4 MP store); the server writes nothing
        os._exit(0)
    finally:
        server.server_close()
