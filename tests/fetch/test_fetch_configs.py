"""The shipped configs' fetch sections validate, and their build sections still load."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from mars_pairs.fetch.config import load_fetch_config
from mars_pairs.pipeline.config import load_config

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


@pytest.mark.parametrize("name", ["msl_gale.yaml", "m2020_jezero.yaml"])
def test_real_configs_name_the_archive_roots(name):
    cfg = load_fetch_config(CONFIGS / name)
    build = load_config(CONFIGS / name)
    assert cfg.products is not None and cfg.products.archive.startswith("https://")
    assert cfg.orbital is not None and cfg.orbital.dem.startswith("https://")
    assert "Eqc_latTs0" in cfg.orbital.dem or "Gale" in cfg.orbital.dem
    assert cfg.radius_m == build.geometry.radius == 5000
    # the build reads what the fetch writes: labels and PLACES under the fetch cache
    assert all(Path(os.path.normpath(g)).is_relative_to(cfg.cache) for g in build.inputs.labels)
    assert Path(build.inputs.places).is_relative_to(cfg.cache)
    assert Path(build.inputs.dem) == cfg.cache / "orbital" / "dem.tif"


def test_a_build_config_may_name_a_remote_raster(tmp_path):
    text = (CONFIGS / "msl_gale.yaml").read_text()
    text = text.replace(
        "dem: ../data/archive/orbital/dem.tif", "dem: https://example.invalid/dem.tif"
    )
    path = tmp_path / "remote.yaml"
    path.write_text(text)
    assert load_config(path).inputs.dem == "/vsicurl/https://example.invalid/dem.tif"
