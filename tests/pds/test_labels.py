"""Label readers on the real NASA samples (skipped without ../shared) and writer round trips."""

from __future__ import annotations

import functools
import math
import re
import shutil
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pytest

from mars_pairs.errors import LabelError
from mars_pairs.geometry.camera import CameraModel
from mars_pairs.observation import MotionCounter, Observation
from mars_pairs.pds import read_observation, read_pds3, read_pds4, sniff_format
from mars_pairs.synth.labels import write_pds3_img, write_pds3_label, write_pds4_label
from support.observations import assert_same

SAMPLES = Path(__file__).resolve().parents[2].parent / "shared" / "pds-samples"
ZLF = "m2020/ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01.xml"
ZRF = "m2020/ZRF_0079_0673952814_113RAD_N0032430ZCAM03128_110085J03.xml"
ML = "msl/2663ML0139550021002124C00_DRCX.LBL"
MR = "msl/1429MR0070670010702567E01_DRCL.LBL"


@pytest.fixture(scope="module")
def samples() -> Path:
    """../shared/pds-samples, or skip with a message saying where it was looked for."""
    if not SAMPLES.is_dir():
        pytest.skip(f"real PDS samples not found at {SAMPLES} (../shared beside the checkout)")
    return SAMPLES


def _labels(samples: Path) -> list[Path]:
    return sorted(samples.glob("msl/*.LBL")) + sorted(samples.glob("m2020/*.xml"))


@functools.cache
def _read(path: Path) -> Observation:
    """read_observation, cached (a real PDS3 label takes ~20 ms to parse)."""
    return read_observation(path)


