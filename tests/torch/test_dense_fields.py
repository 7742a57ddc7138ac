"""The dense members read by MarsPairsDataset, moved by the transforms, and carried between
the views by CarryToChip / CarryToImage (which must reproduce ground_on_map and ortho_view,
before and after geometric transforms)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from affine import Affine

from mars_pairs import Manifest
from mars_pairs.errors import MarsPairsError
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.store.members import DENSE_FIELDS
from mars_pairs.torch import MarsPairsDataset
from mars_pairs.torch.files import ShardFiles
from mars_pairs.torch.transforms import CarryToChip, CarryToImage, Compose, Flip, Rotate
from support.configs import build_config

STRIDE = 8


@pytest.fixture(scope="module")
def dense_dir(small_mission: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("dense-torch")
    config = build_config(
        small_mission, out, geometry={"ray_stride": STRIDE}, chips={"size_px": 256},
        output={"members": ["all"]}, splits=None,
    )  # fmt: skip
    assert run_build(config).failures == 0
    return out


FIELDS = ("ground", "ortho", "dem", "viewshed", *DENSE_FIELDS)


def _best(ds: MarsPairsDataset) -> dict[str, Any]:
    """The sample with the most covered chip pixels."""
    samples = [ds[i] for i in range(len(ds))]
    return max(samples, key=lambda s: int(s["ground_on_map_cover"].sum()))


def test_dense_fields_shapes_dtypes_and_targets(dense_dir: Path) -> None:
    with MarsPairsDataset(dense_dir, fields=FIELDS, localization=True) as ds:
        s = ds[0]
    h, w = s["range"].shape[-2:]
    assert s["range"].dtype == torch.float32 and s["range"].shape[0] == 1
    assert s["hits"].dtype == torch.float64 and s["hits"].shape == (3, h, w)
    assert s["ortho_view"].dtype == torch.uint8 and s["view_valid"].max() <= 1
    assert s["ground_on_map"].shape == (3, 256, 256) and s["ground_px"].shape == (2, 256, 256)
    assert s["dense_ground"].shape == (2, h, w)
    assert float(s["dense_ground"][0, 0, 1]) == pytest.approx(STRIDE + 0.5)
    assert s["rover_px"].shape == (2,) and 0.0 <= float(s["heading_deg"]) < 360.0


def test_verified_localization_reads_meta_once(
    dense_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """verify=True checks meta.json and the localization targets come from those bytes: the
    member is read once (plus its tar header), not again for the targets."""
    with MarsPairsDataset(dense_dir, fields=("ortho",), localization=True) as plain:
        want = plain[0]
    rows = Manifest.open(dense_dir).to_table(columns=["key", "meta_offset"]).to_pylist()
    meta_offset = {r["key"]: r["meta_offset"] for r in rows}[want["meta"]["key"]]
    reads: list[int] = []
    original = ShardFiles.read

    def counted(self: ShardFiles, shard: str, offset: int, size: int) -> bytearray:
        reads.append(offset)
        return original(self, shard, offset, size)

    monkeypatch.setattr(ShardFiles, "read", counted)
    with MarsPairsDataset(dense_dir, fields=("ortho",), localization=True, verify=True) as ds:
        got = ds[0]
    assert reads.count(meta_offset) == 1
    for name in ("rover_px", "camera_px", "heading_deg"):
        assert torch.equal(got[name], want[name]), name


def test_carry_reproduces_ground_on_map_and_ortho_view(dense_dir: Path) -> None:
    with MarsPairsDataset(dense_dir, fields=FIELDS) as ds:
        s = _best(ds)
    cover = s["ground_on_map_cover"][0].bool()
    assert cover.sum() >= 500
    to_chip = CarryToChip("ground", "carried", nearest=False)
    to_image = CarryToImage("ortho", "seen", nearest=False)
    dem_to_image = CarryToImage("dem", "height", nearest=False)

    def check(sample: dict[str, Any], what: str) -> None:
        got = to_chip(sample)
        ok = got["carried_valid"] & sample["ground_on_map_cover"][0].bool()
        assert ok.sum() >= 0.95 * cover.sum(), what
        diff = (got["carried"][:, ok] - sample["ground_on_map"][:, ok].float()).abs()
        assert float(diff.max()) <= 1.0, what
        # ortho_view samples the ortho itself, CarryToImage its chip (resampled onto the
        # chip grid): the same picture, not the same bytes; the DEM (smooth) carries exactly
        seen = to_image(sample)
        valid = seen["seen_valid"] & sample["view_valid"][0].bool()
        assert valid.sum() >= 100, what
        a, b = seen["seen"][0][valid].double(), sample["ortho_view"][0][valid].double()
        assert float(torch.corrcoef(torch.stack([a, b]))[0, 1]) >= 0.95, what
        height = dem_to_image(sample)
        valid = height["height_valid"] & sample["view_valid"][0].bool()
        assert valid.sum() >= 100, what
        diff = (height["height"][0][valid] - sample["dem_view"][0][valid]).abs()
        assert float(diff.max()) <= 0.02, what

    check(s, "as read")
    # the chips turned and mirrored, the ground image mirrored: the maps move along
    moved = Compose([Rotate(90.0), Flip("horizontal", target="chip"),
                     Flip("vertical", target="ground")])(s)  # fmt: skip
    check(moved, "after transforms")


MOVES = Compose([Rotate(90.0), Flip("horizontal", target="chip"),
                 Flip("vertical", target="ground")])  # fmt: skip


@pytest.mark.parametrize("moved", [False, True])
def test_classes_round_trip_nearest(dense_dir: Path, moved: bool) -> None:
    """A class map on the chip (4 classes in random 32 px patches) carried into the image
    lands on the class under each ray's hit (looked up with numpy through the chip's affine),
    and carried back through ``ground_px`` gives each covered chip pixel its own class; after
    chip and ground transforms too."""
    with MarsPairsDataset(dense_dir, fields=FIELDS) as ds:
        s = _best(ds)
    if moved:
        s = MOVES(s)
    n = s["ortho"].shape[-1]
    table = np.random.default_rng(7).integers(0, 4, size=(n // 32 + 1, n // 32 + 1))
    rows, cols = np.mgrid[0:n, 0:n]
    classes = table[rows // 32, cols // 32].astype(np.int16)
    s["classes"] = torch.from_numpy(classes)[None]
    out = CarryToImage("classes", "image_classes", nearest=True, fill=-1)(s)
    image = out["image_classes"][0].numpy()
    valid = out["image_classes_valid"].numpy()
    assert out["image_classes"].dtype == torch.int16
    # chip -> image: the class of the chip pixel holding each hit
    hits = s["hits"].double().numpy()
    col, row = ~Affine(*(float(v) for v in s["transform"][:6])) * (hits[0], hits[1])
    col, row = np.asarray(col), np.asarray(row)
    inside = np.isfinite(col) & (col >= 0) & (col < n) & (row >= 0) & (row < n)
    assert inside.sum() >= 100 and np.array_equal(valid, inside)
    expected = classes[row[inside].astype(int), col[inside].astype(int)]
    assert np.array_equal(image[inside], expected)
    # image -> chip: each covered chip pixel reads the dense cell nearest its ground pixel
    # (cells on a regular grid: line = line0 + i * step, sample = sample0 + j * step, from
    # dense_ground, edge coordinates), the inverse map
    dense = s["dense_ground"].double().numpy() - 0.5  # pixel centres at integers
    line0, dline = dense[1, 0, 0], dense[1, 1, 0] - dense[1, 0, 0]
    sample0, dsample = dense[0, 0, 0], dense[0, 0, 1] - dense[0, 0, 0]
    cover = s["ground_on_map_cover"][0].numpy() > 0
    px = s["ground_px"].double().numpy()[:, cover]
    i = np.rint((px[1] - line0) / dline).astype(int)
    j = np.rint((px[0] - sample0) / dsample).astype(int)
    ok = (i >= 0) & (i < image.shape[0]) & (j >= 0) & (j < image.shape[1])
    back = np.full(px.shape[1], -1)
    back[ok] = image[i[ok], j[ok]]
    ok &= back >= 0
    assert ok.sum() >= 500
    agree = (back[ok] == classes[cover][ok]).mean()
    assert agree >= 0.95, agree


def test_dense_fields_of_a_default_dataset_are_refused(small_mission: Path, tmp_path: Path) -> None:
    run_build(build_config(small_mission, tmp_path / "plain", splits=None))
    with pytest.raises(MarsPairsError, match="range"):
        MarsPairsDataset(tmp_path / "plain", fields=("ground", "range"))
    ds = MarsPairsDataset(tmp_path / "plain", fields=("ortho",), localization=True)
    with ds, pytest.raises(MarsPairsError, match="localization"):
        ds[0]


def test_dense_figure_and_show(dense_dir: Path, tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    import matplotlib.pyplot as plt
    from PIL import Image

    from mars_pairs.report import show_sample

    with MarsPairsDataset(dense_dir, fields=FIELDS) as ds:
        s = _best(ds)
        fig = ds.plot(s, dense=True)
        key = s["meta"]["key"]
    titles = [a.get_title() for a in fig.axes]
    plt.close(fig)
    assert any("range" in t for t in titles) and any("laid on the map" in t for t in titles)
    out = show_sample(dense_dir, key, tmp_path / "show.png")
    dense_png = tmp_path / "show_dense.png"
    assert out.is_file() and dense_png.is_file()
    pixels = np.asarray(Image.open(dense_png).convert("L"))
    assert pixels.std() > 10  # something is drawn


def test_ground_px_follows_ground_size(dense_dir: Path) -> None:
    with MarsPairsDataset(dense_dir, fields=FIELDS) as ds:
        full = ds[0]
    with MarsPairsDataset(dense_dir, fields=FIELDS, ground_size=(300, 412)) as ds:
        small = ds[0]
    h, w = full["ground"].shape[-2:]
    scale = torch.tensor([412 / w, 300 / h], dtype=torch.float32)[:, None, None]
    expected = (full["ground_px"] + 0.5) * scale - 0.5
    assert torch.allclose(small["ground_px"], expected, equal_nan=True)
    ok = small["ground_on_map_cover"][0].bool()
    carried = CarryToChip("ground", "c", nearest=False)(small)
    assert carried["c_valid"][ok].float().mean() > 0.99


def _as_version_2(src: Path, dst: Path) -> None:
    """``src`` rewritten as a format version 2 folder in ``dst``: every dense ``.tif`` member
    but ``ground_px.tif`` replaced by the ``.npy`` (``np.save``) or PNG (Pillow) of GDAL's
    reading of it, the manifest's location columns and dataset.json's version to match."""
    import io
    import json
    import shutil
    import tarfile

    import pyarrow as pa
    import pyarrow.parquet as pq
    from PIL import Image

    from mars_pairs.store.seal import seal
    from mars_pairs.store.shards import ShardWriter
    from support.members import tiff_array

    shutil.copytree(src, dst)
    table = pq.read_table(dst / "manifest.parquet")
    rows = {r["key"]: i for i, r in enumerate(table.select(["key"]).to_pylist())}
    columns = {c: table[c].to_pylist() for c in table.column_names}
    for shard in sorted((dst / "shards").glob("*.tar")):
        samples: dict[str, dict[str, bytes]] = {}
        with tarfile.open(shard) as tar:
            for info in tar.getmembers():
                key, _, member = info.name.partition(".")
                fh = tar.extractfile(info)
                assert fh is not None
                samples.setdefault(key, {})[member] = fh.read()
        rel = shard.relative_to(dst).as_posix()
        shard.unlink()
        with ShardWriter(dst, rel) as writer:
            for key, members in samples.items():
                old: dict[str, bytes] = {}
                for member, data in members.items():
                    field, _, suffix = member.partition(".")
                    if suffix != "tif" or field in ("dem", "ground_px"):
                        old[member] = data
                        continue
                    buf = io.BytesIO()
                    pixels = tiff_array(data)
                    if pixels.dtype == np.uint8:
                        Image.fromarray(pixels).save(buf, format="PNG")
                        old[f"{field}.png"] = buf.getvalue()
                    else:
                        np.save(buf, pixels, allow_pickle=False)
                        old[f"{field}.npy"] = buf.getvalue()
                for member, loc in writer.add(key, old).items():
                    field = "ground" if member.startswith("ground.") else member.split(".")[0]
                    i = rows[key]
                    columns[f"{field}_offset"][i] = loc.offset
                    columns[f"{field}_size"][i] = loc.size
                    columns[f"{field}_crc32c"][i] = loc.crc32c
    arrays = [pa.array(columns[c], type=table.schema.field(c).type) for c in table.column_names]
    pq.write_table(pa.Table.from_arrays(arrays, schema=table.schema), dst / "manifest.parquet")
    doc = json.loads((dst / "dataset.json").read_text())
    doc["format_version"] = 2
    doc.pop("files", None)
    seal(dst, doc)  # dataset.json and SHA256SUMS over the rewritten files


def test_a_version_2_dataset_reads_its_npy_and_png_members_as_the_tiffs(
    dense_dir: Path, tmp_path: Path
) -> None:
    from mars_pairs.store.verify import verify_dataset

    old_root = tmp_path / "v2"
    _as_version_2(dense_dir, old_root)
    assert not verify_dataset(old_root).damage
    with (
        MarsPairsDataset(dense_dir, fields=FIELDS) as new,
        MarsPairsDataset(old_root, fields=FIELDS, verify=True) as old,
    ):
        assert len(old) == len(new) > 0
        for i in range(len(new)):
            a = new[i]
            b = old[old.index_of(a["meta"]["key"])]
            for field in FIELDS:
                assert a[field].dtype == b[field].dtype, field
                assert torch.equal(a[field].nan_to_num(-1), b[field].nan_to_num(-1)), field
        assert old.member_name(0, "hits").endswith(".hits.npy")
        assert old.member_name(0, "ground_on_map").endswith(".ground_on_map.png")
        assert old.member_name(0, "ground_px").endswith(".ground_px.tif")
        assert new.member_name(0, "hits").endswith(".hits.tif")
