"""Orbital windows over HTTP range requests, remote rasters in configs, fetch -> build -> data."""

from __future__ import annotations

import numpy as np
import pyarrow.parquet as pq
import pytest
import rasterio
import yaml
from pyproj import Transformer
from rasterio.windows import from_bounds

from mars_pairs.fetch.config import load_fetch_config
from mars_pairs.fetch.orbital import cut_planned, rover_positions, source_info
from mars_pairs.fetch.run import fetch_orbital, fetch_places, fetch_products
from mars_pairs.fetch.windows import plan_windows
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import load_config
from mars_pairs.torch import MarsPairsDataset
from support.fetch_archive import write_config

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow


def _orbital_config(tmp, url, mission, kind):
    path = write_config(tmp, url, mission)
    doc = yaml.safe_load(path.read_text())
    base = f"{url}/orbital/{mission}"
    doc["fetch"]["orbital"] = {"dem": f"{base}/dem_{kind}.tif", "ortho": f"{base}/ortho_{kind}.tif"}
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.mark.parametrize("kind", ["cog", "striped"])
def test_windows_move_a_fraction_of_the_file_and_equal_the_local_read(
    archive, server, tmp_path, kind
):
    cfg = load_fetch_config(_orbital_config(tmp_path, server.url, "msl", kind))
    server.reset_log()
    results = fetch_orbital(cfg)
    for res in results:
        name = res.path.stem
        remote = f"orbital/msl/{name}_{kind}.tif"
        moved = server.bytes_sent(remote)
        size = (archive.root / remote).stat().st_size
        local = archive.root / remote
        with rasterio.open(res.path) as win, rasterio.open(local) as src:
            assert win.crs == src.crs and win.profile["driver"] == "GTiff"
            assert win.tags(ns="IMAGE_STRUCTURE")["LAYOUT"] == "COG"  # a local COG
            w = from_bounds(*win.bounds, transform=src.transform)
            expect = src.read(window=w.round_offsets().round_lengths())
            assert np.array_equal(win.read(), expect)  # the same cells as the local file
            frac = moved / size
        print(f"{kind} {name}: {moved} of {size} bytes ({frac:.1%}) for {res.shape}")
        if kind == "cog":
            assert frac < 0.5, f"{remote}: {moved} of {size} bytes moved"
        assert any(e.range for e in server.requests_for(remote))  # range requests, not a GET
    server.reset_log()
    again = fetch_orbital(cfg)
    assert all(r.cached for r in again)
    assert not [e for e in server.log if "orbital/" in e.path]  # a rerun reads nothing


def test_the_window_is_cut_in_the_raster_crs_not_the_places_crs(archive, server, tmp_path):
    """PLACES (eqc lat_ts=18.4663) positions inside a DEM in eqc lat_ts=0 (the USGS CRS)."""
    cfg = load_fetch_config(write_config(tmp_path, server.url, "m2020"))
    pos = rover_positions(fetch_places(cfg))
    assert "+lat_ts=18.4663" in pos.crs
    info = source_info(f"{server.url}/orbital/m2020/dem_eqc0_cog.tif")
    plan = plan_windows(pos.x, pos.y, pos.crs, info.grid, 50.0, kind="dem", source=info.source)
    assert plan.windows and not plan.off_raster
    inside = np.zeros(len(pos.x), bool)
    for i, win in enumerate(plan.windows):
        res = cut_planned(win, info, cfg.cache / "orbital" / f"eqc0-{i}.tif")
        with rasterio.open(res.path) as ds:
            to_raster = Transformer.from_crs(pos.crs, ds.crs, always_xy=True)
            x, y = to_raster.transform(pos.x, pos.y)
            left, bottom, right, top = ds.bounds
            inside |= (x > left + 40) & (x < right - 40) & (y > bottom + 40) & (y < top - 40)
            # the trap: the same numbers read as lat_ts=0 eastings fall ~5 % (200 km) west
            assert np.all(pos.x < left - 100_000)
    assert inside.all()


def test_fetch_then_build_then_dataset_and_remote_rasters_give_the_same_chips(
    archive, server, tmp_path
):
    path = _orbital_config(tmp_path, server.url, "msl", "cog")
    cfg = load_fetch_config(path)
    fetch_places(cfg)
    assert not fetch_products(cfg, progress=False).failures
    fetch_orbital(cfg)
    doc = yaml.safe_load(path.read_text())
    doc.update({
        "inputs": {
            "labels": "cache/MSLMST_0001/DATA/RDR/SURFACE/**/*.LBL",
            "places": f"cache/{'MSLPLC_1XXX/DATA/LOCALIZATIONS/localized_interp.csv'}",
            "dem": "cache/orbital/dem.tif",
            "ortho": "cache/orbital/ortho.tif",
        },
        "geometry": {"radius": 200, "ray_stride": 16},
        "chips": {"size_m": 64, "size_px": 64},
        "output": {"dir": "local", "shard_size": 8},
    })  # fmt: skip
    path.write_text(yaml.safe_dump(doc))
    local = run_build(load_config(path), progress=False)
    assert local.samples == 4 and local.failures == 0
    ds = MarsPairsDataset(tmp_path / "local", fields=("ortho", "dem"))
    assert len(ds) == 4 and ds[0]["dem"].shape[-2:] == (64, 64)
    # the same build reading the remote COGs window by window (config names the URLs)
    doc["inputs"]["dem"] = f"{server.url}/orbital/msl/dem_cog.tif"
    doc["inputs"]["ortho"] = f"{server.url}/orbital/msl/ortho_cog.tif"
    doc["output"]["dir"] = "remote"
    path.write_text(yaml.safe_dump(doc))
    server.reset_log()
    remote = run_build(load_config(path), progress=False)
    assert remote.samples == 4 and remote.failures == 0
    moved = server.bytes_sent("orbital/msl/dem_cog.tif")
    size = (archive.root / "orbital/msl/dem_cog.tif").stat().st_size
    print(f"remote build: DEM {moved} of {size} bytes")
    assert 0 < moved < size
    a = pq.read_table(tmp_path / "local" / "manifest.parquet").sort_by("key")
    b = pq.read_table(tmp_path / "remote" / "manifest.parquet").sort_by("key")
    for col in ("key", "easting", "northing", "azimuth_deg", "visible_cells"):
        if col in a.column_names:
            assert a[col].to_pylist() == b[col].to_pylist(), col
    da = MarsPairsDataset(tmp_path / "local", fields=("ortho", "dem", "viewshed"))
    db = MarsPairsDataset(tmp_path / "remote", fields=("ortho", "dem", "viewshed"))
    for i in range(4):
        sa, sb = da[i], db[i]
        for f in ("ortho", "dem", "viewshed"):
            assert np.array_equal(sa[f].numpy(), sb[f].numpy(), equal_nan=True), (i, f)
