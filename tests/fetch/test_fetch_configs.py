"""The shipped configs' fetch sections validate, and their build sections still load."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from mars_pairs.errors import ConfigError
from mars_pairs.fetch.config import load_fetch_config
from mars_pairs.pipeline.config import load_config

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


@pytest.mark.parametrize("name", ["msl_gale.yaml", "m2020_jezero.yaml"])
def test_real_configs_name_the_archive_roots(name):
    cfg = load_fetch_config(CONFIGS / name)
    build = load_config(CONFIGS / name)
    assert cfg.products is not None and cfg.products.archive.startswith("https://")
    assert cfg.orbital is not None and cfg.orbital.dem.startswith("https://")
    # the default orbital source is the PLACES bundle's own maps (what PLACES is registered to)
    maps = {"m2020_jezero.yaml": "/data_maps/m20_orbital_", "msl_gale.yaml": "/MAPS/msl_orbital_"}
    assert cfg.orbital.dem.endswith(maps[name] + "dem.img")
    assert cfg.orbital.ortho.endswith(maps[name] + "map.img")
    assert cfg.radius_m == build.geometry.radius == 5000
    assert cfg.chip_size_m == build.chips.size_m
    # the build reads what the fetch writes: labels and PLACES under the fetch cache, and the
    # orbital windows through their VRT mosaics
    assert all(Path(os.path.normpath(g)).is_relative_to(cfg.cache) for g in build.inputs.labels)
    assert cfg.places is not None
    assert Path(build.inputs.places) == cfg.cache / cfg.places.path
    assert Path(build.inputs.dem) == cfg.cache / "orbital" / "dem.vrt"
    assert Path(build.inputs.ortho) == cfg.cache / "orbital" / "ortho.vrt"


ATTESTED = {  # host + path prefixes named in ../shared/real-archive/README.md or public code
    "https://pds-geosciences.wustl.edu/m2020/urn-nasa-pds-mars2020_rover_places/",
    "https://planetarydata.jpl.nasa.gov/img/data/msl/MSLPLC_1XXX/",
    "https://planetarymaps.usgs.gov/mosaic/mars2020_trn/HiRISE/JEZ_hirise_soc_006_DTM_",
    "https://planetarymaps.usgs.gov/mosaic/mars2020_trn/HiRISE/JEZ_hirise_soc_006_orthoMosaic_25cm_Eqc_latTs0_lon0_first.tif",
    "https://planetarymaps.usgs.gov/mosaic/mars2020_trn/HiRISE/JEZ_hirise_soc_007_orthoMosaic_25cm_Ortho_blend120.tif",
    "https://planetarymaps.usgs.gov/mosaic/Mars/MSL/MSL_Gale_DEM_Mosaic_1m_v3.tif",
    "https://asc-pds-services.s3.us-west-2.amazonaws.com/mosaic/MSL_Gale_Orthophoto_Mosaic_25cm_v3.tif",
}


@pytest.mark.parametrize("name", ["msl_gale.yaml", "m2020_jezero.yaml"])
def test_orbital_and_places_urls_are_attested_and_sourced(name):
    """Every orbital/PLACES URL (set or commented) is an attested one, with its source named."""
    import re

    text = (CONFIGS / name).read_text()
    section = text[text.index("  orbital:\n") :]
    urls = re.findall(r"https://\S+", section)
    assert len(urls) >= 4, urls  # the default maps and the USGS alternatives
    for url in urls:
        assert any(url.startswith(a) for a in ATTESTED), url
    assert "/MSL_Gale/" not in text  # the Gale DEM is under mosaic/Mars/MSL/
    assert "soc_007_orthoMosaic_25cm_Eqc_latTs0_lon0_first" not in text  # a name nowhere attested
    for node in ("PDS", "USGS"):
        assert node in section
    cfg = load_fetch_config(CONFIGS / name)
    assert cfg.places is not None
    assert any(f"{cfg.places.archive}/{cfg.places.path}".startswith(a) for a in ATTESTED)


def test_a_build_config_may_name_a_remote_raster(tmp_path):
    text = (CONFIGS / "msl_gale.yaml").read_text()
    text = text.replace("dem: ../data/msl/orbital/dem.vrt", "dem: https://example.invalid/dem.tif")
    path = tmp_path / "remote.yaml"
    path.write_text(text)
    assert load_config(path).inputs.dem == "/vsicurl/https://example.invalid/dem.tif"


@pytest.mark.parametrize(
    ("value", "message"),
    [("'many'", r"fetch\.orbital\.max_cells: expected an integer in \[1, "),
     ("0", r"fetch\.orbital\.max_cells: expected an integer in \[1, "),
     ("-1", None)],
)  # fmt: skip
def test_orbital_limits_are_validated(tmp_path, value, message):
    text = (CONFIGS / "msl_gale.yaml").read_text()
    if message is None:  # a negative margin
        text = text.replace("margin_m: 10 ", f"margin_m: {value} ")
        message = r"fetch\.orbital\.margin_m: expected a number in \[0, "
    else:
        text = text.replace("max_cells: 200000000", f"max_cells: {value}")
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_fetch_config(path)
