"""store.fs and raster.vsi against the S3 test server: the storage seams the build and the
readers use."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin

from mars_pairs.errors import ConfigError
from mars_pairs.raster import vsi
from mars_pairs.store import fs

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow


def test_dataset_root_keeps_urls_and_makes_paths() -> None:
    assert fs.dataset_root("s3://bucket/prefix/") == "s3://bucket/prefix"
    assert fs.dataset_root("relative/dir") == Path("relative/dir")
    assert fs.dataset_root("file:///tmp/x") == Path("/tmp/x")
    assert fs.join("s3://b/p", "shards/a.tar") == "s3://b/p/shards/a.tar"
    assert fs.join(Path("/d"), "parts/x") == Path("/d/parts/x")


def test_an_unknown_protocol_is_a_config_error_naming_the_url() -> None:
    with pytest.raises(ConfigError, match=r"nosuch://bucket/x: no file system for nosuch://"):
        fs.exists("nosuch://bucket/x")


def test_s3_options_from_the_endpoint_variable() -> None:
    env = {"AWS_ENDPOINT_URL": "http://127.0.0.1:9000/"}
    assert vsi.s3_options(env) == {
        "AWS_S3_ENDPOINT": "127.0.0.1:9000",
        "AWS_HTTPS": "NO",
        "AWS_VIRTUAL_HOSTING": "FALSE",
    }
    assert vsi.s3_options({}) == {}
    assert vsi.gdal_path("s3://bucket/a/dem.tif") == "/vsis3/bucket/a/dem.tif"
    assert vsi.is_remote("s3://bucket/a/dem.tif")


def test_files_on_s3(s3_prefix: str, tmp_path: Path) -> None:
    local = tmp_path / "a.bin"
    local.write_bytes(b"0123456789")
    fs.upload(local, fs.join(s3_prefix, "shards/a.bin"))
    fs.put_bytes(fs.join(s3_prefix, "b.json"), b"{}")
    assert fs.list_files(s3_prefix) == ["b.json", "shards/a.bin"]
    assert fs.list_names(s3_prefix) == ["b.json"]  # the folder's own files
    assert fs.list_names(fs.join(s3_prefix, "none")) == []
    assert fs.read_range(fs.join(s3_prefix, "shards/a.bin"), 3, 4) == b"3456"
    assert fs.size(fs.join(s3_prefix, "shards/a.bin")) == 10
    fs.replace(fs.join(s3_prefix, "b.json"), fs.join(s3_prefix, "c.json"))
    assert fs.list_files(s3_prefix) == ["c.json", "shards/a.bin"]
    assert fs.read_bytes(fs.join(s3_prefix, "c.json")) == b"{}"
    fs.remove(fs.join(s3_prefix, "c.json"))
    fs.remove(fs.join(s3_prefix, "c.json"))  # absent: nothing to do
    assert not fs.exists(fs.join(s3_prefix, "c.json"))
    assert fs.list_files(fs.join(s3_prefix, "none")) == []


def test_a_raster_on_s3_reads_through_vsis3(
    s3_prefix: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A tiled GeoTIFF uploaded to the server reads through /vsis3/ with the endpoint and
    credentials handed to GDAL explicitly, its blocks read after the open's options end."""
    path = tmp_path / "dem.tif"
    data = np.arange(512 * 512, dtype=np.float32).reshape(1, 512, 512)
    profile = dict(driver="GTiff", width=512, height=512, count=1, dtype="float32",
                   crs="EPSG:32611", transform=from_origin(0, 512, 1, 1), tiled=True,
                   blockxsize=128, blockysize=128)  # fmt: skip
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(data)
    fs.upload(path, fs.join(s3_prefix, "dem.tif"))
    gdal = vsi.gdal_path(fs.join(s3_prefix, "dem.tif"))
    with vsi.open_raster(gdal) as src:
        window = rasterio.windows.Window(300, 400, 50, 20)
        assert np.array_equal(src.read(1, window=window), data[0, 400:420, 300:350])


def test_the_orbital_fetch_opens_an_s3_source(s3_prefix: str, tmp_path: Path) -> None:
    """``fetch.orbital.open_source`` opens an ``s3://`` raster through ``/vsis3/`` with the
    endpoint and credentials of the environment (as the build's readers do)."""
    from mars_pairs.fetch.orbital import open_source

    path = tmp_path / "dem.tif"
    data = np.arange(64, dtype=np.float32).reshape(8, 8)
    with rasterio.open(
        path, "w", driver="GTiff", width=8, height=8, count=1, dtype="float32",
        crs="EPSG:32633", transform=from_origin(500000.0, 4000008.0, 1.0, 1.0),
    ) as dst:  # fmt: skip
        dst.write(data, 1)
    url = fs.join(s3_prefix, "dem.tif")
    fs.put_bytes(url, path.read_bytes())
    with open_source(url) as (opened, ds):
        assert opened == url
        assert ds.crs.to_epsg() == 32633
        np.testing.assert_array_equal(ds.read(1), data)
