"""Running a call on a worker thread with a CPU-time budget (bounded-parsing tests).

The budget is on the thread's CPU time (``time.thread_time``), which a busy machine does not
stretch: the work is counted, not the wall clock. The wall clock only catches a hang, after
``WALL_FACTOR`` times the budget (a loaded 2-core machine runs a thread at a fraction of a
core, never at a twentieth of one for long)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

#: the wall-clock bound of a call, in multiples of its CPU budget (a hang detector only)
WALL_FACTOR = 20.0


def on_a_thread(fn: Callable[..., Any], *args: Any, budget_s: float) -> tuple[float, Any]:
    """(CPU seconds the worker thread spent, result or the exception raised) of ``fn(*args)``
    run on a daemon worker thread; fails the test when the thread has not returned within
    ``WALL_FACTOR * budget_s`` wall seconds (the thread is left to finish)."""
    box: list[object] = []
    cpu: list[float] = []

    def run() -> None:
        start = time.thread_time()
        try:
            box.append(fn(*args))
        except BaseException as exc:  # handed back to the test
            box.append(exc)
        finally:
            cpu.append(time.thread_time() - start)

    thread = threading.Thread(target=run, daemon=True)
    start = time.perf_counter()
    thread.start()
    thread.join(WALL_FACTOR * budget_s)
    elapsed = time.perf_counter() - start
    assert not thread.is_alive(), f"still running after {elapsed:.1f} s on a worker thread"
    return cpu[0], box[0]
