"""The pipeline's stages, one module each: ingest (and ingest_rti for classic captures, sharing
the frame sink in ``frames``) -> resample -> reconstruct -> relight, plus previews.

``stages`` import :mod:`ltmstore.core`, :mod:`ltmstore.capture` and :mod:`ltmstore.solve`;
a stage never imports a judge, an exporter or the CLI.
"""
