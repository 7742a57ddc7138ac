"""Cross-view contrastive learning on a mars-pairs dataset: ground image <-> orbital chip.

    python examples/train_contrastive.py --dataset out/demo/dataset --steps 400

Two tiny CNN encoders embed the ground image (resized to --image-size) and the ortho chip
(+ the normalised DEM as a second channel, unless --no-dem) into a shared unit sphere; the
loss is a symmetric InfoNCE over the batch. It trains on the ``train`` split only and
evaluates on the held-out areas (VIGOR's cross-area protocol: the dataset's ``val`` and
``test`` areas are far from every train sample, see dataset.json ``splits``).

Positives are distance-aware, after VIGOR: a ground image's positive is its own chip (images
taken at the same rover position share one chip: multi-positive InfoNCE). Chips of other
positions within --near-m metres (default 64: half a 128 m chip, so they contain the query's
rover position; VIGOR's semi-positives) are left out of its negatives while training, neither
pulled nor pushed. Evaluation ranks every distinct chip of the split (the own chip must win
over its near neighbours too): recall@1/@5 of the own chip, and hit@1 (the top chip lies
within --near-m, so it contains the query's position), each printed beside its chance level.

The dataset's transforms resize the chips and make float32 images; the dataset is small, so
it is decoded once and kept in memory (for a large dataset, give the augmentations to
``MarsPairsDataset(transform=...)`` and iterate a ``mars_pairs.torch.MarsPairsLoader``, a
DataLoader whose workers reuse their shared memory). Every training step augments
its samples with transforms that keep the pairing (``mars_pairs.torch.transforms``: a random
chip crop, which moves the chip's georeferencing and keypoints with it, and colour jitter of
the ground image); ``--plot PNG`` writes ``MarsPairsDataset.plot`` of an augmented sample.
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
    g: torch.Tensor, o: torch.Tensor, loc: torch.Tensor, near: torch.Tensor, temperature: float
) -> torch.Tensor:
    """Symmetric multi-positive InfoNCE: pairs with the same location id are positives;
    pairs flagged ``near`` (other positions close by: semi-positives) are left out."""
    logits = g @ o.T / temperature
    positive = loc[:, None] == loc[None, :]
    logits = logits.masked_fill(near & ~positive, float("-inf"))
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


def location_ids(samples: list[dict]) -> tuple[torch.Tensor, torch.Tensor]:
    """One id per rover position (images from the same stop share a chip), and every
    sample's rover position (map easting, northing; metres in a projected dataset CRS)."""
    ids: dict[tuple[float, float], int] = {}
    xy = [(float(s["meta"]["easting"]), float(s["meta"]["northing"])) for s in samples]
    loc = [ids.setdefault((round(x, 1), round(y, 1)), len(ids)) for x, y in xy]
    return torch.tensor(loc), torch.tensor(xy, dtype=torch.float64)


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
    genc: Encoder, oenc: Encoder, ground: torch.Tensor, chip: torch.Tensor, loc: torch.Tensor,
    xy: torch.Tensor, near_m: float,
) -> dict[str, float]:  # fmt: skip
    """Ground->ortho retrieval over the distinct chips of these samples: recall@1/@5 of the
    own chip, hit@1 (top chip within ``near_m`` metres of the query's rover), their chance
    levels (a random ranking), the number of chips ("chips") and of queries ("queries")."""
    uniq, first = np.unique(loc.numpy(), return_index=True)
    pick = torch.from_numpy(first)
    gallery = oenc(chip[pick])
    sims = genc(ground) @ gallery.T
    order = sims.argsort(dim=1, descending=True)
    truth = torch.from_numpy(np.searchsorted(uniq, loc.numpy()))
    rank = (order == truth[:, None]).float().argmax(dim=1)
    close = torch.cdist(xy, xy[pick]) <= near_m  # [queries, chips]: chips holding the query
    top_close = close.gather(1, order[:, :1]).squeeze(1)
    m = len(uniq)
    return {
        "r1": float((rank < 1).float().mean()), "r5": float((rank < 5).float().mean()),
        "hit1": float(top_close.float().mean()), "chance_r1": 1 / m,
        "chance_r5": min(5, m) / m, "chance_hit1": float(close.float().mean()),
        "chips": m, "queries": len(loc),
    }  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--dataset", type=Path, default=Path("out/demo/dataset"))
    p.add_argument("--steps", type=int, default=400)
    p.add_argument("--batch-size", type=int, default=16)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--lr", type=float, default=2e-3)
    p.add_argument("--image-size", type=int, default=64)
    p.add_argument("--temperature", type=float, default=0.1)
    p.add_argument("--log-every", type=int, default=25)
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    p.add_argument("--no-dem", action="store_true", help="ortho chip only, no DEM channel")
    p.add_argument("--near-m", type=float, default=64.0,
                   help="chips of other positions within this (m) are semi-positives")  # fmt: skip
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
    loc, xy = location_ids(samples)
    splits = np.array([s["meta"]["split"] for s in samples])
    near = torch.cdist(xy, xy) <= args.near_m
    train_idx = torch.from_numpy(np.flatnonzero(splits == "train"))
    if len(set(loc[train_idx].tolist())) < 2:
        print("train has fewer than 2 positions: training on every sample, every other "
              "position a negative (a smoke test: its numbers prove nothing)")  # fmt: skip
        train_idx = torch.arange(n)
        near = torch.zeros_like(near)
    gen = torch.Generator().manual_seed(args.seed)
    # augmentations that keep the pairing: chip crops move the chip's transform and keypoints
    augment = Compose(
        [RandomCrop(size, target="chip", generator=gen), ColorJitter(0.2, 0.2, 0.1, generator=gen)]
    )
    centre = Crop(PAD // 2, PAD // 2, size, size, target="chip")
    plain = [centre(s) for s in samples]
    ground_all, chip_all = tensors(plain, use_dem)
    # statistics of the train split only: nothing is learnt from the held-out areas
    norm_ground, norm_chip = Standardize(ground_all[train_idx]), Standardize(chip_all[train_idx])
    counts = ", ".join(
        f"{name} {int((splits == name).sum())} ({len(set(loc[splits == name].tolist()))} pos.)"
        for name in ("train", "val", "test", "buffer")
    )
    print(
        f"{n} samples at {len(set(loc.tolist()))} positions: {counts}; ground "
        f"{tuple(ground_all.shape[1:])}, chip {tuple(chip_all.shape[1:])}; decoded in "
        f"{time.perf_counter() - t0:.1f} s"
    )
    if args.plot is not None:
        fig = ds.plot(augment(samples[0]), title="an augmented training sample")
        fig.savefig(args.plot, dpi=60)
        print(f"wrote {args.plot}")
    genc, oenc = Encoder(3), Encoder(chip_all.shape[1])
    opt = torch.optim.AdamW([*genc.parameters(), *oenc.parameters()], lr=args.lr)
    n_train = len(train_idx)
    batch = min(args.batch_size, n_train)
    order = train_idx[torch.randperm(n_train, generator=gen)]
    cursor, window = 0, []
    t1 = time.perf_counter()
    for step in range(1, args.steps + 1):
        if cursor + batch > n_train:
            order, cursor = train_idx[torch.randperm(n_train, generator=gen)], 0
        idx = order[cursor : cursor + batch]
        cursor += batch
        g, c = tensors([augment(samples[int(i)]) for i in idx], use_dem)
        loss = info_nce(genc(norm_ground(g)), oenc(norm_chip(c)), loc[idx],
                        near[idx][:, idx], args.temperature)  # fmt: skip
        opt.zero_grad()
        loss.backward()
        opt.step()
        window.append(loss.item())
        if step % args.log_every == 0 or step == args.steps:
            print(f"step {step:5d} loss {np.mean(window):.4f}", flush=True)
            window = []
    epochs = args.steps * batch / n_train
    print(f"trained {args.steps} steps ({epochs:.0f} epochs of train) in "
          f"{time.perf_counter() - t1:.1f} s")  # fmt: skip
    ground, chip = norm_ground(ground_all), norm_chip(chip_all)

    genc.eval()
    oenc.eval()
    print(f"ground->ortho retrieval over each split's distinct chips (chance in brackets; "
          f"hit@1: top chip within {args.near_m:g} m)")  # fmt: skip
    evaluated = 0
    for name in ("train", "val", "test", "all"):
        mask = torch.from_numpy(splits == name) if name != "all" else torch.ones(n, dtype=bool)
        if name == "all" and evaluated > 1:
            break
        if len(set(loc[mask].tolist())) < 2:
            print(f"{name:5s} fewer than 2 positions: not evaluated")
            continue
        evaluated += 1
        r = recall(genc, oenc, ground[mask], chip[mask], loc[mask], xy[mask], args.near_m)
        print(
            f"{name:5s} {r['queries']:3d} queries, {r['chips']:2d} chips: "
            f"recall@1 {r['r1']:.3f} ({r['chance_r1']:.3f})  "
            f"recall@5 {r['r5']:.3f} ({r['chance_r5']:.3f})  "
            f"hit@1 {r['hit1']:.3f} ({r['chance_hit1']:.3f})"
            + ("   <- seen in training" if name in ("train", "all") else "")
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
