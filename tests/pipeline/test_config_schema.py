"""Every key of both config schemas (the build's and fetch's) refuses every wrong type, before
any work: one ConfigError line naming ``section.key`` and the YAML line of the key, exit 2
from the command; the cases the reliability sweep found, each a test; the reference page is
the one the schema generates."""

from __future__ import annotations

import copy
import math
import pickle
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from mars_pairs.cli.main import main
from mars_pairs.errors import ConfigError
from mars_pairs.fetch.config import (
    FetchSection,
    OrbitalSpec,
    ProductsSection,
    RemoteSpec,
    load_fetch_config,
)
from mars_pairs.pipeline.config import (
    ChipsConfig,
    GeometryConfig,
    InputsConfig,
    OutputConfig,
    SplitsConfig,
    SyntheticSpec,
    load_config,
)
from support.schema_walk import section_fields, wrong_values

BUILD = {
    "inputs": {
        "labels": "labels/*.xml",
        "places": "p.csv",
        "dem": "d.tif",
        "ortho": "o.tif",
        "images": "imgs",
        "synthetic": {"root": "mission"},
    },
    "geometry": {},
    "chips": {},
    "output": {"dir": "out"},
    "splits": {},
}
FETCH = {
    "fetch": {
        "cache": "cache",
        "products": {"mission": "msl", "archive": "arch", "volumes": ["MSLMST_0014"]},
        "places": {"archive": "arch", "path": "p.csv"},
        "orbital": {"dem": "d.tif"},
    }
}
BUILD_SECTIONS = [
    ("inputs", InputsConfig),
    ("inputs.synthetic", SyntheticSpec),
    ("geometry", GeometryConfig),
    ("chips", ChipsConfig),
    ("output", OutputConfig),
    ("splits", SplitsConfig),
]
FETCH_SECTIONS = [
    ("fetch", FetchSection),
    ("fetch.products", ProductsSection),
    ("fetch.places", RemoteSpec),
    ("fetch.orbital", OrbitalSpec),
]


def _cases(sections: list[tuple[str, type]], command: str) -> list[Any]:
    return [
        pytest.param(command, prefix, key, value, id=f"{prefix}.{key}: {what}")
        for prefix, cls in sections
        for key in section_fields(cls)
        for what, value in wrong_values(cls, key)
    ]


CASES = _cases(BUILD_SECTIONS, "build") + _cases(FETCH_SECTIONS, "fetch")


def _doc(command: str, prefix: str, key: str, value: Any) -> dict[str, Any]:
    doc = copy.deepcopy(BUILD if command == "build" else FETCH)
    if (prefix, key) == ("splits", "areas"):  # areas are cross-area's
        doc["splits"] = {"style": "cross-area", "areas": {"test": [0, 0, 1, 1]}}
    block = doc
    for part in prefix.split("."):
        block = block[part]
    block[key] = value
    return doc


def _key_span(text: str, path: list[str]) -> tuple[int, int]:
    """The first and last line (1-based) of the key at ``path`` and its value in ``text``."""
    node = yaml.compose(text)
    key_line = 1
    for part in path:
        assert isinstance(node, yaml.MappingNode)
        key_node, node = next((k, v) for k, v in node.value if k.value == part)
        key_line = key_node.start_mark.line + 1
    return key_line, node.end_mark.line + 1


def _setup(tmp_path: Path) -> None:
    (tmp_path / "imgs").mkdir()


@pytest.mark.parametrize(("command", "prefix", "key", "value"), CASES)
def test_every_key_refuses_every_wrong_value_in_one_line(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    command: str,
    prefix: str,
    key: str,
    value: Any,
) -> None:
    _setup(tmp_path)
    path = tmp_path / "c.yaml"
    text = yaml.safe_dump(_doc(command, prefix, key, value), sort_keys=False, width=10**6)
    path.write_text(text)
    before = sorted(p.name for p in tmp_path.iterdir())
    argv = ["build", "--config", str(path)] if command == "build" else ["fetch", "places"]
    if command == "fetch":
        argv += ["--config", str(path)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err[:500]
    head = f"mars-pairs {command}: {path}:"
    assert err.startswith(head), err[:300]
    line, column, message = err[len(head) :].split(":", 2)
    named = f"{prefix}.{key}"
    assert message.startswith(f" {named}"), err[:300]
    assert message[len(named) + 1] in ".:[", err[:300]  # this key or one inside it
    first, last = _key_span(text, [*prefix.split("."), key])
    assert first <= int(line) <= last and int(column) >= 1, (err, first, last)
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no work was done


def test_the_walk_reaches_every_key_of_both_schemas() -> None:
    walked = {(c.values[1], c.values[2]) for c in CASES}
    every = {(p, k) for p, cls in BUILD_SECTIONS + FETCH_SECTIONS for k in section_fields(cls)}
    assert walked == every
    assert len(CASES) > 300


def test_the_bases_of_the_walk_are_valid(tmp_path: Path) -> None:
    _setup(tmp_path)
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(BUILD))
    assert load_config(path).inputs.images == tmp_path / "imgs"
    path.write_text(yaml.safe_dump(FETCH))
    assert load_fetch_config(path).policy.read_timeout_s == 60.0


# --- the fetch reader's drift from the build's ---------------------------------------------------


