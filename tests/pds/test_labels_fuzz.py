"""Property tests: malformed labels of every kind give LabelError naming the file, never else.

Seeds are small synthetic labels written inline with the real keywords / element names and
namespaces (PDS3 Curiosity Mastcam, PDS4 Mastcam-Z), so these tests need no ../shared data.
"""

from __future__ import annotations

import copy
import re
from pathlib import Path

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from lxml import etree

from mars_pairs.errors import LabelError
from mars_pairs.observation import Observation
from mars_pairs.pds import read_observation, read_pds3, read_pds4
from mars_pairs.pds.xml import NS
from support.label_seeds import PDS3_SEED, PDS4_SEED

FAST = settings(
    max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


FLOAT_TEXT = re.compile(r"\s*[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\s*", re.ASCII)
CAMERA = "GEOMETRIC_CAMERA_MODEL_PARMS"
PDS3_REQUIRED = {
    (None, "PRODUCT_ID"),
    (None, "INSTRUMENT_ID"),
    (None, "PLANET_DAY_NUMBER"),
    (None, "ROVER_MOTION_COUNTER_NAME"),
    (None, "ROVER_MOTION_COUNTER"),
    (CAMERA, "MODEL_TYPE"),
    (CAMERA, "REFERENCE_COORD_SYSTEM_NAME"),
    *((CAMERA, f"MODEL_COMPONENT_{i}") for i in range(1, 7)),
    ("IMAGE", "LINES"),
    ("IMAGE", "LINE_SAMPLES"),
}


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


def outcome(path: Path, reader=read_observation) -> Observation | LabelError:
    """The reader's result or its LabelError (checked to name the file); anything else fails."""
    try:
        return reader(path)
    except LabelError as err:
        assert path.name in str(err)
        assert err.path == str(path)
        assert not err.reason.startswith("unexpected"), f"reader bug behind the safety net: {err}"
        return err


def expect_error(path: Path, reader=read_observation, field: str | None = None) -> LabelError:
    result = outcome(path, reader)
    assert isinstance(result, LabelError), f"expected LabelError, got {result}"
    if field is not None:
        assert result.field is not None and field in result.field, str(result)
    return result


def write(workdir: Path, name: str, data: bytes | str) -> Path:
    path = workdir / name
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    return path


# -- the seeds themselves ------------------------------------------------------------------
def test_seeds_are_valid(workdir: Path) -> None:
    obs3 = read_observation(write(workdir, "seed.LBL", PDS3_SEED))
    assert (obs3.width, obs3.height, obs3.site, obs3.drive) == (1152, 432, 78, 2858)
    assert obs3.camera.model_type == "CAHVOR" and obs3.hfov_deg == 14.1467
    obs4 = read_observation(write(workdir, "seed.xml", PDS4_SEED))
    assert (obs4.width, obs4.height, obs4.site, obs4.drive) == (1648, 1200, 3, 1950)
    assert obs4.azimuth_deg == 274.338 and obs4.rmc.pose == 4


# -- not labels at all ---------------------------------------------------------------------
@pytest.mark.parametrize(
    "data",
    [
        b"",
        b"   \n\t",
        b"\x00" * 64,
        b"\xff\xd8\xff\xe0JFIF",
        "PDS_VERSION_ID = PDS3\n".encode("utf-16"),
    ],
)
def test_non_labels(workdir: Path, data: bytes) -> None:
    expect_error(write(workdir, "junk.LBL", data))


def test_missing_file_and_directory(workdir: Path) -> None:
    expect_error(workdir / "does_not_exist.xml")
    (workdir / "adir.LBL").mkdir(exist_ok=True)
    expect_error(workdir / "adir.LBL")
    expect_error(workdir / "does_not_exist.xml", read_pds3)
    expect_error(workdir / "does_not_exist.xml", read_pds4)


def test_wrong_encoding(workdir: Path) -> None:
    latin = PDS3_SEED.replace('"B"', '"\u00e9"').encode("latin-1")
    expect_error(write(workdir, "latin.LBL", latin))
    nul = PDS3_SEED.replace("PLANET_DAY_NUMBER", "PLANET_DAY\x00NUMBER").encode()
    expect_error(write(workdir, "nul.LBL", nul))


@FAST
@given(data=st.binary(max_size=3000))
def test_random_bytes(workdir: Path, data: bytes) -> None:
    expect_error(write(workdir, "random.bin", data))


@FAST
@given(
    prefix=st.sampled_from([b"PDS_VERSION_ID = PDS3\n", b"<?xml version='1.0'?>\n"]),
    data=st.binary(max_size=2000),
)
def test_random_bytes_after_a_label_header(workdir: Path, prefix: bytes, data: bytes) -> None:
    expect_error(write(workdir, "headed.LBL", prefix + data))


@FAST
@given(text=st.text(max_size=2000))
def test_random_text(workdir: Path, text: str) -> None:
    expect_error(write(workdir, "random.txt", text))


# -- truncation and byte mutation ----------------------------------------------------------
@FAST
@given(st.data())
def test_truncated_pds3(workdir: Path, data: st.DataObject) -> None:
    seed = PDS3_SEED.encode()
    last_required = seed.rindex(b" LINE_SAMPLES = 1152") + len(b" LINE_SAMPLES")
    cut = data.draw(st.integers(0, len(seed) - 1))
    path = write(workdir, "cut.LBL", seed[:cut])
    if cut <= last_required:
        expect_error(path)
    else:
        outcome(path)


@FAST
@given(st.data())
def test_truncated_pds4(workdir: Path, data: st.DataObject) -> None:
    seed = PDS4_SEED.encode()
    cut = data.draw(st.integers(0, seed.rindex(b">")))
    expect_error(write(workdir, "cut.xml", seed[:cut]))


@FAST
@given(
    which=st.sampled_from(["LBL", "xml"]),
    edits=st.lists(st.tuples(st.floats(0, 1, exclude_max=True), st.integers(0, 255)), max_size=6),
)
def test_byte_mutations(workdir: Path, which: str, edits: list[tuple[float, int]]) -> None:
    seed = bytearray((PDS3_SEED if which == "LBL" else PDS4_SEED).encode())
    for where, byte in edits:
        seed[int(where * len(seed))] = byte
    result = outcome(write(workdir, f"mutated.{which}", bytes(seed)))
    assert isinstance(result, Observation | LabelError)


# -- PDS3: deleted statements and groups, wrong types --------------------------------------
def _pds3_statements() -> list[tuple[int, str | None, str]]:
    """(line index, enclosing GROUP/OBJECT, keyword) of every statement line of the seed."""
    out, group = [], None
    for i, line in enumerate(PDS3_SEED.splitlines()):
        match = re.match(r"\s*([A-Z_:^0-9]+)\s*=\s*(\S+)?", line)
        if not match:
            continue
        key = match[1]
        if key in ("GROUP", "OBJECT"):
            group = match[2]
        elif key in ("END_GROUP", "END_OBJECT"):
            group = None
        out.append((i, group, key))
    return out


def test_pds3_every_deleted_statement(workdir: Path) -> None:
    lines = PDS3_SEED.splitlines()
    for i, group, key in _pds3_statements():
        path = write(workdir, "deleted.LBL", "\n".join(lines[:i] + lines[i + 1 :]))
        if (group, key) in PDS3_REQUIRED:
            expect_error(path, read_pds3, field=key)
        else:
            outcome(path, read_pds3)


@pytest.mark.parametrize(
    "group, required",
    [
        (CAMERA, True),
        ("IMAGE", True),
        ("ROVER_COORDINATE_SYSTEM_PARMS", False),
        ("INSTRUMENT_STATE_PARMS", False),
        ("DERIVED_IMAGE_PARMS", False),
        ("IMAGE_REQUEST_PARMS", False),
    ],
)
def test_pds3_deleted_group(workdir: Path, group: str, required: bool) -> None:
    block = re.compile(rf"(GROUP|OBJECT) = {group}\n.*?END_\1 = {group}\n", re.S)
    path = write(workdir, "nogroup.LBL", block.sub("", PDS3_SEED))
    if required:
        expect_error(path, field=group)
        return
    obs = read_observation(path)
    assert (obs.width, obs.height) == (1152, 432)
    if group == "DERIVED_IMAGE_PARMS":
        assert obs.azimuth_deg is None and obs.elevation_deg is None
    if group == "INSTRUMENT_STATE_PARMS":
        assert obs.hfov_deg is None and obs.vfov_deg is None
    if group == "ROVER_COORDINATE_SYSTEM_PARMS":
        assert obs.rover_offset_m is None and obs.rover_quaternion is None


_BAD_ANY = ["abc", '"abc"', '""', '"NULL"', "(1, 2)", "NaN", "TRUE", "2016-08-13", '("a")']
_BAD_INT = [*_BAD_ANY, "1.5", "-3", "1.0e999", '"12x"', "1.0"]
# found by fuzzing; pdr's literal_eval reads them as Python ("12002#101#" -> 12002)
_BAD_INT += ["12002#101#", "2#102#", "1_000", "0x10", "12 # c", "3j"]
# issue 17: numbers no column or array can hold (a 400-digit LINES raised OverflowError)
_BAD_INT += ["9" * 400, "2147483648", "1" * 5000]
_BAD_VECTOR = [
    *_BAD_ANY,
    "1.0",
    "(1.0, 2.0, 3.0, 4.0)",
    '(1.0, "a", 3.0)',
    "(NaN, 1.0, 2.0)",
    "(1.0e999, 0.0, 0.0)",
    "(1.0, 2.0, TRUE)",
    "{1.0, 2.0, 3.0}",
]
_BAD_TEXT = ["5", "1.5", "(A, B)", '""', "2016-08-13T00:00:00", '"NULL"']
PDS3_BAD = {
    "PLANET_DAY_NUMBER": _BAD_INT,
    "LINES": [*_BAD_INT, "0", "100001"],
    "LINE_SAMPLES": [*_BAD_INT, "0"],
    **{f"MODEL_COMPONENT_{i}": _BAD_VECTOR for i in range(1, 7)},
    "PRODUCT_ID": _BAD_TEXT,
    "INSTRUMENT_ID": _BAD_TEXT,
    "MODEL_TYPE": [*_BAD_TEXT, "CAHVORE", '"PINHOLE"'],
    "REFERENCE_COORD_SYSTEM_NAME": _BAD_TEXT,
    "ROVER_MOTION_COUNTER": [
        *_BAD_ANY,
        "(1, 2)",
        '("a", 2, 3, 4)',
        "(-1, 2, 3, 4)",
        "(1.5, 2, 3, 4)",
    ],
    "ROVER_MOTION_COUNTER_NAME": ['("DRIVE", "X", "POSE", "ARM")', "(1, 2, 3, 4)", '("SITE")'],
    "ORIGIN_ROTATION_QUATERNION": [
        "(0.0, 0.0, 0.0, 0.0)",
        "(1.0, 2.0, 3.0)",
        '"q"',
        "(2.0, 0.0, 0.0, 0.0)",
    ],
    "ORIGIN_OFFSET_VECTOR": ["(1.0, 2.0)", "(NaN, 0.0, 0.0)", "abc"],
    "FIXED_INSTRUMENT_AZIMUTH": ["abc", "NaN", "(1.0, 2.0)", "1.0e999"],
    "FIXED_INSTRUMENT_ELEVATION": ["abc", "95.0", "-91.0"],
    "HORIZONTAL_FOV": ["abc", "0.0", "-5.0", "200.0"],
    "VERTICAL_FOV": ["TRUE", "0", "NaN"],
    "START_TIME": ['"yesterday"', "12", "(1, 2)"],
}
_PDS3_TARGET = {
    key: next(
        i
        for i, g, k in _pds3_statements()
        if k == key
        and (g == "IMAGE" or key not in ("LINES", "LINE_SAMPLES"))
        and not (key == "REFERENCE_COORD_SYSTEM_NAME" and g != CAMERA)
    )
    for key in PDS3_BAD
}


def _bad_pds3_values() -> st.SearchStrategy[tuple[str, str]]:
    fixed = st.sampled_from([(k, v) for k, values in PDS3_BAD.items() for v in values])
    words = st.text(alphabet="abcxyzQ_", min_size=1, max_size=8)
    generated = st.tuples(
        st.sampled_from(["PLANET_DAY_NUMBER", "LINES", "MODEL_COMPONENT_1", "PRODUCT_ID"]),
        st.one_of(
            words.map(lambda w: f'"{w}"'),
            st.floats(allow_nan=False, allow_infinity=False)
            .filter(lambda x: x != int(x))
            .map(repr),
            st.lists(st.floats(-1e6, 1e6), min_size=0, max_size=5)
            .filter(lambda v: len(v) != 3)
            .map(lambda v: "(" + ", ".join(f"{x:.6e}" for x in v) + ")"),
        ),
    ).filter(lambda kv: not (kv[0] == "PRODUCT_ID" and kv[1].startswith('"')))
    return st.one_of(fixed, generated)


@settings(
    max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(bad=_bad_pds3_values())
def test_pds3_wrong_types(workdir: Path, bad: tuple[str, str]) -> None:
    key, value = bad
    lines = PDS3_SEED.splitlines()
    index = _PDS3_TARGET[key]
    lines[index] = f" {key} = {value}"
    field = "ROVER_MOTION_COUNTER" if key.startswith("ROVER_MOTION_COUNTER") else key
    if bad == ("MODEL_TYPE", "CAHVORE"):
        field = "MODEL_COMPONENT_7"  # a valid type: what is wrong is the CAHVOR seed's missing E
    expect_error(write(workdir, "badtype.LBL", "\n".join(lines)), field=field)


@FAST
@given(order=st.permutations(range(6)))
def test_pds3_group_order_does_not_matter(workdir: Path, order: list[int]) -> None:
    blocks = re.findall(r"(?:GROUP|OBJECT) = \w+\n.*?END_(?:GROUP|OBJECT) = \w+\n", PDS3_SEED, re.S)
    assert len(blocks) == 7
    rest = PDS3_SEED
    for block in blocks:
        rest = rest.replace(block, "")
    head, tail = rest.rsplit("END\n", 1)
    shuffled = [blocks[i] for i in order] + blocks[6:]
    obs = read_observation(
        write(workdir, "shuffled.LBL", head + "".join(shuffled) + "END\n" + tail)
    )
    assert (obs.width, obs.height, obs.azimuth_deg) == (1152, 432, 217.9337)


# -- PDS4: deleted elements, non-numeric text, order ---------------------------------------
_MUST_ERROR_PDS4 = {
    "Identification_Area", "Observation_Area", "Mission_Area", "Mars2020_Parameters",
    "Observation_Information", "sol_number", "Discipline_Area", "Geometry", "Geometry_Lander",
    "Camera_Model_Parameters", "CAHVOR_Model", "Vector_Center", "Vector_Axis",
    "Vector_Horizontal", "Vector_Vertical", "Vector_Optical", "Radial_Terms", "c0", "c1", "c2",
    "File_Area_Observational", "Array_3D_Image",
}  # fmt: skip


def _local(el: etree._Element) -> str:
    return etree.QName(el).localname


def _must_error_if_deleted(el: etree._Element) -> bool:
    """Whether deleting ``el`` leaves the seed without a required field."""
    local = _local(el)
    ancestors = [_local(a) for a in el.iterancestors()]
    if local in _MUST_ERROR_PDS4:
        return True
    if "CAHVOR_Model" in ancestors:  # x_/y_/z_ components of the model vectors
        return True
    if "Camera_Model_Parameters" in ancestors and local in (
        "Coordinate_Space_Reference", "Coordinate_Space_Indexed", "coordinate_space_frame_type",
    ):  # fmt: skip
        return True
    axis = el if local == "Axis_Array" else el.getparent()
    if axis is not None and _local(axis) == "Axis_Array":
        name = axis.find(f"{{{NS['pds']}}}axis_name")
        return name is not None and name.text in ("Line", "Sample")
    return False


def _seed_tree() -> etree._Element:
    return etree.fromstring(PDS4_SEED.encode())


def test_pds4_every_deleted_element(workdir: Path) -> None:
    count = sum(1 for _ in _seed_tree().iter())
    for i in range(1, count):
        root = _seed_tree()
        el = list(root.iter())[i]
        must_error = _must_error_if_deleted(el)
        el.getparent().remove(el)
        path = write(workdir, "deleted.xml", etree.tostring(root))
        if must_error:
            expect_error(path, read_pds4)
        else:
            outcome(path, read_pds4)


def test_pds4_site_frame_pointing_is_chosen_by_frame_not_order(workdir: Path) -> None:
    root = _seed_tree()
    blocks = list(root.iter(f"{{{NS['geom']}}}Derived_Geometry"))
    blocks[0].addprevious(copy.deepcopy(blocks[1]))
    blocks[1].getparent().remove(blocks[1])  # SITE_FRAME block now first
    assert (
        read_observation(write(workdir, "swapped.xml", etree.tostring(root))).azimuth_deg == 274.338
    )
    root = _seed_tree()
    site = list(root.iter(f"{{{NS['geom']}}}Derived_Geometry"))[1]
    site.getparent().remove(site)  # only the ROVER_NAV_FRAME block left: no site pointing
    obs = read_observation(write(workdir, "roveronly.xml", etree.tostring(root)))
    assert obs.azimuth_deg is None and obs.elevation_deg is None


@FAST
@given(st.data())
def test_pds4_child_order_does_not_matter(workdir: Path, data: st.DataObject) -> None:
    root = _seed_tree()
    for parent_name in (
        "Geometry_Lander",
        "Camera_Model_Parameters",
        "CAHVOR_Model",
        "Coordinate_Space_Definition",
    ):
        for parent in root.iter(f"{{{NS['geom']}}}{parent_name}"):
            children = list(parent)
            for child in children:
                parent.remove(child)
            for child in data.draw(st.permutations(children)):
                parent.append(child)
    obs = read_observation(write(workdir, "reordered.xml", etree.tostring(root)))
    assert (obs.azimuth_deg, obs.site, obs.drive, obs.rmc.pose) == (274.338, 3, 1950, 4)
    assert obs.camera.h[0] == -14929.1 and obs.rover_offset_m[0] == 10.3131


PDS4_NUMERIC = [  # (element local name, occurrence, integer?)
    ("sol_number", 0, True),
    ("index_value_number", -3, False),  # SITE of geom:Motion_Counter
    ("x_position", 0, False),
    ("y_unit", 0, False),
    ("z_pixel", 1, False),
    ("c1", 0, False),
    ("elements", 1, True),
    ("elements", 2, True),
    ("qcos", 0, False),
    ("instrument_azimuth", 1, False),
    ("sample_fov", 0, False),
    ("line_fov", 0, False),
    ("start_date_time", 0, False),
]
_SPECIAL_BAD = [
    "nan",
    "NaN",
    "inf",
    "-inf",
    "1e999",
    "",
    "  ",
    "1,5",
    "0x10",
    "\u0661\u0662",
    "1_000",
    "1.5.2",
    "--1",
    "+",
    ".",
    "e5",
]


def _not_number(text: str) -> bool:
    return not FLOAT_TEXT.fullmatch(text)


@settings(
    max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    target=st.sampled_from(PDS4_NUMERIC),
    text=st.one_of(st.sampled_from(_SPECIAL_BAD), st.text(max_size=12).filter(_not_number)),
)
def test_pds4_non_numeric_text(workdir: Path, target: tuple[str, int, bool], text: str) -> None:
    local, nth, _ = target
    root = _seed_tree()
    el = [e for e in root.iter() if isinstance(e.tag, str) and _local(e) == local][nth]
    try:
        el.text = text
    except ValueError:  # lxml refuses control characters: not representable in XML
        assume(False)
    expect_error(write(workdir, "nonnumeric.xml", etree.tostring(root)))


@FAST
@given(
    target=st.sampled_from([t for t in PDS4_NUMERIC if t[2]]),
    value=st.one_of(
        st.integers(max_value=-1).map(str),
        st.floats(allow_nan=False, allow_infinity=False)
        .filter(lambda x: not x.is_integer())
        .map(repr),
    ),
)
def test_pds4_bad_integers(workdir: Path, target: tuple[str, int, bool], value: str) -> None:
    local, nth, _ = target
    root = _seed_tree()
    el = [e for e in root.iter() if isinstance(e.tag, str) and _local(e) == local][nth]
    el.text = value
    expect_error(write(workdir, "badint.xml", etree.tostring(root)))


@FAST
@given(data=st.data())
def test_pds4_random_element_text(workdir: Path, data: st.DataObject) -> None:
    """Any element's text replaced by anything: an Observation or a LabelError, nothing else."""
    root = _seed_tree()
    elements = [e for e in root.iter() if isinstance(e.tag, str)]
    el = data.draw(st.sampled_from(elements))
    try:
        el.text = data.draw(st.text(max_size=20))
    except ValueError:
        assume(False)
    outcome(write(workdir, "anytext.xml", etree.tostring(root)))
