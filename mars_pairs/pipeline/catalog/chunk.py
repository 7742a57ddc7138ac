"""What a worker runs for one chunk of the catalogue: each label's catalogue row
(``entry.catalog_entry``) or its failure row, in label order; the rows go back to the driver,
which writes the chunk's parts (a row is a few KB: the footprint's WKB)."""

from __future__ import annotations

import os
import socket
import time
from pathlib import Path

from mars_pairs.errors import StageError
from mars_pairs.pipeline.builder import worker
from mars_pairs.pipeline.builder.engine import ChunkResult, ChunkTask, Outcome
from mars_pairs.pipeline.catalog.entry import catalog_entry
from mars_pairs.pipeline.config import BuildConfig


def catalog_chunk(config: BuildConfig, task: ChunkTask) -> ChunkResult:
    """The catalogue rows of ``task``'s labels, built in this process's context
    (``worker.context``: WorkerStartError when it could not open); a label that fails is its
    failure row (``worker.failure_row``, the stage named), never an exception."""
    start = time.perf_counter()
    ctx = worker.context()
    outcomes: list[Outcome] = []
    for label in task.labels:
        try:
            row = catalog_entry(Path(label), ctx)
        except StageError as exc:
            outcomes.append(
                Outcome("fail", label, row=worker.failure_row(label, exc.stage, exc.error))
            )
            continue
        except Exception as exc:  # a bug must not stop the catalogue: a failure row
            outcomes.append(Outcome("fail", label, row=worker.failure_row(label, "internal", exc)))
            continue
        outcomes.append(Outcome("ok", label, row["key"], row))
    return ChunkResult(
        task.index,
        tuple(outcomes),
        (),  # no shard
        time.perf_counter() - start,
        f"{socket.gethostname()}:{os.getpid()}",
    )
