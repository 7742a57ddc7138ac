"""``mars-pairs export-qgis``: a GeoPackage of rover positions, footprints and camera wedges;
with ``--chips``, every sample's chips (ortho, DEM, viewshed) as georeferenced GeoTIFFs."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import shapely
from PIL import Image

from mars_pairs.errors import MarsPairsError
from mars_pairs.store.atomic import atomic_path
from mars_pairs.store.beside import beside, outside
from mars_pairs.store.dataset_info import dataset_crs
from mars_pairs.store.dem_codec import dem_chip
from mars_pairs.store.manifest import SUMMARY_COLUMNS
from mars_pairs.store.query import Manifest
from mars_pairs.store.shards import MemberLocation, read_members

ATTRIBUTES = SUMMARY_COLUMNS
QGIS_SUFFIX = "qgis.gpkg"  # the default GeoPackage: <dataset>-qgis.gpkg beside the folder


def camera_wedge(row: dict[str, Any], segments: int = 24) -> shapely.Polygon:
    """The camera's azimuth wedge (map CRS) from the rover out to the farthest visible range."""
    rng = max(float(row["max_visible_range_m"] or 0.0), 1.0)
    az = np.radians(
        np.linspace(
            row["azimuth_deg"] - row["hfov_deg"] / 2,
            row["azimuth_deg"] + row["hfov_deg"] / 2,
            segments,
        )
    )
    x0, y0 = row["easting"], row["northing"]
    ring = [(x0, y0), *zip(x0 + rng * np.sin(az), y0 + rng * np.cos(az), strict=True), (x0, y0)]
    return shapely.Polygon(ring)


def _layer(rows: list[dict[str, Any]], geometries: list[Any]) -> pa.Table:
    columns = {name: [r[name] for r in rows] for name in ATTRIBUTES}
    table = pa.table(columns)
    return table.append_column("geometry", pa.array(shapely.to_wkb(geometries), pa.binary()))


def export_geopackage(
    root: str | Path,
    out: str | Path | None = None,
    with_viewsheds: bool = False,
    with_chips: bool = False,
) -> Path:
    """Write ``out`` (.gpkg; default ``<root>-qgis.gpkg`` beside the dataset folder:
    ``store.beside``; a path inside the folder is refused) with layers rover_positions,
    footprints, camera_wedges (of a footprint catalogue folder: ``catalog_qgis``, with its
    pairs).

    Geometries are in the dataset CRS; attributes come from the manifest. With
    ``with_viewsheds``, each sample's viewshed chip is written as ``KEY_viewshed.tif`` in the
    folder ``viewsheds_folder(out)`` beside it; with ``with_chips``, its ortho, DEM and
    viewshed chips as ``KEY_ortho.tif``, ``KEY_dem.tif``, ``KEY_viewshed.tif`` in
    ``chips_folder(out)`` (``export_chips``).
    """
    from pyogrio.raw import write_arrow

    root = Path(root)
    out = beside(root, QGIS_SUFFIX) if out is None else outside(root, out, QGIS_SUFFIX)
    if out.suffix.lower() != ".gpkg":
        raise MarsPairsError(f"{out}: the output must be a .gpkg file")
    if not root.is_dir():
        raise MarsPairsError(f"{root}: no such dataset folder")
    if (root / "catalog.parquet").is_file() and not (root / "manifest.parquet").exists():
        if with_viewsheds or with_chips:
            raise MarsPairsError(f"{root}: a footprint catalogue has no chips or viewsheds")
        from mars_pairs.export.catalog_qgis import export_catalog_geopackage

        return export_catalog_geopackage(root, out)
    rows = Manifest.open(root).require().to_table().to_pylist()
    if not rows:
        raise MarsPairsError(f"{root}: the dataset has no samples")
    crs = dataset_crs(root)
    out.parent.mkdir(parents=True, exist_ok=True)
    with_foot = [r for r in rows if r["footprint"] is not None]
    layers = [
        (
            "rover_positions",
            rows,
            shapely.points([(r["easting"], r["northing"]) for r in rows]),
            "Point",
        ),
        ("footprints", with_foot, [shapely.from_wkb(r["footprint"]) for r in with_foot], "Polygon"),
        ("camera_wedges", rows, [camera_wedge(r) for r in rows], "Polygon"),
    ]
    with atomic_path(out, suffix=".gpkg") as tmp:  # the GPKG driver goes by the extension
        tmp.unlink(missing_ok=True)
        for i, (name, layer_rows, geoms, kind) in enumerate(layers):
            write_arrow(
                _layer(layer_rows, list(geoms)),
                tmp,
                layer=name,
                driver="GPKG",
                geometry_name="geometry",
                geometry_type=kind,
                crs=crs,
                append=i > 0,
            )
    if with_viewsheds:
        _write_viewsheds(root, rows, viewsheds_folder(out), crs)
    if with_chips:
        export_chips(root, chips_folder(out), rows, crs)
    return out


