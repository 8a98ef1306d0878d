"""Dask graph sizes: each command's task count follows the chunks it reads, not cells x chunks.

Issue 25 item 6: ``ltm evaluate --truth`` of a small 6D store built a graph of millions of tasks
(lattice interpolation by ``xr.dot`` along every chunked lattice axis, then realigned to the
truth's chunks: 3,034,251 tasks for 24 x 24 px at 8 x 8 x 4 x 4 cells) and spent minutes in
``dask.order`` before computing anything. Each bound here is the count measured after the fix on
these stores (32 x 32 px of the session's ``small_acquisition``, 16 px tiles: 4 tiles; 8 x 8 and
16 x 16 cells) plus about 10 %; the counts are those of the graphs the schedulers receive.
"""

from __future__ import annotations

import shutil
from contextlib import contextmanager

import dask
import dask.array as da
import numpy as np
import pytest
import xarray as xr
from dask.callbacks import Callback
from distributed import Client, LocalCluster
from distributed.diagnostics.plugin import SchedulerPlugin

from ltmstore.core.store import open_store
from ltmstore.judge.evaluate import at_cells, compare_stores
from ltmstore.share.export import export
from ltmstore.stages.compact import compact
from ltmstore.stages.ingest import ingest
from ltmstore.stages.plan import plan_tiles
from ltmstore.stages.reconstruct import reconstruct, resample_regions, tile_groups
from ltmstore.stages.relight import relight

TILE = 16
LATTICES = (8, 16)


class _LocalTasks(Callback):
    """The size of every graph the local (threaded) scheduler runs."""

    def __init__(self) -> None:
        super().__init__()
        self.sizes: list[int] = []

    def _start(self, dsk) -> None:
        self.sizes.append(len(dsk))


@contextmanager
def local_tasks():
    """Count the tasks of every Dask computation inside, run on the threaded scheduler."""
    counter = _LocalTasks()
    with dask.config.set(scheduler="threads"), counter:
        yield counter.sizes


class _SchedulerTasks(SchedulerPlugin):
    """The number of tasks of every graph a distributed scheduler receives."""

    def __init__(self) -> None:
        self.sizes: list[int] = []

    def update_graph(self, scheduler, *, tasks, **kwargs) -> None:
        self.sizes.append(len(tasks))


@pytest.fixture(scope="module")
def stores(small_acquisition, tmp_path_factory):
    """``small_acquisition`` reconstructed on 8 x 8 and 16 x 16 cells, with the tasks of each
    reconstruct's graphs (counted on the scheduler)."""
    root = tmp_path_factory.mktemp("graphs")
    out = {}
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                      dashboard_address=None) as cluster:
        for n in LATTICES:
            store = root / f"lattice{n}.zarr"
            ingest(small_acquisition, store, progress=False)
            counter = _SchedulerTasks()
            cluster.scheduler.add_plugin(counter, name="graph-tasks")
            try:
                with Client(cluster) as client:
                    reconstruct(store, client=client, lattice=(n, n), tile=TILE, method="cs",
                                progress=False)
            finally:
                cluster.scheduler.remove_plugin(name="graph-tasks")
            out[n] = (store, counter.sizes)
    return out


def test_reconstruct_tasks_do_not_grow_with_the_lattice(stores):
    # Measured: [3, 4, 1] (resample in one region beside the cells and counts, scattered once
    # to the workers; solve 4 tiles one per task; the light-major copy in one band) on both
    # lattices; before the resample regions and the tile groups, [69, 9, 1]. The finiteness
    # check counts chunks and builds no graph (it was 21 tasks).
    for n in LATTICES:
        assert sum(stores[n][1]) <= 8, (n, stores[n][1])
    assert stores[8][1] == stores[16][1]


def test_a_4k_reconstruct_is_a_few_thousand_tasks():
    """Issue 25 item 5: the 4K capture's reconstruct (3840 x 2160 px, 1,359 frames in chunks of
    256 x 256 px, 32 x 32 px tiles) as a cluster's scheduler receives it: 510 resample tasks of
    128 x 128 px, 2,040 solve tasks of 2 x 2 tiles (Dask's graph was 136,504 resample tasks and
    16,320 solve tasks), each region and tile once; a resumed run groups only its tiles left."""
    plan = plan_tiles((2160, 3840), (36, 36), tile=32)
    regions = resample_regions(plan, (256, 256), 1359)
    assert len(regions) == 510 and {(r.stop - r.start, c.stop - c.start)
                                     for r, c in regions} == {(128, 128), (112, 128)}
    covered = np.zeros(plan.image, dtype=int)
    for where in regions:
        covered[where] += 1
    assert (covered == 1).all()
    todo = np.ones(plan.grid, dtype=bool)
    groups = tile_groups(todo)
    assert len(groups) == 2040 and max(map(len, groups)) == 4
    todo[::3] = False  # an interrupted run: a third of the rows done
    left = tile_groups(todo)
    assert sorted(t for g in left for t in g) == [tuple(t) for t in np.argwhere(todo)]
    assert all(max(abs(a - b) for a, b in zip(g[0], t, strict=True)) <= 1 for g in left for t in g)


def test_evaluate_tasks_follow_the_pixel_blocks(stores, small_acquisition):
    truth = small_acquisition / "truth.zarr"  # 16 x 16 cells, one 32 x 32 px chunk
    with local_tasks() as tasks:
        out = compare_stores(stores[8][0], truth)
    assert out["interpolated_from"] == [8, 8]
    # Measured: [8, 59] (poses; 4 pixel blocks); before the fix 180 tasks in 12 graphs.
    assert sum(tasks) <= 74, tasks
    with local_tasks() as tasks:
        compare_stores(stores[16][0], truth)
    assert sum(tasks) <= 92, tasks  # measured: [8, 75] (16 inner chunks merged); before: 230


