"""A format version 1 dataset (the DEM chip a float32 ``dem.npy``) still reads: the same
samples as the version 2 build it is rewritten from, the DEM as the ``.npy`` holds it."""

from __future__ import annotations

import io
import json
import shutil
import tarfile
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import torch

from mars_pairs.store.seal import seal
from mars_pairs.store.shards import ShardWriter
from mars_pairs.torch import ALL_FIELDS, MarsPairsDataset
from support.members import dem_metres


def _as_version_1(src: Path, dst: Path) -> dict[str, np.ndarray]:
    """``src`` rewritten as a version 1 folder in ``dst``: every ``dem.tif`` replaced by the
    float32 ``dem.npy`` of GDAL's reading of it (tarfile in, ``ShardWriter`` out), the manifest's
    location columns and dataset.json's version to match. Returns the DEM chips by key."""
    shutil.copytree(src, dst)
    table = pq.read_table(dst / "manifest.parquet")
    rows = {r["key"]: i for i, r in enumerate(table.select(["key"]).to_pylist())}
    columns = {c: table[c].to_pylist() for c in table.column_names}
    dems: dict[str, np.ndarray] = {}
    for shard in sorted((dst / "shards").glob("*.tar")):
        samples: dict[str, dict[str, bytes]] = {}
        with tarfile.open(shard) as tar:
            for info in tar.getmembers():
                key, _, member = info.name.partition(".")
                fh = tar.extractfile(info)
                assert fh is not None
                samples.setdefault(key, {})[member] = fh.read()
        rel = shard.relative_to(dst).as_posix()
        shard.unlink()
        with ShardWriter(dst, rel) as writer:
            for key, members in samples.items():
                dem = dem_metres(members["dem.tif"]).astype(np.float32)
                dems[key] = dem
                buf = io.BytesIO()
                np.save(buf, dem, allow_pickle=False)
                renamed = {("dem.npy" if m == "dem.tif" else m): b for m, b in members.items()}
                renamed["dem.npy"] = buf.getvalue()
                for member, loc in writer.add(key, renamed).items():
                    field = "ground" if member.startswith("ground.") else member.split(".")[0]
                    i = rows[key]
                    columns[f"{field}_offset"][i] = loc.offset
                    columns[f"{field}_size"][i] = loc.size
                    columns[f"{field}_crc32c"][i] = loc.crc32c
    arrays = [pa.array(columns[c], type=table.schema.field(c).type) for c in table.column_names]
    pq.write_table(pa.Table.from_arrays(arrays, schema=table.schema), dst / "manifest.parquet")
    doc = json.loads((dst / "dataset.json").read_text())
    doc["format_version"] = 1
    doc.pop("dem_encoding", None)
    doc.pop("files", None)
    seal(dst, doc)  # dataset.json and SHA256SUMS over the rewritten files
    return dems


def test_a_version_1_dataset_reads_as_the_version_2_build(
    dataset_dir: Path, tmp_path: Path
) -> None:
    old_root = tmp_path / "v1"
    dems = _as_version_1(dataset_dir, old_root)
    with (
        MarsPairsDataset(dataset_dir, fields=ALL_FIELDS) as new,
        MarsPairsDataset(old_root, fields=ALL_FIELDS, verify=True) as old,
    ):
        assert len(old) == len(new) == len(dems)
        for i in range(len(new)):
            a, b = new[i], old[old.index_of(new[i]["meta"]["key"])]
            key = a["meta"]["key"]
            for field in ALL_FIELDS:
                assert torch.equal(a[field].nan_to_num(-1), b[field].nan_to_num(-1)), field
            np.testing.assert_array_equal(b["dem"][0].numpy(), dems[key])
        assert old.member_name(0, "dem").endswith(".dem.npy")
        assert new.member_name(0, "dem").endswith(".dem.tif")
