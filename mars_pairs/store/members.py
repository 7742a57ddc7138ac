"""The optional dense members' fields (``output.members``), by the grid they lie on.

A field is a manifest column prefix (``<field>_shard``, ``_offset``, ``_size``, ``_crc32c``)
and a tar member ``<key>.<field>.<ext>``; which member writes which field is the build's
(``pipeline.dense.MEMBER_FILES``). The default members are ``store.manifest.MEMBERS``.
"""

from __future__ import annotations

#: on the ground image's dense grid (every ``output.dense_stride``-th ground-image pixel)
DENSE_GROUND_FIELDS = ("range", "depth", "hits", "ortho_view", "view_valid", "dem_view")

#: on the chip grid (they move with the chips)
DENSE_CHIP_FIELDS = ("ground_on_map", "ground_on_map_cover", "ground_px")

#: every optional dense field, in tar order (a build's manifest has their columns after the
#: default members' ones)
DENSE_FIELDS = DENSE_GROUND_FIELDS + DENSE_CHIP_FIELDS
