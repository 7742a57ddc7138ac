"""Column names that cannot be confused, and the old names kept readable for one release.

``elevation`` (metres above the areoid) sat beside ``elevation_deg`` (the camera's angle
above the horizon); it is now ``elevation_m``. Reading ``elevation`` still works, with a
DeprecationWarning: as a manifest column (``Manifest.to_table(columns=[...])``) and as a
sample's ``meta["elevation"]``. Datasets built before the rename read with the new name.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable, Sequence
from typing import Any

import pyarrow as pa

#: old name -> new name (to be removed in the release after 0.2)
RENAMED = {"elevation": "elevation_m"}

_OLD = {new: old for old, new in RENAMED.items()}


def warn_renamed(old: str, stacklevel: int = 3) -> None:
    warnings.warn(
        f"the column {old!r} is now {RENAMED[old]!r} (units in the name); {old!r} goes in the "
        "next release",
        DeprecationWarning,
        stacklevel=stacklevel,
    )


def canonical_names(stored: Iterable[str]) -> list[str]:
    """The column names a reader sees for a file's ``stored`` names (old names renamed)."""
    stored = list(stored)
    return [RENAMED[n] if n in RENAMED and RENAMED[n] not in stored else n for n in stored]


def stored_name(name: str, stored: Sequence[str]) -> str:
    """The file's column for the requested ``name`` (new or old, on new or old files)."""
    new = RENAMED.get(name, name)
    if new in stored:
        return new
    old = _OLD.get(new)
    return old if old is not None and old in stored else name


def rename_to(table: pa.Table, names: Sequence[str]) -> pa.Table:
    """``table`` with its columns renamed to ``names``."""
    return table.rename_columns(list(names))


class SampleMeta(dict[str, Any]):
    """A sample's meta values; an old column name reads its new one, with a warning."""

    def __missing__(self, key: Any) -> Any:
        new = RENAMED.get(key)
        if new is None or new not in self:
            raise KeyError(key)
        warn_renamed(key)
        return self[new]

    def get(self, key: Any, default: Any = None) -> Any:
        if key not in self and key in RENAMED and RENAMED[key] in self:
            return self[key]
        return super().get(key, default)
