"""The command line's shape: one module per command (``register`` + ``run``), main.py holding
the top-level parser only, every output given as ``--out`` (earlier spellings still accepted)."""

from __future__ import annotations

import argparse
import ast
import importlib
from pathlib import Path
from typing import cast

import pytest

from mars_pairs.cli.main import build_parser, main

CLI = Path(__file__).resolve().parents[2] / "mars_pairs" / "cli"
COMMANDS = {
    "locate": "locate",
    "viewshed": "viewshed",
    "build": "build",
    "inspect": "inspect",
    "verify": "verify",
    "query": "query",
    "show": "show",
    "overview": "overview",
    "report": "report",
    "export-qgis": "export_qgis",
    "fetch": "fetch",
    "synth": "synth",
    "catalog": "catalog",
    "terrain-map": "terrain_map",
}


def _subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    action = next(a for a in parser._actions if a.dest == "command")
    return cast("dict[str, argparse.ArgumentParser]", action.choices)


def test_every_command_has_its_module_with_register_and_run() -> None:
    assert set(_subcommands()) == set(COMMANDS)
    for name, module in COMMANDS.items():
        mod = importlib.import_module(f"mars_pairs.cli.{module}")
        assert callable(mod.register), name
        if name != "fetch":  # fetch's subcommands run mars_pairs.fetch.cli's functions
            assert callable(mod.run), name
            assert _subcommands()[name].get_default("func") is mod.run


def test_main_only_registers() -> None:
    """main.py adds no subparser or option of a command itself: one ``register`` per command."""
    tree = ast.parse((CLI / "main.py").read_text())
    calls = [
        n.func.attr
        for n in ast.walk(tree)
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute)
    ]
    assert calls.count("register") == len(COMMANDS)
    assert calls.count("add_parser") == 0
    assert calls.count("add_argument") == 1  # --version


@pytest.mark.parametrize("command", ["viewshed", "build", "query", "show", "overview", "report"])
def test_every_output_is_out(command: str) -> None:
    options = {o for a in _subcommands()[command]._actions for o in a.option_strings}
    assert "--out" in options


def test_export_qgis_takes_out_and_the_positional(tmp_path: Path) -> None:
    parser = build_parser()
    new = parser.parse_args(["export-qgis", "ds", "--out", "a.gpkg"])
    old = parser.parse_args(["export-qgis", "ds", "a.gpkg"])
    from mars_pairs.cli.arguments import out_path

    assert out_path(new) == out_path(old) == "a.gpkg"


@pytest.mark.parametrize(
    "argv",
    [
        ["export-qgis", "{tmp}", "{tmp}/a.gpkg", "--out", "{tmp}/b.gpkg"],
        ["synth"],
    ],
)
def test_out_missing_or_twice_exits_2_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str]
) -> None:
    args = [a.format(tmp=tmp_path) for a in argv]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"mars-pairs {args[0]}: ") and "--out" in err


def test_synth_out_option(tmp_path: Path) -> None:
    parser = build_parser()
    from mars_pairs.cli.arguments import out_path

    assert out_path(parser.parse_args(["synth", "--out", "m"])) == "m"
    assert out_path(parser.parse_args(["synth", "m"])) == "m"


@pytest.mark.parametrize("spelling", ["--color-by", "--colour-by"])
def test_color_by_has_one_dest_and_the_british_alias(spelling: str) -> None:
    args = build_parser().parse_args(["overview", "ds", spelling, "split"])
    assert args.color_by == "split"
