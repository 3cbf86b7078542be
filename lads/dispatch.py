"""How a build's items are spread over workers: in-process, joblib (loky) or a Dask
cluster, `batch` items per task; rows come back as items finish."""

from __future__ import annotations

from lads.built_tree import BuildPlan
from lads.config import PipelineConfig
from lads.errors import BuildError
from lads.frame import Item
from lads.worker import process_items

GPU_BATCH = 8  # frames per forward pass on a GPU (~0.3 GB of activations at 64 x 2048)


def dispatch(  # type: ignore[no-untyped-def]
    todo: list[Item],
    plan: BuildPlan,
    jobs: int,
    backend: str,
    scheduler: str | None,
    batch: int = 1,
):
    """Yield manifest rows as items finish (any order); `batch` items per task."""
    tasks = [todo[k : k + batch] for k in range(0, len(todo), max(batch, 1))]
    if jobs == 1 and backend == "loky":
        for task in tasks:
            yield from process_items(task, plan)
        return
    if backend == "dask":
        from distributed import Client, as_completed

        try:
            client = Client(scheduler) if scheduler else Client(processes=False)
        except (OSError, TimeoutError) as exc:
            raise BuildError(
                f"--scheduler {scheduler}: cannot reach the Dask scheduler ({exc}); start it "
                "(`dask scheduler`) or pass the address it prints."
            ) from None
        try:
            # Plain futures: joblib's dask backend kept the client process busy, which on a
            # small machine took a core from the workers (2 workers ran slower than 1).
            shared = client.scatter(plan, broadcast=True)
            futures = client.map(process_items, tasks, plan=shared, pure=False)
            for future in as_completed(futures):
                yield from future.result()
        finally:
            client.close()
        return
    from joblib import Parallel, delayed, parallel_config

    # One thread per worker: the workers are the parallelism, and a fixed thread count
    # keeps float reductions in a fixed order.
    with parallel_config(backend=backend, n_jobs=jobs, inner_max_num_threads=1):
        for rows in Parallel(return_as="generator_unordered")(
            delayed(process_items)(task, plan) for task in tasks
        ):
            yield from rows


def check_backend(backend: str, scheduler: str | None) -> None:
    """BuildError, before anything is written, for a backend that cannot run here: dask
    without dask.distributed installed, or a scheduler address without the dask backend."""
    if scheduler is not None and backend != "dask":
        raise BuildError(f"--scheduler {scheduler} is an address for --backend dask; pass both.")
    if backend == "dask":
        try:
            import distributed  # noqa: F401
        except ImportError as exc:
            raise BuildError(
                "--backend dask needs dask.distributed: pip install 'lads[dask]'."
            ) from exc


def default_batch(pipeline: PipelineConfig) -> int:
    """Frames per task: GPU_BATCH when a stage runs on a GPU (its batched forward pass),
    else 1 (on a CPU a batch saves nothing and delays the progress bar)."""
    on_gpu = any(str(s.params.get("device", "cpu")).startswith("cuda") for s in pipeline.stages)
    return GPU_BATCH if on_gpu else 1
