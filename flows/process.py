"""``process_acquisition``: ingest, reconstruct (Dask inside the task), render previews."""

from __future__ import annotations

from prefect import flow, task

from ltmstore.stages.ingest import ingest
from ltmstore.stages.preview import render_previews
from ltmstore.stages.reconstruct import reconstruct


def transient_io(task, task_run, state) -> bool:
    """Retry only on operating-system I/O errors (a flaky share, a busy file), never on a user
    mistake or a full disk (reported as :class:`~ltmstore.core.errors.LtmError`)."""
    return isinstance(state.result(raise_on_failure=False), OSError)


@task(retries=2, retry_delay_seconds=2, retry_condition_fn=transient_io)
def ingest_task(acquisition: str, store: str, overwrite: bool) -> dict:
    return ingest(acquisition, store, overwrite=overwrite)


@task(retries=2, retry_delay_seconds=2, retry_condition_fn=transient_io)
def reconstruct_task(store: str, options: dict, scheduler: str | None) -> dict:
    return reconstruct(store, scheduler=scheduler, **options)


@task(retries=2, retry_delay_seconds=2, retry_condition_fn=transient_io)
def preview_task(store: str, out_dir: str) -> dict:
    return render_previews(store, out_dir)


@flow(name="process-acquisition")
def process_acquisition(acquisition: str, store: str, *, preview_dir: str | None = None,
                        scheduler: str | None = None, overwrite: bool = False,
                        reconstruct_options: dict | None = None) -> dict:
    """Acquisition folder to a reconstructed store (and previews when ``preview_dir``)."""
    options = {"overwrite": overwrite, **(reconstruct_options or {})}
    report = {"ingest": ingest_task(acquisition, store, overwrite)}
    report["reconstruct"] = reconstruct_task(store, options, scheduler)
    if preview_dir:
        report["previews"] = preview_task(store, preview_dir)
    return report
