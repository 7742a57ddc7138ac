"""PLACES-style orbital maps (VICAR, VICAR + PDS4 label, PDS4) read and cut like GeoTIFFs;
windows mosaicked in a VRT the build opens; ``fetch orbital --dry-run`` writes nothing."""

from __future__ import annotations

import math
import multiprocessing
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import rasterio
import yaml
from affine import Affine
from pyproj import CRS

from mars_pairs.cli.main import main
from mars_pairs.errors import FetchError
from mars_pairs.fetch.config import load_fetch_config
from mars_pairs.fetch.orbital import cut_planned, source_info, write_vrt
from mars_pairs.fetch.run import fetch_orbital, plan_orbital
from mars_pairs.fetch.windows import plan_windows
from mars_pairs.geometry.places import M2020_PLACES_CRS, MSL_PLACES_CRS
from mars_pairs.raster.terrain import Terrain
from support.fetch_server import ArchiveServer

R = 3_396_190.0
X0, Y0 = 4_354_000.0, 1_093_700.0  # upper left of the synthetic maps (Jezero, PLACES CRS)
DEM_TR = Affine(1.0, 0, X0, 0, -1.0, Y0)  # 400 x 400 cells of 1 m
MAP_TR = Affine(0.5, 0, X0, 0, -0.5, Y0)  # 800 x 800 cells of 0.5 m
BUNDLE = "m2020/urn-nasa-pds-mars2020_rover_places"
POSITIONS = [(4354080.0, 1093620.0, 10), (4354085.0, 1093615.0, 11), (4354320.0, 1093380.0, 12)]


def _dem() -> np.ndarray:
    rows, cols = np.mgrid[0:400, 0:400]
    return (-2500.0 + 0.37 * cols - 0.21 * rows + 3 * np.sin(cols / 7.0)).astype(np.float32)


def _write(path: Path, data: np.ndarray, transform, driver: str, georef: bool = True) -> None:
    prof = {
        "driver": driver,
        "width": data.shape[-1],
        "height": data.shape[-2],
        "count": 1,
        "dtype": data.dtype.name,
    }
    if georef:
        prof |= {"crs": M2020_PLACES_CRS, "transform": transform}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.Env(GDAL_PAM_ENABLED="NO"), rasterio.open(path, "w", **prof) as dst:
            dst.write(data, 1)


def _vicar_with_pds4_label(folder: Path, stem: str, data: np.ndarray, transform) -> Path:
    """A VICAR file whose own label has no map projection, and a PDS4 label describing it
    (georeferencing in the label's Cartography, the array after the VICAR label, a Header
    object for the VICAR label), as the Mars 2020 PLACES maps are published."""
    img = folder / f"{stem}.img"
    _write(img, data, transform, "VICAR", georef=False)
    lblsize = int(re.match(rb"LBLSIZE=\s*(\d+)", img.read_bytes()[:40]).group(1))
    tmp = folder / "pds4tmp"
    tmp.mkdir()
    _write(tmp / f"{stem}.xml", data, transform, "PDS4")
    label = (tmp / f"{stem}.xml").read_text()
    shutil.rmtree(tmp)
    header = (
        "<Header><local_identifier>vicar_label</local_identifier>"
        '<offset unit="byte">0</offset>'
        f'<object_length unit="byte">{lblsize}</object_length>'
        "<parsing_standard_id>VICAR2</parsing_standard_id></Header>\n    "
    )
    label, n = re.subn(
        r'(<Array_3D_Image>\s*<local_identifier>image</local_identifier>\s*)<offset unit="byte">0',
        lambda m: m.group(1) + f'<offset unit="byte">{lblsize}',
        label,
    )
    assert n == 1
    label = label.replace("<Array_3D_Image>", header + "<Array_3D_Image>", 1)
    (folder / f"{stem}.xml").write_text(label)
    return img


