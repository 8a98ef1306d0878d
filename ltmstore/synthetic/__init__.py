"""Ground-truth scenes, handheld trajectories and simulated acquisitions (with their truth).

``synthetic`` may import :mod:`ltmstore.core`, :mod:`ltmstore.capture`, :mod:`ltmstore.solve`
and :mod:`ltmstore.stages` (to build the failure-regime captures); judges import it, not the
other way round.
"""
