"""A URL made into a ``Path`` (``Path("s3://b/p")`` is ``s3:/b/p``) is refused wherever a
dataset or catalogue root is taken, with an error naming the URL, and nothing is written to a
folder ``s3:`` of the working directory; local paths, Windows drives and URLs as text are
unaffected."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.catalog.run import run_catalog
from mars_pairs.store import fs
from support.configs import build_config


@pytest.mark.parametrize(
    ("value", "url"),
    [
        (Path("s3://bucket/prefix"), "s3://bucket/prefix"),
        ("gs:/bucket/a/b", "gs://bucket/a/b"),
        ("s3://bucket/prefix", None),  # a URL as text
        ("C:/data/out", None),  # a Windows drive, not a scheme
        ("out/s3:/x", None),
        (Path("/tmp/s3/out"), None),
    ],
)
def test_collapsed_url(value: str | Path, url: str | None) -> None:
    assert fs.collapsed_url(value) == url


def test_dataset_root_refuses_a_path_made_of_a_url() -> None:
    with pytest.raises(ConfigError, match=r"s3://bucket/prefix"):
        fs.dataset_root(Path("s3://bucket/prefix"))
    assert fs.dataset_root("s3://bucket/prefix/") == "s3://bucket/prefix"
    assert fs.dataset_root(Path("local/out")) == Path("local/out")


def test_config_refuses_output_dir_made_of_a_url(small_mission: Path, tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"output.*s3://bucket/x"):
        build_config(small_mission, Path("s3://bucket/x"))


def test_catalogue_and_build_write_nothing_locally(
    small_mission: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    config = build_config(small_mission, tmp_path / "unused")
    with pytest.raises(ConfigError, match=r"s3://bucket/cat"):
        run_catalog(config, Path("s3://bucket/cat"), progress=False)
    with pytest.raises(ValueError, match=r"s3://bucket/ds"):  # the config's own validation
        run_build(replace(config, output=replace(config.output, dir=Path("s3://bucket/ds"))))
    assert not (tmp_path / "s3:").exists()
