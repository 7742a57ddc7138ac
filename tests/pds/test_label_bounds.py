"""Label parsing is bounded in work and memory on any thread: pathological labels are a
LabelError within 5 s of CPU time on a worker thread (counted on the thread, whatever the
machine's load) (where no SIGALRM timer runs), the structural bounds
sit far above the real labels, and a label at every bound still parses quickly."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import pytest

from mars_pairs.cli.main import main
from mars_pairs.errors import LabelError
from mars_pairs.pds import pds3 as pds3_module
from mars_pairs.pds import read_observation, read_pds3, read_pds4
from mars_pairs.pds.pds3 import check_structure, load_label
from mars_pairs.pds.xml import MAX_XML_MARKUP
from support.label_shapes import SHAPES, densest_accepted, slowest_accepted
from support.threads import on_a_thread as run_on_a_thread

BUDGET_S = 5.0


def on_a_thread(fn, *args) -> tuple[float, object]:
    """``support.threads.on_a_thread``: under BUDGET_S of the thread's CPU time (not wall
    time: a loaded machine does not fail it)."""
    elapsed, result = run_on_a_thread(fn, *args, budget_s=BUDGET_S)
    assert elapsed < BUDGET_S, f"took {elapsed:.1f} s of CPU time on a worker thread"
    return elapsed, result


@pytest.mark.parametrize("shape", list(SHAPES))
def test_a_pathological_pds3_label_is_a_label_error_on_a_worker_thread(
    tmp_path: Path, shape: str
) -> None:
    path = tmp_path / "shape.LBL"
    path.write_text(SHAPES[shape]())
    elapsed, result = on_a_thread(read_observation, path)
    assert isinstance(result, LabelError), f"{shape}: {result!r} after {elapsed:.1f} s"
    assert str(path) in str(result)


@pytest.mark.parametrize(
    ("shape", "reason"),
    [
        ("^A = 1\n" * 65, "^A: repeated more than 64 times"),
        ("A = 1\n" * 65, "A: repeated more than 64 times"),
        ("GROUP = G\n^A = 1\nEND_GROUP = G\n" * 9, "9 pointer statements share a name"),
        ("GROUP = G\n" * 17 + "END_GROUP = G\n" * 17, "nested deeper than 16"),
        ('A = "' + "X" * 65_535 + '"\n', "A: a value of 65,537 characters"),
        ("A = (" + "1," * 10_001 + "1)\n", "10,001 commas"),
        ("".join(f"K{i} = 1\n" for i in range(10_001)), "10,003 statements"),
        ("\n" * 50_001, "lines and comments (at most 50,000)"),
        ("A = 1\n" * 200_000, "label text of 1,200,026 characters (at most 1,048,576)"),
    ],
)
def test_each_bound_is_a_label_error_naming_it(shape: str, reason: str) -> None:
    with pytest.raises(LabelError, match=r"x\.LBL: .*" + re.escape(reason)):
        check_structure("PDS_VERSION_ID = PDS3\n" + shape + "END\n", Path("x.LBL"))


def test_labels_at_the_bounds_pass_the_pre_scan() -> None:
    at = [
        "A = 1\n" * 64,
        "GROUP = G\n^A = 1\nEND_GROUP = G\n" * 8,
        "GROUP = G\n" * 16 + "END_GROUP = G\n" * 16,
        'A = "' + "X" * 65_534 + '"\n',
        "A = (" + "1," * 10_000 + "1)\n",
    ]
    for body in at:
        check_structure("PDS_VERSION_ID = PDS3\n" + body + "END\n", Path("x.LBL"))


@pytest.mark.parametrize("make", [slowest_accepted, densest_accepted])
def test_labels_at_the_bounds_parse_within_half_the_budget_on_a_worker_thread(
    tmp_path: Path, make
) -> None:
    path = tmp_path / "slow.LBL"
    elapsed, result = on_a_thread(load_label, make().encode(), path)
    assert not isinstance(result, BaseException), result
    assert len(result) > 10
    assert elapsed < BUDGET_S / 2


def test_real_labels_are_far_inside_the_bounds(samples_dir: Path) -> None:
    """Every real PDS3 label still passes at a tenth of each bound, and reads."""
    labels = sorted((samples_dir / "msl").glob("*.LBL"))
    assert labels
    tenth = {
        name: getattr(pds3_module, name) // 10
        for name in ("MAX_LINES", "MAX_STATEMENTS", "MAX_VALUE_CHARS", "MAX_SEPARATORS")
    }
    with pytest.MonkeyPatch.context() as mp:
        for name, value in tenth.items():
            mp.setattr(pds3_module, name, value)
        for label in labels:
            check_structure(label.read_text(), label)
    for label in labels:
        assert read_pds3(label).product_id
    for label in sorted((samples_dir / "m2020").glob("*.xml")):
        assert label.read_bytes().count(b"<") < MAX_XML_MARKUP // 20
        assert read_pds4(label).product_id


@pytest.mark.parametrize(
    "body",
    [
        "<a/>" * 1_000_000,  # 4 MB, ~126 MB of tree
        "<a>" * 10_000 + "</a>" * 10_000,  # past libxml2's depth limit
    ],
)
def test_a_pathological_pds4_label_is_a_label_error_on_a_worker_thread(
    tmp_path: Path, body: str
) -> None:
    path = tmp_path / "shape.xml"
    root = '<Product_Observational xmlns="http://pds.nasa.gov/pds4/pds/v1">'
    path.write_text(root + body + "</Product_Observational>")
    elapsed, result = on_a_thread(read_observation, path)
    assert isinstance(result, LabelError), f"{result!r} after {elapsed:.1f} s"
    assert str(path) in str(result)


def test_a_many_tag_pds4_label_is_refused_before_parsing(tmp_path: Path) -> None:
    path = tmp_path / "tags.xml"
    root = '<Product_Observational xmlns="http://pds.nasa.gov/pds4/pds/v1">'
    path.write_text(root + "<a/>" * MAX_XML_MARKUP + "</Product_Observational>")
    with pytest.raises(LabelError, match=r"tags\.xml: 100,002 tags \(at most 100,000\)"):
        read_observation(path)


def test_a_comment_runs_to_the_end_of_its_line_as_pdr_reads_it() -> None:
    """Python-only numbers are looked for in what pdr parses: after a comment closed on its
    line nothing is parsed; on the next line it is, whether or not the comment was closed."""
    head = "PDS_VERSION_ID = PDS3\n"
    load_label((head + "A = 1 /* 0x10 */ 0x11\nEND\n").encode(), Path("x.LBL"))
    for tail in ("/* open\nB = 0x12\n", "/* one */\nB = 0x12\n"):
        with pytest.raises(LabelError, match=r"x\.LBL: B: line 3: not a PDS3 value"):
            load_label((head + "A = 1 " + tail + "END\n").encode(), Path("x.LBL"))


@pytest.mark.parametrize("reader", [read_observation, read_pds3, read_pds4])
def test_a_nul_in_the_path_is_a_label_error_naming_it(reader) -> None:
    with pytest.raises(LabelError, match=r"bad\x00name\.LBL: not a file path: .*NUL byte"):
        reader("bad\x00name.LBL")


# -- locate: extreme numbers are one clear error, without numpy warnings ----------------------
M2020 = "m2020/ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01.xml"
MSL = "msl/2663ML0139550021002124C00_DRCX.LBL"


def _variant(samples_dir: Path, tmp_path: Path, name: str, old: str, new: str) -> Path:
    source = samples_dir / name
    text, n = re.subn(old, new, source.read_text(), count=1)
    assert n == 1
    out = tmp_path / source.name
    out.write_text(text)
    return out


@pytest.mark.parametrize(
    ("name", "old", "new", "field"),
    [
        (MSL, r"ORIGIN_OFFSET_VECTOR\s*=\s*\([^)]*\)", "ORIGIN_OFFSET_VECTOR = (1e155, 0, 0)",
         "ORIGIN_OFFSET_VECTOR: offset beyond 1e+07 m"),
        (MSL, r"ORIGIN_ROTATION_QUATERNION\s*=\s*\([^)]*\)",
         "ORIGIN_ROTATION_QUATERNION = (1e300, 1e300, 0, 0)",
         "ORIGIN_ROTATION_QUATERNION: expected a unit quaternion, norm is inf"),
        (M2020, r"(<geom:Vector_Origin_Offset>\s*<geom:x_position[^>]*>)[^<]+", r"\g<1>-1e200",
         "geom:Vector_Origin_Offset: offset beyond 1e+07 m"),
    ],
)  # fmt: skip
def test_an_extreme_rover_pose_is_a_label_error_without_numpy_warnings(
    samples_dir: Path, tmp_path: Path, name: str, old: str, new: str, field: str
) -> None:
    label = _variant(samples_dir, tmp_path, name, old, new)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a numpy RuntimeWarning fails the test
        with pytest.raises(LabelError, match=re.escape(f"{label}: {field}")):
            read_observation(label)


def test_locate_takes_an_underflowing_distortion_term(
    samples_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A term that flushes to zero changes nothing: the label is located, quietly."""
    label = _variant(samples_dir, tmp_path, M2020, r"(<geom:c2>)[^<]+", r"\g<1>1e-300")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main(["locate", str(label), "--json"]) == 0
    out = capsys.readouterr()
    assert out.err == "" and '"product_id"' in out.out
