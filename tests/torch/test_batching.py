"""A plain DataLoader batches every dataset (ground images padded to the largest frame with a
mask), unbind_samples gives the samples back, plot() draws a batch, reprs say what is read."""

from __future__ import annotations

from pathlib import Path

import pyarrow.parquet as pq
import pytest
import torch
from torch.utils.data import DataLoader

from mars_pairs.torch import (
    ALL_FIELDS,
    MISSING_INT,
    MarsPairsDataset,
    MarsPairsIterableDataset,
    MarsPairsLoader,
    unbind_samples,
)


def frames(root: Path) -> dict[str, tuple[int, int]]:
    rows = pq.read_table(root / "manifest.parquet", columns=["key", "width", "height"])
    return {r["key"]: (r["height"], r["width"]) for r in rows.to_pylist()}


def test_a_plain_dataloader_batches_mixed_frames(dataset_dir: Path) -> None:
    sizes = frames(dataset_dir)
    largest = (max(h for h, _ in sizes.values()), max(w for _, w in sizes.values()))
    with (
        MarsPairsDataset(dataset_dir, fields=ALL_FIELDS) as ds,
        MarsPairsDataset(dataset_dir, fields=ALL_FIELDS, pad=False) as native,
    ):
        assert ds.frame_hw == largest
        seen = 0
        for batch in DataLoader(ds, batch_size=4):  # torch's default_collate
            assert batch["ground"].shape[1:] == (3, *largest)
            assert batch["ground_mask"].dtype == torch.bool
            for j, key in enumerate(batch["meta"]["key"]):
                h, w = sizes[key]
                mask = batch["ground_mask"][j, 0]
                assert int(mask.sum()) == h * w and bool(mask[:h, :w].all())
                own = native[native.index_of(key)]
                # the image's own pixels unmoved (top-left), zeros around; keypoints NaN-padded
                assert torch.equal(batch["ground"][j][:, :h, :w], own["ground"])
                pad = batch["ground"][j].clone()
                pad[:, :h, :w] = 0
                assert int(pad.sum()) == 0
                gh, gw = own["corr"].shape[1:]
                assert torch.equal(batch["corr"][j][:, :gh, :gw].nan_to_num(-1),
                                   own["corr"].nan_to_num(-1))  # fmt: skip
                assert batch["corr"][j][:, gh:].isnan().all()
                assert torch.equal(batch["corr_ground"][j][:, :gh, :gw], own["corr_ground"])
                seen += 1
        assert seen == len(ds)
        # samples come back out of a batch as ds[i] gives them
        batch = next(iter(DataLoader(ds, batch_size=3)))
        samples = unbind_samples(batch)
        assert len(samples) == 3
        for j, s in enumerate(samples):
            single = ds[j]
            assert s["meta"] == single["meta"] and s["crs"] == single["crs"]
            assert torch.equal(s["ground"], single["ground"])
            assert torch.equal(s["transform"], single["transform"])
        # our collate keeps differing sizes as lists; unbind takes those too
        loose = next(iter(MarsPairsLoader(native, batch_size=len(native))))
        assert [s["meta"]["key"] for s in unbind_samples(loose)] == loose["meta"]["key"]
        assert unbind_samples(single) == [single]


def test_reprs_name_the_folder_rows_splits_and_fields(dataset_dir: Path) -> None:
    splits = pq.read_table(dataset_dir / "manifest.parquet", columns=["split"])["split"]
    with MarsPairsDataset(dataset_dir, fields=("ground", "ortho")) as ds:
        text = repr(ds)
        assert str(dataset_dir) in text and f"rows: {len(ds)}" in text
        for name in set(splits.to_pylist()):
            assert f"{name} {splits.to_pylist().count(name)}" in text
        assert "fields: ground, ortho" in text and "ground_mask" in text
        loader = repr(MarsPairsLoader(ds, batch_size=4))
        assert "batch_size=4" in loader and str(dataset_dir) in loader
    with MarsPairsIterableDataset(dataset_dir, pad=False) as stream:
        assert "native sizes" in repr(stream) and "shards:" in repr(stream)


