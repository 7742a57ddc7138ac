"""The AI4Mars layout: terrain masks found by product id, with their rover and range masks.

Layout, relative to the release root (``ai4mars-dataset-merged-0.x``), and the naming rules,
each from a public source (the release itself is not on this machine). The release's own
``info.md`` ("AI4Mars Merged Dataset", in public copies) says: labels are grayscale PNGs,
"Unless otherwise noted, distances further than 30 meters and the rover itself are masked";
NAV values "0 - soil, 1 - bedrock, 2 - sand, 3 - big rock, 255 - NULL (no label)"; "Names of
images match names of labels, except for the extension (JPG, PNG) and sometimes an obvious
suffix (e.g. _merged)"; rover masks "MXY (MSL), MRL (MER)" and range masks "RNG-30M, RNL-30M",
"Masked regions are set to 1 (binary image)"; "MastCam does not have rover or range masks
applied (they do not exist)"; M2020_GEO labels use a geology key of their own (0-6 bedrock,
10-17 float rock, 20-22 sand, 30 pebbles, 40 vein, 50 hill/peak).

- Per-mission folders ``msl/ncam``, ``msl/mcam``, ``mer``, ``m2020``. Curiosity Navcam:
  images ``msl/ncam/images/edr/<id>.JPG``, training masks ``msl/ncam/labels/train/<id>.png``,
  expert test masks ``msl/ncam/labels/test/masked-gold-min{1,2,3}-100agree/<id>_merged.png``,
  rover masks ``msl/ncam/images/mxy/`` and 30 m range masks ``msl/ncam/images/rng-30m/``.
  The 0.1 release has the same folders without ``ncam`` (``msl/images/edr``,
  ``msl/labels/train``): TigerManon/drive-on-mars ``drive_on_mars/params.py`` (IMAGE_PATH,
  MASK_PATH_TRAIN, TESTS_DIR, MASK_ROVER, RANGE_30M); the ``ncam``/``mcam`` split and the
  Mars 2020 folders ``m2020/labels/NAV`` and ``m2020/labels/M2020_GEO``: Jacob-Miller-s/AI4Mars
  ``ai4mars/dataset.py`` (``find_mask_files``, ``_is_legacy_nav_ignore_mask``).
- Mask names (Jacob-Miller-s/AI4Mars ``ai4mars/dataset.py``, ``build_pairs_by_stem``, quoting
  the release's ``info.md``: "Names of images match names of labels, except for the extension
  (JPG, PNG) and sometimes an obvious suffix (e.g. ``_merged``)"): Navcam ``<id>.png``; gold
  test ``<id>_merged.png``; Mastcam ``<id>_15033_merged.png``; MER ``<id>_merged6.png``;
  Mars 2020 tiled labels ``<id>_01_195J_merged3.png``-style, several per image. A mask is
  tied to an image by trimming ``_``-separated segments off its stem until an image id
  remains (the same loader's ``_find_source_image_for_mask``): here, by product id, the
  ``_merged<N>`` suffix (and Mastcam's ``_15033``) is removed and the rest is the id, or for
  Mars 2020 the id without its trailing two-character version (a Mars 2020 Navcam id ends
  ``..._01_295J01``: ``mars_pairs.synth.cameras.navcam_product_id``; a public Mars 2020 mask
  name ``NLF_0034_0669963392_071ECM_N0031392NCAM03034_07_195J_merged12`` keeps the id's
  ``_07_195J`` and drops the version). Which Mars 2020 tile a mask covers is not described by
  any source found offline: a Mars 2020 mask must be the size of its image, else it is a
  failure row naming the file.
- Class values: ``classes.AI4MARS_CLASSES`` (0 soil, 1 bedrock, 2 sand, 3 big rock, 255 no
  label); Mastcam masks use 4 as ignore (``classes.MASTCAM_IGNORE``). ``M2020_GEO`` masks
  answer another question (geology, not traversability) with another key: they are not read
  (a product with only such a mask has no label, a failure row).
- Rover and range masks: the product id with its product type ``EDR`` replaced by ``MXY``
  (rover) or ``RNG`` (range), PNG; 1 marks an excluded pixel (the rover; beyond 30 m).
  Source: the public loader whose docstring draws the release's tree
  (``msl/images/mxy/NLA_397681455MXY_F0020000AUT_04096M1.png``,
  ``msl/images/rng-30m/NLA_397681455RNG_F0020000AUT_04096M1.png`` next to
  ``edr/NLA_397681455EDR_F0020000AUT_04096M1.JPG``; ``filename.replace("EDR", "MXY")``,
  ``label[rover_mask == 1]``, ``label[range_mask == 1]``), and Jacob-Miller-s/AI4Mars
  ``find_mask_files`` ("rover masks in ``mxy/`` and 30m range masks in ``rng-30m/``").
  Mastcam images have neither (info.md). The masks are applied again on reading (the release's
  labels are already masked, "unless otherwise noted"; applying a mask twice changes nothing).
  A label is 30 m deep where the range masks are (Navcam), so its ``max_range_m`` is 30 for
  Navcam labels and for any label read with a range mask, None otherwise.

Masks are indexed once (one listing per folder); a product id named by more than one mask
in the folders read is a failure row naming them, never a silent choice.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from mars_pairs.errors import TerrainLabelError
from mars_pairs.terrain_labels.classes import (
    AI4MARS_CLASSES,
    MASTCAM_IGNORE,
    NO_LABEL,
    ClassTable,
)
from mars_pairs.terrain_labels.masks import TerrainLabel, read_classes, read_exclusion

RANGE_LIMIT_M = 30.0
GOLD_TEST_SETS = tuple(f"masked-gold-min{k}-100agree" for k in (1, 2, 3))
_MERGED = re.compile(r"_merged\d*$")


@dataclass(frozen=True)
class Scheme:
    """One mask folder of the layout: where (relative to the root), how a mask's name gives
    its id (``suffix``: a regular expression removed from the stem), the table, the folder
    of rover and range masks (relative to the root; None: none) and the range limit."""

    folder: str
    suffix: str
    table: ClassTable
    exclusions: str | None = None
    max_range_m: float | None = None
    versioned_ids: bool = False  # Mars 2020: the id may be named without its version

    def product_id(self, stem: str) -> str | None:
        """The id a mask named ``stem`` labels, None when the name does not fit."""
        if not self.suffix:
            return stem
        cut = re.sub(self.suffix + "$", "", stem)
        return cut if cut != stem else None


def schemes(test_set: str = GOLD_TEST_SETS[2]) -> tuple[Scheme, ...]:
    """The mask folders read, in order: Curiosity Navcam training and the gold ``test_set``
    (both layouts), Curiosity Mastcam, MER, Mars 2020 NAV."""
    mastcam = AI4MARS_CLASSES.with_ignore(MASTCAM_IGNORE)
    out: list[Scheme] = []
    for msl in ("msl/ncam", "msl"):
        excl = f"{msl}/images"
        out += [
            Scheme(f"{msl}/labels/train", "", AI4MARS_CLASSES, excl, RANGE_LIMIT_M),
            Scheme(f"{msl}/labels/test/{test_set}", "_merged", AI4MARS_CLASSES, excl,
                   RANGE_LIMIT_M),
        ]  # fmt: skip
    out += [
        Scheme(MASTCAM_TRAIN, "_15033_merged", mastcam),
        Scheme("mer/labels/train/merged-unmasked", r"_merged\d+", AI4MARS_CLASSES),
        Scheme(M2020_NAV, r"_merged\d*", AI4MARS_CLASSES, "m2020/images", versioned_ids=True),
    ]
    return tuple(out)


MASTCAM_TRAIN = "msl/mcam/labels/train"
M2020_NAV = "m2020/labels/NAV"


def exclusion_name(product_id: str, kind: str) -> str | None:
    """The rover (``MXY``) or range (``RNG``) mask's stem for ``product_id``: its product
    type (``EDR``; Mars 2020 ``ECM`` or ``RAD``, right after the clock digits) swapped; None
    when the id has none."""
    swapped, n = re.subn(r"(?<=\d)(?:EDR|ECM|RAD)(?=_)", kind, product_id, count=1)
    return swapped if n else None


def mask_relpath(mission: str, instrument: str, product_id: str) -> str:
    """Where the layout keeps the training mask of a product (relative to the root): a
    Curiosity Mastcam mask ``msl/mcam/labels/train/<id>_15033_merged.png``, a Curiosity
    Navcam one ``msl/ncam/labels/train/<id>.png``, a Mars 2020 one
    ``m2020/labels/NAV/<id without version>_merged3.png``."""
    if mission == "msl":
        if instrument.startswith("MAST"):
            return f"{MASTCAM_TRAIN}/{product_id}_15033_merged.png"
        return f"msl/ncam/labels/train/{product_id}.png"
    return f"{M2020_NAV}/{product_id[:-2]}_merged3.png"


def exclusion_relpath(mission: str, product_id: str, kind: str) -> str | None:
    """Where the layout keeps a product's rover (``MXY``) or range (``RNG``) mask, None when
    its id has no product type to swap. (The release has them for Curiosity Navcam; a Mars
    2020 one is read where present, as the synthetic mission writes them.)"""
    stem = exclusion_name(product_id, kind)
    if stem is None:
        return None
    images = "msl/ncam/images" if mission == "msl" else "m2020/images"
    return f"{images}/{'mxy' if kind == 'MXY' else 'rng-30m'}/{stem}.png"


class AI4MarsLabels:
    """Terrain labels in the AI4Mars layout under ``root``, read by product id."""

    format = "ai4mars"

    def __init__(self, root: Path, test_set: str = GOLD_TEST_SETS[2]) -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise TerrainLabelError(f"{self.root}: AI4Mars root is not a folder")
        self.schemes = schemes(test_set)
        self.table = AI4MARS_CLASSES
        self._index: dict[str, list[tuple[Path, Scheme]]] = {}
        #: mask files whose names fit no scheme of their folder, named (never dropped quietly)
        self.unmatched: list[Path] = []
        for scheme in self.schemes:
            folder = self.root / scheme.folder
            if not folder.is_dir():
                continue
            for path in sorted(folder.glob("*.png")):
                pid = scheme.product_id(path.stem)
                if pid is None:
                    self.unmatched.append(path)
                    continue
                self._index.setdefault(pid, []).append((path, scheme))

    def product_ids(self) -> list[str]:
        """Every id a mask names (Mars 2020 ids possibly without their version), sorted."""
        return sorted(self._index)

    def _find(self, product_id: str) -> tuple[Path, Scheme]:
        found = self._index.get(product_id, [])
        if not found and len(product_id) > 2:
            found = [(p, s) for p, s in self._index.get(product_id[:-2], []) if s.versioned_ids]
        if not found:
            raise TerrainLabelError(
                f"{self.root}: no AI4Mars terrain mask names product {product_id} (folders "
                f"{', '.join(s.folder for s in self.schemes if (self.root / s.folder).is_dir())})"
            )
        if len(found) > 1:
            names = ", ".join(str(p) for p, _ in found)
            raise TerrainLabelError(f"product {product_id}: several terrain masks: {names}")
        return found[0]

    def read(self, product_id: str, size: tuple[int, int]) -> TerrainLabel:
        """The label of ``product_id`` for its image of ``size`` (width, height): the mask,
        with the rover and range masks (when the layout has them for it) set to no label."""
        path, scheme = self._find(product_id)
        classes = read_classes(path, scheme.table, size)
        rover = range_ = None
        if scheme.exclusions is not None:
            base = self.root / scheme.exclusions
            for kind, folder in (("MXY", "mxy"), ("RNG", "rng-30m")):
                stem = exclusion_name(product_id, kind)
                candidate = base / folder / f"{stem}.png" if stem else None
                if candidate is None or not candidate.is_file():
                    continue
                what = "rover mask" if kind == "MXY" else "range mask"
                excluded = read_exclusion(candidate, what, size)
                classes[excluded] = NO_LABEL
                if kind == "MXY":
                    rover = candidate
                else:
                    range_ = candidate
        limit = RANGE_LIMIT_M if range_ is not None else scheme.max_range_m
        return TerrainLabel(product_id, classes, scheme.table, path, rover, range_, limit)
