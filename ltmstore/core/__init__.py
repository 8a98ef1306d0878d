"""What everything stands on: dimension names and the lattice, the store (Zarr plan, open and
create, stage records), provenance, errors, transfer functions, operators, the Dask cluster,
image files written whole or not at all (``imagefile``) and the rule that keeps every output
apart from the command's inputs (``paths``).

``core`` imports nothing else of ltmstore: every other subpackage may import it.
"""
