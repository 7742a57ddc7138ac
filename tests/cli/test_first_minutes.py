"""What a newcomer meets first: query by split alone, samples named by product id,
``--version``, the synthetic example's output path, empty and unknown splits, dry runs."""

from __future__ import annotations

import io
import json
import warnings
from pathlib import Path

import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import pytest
import yaml

from mars_pairs.cli.main import build_parser, main
from mars_pairs.errors import ArgumentError, SampleKeyError
from support.builds import cli_built_dataset

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory, small_mission: Path) -> Path:
    return cli_built_dataset(tmp_path_factory.getbasetemp(), small_mission)


def rows(root: Path) -> list[dict]:
    return pq.read_table(root / "manifest.parquet").to_pylist()


def query_csv(capsys: pytest.CaptureFixture, *argv: str) -> list[dict]:
    assert main(["query", *argv, "--format", "csv"]) == 0
    return pacsv.read_csv(io.BytesIO(capsys.readouterr().out.encode())).to_pylist()


# -- query without a place ------------------------------------------------------------------


def test_query_by_split_mission_or_sol_alone(dataset: Path, capsys) -> None:
    splits = sorted(r["split"] for r in rows(dataset))
    assert splits == ["buffer", "buffer", "test", "test"]
    got = query_csv(capsys, str(dataset), "--split", "test")
    assert [r["split"] for r in got] == ["test", "test"]
    assert len(query_csv(capsys, str(dataset), "--split", "test", "--split", "buffer")) == 4
    assert len(query_csv(capsys, str(dataset), "--mission", "m2020")) == 4
    sol = rows(dataset)[0]["sol"]
    got = query_csv(capsys, str(dataset), "--sol", str(sol), str(sol))
    assert {r["sol"] for r in got} == {sol}
    assert len(got) == sum(r["sol"] == sol for r in rows(dataset))
    later = [r for r in rows(dataset) if r["sol"] > sol]
    assert len(query_csv(capsys, str(dataset), "--sol", str(sol + 1), str(sol + 9))) == len(later)
    assert len(query_csv(capsys, str(dataset))) == 4  # no filter: every row
    # a place filter still combines with them; two place filters are refused
    with pytest.raises(SystemExit):
        build_parser().parse_args(["query", "d", "--bbox", "0", "0", "1", "1", "--polygon", "x"])


def test_query_and_dataset_refuse_an_unknown_split_naming_the_known_ones(
    dataset: Path, capsys
) -> None:
    assert main(["query", str(dataset), "--split", "validation"]) == 2
    err = capsys.readouterr().err.strip()
    assert "'validation'" in err and "buffer, test, train" in err and "\n" not in err
    from mars_pairs.torch import MarsPairsDataset

    with pytest.raises(ArgumentError, match=r"'validation'.*buffer, test, train"):
        MarsPairsDataset(dataset, split="validation")
    with pytest.raises(ArgumentError, match="'valid'"):
        MarsPairsDataset(dataset, split=["test", "valid"])
    # a known split without samples is no error: it is empty
    with MarsPairsDataset(dataset, split="train") as ds:
        assert len(ds) == 0
    assert query_csv(capsys, str(dataset), "--split", "train") == []


# -- samples named by key or product id -----------------------------------------------------


def test_sample_index_by_key_or_product_id() -> None:
    from mars_pairs.store.filter_args import sample_index

    keys = pa.array(["m2020_zlf_0052_a", "msl_0123ml0005_drcl", "m2020_x_1"])
    ids = pa.array(["ZLF_0052_A", "0123ML0005.DRCL", "X_1"])
    for name, want in (
        ("m2020_zlf_0052_a", 0),
        ("ZLF_0052_A", 0),
        ("zlf_0052_a", 0),
        ("M2020_ZLF_0052_A", 0),
        ("0123ML0005.DRCL", 1),
        ("0123ml0005_drcl", 1),
        (" X_1 ", 2),
    ):
        assert sample_index(name, keys, ids, "ds") == want, name
    with pytest.raises(SampleKeyError, match=r"no sample with key 'ZLF_9' \(nor with that"):
        sample_index("ZLF_9", keys, ids, "ds")
    twice = pa.array(["m2020_a", "msl_a"])
    with pytest.raises(SampleKeyError, match="names 2 samples"):
        sample_index("A", twice, pa.array(["A", "A"]), "ds")
    with pytest.raises(ArgumentError):
        sample_index(3, keys, ids, "ds")


def test_show_and_the_dataset_take_a_product_id(
    dataset: Path, tmp_path: Path, monkeypatch, capsys
) -> None:
    pytest.importorskip("matplotlib")
    from mars_pairs.torch import MarsPairsDataset

    row = sorted(rows(dataset), key=lambda r: r["key"])[0]
    with MarsPairsDataset(dataset) as ds:
        i = ds.index_of(row["key"])
        assert ds.index_of(row["product_id"]) == i
        assert ds.index_of(row["product_id"].lower()) == i
        with pytest.raises(SampleKeyError):
            ds.index_of("NOT_A_PRODUCT")
    monkeypatch.chdir(tmp_path)
    assert main(["show", str(dataset), row["product_id"]]) == 0
    out = capsys.readouterr().out.strip()
    assert out == f"{row['key']}.png" and (tmp_path / out).stat().st_size > 10_000
    assert main(["show", str(dataset), "ZZZ_NOPE"]) == 2
    assert "no sample with key 'ZZZ_NOPE' (nor with that product id)" in capsys.readouterr().err


# -- --version --------------------------------------------------------------------------------


