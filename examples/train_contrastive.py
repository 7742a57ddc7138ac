"""Cross-view contrastive learning on a mars-pairs dataset: ground image <-> orbital chip.

    python examples/train_contrastive.py --dataset out/demo/dataset --steps 300

Two tiny CNN encoders embed the ground image (resized to --image-size) and the ortho chip
(+ the normalised DEM as a second channel, unless --no-dem) into a shared unit sphere; the
loss is a symmetric InfoNCE over the batch. Images taken at the same rover position share one
chip, so every pair from the same position counts as a positive (multi-positive InfoNCE).

The dataset's transforms resize the chips and make float32 images; the dataset is small, so
it is decoded once and kept in memory (for a large dataset, give the augmentations to
``MarsPairsDataset(transform=...)`` and iterate a ``mars_pairs.torch.MarsPairsLoader``, a
DataLoader whose workers reuse their shared memory). Every training step augments
its samples with transforms that keep the pairing (``mars_pairs.torch.transforms``: a random
chip crop, which moves the chip's georeferencing and keypoints with it, and colour jitter of
the ground image); ``--plot PNG`` writes ``MarsPairsDataset.plot`` of an augmented sample.
At the end it prints ground->ortho retrieval recall@1/@5 against the distinct chips
of the val split (or of all samples when val has fewer than 2 positions), with chance levels.
Deterministic for a given --seed (single-threaded CPU by default).
"""

from __future__ import annotations

import argparse
import random
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mars_pairs.torch import MarsPairsDataset
from mars_pairs.torch.transforms import ColorJitter, Compose, Crop, RandomCrop, Resize, ToFloat


