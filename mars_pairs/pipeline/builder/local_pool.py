"""The local engine: worker processes on this machine, started early, a bounded window.

- Start-up overlaps the driver's planning: :class:`LocalPool` starts its processes when the
  build starts, and each opens the rasters and the PLACES table while the driver lists the
  labels and clears the output.
- Processes come from a fork server that imported the build's modules once (numba, GDAL,
  pyarrow), so a worker does not import them again; each worker is a fork of that clean
  server, never of the driver, whose numba OpenMP threads make forking unsafe. Where there is
  no fork server (Windows), workers are spawned. A worker takes the driver's build settings
  and the process defaults (:mod:`mars_pairs.runtime`) before it opens its context.
- A build hands the pool whole chunks (``run``, the ``pipeline.builder.engine.Engine`` contract): a
  worker builds a chunk's samples and writes its shard itself, and returns only rows; at most
  2 chunks per worker are in flight, and results come back in chunk order. (``results``
  hands out single labels, at most ``window`` in flight, 4 per worker, results in order.)
- A worker that dies (killed, out of memory, a crash) fails the build at once, naming a
  label in flight; the chunks already written stay, and ``--resume`` goes on from there.
- The workers die with their build. Each watches the driver: a thread waits on the pipe only
  the driver holds (``multiprocessing.parent_process().sentinel``) and ends the worker when
  it closes, whatever ended the driver (SIGKILL, SIGTERM, a crash); the fork server then
  exits (its last client gone), and the resource tracker after it. On an error or Ctrl-C in
  the driver the pool kills its workers instead of waiting for their samples. The fork
  server and its workers ignore SIGINT (the server starts with it ignored, before its
  imports): Ctrl-C is the driver's to handle, and prints no worker or server traceback. The
  locks a worker makes are anonymous (``_anonymous_locks``), so a killed worker leaves no
  semaphore for the resource tracker to warn about: a Ctrl-C prints the tool's line only.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import signal
import sys
import threading
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from itertools import islice
from multiprocessing.context import BaseContext
from multiprocessing.process import BaseProcess
from typing import Any

import mars_pairs.runtime as runtime
from mars_pairs.errors import WorkerDiedError, WorkerStartError
from mars_pairs.pipeline.builder import worker
from mars_pairs.pipeline.builder.engine import ChunkResult, ChunkTask, build_chunk
from mars_pairs.pipeline.config import BuildConfig

_PRELOAD = ["mars_pairs.pipeline.builder.worker", "mars_pairs.pipeline.builder.engine"]


def worker_context() -> BaseContext:
    """A fork server preloaded with the build's modules, or spawn where there is none."""
    if "forkserver" not in mp.get_all_start_methods():
        return mp.get_context("spawn")
    ctx = mp.get_context("forkserver")
    ctx.set_forkserver_preload(_PRELOAD)  # used when this process starts its server
    return ctx


def started_context(preload: Sequence[str] = ()) -> BaseContext:
    """:func:`worker_context` with its fork server running: started now if it is not yet,
    preloading the build's modules and ``preload`` (modules a caller's workers run)."""
    ctx = worker_context()
    if preload and ctx.get_start_method() == "forkserver":
        ctx.set_forkserver_preload([*_PRELOAD, *preload])
    _start_server(ctx)
    return ctx


def _start_server(ctx: BaseContext) -> None:
    """Start the fork server now (if ``ctx`` uses one and it is not running) with SIGINT
    ignored, which it and every worker it forks inherit through exec and fork (a Ctrl-C
    while the server imports the build's modules would print its traceback and break the
    pool). The driver ignores SIGINT for the few milliseconds of the server's fork and exec
    (only from the main thread, the one that may set signal handlers)."""
    if ctx.get_start_method() != "forkserver":
        return
    from multiprocessing import forkserver, resource_tracker

    with _safe_path():
        resource_tracker.ensure_running()  # also a `python -c`: started without the cwd
        if threading.current_thread() is not threading.main_thread():
            forkserver.ensure_running()
            return
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
        try:
            forkserver.ensure_running()
        finally:
            signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def _safe_path() -> Iterator[None]:
    """The environment of a helper process this block execs (the fork server, the resource
    tracker: ``python -c ...``, which would put the current folder first on ``sys.path``, so
    a user's ``concurrent.py`` there would shadow the standard library in every worker):
    ``PYTHONSAFEPATH=1`` (no current folder) and ``PYTHONPATH`` the driver's own ``sys.path``
    without the current folder (the fork server of Python 3.11 ignores the driver's path)."""
    cwd = os.getcwd()
    path = [p for p in sys.path if p and os.path.abspath(p) != cwd]
    saved = {k: os.environ.get(k) for k in ("PYTHONSAFEPATH", "PYTHONPATH")}
    os.environ["PYTHONSAFEPATH"] = "1"
    os.environ["PYTHONPATH"] = os.pathsep.join(path)
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


