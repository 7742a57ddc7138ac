"""``mars-pairs viewshed``: GeoTIFFs from a real Perseverance label and from a raw observer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from pyproj import CRS
from rasterio.enums import ColorInterp

from mars_pairs.cli.main import main
from mars_pairs.geometry.frames import M2020_PLACES_CRS

SAMPLES = Path(__file__).resolve().parents[2].parent / "shared" / "pds-samples"
LABEL = SAMPLES / "m2020" / "ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01.xml"
PLACES = SAMPLES / "m2020" / "best_interp.csv"
# the rover's PLACES position for that label (mars-pairs locate), M2020_PLACES_CRS metres
ROVER_XY = (4354557.816, 1093309.691)


@pytest.fixture(scope="module")
def real_label() -> Path:
    if not LABEL.is_file() or not PLACES.is_file():
        pytest.skip(f"real PDS samples not found at {SAMPLES} (../shared beside the checkout)")
    return LABEL


def write_dem(
    path: Path,
    centre: tuple[float, float],
    z: np.ndarray,
    res: float = 1.0,
    crs: str | None = M2020_PLACES_CRS,
) -> Path:
    """A float32 GeoTIFF of ``z`` centred on ``centre`` (x, y), north-up, ``res`` m cells."""
    rows, cols = z.shape
    x0 = round(centre[0]) - cols * res / 2
    y0 = round(centre[1]) + rows * res / 2
    profile = {
        "driver": "GTiff",
        "width": cols,
        "height": rows,
        "count": 1,
        "dtype": "float32",
        "transform": Affine(res, 0.0, x0, 0.0, -res, y0),
        "nodata": -9999.0,
    }
    if crs is not None:
        profile["crs"] = crs
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(z.astype(np.float32), 1)
    return path


def fractal_slope(n: int, seed: int = 0) -> np.ndarray:
    """A gentle slope rising to the east with a few metres of smooth fractal relief."""
    rng = np.random.default_rng(seed)
    spectrum = np.fft.fft2(rng.normal(size=(n, n)))
    f = np.hypot(*np.meshgrid(np.fft.fftfreq(n), np.fft.fftfreq(n)))
    f[0, 0] = 1.0
    relief = np.real(np.fft.ifft2(spectrum / f**1.8))
    relief = 3.0 * (relief - relief.mean()) / relief.std()
    cols = np.arange(n)[None, :]
    return -2569.0 + 0.02 * (cols - n / 2) + relief


def bearings(src: rasterio.io.DatasetReader, mask: np.ndarray, x: float, y: float) -> np.ndarray:
    rows, cols = np.nonzero(mask)
    xs, ys = src.xy(rows, cols)
    return np.degrees(np.arctan2(np.asarray(xs) - x, np.asarray(ys) - y)) % 360.0


def test_real_label_over_a_generated_dem(real_label: Path, tmp_path: Path) -> None:
    dem = write_dem(tmp_path / "dem.tif", ROVER_XY, fractal_slope(1200))
    out = tmp_path / "out" / "viewshed.tif"
    argv = ["viewshed", "--dem", str(dem), "--out", str(out), "--label", str(real_label)]
    assert main([*argv, "--places", str(PLACES), "--radius", "500"]) == 0
    with rasterio.open(dem) as d:
        dem_crs = CRS.from_user_input(d.crs.to_wkt())
    with rasterio.open(out) as src:
        assert CRS.from_user_input(src.crs.to_wkt()).equals(dem_crs)
        assert src.nodata == 255
        assert src.colorinterp[0] == ColorInterp.palette
        colours = src.colormap(1)
        assert colours[1][:3] == (40, 220, 90)
        codes = src.read(1)
        assert set(np.unique(codes)) <= {0, 1, 255}
        assert (codes == 255).any()  # outside the radius
        visible = codes == 1
        assert visible.sum() > 100
        az = bearings(src, visible, *ROVER_XY)
    # the camera looked west (azimuth 274.3 deg, hFOV 6.4 deg): visible cells lie around it
    # (the camera centre is ~1 m from the rover origin, hence the margin near the rover)
    assert np.all(np.abs((az - 274.3 + 180.0) % 360.0 - 180.0) < 10.0)
    behind = np.abs((az - 94.3 + 180.0) % 360.0 - 180.0) < 90.0
    assert not behind.any()


def test_raw_observer_on_a_flat_dem_gives_the_annular_sector(tmp_path: Path) -> None:
    centre = (1000.5, 2000.5)  # a cell centre
    dem = write_dem(tmp_path / "flat.tif", centre, np.zeros((201, 201)))
    out = tmp_path / "sector.tif"
    h, el_min, el_max, az_min, az_max = 2.0, -20.0, -5.0, 30.0, 90.0
    argv = ["viewshed", "--dem", str(dem), "--out", str(out), "--radius", "60"]
    argv += ["--x", str(centre[0]), "--y", str(centre[1]), "--height", str(h)]
    argv += ["--az-min", str(az_min), "--az-max", str(az_max)]
    argv += ["--el-min", str(el_min), "--el-max", str(el_max)]
    assert main(argv) == 0
    with rasterio.open(out) as src:
        codes = src.read(1)
        rows, cols = np.indices(codes.shape)
        xs, ys = src.xy(rows.ravel(), cols.ravel())
    dx = np.asarray(xs).reshape(codes.shape) - centre[0]
    dy = np.asarray(ys).reshape(codes.shape) - centre[1]
    r = np.hypot(dx, dy)
    az = np.degrees(np.arctan2(dx, dy)) % 360.0
    r_in, r_out = h / np.tan(np.radians(-el_min)), h / np.tan(np.radians(-el_max))
    expected = (r >= r_in) & (r <= r_out) & (az >= az_min) & (az <= az_max)
    # cells whose centre is more than ~a cell from the sector's edges must agree exactly
    edge = (
        (np.abs(r - r_in) < 1.0)
        | (np.abs(r - r_out) < 1.0)
        | (np.minimum(np.abs(az - az_min), np.abs(az - az_max)) * np.pi / 180 * r < 1.0)
    )
    got = codes == 1
    assert expected.sum() > 200  # (60 / 360) * pi * (r_out² - r_in²) ≈ 258 cells
    assert np.array_equal(got[~edge], expected[~edge])
    assert (codes[r > 60.5] == 255).all() and (codes[r < 59.5] != 255).all()


def test_observer_off_the_dem_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    dem = write_dem(tmp_path / "flat.tif", (1000.0, 2000.0), np.zeros((50, 50)))
    argv = ["viewshed", "--dem", str(dem), "--out", str(tmp_path / "v.tif"), "--radius", "30"]
    assert main([*argv, "--x", "5000", "--y", "2000", "--height", "2"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "outside the DEM" in err, err
    assert not (tmp_path / "v.tif").exists()


def test_dem_without_crs_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    dem = write_dem(tmp_path / "nocrs.tif", (1000.0, 2000.0), np.zeros((50, 50)), crs=None)
    argv = ["viewshed", "--dem", str(dem), "--out", str(tmp_path / "v.tif"), "--radius", "30"]
    assert main([*argv, "--x", "1000", "--y", "2000", "--height", "2"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no CRS" in err, err


def test_label_without_places_exits_2(
    real_label: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    dem = write_dem(tmp_path / "dem.tif", ROVER_XY, np.zeros((100, 100)))
    argv = ["viewshed", "--dem", str(dem), "--out", str(tmp_path / "v.tif")]
    assert main([*argv, "--label", str(real_label)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--places" in err, err


def test_label_frustum_mask_is_inside_the_image_and_band_is_the_studys(
    real_label: Path, tmp_path: Path
) -> None:
    """--mask frustum (default) keeps what the image saw; --mask band the study's rectangle.

    Checked with the independent truth (label fields, numpy + pyproj; no mars_pairs code).
    """
    from support import independent_truth as truth

    dem = write_dem(tmp_path / "dem.tif", ROVER_XY, fractal_slope(1200))
    counts, inside = {}, {}
    for mask in ("frustum", "band"):
        out = tmp_path / f"{mask}.tif"
        argv = ["viewshed", "--dem", str(dem), "--out", str(out), "--label", str(real_label)]
        assert main([*argv, "--places", str(PLACES), "--radius", "500", "--mask", mask]) == 0
        with rasterio.open(out) as src:
            rows, cols = np.nonzero(src.read(1) == 1)
            xs, ys = rasterio.transform.xy(src.transform, rows, cols)
        counts[mask] = len(rows)
        inside[mask] = truth.fraction_inside_image(
            real_label, PLACES, dem, np.column_stack([xs, ys]), lo=-0.5
        )
    assert counts["frustum"] > 100
    assert inside["frustum"] >= 0.99, inside
    # the band is the image's az/el rectangle: it holds the image and sees more beside it
    assert counts["band"] > counts["frustum"] and inside["band"] < inside["frustum"], inside
