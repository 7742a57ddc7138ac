"""The build on a Dask cluster: one task per chunk, results written by the driver in order.

``run_build(..., engine=DaskEngine(...))`` hands the chunks still to build to a Dask
cluster: an existing one (``scheduler="tcp://HOST:PORT"``) or a ``LocalCluster`` of
``workers`` processes with one thread each. A task receives the build config (paths or
GDAL URLs, never open handles) and the label paths of one chunk, and returns the chunk's
results: the very ``worker.work`` results the local engine's pool returns, built by the very
worker initializer (``worker.open_context``) in each Dask worker process, once (a worker
plugin opens the rasters and loads the numba kernels before the first task; a task that
lands on a worker whose context is for another config reopens it).

The driver keeps at most ``window`` chunks in flight and writes them in chunk order with
the local engine's writer, so the shards, parts and manifest are byte-identical to the
local engine's, ``--resume`` works across engines (the chunk parts are the same files),
and the driver's memory is bounded by the window, not by the number of chunks. The
trade-off: chunk bytes travel to the driver (~1 MB per 512 px sample), which caps a
build at the driver's network and disk (hundreds of samples/s); the workers need read
access to the inputs only, never write access to the output.

A worker that dies mid-task (killed, out of memory) costs a retry: the scheduler reruns
its tasks elsewhere (``distributed.scheduler.allowed-failures`` deaths per task, default
3, before the build fails with ``KilledWorker``), and the output is the same.
"""

from __future__ import annotations

import contextlib
import sys
import threading
import uuid
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from itertools import chain
from typing import Any

from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.config import BuildConfig

_LOCK = threading.Lock()  # one chunk at a time per worker process (rasterio is not thread-safe)
PLUGIN_NAME = "mars-pairs-build"


def build_chunk(config: BuildConfig, labels: Sequence[str]) -> list[tuple[str, Any]]:
    """A Dask task: the local engine's worker results for ``labels``, in order.

    Runs in a Dask worker process; opens the worker's context for ``config`` unless it is
    already open for it.
    """
    from mars_pairs.pipeline import worker

    with _LOCK:
        if worker.current_config() != config:
            worker.open_context(config)
        return [worker.work(label) for label in labels]


def close_context() -> None:
    """Close this process's build context, if open (the worker plugin's teardown)."""
    from mars_pairs.pipeline import worker

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
            build_chunk(self.config, [])

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

    def results(
        self, config: BuildConfig, chunks: Iterable[Sequence[str]]
    ) -> Iterator[tuple[str, Any]]:
        """Every label's result, chunk after chunk, in order (as the local engine's).

        ``chunks`` may be a lazy iterator: it is pulled one chunk at a time as the window
        frees, never listed; no cluster starts when it is empty."""
        from mars_pairs.pipeline.worker import WorkerStartError

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
            todo = enumerate(chain([first], pending))
            flight: deque[Any] = deque()

            def submit() -> None:
                for k, labels in todo:
                    flight.append(
                        client.submit(
                            build_chunk, config, list(labels), key=f"chunk-{run}-{k}", pure=False
                        )
                    )
                    return

            try:
                for _ in range(window):
                    submit()
                while flight:
                    future = flight.popleft()
                    batch = future.result()
                    submit()
                    for status, result in batch:
                        if status == "start":
                            raise WorkerStartError(result)
                        yield status, result
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
