"""What a build worker process runs: its context, opened once, and one label -> one result.

Shared by the local pool (``pipeline.builder.local_pool``), the in-process build (one worker) and
the Dask engine. A result is ("ok", Sample), ("fail", failure row) or ("start", message)
when the process could not open its context.
"""

from __future__ import annotations

import contextlib
import re
from pathlib import Path
from typing import Any

from mars_pairs.allocator import reuse_freed_memory
from mars_pairs.errors import MarsPairsError, StageError, WorkerStartError
from mars_pairs.kernels.warm import warm_kernels
from mars_pairs.pipeline.config import BuildConfig
from mars_pairs.pipeline.sample.build_sample import Sample, build_sample
from mars_pairs.pipeline.sample.context import SampleContext
from mars_pairs.store.manifest import check_row

#: The longest sample key: ``<key>.<member>`` must fit tar's 100-byte USTAR name field.
MAX_KEY_LENGTH = 80
_KEY = re.compile(r"[a-z0-9_\-]+", re.ASCII)

# One per worker process (a pool initializer cannot hand its worker anything else).
_CONTEXT: SampleContext | None = None
_START_ERROR: str | None = None  # why the process could not open its context, if it could not


def open_context(config: BuildConfig) -> None:
    """Open this process's context for ``config``. Never raises: a pool respawns workers whose
    initializer raised, for ever; the error is kept and reported by the first task.

    The process's environment is set up before (``mars_pairs.runtime``)."""
    global _CONTEXT, _START_ERROR
    close_context()
    reuse_freed_memory()  # a worker process: keep freed blocks for the next sample
    try:
        _CONTEXT = SampleContext.open(config)
        _START_ERROR = None
    except Exception as exc:
        own = isinstance(exc, MarsPairsError)
        _START_ERROR = str(exc) if own else f"{type(exc).__name__}: {exc}"
        return
    # while the driver still plans, so the first sample does not load them (only a head
    # start: if it fails, the first sample loads what is missing)
    with contextlib.suppress(Exception):
        warm_kernels()


def use_context(context: SampleContext | None) -> None:
    """Make ``context`` this process's (the one-worker build opens its own)."""
    global _CONTEXT
    _CONTEXT = context


def current_config() -> BuildConfig | None:
    """The config this process's context was opened for."""
    return None if _CONTEXT is None else _CONTEXT.config


def context() -> SampleContext:
    """This process's open context; WorkerStartError (with why it could not open) if none."""
    if _CONTEXT is None:
        raise WorkerStartError(_START_ERROR or "worker context not opened")
    return _CONTEXT


def close_context() -> None:
    """Close this process's context, if open."""
    global _CONTEXT
    if _CONTEXT is not None:
        _CONTEXT.close()
        _CONTEXT = None


def work(label: str) -> tuple[str, Any]:
    """Build one sample in this process: ("ok", Sample), ("fail", failure row), or
    ("start", message) when the process could not open its context."""
    if _CONTEXT is None:
        return "start", _START_ERROR or "worker context not opened"
    try:
        sample = build_sample(Path(label), _CONTEXT)
        check_record(sample)
        return "ok", sample
    except StageError as exc:
        return "fail", failure_row(label, exc.stage, exc.error)
    except Exception as exc:
        return "fail", failure_row(label, "internal", exc)


def check_record(sample: Sample) -> None:
    """StageError("record") unless the sample's key makes valid tar member names and its row
    fits the manifest schema (``store.manifest.check_row``: a sol too large for int32; a key
    with '/', a 300-char id)."""
    key = sample.key
    try:
        if not _KEY.fullmatch(key) or len(key) > MAX_KEY_LENGTH:
            raise ValueError(
                f"sample key {key[:100]!r} (from the product id) must be 1 to {MAX_KEY_LENGTH} "
                "characters of a-z, 0-9, '_' and '-'"
            )
        check_row(sample.row)
    except ValueError as exc:
        raise StageError("record", exc) from None


def failure_row(label: str, stage: str, error: BaseException) -> dict[str, Any]:
    """A row of failures.parquet."""
    return {
        "product_id": Path(label).stem.upper(),
        "path": label,
        "stage": stage,
        "error_type": type(error).__name__,
        "message": str(error),
    }
