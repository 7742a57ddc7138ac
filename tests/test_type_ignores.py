"""Every ``type: ignore`` in the package names its error code and says why.

mypy (``make lint``, ``warn_unused_ignores``) reports an ignore that no longer silences
anything; this test covers what mypy does not: a bare ``type: ignore`` or one without a reason
comment after it (``# type: ignore[operator]  # affine's hints: floats, not arrays``).
"""

from __future__ import annotations

import io
import re
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "mars_pairs"

IGNORE = re.compile(r"#\s*type:\s*ignore\b")
EXPLAINED = re.compile(r"# type: ignore\[[a-z-]+(?:, *[a-z-]+)*\]  # \S")


def _ignores(source: str) -> list[tuple[int, str]]:
    """(line, comment) of every comment holding ``type: ignore`` (not strings or docstrings)."""
    tokens = tokenize.generate_tokens(io.StringIO(source).readline)
    return [
        (t.start[0], t.string)
        for t in tokens
        if t.type == tokenize.COMMENT and IGNORE.search(t.string)
    ]


def test_the_scan_finds_comments_only() -> None:
    source = (
        '"""A docstring naming # type: ignore."""\n'
        "x = 1  # type: ignore\n"
        "y = 2  # type: ignore[operator]  # affine's hints: floats, not arrays\n"
        "z = '# type: ignore'\n"
    )
    found = _ignores(source)
    assert [line for line, _ in found] == [2, 3]
    assert [bool(EXPLAINED.search(text)) for _, text in found] == [False, True]


def test_every_type_ignore_has_a_code_and_a_reason() -> None:
    bad = [
        f"{path.relative_to(ROOT.parent)}:{line}: {text}"
        for path in sorted(ROOT.rglob("*.py"))
        for line, text in _ignores(path.read_text(encoding="utf-8"))
        if not EXPLAINED.search(text)
    ]
    assert not bad, "type: ignore without an error code and a reason:\n" + "\n".join(bad)
