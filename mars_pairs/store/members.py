"""The dataset's member vocabulary: the tar members a sample has and the fields they decode to.

A sample's default members are ``MEMBERS``. The optional dense members (``output.members``,
written by ``pipeline.sample.dense``) are named by ``DENSE_MEMBERS``; each brings the tar
members in ``MEMBER_FILES`` (a validity or pixel map besides the value), whose field names
(the tar member's stem, the manifest's ``<field>_shard/_offset/_size/_crc32c`` column
prefix) are ``DENSE_FIELDS``: on the ground image's dense grid (``DENSE_GROUND_FIELDS``) or
on the chip grid (``DENSE_CHIP_FIELDS``). With terrain labels (``inputs.terrain_labels``) a
sample also has ``TERRAIN_FIELDS``; ``OPTIONAL_FIELDS`` are both kinds, ``CHIP_GRID_FIELDS``
the optional fields on the chip grid.
"""

from __future__ import annotations

#: Every sample's members, in tar order.
MEMBERS = ("ground", "ortho", "dem", "viewshed", "corr", "meta")

#: The names ``output.members`` accepts (``all``: every one), in member order.
DENSE_MEMBERS = (
    "range", "depth", "hits", "ortho_view", "dem_view", "ground_on_map", "ground_px",
)  # fmt: skip

#: The tar members each written member name brings (companions: validity and pixel maps);
#: each a one-strip zstd TIFF (``store.dense_codec``; format version 2 wrote ``.npy`` arrays
#: and PNG images: ``store.dense_codec.V2_MEMBERS``).
MEMBER_FILES: dict[str, tuple[str, ...]] = {
    "range": ("range.tif",),
    "depth": ("depth.tif",),
    "hits": ("hits.tif",),
    "ortho_view": ("ortho_view.tif", "view_valid.tif"),
    "dem_view": ("dem_view.tif", "view_valid.tif"),
    "ground_on_map": ("ground_on_map.tif", "ground_on_map_cover.tif"),
    "ground_px": ("ground_px.tif",),  # format version 1: ground_px.npy
}

#: The terrain-label members (written when ``inputs.terrain_labels`` is set): ``terrain``
#: (the ground image's classes, uint8 PNG on its pixel grid) and ``terrain_on_map`` (the
#: classes carried onto the chip grid; 255 where not seen or past the label's range).
TERRAIN_FIELDS = ("terrain", "terrain_on_map")

#: Every field the dense members can add, in tar order.
DENSE_FIELDS = tuple(dict.fromkeys(f.split(".")[0] for m in DENSE_MEMBERS for f in MEMBER_FILES[m]))

#: Every optional field a sample can have (dense, then terrain), in tar order.
OPTIONAL_FIELDS = DENSE_FIELDS + TERRAIN_FIELDS

#: Dense fields on the ground image's dense grid (every ``output.dense_stride``-th pixel).
DENSE_GROUND_FIELDS = ("range", "depth", "hits", "ortho_view", "view_valid", "dem_view")

#: Dense fields on the chip grid (S x S, the chip's affine).
DENSE_CHIP_FIELDS = ("ground_on_map", "ground_on_map_cover", "ground_px")

#: Optional fields on the chip grid (S x S, the chip's affine): dense, then terrain.
CHIP_GRID_FIELDS = (*DENSE_CHIP_FIELDS, "terrain_on_map")


def member_fields(members: tuple[str, ...]) -> tuple[str, ...]:
    """The fields (manifest column prefixes) that the dense ``members`` write, in tar order."""
    files = {f.split(".")[0] for m in members for f in MEMBER_FILES[m]}
    return tuple(f for f in DENSE_FIELDS if f in files)
