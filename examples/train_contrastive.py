"""Cross-view retrieval on a mars-pairs dataset: ground image -> orbital chip.

    python examples/train_contrastive.py --dataset out/demo/dataset [--method polar|global|both]

It trains on the ``train`` split only and evaluates on the held-out areas (VIGOR's
cross-area protocol: the dataset's ``val`` and ``test`` areas are far from every train
sample, see dataset.json ``splits``). Evaluation ranks every distinct chip of the split for
each ground image: recall@1/@5 of the own chip, and hit@1 (the top chip lies within
--near-m, default 64 m: half a 128 m chip, so it contains the query's rover position), each
printed beside its chance level.

``--method polar`` (default): orientation-aligned polar matching (the polar transform of Shi
et al. 2019, SAFA; VIGOR/CVR's known-orientation setting). The camera's pointing is known at
query time (manifest ``azimuth_deg``, ``elevation_deg``, ``hfov_deg``, ``vfov_deg``), so for
every candidate chip its centre is taken as the rover position and the ortho is resampled on a
(ground distance x azimuth) grid: rows 3..60 m log-spaced, columns across the query camera's
horizontal field of view around its azimuth. The ground image is resampled on the same grid
(inverse perspective: a pinhole pitched by ``elevation_deg``, --camera-height above the
candidate DEM's centre, terrain heights from the candidate's DEM, occlusion ignored). Only
the query's own pointing and the candidate's chips are used, never its true position or
viewshed. The score of a pair is a per-channel normalised cross-correlation of the two
branches over the grid cells both see: channel 0 is the grey image itself (step 0 is plain
NCC, printed first), the other channels come from two small learnt convolutions per branch,
weighted by learnt weights. Training: each train query against every train chip, softmax
cross-entropy (InfoNCE) with its own chip the positive, chips of other positions within
--near-m left out (VIGOR's semi-positives), azimuth mirroring of both branches.

``--method global``: the global-embedding baseline. Two tiny CNN encoders embed the ground
image (resized to --image-size) and the ortho chip (+ the normalised DEM as a second channel,
unless --no-dem) into a shared unit sphere; symmetric multi-positive InfoNCE over the batch
(images taken at the same rover position share one chip), near chips left out of the
negatives. The dataset's transforms resize the chips and make float32 images; the dataset is
small, so it is decoded once and kept in memory (for a large dataset, give the augmentations
to ``MarsPairsDataset(transform=...)`` and iterate a ``mars_pairs.torch.MarsPairsLoader``, a
DataLoader whose workers reuse their shared memory). Every training step augments its
samples with transforms that keep the pairing (``mars_pairs.torch.transforms``: a random chip
crop, which moves the chip's georeferencing and keypoints with it, and colour jitter of the
ground image); ``--plot PNG`` writes ``MarsPairsDataset.plot`` of an augmented sample (polar:
the ground image and both branches on the polar grid of a train sample).
Deterministic for a given --seed (single-threaded CPU by default).
"""

from __future__ import annotations

import argparse
import math
import random
import sys
import time
from dataclasses import dataclass
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
    _, first = np.unique(loc.numpy(), return_index=True)
    pick = torch.from_numpy(first)
    sims = genc(ground) @ oenc(chip[pick]).T
    return rank_metrics(sims, loc, xy, loc[pick], xy[pick], near_m)


# ---- polar method -------------------------------------------------------------------------------
@dataclass(frozen=True)
class PolarGrid:
    """The (ground distance x azimuth) grid both branches are resampled to: ``rows`` distances
    log-spaced from ``far_m`` (row 0, the top, as in the image) to ``near_m`` metres from the
    candidate rover position, ``cols`` azimuths across the query camera's horizontal field of
    view; ``camera_height_m``: the camera centre above the ground at the rover (metres)."""

    rows: int = 24
    cols: int = 48
    near_m: float = 3.0
    far_m: float = 60.0
    camera_height_m: float = 2.0

    def distances(self) -> torch.Tensor:
        """[rows] ground distances, metres, far to near."""
        return torch.from_numpy(np.geomspace(self.far_m, self.near_m, self.rows)).float()

    def azimuths(self, hfov_deg: float) -> torch.Tensor:
        """[cols] azimuths relative to the camera's centre ray (radians, clockwise): the
        centres of ``cols`` equal bins across ``hfov_deg``."""
        half = math.radians(hfov_deg) / 2
        return torch.linspace(-half, half, self.cols + 1)[:-1] + half / self.cols


