"""``ltm capture FOLDER``: a capture guided live by two phones' browsers (issue 30)."""

from __future__ import annotations

import argparse
import sys
import time

from ltmstore.cli.args import number, numbers
from ltmstore.cli.names import TARGET_RATIO

DESCRIPTION = """\
Start a small server on this computer and print two addresses (and QR codes): open the first on
phone A (the light), the second on camera B. Phone A's page switches its torch on where the
browser allows it (otherwise it asks you to), streams camera frames here and draws what this
server answers: the light's path over the plane, the lattice cells covered, K/M and the SNR to
expect at that coverage (measured on the project's simulations, with its spread), "enough" once
--target-km is reached, and a warning when the tracker loses the light or the light leaves the
plane's height. Both pages also record their camera and upload the recording in numbered
chunks, so a dropped connection loses nothing already sent (camera B with its exposure locked
where the browser allows it). When phone A stops, its whole recording is tracked here (every
frame, as `ltm track`) for poses.csv; the live frames serve the feedback only.

Protocol: start both recordings, wave the light until phone A says "enough", stop camera B,
then stop phone A; the capture finishes when both pages have finished. FOLDER then is an ordinary
acquisition (acquisition.json, video_b.*, poses.csv, phone_a.mp4): run `ltm sync FOLDER` (the
phones' clocks differ), `ltm ingest` and `ltm reconstruct --lattice` as printed. Until then FOLDER
holds CAPTURE_INCOMPLETE and `ltm ingest` refuses it; Ctrl-C stops the server and leaves it so.

On 127.0.0.1 (the default) the server speaks HTTP; with --host naming another interface (a
laptop's Wi-Fi address, for phones on the same network) it speaks HTTPS with a certificate made
for this session (accept it once on each phone; check the printed fingerprint). Every address
carries a one-time token; requests without it get 403.
"""


