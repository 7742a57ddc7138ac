"""Pathological PDS3 label texts: the shapes a reliability sweep fed the reader, and the
slowest label the structural bounds of ``mars_pairs.pds.pds3`` still accept.

Each shape is a function of nothing returning the label text; ``SHAPES`` names them. Shared by
``tests/pds/test_label_bounds.py`` and ``benchmarks/bench_labels.py``.
"""

from __future__ import annotations

from collections.abc import Callable

from mars_pairs.pds.pds3 import (
    MAX_REPEATED_POINTERS,
    MAX_SEPARATORS,
    MAX_STATEMENTS,
    MAX_TEXT_CHARS,
    MAX_VALUE_CHARS,
)

HEAD = "PDS_VERSION_ID = PDS3\nPRODUCT_ID = SHAPE\n"
FOUR_MB = 4_000_000


def _label(body: str) -> str:
    return HEAD + body + "END\n"


SHAPES: dict[str, Callable[[], str]] = {
    # pdr's index_duplicate_pointers copies the label twice per repeat: quadratic
    "10k duplicate pointers": lambda: _label("^A = 1\n" * 10_000),
    "100k duplicate pointers": lambda: _label("^A = 1\n" * 100_000),
    "2k duplicate pointers, one per group": lambda: _label(
        "GROUP = G\n^A = 1\nEND_GROUP = G\n" * 2_000
    ),
    "10k duplicate keys": lambda: _label("A = 1\n" * 10_000),
    "100k duplicate keys": lambda: _label("A = 1\n" * 100_000),
    "100k distinct keys": lambda: _label("".join(f"K{i} = 1\n" for i in range(100_000))),
    # literal_eval of one 4 MB tuple: ~9 s and ~1.9 GB
    "4 MB tuple value": lambda: _label("A = (" + "1," * (FOUR_MB // 2) + "1)\n"),
    "4 MB quoted value": lambda: _label('A = "' + "X" * FOUR_MB + '"\n'),
    "4 MB unclosed quote, 2M lines": lambda: _label('A = "' + "x\n" * (FOUR_MB // 2)),
    "4 MB of quantities in 64 KB values": lambda: _label(
        "".join(f"Q{i} = (" + "1 <m>," * 10_900 + "1)\n" for i in range(60))
    ),
    "10k nested GROUPs": lambda: _label("GROUP = G\n" * 10_000 + "END_GROUP = G\n" * 10_000),
    "1k nested OBJECTs, unclosed": lambda: _label("OBJECT = O\n" * 1_000),
    "20k unclosed comment lines": lambda: _label("/* x\n" * 20_000),
}


def slowest_accepted() -> str:
    """A label at the bounds: the most statements, commas (as ``1 <m>`` quantities, pdr's
    slowest items) and repeated pointers ``check_structure`` accepts."""
    pointers = "^A = 1\n" * MAX_REPEATED_POINTERS
    n = min(MAX_STATEMENTS - MAX_REPEATED_POINTERS - 10, MAX_SEPARATORS)
    body = "".join(f"Q{i} = (1 <m>, 1 <m>)\n" for i in range(n))
    return _label(pointers + body)


def densest_accepted() -> str:
    """A label of the most text ``check_structure`` accepts, in the longest values, each a
    run of implicitly concatenated strings (``"A" "A" ...``: one parser token per 4 bytes,
    no commas)."""
    value = '"A" ' * ((MAX_VALUE_CHARS - 8) // 4)
    n = (MAX_TEXT_CHARS - len(HEAD) - 100) // (len(value) + 12)
    return _label("".join(f"V{i:04d} = {value}\n" for i in range(n)))
