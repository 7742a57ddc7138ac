"""Georeferenced samples: crs, bounds, transform and rotation against meta.json and rasterio."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import rasterio
import torch
from pyproj import CRS

from mars_pairs import Manifest
from mars_pairs.torch import ALL_FIELDS, MarsPairsDataset, collate_samples
from support.members import metas


@pytest.mark.parametrize("which", ["dataset_dir", "heading_up_dir"])
def test_transform_bounds_rotation_and_crs_match_the_build(
    which: str, request: pytest.FixtureRequest
) -> None:
    root: Path = request.getfixturevalue(which)
    by_key = metas(root)
    rows = {
        r["key"]: r
        for r in Manifest.open(root).to_table().to_pylist()  # the manifest's chip columns
    }
    crs = CRS.from_user_input(json.loads((root / "dataset.json").read_text())["crs"])
    rotations = []
    with MarsPairsDataset(root, fields=("ortho",)) as ds:
        for i in range(len(ds)):
            s = ds[i]
            key = s["meta"]["key"]
            meta, row = by_key[key], rows[key]
            np.testing.assert_allclose(
                s["transform"].numpy(), meta["chip_transform"], rtol=1e-12, atol=1e-6
            )
            bounds = [row[f"chip_{c}"] for c in ("xmin", "ymin", "xmax", "ymax")]
            assert s["bounds"].tolist() == bounds
            assert float(s["rotation"]) == row["chip_rotation_deg"]
            assert CRS.from_user_input(s["crs"]).equals(crs)
            assert CRS.from_user_input(meta["crs"]).equals(crs)
            rotations.append(row["chip_rotation_deg"])
    if which == "heading_up_dir":
        assert len({round(r) for r in rotations}) > 2  # really rotated grids


def test_chips_are_the_rasters_through_the_transform(
    heading_up_dir: Path, mission_dir: Path
) -> None:
    """Read the orbital ortho and DEM with rasterio at the map points of chip pixel centres."""
    with (
        MarsPairsDataset(heading_up_dir, fields=("ortho", "dem")) as ds,
        rasterio.open(mission_dir / "orbital" / "ortho.tif") as ortho,
        rasterio.open(mission_dir / "orbital" / "dem.tif") as dem,
    ):
        for i in range(0, len(ds), 2):
            s = ds[i]
            a, b, c, d, e, f = s["transform"].tolist()
            rows, cols = np.mgrid[2:126:5, 2:126:5]
            x = a * (cols + 0.5) + b * (rows + 0.5) + c
            y = d * (cols + 0.5) + e * (rows + 0.5) + f
            truth = np.array([v[0] for v in ortho.sample(np.c_[x.ravel(), y.ravel()])], float)
            chip = s["ortho"][0].numpy()[rows.ravel(), cols.ravel()].astype(float)
            assert np.corrcoef(truth, chip)[0, 1] > 0.9
            heights = np.array([v[0] for v in dem.sample(np.c_[x.ravel(), y.ravel()])], float)
            ours = s["dem"][0].numpy()[rows.ravel(), cols.ravel()]
            assert np.median(np.abs(heights - ours)) < 0.3  # metres


def test_corr_ground_names_the_strided_pixels(dataset_dir: Path) -> None:
    stride = json.loads((dataset_dir / "dataset.json").read_text())["config"]["geometry"][
        "ray_stride"
    ]
    for size in (None, (150, 206)):
        with MarsPairsDataset(dataset_dir, fields=("ground", "corr"), ground_size=size) as ds:
            s = ds[1]
        rows = Manifest.open(dataset_dir).to_table(columns=["key", "width", "height"]).to_pylist()
        row = next(r for r in rows if r["key"] == s["meta"]["key"])
        width, height = row["width"], row["height"]
        h, w = s["ground"].shape[-2:]
        gx, gy = s["corr_ground"][0].double(), s["corr_ground"][1].double()
        assert s["corr_ground"].shape == s["corr"].shape
        j = torch.arange(s["corr"].shape[2], dtype=torch.float64)
        i = torch.arange(s["corr"].shape[1], dtype=torch.float64)
        torch.testing.assert_close(gx[0], (j * stride + 0.5) * w / width)
        torch.testing.assert_close(gy[:, 0], (i * stride + 0.5) * h / height)
        assert float(gx.max()) < w and float(gy.max()) < h


def test_georeferencing_batches(dataset_dir: Path) -> None:
    with MarsPairsDataset(dataset_dir, fields=ALL_FIELDS, ground_size=32) as ds:
        batch = collate_samples(ds.__getitems__([0, 3, 5]))
        single = ds[3]
    assert batch["transform"].shape == (3, 6) and batch["transform"].dtype == torch.float64
    assert batch["bounds"].shape == (3, 4) and batch["rotation"].shape == (3,)
    assert torch.equal(batch["transform"][1], single["transform"])
    assert batch["crs"] == [single["crs"]] * 3 and isinstance(single["crs"], str)
    side = float(batch["bounds"][0, 2] - batch["bounds"][0, 0])
    assert math.isclose(side, 128.0)  # chips of 128 m, north-up
