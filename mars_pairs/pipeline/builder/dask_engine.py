"""The build on a Dask cluster: one task per chunk; each worker writes its chunk's shard.

``run_build(..., engine=DaskEngine(...))`` hands the chunks still to build to a Dask
cluster: an existing one (``scheduler="tcp://HOST:PORT"``) or a ``LocalCluster`` of
``workers`` processes with one thread each. A task receives the build config (paths or
GDAL URLs, never open handles) and one chunk (``engine.ChunkTask``), builds its samples with
the very ``worker.work`` the local engine runs, in a context opened by the very worker
initializer (``worker.open_context``) once per worker process (a worker plugin opens the
rasters and loads the numba kernels before the first task; a task that lands on a worker
whose context is for another config reopens it), and writes the chunk's shard into the
output folder (``engine.build_chunk``).

The driver receives only each chunk's rows and member locations (``engine.ChunkResult``, a
few hundred bytes a sample), keeps at most ``window`` chunks in flight and commits them in
chunk order, as the local engine does, so the shards, parts and manifest are byte-identical
to the local engine's, ``--resume`` works across engines (the chunk parts are the same
files), and the driver's memory is bounded by the window. The workers need write access to
the output folder, at the driver's path (a shared file system).

A worker that dies mid-task (killed, out of memory) costs a retry: the scheduler reruns
its tasks elsewhere (``distributed.scheduler.allowed-failures`` deaths per task, default
3, before the build fails with ``KilledWorker``), and the output is the same (the dead
worker's temporary shard is removed when the build ends). A task still running when the
build fails may yet rename its shard into place: a shard of an uncommitted chunk, which
``--resume`` writes again.
"""

from __future__ import annotations

import contextlib
import sys
import threading
import uuid
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from itertools import chain
from typing import Any

from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.builder.engine import ChunkResult, ChunkTask
from mars_pairs.pipeline.config import BuildConfig

_LOCK = threading.Lock()  # one chunk at a time per worker process (rasterio is not thread-safe)
PLUGIN_NAME = "mars-pairs-build"


def run_chunk(config: BuildConfig, task: ChunkTask | None) -> ChunkResult | None:
    """A Dask task: chunk ``task`` built and its shard written (``engine.build_chunk``).

    Runs in a Dask worker process; opens the worker's context for ``config`` unless it is
    already open for it (``task`` None: only that).
    """
    from mars_pairs.pipeline.builder import worker
    from mars_pairs.pipeline.builder.engine import build_chunk

    with _LOCK:
        if worker.current_config() != config:
            worker.open_context(config)
        return None if task is None else build_chunk(config, task)


def close_context() -> None:
    """Close this process's build context, if open (the worker plugin's teardown)."""
    from mars_pairs.pipeline.builder import worker

    with _LOCK:
        worker.close_context()


def _plugin(config: BuildConfig) -> Any:
    """A worker plugin that opens the context (which loads the kernels) when a worker
    starts, including a worker that replaces a dead one."""
    from distributed.diagnostics.plugin import WorkerPlugin

    class WarmWorker(WorkerPlugin):
        def __init__(self) -> None:
            self.config = config

        def setup(self, worker: Any) -> None:
            from mars_pairs.runtime import configure_process

            configure_process()
            run_chunk(self.config, None)

        def teardown(self, worker: Any) -> None:
            close_context()

    return WarmWorker()


@dataclass(frozen=True)
class DaskEngine:
    """Where and how a build runs on Dask."""

    scheduler: str | None = None  # "tcp://HOST:PORT" of a running cluster; None: a LocalCluster
    workers: int = 1  # LocalCluster worker processes (one thread each)
    window: int = 0  # chunks in flight; 0: 2 per worker thread + 2
    announce: bool = True  # print the dashboard address on stderr

    def run(self, config: BuildConfig, chunks: Iterable[ChunkTask]) -> Iterator[ChunkResult]:
        """The ``builder.engine.Engine`` contract: one task per chunk, whose
        worker writes the shard; results in chunk order.

        ``chunks`` may be a lazy iterator: it is pulled one chunk at a time as the window
        frees, never listed; no cluster starts when it is empty."""
        pending = iter(chunks)
        first = next(pending, None)
        if first is None:
            return
        with self._client() as client:
            if self.announce:
                print(f"dask dashboard: {client.dashboard_link}", file=sys.stderr, flush=True)
            client.register_plugin(_plugin(config), name=PLUGIN_NAME)
            threads = sum(client.nthreads().values()) or 1
            window = self.window or 2 * threads + 2
            run = uuid.uuid4().hex[:8]
            todo = chain([first], pending)
            flight: deque[Any] = deque()

            def submit() -> None:
                for task in todo:
                    key = f"chunk-{run}-{task.index}"
                    flight.append(client.submit(run_chunk, config, task, key=key, pure=False))
                    return

            try:
                for _ in range(window):
                    submit()
                while flight:
                    result = flight.popleft().result()
                    submit()
                    yield result
            finally:
                for future in flight:
                    future.cancel()
                with contextlib.suppress(Exception):
                    client.unregister_worker_plugin(PLUGIN_NAME)

    @contextlib.contextmanager
    def _client(self) -> Iterator[Any]:
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise ConfigError(
                "--engine dask: dask.distributed is not installed; pip install 'mars-pairs[dask]'"
            ) from None
        if self.scheduler:
            try:
                client = Client(self.scheduler, timeout="20s")
            except OSError as exc:
                raise ConfigError(f"--scheduler: cannot reach {self.scheduler}: {exc}") from None
            with client:
                yield client
            return
        import dask

        # workers without Dask's MALLOC_TRIM_THRESHOLD_ (see mars_pairs.allocator)
        with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}):
            cluster = LocalCluster(
                n_workers=self.workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=":0",
                host="127.0.0.1",
            )
        with cluster, Client(cluster) as client:
            yield client
