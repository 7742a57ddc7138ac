"""Torch datasets over a small built dataset: decoding, filters, loaders, workers, ranks."""

from __future__ import annotations

import io
import json
import math
import re
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from PIL import Image
from torch.utils.data import DataLoader

import mars_pairs.torch.datasets as mpd
import mars_pairs.torch.streaming as mps
from mars_pairs import Manifest
from mars_pairs.errors import ArgumentError
from mars_pairs.torch import MarsPairsDataset, MarsPairsIterableDataset, collate_samples
from support.members import dem_metres, manifest_keys

pytestmark = pytest.mark.slow  # its tests share a fixture of > 3 s

ROOT = Path(__file__).resolve().parents[2]


def filtered_keys(root: Path, **filters: Any) -> set[str]:
    table = Manifest.open(root).filter(**filters).to_table(columns=["key"])
    return set(table.column("key").to_pylist())


def dataset_keys(ds: MarsPairsDataset) -> list[str]:
    return [ds[i]["meta"]["key"] for i in range(len(ds))]


def member(members: dict[str, bytes], key: str, suffix: str) -> bytes:
    return members[f"{key}.{suffix}"]


# -- map-style samples ---------------------------------------------------------------------------
GEO_KEYS = {"crs", "bounds", "transform", "rotation"}


def test_samples_match_the_tar_members(dataset_dir: Path, members: dict[str, bytes]) -> None:
    ds = MarsPairsDataset(
        dataset_dir, fields=mpd.ALL_FIELDS, image_dtype=torch.float32, pad=False
    )  # native sizes: the members as the tar holds them
    assert len(ds) == 9
    assert sorted(dataset_keys(ds)) == sorted(manifest_keys(dataset_dir))
    for i in range(len(ds)):
        s = ds[i]
        key = s["meta"]["key"]
        assert set(s) == {
            "ground",
            "ortho",
            "dem",
            "viewshed",
            "corr",
            "corr_ground",
            "meta",
        }.union(GEO_KEYS)

        with Image.open(io.BytesIO(member(members, key, "ground.jpg"))) as im:
            ground = np.asarray(im.convert("RGB"), dtype=np.float32).transpose(2, 0, 1) / 255
        assert s["ground"].dtype == torch.float32 and s["ground"].shape == ground.shape
        assert float(s["ground"].min()) >= 0.0 and float(s["ground"].max()) <= 1.0
        np.testing.assert_allclose(s["ground"].numpy(), ground, atol=1e-6)

        with Image.open(io.BytesIO(member(members, key, "ortho.png"))) as im:
            ortho = np.asarray(im, dtype=np.float32) / 255
        assert s["ortho"].dtype == torch.float32 and s["ortho"].shape == (1, *ortho.shape)
        np.testing.assert_allclose(s["ortho"][0].numpy(), ortho, atol=1e-6)

        dem = dem_metres(member(members, key, "dem.tif"))  # GDAL's reading
        assert s["dem"].dtype == torch.float32 and s["dem"].shape == (1, *dem.shape)
        np.testing.assert_array_equal(s["dem"][0].numpy(), dem)  # exact: powers of two
        finite = dem[np.isfinite(dem)]
        assert finite.size and -9000 < finite.min() < 0  # metres above the areoid (Jezero)

        with Image.open(io.BytesIO(member(members, key, "viewshed.png"))) as im:
            vis = np.asarray(im) > 127
        assert s["viewshed"].dtype == torch.float32 and s["viewshed"].shape == (1, *vis.shape)
        assert set(np.unique(s["viewshed"].numpy())) <= {0.0, 1.0}
        np.testing.assert_array_equal(s["viewshed"][0].numpy() == 1.0, vis)

        meta = json.loads(member(members, key, "meta.json"))
        corr = np.load(io.BytesIO(member(members, key, "corr.npy")))
        k = meta["ray_stride"]
        height, width = ground.shape[1:]
        assert s["corr"].dtype == torch.float32
        assert s["corr"].shape == (2, math.ceil(height / k), math.ceil(width / k))
        np.testing.assert_array_equal(s["corr"].numpy(), corr.transpose(2, 0, 1))

        for name, value in s["meta"].items():
            assert value is None or type(value) in (str, int, float, bool), (name, value)
            if name in meta:
                assert value == pytest.approx(meta[name]), name


