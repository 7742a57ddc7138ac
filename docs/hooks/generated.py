"""mkdocs hook: pages whose tables are generated from the code at build time, so they cannot
go stale.

A page holds a marker comment; the hook replaces it with Markdown made from the package:

- ``<!-- generated: cli -->``: every command and subcommand of ``mars-pairs`` with its usage
  and options (``mars_pairs.cli.main.build_parser``, the parser the command line runs);
- ``<!-- generated: manifest-columns -->``: every manifest column with its Arrow type, units and
  frame (``store.manifest.manifest_schema`` with every optional member, ``store.card.COLUMN_DOCS``);
- ``<!-- generated: members -->``: every shard member (``store.card.MEMBER_DOCS``);
- ``<!-- generated: failure-columns -->``: the columns of ``failures.parquet``.
"""

from __future__ import annotations

import argparse
import re
from typing import Any

MARKER = re.compile(r"<!-- generated: ([a-z-]+) -->")


def _table(header: list[str], rows: list[list[str]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(cell.replace("|", "\\|") for cell in row) + " |" for row in rows]
    return "\n".join(out)


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:  # argparse keeps its subcommands here, as sphinx-argparse reads
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _command(name: str, parser: argparse.ArgumentParser, level: int) -> list[str]:
    parser.prog = name
    out = [f"{'#' * level} `{name}`", ""]
    helps = {
        a.dest: a.help
        for a in parser._actions
        if isinstance(a, argparse._SubParsersAction)
        for a in a._choices_actions
    }
    if parser.description:
        out += [parser.description, ""]
    out += ["```text", parser.format_usage().removeprefix("usage: ").strip(), "```", ""]
    rows = []
    for action in parser._actions:
        if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)):
            continue
        flags = ", ".join(f"`{s}`" for s in action.option_strings) or f"`{action.dest}`"
        default = action.default
        shown = "" if default in (None, False, argparse.SUPPRESS) else f"`{default}`"
        rows.append([flags, (action.help or "").replace("\n", " "), shown])
    if rows:
        out += [_table(["argument", "meaning", "default"], rows), ""]
    for sub_name, sub in _subparsers(parser).items():
        if helps.get(sub_name):
            sub.description = sub.description or helps[sub_name]
        out += _command(f"{name} {sub_name}", sub, min(level + 1, 4))
    return out


def cli_reference() -> str:
    from mars_pairs.cli.main import build_parser

    parser = build_parser()
    out: list[str] = []
    top = _subparsers(parser)
    helps = {
        a.dest: a.help
        for action in parser._actions
        if isinstance(action, argparse._SubParsersAction)
        for a in action._choices_actions
    }
    for name, sub in top.items():
        sub.description = sub.description or helps.get(name)
        out += _command(f"mars-pairs {name}", sub, 2)
    return "\n".join(out)


def manifest_columns() -> str:
    from mars_pairs.store.card import COLUMN_DOCS
    from mars_pairs.store.manifest import manifest_schema
    from mars_pairs.store.members import DENSE_MEMBERS

    schema = manifest_schema(tuple(DENSE_MEMBERS))
    rows = []
    for f in schema:
        units, frame = COLUMN_DOCS.get(f.name, ("-", "-"))
        rows.append([f"`{f.name}`", f"`{f.type}`", units, frame])
    return _table(["column", "Arrow type", "units", "frame"], rows)


def members() -> str:
    from mars_pairs.store.card import MEMBER_DOCS

    rows = [[f"`{n}`", f"`{file}`", fmt, units] for n, (file, fmt, units) in MEMBER_DOCS.items()]
    return _table(["member", "file in the shard", "format", "units"], rows)


def failure_columns() -> str:
    from mars_pairs.store.manifest import FAILURE_SCHEMA

    return _table(
        ["column", "Arrow type"], [[f"`{f.name}`", f"`{f.type}`"] for f in FAILURE_SCHEMA]
    )


GENERATORS = {
    "cli": cli_reference,
    "manifest-columns": manifest_columns,
    "members": members,
    "failure-columns": failure_columns,
}


def on_page_markdown(markdown: str, **kwargs: Any) -> str:
    return MARKER.sub(lambda m: GENERATORS[m[1]](), markdown)
