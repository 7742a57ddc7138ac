"""Ground images: decoded and checked before they enter a shard; new label kinds build.

Every label kind the readers gained (MIPL group names, attached-label IMG, CAHVORE in PDS3 and
PDS4, PDS4 + IMG) is written by the synthetic label writers from a generated mission's
observations, read back to the same camera and pose, and built into samples with 0 failures.
"""

from __future__ import annotations

import io
import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from PIL import Image

from mars_pairs.errors import ImageError
from mars_pairs.geometry.camera import CameraModel
from mars_pairs.observation import Observation
from mars_pairs.pds import read_observation
from mars_pairs.pipeline.builder.run import run_build
from mars_pairs.pipeline.config import load_config
from mars_pairs.pipeline.sample.ground import ground_image
from mars_pairs.synth.labels import write_pds3_img, write_pds3_label, write_pds4_label
from support.configs import config_file
from support.members import metas as read_metas
from support.missions import MissionCache

pytestmark = pytest.mark.slow  # its tests share a fixture of > 3 s


@pytest.fixture(scope="module")
def mission(missions: MissionCache) -> Path:
    return missions(seed=5, stops=2, images_per_stop=2)


def observations(mission: Path) -> list[Observation]:
    return [read_observation(p) for p in sorted((mission / "labels").glob("*.xml"))]


def assert_same(got: Observation, want: Observation) -> None:
    """Every Observation field equal (vectors within 1e-9), label and image paths aside."""
    for name in ("mission", "product_id", "instrument", "sol", "rmc", "width", "height",
                 "start_time"):  # fmt: skip
        assert getattr(got, name) == getattr(want, name), name
    for name in ("azimuth_deg", "elevation_deg", "hfov_deg", "vfov_deg"):
        assert getattr(got, name) == pytest.approx(getattr(want, name), abs=1e-9), name
    for name in ("rover_offset_m", "rover_quaternion"):
        np.testing.assert_allclose(getattr(got, name), getattr(want, name), atol=1e-9)
    for name in ("model_type", "frame", "mtype", "mparm"):
        assert getattr(got.camera, name) == getattr(want.camera, name), name
    for name in ("c", "a", "h", "v", "o", "r", "e"):
        mine, theirs = getattr(got.camera, name), getattr(want.camera, name)
        assert (mine is None) == (theirs is None), name
        if theirs is not None:
            np.testing.assert_allclose(mine, theirs, atol=1e-9)


def rgb(obs: Observation) -> np.ndarray:
    assert obs.image_path is not None
    with Image.open(obs.image_path) as im:
        return np.asarray(im.convert("RGB"))


def as_cahvore(cam: CameraModel) -> CameraModel:
    """The same camera as a CAHVORE (type 3, linearity 1, a small moving pupil)."""
    o = cam.a if cam.o is None else cam.o
    r = np.zeros(3) if cam.r is None else cam.r
    return CameraModel("CAHVORE", cam.c, cam.a, cam.h, cam.v, o=o, r=r, frame=cam.frame,
                       e=np.array([0.0, 0.002, -0.001]), mtype=3, mparm=1.0)  # fmt: skip


def renamed(obs: Observation, tag: str) -> Observation:
    return replace(obs, product_id=f"{obs.product_id[:40]}_{tag}")


def write_kinds(mission: Path, out: Path) -> dict[str, list[Path]]:
    """Each new label kind, for every observation of the mission; returns paths by kind."""
    out.mkdir(parents=True, exist_ok=True)
    kinds: dict[str, list[Path]] = {}
    for i, obs in enumerate(observations(mission)):
        jpg = out / f"browse_{i}.jpg"
        shutil.copyfile(obs.image_path, jpg)
        pixels = rgb(obs)
        gray16 = (pixels.mean(axis=2) * 200.0 + 1000.0).astype(np.uint16)
        made = {
            "mipl_pds3": write_pds3_label(
                replace(renamed(obs, "MIPL"), image_path=jpg), out / f"mipl_{i}.LBL", style="mipl"
            ),
            "attached_img": write_pds3_img(
                replace(renamed(obs, "ATT"), image_path=None), out / f"att_{i}.IMG", gray16
            ),
            "cahvore_pds3": write_pds3_label(
                replace(renamed(obs, "ORE3"), camera=as_cahvore(obs.camera), image_path=jpg),
                out / f"ore3_{i}.LBL",
                style="mipl",
            ),
            "cahvore_pds4": write_pds4_label(
                replace(renamed(obs, "ORE4"), camera=as_cahvore(obs.camera), image_path=jpg),
                out / f"ore4_{i}.xml",
            ),
            "pds4_img": write_pds4_label(
                replace(renamed(obs, "IMG4"), image_path=None), out / f"img4_{i}.xml", pixels
            ),
        }
        for kind, path in made.items():
            kinds.setdefault(kind, []).append(path)
    return kinds


