"""Carry a terrain-class map from the ground image to the orbital chip, and back.

    python examples/carry_terrain_classes.py --dataset out/dense/dataset [--out classes.png]

The dataset must be built with the dense members (``output: {members: all}`` in the build
config, or at least ``ground_on_map`` and ``hits``). A real pipeline would take the class map
from a segmentation network run on the ground image; here a stand-in labels each ground pixel
by its brightness (3 classes: dark, mid, bright, each view's own terciles). ``CarryToChip``
lays the per-pixel classes on the chip grid (nearest: labels stay labels; only chip pixels
the camera sees are covered, so occluded terrain gets no label), and ``CarryToImage``
carries a chip raster (here the ortho's own brightness classes) into the image through each
ray's first terrain hit. The script prints how often the two agree where both exist and,
with ``--out``, draws them.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mars_pairs.torch import MarsPairsDataset
from mars_pairs.torch.transforms import CarryToChip, CarryToImage, Compose

FIELDS = ("ground", "ortho", "ground_on_map_cover", "ground_px", "hits")


def brightness_classes(image: torch.Tensor, edges: tuple[float, float]) -> torch.Tensor:
    """int16 [1, H, W] classes 0..2 of a uint8 [C, H, W] image's mean brightness."""
    grey = image.float().mean(dim=0, keepdim=True)
    return torch.bucketize(grey, torch.tensor(edges)).to(torch.int16)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, required=True)
    parser.add_argument("--index", type=int, default=None, help="default: best covered")
    parser.add_argument("--out", type=Path, help="a PNG of the classes in both views")
    args = parser.parse_args()
    with MarsPairsDataset(args.dataset, fields=FIELDS) as ds:
        if args.index is None:
            covered = [int(ds[i]["ground_on_map_cover"].sum()) for i in range(len(ds))]
            args.index = int(np.argmax(covered))
        sample = ds[args.index]
    # each view's own brightness terciles over the terrain both see (the ground image is
    # tinted and compressed: the same terrain is not the same grey in both)
    cover = sample["ground_on_map_cover"][0].bool()
    px = sample["ground_px"][:, cover].round().long()
    grey = sample["ground"].float().mean(dim=0)[px[1], px[0]].numpy()
    ground_edges = tuple(float(v) for v in np.percentile(grey, [33, 66]))
    chip_edges = tuple(float(v) for v in np.percentile(sample["ortho"][0][cover], [33, 66]))
    sample["ground_classes"] = brightness_classes(sample["ground"], ground_edges)
    sample["chip_classes"] = brightness_classes(sample["ortho"], chip_edges)
    carry = Compose([
        CarryToChip("ground_classes", "classes_on_chip", nearest=True, fill=-1),
        CarryToImage("chip_classes", "classes_in_image", nearest=True, fill=-1),
    ])  # fmt: skip
    out = carry(sample)
    on_chip, ok = out["classes_on_chip"][0], out["classes_on_chip_valid"]
    agree = (on_chip[ok] == sample["chip_classes"][0][ok]).float().mean()
    print(f"sample {args.index}: {int(ok.sum())} chip pixels labelled from the image; "
          f"{float(agree):.1%} agree with the chip's own classes")  # fmt: skip
    in_image, ok = out["classes_in_image"][0], out["classes_in_image_valid"]
    print(f"{int(ok.sum())} dense image pixels labelled from the chip")
    if args.out:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, 3, figsize=(15, 5))
        axes[0].imshow(sample["ground_classes"][0], cmap="viridis", vmin=-1, vmax=2)
        axes[0].set_title("classes in the ground image")
        axes[1].imshow(sample["ortho"][0], cmap="gray")
        axes[1].imshow(np.ma.masked_less(on_chip.numpy(), 0), cmap="viridis", vmin=-1, vmax=2)
        axes[1].set_title("... carried to the chip (visible pixels only)")
        axes[2].imshow(np.ma.masked_less(in_image.numpy(), 0), cmap="viridis", vmin=-1, vmax=2)
        axes[2].set_title("chip classes carried into the image (dense grid)")
        fig.tight_layout()
        fig.savefig(args.out, dpi=100)
        print(args.out)


if __name__ == "__main__":
    main()
