"""``ltm lights``: the ``.lp`` light file of a classic capture from the reflective spheres in
its photographs (:mod:`ltmstore.capture.sphere`)."""

from __future__ import annotations

import argparse

from ltmstore.cli.args import number, numbers


def register(sub) -> None:
    """Add ``ltm lights`` to the ``ltm`` subparsers ``sub``."""
    p = sub.add_parser("lights", help="write the .lp light file from reflective spheres in the "
                       "photographs",
                       description="Find one or more reflective spheres (chrome or black "
                       "glossy) photographed beside the object, locate each photograph's "
                       "highlight on them to a fraction of a pixel and write the .lp file "
                       "(one direction towards the light per photograph, x right, y up, z "
                       "towards the camera) for ltm ingest-rti. The camera is taken as looking "
                       "straight down at the object (orthographic). With two spheres or more, "
                       "a near light's position is where the reflected rays meet: --dome "
                       "writes it as Relight's .dome file (lights3d).")
    p.add_argument("photos", nargs="+", metavar="PHOTO",
                   help="the capture's photographs, or one folder of them")
    p.add_argument("-o", "--output", required=True, metavar="LIGHTS.lp",
                   help="the .lp file to write, in the photographs' folder or above it")
    p.add_argument("--sphere", type=numbers("X,Y,R", "pixels"), action="append",
                   metavar="X,Y,R", help="a sphere's centre and radius in pixels (column, row "
                   "from the top-left; approximate: refined here); repeat for a second sphere "
                   "(default: detected)")
    p.add_argument("--spheres", type=int, default=None, metavar="N",
                   help="how many spheres to detect (default: every one showing highlights)")
    p.add_argument("--dome", metavar="OUT.dome", help="also write Relight's .dome file with "
                   "the lights' 3D positions (two spheres or more)")
    p.add_argument("--image-width", type=number, default=None, metavar="MM",
                   help="the photographs' field width at the object in mm: the .dome's "
                   "positions in mm (default: in image widths)")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    p.set_defaults(func=cmd_lights)


def cmd_lights(a: argparse.Namespace) -> None:
    from ltmstore.capture.sphere import write_lights

    r = write_lights(a.photos, a.output, spheres=a.sphere, count=a.spheres, dome=a.dome,
                     image_width_mm=a.image_width, overwrite=a.overwrite)
    spheres = "; ".join(f"({x:.2f}, {y:.2f}) r {radius:.2f} px" for x, y, radius in
                        r["spheres"])
    dome = f" and {r['dome']}" if r["dome"] else ""
    print(f"wrote {r['path']}{dome} ({r['lights']} lights from {len(r['spheres'])} "
          f"sphere(s): {spheres})")
    for note in r["notes"]:
        print(f"ltm lights: {note}")
