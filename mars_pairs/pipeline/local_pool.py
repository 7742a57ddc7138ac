"""The local engine: worker processes on this machine, started early, a bounded window.

- Start-up overlaps the driver's planning: :class:`LocalPool` starts its processes when the
  build starts, and each opens the rasters and the PLACES table while the driver lists the
  labels and clears the output.
- Processes come from a fork server that imported the build's modules once (numba, GDAL,
  pyarrow: ~0.7 s a process when each spawned worker imported them itself); each worker is
  a fork of that clean server, never of the driver, whose numba OpenMP threads make forking
  unsafe. Where there is no fork server (Windows), workers are spawned.
- At most ``window`` labels are in flight (4 per worker): the driver's memory does not grow
  with the label count, and results come back in label order.
"""

from __future__ import annotations

import multiprocessing as mp
from collections import deque
from collections.abc import Iterable, Iterator
from itertools import islice
from multiprocessing.context import BaseContext
from typing import Any

from mars_pairs.pipeline import worker
from mars_pairs.pipeline.config import BuildConfig

_PRELOAD = ["mars_pairs.pipeline.worker"]


def worker_context() -> BaseContext:
    """A fork server preloaded with the build's modules, or spawn where there is none."""
    if "forkserver" not in mp.get_all_start_methods():
        return mp.get_context("spawn")
    ctx = mp.get_context("forkserver")
    ctx.set_forkserver_preload(_PRELOAD)  # used when this process starts its server
    return ctx


class LocalPool:
    """``workers`` processes building samples for ``config``; a context manager."""

    def __init__(self, config: BuildConfig, workers: int, window: int = 0) -> None:
        self.workers = workers
        self.window = window or 4 * workers
        self._pool = worker_context().Pool(
            workers, initializer=worker.open_context, initargs=(config,)
        )

    def results(self, labels: Iterable[str]) -> Iterator[tuple[str, Any]]:
        """Every label's result, in order; WorkerStartError (once) if a worker could not
        open the inputs."""
        todo = iter(labels)
        flight: deque[Any] = deque(
            self._pool.apply_async(worker.work, (label,)) for label in islice(todo, self.window)
        )
        while flight:
            status, result = flight.popleft().get()
            for label in islice(todo, 1):
                flight.append(self._pool.apply_async(worker.work, (label,)))
            if status == "start":
                raise worker.WorkerStartError(result)
            yield status, result

    def close(self, abort: bool = False) -> None:
        """Let the workers finish and exit; with ``abort``, kill them (what is in flight is
        dropped)."""
        if abort:
            self._pool.terminate()
        else:
            self._pool.close()
        self._pool.join()

    def __enter__(self) -> LocalPool:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        self.close(abort=exc_type is not None)