def test_plot_draws_a_batch(dataset_dir: Path) -> None:
    pytest.importorskip("matplotlib")
    from mars_pairs.viz.common import pyplot

    with MarsPairsDataset(dataset_dir, fields=ALL_FIELDS) as ds:
        batch = next(iter(DataLoader(ds, batch_size=5)))
        fig = ds.plot(batch, max_samples=4)
        loose = ds.plot(next(iter(MarsPairsLoader(MarsPairsDataset(dataset_dir, pad=False),
                                                   batch_size=2))))  # fmt: skip
    try:
        assert len(fig.axes) == 3 * 4  # ground, ortho, DEM rows; four columns
        assert "first 4 shown" in fig._suptitle.get_text()
        assert [a.get_ylabel() for a in fig.axes[::4]] == ["ground image", "ortho + viewshed",
                                                           "DEM (shaded)"]  # fmt: skip
        assert len(loose.axes) == 3 * 2
    finally:
        pyplot().close(fig)
        pyplot().close(loose)


def test_ground_transforms_move_the_mask_with_the_image() -> None:
    from mars_pairs.torch.transforms import Crop, Flip, Resize

    mask = torch.zeros((1, 10, 20), dtype=torch.bool)
    mask[:, :7, :12] = True  # a 7 x 12 image padded to 10 x 20
    ground = mask.to(torch.uint8).expand(3, -1, -1) * 200
    sample = {"ground": ground.clone(), "ground_mask": mask}
    flipped = Flip("horizontal", target="ground")(sample)
    assert flipped["ground_mask"].dtype == torch.bool
    assert torch.equal(flipped["ground_mask"], torch.flip(mask, dims=(-1,)))
    resized = Resize(ground=(20, 40))(sample)["ground_mask"]
    assert resized.shape == (1, 20, 40) and int(resized.sum()) == 14 * 24
    cut = Crop(0, 0, 5, 10, target="ground")(sample)["ground_mask"]
    assert bool(cut.all())
    # the mask stays where the image's own (bright) pixels went
    for out in (Flip("horizontal", target="ground")(sample), Resize(ground=(20, 40))(sample)):
        assert torch.equal(out["ground_mask"][0], out["ground"][0] > 100)


def test_meta_with_missing_values_batches_with_the_default_collate(
    dataset_dir: Path, tmp_path: Path
) -> None:
    import math
    import shutil

    import pyarrow as pa

    root = Path(shutil.copytree(dataset_dir, tmp_path / "ds"))
    table = pq.read_table(root / "manifest.parquet")
    missing = [j % 2 == 0 for j in range(table.num_rows)]  # every other row lacks them
    for name in ("sol", "site", "max_visible_range_m", "localization"):
        column = table[name].combine_chunks()
        nulls = pa.array([None] * table.num_rows, type=column.type)
        k = table.schema.get_field_index(name)
        table = table.set_column(k, name, pa.compute.if_else(pa.array(missing), nulls, column))
    pq.write_table(table, root / "manifest.parquet")
    truth = {r["key"]: r for r in table.to_pylist()}  # the manifest, nulls as None
    with MarsPairsDataset(root) as ds, MarsPairsIterableDataset(root) as stream:
        seen = 0
        for batch in DataLoader(ds, batch_size=4):  # torch's default_collate
            meta = batch["meta"]
            assert meta["sol"].dtype == torch.int64 and meta["site"].dtype == torch.int64
            assert meta["max_visible_range_m"].dtype == torch.float64
            for j, key in enumerate(meta["key"]):
                row = truth[key]
                if row["sol"] is None:
                    assert int(meta["sol"][j]) == MISSING_INT == int(meta["site"][j])
                    assert math.isnan(float(meta["max_visible_range_m"][j]))
                    assert meta["localization"][j] == ""
                else:
                    assert int(meta["sol"][j]) == row["sol"]
                    assert int(meta["site"][j]) == row["site"]
                    assert float(meta["max_visible_range_m"][j]) == row["max_visible_range_m"]
                    assert meta["localization"][j] == row["localization"]
                seen += 1
            assert [s["meta"]["key"] for s in unbind_samples(batch)] == meta["key"]
        assert seen == len(ds) == table.num_rows
        assert sum(len(b["meta"]["key"]) for b in DataLoader(stream, batch_size=4)) == seen
        lacking = ds[ds.index_of(next(k for k, r in truth.items() if r["sol"] is None))]
        assert lacking["meta"]["sol"] == MISSING_INT and lacking["meta"]["localization"] == ""
