"""The LED-off lead of a two-phone capture, found in camera B's brightness.

The capture protocol: both recordings start with the phone's LED off for about a second (the
room light on), then the user turns the torch on. Camera B's frames of that lead show the room
light alone (the ambient term), far darker than the frames lit by the LED, and the lead ends in
a step up. Found from the data, never assumed: a video without such a lead has none.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MAX_LEAD_S = 10.0  # a lead is searched for in the first seconds of the video only
# Lead frames are below this fraction of the lit frames' median brightness. A camera B whose
# auto exposure is on compresses the step (the simulated one: lit frames 1.9 times the lead).
DARK_FRACTION = 0.67
STEP_RATIO = 1.5  # the torch coming on: the first frame this much brighter than the start ...
STEP_FRAMES = 2  # ... and, within this many frames, than the lead's last frames: a torch comes
# on at once, a light moving onto the painting from the plane's dark edge brightens gradually
MIN_LEAD_FRAMES = 3
STEP_MARGIN_S = 0.1  # frames this close to the step are neither ambient nor samples
HEAD_FRAMES = 3  # the first frames, whose median is the dark level
MAX_LEAD_RATIO = 1.5  # the lead's brightest frame over its darkest: the room light is steady
DARK_NOISE = 0.02  # plus this fraction of the lit level (a dark room: noise around zero)


@dataclass(frozen=True)
class Lead:
    """A leading LED-off segment of a video.

    Attributes
    ----------
    step : int
        Index of the first frame :data:`STEP_RATIO` times brighter than the dark start (the
        torch coming on).
    ambient : (int, int)
        Frame range ``[start, stop)`` whose frames measure the room light (before the step,
        less the margin).
    excluded : (int, int)
        Frame range ``[0, stop)`` kept out of the samples (the lead and the step's margin).
    level : float
        Median brightness of the ambient frames.
    lit_level : float
        Median brightness of the frames after the lead.
    """

    step: int
    ambient: tuple[int, int]
    excluded: tuple[int, int]
    level: float
    lit_level: float

    def to_json(self) -> dict:
        return {"step_frame": self.step, "ambient_frames": list(self.ambient),
                "excluded_frames": list(self.excluded), "level": self.level,
                "lit_level": self.lit_level,
                "fraction_of_lit": self.level / self.lit_level if self.lit_level > 0 else None}


def find_lead(brightness: np.ndarray, fps: float) -> Lead | None:
    """Find the LED-off lead in per-frame mean brightness (linear light).

    Parameters
    ----------
    brightness : ndarray (n,)
        Mean linear brightness of every frame of camera B, in order.
    fps : float
        Frame rate.

    Returns
    -------
    Lead or None
        None unless the video starts with at least :data:`MIN_LEAD_FRAMES` frames of steady
        brightness (brightest over darkest at most :data:`MAX_LEAD_RATIO`) that then step up,
        within :data:`STEP_FRAMES` frames, to :data:`STEP_RATIO` times the lead's last frames,
        and to a median brightness more than ``1 / DARK_FRACTION`` times higher.
    """
    b = np.asarray(brightness, dtype=np.float64)
    window = min(len(b), int(math.ceil(MAX_LEAD_S * fps)))
    if window < HEAD_FRAMES + MIN_LEAD_FRAMES or not np.isfinite(b).all():
        return None
    dark = float(np.median(b[:HEAD_FRAMES]))
    scale = float(np.percentile(b, 75))  # lit frames are most of any capture
    above = np.flatnonzero(b[:window] > STEP_RATIO * dark + DARK_NOISE * scale)
    step = int(above[0]) if above.size else window
    margin = max(1, int(round(STEP_MARGIN_S * fps)))
    lead = b[:step]
    if step < MIN_LEAD_FRAMES or step + margin >= len(b) \
            or lead.max() > MAX_LEAD_RATIO * lead.min() + DARK_NOISE * scale:
        return None
    if b[step:step + STEP_FRAMES].max() <= STEP_RATIO * float(np.median(lead[-HEAD_FRAMES:])) \
            + DARK_NOISE * scale:
        return None  # a gradual rise, not a step
    lit = float(np.median(b[step + margin:]))
    if not dark < DARK_FRACTION * lit:
        return None
    ambient = (0, max(1, step - margin))
    return Lead(step=step, ambient=ambient, excluded=(0, step + margin),
                level=float(np.median(b[slice(*ambient)])), lit_level=lit)