def test_normalized_dem_is_the_chip_minus_its_median(
    dataset_dir: Path, members: dict[str, bytes]
) -> None:
    ds = MarsPairsDataset(dataset_dir, fields=("dem",), normalize_dem=True)
    for i in range(len(ds)):
        s = ds[i]
        dem = dem_metres(member(members, s["meta"]["key"], "dem.tif"))
        finite = np.isfinite(dem)
        expected = np.where(finite, dem - np.median(dem[finite]), 0.0)
        assert s["dem"].dtype == torch.float32 and torch.isfinite(s["dem"]).all()
        np.testing.assert_allclose(s["dem"][0].numpy(), expected, atol=1e-3)
        assert abs(float(s["dem"].median())) < 1.0


def test_uint8_images_are_the_default(dataset_dir: Path) -> None:
    floats = MarsPairsDataset(
        dataset_dir, fields=mpd.ALL_FIELDS, ground_size=40, image_dtype=torch.float32
    )
    ints = MarsPairsDataset(dataset_dir, fields=mpd.ALL_FIELDS, ground_size=40)
    a, b = floats[2], ints[2]
    for name in ("ground", "ortho", "viewshed"):
        assert b[name].dtype == torch.uint8 and b[name].shape == a[name].shape
    assert torch.equal(b["ground"].float() / 255, a["ground"])
    assert torch.equal(b["ortho"].float() / 255, a["ortho"])
    assert torch.equal(b["viewshed"].float(), a["viewshed"])
    assert b["dem"].dtype == b["corr"].dtype == torch.float32
    batch = collate_samples(ints.__getitems__([0, 1, 2]))
    assert batch["ground"].dtype == torch.uint8 and batch["ground"].shape == (3, 3, 40, 40)
    assert torch.equal(batch["ground"][2], b["ground"])
    with pytest.raises(ValueError, match="image_dtype"):
        MarsPairsDataset(dataset_dir, image_dtype=torch.float64)


def test_batched_fetch_equals_single_items(dataset_dir: Path) -> None:
    ds = MarsPairsDataset(dataset_dir, fields=mpd.ALL_FIELDS, ground_size=(30, 40))
    samples = ds.__getitems__([4, 0, 7])
    batch = collate_samples(samples)
    for j, i in enumerate([4, 0, 7]):
        single = ds[i]
        assert samples[j]["meta"] == single["meta"]
        for name in mpd.ALL_FIELDS:
            np.testing.assert_array_equal(samples[j][name].numpy(), single[name].numpy())
            np.testing.assert_array_equal(batch[name][j].numpy(), single[name].numpy())
    # the rows of one buffer are handed on as that buffer, without a copy
    ptr = samples[0]["ground"].untyped_storage().data_ptr()
    assert batch["ground"].untyped_storage().data_ptr() == ptr


def _assert_same_sample(got: dict[str, Any], want: dict[str, Any]) -> None:
    assert got.keys() == want.keys()
    for name, value in want.items():
        if isinstance(value, torch.Tensor):
            assert got[name].dtype == value.dtype, name
            np.testing.assert_array_equal(got[name].numpy(), value.numpy(), err_msg=name)
        elif name == "meta":
            assert list(got[name]) == list(value)
            for key, v in value.items():
                w = got[name][key]
                assert w == v or (math.isnan(w) and math.isnan(v)), key
        else:
            assert got[name] == value, name


