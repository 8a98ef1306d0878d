"""What leaves a store for other tools and people: exports to the RTI world's formats and the
interactive viewer.

``share`` may import :mod:`ltmstore.core`, :mod:`ltmstore.solve` and :mod:`ltmstore.stages`.
"""
