"""YAML configs are read strictly and fast (issue 22): a key twice in one mapping is refused,
naming the key and both lines; aliases may not expand beyond a bound (a ~300-byte "billion
laughs" document is refused at once) nor into themselves; a syntax error is one line with the
file, line and column; long values are elided in messages. The fetch config shares the loader.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from mars_pairs.cli.main import main
from mars_pairs.errors import ConfigError
from mars_pairs.fetch.config import load_fetch_config
from mars_pairs.pipeline.config import ChipsConfig, GeometryConfig, load_config, read_yaml
from mars_pairs.pipeline.config_schema import read_section

BOMB = "a: &a [lol, lol, lol, lol, lol, lol, lol, lol, lol]\n" + "".join(
    f"{n}: &{n} [{', '.join([f'*{p}'] * 9)}]\n" for p, n in zip("abcdefgh", "bcdefghi", strict=True)
)
BOMB += "inputs: {labels: '*.xml', places: p.csv, dem: d.tif, ortho: o.tif, images: *i}\n"


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "config.yaml"
    path.write_text(text)
    return path


def test_a_duplicate_key_names_the_key_and_both_lines(tmp_path: Path) -> None:
    path = _write(tmp_path, "inputs:\n  labels: a\ngeometry:\n  radius: 100\n  radius: 5\n")
    with pytest.raises(
        ConfigError, match=r"config\.yaml: duplicate key 'radius' at line:column 4:3 and 5:3"
    ):
        load_config(path)
    top = _write(tmp_path, "output: {dir: a}\nchips: {}\noutput: {dir: b}\n")
    with pytest.raises(ConfigError, match="duplicate key 'output' at line:column 1:1 and 3:1"):
        read_yaml(top)
    fetch = _write(tmp_path, "fetch:\n  cache: a\n  cache: b\n")
    with pytest.raises(ConfigError, match="duplicate key 'cache' at line:column 2:3 and 3:3"):
        load_fetch_config(fetch)
    # the same key twice on one line (a flow mapping) is a duplicate too
    flow = _write(
        tmp_path, "inputs:\n  labels: a\ngeometry: {radius: 200, ray_stride: 8, radius: 5}\n"
    )
    with pytest.raises(ConfigError, match="duplicate key 'radius' at line:column 3:12 and 3:40"):
        load_config(flow)


def test_anchors_and_merge_keys_within_the_bound_still_load(tmp_path: Path) -> None:
    path = _write(tmp_path, "base: &b {p: 1, q: [1, 2]}\nmine:\n  <<: *b\n  p: 2\nagain: *b\n")
    assert read_yaml(path) == {
        "base": {"p": 1, "q": [1, 2]},
        "mine": {"p": 2, "q": [1, 2]},
        "again": {"p": 1, "q": [1, 2]},
    }


def test_an_alias_bomb_is_refused_at_once(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _write(tmp_path, BOMB)
    assert len(BOMB) < 800
    start = time.monotonic()
    assert main(["build", "--config", str(path), "--dry-run"]) == 2
    assert time.monotonic() - start < 1.0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "aliases expand the config beyond" in err, err[:300]
    with pytest.raises(ConfigError, match="alias inside its own anchor"):
        read_yaml(_write(tmp_path, "a: &a [1, *a]\n"))


def test_a_yaml_syntax_error_is_one_line_with_line_and_column(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _write(tmp_path, "inputs:\n  labels: [a, b\n  dem: x\n")
    assert main(["build", "--config", str(path), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"mars-pairs build: {path}:3:6: not valid YAML: expected ',' or ']', but got ':' "
        "(while parsing a flow sequence at line 2)\n"
    )
    tab = _write(tmp_path, "inputs:\n\tlabels: a\n")
    with pytest.raises(ConfigError, match=r"config\.yaml:2:1: not valid YAML: found character"):
        read_yaml(tab)


def test_long_values_are_elided_in_messages() -> None:
    long = [1.5] * 5000
    with pytest.raises(ConfigError) as caught:
        read_section(GeometryConfig, {"radius": long}, "geometry")
    message = str(caught.value)
    assert message.startswith("geometry.radius: expected a number in (0, 200000], got [1.5, 1.5,")
    assert "..." in message and len(message) < 200
    with pytest.raises(ConfigError, match=r"unknown key") as caught:
        read_section(ChipsConfig, {"x" * 10_000: 1}, "chips")
    assert len(str(caught.value)) < 300
