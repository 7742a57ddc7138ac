"""Pictures (show, overview) and the QGIS export of a small built dataset."""

from __future__ import annotations

import io
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from pyproj import CRS

from mars_pairs.cli.main import main
from mars_pairs.store.shards import MemberLocation, read_member
from support.builds import build
from support.members import manifest_rows as rows_of
from support.missions import MissionCache

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow

pytest.importorskip("matplotlib")


@pytest.fixture(scope="module")
def dataset(missions: MissionCache, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 4-sample dataset (2 stops x 2 images) with small chips and a coarse ray stride."""
    mission = missions(seed=5, stops=2, images_per_stop=2)
    out = tmp_path_factory.mktemp("viz") / "ds"
    return build(mission, out, fine=True, geometry={"radius": 400}, output={"shard_size": 2})


def dataset_crs(root: Path) -> CRS:
    return CRS.from_user_input(json.loads((root / "dataset.json").read_text())["crs"])


def png_size(path: Path) -> tuple[int, int]:
    assert path.is_file() and path.stat().st_size > 10_000, path
    with Image.open(path) as im:
        assert im.format == "PNG"
        return im.size


def test_show_writes_a_png_of_the_expected_size(dataset: Path, tmp_path: Path) -> None:
    from mars_pairs.viz.common import DPI, SHOW_SIZE

    key = rows_of(dataset)[0]["key"]
    out = tmp_path / "fig" / "sample.png"
    assert main(["show", str(dataset), key, "--out", str(out)]) == 0
    assert png_size(out) == (round(SHOW_SIZE[0] * DPI), round(SHOW_SIZE[1] * DPI))


@pytest.mark.parametrize("colour_by", ["sol", "split"])
def test_overview_writes_a_png_of_the_expected_size(
    dataset: Path, tmp_path: Path, colour_by: str
) -> None:
    from mars_pairs.viz.common import DPI, OVERVIEW_SIZE

    out = tmp_path / "overview.png"
    assert main(["overview", str(dataset), "--out", str(out), "--colour-by", colour_by]) == 0
    assert png_size(out) == (round(OVERVIEW_SIZE[0] * DPI), round(OVERVIEW_SIZE[1] * DPI))


def test_hillshade_lights_slopes_facing_the_sun() -> None:
    import numpy as np

    from mars_pairs.viz.common import hillshade

    cols = np.tile(np.arange(20.0), (20, 1))
    facing_west = hillshade(cols, 1.0)  # rises to the east: faces west, towards a NW sun
    facing_east = hillshade(-cols, 1.0)
    flat = hillshade(np.zeros((20, 20)), 1.0)
    assert facing_west.mean() > flat.mean() > facing_east.mean()


def test_export_qgis_reads_back_with_the_dataset_crs(dataset: Path, tmp_path: Path) -> None:
    import pyogrio
    from pyogrio.raw import read_arrow

    out = tmp_path / "demo.gpkg"
    assert main(["export-qgis", str(dataset), str(out)]) == 0
    rows = rows_of(dataset)
    layers = {name: kind for name, kind in pyogrio.list_layers(out)}
    assert layers == {
        "rover_positions": "Point",
        "footprints": "Polygon",
        "camera_wedges": "Polygon",
    }
    crs = dataset_crs(dataset)
    for name in layers:
        info = pyogrio.read_info(out, layer=name)
        assert info["features"] == len(rows), name
        assert CRS.from_user_input(info["crs"]).equals(crs), name
        meta, table = read_arrow(out, layer=name)
        assert sorted(table.column("key").to_pylist()) == [r["key"] for r in rows]
        assert CRS.from_user_input(meta["crs"]).equals(crs)
    assert not (tmp_path / "demo_viewsheds").exists()


def test_export_qgis_viewsheds_are_geotiffs_in_the_dataset_crs(
    dataset: Path, tmp_path: Path
) -> None:
    import rasterio

    from mars_pairs.export.qgis import viewsheds_folder

    out = tmp_path / "q.gpkg"
    assert main(["export-qgis", str(dataset), str(out), "--viewsheds"]) == 0
    rows = rows_of(dataset)
    tifs = sorted(viewsheds_folder(out).glob("*.tif"))
    assert [t.name for t in tifs] == [f"{r['key']}_viewshed.tif" for r in rows]
    crs = dataset_crs(dataset)
    visible = 0
    for tif, row in zip(tifs, rows, strict=True):
        with rasterio.open(tif) as src:
            assert CRS.from_user_input(src.crs.to_wkt()).equals(crs)
            band = src.read(1)
            # the same cells as the sample's viewshed member
            png = read_member(
                dataset,
                MemberLocation(row["viewshed_shard"], row["viewshed_offset"], row["viewshed_size"]),
            )
            expected = np.asarray(Image.open(io.BytesIO(png))) > 0
            assert np.array_equal(band == 1, expected)
            # hidden cells are 0, not nodata: the codes of `mars-pairs viewshed` (255 nodata)
            assert src.nodata == 255 and set(np.unique(band)) <= {0, 1}
            visible += int(expected.sum())
            left, bottom, right, top = src.bounds
            assert left <= row["easting"] <= right and bottom <= row["northing"] <= top
    assert visible > 0


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["show", "{ds}", "no_such_key", "--out", "{tmp}/x.png"], "no sample with key"),
        (["show", "{tmp}/missing", "k", "--out", "{tmp}/x.png"], "missing"),
        (["overview", "{tmp}/missing", "--out", "{tmp}/x.png"], "missing"),
        (["export-qgis", "{tmp}/missing", "{tmp}/x.gpkg"], "missing"),
    ],
)
def test_bad_input_exits_2_with_one_line(
    dataset: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    argv: list[str],
    expected: str,
) -> None:
    args = [a.format(ds=dataset, tmp=tmp_path) for a in argv]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and expected in err and "Traceback" not in err, err
    assert err.startswith(f"mars-pairs {args[0]}: ")
    assert not (tmp_path / "x.png").exists()


def test_bad_input_through_the_console_script(dataset: Path, tmp_path: Path) -> None:
    for args in (
        ["show", str(dataset), "no_such_key", "--out", str(tmp_path / "x.png")],
        ["overview", str(tmp_path / "missing"), "--out", str(tmp_path / "x.png")],
    ):
        done = subprocess.run(
            [sys.executable, "-m", "mars_pairs.cli", *args],
            capture_output=True,
            text=True,
            check=False,
            timeout=120,
        )
        assert done.returncode == 2, done.stderr
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"mars-pairs {args[0]}: "), done.stderr


def test_matplotlib_is_imported_only_by_the_picture_commands() -> None:
    code = (
        "import mars_pairs.pipeline.builder.run, mars_pairs.torch.datasets, mars_pairs.cli.main, "
        "mars_pairs.export.qgis; "
        "import sys; assert 'matplotlib' not in sys.modules, 'matplotlib imported'"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=False, timeout=120
    )
    assert done.returncode == 0, done.stderr


def test_viz_imports_no_torch_and_no_private_name_of_another_module() -> None:
    """The layers go one way (report -> torch -> viz): no viz module imports torch or report,
    and no viz or report module imports another module's private (``_``) name."""
    import ast

    package = Path(__file__).resolve().parents[2] / "mars_pairs"
    above = ("mars_pairs.torch", "mars_pairs.report")
    upward, private = [], []
    for layer in ("viz", "report"):
        for path in sorted((package / layer).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Import):
                    modules, names = [a.name for a in node.names], []
                elif isinstance(node, ast.ImportFrom) and node.module:
                    modules, names = [node.module], [a.name for a in node.names]
                else:
                    continue
                if layer == "viz":
                    upward += [(path.name, m) for m in modules if m.startswith(above)]
                if modules[0].startswith("mars_pairs"):
                    private += [
                        (path.name, f"{modules[0]}.{n}")
                        for n in names
                        if n.startswith("_") and not n.startswith("__")
                    ]
    assert upward == [], upward
    assert private == [], private
