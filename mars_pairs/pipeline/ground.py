"""The ground image member: the original bytes, or an IMG product decoded and encoded."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from PIL import Image

from mars_pairs.errors import MarsPairsError
from mars_pairs.pds.observation import Observation


def ground_member(obs: Observation, encoding: str) -> tuple[str, bytes, tuple[int, int]]:
    """The ground image member: original bytes for JPEG/PNG, else decoded (pdr) and encoded."""
    path = obs.image_path
    if path is None or not Path(path).is_file():
        raise MarsPairsError(f"{obs.label_path}: no image file beside the label")
    suffix = Path(path).suffix.lower()
    if suffix in (".jpg", ".jpeg", ".png"):
        data = Path(path).read_bytes()
        with Image.open(io.BytesIO(data)) as im:
            size = im.size
        return ("ground.png" if suffix == ".png" else "ground.jpg"), data, size
    import pdr  # only decoded products (IMG) need it

    arr = np.asarray(pdr.read(str(obs.label_path))["IMAGE"])
    if arr.ndim == 3 and arr.shape[0] in (1, 3):
        arr = np.moveaxis(arr, 0, -1)
    arr = np.squeeze(arr)
    if arr.dtype != np.uint8:
        lo, hi = np.nanpercentile(arr, [0.5, 99.5])
        arr = np.clip((arr - lo) / max(hi - lo, 1e-9) * 255, 0, 255).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, format="PNG" if encoding == "png" else "JPEG")
    return f"ground.{encoding}", buf.getvalue(), (arr.shape[1], arr.shape[0])