def _rotation(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion (s, v1, v2, v3)."""
    s, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - s * z), 2 * (x * z + s * y)],
            [2 * (x * y + s * z), 1 - 2 * (x * x + z * z), 2 * (y * z - s * x)],
            [2 * (x * z - s * y), 2 * (y * z + s * x), 1 - 2 * (x * x + y * y)],
        ]
    )


# -- every real label ------------------------------------------------------------------------
def test_every_sample_label_parses(samples: Path) -> None:
    labels = _labels(samples)
    assert len(labels) >= 13
    for path in labels:
        obs = _read(path)
        assert obs.mission == ("m2020" if path.suffix == ".xml" else "msl")
        assert obs.product_id == path.stem
        assert obs.camera.frame == "ROVER_NAV_FRAME"
        assert obs.image_path == path.with_suffix(".jpg")
        assert obs.rover_quaternion is not None and obs.rover_offset_m is not None
        assert obs.start_time is not None and obs.start_time.tzinfo is not None
        for value in (obs.azimuth_deg, obs.elevation_deg, obs.hfov_deg, obs.vfov_deg):
            assert value is not None and math.isfinite(value)


def test_model_fov_matches_label_fov(samples: Path) -> None:
    """The camera model on the IMAGE grid reproduces the label's FOV (ZLF is off by 0.7 %)."""
    for path in _labels(samples):
        obs = _read(path)
        hfov, vfov = obs.camera.fov_deg(obs.width, obs.height)
        assert hfov == pytest.approx(obs.hfov_deg, rel=0.01), path.name
        assert vfov == pytest.approx(obs.vfov_deg, rel=0.01), path.name


def test_site_pointing_is_rover_axis_turned_by_quaternion(samples: Path) -> None:
    """SITE_FRAME azimuth/elevation = the model axis rotated by the rover quaternion."""
    for path in _labels(samples):
        obs = _read(path)
        axis = _rotation(obs.rover_quaternion) @ obs.camera.a
        az = math.degrees(math.atan2(axis[1], axis[0])) % 360.0
        el = math.degrees(math.asin(-axis[2]))
        assert abs((az - obs.azimuth_deg + 180.0) % 360.0 - 180.0) < 1.5, path.name
        assert abs(el - obs.elevation_deg) < 1.5, path.name


def test_pds4_product_id_encodes_site_and_drive(samples: Path) -> None:
    for path in sorted(samples.glob("m2020/*.xml")):
        obs = read_pds4(path)
        match = re.search(r"_N(\d{3})(\d{4})", obs.product_id)
        assert match is not None
        assert (obs.site, obs.drive) == (int(match[1]), int(match[2]))


# -- concrete values -------------------------------------------------------------------------
def test_zlf_0052(samples: Path) -> None:
    obs = read_observation(samples / ZLF)
    assert obs.product_id == "ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01"
    assert (obs.instrument, obs.sol) == ("MCZ_LEFT", 52)
    assert obs.rmc == MotionCounter(site=3, drive=1950, pose=4)
    assert (obs.width, obs.height) == (1648, 1200)
    assert obs.camera.model_type == "CAHVOR"
    np.testing.assert_allclose(obs.camera.c, [0.92755, 0.589019, -1.98371])
    np.testing.assert_allclose(obs.camera.r, [0.000232333, 0.449144, 0.08829])
    # two Derived_Geometry blocks: 94.4856 is ROVER_NAV_FRAME, 274.338 is SITE_FRAME
    assert obs.azimuth_deg == pytest.approx(274.338)
    assert obs.elevation_deg == pytest.approx(-2.8571)
    assert (obs.hfov_deg, obs.vfov_deg) == pytest.approx((6.35693, 4.63392))
    np.testing.assert_allclose(obs.rover_offset_m, [10.3131, 65.9943, 0.715083])
    np.testing.assert_allclose(
        obs.rover_quaternion, [0.00131628, 0.000646026, -0.000920782, 0.999999], atol=1e-6
    )
    assert obs.start_time == datetime(2021, 4, 13, 4, 17, 42, 580000, tzinfo=timezone.utc)


def test_zrf_0079(samples: Path) -> None:
    obs = read_observation(samples / ZRF)
    assert (obs.instrument, obs.sol) == ("MCZ_RIGHT", 79)
    assert obs.rmc == MotionCounter(site=3, drive=2430, pose=80)
    assert obs.azimuth_deg == pytest.approx(145.926)
    assert obs.hfov_deg == pytest.approx(6.36042)


def test_mastcam_left_cahvor(samples: Path) -> None:
    obs = read_observation(samples / ML)
    assert (obs.instrument, obs.sol, obs.mission) == ("MAST_LEFT", 2663, "msl")
    assert obs.rmc == MotionCounter(site=78, drive=2858, pose=40)
    assert (obs.width, obs.height) == (1152, 432)
    assert obs.camera.model_type == "CAHVOR"
    np.testing.assert_allclose(obs.camera.r, [-0.000151, -0.139189, -1.250336])
    np.testing.assert_allclose(obs.camera.o, [0.924242, 0.3575774, 0.1337885])
    assert (obs.azimuth_deg, obs.elevation_deg) == pytest.approx((217.9337, 5.3246))
    assert (obs.hfov_deg, obs.vfov_deg) == pytest.approx((14.1467, 5.3288))
    np.testing.assert_allclose(obs.rover_offset_m, [-168.132843, -44.091644, -23.868143])


def test_mastcam_right_cahv_uses_image_object_grid(samples: Path) -> None:
    """IMAGE_REQUEST_PARMS says 1344 x 1200; the IMAGE object (the model's grid) 1339 x 1196."""
    obs = read_observation(samples / MR)
    assert obs.instrument == "MAST_RIGHT"
    assert obs.rmc == MotionCounter(site=56, drive=1632, pose=8)
    assert (obs.width, obs.height) == (1339, 1196)
    assert obs.camera.model_type == "CAHV"
    assert obs.camera.o is None and obs.camera.r is None
    np.testing.assert_allclose(obs.camera.h, [-7710.577, 10892.38, -204.2618])
    assert (obs.azimuth_deg, obs.elevation_deg) == pytest.approx((270.3563, 7.0173))
    assert obs.start_time == datetime(2016, 8, 13, 10, 4, 17, 525000, tzinfo=timezone.utc)


# -- format by content, files beside the label --------------------------------------------
def test_format_is_sniffed_by_content_not_extension(samples: Path, tmp_path: Path) -> None:
    pds3 = tmp_path / "label_a.xml"
    pds4 = tmp_path / "label_b.LBL"
    shutil.copyfile(samples / MR, pds3)
    shutil.copyfile(samples / ZLF, pds4)
    assert sniff_format(pds3.read_bytes()) == "pds3"
    assert sniff_format(pds4.read_bytes()) == "pds4"
    assert read_observation(pds3).mission == "msl"
    assert read_observation(pds4).mission == "m2020"


def test_no_image_beside_label_gives_none(samples: Path, tmp_path: Path) -> None:
    for name in (MR, ZLF):
        copy = tmp_path / Path(name).name
        shutil.copyfile(samples / name, copy)
        assert read_observation(copy).image_path is None


def test_wrong_reader_raises_label_error(samples: Path) -> None:
    with pytest.raises(LabelError):
        read_pds3(samples / ZLF)
    with pytest.raises(LabelError):
        read_pds4(samples / MR)


def test_missing_file_is_label_error(tmp_path: Path) -> None:
    missing = tmp_path / "nope.LBL"
    with pytest.raises(LabelError, match=r"nope\.LBL"):
        read_observation(missing)


# -- writers ------------------------------------------------------------------------------
def _synthetic(model: str, full: bool) -> Observation:
    rng = np.random.default_rng(7 if full else 11)
    a = np.array([0.8, 0.55, 0.1])
    a /= np.linalg.norm(a)
    distorted = model in ("CAHVOR", "CAHVORE")
    camera = CameraModel(
        model_type=model,
        c=rng.normal(size=3),
        a=a,
        h=np.array([-1200.3, 3500.1234567890123, 12.5]),
        v=np.array([140.2, 120.8, 3600.000000001]),
        o=a + np.array([0.001, -0.002, 0.0005]) if distorted else None,
        r=np.array([-1.5e-4, -0.139189, -1.250336]) if distorted else None,
        e=np.array([-8.0e-09, 1.0e-08, -2.9e-08]) if model == "CAHVORE" else None,
        mtype=3 if model == "CAHVORE" else None,
        mparm=0.37 if model == "CAHVORE" else None,
    )
    q = rng.normal(size=4)
    optional = {
        "rover_offset_m": rng.normal(size=3) * 100,
        "rover_quaternion": q / np.linalg.norm(q),
        "azimuth_deg": 217.93371234567,
        "elevation_deg": -5.25e-3,
        "hfov_deg": 14.1467,
        "vfov_deg": 5.3288,
        "start_time": datetime(2020, 2, 2, 6, 30, 46, 741123, tzinfo=timezone.utc),
    }
    return Observation(
        label_path=Path("synthetic"),
        mission="msl",
        product_id="2663ML0139550021002124C00_DRCX",
        instrument="MAST_LEFT",
        sol=2663,
        rmc=MotionCounter(site=78, drive=2858, pose=40 if full else None),
        width=1152,
        height=432,
        camera=camera,
        **(optional if full else {}),
    )


@pytest.mark.parametrize("style", ["mastcam", "mipl"])
@pytest.mark.parametrize("model", ["CAHV", "CAHVOR", "CAHVORE"])
@pytest.mark.parametrize("full", [True, False])
def test_pds3_writer_round_trip(tmp_path: Path, model: str, full: bool, style: str) -> None:
    obs = _synthetic(model, full)
    path = write_pds3_label(obs, tmp_path / f"{obs.product_id}.LBL", style=style)
    got = read_observation(path)
    assert_same(got, obs)
    assert got.label_path == path and got.image_path is None


@pytest.mark.parametrize("model", ["CAHV", "CAHVOR", "CAHVORE"])
@pytest.mark.parametrize("full", [True, False])
def test_pds4_writer_round_trip(tmp_path: Path, model: str, full: bool) -> None:
    obs = replace(
        _synthetic(model, full),
        mission="m2020",
        product_id="ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01",
        instrument="MCZ_LEFT",
    )
    path = write_pds4_label(obs, tmp_path / "renamed.xml")
    assert_same(read_observation(path), obs)


def test_writers_point_to_the_image(tmp_path: Path) -> None:
    image = tmp_path / "browse.png"
    image.write_bytes(b"\x89PNG")
    obs = replace(_synthetic("CAHV", True), image_path=image)
    assert read_observation(write_pds3_label(obs, tmp_path / "a.LBL")).image_path == image
    assert read_observation(write_pds4_label(obs, tmp_path / "b.xml")).image_path == image


def test_pds4_writer_structure(tmp_path: Path) -> None:
    """The synthetic PDS4 label has the real structure: frames and pointing blocks in order."""
    from lxml import etree

    from mars_pairs.pds.xml import q

    root = etree.parse(str(write_pds4_label(_synthetic("CAHVOR", True), tmp_path / "x.xml")))
    derived = root.findall(".//" + q("geom", "Derived_Geometry"))
    assert len(derived) == 2
    assert derived[0].find(".//" + q("pds", "local_identifier_reference")) is not None
    kind = derived[1].find(".//" + q("geom", "coordinate_space_frame_type"))
    assert kind is not None and kind.text == "SITE_FRAME"
    assert len(root.findall(".//" + q("geom", "Coordinate_Space_Definition"))) >= 2


def test_real_labels_round_trip_through_writers(samples: Path, tmp_path: Path) -> None:
    for path in (samples / ZLF, samples / ML, samples / MR):
        obs = read_observation(path)
        as_msl, as_m2020 = replace(obs, mission="msl"), replace(obs, mission="m2020")
        assert_same(read_observation(write_pds3_label(obs, tmp_path / "r.LBL")), as_msl)
        assert_same(read_observation(write_pds4_label(obs, tmp_path / "r.xml")), as_m2020)


@pytest.mark.parametrize("model", ["CAHV", "CAHVORE"])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("bands", [1, 3])
def test_attached_label_img_round_trip(tmp_path: Path, model: str, dtype: type, bands: int) -> None:
    """write_pds3_img: the label at the start of the IMG reads back; pdr reads the pixels."""
    import pdr

    full = _synthetic(model, True)
    # a 40 x 24 crop of the frame: the label's field of view is the crop's (a plausible model)
    assert full.hfov_deg is not None and full.vfov_deg is not None
    obs = replace(
        full,
        width=40,
        height=24,
        hfov_deg=full.hfov_deg * 40 / full.width,
        vfov_deg=full.vfov_deg * 24 / full.height,
    )
    rng = np.random.default_rng(1)
    shape = (24, 40) if bands == 1 else (24, 40, 3)
    pixels = rng.integers(0, np.iinfo(dtype).max, size=shape).astype(dtype)
    path = write_pds3_img(obs, tmp_path / "product.IMG", pixels, style="mipl")
    got = read_observation(path)
    assert_same(got, obs)
    assert got.image_path == path
    arr = np.asarray(pdr.read(str(path))["IMAGE"])
    expected = pixels if bands == 1 else np.moveaxis(pixels, -1, 0)
    np.testing.assert_array_equal(arr, expected)


def test_writer_rejects_non_finite(tmp_path: Path) -> None:
    obs = replace(_synthetic("CAHV", True), azimuth_deg=float("nan"))
    with pytest.raises(ValueError):
        write_pds3_label(obs, tmp_path / "bad.LBL")