@pytest.fixture(scope="module")
def maps(tmp_path_factory) -> dict[str, Path]:
    """The same DEM and map as GeoTIFF, VICAR (own map label), VICAR + PDS4 label, PDS4."""
    root = tmp_path_factory.mktemp("maps")
    dem = _dem()
    ortho = (np.add.outer(np.arange(800), 3 * np.arange(800)) % 251).astype(np.uint8)
    out = {}
    for kind, data, tr in (("dem", dem, DEM_TR), ("map", ortho, MAP_TR)):
        (root / "tif").mkdir(exist_ok=True)
        out[f"tif_{kind}"] = root / "tif" / f"{kind}.tif"
        _write(out[f"tif_{kind}"], data, tr, "GTiff")
        for variant in ("vicar", "vicar_pds4", "pds4"):
            (root / variant).mkdir(exist_ok=True)
        out[f"vicar_{kind}"] = root / "vicar" / f"m20_orbital_{kind}.img"
        _write(out[f"vicar_{kind}"], data, tr, "VICAR")
        folder = root / "vicar_pds4" / BUNDLE / "data_maps"
        folder.mkdir(parents=True, exist_ok=True)
        out[f"vicar_pds4_{kind}"] = _vicar_with_pds4_label(folder, f"m20_orbital_{kind}", data, tr)
        out[f"pds4_{kind}"] = root / "pds4" / f"m20_orbital_{kind}.xml"
        _write(out[f"pds4_{kind}"], data, tr, "PDS4")
    return out


def _serve(root: str, requests, replies) -> None:  # type: ignore[no-untyped-def]
    with ArchiveServer(Path(root)) as srv:
        replies.put(srv.url)
        while (ask := requests.get()) is not None:
            if ask == "reset":
                srv.reset_log()
                replies.put(None)
            elif ask == "log":
                replies.put([e.path for e in srv.log])
            else:
                replies.put(srv.bytes_sent(ask))


class OtherProcessServer:
    """The loopback archive server in a child process: GDAL may hold the GIL while it reads
    a raw (PDS4/VICAR) raster over HTTP, so a server thread of the same process would hang."""

    def __init__(self, root: Path) -> None:
        ctx = multiprocessing.get_context("fork")
        self._ask, self._reply = ctx.Queue(), ctx.Queue()
        self._proc = ctx.Process(target=_serve, args=(str(root), self._ask, self._reply))

    def __enter__(self) -> OtherProcessServer:
        self._proc.start()
        self.url = self._reply.get(timeout=20)
        return self

    def _call(self, ask: str):  # type: ignore[no-untyped-def]
        self._ask.put(ask)
        return self._reply.get(timeout=20)

    def bytes_sent(self, rel: str) -> int:
        return self._call(rel)

    def paths(self) -> list[str]:
        return self._call("log")

    def reset_log(self) -> None:
        self._call("reset")

    def __exit__(self, *exc: object) -> None:
        self._ask.put(None)
        self._proc.join(timeout=10)
        if self._proc.is_alive():
            self._proc.kill()


def _xy():
    return np.array([p[0] for p in POSITIONS]), np.array([p[1] for p in POSITIONS])


def _same_crs(wkt: str) -> bool:
    return CRS.from_user_input(wkt).equals(CRS.from_user_input(M2020_PLACES_CRS))


@pytest.mark.parametrize("variant", ["vicar", "vicar_pds4", "pds4"])
def test_planetary_formats_are_read_and_cut_like_the_geotiff(maps, variant, tmp_path):
    for kind, tr in (("dem", DEM_TR), ("map", MAP_TR)):
        info = source_info(str(maps[f"{variant}_{kind}"]))
        if variant == "vicar_pds4":  # the .img was named; its PDS4 label was opened
            assert info.opened.endswith(f"m20_orbital_{kind}.xml") and info.driver == "PDS4"
        assert info.grid.transform.almost_equals(tr) and (info.width, info.height) == (
            (400, 400) if kind == "dem" else (800, 800)
        )
        assert _same_crs(info.crs), info.crs
        x, y = _xy()
        plan = plan_windows(x, y, M2020_PLACES_CRS, info.grid, 30.0, kind=kind, source="s")
        assert len(plan.windows) == 2
        with rasterio.open(maps[f"tif_{kind}"]) as ref:
            for i, win in enumerate(plan.windows):
                res = cut_planned(win, info, tmp_path / f"{variant}-{kind}-{i}.tif")
                window = rasterio.windows.Window(win.col_off, win.row_off, win.width, win.height)
                with rasterio.open(res.path) as got:
                    assert np.array_equal(got.read(1), ref.read(1, window=window))
                    assert got.transform.almost_equals(ref.window_transform(window))
                    assert _same_crs(got.crs.to_wkt())
                    assert got.tags(ns="IMAGE_STRUCTURE")["LAYOUT"] == "COG"


