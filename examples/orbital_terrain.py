"""Train a terrain classifier on orbit from labels drawn on the ground.

    python examples/orbital_terrain.py --dataset out/demo_terrain/dataset [--out terrain.png]

The dataset must be built with ``inputs.terrain_labels`` (``configs/demo_terrain.yaml``): each
sample's ``terrain_on_map`` holds the ground image's terrain classes carried onto its orbital
chip (255 where the camera did not see the ground within the label's 30 m). A small fully
convolutional network takes the ortho and DEM chips averaged to 1 m pixels (the DEM's own
cells; the labels and the truth are taken at 1 m too) and three maps made from them on the
whole chip (the slope, the DEM's relief against its 25 m mean, the ortho against its 9 m mean:
``features``), and is trained with cross-entropy on the carried classes of the train split
(255 ignored, classes weighted by the square root of their inverse frequency), on the chips'
central ``--crop`` pixels (the carried labels lie within 30 m of the rover). It is scored on
the held-out splits (the cross-area test and val areas: terrain the network never saw) per
class (IoU) and as mIoU, against the carried labels and, when the dataset's ortho has the
synthetic mission's ``terrain_classes.tif`` beside it, against the true classes on every chip
pixel of the crop; the majority class of the train labels is the baseline. Three seeds by
default (CPU, a few minutes on the demo).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mars_pairs.store.dataset_info import build_input, read_dataset_doc
from mars_pairs.torch import MarsPairsDataset

CLASSES = ("soil", "bedrock", "sand", "big_rock")
IGNORE = 255


def features(ortho: torch.Tensor, dem: torch.Tensor, res_m: float) -> torch.Tensor:
    """[5, S/2, S/2] inputs of a whole chip (ortho 0..1, DEM metres minus its median; ``res_m``
    metres a chip pixel), averaged over 2 x 2 pixels: the ortho, the DEM / 4, the slope
    (tangent), the DEM's relief against its 25-pixel mean, and the ortho against its
    9-pixel mean (computed on the whole chip, so the crop has no edge effects)."""
    f = torch.nn.functional
    x = f.avg_pool2d(torch.stack([ortho, dem])[None], 2)[0]
    o, z = x[0], x[1]
    gy, gx = torch.gradient(z, spacing=2.0 * res_m)
    slope = torch.hypot(gx, gy)

    def mean(a: torch.Tensor, k: int) -> torch.Tensor:
        return f.avg_pool2d(a[None, None], k, 1, k // 2, count_include_pad=False)[0, 0]

    return torch.stack([o, z / 4.0, slope, z - mean(z, 25), (o - mean(o, 9)) * 4.0])


def load(root: Path, splits: list[str], crop: int, truth_path: Path | None):
    """(x [N, 5, crop/2, crop/2], y [N, crop/2, crop/2] int64 with 255 ignored, truth or
    None): the chips' central ``crop`` pixels at 1 m (2 x 2 chip pixels), labels and truth
    at each block's first pixel."""
    xs, ys, ts = [], [], []
    truth = src = None
    if truth_path is not None:
        import rasterio

        src = rasterio.open(truth_path)
        truth, inv = src.read(1), ~src.transform
    with MarsPairsDataset(root, fields=("ortho", "dem", "terrain_on_map"), split=splits,
                          normalize_dem=True) as ds:  # fmt: skip
        for i in range(len(ds)):
            s = ds[i]
            size = s["ortho"].shape[-1]
            t = s["transform"].double().numpy()
            a = (size - crop) // 2
            cut, half = slice(a, a + crop, 2), slice(a // 2, (a + crop) // 2)
            res_m = float(np.hypot(t[0], t[3]))
            x = features(s["ortho"][0].float() / 255.0, s["dem"][0].float(), res_m)
            xs.append(x[:, half, half])
            ys.append(s["terrain_on_map"][0, cut, cut].long())
            if truth is not None:
                rows, cols = np.mgrid[cut, cut]
                mx = t[0] * (cols + 0.5) + t[1] * (rows + 0.5) + t[2]
                my = t[3] * (cols + 0.5) + t[4] * (rows + 0.5) + t[5]
                c, r = inv * (mx, my)
                cls = truth[np.floor(r).astype(int), np.floor(c).astype(int)]
                ts.append(torch.from_numpy(cls.astype(np.int64)))
    if src is not None:
        src.close()
    return torch.stack(xs), torch.stack(ys), (torch.stack(ts) if ts else None)


def network(width: int = 16) -> nn.Module:
    """A small fully convolutional net (dilations 1, 2, 4, 1: a 17 px receptive field)."""
    layers: list[nn.Module] = []
    c = 5
    for d in (1, 2, 4, 1):
        layers += [nn.Conv2d(c, width, 3, padding=d, dilation=d), nn.BatchNorm2d(width), nn.ReLU()]
        c = width
    layers.append(nn.Conv2d(width, len(CLASSES), 1))
    return nn.Sequential(*layers)


def iou(pred: torch.Tensor, target: torch.Tensor) -> np.ndarray:
    """Per-class IoU over pixels where ``target`` is labelled (NaN: class absent in both)."""
    ok = target != IGNORE
    p, t = pred[ok], target[ok]
    out = np.full(len(CLASSES), np.nan)
    for k in range(len(CLASSES)):
        union = int(((p == k) | (t == k)).sum())
        if union:
            out[k] = int(((p == k) & (t == k)).sum()) / union
    return out


def train(x: torch.Tensor, y: torch.Tensor, seed: int, epochs: int) -> nn.Module:
    torch.manual_seed(seed)
    net = network()
    counts = torch.bincount(y[y != IGNORE], minlength=len(CLASSES)).float()
    weight = (counts.sum() / counts.clamp(min=1.0)) ** 0.5
    loss_fn = nn.CrossEntropyLoss(weight=weight / weight.mean(), ignore_index=IGNORE)
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    gen = torch.Generator().manual_seed(seed)
    for _ in range(epochs):
        net.train()
        for idx in torch.randperm(len(x), generator=gen).split(16):
            xb, yb = x[idx], y[idx]
            if torch.rand(1, generator=gen) < 0.5:  # flips: the map has no preferred side
                xb, yb = xb.flip(-1), yb.flip(-1)
            opt.zero_grad()
            loss = loss_fn(net(xb), yb)
            loss.backward()
            opt.step()
    return net.eval()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, required=True)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--epochs", type=int, default=16)
    parser.add_argument("--crop", type=int, default=96, help="central chip pixels used")
    parser.add_argument("--held-out", nargs="+", default=["test", "val"])
    parser.add_argument("--out", type=Path, help="a PNG of held-out predictions")
    args = parser.parse_args()
    torch.set_num_threads(1)  # small convolutions: one thread is fastest on a shared machine
    doc = read_dataset_doc(args.dataset)
    ortho = build_input(args.dataset, doc, "ortho")
    truth_path = ortho.with_name("terrain_classes.tif") if ortho is not None else None
    truth_path = truth_path if truth_path is not None and truth_path.exists() else None
    t0 = time.perf_counter()
    x, y, _ = load(args.dataset, ["train"], args.crop, None)
    hx, hy, ht = load(args.dataset, args.held_out, args.crop, truth_path)
    labelled, held = int((y != IGNORE).sum()), int((hy != IGNORE).sum())
    print(f"train {len(x)} chips ({labelled} labelled px), held out {len(hx)} ({held} "
          f"labelled px) ({time.perf_counter() - t0:.0f} s)")  # fmt: skip
    majority = int(torch.bincount(y[y != IGNORE], minlength=len(CLASSES)).argmax())
    base = torch.full_like(hy, majority)
    rows = {"majority vs carried": iou(base, hy)}
    if ht is not None:
        rows["majority vs truth"] = iou(base, ht)
    runs: dict[str, list[np.ndarray]] = {"model vs carried": [], "model vs truth": []}
    pred = None
    for seed in range(args.seeds):
        net = train(x, y, seed, args.epochs)
        with torch.no_grad():
            pred = torch.cat([net(b).argmax(1) for b in hx.split(32)])
        runs["model vs carried"].append(iou(pred, hy))
        if ht is not None:
            runs["model vs truth"].append(iou(pred, ht))
        print(f"seed {seed}: mIoU vs carried {np.nanmean(runs['model vs carried'][-1]):.3f}"
              + (f", vs truth {np.nanmean(runs['model vs truth'][-1]):.3f}" if ht is not None
                 else "") + f" ({time.perf_counter() - t0:.0f} s)")  # fmt: skip
    print(f"\n{'held-out IoU':<22}" + "".join(f"{c:>10}" for c in CLASSES) + f"{'mIoU':>14}")
    for name, per in rows.items():
        print(f"{name:<22}" + "".join(f"{v:>10.3f}" for v in per) + f"{np.nanmean(per):>14.3f}")
    for name, seeds in runs.items():
        if not seeds:
            continue
        per, m = np.nanmean(seeds, axis=0), [np.nanmean(s) for s in seeds]
        print(f"{name:<22}" + "".join(f"{v:>10.3f}" for v in per)
              + f"{np.mean(m):>8.3f} ± {np.std(m):.3f}")  # fmt: skip
    if args.out and pred is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.colors import ListedColormap

        cmap = ListedColormap(["#c8a165", "#6b6b6b", "#e8d27a", "#8b2d1f"])
        picks = torch.argsort((hy != IGNORE).sum((1, 2)), descending=True)[:4]
        cols = 4 if ht is not None else 3
        fig, axes = plt.subplots(len(picks), cols, figsize=(3 * cols, 3 * len(picks)))
        for r, i in enumerate(picks):
            axes[r, 0].imshow(hx[i, 0], cmap="gray")
            lab = np.ma.masked_equal(hy[i].numpy(), IGNORE)
            axes[r, 1].imshow(hx[i, 0], cmap="gray")
            axes[r, 1].imshow(lab, cmap=cmap, vmin=0, vmax=3, interpolation="nearest")
            axes[r, 2].imshow(pred[i], cmap=cmap, vmin=0, vmax=3, interpolation="nearest")
            if ht is not None:
                axes[r, 3].imshow(ht[i], cmap=cmap, vmin=0, vmax=3, interpolation="nearest")
        titles = ["ortho (held out)", "carried labels", "prediction", "true classes"]
        for c in range(cols):
            axes[0, c].set_title(titles[c])
        for a in axes.ravel():
            a.set_axis_off()
        fig.suptitle("soil (tan), bedrock (grey), sand (yellow), big rock (red)")
        fig.tight_layout()
        fig.savefig(args.out, dpi=80)
        print(args.out)


if __name__ == "__main__":
    main()
