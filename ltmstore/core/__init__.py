"""What everything stands on: dimension names and the lattice, the store (Zarr plan, open and
create, stage records), provenance, errors, transfer functions, operators and the Dask cluster.

``core`` imports nothing else of ltmstore: every other subpackage may import it.
"""