@pytest.fixture(scope="module")
def kinds(mission: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, list[Path]]:
    return write_kinds(mission, tmp_path_factory.mktemp("kinds"))


TAGS = {"mipl_pds3": "_MIPL", "attached_img": "_ATT", "cahvore_pds3": "_ORE3",
        "cahvore_pds4": "_ORE4", "pds4_img": "_IMG4"}  # fmt: skip


def test_every_kind_reads_back_to_the_same_camera_and_pose(
    mission: Path, kinds: dict[str, list[Path]]
) -> None:
    originals = observations(mission)
    for kind, paths in kinds.items():
        for obs, path in zip(originals, paths, strict=True):
            got = read_observation(path)
            want = obs
            if kind.startswith("cahvore"):
                want = replace(want, camera=as_cahvore(obs.camera))
            want = replace(want, product_id=got.product_id)
            if kind.endswith("pds3") or kind == "attached_img":
                want = replace(want, mission="msl")
            assert_same(got, want)
            assert got.product_id.endswith(TAGS[kind])
    attached = read_observation(kinds["attached_img"][0])
    assert attached.image_path == kinds["attached_img"][0]  # the label is inside the image
    assert read_observation(kinds["pds4_img"][0]).image_path.suffix == ".IMG"


def test_img_products_decode_through_pdr(kinds: dict[str, list[Path]], mission: Path) -> None:
    obs = observations(mission)[0]
    four = ground_image(read_observation(kinds["pds4_img"][0]), "png")
    assert four.size == (obs.width, obs.height) and four.name == "ground.png"
    with Image.open(io.BytesIO(four.data)) as im:
        np.testing.assert_array_equal(np.asarray(im), rgb(obs))  # lossless, same pixels
    assert four.meta["source_array"] == read_observation(kinds["pds4_img"][0]).product_id.lower()
    assert "stretch" not in four.meta

    three = ground_image(read_observation(kinds["attached_img"][0]), "png")
    assert three.size == (obs.width, obs.height)
    stretch = three.meta["stretch"]
    assert stretch["source_dtype"] == ">u2" or stretch["source_dtype"].endswith("u2")
    gray16 = (rgb(obs).mean(axis=2) * 200.0 + 1000.0).astype(np.uint16)
    lo, hi = np.percentile(gray16, stretch["percentiles"])
    assert (stretch["low"], stretch["high"]) == pytest.approx((lo, hi))
    with Image.open(io.BytesIO(three.data)) as im:
        got = np.asarray(im).astype(float)
    expected = np.clip(np.rint((gray16 - lo) / (hi - lo) * 255), 0, 255)
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("factor", [2, 4])
def test_a_resized_browse_gets_its_camera_scaled(
    mission: Path, tmp_path: Path, factor: int
) -> None:
    obs = observations(mission)[0]
    small = tmp_path / "small.jpg"
    with Image.open(obs.image_path) as im:
        size = (round(obs.width / factor), round(obs.height / factor))
        im.resize(size, Image.BILINEAR).save(small, quality=90)
    got = ground_image(replace(obs, image_path=small), "jpg")
    sx, sy = size[0] / obs.width, size[1] / obs.height
    assert got.meta["image_scale"] == [sx, sy]
    assert got.meta["label_size"] == [obs.width, obs.height]
    assert (got.observation.width, got.observation.height) == size
    # the scaled camera puts every terrain point where the resized image shows it
    _, rays = obs.camera.unproject(np.array([[10.0, 20.0], [400.0, 300.0], [800.0, 590.0]]))
    points = obs.camera.c + 50.0 * rays
    full = obs.camera.project(points)
    np.testing.assert_allclose(
        got.observation.camera.project(points), (full + 0.5) * [sx, sy] - 0.5, atol=1e-6
    )
    assert got.data == small.read_bytes()