def viewsheds_folder(out: str | Path) -> Path:
    """The folder of the viewshed GeoTIFFs written beside ``out`` (``NAME_viewsheds``)."""
    out = Path(out)
    return out.with_name(f"{out.stem}_viewsheds")


def chips_folder(out: str | Path) -> Path:
    """The folder of the chip GeoTIFFs written beside ``out`` (``NAME_chips``)."""
    out = Path(out)
    return out.with_name(f"{out.stem}_chips")


def _members(root: Path, row: dict[str, Any], names: tuple[str, ...]) -> dict[str, bytes]:
    """The bytes of the manifest row's members ``names`` (errors name ``<key>.<name>``)."""
    locations = {
        n: MemberLocation(row[f"{n}_shard"], row[f"{n}_offset"], row[f"{n}_size"]) for n in names
    }
    return read_members(root, locations, key=row["key"])


def export_chips(
    root: str | Path,
    folder: str | Path,
    rows: list[dict[str, Any]] | None = None,
    crs: str | None = None,
) -> list[Path]:
    """Write each sample's chips as GeoTIFFs in ``folder``: ``KEY_ortho.tif`` (uint8, the
    ortho member's values), ``KEY_dem.tif`` (float32 metres, NaN no data) and
    ``KEY_viewshed.tif`` (1 visible, 0 hidden, colour table), on the chip grid of meta.json's
    ``chip_transform`` (affine: chip pixel column, row from the top-left edge -> map x, y;
    rotated for heading-up chips) in the dataset CRS (dataset.json); written atomically.
    ``rows``: the manifest rows (None: every sample). Returns the paths written."""
    from affine import Affine

    from mars_pairs.raster.viewshed_tiff import write_viewshed_geotiff

    root, folder = Path(root), Path(folder)
    if rows is None:
        rows = Manifest.open(root).require().to_table().to_pylist()
    if crs is None:
        crs = dataset_crs(root)
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for row in rows:
        data = _members(root, row, ("meta", "ortho", "dem", "viewshed"))
        meta = json.loads(data["meta"])
        transform = Affine(*meta["chip_transform"])
        ortho = np.asarray(Image.open(io.BytesIO(data["ortho"])))
        if ortho.ndim == 3:
            ortho = ortho[..., 0]
        dem = dem_chip(data["dem"])
        view = np.asarray(Image.open(io.BytesIO(data["viewshed"])))
        key = row["key"]
        for name, array, nodata in (
            ("ortho", ortho.astype(np.uint8), None),
            ("dem", dem.astype(np.float32), float("nan")),
        ):
            path = folder / f"{key}_{name}.tif"
            _write_geotiff(path, array, transform, crs, nodata, f"{name} chip of {key}")
            written.append(path)
        path = folder / f"{key}_viewshed.tif"
        write_viewshed_geotiff(path, (view > 0).astype(np.uint8), transform, crs)
        written.append(path)
    return written


def _write_geotiff(
    path: Path, array: np.ndarray, transform: Any, crs: str, nodata: float | None, what: str
) -> None:
    """One band GeoTIFF of ``array`` on ``transform`` in ``crs``, written atomically."""
    import rasterio

    profile = {
        "driver": "GTiff",
        "width": array.shape[1],
        "height": array.shape[0],
        "count": 1,
        "dtype": array.dtype.name,
        "crs": crs,
        "transform": transform,
        "compress": "deflate",
    }
    if nodata is not None:
        profile["nodata"] = nodata
    with atomic_path(path) as tmp, rasterio.open(tmp, "w", **profile) as dst:
        dst.write(array, 1)
        dst.set_band_description(1, what)


def _write_viewsheds(root: Path, rows: list[dict[str, Any]], folder: Path, crs: str) -> None:
    from affine import Affine

    from mars_pairs.raster.viewshed_tiff import write_viewshed_geotiff

    folder.mkdir(parents=True, exist_ok=True)
    for row in rows:
        data = _members(root, row, ("meta", "viewshed"))
        meta = json.loads(data["meta"])
        png = data["viewshed"]
        visible = (np.asarray(Image.open(io.BytesIO(png))) > 0).astype(np.uint8)
        path = folder / f"{row['key']}_viewshed.tif"
        write_viewshed_geotiff(path, visible, Affine(*meta["chip_transform"]), crs)
