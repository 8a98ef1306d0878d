"""Screenshots of the two ``ltm capture`` pages while a capture runs, on a phone-sized viewport.

The same simulated capture and fake cameras as ``tests/capture/test_live_pages.py``: headless
Chromium (Debian's ``chromium``) plays phone A's and camera B's simulated videos into the pages
served by the real ``ltm capture``; each page is photographed while phone A streams.

    python bench/capture_screenshots.py  # bench/results/capture_phone_a.png, capture_camera_b.png
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from capture_pages_helpers import VIEWPORT, run_capture, simulate  # noqa: E402

RESULTS = Path(__file__).parent / "results"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=RESULTS, help="folder of the PNGs")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    shots = {"a": args.out / "capture_phone_a.png", "b": args.out / "capture_camera_b.png"}
    with tempfile.TemporaryDirectory(prefix="ltm-capture-shots-") as tmp:
        work = Path(tmp)
        simulate(work / "sim")
        pages = run_capture(work / "sim", work / "acq", work, shots=shots)
    a, b = pages["a"], pages["b"]
    print(f"{VIEWPORT[0]} x {VIEWPORT[1]} CSS px; phone A: {a['placed']} of {a['sent']} frames "
          f"placed, {a['rateHz']:.1f} answers/s, {a['latencyMs']:.0f} ms each; camera B: "
          f"{b['acked']} of {b['recorded']} pieces sent")
    for path in shots.values():
        print(path)


if __name__ == "__main__":
    main()