def test_batched_fetch_gives_every_value_of_single_items(dataset_dir: Path) -> None:
    # padded mixed frames (ground_mask), the placement and meta made for the batch at once
    ds = MarsPairsDataset(dataset_dir, fields=mpd.ALL_FIELDS)
    order = [5, 0, 3, 7, 1]
    samples = ds.__getitems__(order)
    for j, i in enumerate(order):
        _assert_same_sample(samples[j], ds[i])
    batch = collate_samples(samples)
    for name in ("bounds", "rotation", "transform", "ground_mask"):
        # rows of one [B, ...] tensor each, handed on without a copy
        ptr = samples[0][name].untyped_storage().data_ptr()
        assert batch[name].untyped_storage().data_ptr() == ptr, name
        assert torch.equal(batch[name], torch.stack([ds[i][name] for i in order]))


def test_members_side_by_side_are_read_in_one_call(dataset_dir: Path) -> None:
    ds = MarsPairsDataset(dataset_dir, fields=mpd.ALL_FIELDS)
    spans = [ds._index.location(2, f) for f in mpd.ALL_FIELDS]
    shard = spans[0][0]
    spans_in_order = sorted((offset, size) for _, offset, size in spans)
    got = ds._files.read_adjacent(shard, spans_in_order)
    assert got == [ds._files.read(shard, offset, size) for offset, size in spans_in_order]
    assert ds._files.read_adjacent(shard, spans_in_order[::-1]) is None  # out of order
    assert ds._files.read_adjacent(shard, spans_in_order, max_gap=0) is None  # headers between
    past = [*spans_in_order[:-1], (spans_in_order[-1][0], 1 << 40)]
    assert ds._files.read_adjacent(shard, past) is None  # past the end: read() names it


def test_open_descriptors_are_capped(dataset_dir: Path) -> None:
    ds = MarsPairsDataset(dataset_dir, fields=("ortho", "dem"))
    reference = [ds[i] for i in range(len(ds))]
    ds = MarsPairsDataset(dataset_dir, fields=("ortho", "dem"))
    ds._files.max_open = 1  # before any shard is open
    for i in range(len(ds)):
        s = ds[i]
        assert torch.equal(s["ortho"], reference[i]["ortho"])
        assert torch.equal(s["dem"], reference[i]["dem"])
        assert len(ds._files._files) == 1


def test_fields_and_transform(dataset_dir: Path) -> None:
    ds = MarsPairsDataset(
        dataset_dir,
        fields=("ortho",),
        transform=lambda s: {**s, "extra": s["ortho"].float().mean()},
    )
    s = ds[0]
    assert set(s) == {"ortho", "meta", "extra"} | GEO_KEYS
    with pytest.raises(ValueError, match="unknown field"):
        MarsPairsDataset(dataset_dir, fields=("ground", "nope"))
    with pytest.raises(TypeError, match="unknown filter"):
        MarsPairsDataset(dataset_dir, nearby=(0, 0, 1))


# -- filters -------------------------------------------------------------------------------------
def test_filters_match_the_manifest(dataset_dir: Path) -> None:
    table = Manifest.open(dataset_dir).to_table(columns=["key", "latitude", "longitude", "split"])
    lat = np.asarray(table.column("latitude").to_pylist())
    lon = np.asarray(table.column("longitude").to_pylist())
    splits = set(table.column("split").to_pylist())
    everything = manifest_keys(dataset_dir)
    cases: list[dict[str, Any]] = [{"split": s} for s in sorted(splits)]
    cases += [
        {"sol": (99_999, 99_999)},  # nothing
        {"near": (float(lon[0]), float(lat[0]), 1.0)},  # the first stop only
        {"near": (float(lon[0]), float(lat[0]), 1e6)},  # everything
        {
            "bbox_lonlat": (
                float(lon.min()) - 1e-6,
                float(lat.min()) - 1e-6,
                float(np.median(lon)),
                float(np.median(lat)),
            )
        },
        {"split": sorted(splits)[0], "near": (float(lon[-1]), float(lat[-1]), 50.0)},
    ]
    seen = set()
    for filters in cases:
        expected = filtered_keys(dataset_dir, **filters)
        ds = MarsPairsDataset(dataset_dir, fields=("viewshed",), **filters)
        keys = dataset_keys(ds)
        assert len(keys) == len(set(keys)) and set(keys) == expected, filters
        assert expected <= everything
        if "split" in filters and len(filters) == 1:
            assert all(ds[i]["meta"]["split"] == filters["split"] for i in range(len(ds)))
        seen.add(len(keys))
    # the cases are not all trivial: some subset strictly between nothing and everything
    assert 0 in seen and len(everything) in seen and any(0 < n < len(everything) for n in seen)
    assert 0 < len(filtered_keys(dataset_dir, near=(float(lon[0]), float(lat[0]), 1.0))) < 9
    # a split name the dataset does not know is refused, the known ones listed
    with pytest.raises(ArgumentError, match=r"'none-such'; its splits are .*train"):
        MarsPairsDataset(dataset_dir, split="none-such")