def test_a_remote_img_is_read_through_its_pds4_label(maps, tmp_path):
    root = maps["vicar_pds4_dem"].parents[3]
    with OtherProcessServer(root) as srv:
        url = f"{srv.url}/{BUNDLE}/data_maps/m20_orbital_dem.img"
        info = source_info(url)
        assert info.opened == url[: -len(".img")] + ".xml" and info.driver == "PDS4"
        x, y = _xy()
        (win, _) = plan_windows(
            x, y, M2020_PLACES_CRS, info.grid, 30.0, kind="dem", source=url
        ).windows
        res = cut_planned(win, info, tmp_path / "remote.tif")
        moved = srv.bytes_sent(f"{BUNDLE}/data_maps/m20_orbital_dem.img")
        assert 0 < moved < maps["vicar_pds4_dem"].stat().st_size  # range reads, not the file
    window = rasterio.windows.Window(win.col_off, win.row_off, win.width, win.height)
    with rasterio.open(maps["tif_dem"]) as ref, rasterio.open(res.path) as got:
        assert np.array_equal(got.read(1), ref.read(1, window=window))


def test_an_img_without_georeferencing_or_label_names_what_was_tried(tmp_path):
    img = tmp_path / "bare.img"
    _write(img, _dem(), DEM_TR, "VICAR", georef=False)
    with pytest.raises(FetchError, match=r"bare\.xml.*bare\.lbl.*bare\.img: opened \(VICAR\)"):
        source_info(str(img))


def test_windows_mosaic_in_a_vrt_the_terrain_reads(maps, tmp_path):
    info = source_info(str(maps["vicar_pds4_dem"]))
    x, y = _xy()
    plan = plan_windows(x, y, M2020_PLACES_CRS, info.grid, 30.0, kind="dem", source="s")
    files = [tmp_path / f"dem-{i:03d}.tif" for i in range(len(plan.windows))]
    for win, f in zip(plan.windows, files, strict=True):
        cut_planned(win, info, f)
    vrt = write_vrt(tmp_path / "dem.vrt", info, list(plan.windows), files)
    ref = _dem()
    with Terrain.open(vrt) as t:
        for px, py, _ in POSITIONS:
            w = t.read_dem_window(px, py, 25.0)
            c0, r0 = ~DEM_TR * (w.transform.c, w.transform.f)
            h, wd = w.shape
            assert np.array_equal(
                w.data, ref[round(r0) : round(r0) + h, round(c0) : round(c0) + wd]
            )
        # between the two windows: no data (NaN), not zeros
        gap = t.read_dem_window(4354200.0, 1093500.0, 2.0, check_observer=False)
        assert np.isnan(gap.data).all()


def _places_csv(path: Path) -> None:
    """A best_interp.csv-like table: ROVER rows at POSITIONS (longitude from the PLACES CRS)."""
    lines = ["frame,site,drive,easting,northing,longitude,elevation,sol"]
    for x, y, sol in POSITIONS:
        lon = math.degrees(x / (R * math.cos(math.radians(18.4663))))
        lines.append(f"ROVER,3,{sol * 10},{x},{y},{lon:.9f},-2500.0,{sol}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")