DIMS_6D = ("y", "x", "r", "s", "p", "q")


def lattice_store(path, lattice: tuple[int, ...], *, chunks, shards=None, seed: int = 0):
    """A store holding only a complete 6D ``ltm`` (8 x 8 px) of random values."""
    from ltmstore.core import store as st

    values = np.random.default_rng(seed).random((8, 8, *lattice), dtype=np.float32)
    with st.new_store(path) as group:
        st.write_coord(group, "y", np.arange(8))
        st.write_coord(group, "x", np.arange(8))
        for dim, n in zip(DIMS_6D[2:], lattice, strict=True):
            st.write_coord(group, dim, np.linspace(-0.1, 0.1, n))
        st.create_variable(group, "ltm", DIMS_6D, values.shape, chunks=chunks,
                           shards=shards)[...] = values
        st.complete_stage(group, "truth", {})
    return path


def test_evaluate_6d_tasks_do_not_grow_with_either_lattice(tmp_path):
    """A 6D estimate in 2 x 2 x 2 x 2 lattice chunks, on a small and on a larger lattice,
    against truths on two other lattices (4 x 4 px chunks): the same graph every time."""
    counts = {}
    for est in ((4, 4, 2, 2), (8, 8, 4, 4)):
        store = lattice_store(tmp_path / f"e{est[0]}.zarr", est, shards=(8, 8, *est),
                              chunks=(8, 8, *(n // 2 for n in est)), seed=1)
        for ref in ((6, 6, 3, 3), (8, 8, 4, 4)):
            truth = lattice_store(tmp_path / f"t{est[0]}{ref[0]}.zarr", ref,
                                  chunks=(4, 4, *ref), seed=2)
            with local_tasks() as tasks:
                compare_stores(store, truth)
            counts[est, ref] = sum(tasks)
    # Measured: 35 each; before the fix 452, and 928 on the same lattice.
    assert len(set(counts.values())) == 1 and max(counts.values()) <= 38, counts


def test_at_cells_6d_graph_does_not_grow_with_the_lattices():
    """The graph of the interpolation alone (not computed) is the same for every lattice.
    Before the fix a 12 x 12 x 6 x 6 truth made the ``xr.dot`` chain split the pixels into
    single-pixel chunks: 458,170 tasks for 8 x 8 px (102 for an 8 x 8 x 4 x 4 truth)."""
    def lattice(shape, chunks):
        return xr.DataArray(da.ones((8, 8, *shape), chunks=chunks, dtype=np.float32),
                            dims=DIMS_6D, coords={d: np.linspace(0, 1, n) for d, n in
                                                  zip(DIMS_6D[2:], shape, strict=True)})
    counts = {}
    for est in ((4, 4, 2, 2), (8, 8, 4, 4)):
        estimate = lattice(est, (8, 8, *(n // 2 for n in est)))
        for ref in ((8, 8, 4, 4), (12, 12, 6, 6)):
            result = at_cells(estimate, lattice(ref, (4, 4, *ref)))
            counts[est, ref] = len(result.data.__dask_graph__())
    assert set(counts.values()) == {18}, counts  # measured: 18 each
    np.testing.assert_allclose(result.values, 1, rtol=1e-6)


def test_heldout_tasks_follow_the_tiles_it_reads(stores):
    """``ltm evaluate``'s held-out error reads whole sample tiles: one task per tile."""
    from ltmstore.judge.heldout import heldout_store

    counts = []
    for n in LATTICES:
        with local_tasks() as tasks:
            heldout_store(stores[n][0], max_pixels=2 * TILE * TILE, folds=2)
        counts.append(tasks)
    # Measured: [8, 5] (poses; 2 tiles of samples) on both lattices.
    assert counts[0] == counts[1] and sum(counts[0]) <= 14, counts


def test_relight_point_light_tasks_do_not_grow_with_the_lattice(stores):
    counts = []
    for n in LATTICES:
        with local_tasks() as tasks:
            relight(stores[n][0], [[0.01, 0.02]]).compute()
        counts.append(sum(tasks))
    assert counts[0] == counts[1] <= 25, counts  # measured: [8, 15] (4 cells' planes)


def test_relight_pattern_tasks_follow_the_cells_it_reads(stores):
    """A pattern over every cell reads each cell's plane of the light-major copy (one chunk
    per cell here): about two tasks per chunk read, nothing per cell pair."""
    for n in LATTICES:
        chunks = open_store(stores[n][0])["ltm_by_light"].data.npartitions
        assert chunks == n * n
        with local_tasks() as tasks:
            relight(stores[n][0], xr.DataArray(np.full((n, n), 1 / n**2), dims=("r", "s"))
                    ).compute()
        # Measured: [8, 137] on 8 x 8 (64 chunks), [8, 521] on 16 x 16 (256): 2 x chunks + 17.
        assert sum(tasks) <= 2.1 * chunks + 20, (n, tasks)


def test_export_and_compact_read_without_a_graph_per_cell(stores, tmp_path):
    counts = []
    for n in LATTICES:
        store = tmp_path / f"store{n}.zarr"
        shutil.copytree(stores[n][0], store)
        with local_tasks() as tasks:
            export(store, tmp_path / f"out{n}.ptm", fmt="ptm")
        counts.append(sum(tasks))
    # the fit reads the LTM by blocks (18 tasks: poses, chroma); the loss it prints relights
    # 16 lights (182 on 16 x 16 cells)
    assert max(counts) <= 210 and abs(counts[1] - counts[0]) <= 32, counts
    with local_tasks() as tasks:
        compact(store, keep_frames=True)
    assert sum(tasks) == 0, tasks  # measured: 0 (shards copied on a thread pool)
