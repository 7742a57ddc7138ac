"""The DEM chip's codec against the alternatives: size, encode and decode time, precision.

    python benchmarks/bench_dem_codec.py [--dataset DIR] [--chips 40]

Takes the DEM chips of a built dataset (``out/demo/dataset`` by default; either format: the
chips are decoded to float32 metres first, so a format-1 build gives the float32 chips the
build cut), gives each chip a no-data corner, and encodes it with each codec: the float32
``.npy`` (the anchor, lossless), ``dem.tif`` (``store.dem_codec``: uint16 at 2^-7 m, zstd,
horizontal differencing), the same uint16 values as a 16-bit PNG (libpng, zlib level 1, Sub
filter), the same file decoded by libtiff (``imagecodecs.tiff_decode``), the uint16 values
in blosc2 (lz4, byte shuffle), and the float32 chip in zstd after byte shuffling (lossless).
Prints a markdown table: mean KiB, best-of-``--repeats`` encode and decode ms (median over
chips), the largest |decoded - chip| over finite cells and whether every NaN stays NaN, with
the load average.
"""

from __future__ import annotations

import argparse
import io
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import imagecodecs
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mars_pairs.store.dem_codec import (  # noqa: E402
    decode_dem,
    dem_encoding,
    dequantize,
    encode_dem,
    quantize,
)
from mars_pairs.torch import MarsPairsDataset  # noqa: E402


def _npy(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a, allow_pickle=False)
    return buf.getvalue()


def _png16(a: np.ndarray) -> tuple[bytes, Any]:
    enc = dem_encoding(a)
    png = imagecodecs.png_encode(quantize(a, enc), level=1, strategy=3, filter=16)
    return bytes(png), enc


def _blosc2(a: np.ndarray) -> tuple[bytes, Any]:
    enc = dem_encoding(a)
    data = imagecodecs.blosc2_encode(
        quantize(a, enc).tobytes(), 5, compressor="lz4", shuffle="shuffle", typesize=2,
        numthreads=1,
    )  # fmt: skip
    return bytes(data), enc


def _shuffled_zstd(a: np.ndarray) -> tuple[bytes, tuple[int, ...]]:
    planes = np.ascontiguousarray(a).view(np.uint8).reshape(-1, 4).T.copy()
    return bytes(imagecodecs.zstd_encode(planes.tobytes(), 3)), a.shape


def _unshuffled(e: tuple[bytes, tuple[int, ...]]) -> np.ndarray:
    planes = np.frombuffer(imagecodecs.zstd_decode(e[0]), np.uint8).reshape(4, -1)
    return planes.T.copy().view(np.float32).reshape(e[1])


CODECS: dict[str, tuple[Callable[[np.ndarray], Any], Callable[[Any], np.ndarray]]] = {
    "float32 .npy (anchor, lossless)": (_npy, lambda b: np.load(io.BytesIO(b))),
    "**dem.tif**: uint16 2^-7 m, zstd 3, differencing (ours)": (
        lambda a: encode_dem(a)[0], decode_dem,
    ),
    "same file, decoded by libtiff (imagecodecs.tiff_decode)": (
        encode_dem, lambda e: dequantize(imagecodecs.tiff_decode(e[0]), e[1]),
    ),
    "uint16 16-bit PNG (zlib 1, Sub filter)": (
        _png16, lambda e: dequantize(imagecodecs.png_decode(e[0]), e[1]),
    ),
    "uint16 blosc2 (lz4, byte shuffle; no TIFF reader)": (
        _blosc2,
        lambda e: dequantize(
            np.frombuffer(imagecodecs.blosc2_decode(e[0], numthreads=1), np.uint16), e[1]
        ),
    ),
    "float32 zstd 3 after byte shuffling (lossless)": (_shuffled_zstd, _unshuffled),
}  # fmt: skip


def _size(encoded: Any) -> int:
    return len(encoded[0] if isinstance(encoded, tuple) else encoded)


def _best_ms(fn: Callable[[], Any], repeats: int) -> tuple[Any, float]:
    best, out = float("inf"), None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return out, best * 1e3


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--dataset", type=Path, default=ROOT / "out" / "demo" / "dataset")
    p.add_argument("--chips", type=int, default=40)
    p.add_argument("--repeats", type=int, default=20)
    args = p.parse_args()
    ds = MarsPairsDataset(args.dataset, fields=("dem",))
    chips = []
    for i in range(min(args.chips, len(ds))):
        chip = ds[i]["dem"][0].numpy().copy()
        chip[:5, :9] = np.nan  # a no-data corner
        chips.append(chip)
    load0 = os.getloadavg()[0]
    rows = []
    for name, (encode, decode) in CODECS.items():
        sizes, enc_ms, dec_ms, err, nan_kept = [], [], [], 0.0, True
        for chip in chips:
            encoded, te = _best_ms(lambda c=chip, f=encode: f(c), args.repeats)
            decoded, td = _best_ms(lambda e=encoded, f=decode: f(e), args.repeats)
            decoded = np.asarray(decoded).reshape(chip.shape)
            finite = np.isfinite(chip)
            err = max(err, float(np.abs(decoded[finite].astype(np.float64) - chip[finite]).max()))
            nan_kept &= bool(np.array_equal(np.isnan(decoded), ~finite))
            sizes.append(_size(encoded))
            enc_ms.append(te)
            dec_ms.append(td)
        kib = float(np.mean(sizes)) / 1024
        rows.append((name, kib, np.median(enc_ms), np.median(dec_ms), err, nan_kept))
    shape = "x".join(map(str, chips[0].shape))
    print(f"\n{len(chips)} DEM chips ({shape}) of {args.dataset}; load {load0:.2f} -> "
          f"{os.getloadavg()[0]:.2f}\n")  # fmt: skip
    print("| codec | KiB | encode ms | decode ms | max abs error (m) | NaN kept |")
    print("|---|---:|---:|---:|---:|---|")
    for name, kib, te, td, err, kept in rows:
        kept_text = "yes" if kept else "no"
        print(f"| {name} | {kib:.1f} | {te:.2f} | {td:.2f} | {err:.4f} | {kept_text} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
