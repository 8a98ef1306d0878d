"""What makes an acquisition: the phone-side tools (ChArUco board, calibration, tracking, clock
sync), camera B's video and its registration onto the object plane, and the readers of
acquisition folders and classic ``.lp`` captures.

``capture`` imports only :mod:`ltmstore.core`; the stages build stores from what it reads.
"""