def _bad_images(obs: Observation, where: Path) -> dict[str, Path]:
    good = obs.image_path.read_bytes()
    tiny = where / "tiny.jpg"
    Image.new("RGB", (16, 16)).save(tiny)
    stretched = where / "stretched.jpg"
    Image.new("RGB", (obs.width // 2, obs.height)).save(stretched)
    half = where / "half.jpg"
    half.write_bytes(good[: len(good) // 2])
    png = where / "broken.png"
    buf = io.BytesIO()
    Image.fromarray(rgb(obs)).save(buf, format="PNG")
    data = bytearray(buf.getvalue())
    data[len(data) // 2 : len(data) // 2 + 64] = bytes(64)
    png.write_bytes(bytes(data))
    header = where / "header.jpg"
    header.write_bytes(good[:2] + bytes(200) + good[202:])
    return {"tiny": tiny, "stretched": stretched, "half": half, "png": png, "header": header}


def test_bad_images_are_refused_naming_the_file(mission: Path, tmp_path: Path) -> None:
    obs = observations(mission)[0]
    for name, path in _bad_images(obs, tmp_path).items():
        with pytest.raises(ImageError) as err:
            ground_image(replace(obs, image_path=path), "jpg")
        assert path.name in str(err.value), name
        if name in ("tiny", "stretched"):
            shown = f"{Image.open(path).size[0]} x {Image.open(path).size[1]}"
            assert shown in str(err.value) and f"{obs.width} x {obs.height}" in str(err.value)


def _config(tmp: Path, mission: Path, globs: list[str]) -> Path:
    return config_file(
        tmp / "config.yaml", mission, tmp / "out", fine=True, labels=globs,
        geometry={"radius": 400}, chips={"size_px": 64}, output={"shard_size": 8},
    )  # fmt: skip


def test_every_new_kind_builds_into_samples_with_no_failure(
    mission: Path, kinds: dict[str, list[Path]], tmp_path: Path
) -> None:
    folder = kinds["mipl_pds3"][0].parent
    globs = [str(folder / g) for g in ("*.LBL", "*.xml", "att_*.IMG")]
    run_build(load_config(_config(tmp_path, mission, globs)), workers=1)
    out = tmp_path / "out"
    rows = pq.read_table(out / "manifest.parquet").to_pylist()
    failures = pq.read_table(out / "failures.parquet").to_pylist()
    assert failures == []
    assert len(rows) == sum(len(v) for v in kinds.values())
    by_tag = {r["product_id"].rsplit("_", 1)[1] for r in rows}
    assert by_tag == {"MIPL", "ATT", "ORE3", "ORE4", "IMG4"}
    metas = read_metas(out)
    assert len(metas) == len(rows)
    types = {m["product_id"].rsplit("_", 1)[1]: m["camera_model_type"] for m in metas.values()}
    assert types["ORE3"] == types["ORE4"] == "CAHVORE"
    stretched = [m for m in metas.values() if m["product_id"].endswith("_ATT")]
    assert all(m["ground_image"]["stretch"]["method"] == "linear percentile" for m in stretched)


def test_bad_images_become_failure_rows_and_the_rest_builds(mission: Path, tmp_path: Path) -> None:
    good = observations(mission)
    folder = tmp_path / "labels"
    folder.mkdir()
    bad = _bad_images(good[0], folder)
    for i, (name, image) in enumerate(bad.items()):
        write_pds4_label(replace(renamed(good[i % len(good)], name.upper()), image_path=image),
                         folder / f"bad_{name}.xml")  # fmt: skip
    for obs in good:
        shutil.copyfile(obs.label_path, folder / obs.label_path.name)
        shutil.copyfile(obs.image_path, folder / obs.image_path.name)
    run_build(load_config(_config(tmp_path, mission, [str(folder / "*.xml")])), workers=1)
    out = tmp_path / "out"
    failures = pq.read_table(out / "failures.parquet").to_pylist()
    assert len(pq.read_table(out / "manifest.parquet")) == len(good)
    assert sorted(f["path"].rsplit("/", 1)[1] for f in failures) == sorted(
        f"bad_{n}.xml" for n in bad
    )
    for row in failures:
        assert row["stage"] == "image"
        name = Path(row["path"]).stem.removeprefix("bad_")
        assert bad[name].name in row["message"]


SAMPLES = Path(__file__).resolve().parents[2].parent / "shared" / "pds-samples"


def _real_labels() -> list[Path]:
    if not SAMPLES.is_dir():
        pytest.skip(f"real PDS samples not found at {SAMPLES} (../shared beside the checkout)")
    return sorted(SAMPLES.glob("msl/*.LBL")) + sorted(SAMPLES.glob("m2020/*.xml"))


def test_real_browse_images_fit_their_labels_and_resized_ones_keep_the_label_fov(
    tmp_path: Path,
) -> None:
    """Every real browse image is the label's grid; resized to 1/2 and 1/4 its scaled camera
    still gives the label's own HORIZONTAL_FOV / VERTICAL_FOV (an independent check)."""
    for label in _real_labels():
        obs = read_observation(label)
        same = ground_image(obs, "jpg")
        assert same.meta["image_scale"] == [1.0, 1.0] and same.observation == obs
        for factor in (2, 4):
            small = tmp_path / f"{label.stem}_{factor}.jpg"
            with Image.open(obs.image_path) as im:
                im.resize((round(obs.width / factor), round(obs.height / factor))).save(small)
            got = ground_image(replace(obs, image_path=small), "jpg").observation
            hfov, vfov = got.camera.fov_deg(got.width, got.height)
            assert hfov == pytest.approx(obs.hfov_deg, rel=0.01), (label.name, factor)
            assert vfov == pytest.approx(obs.vfov_deg, rel=0.01), (label.name, factor)


def test_locate_reads_every_new_kind(
    mission: Path, kinds: dict[str, list[Path]], capsys: pytest.CaptureFixture[str]
) -> None:
    from mars_pairs.cli.main import main

    paths = [str(p) for paths in kinds.values() for p in paths]
    places = str(mission / "places" / "best_interp.csv")
    assert main(["locate", *paths, "--places", places, "--json"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line]
    assert len(lines) == len(paths)
    types = {d["product_id"].rsplit("_", 1)[1]: d["camera_model_type"] for d in lines}
    assert types["ORE3"] == types["ORE4"] == "CAHVORE"
    assert all(d["localization"] for d in lines)


def _mipl_navcam_img(path: Path, pixels: np.ndarray) -> Path:
    """An attached-label Navcam RDR as MIPL writes them (ODL3 header, no MSL: prefixes,
    GEOMETRIC_CAMERA_MODEL / ROVER_COORDINATE_SYSTEM, a VICAR header object before the image,
    record pointers), written by hand rather than by our writer."""
    record, lines, samples = 2048, *pixels.shape
    label = f"""ODL_VERSION_ID = ODL3
RECORD_TYPE = FIXED_LENGTH
RECORD_BYTES = {record}
FILE_RECORDS = {3 + lines * samples * 2 // record}
LABEL_RECORDS = 2
^IMAGE_HEADER = 3
^IMAGE = 4
INSTRUMENT_ID = NAV_RIGHT_B
PLANET_DAY_NUMBER = 3423
PRODUCT_ID = "NRB_701383954RAS_F0933408NCAM00200M1"
ROVER_MOTION_COUNTER_NAME = ("SITE", "DRIVE", "POSE")
ROVER_MOTION_COUNTER = (93, 3408, 12)
GROUP = ROVER_COORDINATE_SYSTEM
 COORDINATE_SYSTEM_NAME = ROVER_NAV_FRAME
 ORIGIN_OFFSET_VECTOR = (1.0, 2.0, 0.5)
 ORIGIN_ROTATION_QUATERNION = (1.0, 0.0, 0.0, 0.0)
 REFERENCE_COORD_SYSTEM_NAME = SITE_FRAME
END_GROUP = ROVER_COORDINATE_SYSTEM
GROUP = GEOMETRIC_CAMERA_MODEL
 MODEL_TYPE = CAHVOR
 MODEL_COMPONENT_ID = ("C","A","H","V","O","R")
 MODEL_COMPONENT_UNIT = (METER,"N/A",PIXEL,PIXEL,"N/A","N/A")
 MODEL_COMPONENT_1 = (0.953083,0.737269,-1.83989)
 MODEL_COMPONENT_2 = (0.61802,-0.158336,0.770042)
 MODEL_COMPONENT_3 = (622.069,1100.35,388.444)
 MODEL_COMPONENT_4 = (-588.816,157.005,1176.66)
 MODEL_COMPONENT_5 = (0.615108,-0.158211,0.772395)
 MODEL_COMPONENT_6 = (1.35787e-05,0.00183074,-0.0057552)
 REFERENCE_COORD_SYSTEM_NAME = ROVER_NAV_FRAME
END_GROUP = GEOMETRIC_CAMERA_MODEL
GROUP = SITE_DERIVED_GEOMETRY_PARMS
 INSTRUMENT_AZIMUTH = 346.2 <deg>
 INSTRUMENT_ELEVATION = -50.1 <deg>
 REFERENCE_COORD_SYSTEM_NAME = SITE_FRAME
END_GROUP = SITE_DERIVED_GEOMETRY_PARMS
OBJECT = IMAGE_HEADER
 HEADER_TYPE = VICAR2
 INTERCHANGE_FORMAT = ASCII
 BYTES = {record}
END_OBJECT = IMAGE_HEADER
OBJECT = IMAGE
 LINES = {lines}
 LINE_SAMPLES = {samples}
 SAMPLE_TYPE = MSB_INTEGER
 SAMPLE_BITS = 16
 BANDS = 1
 BAND_STORAGE_TYPE = BAND_SEQUENTIAL
END_OBJECT = IMAGE
END
""".replace("\n", "\r\n").encode()
    assert len(label) <= 2 * record
    vicar = b"LBLSIZE=2048 FORMAT='HALF' NL=64 NS=64".ljust(record, b" ")
    path.write_bytes(label.ljust(2 * record, b" ") + vicar + pixels.astype(">i2").tobytes())
    return path


def test_a_mipl_navcam_img_reads_and_its_image_is_chosen_by_type(tmp_path: Path) -> None:
    pixels = (np.arange(64 * 64).reshape(64, 64) % 4000).astype(np.int16)
    path = _mipl_navcam_img(tmp_path / "NRB_701383954RAS_F0933408NCAM00200M1.IMG", pixels)
    obs = read_observation(path)
    assert (obs.instrument, obs.sol, obs.rmc.site, obs.rmc.drive) == ("NAV_RIGHT_B", 3423, 93, 3408)
    assert (obs.width, obs.height, obs.camera.model_type) == (64, 64, "CAHVOR")
    assert (obs.azimuth_deg, obs.elevation_deg) == (346.2, -50.1)
    np.testing.assert_allclose(obs.rover_offset_m, [1.0, 2.0, 0.5])
    assert obs.image_path == path
    got = ground_image(obs, "png")
    assert got.meta["source_array"] == "IMAGE"  # not IMAGE_HEADER
    lo, hi = np.percentile(pixels, [0.5, 99.5])
    with Image.open(io.BytesIO(got.data)) as im:
        expected = np.clip(np.rint((pixels - lo) / (hi - lo) * 255), 0, 255)
        np.testing.assert_array_equal(np.asarray(im), expected)


@pytest.mark.parametrize("mode", ["RGB", "L"])
def test_kept_pixels_are_the_decoded_image(mode: str) -> None:
    """The pixels kept for the dense members are Pillow's decode: grey (H, W); colour as
    Pillow holds it, RGBX (H, W, 4), whose first 3 bands are the RGB values."""
    from mars_pairs.pipeline.sample.ground import decoded_size

    rng = np.random.default_rng(2)
    shape = (24, 40, 3) if mode == "RGB" else (24, 40)
    buf = io.BytesIO()
    Image.fromarray(rng.integers(0, 256, size=shape, dtype=np.uint8)).save(buf, format="JPEG")
    kept: list[np.ndarray] = []
    assert decoded_size(buf.getvalue(), Path("x.jpg"), kept) == (40, 24)
    want = np.asarray(Image.open(io.BytesIO(buf.getvalue())))
    (pixels,) = kept
    if mode == "RGB":
        assert pixels.shape == (24, 40, 4) and np.array_equal(pixels[..., :3], want)
    else:
        assert pixels.shape == (24, 40) and np.array_equal(pixels, want)


def test_colours_laid_on_the_map_from_rgbx_are_those_from_rgb() -> None:
    from mars_pairs.pipeline.sample.dense import ground_on_map

    rng = np.random.default_rng(8)
    rgb = rng.integers(0, 256, size=(30, 50, 3), dtype=np.uint8)
    rgbx = np.concatenate([rgb, np.full((30, 50, 1), 255, dtype=np.uint8)], axis=2)
    ground_px = np.stack([rng.uniform(-2, 52, (16, 16)), rng.uniform(-2, 32, (16, 16))], -1)
    ground_px = ground_px.astype(np.float32)
    ground_px[rng.random((16, 16)) < 0.3] = np.nan
    colours, cover = ground_on_map(rgb, ground_px)
    padded, padded_cover = ground_on_map(rgbx, ground_px)
    assert colours.shape == padded.shape == (16, 16, 3) and 0 < cover.sum() < 16 * 16
    assert np.array_equal(colours, padded) and np.array_equal(cover, padded_cover)
