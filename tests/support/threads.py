"""Running a call on a worker thread with a time budget (bounded-parsing tests)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any


def on_a_thread(fn: Callable[..., Any], *args: Any, budget_s: float) -> tuple[float, Any]:
    """(seconds, result or the exception raised) of ``fn(*args)`` run on a daemon worker
    thread; fails the test when it has not returned within ``budget_s`` (the thread is left
    to finish)."""
    box: list[object] = []

    def run() -> None:
        try:
            box.append(fn(*args))
        except BaseException as exc:  # handed back to the test
            box.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    start = time.perf_counter()
    thread.start()
    thread.join(budget_s)
    elapsed = time.perf_counter() - start
    assert not thread.is_alive(), f"still running after {elapsed:.1f} s on a worker thread"
    return elapsed, box[0]