@contextlib.contextmanager
def _sigint_deferred() -> Iterator[None]:
    """Hold a Ctrl-C (SIGINT) that arrives in the block until its end, then raise its
    KeyboardInterrupt; only in the main thread (elsewhere, the block runs as it is)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt


def _exit_with_driver() -> None:
    """End this worker process as soon as the driver that started it is gone: a daemon
    thread waits on the pipe whose other end only the driver holds."""
    parent = mp.parent_process()
    if parent is None:
        return

    def watch() -> None:
        from multiprocessing.connection import wait

        wait([parent.sentinel])  # ready (at EOF) once the driver process has ended
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-driver", daemon=True).start()


def _anonymous_locks() -> None:
    """Make the locks this worker creates (numba's threading-layer lock, made when its first
    parallel kernel runs) anonymous semaphores, unlinked as they are made, rather than named
    ones registered with the resource tracker: a worker killed on an error or a Ctrl-C then
    leaves no semaphore behind, and the tracker prints no "leaked semaphore" warning. A
    worker starts no process, so its default start method serves only these locks."""
    if "fork" in mp.get_all_start_methods():
        mp.set_start_method("fork", force=True)


def start_worker_process(settings: dict[str, str]) -> None:
    """The start of a worker of :func:`started_context`: watch the driver, take the driver's
    build ``settings`` (``runtime.build_settings``: a fork server's workers inherit the
    server's environment, from when it started) and set the process defaults."""
    _exit_with_driver()
    _anonymous_locks()
    runtime.take_build_settings(settings)
    runtime.configure_process()


def _start_worker(config: BuildConfig, settings: dict[str, str]) -> None:
    """A build worker's initializer: :func:`start_worker_process`, then open the build
    context."""
    start_worker_process(settings)
    worker.open_context(config)


class LocalPool:
    """``workers`` processes building samples for ``config``; a context manager.

    A ``concurrent.futures`` process pool: a worker that dies fails the build with
    WorkerDiedError (rerun with ``--resume``) where ``multiprocessing.Pool`` would wait for
    its lost task for ever.
    """

    def __init__(self, config: BuildConfig, workers: int, window: int = 0) -> None:
        self.workers = workers
        self.window = window or 4 * workers
        ctx = started_context()
        self._pool = ProcessPoolExecutor(
            workers,
            mp_context=ctx,
            initializer=_start_worker,
            initargs=(config, runtime.build_settings()),  # this build's, not the server's
        )
        try:
            with _sigint_deferred():  # a Ctrl-C mid-start would orphan a starting worker
                for _ in range(workers):  # start them all now (the pool starts one per task)
                    self._pool.submit(_started)
        except BaseException:
            self.close(abort=True)
            raise

    def results(self, labels: Iterable[str]) -> Iterator[tuple[str, Any]]:
        """Every label's result, in order; WorkerStartError (once) if a worker could not
        open the inputs, WorkerDiedError if one died."""
        todo = iter(labels)
        flight: deque[tuple[str, Future[tuple[str, Any]]]] = deque()

        def submit(count: int) -> None:
            for label in islice(todo, count):
                flight.append((label, self._pool.submit(worker.work, label)))

        label = "the first label"
        try:  # a dead worker breaks the pool: submitting raises as well as waiting
            submit(self.window)
            while flight:
                label, future = flight.popleft()
                status, result = future.result()
                submit(1)
                if status == "start":
                    raise WorkerStartError(result)
                yield status, result
        except BrokenProcessPool:
            raise WorkerDiedError(
                f"a build worker process died (killed, out of memory or crashed) while "
                f"{label} or a label near it was in flight; rerun with --resume"
            ) from None

    def run(self, config: BuildConfig, chunks: Iterable[ChunkTask]) -> Iterator[ChunkResult]:
        """The ``builder.engine.Engine`` contract: each chunk built and its
        shard written by one worker (``engine.build_chunk``), results in chunk order, at most
        ``2 * workers`` chunks in flight; WorkerStartError if a worker could not open the
        inputs, WorkerDiedError if one died. ``config`` is the pool's."""
        todo = iter(chunks)
        flight: deque[tuple[ChunkTask, Future[ChunkResult]]] = deque()

        def submit(count: int) -> None:
            for task in islice(todo, count):
                flight.append((task, self._pool.submit(build_chunk, config, task)))

        task = None
        try:
            submit(2 * self.workers)
            while flight:
                task, future = flight.popleft()
                result = future.result()
                submit(1)
                yield result
        except BrokenProcessPool:
            where = f"chunk {task.index} ({task.labels[0]} ...)" if task else "the first chunk"
            raise WorkerDiedError(
                f"a build worker process died (killed, out of memory or crashed) while "
                f"{where} or a chunk near it was in flight; rerun with --resume"
            ) from None

    def close(self, abort: bool = False) -> None:
        """Let the workers finish and exit; with ``abort`` (an error, Ctrl-C), drop what is
        queued and kill the workers rather than wait for the samples they are building."""
        if abort:
            for process in pool_processes(self._pool):
                process.kill()
        self._pool.shutdown(wait=True, cancel_futures=abort)

    def __enter__(self) -> LocalPool:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        self.close(abort=exc_type is not None)


def pool_processes(pool: ProcessPoolExecutor) -> list[BaseProcess]:
    """The worker processes of ``pool``: the one private attribute of the standard library
    this package reads (``ProcessPoolExecutor._processes``, pid -> process, CPython 3.10 to
    3.13; 3.14 adds the public ``kill_workers``). ``tests/pipeline/test_local_pool.py``
    fails when it changes; a pool without it gives [] (the pool then waits for its workers
    instead of killing them)."""
    processes = getattr(pool, "_processes", None)
    return list(processes.values()) if isinstance(processes, dict) else []


def _started() -> None:
    """A task that only makes the pool start a worker (which opens its context)."""