@pytest.mark.parametrize(
    ("where", "text"),
    [
        ("fetch.timeout_s", "  timeout_s: .inf\n"),
        ("fetch.backoff_s", "  backoff_s: .inf\n"),
        ("fetch.orbital.margin_m", "  orbital: {dem: d.tif, margin_m: .inf}\n"),
        ("fetch.timeout_s", "  timeout_s: .nan\n"),
        ("fetch.timeout_s", "  timeout_s: 0\n"),
        ("fetch.timeout_s", "  timeout_s: 1e-9\n"),
        ("fetch.1", "  1: 2\n  zz: 3\n"),
    ],
)
def test_the_fetch_reader_refuses_what_the_build_reader_refuses(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], where: str, text: str
) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("fetch:\n  cache: c\n" + text)
    assert main(["fetch", "places", "--config", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "bad.yaml:3:" in err and f": {where}: " in err, err


def test_a_fetch_section_with_mixed_key_types_exits_2_with_one_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text("fetch:\n  cache: c\n  1: 2\n  zz: 3\n")
    cmd = [sys.executable, "-m", "mars_pairs.cli", "fetch", "places", "--config", str(path)]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert run.returncode == 2, run.stderr
    assert run.stderr.count("\n") == 1 and "Traceback" not in run.stderr
    assert f"{path}:3:3: fetch.1: unknown key" in run.stderr
    assert not (tmp_path / "c").exists()


def test_numbers_written_as_text_are_numbers_in_both_readers(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("fetch:\n  cache: c\n  timeout_s: 1e1\n  backoff_s: 5E-1\n")
    policy = load_fetch_config(path).policy
    assert (policy.read_timeout_s, policy.backoff_s) == (10.0, 0.5)


# --- inputs that ran long, crashed or were accepted ------------------------------------------


def _build_config(tmp_path: Path, **inputs: Any) -> Path:
    doc = {
        "inputs": {"labels": "labels/*.xml", "places": "p.csv", "dem": "d.tif", "ortho": "o.tif"},
        "output": {"dir": "out"},
    }
    doc["inputs"].update(inputs)
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(doc, width=10**6))
    return path


@pytest.mark.parametrize(
    ("inputs", "needle"),
    [
        ({"labels": 5}, "inputs.labels: expected a glob or a list of globs, got 5"),
        ({"labels": "/**/*.xml"}, "inputs.labels: '/**/*.xml' would walk the whole file system"),
        ({"labels": ["a/*.xml", "/**/x.LBL"]}, "inputs.labels: '/**/x.LBL' would walk"),
        ({"labels": "../" * 40 + "**/*.xml"}, "would walk the whole file system"),
        (
            {"synthetic": {"root": "m", "stops": 2_000_000_000}},
            "inputs.synthetic.stops: expected an integer in [1, 10000], got 2000000000",
        ),
        ({"images": "/nonexistent"}, "inputs.images: /nonexistent: no such folder"),
    ],
)
def test_bad_inputs_are_refused_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], inputs: dict[str, Any], needle: str
) -> None:
    path = _build_config(tmp_path, **inputs)
    assert main(["build", "--config", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.yaml"]  # no mission, no output


def test_a_recursive_glob_below_the_root_is_kept(tmp_path: Path) -> None:
    path = _build_config(tmp_path, labels=["labels/**/*.xml", "/data/**/*.LBL"])
    assert load_config(path).inputs.labels == (str(tmp_path / "labels/**/*.xml"), "/data/**/*.LBL")


def test_text_values_are_bounded(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    doc = yaml.safe_load(_build_config(tmp_path).read_text())
    doc["output"]["license"] = "x" * 100_000
    path.write_text(yaml.safe_dump(doc, width=10**6))
    with pytest.raises(ConfigError, match=r"c\.yaml:\d+:3: output\.license: expected an SPDX") as e:
        load_config(path)
    assert len(str(e.value)) < 400  # the value is elided
    doc["output"]["license"] = "CC-BY-4.0"
    path.write_text(yaml.safe_dump(doc))
    assert load_config(path).output.license == "CC-BY-4.0"


def test_a_config_error_keeps_its_line_through_pickle() -> None:
    error = ConfigError("geometry.radius: expected a number", line=(5, 3))
    again = pickle.loads(pickle.dumps(error))
    assert (str(again), again.line) == (str(error), (5, 3))


def test_null_is_the_default_and_a_required_null_is_missing(tmp_path: Path) -> None:
    path = _build_config(tmp_path)
    text = path.read_text() + "geometry:\n  radius: null\n  observer_height: null\n"
    path.write_text(text)
    config = load_config(path)
    assert (config.geometry.radius, config.geometry.observer_height) == (2000.0, None)
    path.write_text(text.replace("places: p.csv", "places: null"))
    with pytest.raises(ConfigError, match=r"inputs\.places: required key is missing"):
        load_config(path)
    assert math.isfinite(config.chips.size_m)


# --- the reference page -----------------------------------------------------------------------


def test_the_committed_reference_page_is_the_generated_one() -> None:
    from mars_pairs.config_reference import SECTIONS, reference_page

    page = Path(__file__).resolve().parents[2] / "docs" / "reference" / "config.md"
    assert page.read_text() == reference_page(), "run: python scripts/config_reference.py"
    text = page.read_text()
    for prefix, cls in SECTIONS:  # every key, with what it takes and its default
        for key in section_fields(cls):
            row = next(r for r in text.splitlines() if r.startswith(f"| `{prefix}.{key}` |"))
            takes, default, meaning = (c.strip() for c in row.split(" | ")[1:4])
            assert takes and default and meaning, row
    assert "| `geometry.radius` | a number in (0, 200000] | `2000` |" in text
    assert "| `geometry.viewshed` | one of ['wedge', 'raycast', 'both'] | `both` |" in text
    assert "| `fetch.timeout_s` | a number in [0.001, 3600] | `60` |" in text