def register(sub) -> None:
    """Add ``ltm capture`` to the ``ltm`` subparsers ``sub``."""
    p = sub.add_parser("capture", help="a capture guided live: pages for phone A and camera B",
                       description=DESCRIPTION,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("folder", help="acquisition folder to write (new or empty)")
    p.add_argument("--intrinsics", required=True, help="phone A's camera, JSON from "
                   "`ltm calibrate` (frames of another size with the same aspect are scaled)")
    target = p.add_mutually_exclusive_group(required=True)
    target.add_argument("--board", help="board spec JSON from `ltm board` (phone A films it)")
    target.add_argument("--painting", help="image (or camera B video) of the painting: phone A "
                        "tracks the painting itself (needs --painting-width)")
    p.add_argument("--painting-width", type=number, help="the painting's width, metres")
    p.add_argument("--led-offset", type=numbers("DX,DY,DZ", "metres"), default=(0.0, 0.0, 0.0),
                   help="LED position from phone A's camera, metres, camera axes (x right, "
                   "y down, z along the view), e.g. 0.012,0,0")
    p.add_argument("--lattice", default="32x32",
                   help="RxS cells the coverage is counted on (default: %(default)s); use the "
                   "same with `ltm reconstruct --lattice`")
    p.add_argument("--plane", type=numbers("R0,R1,S0,S1", "metres"), default=(-0.2, 0.2, -0.2, 0.2),
                   help="illumination plane rectangle, metres from the board's (or painting's) "
                   "centre (default: -0.2,0.2,-0.2,0.2)")
    p.add_argument("--height", type=number, default=0.3,
                   help="height of the plane the light is waved in, metres (default: "
                   "%(default)s); frames further than 5 %% of it are warned about and not counted")
    p.add_argument("--target-km", type=number, default=TARGET_RATIO,
                   help="K/M at which phone A's page says enough (default: %(default)s, the "
                   "paper's ratio)")
    p.add_argument("--host", default="127.0.0.1", help="interface to listen on (default: "
                   "%(default)s); another than loopback serves HTTPS")
    p.add_argument("--port", type=int, default=0, help="port (default: a free one)")
    p.add_argument("--no-qr", action="store_true", help="do not print QR codes")
    p.set_defaults(func=cmd_capture)


def cmd_capture(a: argparse.Namespace) -> None:
    from ltmstore.capture.live_server import make_server

    session = _session(a)
    server = make_server(session, host=a.host, port=a.port)
    try:
        _announce(server, qr=not a.no_qr)
        session.listeners.append(_Progress())
        server.serve_forever()
    except KeyboardInterrupt:
        print(f"\nltm capture: stopped; {a.folder} stays marked incomplete", file=sys.stderr)
        raise
    finally:
        server.server_close()
    if session.finished:
        lattice = "x".join(map(str, session.config.lattice))
        print(f"\nltm capture: finished; next: ltm sync {a.folder} && ltm ingest {a.folder} "
              f"STORE && ltm reconstruct STORE --lattice {lattice}")


def _session(a: argparse.Namespace):
    from ltmstore.capture.calibrate import load_intrinsics
    from ltmstore.capture.live import (
        LiveConfig,
        LiveSession,
        board_tracker,
        board_video_tracker,
        painting_trackers,
    )
    from ltmstore.capture.track import TrackConfig
    from ltmstore.core.dims import Plane, parse_lattice
    from ltmstore.core.errors import LtmError
    from ltmstore.stages.ingest import Z_TOLERANCE_FRACTION

    if a.painting and not (a.painting_width and a.painting_width > 0):
        raise LtmError("--painting needs --painting-width W, the painting's width in metres "
                       "(a positive number)")
    if not 0 < a.target_km <= 1:
        raise LtmError(f"--target-km {a.target_km} must lie in (0, 1]")
    if not a.height > 0:
        raise LtmError(f"--height {a.height} must be a positive number of metres")
    r0, r1, s0, s1 = a.plane
    if not (r0 < r1 and s0 < s1):
        raise LtmError(f"--plane {r0},{r1},{s0},{s1} must have R0 < R1 and S0 < S1")
    plane = Plane(r=(r0, r1), s=(s0, s1), height=a.height)
    tolerance = Z_TOLERANCE_FRACTION * a.height
    intr = load_intrinsics(a.intrinsics)
    track = TrackConfig(led_offset=a.led_offset, height=a.height, z_tolerance=tolerance)
    if a.board:
        from ltmstore.capture.board import load_board

        spec = load_board(a.board)
        tracker, kind = board_tracker(spec, intr, track), "board"
        video_tracker = board_video_tracker(spec, intr, track)
    else:
        tracker, video_tracker = painting_trackers(a.painting, a.painting_width, intr, track)
        kind = "painting"
    config = LiveConfig(plane=plane, lattice=tuple(parse_lattice(a.lattice)), tracker=kind,
                        target_km=a.target_km, height_tolerance=tolerance)
    return LiveSession(a.folder, config, tracker, video_tracker=video_tracker)


def _announce(server, *, qr: bool) -> None:
    for who, path in (("phone A (the light)", "/a"), ("camera B", "/b")):
        url = server.url(path)
        print(f"{who}: {url}")
        if qr:
            import segno

            segno.make(url, error="l").terminal(compact=True)
    if server.fingerprint:
        print(f"certificate SHA-256 {server.fingerprint} (made for this session: accept it on "
              "each phone)")
    print(f"writing {server.session.folder}; Ctrl-C stops (the folder stays incomplete)")
    print("ltm capture: listening", flush=True)


class _Progress:
    """One terminal line, rewritten at most twice a second."""

    def __init__(self) -> None:
        self.last = 0.0

    def __call__(self, s: dict) -> None:
        now = time.monotonic()
        if now - self.last < 0.5 and not s["finished"]:
            return
        self.last = now
        c = s["coverage"]
        line = (f"A: {s['frames']} frames, {s['placed_frames']} placed | K/M "
                f"{c['k_over_m']:.3f} ({c['covered']}/{c['cells']}) | SNR ~"
                f"{s['expected_snr_db']:.0f} +- {s['expected_snr_spread_db']:.0f} dB"
                f"{' | enough' if s['enough'] else ''} | B: {s['b']['chunks']} chunks, "
                f"{s['b']['bytes'] / 1e6:.1f} MB")
        print("\r" + line.ljust(100), end="", file=sys.stderr, flush=True)
