"""The streamed label listing equals sorted glob results, one path once, without sorting."""

from __future__ import annotations

import glob
import os
from pathlib import Path

import pytest

from mars_pairs.pipeline.builder.label_list import iter_matches

# names whose order differs between strings and path components: "a-b/x" < "a/x" as strings
# ('-' < '/'), but "a" < "a-b" as components, which is the order the build always used
NAMES = ("a", "a-b", "a.b", "a_b", "a0", "a10", "a9", "B", "-z", ".hidden", "x.xml", "x.XML")


@pytest.fixture(scope="module")
def tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tree where the order matters: the same names as folders at three depths, files in
    each, a hidden folder with labels, a symlinked folder and a broken symlink."""
    root = tmp_path_factory.mktemp("tree")
    for top in NAMES:
        for mid in ("", *NAMES[:5]):
            folder = root / top / mid
            folder.mkdir(parents=True, exist_ok=True)
            for name in ("f.xml", "f-1.xml", "f_1.xml", "f.1.xml", "g.lbl", ".h.xml"):
                (folder / name).touch()
    (root / "top.xml").touch()
    (root / "link").symlink_to(root / "a-b")
    (root / "broken.xml").symlink_to(root / "nowhere")
    return root


def _sorted_glob(patterns: list[str]) -> list[str]:
    """The build's listing before streaming: every glob match, de-duplicated, sorted."""
    found = {Path(p) for pattern in patterns for p in glob.glob(pattern, recursive=True)}
    return [str(p) for p in sorted(found)]


PATTERNS = [
    "*",
    "*.xml",
    "*/*.xml",
    "*/*/*.xml",
    "**",
    "**/*.xml",
    "**/",
    "a*/**",
    "a*/**/*.xml",
    "**/a*/f*.xml",
    "*/**/**/f.xml",
    "[ab]*/*",
    "[!a]*/?.xml",
    ".*/*.xml",
    "**/.h.xml",
    "*/../a/f.xml",
    "a/f.xml",
    "missing/*.xml",
]


@pytest.mark.parametrize("pattern", PATTERNS)
def test_the_stream_is_sorted_glob_relative_and_absolute(
    pattern: str, tree: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    root = tree
    absolute = str(root / pattern)
    assert list(iter_matches([absolute])) == _sorted_glob([absolute])
    monkeypatch.chdir(root)
    assert list(iter_matches([pattern])) == _sorted_glob([pattern])


def test_the_order_is_by_path_components_not_by_string(tree: Path) -> None:
    root = tree
    found = list(iter_matches([str(root / "*" / "f.xml")]))
    assert found.index(str(root / "a" / "f.xml")) < found.index(str(root / "a-b" / "f.xml"))
    assert found != sorted(found)  # as strings, "a-b/f.xml" < "a/f.xml"


def test_overlapping_patterns_give_each_path_once(tree: Path) -> None:
    root = tree
    patterns = [str(root / p) for p in ("**/*.xml", "a*/*.xml", "a/f.xml", "*/a*/f*.xml")]
    found = list(iter_matches(patterns))
    assert len(found) == len(set(found))
    assert found == _sorted_glob(patterns)
    assert list(iter_matches([patterns[0], patterns[0]])) == _sorted_glob(patterns[:1])


def test_double_star_matches_zero_or_more_folders(tmp_path: Path) -> None:
    for rel in ("x.xml", "s/x.xml", "s/t/x.xml", "s/t/u/x.xml", "s/t/u/y.lbl"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).touch()
    found = [str(Path(p).relative_to(tmp_path)) for p in iter_matches([f"{tmp_path}/**/x.xml"])]
    assert found == ["s/t/u/x.xml", "s/t/x.xml", "s/x.xml", "x.xml"]
    every = [str(Path(p).relative_to(tmp_path)) for p in iter_matches([f"{tmp_path}/s/**"])]
    assert every == ["s", "s/t", "s/t/u", "s/t/u/x.xml", "s/t/u/y.lbl", "s/t/x.xml", "s/x.xml"]


def test_hidden_names_are_skipped_like_glob(tmp_path: Path) -> None:
    for rel in ("v.xml", ".w.xml", ".cache/x.xml", "d/.y.xml", "d/z.xml"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).touch()
    names = {
        p: [str(Path(x).relative_to(tmp_path)) for x in iter_matches([f"{tmp_path}/{p}"])]
        for p in ("**/*.xml", "*.xml", ".*.xml", "*/.*.xml", ".cache/*.xml")
    }
    assert names == {
        "**/*.xml": ["d/z.xml", "v.xml"],
        "*.xml": ["v.xml"],
        ".*.xml": [".w.xml"],
        "*/.*.xml": ["d/.y.xml"],
        ".cache/*.xml": [".cache/x.xml"],
    }


@pytest.mark.skipif(not hasattr(os, "symlink"), reason="needs symlinks")
def test_double_star_does_not_follow_a_symlink_loop(tmp_path: Path) -> None:
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "x.xml").touch()
    (tmp_path / "s" / "up").symlink_to(tmp_path)  # s/up/s/up/... for ever
    found = list(iter_matches([f"{tmp_path}/**/*.xml"]))
    assert found == [f"{tmp_path}/s/x.xml"]


@pytest.mark.skipif(not hasattr(os, "symlink"), reason="needs symlinks")
def test_a_label_that_is_a_symlink_loop_is_listed_not_dropped(tmp_path: Path) -> None:
    (tmp_path / "a.xml").touch()
    (tmp_path / "self.xml").symlink_to(tmp_path / "self.xml")  # stat: ELOOP
    (tmp_path / "p.xml").symlink_to(tmp_path / "q.xml")  # p -> q -> p
    (tmp_path / "q.xml").symlink_to(tmp_path / "p.xml")
    (tmp_path / "dangling.xml").symlink_to(tmp_path / "nowhere")
    names = ["a.xml", "dangling.xml", "p.xml", "q.xml", "self.xml"]
    for pattern in ("*.xml", "**/*.xml"):
        found = list(iter_matches([f"{tmp_path}/{pattern}"]))
        assert found == [f"{tmp_path}/{n}" for n in names], pattern
        assert found == _sorted_glob([f"{tmp_path}/{pattern}"])  # as glob lists them