# -- batching and workers ------------------------------------------------------------------------
def test_ground_size_resizes_and_batches(dataset_dir: Path, members: dict[str, bytes]) -> None:
    ds = MarsPairsDataset(dataset_dir, ground_size=(48, 64), image_dtype=torch.float32)
    s = ds[0]
    assert s["ground"].shape == (3, 48, 64)
    with Image.open(io.BytesIO(member(members, s["meta"]["key"], "ground.jpg"))) as im:
        small = im.convert("RGB").resize((64, 48), Image.BILINEAR)
    np.testing.assert_allclose(
        s["ground"].numpy(), np.asarray(small, np.float32).transpose(2, 0, 1) / 255, atol=2 / 255
    )
    loader = DataLoader(ds, batch_size=4, collate_fn=collate_samples)
    batches = list(loader)
    assert [b["ground"].shape[0] for b in batches] == [4, 4, 1]
    b = batches[0]
    assert b["ground"].shape == (4, 3, 48, 64) and b["ground"].dtype == torch.float32
    assert b["ortho"].shape == (4, 1, 128, 128) and b["dem"].shape == (4, 1, 128, 128)
    assert b["viewshed"].shape == (4, 1, 128, 128)
    assert isinstance(b["meta"]["key"], list) and len(b["meta"]["key"]) == 4
    assert sorted(k for b in batches for k in b["meta"]["key"]) == sorted(dataset_keys(ds))


@pytest.mark.parametrize("context", ["fork", "spawn"])
def test_dataloader_with_two_workers(dataset_dir: Path, context: str) -> None:
    ds = MarsPairsDataset(dataset_dir, ground_size=32)
    loader = DataLoader(
        ds,
        batch_size=2,
        shuffle=True,
        num_workers=2,
        multiprocessing_context=context,
        collate_fn=collate_samples,
        generator=torch.Generator().manual_seed(0),
    )
    keys = []
    for batch in loader:
        # image fields cross as uint8, bit for bit the single items
        for j, key in enumerate(batch["meta"]["key"]):
            single = ds[dataset_keys(ds).index(key)]
            for name in (*mpd.DEFAULT_FIELDS, "transform", "bounds"):
                assert type(batch[name]) is torch.Tensor and batch[name].dtype == single[name].dtype
                assert torch.equal(batch[name][j], single[name]), (name, key)
            assert batch["ground"].dtype == torch.uint8
        keys += batch["meta"]["key"]
    assert sorted(keys) == sorted(manifest_keys(dataset_dir))


def stack_ground(batch: Sequence[dict[str, Any]]) -> tuple[torch.Tensor, list[str]]:
    """A collate function of the user's that indexes the samples itself."""
    return torch.stack([s["ground"] for s in batch]), [s["meta"]["key"] for s in batch]


