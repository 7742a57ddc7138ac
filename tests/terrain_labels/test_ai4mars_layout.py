"""The AI4Mars layout as its public sources describe it: every naming scheme, the class values,
the Mastcam ignore value, the Mars 2020 tiles, the rover and range masks; and every bad mask
a failure naming the file. Each table row cites where its name or value comes from."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from mars_pairs.errors import ConfigError, TerrainLabelError
from mars_pairs.pipeline.config import parse_config
from mars_pairs.terrain_labels import AI4MARS_CLASSES, AI4MarsLabels, ClassTable, FolderLabels
from mars_pairs.terrain_labels.ai4mars import exclusion_name

JM = "Jacob-Miller-s/AI4Mars ai4mars/dataset.py"
TIGER = "TigerManon/drive-on-mars drive_on_mars/params.py"
TREE = "public AI4Mars loader docstring drawing the release tree (msl/images/{edr,mxy,rng-30m})"
M2020_MASK = "public project notes naming m2020 mask NLF_0034_..._07_195J_merged12"

# (mask path relative to the root, product id it labels, gold test set read, source)
NAMES = [
    ("msl/ncam/labels/train/NLA_397681455EDR_F0020000AUT_04096M1.png",
     "NLA_397681455EDR_F0020000AUT_04096M1", None, f"{JM} build_pairs_by_stem: <stem>.png"),
    ("msl/labels/train/NLA_397681455EDR_F0020000AUT_04096M1.png",
     "NLA_397681455EDR_F0020000AUT_04096M1", None, f"{TIGER} MASK_PATH_TRAIN (release 0.1)"),
    ("msl/ncam/labels/test/masked-gold-min1-100agree/"
     "NLA_602664178EDR_F0732958NCAM00271M1_merged.png",
     "NLA_602664178EDR_F0732958NCAM00271M1", "masked-gold-min1-100agree", f"{TREE}; {TIGER}"),
    ("msl/ncam/labels/test/masked-gold-min3-100agree/"
     "NLA_602664178EDR_F0732958NCAM00271M1_merged.png",
     "NLA_602664178EDR_F0732958NCAM00271M1", None, f"{TIGER} TESTS_DIR"),
    ("msl/mcam/labels/train/1429MR0070670010702567E01_DRCL_15033_merged.png",
     "1429MR0070670010702567E01_DRCL", None, f"{JM} <stem>_15033_merged.png"),
    ("mer/labels/train/merged-unmasked/1P128287198EFF0000P2303L2M1_merged6.png",
     "1P128287198EFF0000P2303L2M1", None, f"{JM} <stem>_merged6.png"),
    ("m2020/labels/NAV/NLF_0034_0669963392_071ECM_N0031392NCAM03034_07_195J_merged12.png",
     "NLF_0034_0669963392_071ECM_N0031392NCAM03034_07_195J01", None,
     f"{JM} <stem>_01_195J_merged3.png tiles; {M2020_MASK}"),
]  # fmt: skip

# (mask value, what it reads as, source)
VALUES = [
    (0, "soil", f"{JM} docstring; {TIGER} labels_key"),
    (1, "bedrock", f"{JM} docstring; {TIGER} labels_key"),
    (2, "sand", f"{JM} docstring; {TIGER} labels_key"),
    (3, "big_rock", f"{JM} docstring; {TIGER} labels_key"),
    (255, None, f"{JM} docstring: 255 -> ignore / unlabeled"),
]

# (product id, rover mask stem, range mask stem, source)
EXCLUSIONS = [
    ("NLA_397681455EDR_F0020000AUT_04096M1", "NLA_397681455MXY_F0020000AUT_04096M1",
     "NLA_397681455RNG_F0020000AUT_04096M1", f"{TREE}: filename.replace('EDR', 'MXY')"),
]  # fmt: skip


def _png(path: Path, arr: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(arr.astype(np.uint8), mode="L").save(path)
    return path


SIZE = (8, 6)  # width, height


def _mask(values: list[int]) -> np.ndarray:
    arr = np.full((SIZE[1], SIZE[0]), 255, dtype=np.uint8)
    arr.flat[: len(values)] = values
    return arr


@pytest.mark.parametrize(("rel", "product_id", "test_set", "source"), NAMES)
def test_mask_names_of_the_release(tmp_path: Path, rel: str, product_id: str,
                                   test_set: str | None, source: str) -> None:  # fmt: skip
    _png(tmp_path / rel, _mask([0, 1, 2, 3]))
    labels = AI4MarsLabels(tmp_path, test_set) if test_set else AI4MarsLabels(tmp_path)
    label = labels.read(product_id, SIZE)
    assert label.mask_path == tmp_path / rel, source
    assert label.classes.flat[:4].tolist() == [0, 1, 2, 3], source
    assert not labels.unmatched


@pytest.mark.parametrize(("value", "name", "source"), VALUES)
def test_class_values(tmp_path: Path, value: int, name: str | None, source: str) -> None:
    _png(tmp_path / "msl/ncam/labels/train/NLA_1EDR_F1.png", _mask([value]))
    label = AI4MarsLabels(tmp_path).read("NLA_1EDR_F1", SIZE)
    assert label.classes.flat[0] == value, source
    if name is not None:
        assert AI4MARS_CLASSES.name(value) == name, source


def test_mastcam_ignore_value_is_no_label(tmp_path: Path) -> None:
    """Mastcam masks use 4 where the others use 255 (Jacob-Miller-s/AI4Mars
    ai4mars/dataset.py ``_is_legacy_nav_ignore_mask``); 4 elsewhere is an unknown value."""
    _png(tmp_path / "msl/mcam/labels/train/X_DRCL_15033_merged.png", _mask([4, 2]))
    assert AI4MarsLabels(tmp_path).read("X_DRCL", SIZE).classes.flat[:2].tolist() == [255, 2]
    _png(tmp_path / "msl/ncam/labels/train/NLA_2EDR_F1.png", _mask([4]))
    with pytest.raises(TerrainLabelError, match=r"NLA_2EDR_F1\.png: mask value\(s\) \[4\]"):
        AI4MarsLabels(tmp_path).read("NLA_2EDR_F1", SIZE)


@pytest.mark.parametrize(("product_id", "rover", "range_", "source"), EXCLUSIONS)
def test_rover_and_range_mask_names(product_id: str, rover: str, range_: str,
                                    source: str) -> None:  # fmt: skip
    assert exclusion_name(product_id, "MXY") == rover, source
    assert exclusion_name(product_id, "RNG") == range_, source


def test_rover_and_range_masks_exclude_pixels(tmp_path: Path) -> None:
    pid = "NLA_397681455EDR_F0020000AUT_04096M1"
    _png(tmp_path / f"msl/ncam/labels/train/{pid}.png", _mask([0, 1, 2, 3]))
    rover = np.zeros((SIZE[1], SIZE[0]), np.uint8)
    rover.flat[0] = 1
    far = np.zeros_like(rover)
    far.flat[2] = 1
    _png(tmp_path / "msl/ncam/images/mxy/NLA_397681455MXY_F0020000AUT_04096M1.png", rover)
    _png(tmp_path / "msl/ncam/images/rng-30m/NLA_397681455RNG_F0020000AUT_04096M1.png", far)
    label = AI4MarsLabels(tmp_path).read(pid, SIZE)
    assert label.classes.flat[:4].tolist() == [255, 1, 255, 3]
    assert label.rover_mask is not None and label.range_mask is not None
    assert label.max_range_m == 30.0


@pytest.mark.parametrize(
    ("write", "match"),
    [
        (lambda r: _png(r / "msl/ncam/labels/train/P_1EDR_X.png", np.zeros((5, 8))),
         r"P_1EDR_X\.png: terrain mask is 8 x 5 pixels, its image 8 x 6"),
        (lambda r: _png(r / "msl/ncam/labels/train/P_1EDR_X.png", _mask([7])),
         r"P_1EDR_X\.png: mask value\(s\) \[7\]"),
        (lambda r: Image.new("RGB", SIZE).save(_dir(r / "msl/ncam/labels/train") / "P_1EDR_X.png"),
         r"P_1EDR_X\.png: terrain mask must be a single-band"),
        (lambda r: _png(r / "msl/ncam/labels/train/Q_1EDR_X.png", _mask([0])),
         r"no AI4Mars terrain mask names product P_1EDR_X"),
        (lambda r: (_png(r / "msl/ncam/labels/train/P_1EDR_X.png", _mask([0])),
                    _png(r / "msl/ncam/images/rng-30m/P_1RNG_X.png", _mask([2]))),
         r"P_1RNG_X\.png: range mask holds \[2"),
        (lambda r: (_png(r / "msl/ncam/labels/train/P_1EDR_X.png", _mask([0])),
                    _png(r / "msl/labels/train/P_1EDR_X.png", _mask([0]))),
         r"product P_1EDR_X: several terrain masks"),
    ],
)  # fmt: skip
def test_bad_masks_are_errors_naming_the_file(tmp_path: Path, write: object,
                                              match: str) -> None:  # fmt: skip
    write(tmp_path)  # type: ignore[operator]
    with pytest.raises(TerrainLabelError, match=match):
        AI4MarsLabels(tmp_path).read("P_1EDR_X", SIZE)


def _dir(path: Path) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    return path


def test_names_that_fit_no_scheme_are_named(tmp_path: Path) -> None:
    _png(tmp_path / "msl/mcam/labels/train/1429MR_DRCL.png", _mask([0]))
    labels = AI4MarsLabels(tmp_path)
    assert labels.unmatched == [tmp_path / "msl/mcam/labels/train/1429MR_DRCL.png"]


def test_folder_format_with_its_class_table(tmp_path: Path) -> None:
    table = ClassTable.from_mapping({0: "ground", 5: "rock"}, "classes")
    _png(tmp_path / "ZLF_1.png", _mask([5, 0, 255]))
    labels = FolderLabels(tmp_path, table, max_range_m=40.0)
    label = labels.read("ZLF_1", SIZE)
    assert label.classes.flat[:3].tolist() == [5, 0, 255] and label.max_range_m == 40.0
    assert labels.product_ids() == ["ZLF_1"]
    _png(tmp_path / "ZLF_2.png", _mask([1]))
    with pytest.raises(TerrainLabelError, match=r"ZLF_2\.png: mask value\(s\) \[1\]"):
        labels.read("ZLF_2", SIZE)
    with pytest.raises(TerrainLabelError, match=r"ZLF_3\.png: no terrain mask"):
        labels.read("ZLF_3", SIZE)


def _config(tmp_path: Path, terrain: object) -> dict[str, object]:
    return {
        "inputs": {"labels": "*.xml", "places": "p.csv", "dem": "d.tif", "ortho": "o.tif",
                   "terrain_labels": terrain},
        "output": {"dir": "out"},
    }  # fmt: skip


def test_config_key(tmp_path: Path) -> None:
    (tmp_path / "labels").mkdir()
    cfg = parse_config(_config(tmp_path, {"format": "ai4mars", "root": "labels"}), tmp_path)
    spec = cfg.inputs.terrain_labels
    assert spec is not None and spec.format == "ai4mars" and spec.root == tmp_path / "labels"
    assert "terrain_labels" in cfg.to_dict()["inputs"]
    plain = parse_config({**_config(tmp_path, None)}, tmp_path)
    assert "terrain_labels" not in plain.to_dict()["inputs"]  # fingerprints stay as they were
    folder = {"format": "folder", "root": "labels", "classes": {0: "soil", 2: "sand"}}
    assert parse_config(_config(tmp_path, folder), tmp_path).inputs.terrain_labels.classes == {
        0: "soil", 2: "sand"}  # type: ignore[union-attr]  # fmt: skip
    for bad, match in (
        ({"format": "png", "root": "labels"}, r"inputs\.terrain_labels\.format"),
        ({"format": "folder", "root": "labels"}, r"inputs\.terrain_labels\.classes: a folder"),
        ({"format": "folder", "root": "labels", "classes": {0: "Soil"}}, r"lower case"),
        ({"format": "ai4mars", "root": "labels", "colour": 1}, r"unknown key"),
    ):
        with pytest.raises(ConfigError, match=match):
            parse_config(_config(tmp_path, bad), tmp_path)