def polar_pairs(
    ground: torch.Tensor, meta: dict, chips: torch.Tensor, transforms: torch.Tensor,
    grid: PolarGrid,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:  # fmt: skip
    """One query against C candidate chips, on the polar grid of ``grid``.

    ``ground``: the query image [3, H, W] (float); ``meta``: its manifest row (uses only what
    the camera knows at query time: ``azimuth_deg`` clockwise from north, ``elevation_deg``,
    ``hfov_deg``, ``vfov_deg``); ``chips``: [C, 2, S, S] ortho and DEM (metres) of the
    candidates; ``transforms``: [C, 6] their chip pixel (column, row; pixel-edge) -> map x, y
    affines (map metres, north-up or rotated). Each candidate's chip centre is taken as the
    rover position. Returns the ortho's polar image [C, 1, R, A] (the map around the
    candidate, column j looking along the query's azimuth + offset j), the ground image's
    [C, 1, R, A] (grey, where the ray to that map point meets it: a pinhole camera pitched by
    ``elevation_deg`` at ``camera_height_m`` above the candidate DEM's centre, the terrain
    height from the candidate's DEM; occlusion ignored) and [C, R, A] validity (inside the
    image, in front of the camera, finite DEM).
    """
    c = chips.shape[0]
    size = chips.shape[-1]
    d = grid.distances()[:, None]
    alpha = grid.azimuths(float(meta["hfov_deg"]))[None, :]
    bearing = math.radians(float(meta["azimuth_deg"])) + alpha
    east, north = d * torch.sin(bearing), d * torch.cos(bearing)  # [R, A] map metres
    t = transforms.double()
    a, b, dd, e = (t[:, i, None, None] for i in (0, 1, 3, 4))
    det = a * e - b * dd
    # offsets from the chip centre -> chip pixels (inverse of the linear part), then to [-1, 1]
    col = (e * east - b * north) / det + size / 2
    row = (-dd * east + a * north) / det + size / 2
    where = torch.stack([col / size * 2 - 1, row / size * 2 - 1], dim=-1).float()  # [C, R, A, 2]
    polar = F.grid_sample(chips, where, align_corners=False)  # [C, 2, R, A]
    centre = F.grid_sample(chips[:, 1:], torch.zeros(c, 1, 1, 2), align_corners=False)
    up = polar[:, 1] - centre[:, 0] - grid.camera_height_m  # terrain height below the camera
    el = math.radians(float(meta["elevation_deg"]))
    th = math.tan(math.radians(float(meta["hfov_deg"])) / 2)
    tv = math.tan(math.radians(float(meta["vfov_deg"])) / 2)
    fwd, right = d * torch.cos(alpha), d * torch.sin(alpha)  # level frame, metres
    fc = fwd * math.cos(el) + up * math.sin(el)  # camera frame (pitched by el)
    uc = -fwd * math.sin(el) + up * math.cos(el)
    x, y = right / fc / th, -uc / fc / tv  # normalised image coordinates, [-1, 1] inside
    valid = (fc > 0) & (x.abs() < 1) & (y.abs() < 1) & torch.isfinite(up)
    xy = torch.stack([x, y], dim=-1).nan_to_num(2.0)
    grey = ground.mean(dim=0, keepdim=True)[None].expand(c, -1, -1, -1)
    seen = F.grid_sample(grey, xy, align_corners=False)
    return polar[:, :1].nan_to_num(0.0), seen, valid


class PolarEncoder(nn.Module):
    """[N, 1, R, A] polar image -> [N, 1 + k, R, A]: the image itself beside k learnt features
    (two 3x3 convolutions; a convolution sees neighbouring distances and azimuths)."""

    def __init__(self, k: int = 4) -> None:
        super().__init__()
        self.conv = nn.Sequential(
            nn.Conv2d(1, k, 3, padding=1), nn.GELU(), nn.Conv2d(k, k, 3, padding=1)
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.cat([x, self.conv(x)], dim=1)


class PolarMatcher(nn.Module):
    """The score of (ground, candidate) polar pairs: per channel, the normalised
    cross-correlation of the two branches' features over the valid cells, weighted by a
    learnt weight per channel. The weights start at (1, 0, ..., 0): before training the score
    is the plain NCC of the grey ground image and the ortho on the polar grid."""

    def __init__(self, k: int = 4) -> None:
        super().__init__()
        self.ground, self.ortho = PolarEncoder(k), PolarEncoder(k)
        self.weight = nn.Parameter(torch.zeros(1 + k))
        with torch.no_grad():
            self.weight[0] = 1.0

    def forward(self, seen: torch.Tensor, ortho: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        """seen, ortho [..., 1, R, A], valid [..., R, A] -> scores [...]."""
        lead = seen.shape[:-3]
        seen, ortho = seen.flatten(0, -4), ortho.flatten(0, -4)
        w = valid.flatten(0, -3)[:, None].float()
        n = w.sum(dim=(2, 3), keepdim=True).clamp_min(1.0)
        corr = []
        for f in (self.ground(seen), self.ortho(ortho)):
            f = f - (f * w).sum(dim=(2, 3), keepdim=True) / n
            f = f * w
            corr.append(f / f.norm(dim=(2, 3), keepdim=True).clamp_min(1e-6))
        ncc = (corr[0] * corr[1]).sum(dim=(2, 3))  # [N, 1 + k]
        return (ncc * self.weight).sum(dim=1).reshape(lead)


def polar_split(
    samples: list[dict], queries: np.ndarray, gallery: np.ndarray, grid: PolarGrid
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Polar pairs of every query (sample indices) against every gallery chip (sample
    indices): [Q, C, 1, R, A] ground and ortho, [Q, C, R, A] validity."""
    chips = torch.stack([torch.cat([samples[i]["ortho"], samples[i]["dem"]]) for i in gallery])
    transforms = torch.stack([samples[i]["transform"] for i in gallery])
    out = [polar_pairs(samples[q]["ground"], samples[q]["meta"], chips, transforms, grid)
           for q in queries]  # fmt: skip
    seen, ortho, valid = (torch.stack(parts) for parts in zip(*out, strict=True))
    return ortho, seen, valid


def rank_metrics(
    sims: torch.Tensor, loc: torch.Tensor, xy: torch.Tensor, gallery_loc: torch.Tensor,
    gallery_xy: torch.Tensor, near_m: float,
) -> dict[str, float]:  # fmt: skip
    """recall@1/@5 of the own chip, hit@1 and their chance levels from [queries, chips]
    similarities; ``loc``/``xy`` of the queries, ``gallery_loc``/``gallery_xy`` of the chips
    (map metres)."""
    order = sims.argsort(dim=1, descending=True)
    truth = (loc[:, None] == gallery_loc[None, :]).float().argmax(dim=1)
    rank = (order == truth[:, None]).float().argmax(dim=1)
    close = torch.cdist(xy, gallery_xy) <= near_m
    top_close = close.gather(1, order[:, :1]).squeeze(1)
    m = len(gallery_loc)
    return {
        "r1": float((rank < 1).float().mean()), "r5": float((rank < 5).float().mean()),
        "hit1": float(top_close.float().mean()), "chance_r1": 1 / m,
        "chance_r5": min(5, m) / m, "chance_hit1": float(close.float().mean()),
        "chips": m, "queries": len(loc),
    }  # fmt: skip


def print_row(name: str, r: dict[str, float]) -> None:
    print(
        f"{name:5s} {r['queries']:3d} queries, {r['chips']:2d} chips: "
        f"recall@1 {r['r1']:.3f} ({r['chance_r1']:.3f})  "
        f"recall@5 {r['r5']:.3f} ({r['chance_r5']:.3f})  "
        f"hit@1 {r['hit1']:.3f} ({r['chance_hit1']:.3f})"
        + ("   <- seen in training" if name in ("train", "all") else "")
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--dataset", type=Path, default=Path("out/demo/dataset"))
    p.add_argument("--method", choices=("polar", "global", "both"), default="polar",
                   help="polar: orientation-aligned polar matching (default); global: the "
                   "global-embedding baseline; both: one after the other")  # fmt: skip
    p.add_argument("--steps", type=int, default=None,
                   help="training steps (default: polar 150, global 400)")  # fmt: skip
    p.add_argument("--batch-size", type=int, default=None, help="default: polar 8, global 16")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--lr", type=float, default=None, help="default: polar 1e-2, global 2e-3")
    p.add_argument("--image-size", type=int, default=64,
                   help="global: ground and chip side (px); polar: ground side / 2")  # fmt: skip
    p.add_argument("--temperature", type=float, default=None,
                   help="InfoNCE temperature (default: polar 0.05, global 0.1)")  # fmt: skip
    p.add_argument("--camera-height", type=float, default=2.0,
                   help="polar: camera centre above the ground (m; a mast's ~2 m)")  # fmt: skip
    p.add_argument("--log-every", type=int, default=25)
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    p.add_argument("--no-dem", action="store_true", help="global: ortho chip only, no DEM channel")
    p.add_argument("--near-m", type=float, default=64.0,
                   help="chips of other positions within this (m) are semi-positives")  # fmt: skip
    p.add_argument("--plot", type=Path, help="write the figure of a training sample (PNG)")
    args = p.parse_args(argv)
    methods = ("polar", "global") if args.method == "both" else (args.method,)
    for method in methods:
        random.seed(args.seed)
        np.random.seed(args.seed)
        torch.manual_seed(args.seed)
        torch.set_num_threads(args.threads)
        torch.use_deterministic_algorithms(True)
        if len(methods) > 1:
            print(f"== method {method}")
        (run_polar if method == "polar" else run_global)(args)
    return 0


def run_global(args: argparse.Namespace) -> None:
    """The global-embedding baseline: two CNNs embed the whole ground image and chip."""
    steps = args.steps if args.steps is not None else 400
    lr = args.lr if args.lr is not None else 2e-3
    temperature = args.temperature if args.temperature is not None else 0.1
    batch_size = args.batch_size if args.batch_size is not None else 16
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
    opt = torch.optim.AdamW([*genc.parameters(), *oenc.parameters()], lr=lr)
    n_train = len(train_idx)
    batch = min(batch_size, n_train)
    order = train_idx[torch.randperm(n_train, generator=gen)]
    cursor, window = 0, []
    t1 = time.perf_counter()
    for step in range(1, steps + 1):
        if cursor + batch > n_train:
            order, cursor = train_idx[torch.randperm(n_train, generator=gen)], 0
        idx = order[cursor : cursor + batch]
        cursor += batch
        g, c = tensors([augment(samples[int(i)]) for i in idx], use_dem)
        loss = info_nce(genc(norm_ground(g)), oenc(norm_chip(c)), loc[idx],
                        near[idx][:, idx], temperature)  # fmt: skip
        opt.zero_grad()
        loss.backward()
        opt.step()
        window.append(loss.item())
        if step % args.log_every == 0 or step == steps:
            print(f"step {step:5d} loss {np.mean(window):.4f}", flush=True)
            window = []
    epochs = steps * batch / n_train
    print(f"trained {steps} steps ({epochs:.0f} epochs of train) in "
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
        print_row(name, r)


def run_polar(args: argparse.Namespace) -> None:
    """Orientation-aligned polar matching: every (query, candidate chip) pair resampled to the
    query camera's (distance x azimuth) grid, scored by a learnt per-channel NCC."""
    steps = args.steps if args.steps is not None else 150
    batch_size = args.batch_size if args.batch_size is not None else 8
    lr = args.lr if args.lr is not None else 1e-2
    temperature = args.temperature if args.temperature is not None else 0.05
    grid = PolarGrid(camera_height_m=args.camera_height)
    t0 = time.perf_counter()
    ds = MarsPairsDataset(
        args.dataset, fields=("ground", "ortho", "dem"), ground_size=2 * args.image_size,
        normalize_dem=False, transform=ToFloat(),
    )  # fmt: skip
    if len(ds) < 2:
        raise SystemExit(f"{args.dataset}: need at least 2 samples, found {len(ds)}")
    samples = [ds[i] for i in range(len(ds))]
    n = len(samples)
    loc, xy = location_ids(samples)
    splits = np.array([s["meta"]["split"] for s in samples])
    near = torch.cdist(xy, xy) <= args.near_m
    names = ["train", "val", "test"]
    train_idx = np.flatnonzero(splits == "train")
    if len(set(loc[train_idx].tolist())) < 2:
        print("train has fewer than 2 positions: training on every sample, every other "
              "position a negative (a smoke test: its numbers prove nothing)")  # fmt: skip
        splits = np.where(splits == "train", "all", splits)
        train_idx, names = np.arange(n), ["all"]
        near = torch.zeros_like(near)
    counts = ", ".join(
        f"{name} {int((splits == name).sum())} ({len(set(loc[splits == name].tolist()))} pos.)"
        for name in ("train", "val", "test", "buffer")
    )
    pairs: dict[str, tuple] = {}
    for name in names:
        queries = train_idx if name == "all" else np.flatnonzero(splits == name)
        _, first = np.unique(loc[queries].numpy(), return_index=True)
        gallery = queries[first]
        if len(gallery) < 2:
            print(f"{name:5s} fewer than 2 positions: not evaluated")
            continue
        pairs[name] = (queries, gallery, *polar_split(samples, queries, gallery, grid))
    print(
        f"{n} samples at {len(set(loc.tolist()))} positions: {counts}; polar grid "
        f"{grid.rows} distances ({grid.near_m:g}-{grid.far_m:g} m) x {grid.cols} azimuths; "
        f"decoded and projected in {time.perf_counter() - t0:.1f} s"
    )
    if args.plot is not None:
        plot_polar(samples[int(train_idx[0])], grid, args.plot)
    model = PolarMatcher()
    train_name = "all" if names == ["all"] else "train"

    def evaluate(title: str) -> None:
        print(f"ground->ortho retrieval, {title}, over each split's distinct chips (chance in "
              f"brackets; hit@1: top chip within {args.near_m:g} m)")  # fmt: skip
        with torch.no_grad():
            for name, (queries, gallery, ortho, seen, valid) in pairs.items():
                sims = model(seen, ortho, valid)
                r = rank_metrics(sims, loc[queries], xy[queries], loc[gallery], xy[gallery],
                                 args.near_m)  # fmt: skip
                print_row(name, r)

    evaluate("untrained (step 0: NCC of the grey image and the ortho on the polar grid)")
    if train_name not in pairs:
        return
    queries, gallery, ortho, seen, valid = pairs[train_name]
    own = loc[queries][:, None] == loc[gallery][None, :]
    left_out = near[queries][:, gallery] & ~own  # semi-positives: neither pulled nor pushed
    target = own.float().argmax(dim=1)
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-3)
    gen = torch.Generator().manual_seed(args.seed)
    q = len(queries)
    batch = min(batch_size, q)
    order, cursor, window = torch.randperm(q, generator=gen), 0, []
    t1 = time.perf_counter()
    for step in range(1, steps + 1):
        if cursor + batch > q:
            order, cursor = torch.randperm(q, generator=gen), 0
        idx = order[cursor : cursor + batch]
        cursor += batch
        s, o, v = seen[idx], ortho[idx], valid[idx]
        if torch.rand(1, generator=gen).item() < 0.5:  # mirror the azimuths of both branches
            s, o, v = s.flip(-1), o.flip(-1), v.flip(-1)
        logits = (model(s, o, v) / temperature).masked_fill(left_out[idx], float("-inf"))
        loss = F.cross_entropy(logits, target[idx])
        opt.zero_grad()
        loss.backward()
        opt.step()
        window.append(loss.item())
        if step % args.log_every == 0 or step == steps:
            print(f"step {step:5d} loss {np.mean(window):.4f}", flush=True)
            window = []
    print(f"trained {steps} steps ({steps * batch / q:.0f} epochs of {train_name}, each query "
          f"against its {len(gallery)} chips) in {time.perf_counter() - t1:.1f} s")  # fmt: skip
    evaluate("trained")


def plot_polar(sample: dict, grid: PolarGrid, path: Path) -> None:
    """Write a PNG: the ground image, its polar resampling and the own chip's polar image."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    chips = torch.cat([sample["ortho"], sample["dem"]])[None]
    ortho, seen, valid = polar_pairs(
        sample["ground"], sample["meta"], chips, sample["transform"][None], grid
    )
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.5))
    axes[0].imshow(sample["ground"].permute(1, 2, 0).clamp(0, 1).numpy())
    axes[0].set_title(f"ground, azimuth {sample['meta']['azimuth_deg']:.0f} deg")
    for ax, img, title in ((axes[1], seen, "ground on the polar grid"),
                           (axes[2], ortho, "own chip on the polar grid")):  # fmt: skip
        shown = np.where(valid[0].numpy(), img[0, 0].numpy(), np.nan)
        ax.imshow(shown, cmap="gray", aspect="auto")
        ax.set_title(title)
        ax.set_xlabel("azimuth across the field of view")
        ax.set_ylabel(f"distance {grid.far_m:g} m (top) to {grid.near_m:g} m")
    fig.tight_layout()
    fig.savefig(path, dpi=60)
    plt.close(fig)
    print(f"wrote {path}")


if __name__ == "__main__":
    raise SystemExit(main())
