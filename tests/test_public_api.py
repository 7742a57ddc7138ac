"""The curated public API: every name of ``mars_pairs.__all__`` resolves, the whole error family
is there, ``import mars_pairs`` imports neither torch nor numba, type checkers see every name,
and the package ships ``py.typed``."""

from __future__ import annotations

import ast
import inspect
import subprocess
import sys
from pathlib import Path

import mars_pairs
from mars_pairs import errors

PACKAGE = Path(mars_pairs.__file__).resolve().parent


def test_every_public_name_resolves() -> None:
    missing = [n for n in mars_pairs.__all__ if getattr(mars_pairs, n, None) is None]
    assert missing == []
    assert sorted(mars_pairs.__all__) == mars_pairs.__all__
    assert len(set(mars_pairs.__all__)) == len(mars_pairs.__all__)


def test_the_whole_error_family_is_public() -> None:
    family = {
        name
        for name, obj in vars(errors).items()
        if inspect.isclass(obj)
        and issubclass(obj, BaseException)
        and obj.__module__ == errors.__name__
    }
    assert len(family) >= 21 and {"DatasetError", "ArgumentError", "MarsPairsError"} <= family
    assert family <= set(mars_pairs.__all__)
    for name in family:
        assert getattr(mars_pairs, name) is getattr(errors, name)
        assert issubclass(getattr(errors, name), errors.MarsPairsError)


def test_the_verbs_are_the_defining_modules_objects() -> None:
    from mars_pairs.kernels.viewshed import compute_viewshed
    from mars_pairs.pds import read_observation
    from mars_pairs.pipeline.builder.run import run_build
    from mars_pairs.pipeline.config import load_config
    from mars_pairs.synth import generate_mission
    from mars_pairs.torch import MarsPairsDataset, MarsPairsIterableDataset, MarsPairsLoader

    assert mars_pairs.read_observation is read_observation
    assert mars_pairs.load_config is load_config
    assert mars_pairs.run_build is run_build
    assert mars_pairs.generate_mission is generate_mission
    assert mars_pairs.compute_viewshed is compute_viewshed
    assert mars_pairs.MarsPairsLoader is MarsPairsLoader
    assert mars_pairs.MarsPairsDataset is MarsPairsDataset
    assert mars_pairs.MarsPairsIterableDataset is MarsPairsIterableDataset


def test_an_unknown_name_is_an_attribute_error() -> None:
    try:
        mars_pairs.no_such_name  # noqa: B018
    except AttributeError as exc:
        assert "no_such_name" in str(exc)
    else:
        raise AssertionError("no AttributeError")


HEAVY = ("torch", "numba", "matplotlib", "rasterio", "pyarrow", "shapely", "pydantic", "dask",
         "lxml", "yaml", "pyproj")  # fmt: skip


def _loaded_heavy(module: str) -> list[str]:
    """The modules of ``HEAVY`` a new process has loaded after importing ``module``."""
    code = f"import sys, {module}; print(' '.join(m for m in {HEAVY!r} if m in sys.modules))"
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=False, timeout=300
    )
    assert done.returncode == 0, done.stderr
    return done.stdout.split()


def test_import_mars_pairs_stays_light() -> None:
    """Label, build and CLI code imports the package root: it loads none of the heavy
    libraries (every public name but the errors imports on first use)."""
    assert _loaded_heavy("mars_pairs") == []


def test_the_command_line_parser_stays_light() -> None:
    """Every ``mars-pairs`` command imports the parser of all: it loads none of the heavy
    libraries (each command imports what it needs when it runs)."""
    assert _loaded_heavy("mars_pairs.cli.main") == []


def test_type_checkers_see_every_public_name() -> None:
    """Each ``__all__`` name is bound by an import in ``__init__.py`` (at module level or under
    ``TYPE_CHECKING``), never only by ``__getattr__`` (which mypy and IDEs type as object)."""
    tree = ast.parse((PACKAGE / "__init__.py").read_text())
    bound = {
        a.asname or a.name
        for node in ast.walk(tree)
        if isinstance(node, ast.ImportFrom)
        for a in node.names
    }
    assert set(mars_pairs.__all__) - bound == set()


def test_py_typed_is_shipped() -> None:
    assert (PACKAGE / "py.typed").is_file()
    pyproject = (PACKAGE.parent / "pyproject.toml").read_text()
    assert '"mars_pairs" = ["py.typed"]' in pyproject  # [tool.setuptools.package-data]