def _config(tmp_path: Path, url: str, **orbital) -> Path:
    doc = {
        "fetch": {
            "cache": "cache",
            "retries": 1,
            "backoff_s": 0.01,
            "timeout_s": 5,
            "places": {"archive": url, "path": f"{BUNDLE}/data_localizations/best_interp.csv"},
            "orbital": {
                "dem": f"{url}/{BUNDLE}/data_maps/m20_orbital_dem.img",
                "ortho": f"{url}/{BUNDLE}/data_maps/m20_orbital_map.img",
                **orbital,
            },
        },
        "geometry": {"radius": 40},
        "chips": {"size_m": 20, "size_px": 64},
    }
    path = tmp_path / "orbital.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_fetch_orbital_dry_run_prints_windows_and_writes_nothing(maps, tmp_path, capsys):
    root = maps["vicar_pds4_dem"].parents[3]
    _places_csv(root / BUNDLE / "data_localizations" / "best_interp.csv")
    with OtherProcessServer(root) as srv:
        config = _config(tmp_path, srv.url)
        assert main(["fetch", "orbital", "--config", str(config), "--dry-run", "--quiet"]) == 0
        out = capsys.readouterr().out
        assert not (tmp_path / "cache").exists()  # nothing written, PLACES table included
        dem_lines = [ln for ln in out.splitlines() if ln.startswith("dry run:   dem ")]
        ortho_lines = [ln for ln in out.splitlines() if ln.startswith("dry run:   ortho ")]
        assert len(dem_lines) == 2 and len(ortho_lines) == 2, out
        assert all("accepted" in ln and "+lat_ts=18.4663" in ln for ln in dem_lines)
        assert "dry run: 3 rover positions" in out
        # fetch all --dry-run: the PLACES URL and the same windows, still nothing written
        assert main(["fetch", "all", "--config", str(config), "--dry-run", "--quiet"]) == 0
        out = capsys.readouterr().out
        assert f"dry run: {srv.url}/{BUNDLE}/data_localizations/best_interp.csv -> " in out
        assert "not yet in the cache" in out and out.count("accepted") == 4
        assert not (tmp_path / "cache").exists()
        # the same plan, fetched: two windows each, and the VRTs naming them
        assert main(["fetch", "orbital", "--config", str(config), "--quiet"]) == 0
        cache = tmp_path / "cache" / "orbital"
        names = sorted(p.name for p in cache.iterdir())
        assert names == [
            "dem-000.tif",
            "dem-001.tif",
            "dem.source.json",
            "dem.vrt",
            "ortho-000.tif",
            "ortho-001.tif",
            "ortho.source.json",
            "ortho.vrt",
        ]
        # a rerun reads no orbital bytes (windows and source headers cached)
        srv.reset_log()
        cfg = load_fetch_config(config)
        assert all(r.cached for r in fetch_orbital(cfg))
        assert not [p for p in srv.paths() if "data_maps" in p]
        # a tiny limit: the dry run says REJECTED (exit 1), the fetch refuses naming the key
        small = _config(tmp_path, srv.url, max_cells=1000)
        assert main(["fetch", "orbital", "--config", str(small), "--dry-run", "--quiet"]) == 1
        assert "REJECTED: above fetch.orbital.max_cells" in capsys.readouterr().out
        assert main(["fetch", "orbital", "--config", str(small), "--quiet"]) == 2
        assert "fetch.orbital.max_cells" in capsys.readouterr().err
        # another config naming another DEM in the same cache is refused, the windows kept
        vrt_before = (cache / "dem.vrt").read_bytes()
        other = _config(tmp_path, srv.url, dem=f"{srv.url}/{BUNDLE}/data_maps/m20_orbital_map.img")
        assert main(["fetch", "orbital", "--config", str(other), "--quiet"]) == 2
        err = capsys.readouterr().err
        assert "fetch.cache" in err and "holds dem windows of" in err
        assert (cache / "dem.vrt").read_bytes() == vrt_before
    # the VRT holds the source's cells inside every window (the plan, as a dry run reads it)
    with rasterio.open(cache / "dem.vrt") as vrt, rasterio.open(maps["tif_dem"]) as ref:
        assert vrt.crs == ref.crs and vrt.res == ref.res
        for p in plan_orbital(cfg, dry_run=True).plans[0].windows:
            win = rasterio.windows.from_bounds(*p.bounds, transform=vrt.transform)
            src = rasterio.windows.from_bounds(*p.bounds, transform=ref.transform)
            assert np.array_equal(vrt.read(1, window=win), ref.read(1, window=src))


