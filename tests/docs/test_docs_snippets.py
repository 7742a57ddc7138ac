"""The Python blocks of the getting-started page and of the README run as written, on a
dataset built from a small synthetic mission (the demo's path replaced by it)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from support.builds import build_small

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "docs" / "getting-started.md", ROOT / "README.md"]
BLOCK = re.compile(r"```python\n(.*?)```", re.S)


def blocks(page: Path) -> list[str]:
    return BLOCK.findall(page.read_text())


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory, small_mission: Path) -> Path:
    out = tmp_path_factory.mktemp("snippets") / "ds"
    return build_small(small_mission, out, splits={"ratios": {"train": 1.0}})


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_python_blocks_run(page: Path, dataset: Path, capsys: pytest.CaptureFixture[str]) -> None:
    found = blocks(page)
    assert found, f"{page.name} holds no python block"
    for code in found:
        exec(compile(code.replace("out/demo/dataset", str(dataset)), page.name, "exec"), {})
    assert capsys.readouterr().out  # the blocks print what they show
