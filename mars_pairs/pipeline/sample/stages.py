"""Stage names and timings of one sample build; StageError names the failing stage."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager


class Stages:
    """Names the running stage (for failure rows) and times each one."""

    def __init__(self) -> None:
        self.name = "label"
        self.seconds: dict[str, float] = {}

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        self.name = name
        start = time.perf_counter()
        yield
        self.seconds[name] = time.perf_counter() - start