def test_a_pds3_img_is_read_through_its_detached_lbl(tmp_path):
    """Curiosity's MSLPLC_1XXX/DATA/MAPS/msl_orbital_dem.img: raw pixels, a detached PDS3
    label (msl_orbital_dem.lbl, as msl_toolbox reads it) with an IMAGE_MAP_PROJECTION."""
    x0, y0 = 8_141_036.5, -271_512.1  # the real map's upper left (real-archive README)
    data = (np.arange(120 * 100, dtype="<f4").reshape(120, 100) - 4400.0).astype("<f4")
    folder = tmp_path / "MSLPLC_1XXX" / "DATA" / "MAPS"
    folder.mkdir(parents=True)
    data.tofile(folder / "msl_orbital_dem.img")
    # GDAL's PDS driver: upper left x = -(SAMPLE_PROJECTION_OFFSET + 0.5) * MAP_SCALE, y alike
    (folder / "msl_orbital_dem.lbl").write_text(
        "PDS_VERSION_ID = PDS3\nRECORD_TYPE = FIXED_LENGTH\nRECORD_BYTES = 400\n"
        'FILE_RECORDS = 120\n^IMAGE = ("msl_orbital_dem.img", 1)\n'
        "OBJECT = IMAGE_MAP_PROJECTION\n  MAP_PROJECTION_TYPE = EQUIRECTANGULAR\n"
        "  A_AXIS_RADIUS = 3396.19 <KM>\n  B_AXIS_RADIUS = 3396.19 <KM>\n"
        "  C_AXIS_RADIUS = 3396.19 <KM>\n  COORDINATE_SYSTEM_NAME = PLANETOCENTRIC\n"
        "  POSITIVE_LONGITUDE_DIRECTION = EAST\n  CENTER_LATITUDE = 0.0 <DEG>\n"
        "  CENTER_LONGITUDE = 0.0 <DEG>\n  LINE_FIRST_PIXEL = 1\n  LINE_LAST_PIXEL = 120\n"
        "  SAMPLE_FIRST_PIXEL = 1\n  SAMPLE_LAST_PIXEL = 100\n  MAP_SCALE = 1.0 <METERS/PIXEL>\n"
        f"  LINE_PROJECTION_OFFSET = {y0 - 0.5}\n  SAMPLE_PROJECTION_OFFSET = {-x0 - 0.5}\n"
        "END_OBJECT = IMAGE_MAP_PROJECTION\nOBJECT = IMAGE\n  LINES = 120\n  LINE_SAMPLES = 100\n"
        "  SAMPLE_TYPE = PC_REAL\n  SAMPLE_BITS = 32\n  BANDS = 1\n"
        "  BAND_STORAGE_TYPE = BAND_SEQUENTIAL\nEND_OBJECT = IMAGE\nEND\n"
    )
    info = source_info(str(folder / "msl_orbital_dem.img"))
    assert info.opened.endswith("msl_orbital_dem.lbl") and info.driver == "PDS"
    assert info.grid.transform.almost_equals(Affine(1.0, 0, x0, 0, -1.0, y0))
    assert CRS.from_user_input(info.crs).equals(CRS.from_user_input(MSL_PLACES_CRS))
    x, y = np.array([x0 + 50.0]), np.array([y0 - 60.0])
    (win,) = plan_windows(x, y, MSL_PLACES_CRS, info.grid, 20.0, kind="dem", source="s").windows
    res = cut_planned(win, info, tmp_path / "dem.tif")
    with rasterio.open(res.path) as got:
        r0, c0 = win.row_off, win.col_off
        assert np.array_equal(got.read(1), data[r0 : r0 + win.height, c0 : c0 + win.width])
        assert got.transform.almost_equals(Affine(1.0, 0, x0 + c0, 0, -1.0, y0 - r0))


@pytest.mark.parametrize("variant", ["vicar", "vicar_pds4", "pds4"])
def test_the_build_opens_the_maps_as_they_are(maps, variant):
    """inputs.dem may name a VICAR file or a PDS4 label directly (read window by window)."""
    path = maps[f"{variant}_dem"]
    if variant == "vicar_pds4":
        path = path.with_suffix(".xml")  # the label: the VICAR file's own label has no map
    ref = _dem()
    with Terrain.open(path, ortho=maps[f"{variant}_map"].with_suffix(path.suffix)) as t:
        assert t.transform.almost_equals(DEM_TR) and t.contains(*POSITIONS[0][:2])
        w = t.read_dem_window(*POSITIONS[2][:2], 10.0)
        c0, r0 = ~DEM_TR * (w.transform.c, w.transform.f)
        rows, cols = w.shape
        assert np.array_equal(
            w.data, ref[round(r0) : round(r0) + rows, round(c0) : round(c0) + cols]
        )
