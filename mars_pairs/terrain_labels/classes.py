"""Terrain class tables: which mask value means which terrain class.

A terrain label is a single-band uint8 mask on a ground image's pixel grid: each pixel holds a
class value of its table, ``NO_LABEL`` (255) where nobody labelled it, or one of the table's
``ignore`` values (read as ``NO_LABEL``).

The AI4Mars table (``AI4MARS_CLASSES``): 0 soil, 1 bedrock, 2 sand, 3 big rock, 255 no label.
Sources: the dataset's loaders in public repositories, e.g. Jacob-Miller-s/AI4Mars
``ai4mars/dataset.py`` (module docstring: "0 -> soil, 1 -> bedrock, 2 -> sand, 3 -> big_rock,
255 -> ignore / unlabeled") and TigerManon/drive-on-mars ``drive_on_mars/params.py``
(``labels_key`` 0 soil, 1 bedrock, 2 sand, 3 big rock). The Curiosity Mastcam training masks
(``msl/mcam/labels/train/*_15033_merged.png``) use 4 where the rest use 255
(``MASTCAM_IGNORE``; Jacob-Miller-s/AI4Mars ``ai4mars/dataset.py``,
``_is_legacy_nav_ignore_mask`` and ``normalize_ai4mars_mask``).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass

from mars_pairs.errors import ConfigError

NO_LABEL = 255
MASTCAM_IGNORE = 4
_NAME = re.compile(r"[a-z][a-z0-9_]*")


@dataclass(frozen=True)
class ClassTable:
    """Mask value -> class name (lower case, ``[a-z][a-z0-9_]*``: it names manifest columns
    ``terrain_<name>_px``); ``ignore``: values read as ``NO_LABEL``."""

    names: tuple[tuple[int, str], ...]
    ignore: tuple[int, ...] = ()

    @property
    def values(self) -> tuple[int, ...]:
        """The class values, ascending."""
        return tuple(v for v, _ in self.names)

    def name(self, value: int) -> str:
        """The class name of ``value`` (KeyError when the table has none)."""
        return dict(self.names)[value]

    def with_ignore(self, *values: int) -> ClassTable:
        """This table with ``values`` also read as no label."""
        return ClassTable(self.names, tuple(sorted({*self.ignore, *values})))

    @classmethod
    def from_mapping(cls, data: object, key: str) -> ClassTable:
        """A table from a config mapping {value: name}; ConfigError naming ``key``."""
        if not isinstance(data, Mapping) or not data:
            raise ConfigError(f"{key}: expected a mapping of mask value to class name")
        names: dict[int, str] = {}
        for raw, name in data.items():
            value = int(raw) if isinstance(raw, str) and raw.isdigit() else raw
            if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value < 255:
                raise ConfigError(f"{key}: mask value {raw!r} is not an integer 0..254")
            if not isinstance(name, str) or not _NAME.fullmatch(name):
                raise ConfigError(
                    f"{key}.{value}: class name {name!r} must be lower case [a-z][a-z0-9_]*"
                )
            if name in names.values():
                raise ConfigError(f"{key}: class name {name!r} given twice")
            names[value] = name
        return cls(tuple(sorted(names.items())))


AI4MARS_CLASSES = ClassTable(((0, "soil"), (1, "bedrock"), (2, "sand"), (3, "big_rock")))


def count_columns(table: ClassTable) -> tuple[str, ...]:
    """The manifest columns counting each class's pixels on the chip (``terrain_on_map``)."""
    return tuple(f"terrain_{name}_px" for _, name in table.names)