class Encoder(nn.Module):
    """Four stride-2 conv + GroupNorm layers, global average pooling, a linear head, L2 norm."""

    def __init__(self, in_channels: int, dim: int = 64, width: int = 32) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        channels = in_channels
        for out in (width // 2, width, width * 2, width * 2):
            layers += [
                nn.Conv2d(channels, out, 3, stride=2, padding=1),
                nn.GroupNorm(4, out),
                nn.GELU(),
            ]
            channels = out
        self.features = nn.Sequential(*layers)
        self.head = nn.Linear(channels, dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.normalize(self.head(self.features(x).mean(dim=(2, 3))), dim=-1)


def info_nce(
    g: torch.Tensor, o: torch.Tensor, loc: torch.Tensor, temperature: float
) -> torch.Tensor:
    """Symmetric multi-positive InfoNCE: pairs with the same location id are positives."""
    logits = g @ o.T / temperature
    positive = loc[:, None] == loc[None, :]
    masked = logits.masked_fill(~positive, float("-inf"))
    g2o = torch.logsumexp(logits, dim=1) - torch.logsumexp(masked, dim=1)
    o2g = torch.logsumexp(logits, dim=0) - torch.logsumexp(masked, dim=0)
    return (g2o.mean() + o2g.mean()) / 2


PAD = 8  # chips are resized to image_size + PAD, then cropped (randomly while training)


def load(root: Path, image_size: int, use_dem: bool) -> tuple[MarsPairsDataset, list[dict]]:
    """Decode every sample once, through the dataset's transforms: the ground image resized
    to image_size (at decode), the chips to image_size + PAD, images to float32."""
    fields = ("ground", "ortho", "dem", "corr") if use_dem else ("ground", "ortho", "corr")
    base = Compose([Resize(chip=image_size + PAD), ToFloat()])
    ds = MarsPairsDataset(
        root, fields=fields, ground_size=image_size, normalize_dem=True, transform=base
    )
    if len(ds) < 2:
        raise SystemExit(f"{root}: need at least 2 samples, found {len(ds)}")
    return ds, [ds[i] for i in range(len(ds))]


def location_ids(samples: list[dict]) -> torch.Tensor:
    """One id per rover position (images from the same stop share a chip)."""
    ids: dict[tuple[float, float], int] = {}
    return torch.tensor(
        [
            ids.setdefault(
                (round(s["meta"]["easting"], 1), round(s["meta"]["northing"], 1)), len(ids)
            )
            for s in samples
        ]
    )


def tensors(samples: list[dict], use_dem: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """Ground [N, 3, S, S] and chip [N, C, S, S] batches of samples."""
    ground = torch.stack([s["ground"] for s in samples])
    chip = torch.stack([s["ortho"] for s in samples])
    if use_dem:  # ~unit scale (metres / 20)
        chip = torch.cat([chip, torch.stack([s["dem"] for s in samples]) / 20.0], dim=1)
    return ground, chip


class Standardize:
    """Zero mean, unit variance per channel, with statistics of the whole (unaugmented) set."""

    def __init__(self, x: torch.Tensor) -> None:
        self.mean = x.mean(dim=(0, 2, 3), keepdim=True)
        self.std = x.std(dim=(0, 2, 3), keepdim=True).clamp_min(1e-6)

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.mean) / self.std


@torch.no_grad()
def recall(
    genc: Encoder, oenc: Encoder, ground: torch.Tensor, chip: torch.Tensor, loc: torch.Tensor
) -> tuple[float, float, int]:
    """Ground->ortho recall@1 and @5 against the distinct chips; and their number."""
    uniq, first = np.unique(loc.numpy(), return_index=True)
    gallery = oenc(chip[torch.from_numpy(first)])
    sims = genc(ground) @ gallery.T
    order = sims.argsort(dim=1, descending=True)
    truth = torch.from_numpy(np.searchsorted(uniq, loc.numpy()))
    rank = (order == truth[:, None]).float().argmax(dim=1)
    return float((rank < 1).float().mean()), float((rank < 5).float().mean()), len(uniq)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--dataset", type=Path, default=Path("out/demo/dataset"))
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--batch-size", type=int, default=16)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--lr", type=float, default=2e-3)
    p.add_argument("--image-size", type=int, default=64)
    p.add_argument("--temperature", type=float, default=0.1)
    p.add_argument("--log-every", type=int, default=25)
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    p.add_argument("--no-dem", action="store_true", help="ortho chip only, no DEM channel")
    p.add_argument("--plot", type=Path, help="write the figure of an augmented sample (PNG)")
    args = p.parse_args(argv)

    random.seed(args.seed)
    np.random.seed(args.seed)
    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    torch.use_deterministic_algorithms(True)

    t0 = time.perf_counter()
    use_dem = not args.no_dem
    ds, samples = load(args.dataset, args.image_size, use_dem)
    n, size = len(samples), args.image_size
    loc = location_ids(samples)
    splits = [s["meta"]["split"] for s in samples]
    gen = torch.Generator().manual_seed(args.seed)
    # augmentations that keep the pairing: chip crops move the chip's transform and keypoints
    augment = Compose(
        [RandomCrop(size, target="chip", generator=gen), ColorJitter(0.2, 0.2, 0.1, generator=gen)]
    )
    centre = Crop(PAD // 2, PAD // 2, size, size, target="chip")
    plain = [centre(s) for s in samples]
    ground_all, chip_all = tensors(plain, use_dem)
    norm_ground, norm_chip = Standardize(ground_all), Standardize(chip_all)
    print(
        f"{n} samples at {len(set(loc.tolist()))} positions, ground {tuple(ground_all.shape[1:])}, "
        f"chip {tuple(chip_all.shape[1:])}; decoded in {time.perf_counter() - t0:.1f} s"
    )
    if args.plot is not None:
        fig = ds.plot(augment(samples[0]), title="an augmented training sample")
        fig.savefig(args.plot, dpi=60)
        print(f"wrote {args.plot}")
    genc, oenc = Encoder(3), Encoder(chip_all.shape[1])
    opt = torch.optim.AdamW([*genc.parameters(), *oenc.parameters()], lr=args.lr)
    batch = min(args.batch_size, n)
    order = torch.randperm(n, generator=gen)
    cursor, window = 0, []
    t1 = time.perf_counter()
    for step in range(1, args.steps + 1):
        if cursor + batch > n:
            order, cursor = torch.randperm(n, generator=gen), 0
        idx = order[cursor : cursor + batch]
        cursor += batch
        g, c = tensors([augment(samples[int(i)]) for i in idx], use_dem)
        loss = info_nce(genc(norm_ground(g)), oenc(norm_chip(c)), loc[idx], args.temperature)
        opt.zero_grad()
        loss.backward()
        opt.step()
        window.append(loss.item())
        if step % args.log_every == 0 or step == args.steps:
            print(f"step {step:5d} loss {np.mean(window):.4f}", flush=True)
            window = []
    print(f"trained {args.steps} steps in {time.perf_counter() - t1:.1f} s")
    ground, chip = norm_ground(ground_all), norm_chip(chip_all)

    genc.eval()
    oenc.eval()
    val = torch.tensor([s == "val" for s in splits])
    subsets = [("train", torch.tensor([s == "train" for s in splits])), ("val", val)]
    if len(set(loc[val].tolist())) < 2:
        print("val has fewer than 2 positions: evaluating on all samples")
        subsets.append(("all", torch.ones(n, dtype=torch.bool)))
    for name, mask in subsets:
        if len(set(loc[mask].tolist())) < 2:
            continue
        r1, r5, m = recall(genc, oenc, ground[mask], chip[mask], loc[mask])
        print(
            f"{name:5s} ground->ortho over {m} chips ({int(mask.sum())} queries): "
            f"recall@1 {r1:.3f} (chance {1 / m:.3f})  recall@5 {r5:.3f} "
            f"(chance {min(5, m) / m:.3f})"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
