"""Exception types. Every error a user can cause names the file and the field at fault."""

from __future__ import annotations


class MarsPairsError(Exception):
    """Base class of every error mars-pairs raises on bad input."""


class LabelError(MarsPairsError):
    """A PDS label is missing, unreadable, or lacks a required field.

    The message always names the file and, where one is at fault, the field.
    """

    def __init__(self, path: object, field: str | None, reason: str) -> None:
        self.path = str(path)
        self.field = field
        self.reason = reason
        where = f"{self.path}: {field}" if field else self.path
        super().__init__(f"{where}: {reason}")


class ImageError(MarsPairsError):
    """A product's image is missing, undecodable, truncated, or does not fit its label's grid;
    the message names the image file (and both sizes for a size mismatch)."""


class PlacesError(MarsPairsError):
    """A PLACES table is unreadable, or has no row that can place an observation."""


class TerrainError(MarsPairsError):
    """A DEM or orthoimage cannot serve a request (no CRS, observer off the raster, nodata)."""


class CoverageError(TerrainError):
    """An orbital chip has too little data (``chips.min_coverage``): the message names the
    raster, its extent and the chip's bounds."""


class TerrainLabelError(MarsPairsError):
    """A terrain label (a ground image's class mask) is missing for a product, does not fit
    its image, or holds a value its class table does not know; the message names the file."""


class ConfigError(MarsPairsError):
    """A build configuration is invalid; the message names the key and what was expected.

    ``line``: (line, column), 1-based, of the key at fault in the config's YAML, when known
    (``load_config`` puts it after the file's name: ``c.yaml:5:3: geometry.radius: ...``)."""

    def __init__(self, message: str, *, line: tuple[int, int] | None = None) -> None:
        super().__init__(message)
        self.line = line

    def __reduce__(self) -> tuple[object, ...]:  # pickles with its line
        return (_config_error, (str(self), self.line))


def _config_error(message: str, line: tuple[int, int] | None) -> ConfigError:
    return ConfigError(message, line=line)


class DatasetError(MarsPairsError):
    """A built dataset is damaged: the message names the file at fault and what in it.

    ``path``: the file (a shard, manifest.parquet, dataset.json, ...); ``member``: what in it
    is at fault: a shard's member (``<key>.<field>``), a manifest column or key, a
    dataset.json key (None: the whole file); ``reason``: what is wrong.

    ``DatasetError(message)`` (one argument: how a DataLoader re-raises a worker's exception,
    the worker's traceback as the message) keeps the type; its ``path`` is then "" and its
    ``reason`` the message.
    """

    def __init__(self, path: object, member: str | None = None, reason: str | None = None) -> None:
        if reason is None and member is None:  # one message (a DataLoader's re-raise)
            self.path, self.member, self.reason = "", None, str(path)
            super().__init__(self.reason)
            return
        self.path = str(path)
        self.member = member
        self.reason = reason or ""
        where = f"{self.path}: {member}" if member else self.path
        super().__init__(f"{where}: {self.reason}")

    def __reduce__(self) -> tuple[type, tuple[object, ...]]:  # pickles with its fields
        if self.path or self.member is not None:
            return type(self), (self.path, self.member, self.reason)
        return type(self), (self.reason,)


class FetchError(MarsPairsError):
    """A download or archive index failed; the message names the URL (or index file) at fault."""

    def __init__(self, url: object, reason: str) -> None:
        self.url = str(url)
        self.reason = reason
        super().__init__(f"{self.url}: {reason}")


class StorageError(MarsPairsError):
    """Object storage failed a request (unreachable, no credentials, no such bucket, refused):
    the message names the URL and the file system's reason."""

    def __init__(self, url: object, reason: str) -> None:
        self.url = str(url)
        self.reason = reason
        super().__init__(f"{self.url}: {reason}")

    def __reduce__(self) -> tuple[type, tuple[object, ...]]:  # pickles with its fields
        return type(self), (self.url, self.reason)


class MissingMemberError(DatasetError, KeyError):
    """A sample has no member of the requested field (also a KeyError, as before)."""

    def __str__(self) -> str:  # KeyError would quote the message
        return Exception.__str__(self)


class UsageError(MarsPairsError):
    """A caller's misuse: a bad argument or command-line option (the CLI exits with 2)."""


class ArgumentError(UsageError, ValueError, TypeError):
    """A function argument of the wrong type or value; the message names the argument.

    Also a ValueError and a TypeError, which is what code written against the earlier
    releases catches."""


class SampleKeyError(UsageError, KeyError):
    """No sample with the requested key (a KeyError too)."""

    def __str__(self) -> str:  # KeyError would quote the message
        return Exception.__str__(self)


class SampleIndexError(UsageError, IndexError):
    """A dataset index out of range (an IndexError, so ``for s in ds`` still ends)."""


class StageError(MarsPairsError):
    """A failure at a named stage of one observation; becomes a row of failures.parquet."""

    def __init__(self, stage: str, error: BaseException) -> None:
        self.stage, self.error = stage, error
        super().__init__(f"{stage}: {type(error).__name__}: {error}")


class WorkerStartError(MarsPairsError):
    """A worker could not open the build's inputs (the message is the worker's error)."""


class WorkerDiedError(MarsPairsError):
    """A build worker process died (killed, out of memory, crashed) with samples in flight."""


class DuplicateKeyError(MarsPairsError):
    """Two labels give the same sample key (the same product id): the first one is kept."""


class BuildError(MarsPairsError):
    """A strict build stopped at its first failure."""


class ContentError(FetchError):
    """A downloaded file is not what its kind requires; names the URL (or file) and why."""


class FolderLockedError(MarsPairsError):
    """Another build, ``--resume`` or ``--append`` holds the output folder's lock."""
