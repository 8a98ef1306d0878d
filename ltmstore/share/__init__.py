"""What leaves a store for other tools and people: exports to the RTI world's formats and the
interactive viewer.

``export`` (``ltm export``) fits a light basis per pixel (``directions``: the lights and colours
of a store; ``bases``: the bases as the readers evaluate them; ``fit``: display-referred ridge
fits), quantises it (``quantize``) and writes PTM 1.2 (``ptm``), HSH ``.rti`` (``hsh_rti``) or
Relight's web format (``relight_web``) atomically (``atomic``). ``maps`` (``ltm maps``) writes
the surface model's normal, albedo, specular and roughness maps of a far-light store, and relights
it with its material changed.

``share`` may import :mod:`ltmstore.core`, :mod:`ltmstore.solve` and :mod:`ltmstore.stages`.
"""
