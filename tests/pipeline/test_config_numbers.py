"""Config numbers are finite and in range (issue 17); ``1e12`` (text to YAML 1.1) is a number."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.config import load_config, parse_config

BASE = {
    "inputs": {"labels": "labels/*.xml", "places": "p.csv", "dem": "d.tif", "ortho": "o.tif"},
    "output": {"dir": "out"},
}


def with_key(section: str, key: str, value: object) -> dict:
    doc = {k: dict(v) for k, v in BASE.items()}
    doc.setdefault(section, {})[key] = value
    return doc


@pytest.mark.parametrize(
    ("section", "key"),
    [
        ("geometry", "observer_height"),
        ("geometry", "radius"),
        ("chips", "size_m"),
        ("splits", "block_m"),
    ],
)
@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_non_finite_numbers_are_refused(
    tmp_path: Path, section: str, key: str, value: float
) -> None:
    with pytest.raises(ConfigError, match=rf"{section}\.{key}: expected a finite number"):
        parse_config(with_key(section, key, value), tmp_path)


@pytest.mark.parametrize("text", [".nan", ".inf", "-.inf"])
def test_yaml_nan_and_inf_are_refused(tmp_path: Path, text: str) -> None:
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(BASE) + f"geometry:\n  radius: {text}\n")
    with pytest.raises(ConfigError, match=r"c\.yaml:\d+:3: geometry\.radius: expected a finite"):
        load_config(path)


def test_exponent_without_a_dot_is_a_number(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(BASE) + "geometry:\n  radius: 1e3\nchips:\n  size_m: 2E2\n")
    assert yaml.safe_load(path.read_text())["geometry"]["radius"] == "1e3"  # YAML 1.1's text
    config = load_config(path)
    assert (config.geometry.radius, config.chips.size_m) == (1000.0, 200.0)
    path.write_text(yaml.safe_dump(BASE) + "geometry:\n  radius: 1e12\n")
    with pytest.raises(ConfigError, match=r"geometry\.radius: expected a number in \(0, 200000\]"):
        load_config(path)


@pytest.mark.parametrize(
    ("section", "key", "value", "needle"),
    [
        ("chips", "size_px", 100000, r"chips\.size_px: expected an integer in \[8, 8192\]"),
        ("geometry", "observer_height", 1e9, r"geometry\.observer_height: expected a number in"),
        ("chips", "size_m", 1e7, r"chips\.size_m: expected a number in \(0, 200000\]"),
        ("output", "shard_size", 2**40, r"output\.shard_size: expected an integer in"),
    ],
)
def test_numbers_that_cannot_fit_in_memory_or_meaning_are_refused(
    tmp_path: Path, section: str, key: str, value: float, needle: str
) -> None:
    with pytest.raises(ConfigError, match=needle):
        parse_config(with_key(section, key, value), tmp_path)
