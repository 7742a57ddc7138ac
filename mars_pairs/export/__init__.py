"""Exports of a built dataset for GIS tools: a GeoPackage of rover positions, footprints and
camera wedges, and every sample's chips as georeferenced GeoTIFFs (:mod:`.qgis`)."""

from mars_pairs.export.qgis import chips_folder, export_chips, export_geopackage, viewsheds_folder

__all__ = ["chips_folder", "export_chips", "export_geopackage", "viewsheds_folder"]
