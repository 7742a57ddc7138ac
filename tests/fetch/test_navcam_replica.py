"""The Navcam products of both missions fetched from a replica archive on 127.0.0.1, and a
fetch restricted to the ids a terrain-label folder names.

What is real and what is made (so the test says what it proves): the paths, volume, index
and id rules are the cited ones (``fetch.config``: ``MSLNAV_1XXX/INDEX/INDEX.LBL`` +
``.TAB`` with ``DATA_V1/SOL<5-digit sol>/`` paths; ``mars2020_navcam_ops_raw`` with
``data/sol/<5-digit sol>/ids/edr/ncam/<FILE ID>.xml`` and LIDVID inventory rows); the labels'
bytes are the real Mastcam ones of ``../shared/pds-samples`` with the Navcam product's file
names written in (no real Navcam label is on this machine), each with the image its label
describes. Every product is fetched or named in ``fetch_skipped.parquet``.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml
from PIL import Image

from support import replica_archive as replica
from support.fetch_archive import write_pds3_index
from support.fetch_server import ArchiveServer

REPO = Path(__file__).resolve().parents[2]
SAMPLES = replica.SAMPLES

# Curiosity Navcam EDR ids (the AI4Mars release's first example and another of the same sol)
MSL_IDS = ("NLA_397681455EDR_F0020000AUT_04096M1", "NLB_397681500EDR_F0020000AUT_04096M1")
# Mars 2020 Navcam ids in the SIS grammar (the real example NLF_0034_..._071ECM_... shape)
M2020_IDS = ("NLF_0052_0671559321_081ECM_N0031950NCAM00500_01_295J01",
             "NRF_0052_0671559400_100ECM_N0031950NCAM00500_01_295J01")  # fmt: skip
M2020_BUNDLE = "mars2020_navcam_ops_raw"


def _msl_archive(root: Path) -> list[str]:
    volume = root / "MSLNAV_1XXX"
    real = sorted((SAMPLES / "msl").glob("1429*.LBL"))[0]
    rows, placed = [], []
    for pid in MSL_IDS:
        folder = volume / "DATA_V1" / "SOL00000"  # sclk 397681455: sol 0 (before sol 1870)
        folder.mkdir(parents=True, exist_ok=True)
        text = real.read_text(encoding="latin-1").replace(real.stem, pid)
        (folder / f"{pid}.LBL").write_text(text, encoding="latin-1")
        replica._msl_img(real.with_suffix(".jpg"), folder / f"{pid}.IMG")
        rows.append({"VOLUME_ID": "MSLNAV_1XXX", "PATH_NAME": "DATA_V1/SOL00000/",
                     "FILE_NAME": f"{pid}.LBL", "PRODUCT_ID": pid,
                     "INSTRUMENT_ID": "NAV_LEFT_A" if pid[1] == "L" else "NAV_LEFT_B",
                     "PLANET_DAY_NUMBER": 0, "IMAGE_ID": pid[:13]})  # fmt: skip
        placed.append(f"MSLNAV_1XXX/DATA_V1/SOL00000/{pid}.LBL")
    write_pds3_index(volume, rows, name="INDEX")
    return placed


def _m2020_archive(root: Path) -> list[str]:
    bundle = root / M2020_BUNDLE
    real = sorted((SAMPLES / "m2020").glob("ZLF*.xml"))[0]
    placed, lines = [], []
    for pid in M2020_IDS:
        rel = f"{M2020_BUNDLE}/data/sol/00052/ids/edr/ncam/{pid}.xml"
        dest = root / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        dest.write_text(real.read_text().replace(real.stem, pid))
        replica._m2020_img(dest, real.with_suffix(".jpg"), dest.with_suffix(".IMG"))
        placed.append(rel)
        lines.append(f"P,urn:nasa:pds:{M2020_BUNDLE}:data:{pid[:52].lower()}::1.0")
    # a Mastcam-Z row (not a Navcam id) and a secondary member: named, never fetched
    lines.append("P,urn:nasa:pds:mars2020_mastcamz_ops_calibrated:data:"
                 "zlf_0052_0671559321_081rad_n0031950zcam05024_110085j::1.0")  # fmt: skip
    lines.append(f"S,urn:nasa:pds:{M2020_BUNDLE}:data:{M2020_IDS[0][:52].lower()}::1.0")
    inventory = ("\r\n".join(lines) + "\r\n").encode()
    (bundle / "data").mkdir(parents=True, exist_ok=True)
    (bundle / "data" / "collection_data_inventory.csv").write_bytes(inventory)
    label = replica._collection_label(len(lines), len(inventory), "collection_data_inventory.csv")
    (bundle / "data" / "collection_data.xml").write_bytes(label)
    return placed


@pytest.fixture(scope="module")
def archive(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[str], list[str]]:
    why = replica.available()
    if why is not None:
        pytest.skip(f"the Navcam replica needs ../shared: {why}")
    root = tmp_path_factory.mktemp("navcam-archive")
    return root, _msl_archive(root / "msl"), _m2020_archive(root / "mars2020")


@pytest.fixture(scope="module")
def server(archive):
    with ArchiveServer(archive[0]) as srv:
        yield srv


def _labels_folder(root: Path) -> Path:
    """An AI4Mars layout naming the first id of each mission (Mars 2020: without version)."""
    mask = np.zeros((4, 4), dtype=np.uint8)
    for rel in (f"msl/ncam/labels/train/{MSL_IDS[0]}.png",
                f"m2020/labels/NAV/{M2020_IDS[0][:-2]}_merged3.png"):  # fmt: skip
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(mask, mode="L").save(root / rel)
    return root


def _fetch(work: Path, url: str, mission: str, restrict: bool) -> subprocess.CompletedProcess:
    products: dict[str, object] = {"mission": mission, "camera": "ncam"}
    if mission == "msl":
        products["archive"] = f"{url}/msl"
    else:
        products.update(archive=f"{url}/mars2020", bundle=M2020_BUNDLE)
    if restrict:
        products["terrain_labels"] = {"format": "ai4mars", "root": "ai4mars"}
        _labels_folder(work / "ai4mars")
    doc = {"fetch": {"cache": "cache", "retries": 1, "backoff_s": 0.01, "timeout_s": 20,
                     "workers": 2, "products": products}}  # fmt: skip
    work.mkdir(parents=True, exist_ok=True)
    (work / "c.yaml").write_text(yaml.safe_dump(doc))
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run(
        [sys.executable, "-m", "mars_pairs.cli", "fetch", "products", "--config",
         str(work / "c.yaml"), "--quiet"],
        capture_output=True, text=True, env=env, timeout=300, check=False,
    )  # fmt: skip


@pytest.mark.parametrize("mission", ["msl", "m2020"])
def test_navcam_products_fetched_or_named(archive, server, tmp_path, mission) -> None:
    root, msl, m2020 = archive
    done = _fetch(tmp_path, server.url, mission, restrict=False)
    assert done.returncode == 0, done.stdout[-1500:] + done.stderr[-1500:]
    cache = tmp_path / "cache"
    assert pq.read_table(cache / "fetch_failures.parquet").num_rows == 0
    placed = msl if mission == "msl" else m2020
    base = root / ("msl" if mission == "msl" else "mars2020")
    for rel in placed:
        got = cache / rel
        assert got.read_bytes() == (base / rel).read_bytes()
        image = (base / rel).with_suffix(".IMG")
        assert got.with_suffix(".IMG").read_bytes() == image.read_bytes()
    reasons = sorted(
        r["reason"] for r in pq.read_table(cache / "fetch_skipped.parquet").to_pylist()
    )
    assert reasons == ([] if mission == "msl" else ["not a Navcam id", "secondary member"])


@pytest.mark.parametrize("mission", ["msl", "m2020"])
def test_fetch_restricted_to_the_terrain_labels(archive, server, tmp_path, mission) -> None:
    _, msl, m2020 = archive
    done = _fetch(tmp_path, server.url, mission, restrict=True)
    assert done.returncode == 0, done.stdout[-1500:] + done.stderr[-1500:]
    cache = tmp_path / "cache"
    placed = msl if mission == "msl" else m2020
    assert (cache / placed[0]).is_file() and not (cache / placed[1]).exists()
    skipped = pq.read_table(cache / "fetch_skipped.parquet").to_pylist()
    named = [s for s in skipped if s["reason"] == "not named by the terrain labels"]
    want = MSL_IDS[1] if mission == "msl" else M2020_IDS[1]
    assert [s["product_id"] for s in named] == [want]


def _parse(products: dict[str, object], tmp_path: Path):
    from mars_pairs.fetch.config import parse_fetch

    return parse_fetch({"cache": "c", "products": products}, tmp_path, 100, 128).products


def test_navcam_config_defaults(tmp_path) -> None:
    from mars_pairs.errors import ConfigError

    msl = _parse({"mission": "msl", "camera": "ncam", "archive": "http://x"}, tmp_path)
    assert msl.volumes == ("MSLNAV_1XXX",) and msl.index == "INDEX"
    m20 = _parse({"mission": "m2020", "camera": "ncam", "archive": "http://x",
                  "bundle": M2020_BUNDLE}, tmp_path)  # fmt: skip
    assert m20.label_path == "data/sol/{sol:05d}/ids/edr/ncam/{product_id}.xml"
    with pytest.raises(ConfigError, match=r"fetch\.products\.camera"):
        _parse({"mission": "msl", "camera": "zcam", "archive": "http://x"}, tmp_path)
