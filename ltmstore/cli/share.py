"""``ltm`` commands that share a store with other tools: export."""

from __future__ import annotations

import argparse


def register(sub) -> None:
    """Add the sharing commands to the ``ltm`` subparsers ``sub``."""
    from ltmstore.share.export import COLORS, FORMATS, HSH_ORDERS, WEB_BASES
    from ltmstore.share.relight_web import DEFAULT_QUALITY

    p = sub.add_parser("export", help="write a .ptm, .rti or Relight web folder (RTIViewer, "
                       "OpenLIME)",
                       description="Fit a PTM or HSH basis per pixel to the store's colours at "
                       "the lattice cells' light directions and write it as PTM 1.2 (.ptm), "
                       "HSH RTI (.rti, RTIViewer) or Relight's web format (a folder with "
                       "info.json and plane_<j>.jpg, for OpenLIME). Values are display sRGB; "
                       "the 99.5th percentile of the store's linear RGB is white.")
    p.add_argument("store")
    p.add_argument("output", help="OUT.ptm, OUT.rti, or a folder for --format relight")
    p.add_argument("--format", dest="fmt", required=True, choices=FORMATS)
    p.add_argument("--order", type=int, default=3, choices=HSH_ORDERS,
                   help="hsh: 2 (9 terms) or 3 (16 terms) (default: %(default)s)")
    p.add_argument("--basis", default="ptm", choices=WEB_BASES,
                   help="relight: the basis of the web format (default: %(default)s)")
    p.add_argument("--color", default="rgb", choices=COLORS,
                   help="ptm: a polynomial per channel (rgb) or luminance times colour (lrgb) "
                   "(default: %(default)s)")
    p.add_argument("--quality", type=int, default=DEFAULT_QUALITY,
                   help="relight: JPEG quality of the planes (default: %(default)s)")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=cmd_export)


def cmd_export(a: argparse.Namespace) -> None:
    from ltmstore.share.export import export

    r = export(a.store, a.output, fmt=a.fmt, order=a.order, basis=a.basis, color=a.color,
               quality=a.quality, overwrite=a.overwrite)
    print(f"wrote {r['path']} ({r['format']}, {r['basis']} basis, {r['terms']} terms, "
          f"{r['width']}x{r['height']} px, fitted at {r['directions']} light directions; "
          f"white = {r['white']:.4g} linear)")
