"""``mars-pairs export-qgis``: a GeoPackage of rover positions, footprints and camera wedges."""

from __future__ import annotations

import io
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import shapely
from PIL import Image

from mars_pairs.errors import DatasetError, MarsPairsError
from mars_pairs.store.manifest import SUMMARY_COLUMNS, Manifest
from mars_pairs.store.shards import MemberLocation, read_member

ATTRIBUTES = SUMMARY_COLUMNS


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


def export_geopackage(root: str | Path, out: str | Path, with_viewsheds: bool = False) -> Path:
    """Write ``out`` (.gpkg) with layers rover_positions, footprints, camera_wedges.

    Geometries are in the dataset CRS; attributes come from the manifest. With
    ``with_viewsheds``, each sample's viewshed chip is written as ``KEY_viewshed.tif`` in the
    folder ``viewsheds_folder(out)`` beside it.
    """
    from pyogrio.raw import write_arrow

    root, out = Path(root), Path(out)
    if out.suffix.lower() != ".gpkg":
        raise MarsPairsError(f"{out}: the output must be a .gpkg file")
    if not root.is_dir():
        raise MarsPairsError(f"{root}: no such dataset folder")
    rows = Manifest.open(root).require().to_table().to_pylist()
    if not rows:
        raise MarsPairsError(f"{root}: the dataset has no samples")
    crs = _dataset_crs(root)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}.gpkg")
    tmp.unlink(missing_ok=True)
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
    os.replace(tmp, out)
    if with_viewsheds:
        _write_viewsheds(root, rows, viewsheds_folder(out), crs)
    return out


def _dataset_crs(root: Path) -> str:
    """The dataset CRS from dataset.json; DatasetError when it is missing or damaged."""
    path = root / "dataset.json"
    try:
        crs = json.loads(path.read_bytes())["crs"]
    except FileNotFoundError:
        raise DatasetError(path, None, "no such file") from None
    except (ValueError, KeyError, TypeError) as exc:
        raise DatasetError(path, "crs", f"unreadable: {exc!r}") from None
    if not isinstance(crs, str):
        raise DatasetError(path, "crs", f"expected CRS text, got {type(crs).__name__}")
    return crs


def viewsheds_folder(out: str | Path) -> Path:
    """The folder of the viewshed GeoTIFFs written beside ``out`` (``NAME_viewsheds``)."""
    out = Path(out)
    return out.with_name(f"{out.stem}_viewsheds")


def _write_viewsheds(root: Path, rows: list[dict[str, Any]], folder: Path, crs: str) -> None:
    from affine import Affine

    from mars_pairs.raster.viewshed_tiff import write_viewshed_geotiff

    folder.mkdir(parents=True, exist_ok=True)
    for row in rows:
        meta = json.loads(
            read_member(
                root, MemberLocation(row["meta_shard"], row["meta_offset"], row["meta_size"])
            )
        )
        png = read_member(
            root,
            MemberLocation(row["viewshed_shard"], row["viewshed_offset"], row["viewshed_size"]),
        )
        visible = (np.asarray(Image.open(io.BytesIO(png))) > 0).astype(np.uint8)
        path = folder / f"{row['key']}_viewshed.tif"
        write_viewshed_geotiff(path, visible, Affine(*meta["chip_transform"]), crs)