def test_version_names_the_package_and_key_libraries(capsys) -> None:
    import mars_pairs

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].startswith(f"mars-pairs {mars_pairs.__version__} (Python ")
    assert len(lines) == 2
    for name in ("numpy", "pyarrow", "rasterio", "GDAL", "torch"):
        assert f"{name} " in lines[1], name


# -- the synthetic example's output -----------------------------------------------------------


def test_synth_example_writes_where_told_and_prints_help(tmp_path, monkeypatch, capsys) -> None:
    from mars_pairs.synth import example

    written: list[Path] = []

    def fake(out, *, seed):  # the figure itself is drawn by make_example_figure
        written.append(Path(out))
        Path(out).write_bytes(b"png")
        return f"PRODUCT_{seed}"

    monkeypatch.setattr(example, "make_example_figure", fake)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        example.main(["--help"])
    assert exc.value.code == 0
    assert "usage: python -m mars_pairs.synth.example" in capsys.readouterr().out
    assert written == [] and list(tmp_path.iterdir()) == []  # no --help.png
    assert example.main([]) == 0  # default: the current directory, not docs/
    assert written == [Path("synth_example.png")]
    assert example.main([str(tmp_path / "figs" / "x.png"), "--seed", "7"]) == 0
    assert written[-1] == tmp_path / "figs" / "x.png"
    assert capsys.readouterr().out.splitlines()[-1].endswith("x.png: PRODUCT_7")
    for bad in (["x.txt"], [str(tmp_path)]):
        with pytest.raises(SystemExit) as exc:
            example.main(bad)
        assert exc.value.code == 2


# -- empty splits -----------------------------------------------------------------------------


def test_empty_split_warnings_say_where_the_samples_went() -> None:
    from mars_pairs.store.splits import empty_split_warnings

    ratios = {"train": 0.8, "val": 0.1, "test": 0.1}
    got = empty_split_warnings("same-area", ratios, {}, 10000.0, {"val": 12})
    assert got[0].startswith("split 'train' is empty (12 samples: val 12)")
    assert "splits.block_m = 10000" in got[0] and len(got) == 2  # train, then test
    assert "'test'" in got[1]
    full = {"train": 8, "val": 2, "test": 2}
    assert empty_split_warnings("same-area", ratios, {}, 100.0, full) == []
    assert empty_split_warnings("same-area", ratios, {}, 100.0, {}) == []  # no sample
    got = empty_split_warnings("same-area", ratios, {}, 15.0, {"buffer": 4})
    assert got == [
        "split 'train', 'test', 'val' are empty (4 samples: buffer 4); every sample is in the "
        "buffer zone around held-out regions: use regions several times wider than the zone "
        "(reach_m + buffer_m in dataset.json; splits.block_m = 15 map units)"
    ]
    areas = {"test": [[0, 0, 1, 1]]}
    got = empty_split_warnings("cross-area", {}, areas, 1.0, {"train": 3})
    assert got == ["split 'test' is empty (3 samples: train 3); no rover position lies "
                   "inside splits.areas.test"]  # fmt: skip


def test_a_build_without_train_warns_in_its_summary_dataset_json_and_inspect(
    dataset: Path, capsys
) -> None:
    out = (dataset.parent / "build.out").read_text()
    warning = [ln for ln in out.splitlines() if ln.startswith("warning: ")]
    assert len(warning) == 1 and "split 'train' is empty (4 samples: buffer 2, test 2)" in out
    doc = json.loads((dataset / "dataset.json").read_text())
    assert doc["splits"]["warnings"] == [warning[0].removeprefix("warning: ")]
    assert main(["inspect", str(dataset)]) == 0
    assert warning[0] in capsys.readouterr().out.splitlines()
    # the library (run_build) warns too, with a category a caller can filter
    from mars_pairs.pipeline.config import load_config
    from mars_pairs.pipeline.splitting import splits_report
    from mars_pairs.store.splits import EmptySplitWarning

    config = load_config(dataset.parent / "c.yaml")
    with pytest.warns(EmptySplitWarning, match="split 'train' is empty"):
        splits_report(config, pq.read_table(dataset / "manifest.parquet"), 0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a full dataset: no warning
        table = pq.read_table(dataset / "manifest.parquet")
        table = table.set_column(
            table.schema.get_field_index("split"), "split", pa.array(["train", "test"] * 2)
        )
        assert splits_report(config, table, 0)["warnings"] == []


# -- dry runs ---------------------------------------------------------------------------------


def test_every_fetch_command_has_a_dry_run_and_places_writes_nothing(tmp_path, capsys) -> None:
    for command in ("products", "places", "orbital", "all"):
        args = build_parser().parse_args(["fetch", command, "--config", "c.yaml", "--dry-run"])
        assert args.dry_run is True, command
    config = tmp_path / "c.yaml"
    places = "MSLPLC_1XXX/DATA/LOCALIZATIONS/localized_interp.csv"
    doc = {"fetch": {"cache": "cache", "places": {"archive": "http://127.0.0.1:9/msl",
                                                  "path": places}}}  # fmt: skip
    config.write_text(yaml.safe_dump(doc))
    assert main(["fetch", "places", "--config", str(config), "--dry-run"]) == 0
    out = capsys.readouterr().out.strip()
    assert out.startswith(f"dry run: http://127.0.0.1:9/msl/{places} -> ")
    assert out.endswith("(not yet in the cache)") and not (tmp_path / "cache").exists()
    # fetch all --dry-run with only the PLACES step: the same line, still nothing written
    assert main(["fetch", "all", "--config", str(config), "--dry-run"]) == 0
    assert capsys.readouterr().out.strip() == out and not (tmp_path / "cache").exists()