def scale_after_collate(batch: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """A collate function of the user's that post-processes collate_samples in the worker."""
    out = collate_samples(batch)
    out["ground"] = out["ground"] * 2
    out["ortho_mean"] = torch.mean(out["ortho"], dim=(1, 2, 3))
    out["dem_shape"] = tuple(out["dem"].shape)
    return out


def test_worker_batches_with_other_collate_functions(dataset_dir: Path) -> None:
    ds = MarsPairsDataset(dataset_dir, ground_size=32, image_dtype=torch.float32)
    reference = collate_samples([ds[i] for i in range(4)])
    kwargs: dict[str, Any] = dict(batch_size=4, num_workers=1, multiprocessing_context="fork")
    ground, keys = next(iter(DataLoader(ds, collate_fn=stack_ground, **kwargs)))
    assert ground.dtype == torch.float32 and torch.equal(ground, reference["ground"])
    assert keys == reference["meta"]["key"]
    out = next(iter(DataLoader(ds, collate_fn=scale_after_collate, **kwargs)))
    assert torch.equal(out["ground"], reference["ground"] * 2)
    assert torch.equal(out["ortho_mean"], reference["ortho"].mean(dim=(1, 2, 3)))
    assert out["dem_shape"] == (4, 1, 128, 128)
    assert torch.equal(out["viewshed"], reference["viewshed"])


# -- streaming -----------------------------------------------------------------------------------
def stream_keys(ds: MarsPairsIterableDataset, workers: int = 0) -> list[str]:
    loader = DataLoader(
        ds,
        batch_size=None,
        num_workers=workers,
        multiprocessing_context="fork" if workers else None,
    )
    return [s["meta"]["key"] for s in loader]


def test_shard_order_lists_every_sample_once_in_file_order(dataset_dir: Path) -> None:
    with MarsPairsDataset(dataset_dir, fields=("viewshed", "dem")) as ds:
        order = ds.shard_order()
        assert sorted(int(i) for ids in order.values() for i in ids) == list(range(len(ds)))
        rows = Manifest.open(dataset_dir).to_table(columns=["key", "dem_shard", "dem_offset"])
        where = {r["key"]: (r["dem_shard"], r["dem_offset"]) for r in rows.to_pylist()}
        for shard, ids in ds.shard_order("dem").items():
            found = [where[ds[int(i)]["meta"]["key"]] for i in ids]
            assert {s for s, _ in found} == {shard}
            assert [o for _, o in found] == sorted(o for _, o in found)
        with pytest.raises(ArgumentError, match="ground"):
            ds.shard_order("ground")


def test_iterable_yields_every_sample_once_across_workers(dataset_dir: Path) -> None:
    ds = MarsPairsIterableDataset(dataset_dir, fields=("viewshed",), shuffle_buffer=4, seed=1)
    assert len(ds.shards) == 3 and len(ds) == 9
    single = stream_keys(ds)
    assert sorted(single) == sorted(manifest_keys(dataset_dir))
    assert single == stream_keys(ds)  # same epoch: same order
    two = stream_keys(ds, workers=2)
    assert sorted(two) == sorted(manifest_keys(dataset_dir))
    ds.set_epoch(1)
    assert sorted(stream_keys(ds)) == sorted(single)


def test_iterable_through_workers_gives_the_single_items(dataset_dir: Path) -> None:
    ds = MarsPairsIterableDataset(dataset_dir, ground_size=32, shuffle_buffer=3)
    single = MarsPairsDataset(dataset_dir, ground_size=32)
    by_key = {key: i for i, key in enumerate(dataset_keys(single))}
    kwargs: dict[str, Any] = dict(num_workers=2, multiprocessing_context="fork")
    unbatched = list(DataLoader(ds, batch_size=None, **kwargs))
    batched = list(DataLoader(ds, batch_size=4, collate_fn=collate_samples, **kwargs))
    rows = [(s, None) for s in unbatched] + [(b, j) for b in batched for j in range(4)]
    seen = 0
    for item, j in rows:
        keys = item["meta"]["key"]
        if j is not None and j >= len(keys):
            continue
        reference = single[by_key[keys if j is None else keys[j]]]
        for name in mpd.DEFAULT_FIELDS:
            value = item[name] if j is None else item[name][j]
            assert type(item[name]) is torch.Tensor and value.dtype == reference[name].dtype
            assert torch.equal(value, reference[name]), name
        seen += 1
    assert seen == 2 * len(single)


def test_iterable_splits_shards_across_ranks(
    dataset_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    ds = MarsPairsIterableDataset(dataset_dir, fields=("viewshed",), split=None, seed=3)
    per_rank: list[list[str]] = []
    per_rank_workers: list[list[str]] = []
    for rank in (0, 1):
        monkeypatch.setattr(mps, "_world", lambda rank=rank: (rank, 2))
        per_rank.append(stream_keys(ds))
        per_rank_workers.append(stream_keys(ds, workers=2))  # 2 ranks x 2 workers, 3 shards
    everything = manifest_keys(dataset_dir)
    for got in (per_rank, per_rank_workers):
        a, b = (set(keys) for keys in got)
        assert len(got[0]) == len(a) and len(got[1]) == len(b)
        assert a | b == everything and not a & b
        assert a and b


# -- the example ---------------------------------------------------------------------------------
def test_train_contrastive_example_runs_and_learns(dataset_dir: Path) -> None:
    script = ROOT / "examples" / "train_contrastive.py"
    plot = dataset_dir.parent / "augmented.png"
    args = ["--dataset", str(dataset_dir), "--steps", "60", "--batch-size", "6", "--seed", "0"]
    args += ["--plot", str(plot)]
    proc = subprocess.run(
        [sys.executable, str(script), *args, "--log-every", "10"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    losses = [float(x) for x in re.findall(r"^step\s+\d+\s+loss\s+([0-9.]+)", proc.stdout, re.M)]
    assert len(losses) >= 3, proc.stdout
    assert losses[-1] < losses[0], proc.stdout
    assert re.search(r"recall@1", proc.stdout) and re.search(r"chance", proc.stdout)
    # the polar method prints the untrained (plain NCC) table, then the trained one
    assert re.search(r"untrained.*\n(.*\n)*.*trained,", proc.stdout), proc.stdout
    with Image.open(plot) as im:  # the ground image and both polar grids of a sample
        assert im.format == "PNG" and im.size[0] > 500
    baseline = subprocess.run(
        [sys.executable, str(script), *args[:-2], "--method", "global", "--steps", "10"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert baseline.returncode == 0, baseline.stderr[-3000:]
    assert re.search(r"recall@1", baseline.stdout), baseline.stdout


def test_meta_names_units_and_reads_the_old_name(dataset_dir: Path) -> None:
    with MarsPairsDataset(dataset_dir, fields=("viewshed",)) as ds:
        meta = ds[0]["meta"]
        batch = collate_samples(ds.__getitems__([0, 1]))
    assert -9000 < meta["elevation_m"] < 0 and -90 <= meta["elevation_deg"] <= 90
    with pytest.warns(DeprecationWarning, match="elevation_m"):
        assert meta["elevation"] == meta["elevation_m"]
    assert "elevation" not in batch["meta"] and len(batch["meta"]["elevation_m"]) == 2


def test_a_dataset_built_before_the_rename_reads(dataset_dir: Path, tmp_path: Path) -> None:
    import shutil

    import pyarrow.parquet as pq

    old = Path(shutil.copytree(dataset_dir, tmp_path / "old"))
    table = pq.read_table(old / "manifest.parquet")
    names = ["elevation" if n == "elevation_m" else n for n in table.column_names]
    pq.write_table(table.rename_columns(names), old / "manifest.parquet")
    with MarsPairsDataset(old, fields=("ortho",)) as ds, MarsPairsDataset(dataset_dir) as new:
        assert ds[0]["meta"]["elevation_m"] == new[0]["meta"]["elevation_m"]
