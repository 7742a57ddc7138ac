"""Synthetic Mars missions with exact ground truth: terrain, traverse, labels, rendered images.

``generate_mission(out_dir, seed=..., mission="m2020"|"msl"|"both", ...)`` writes orbital
rasters, a PLACES table, PDS labels with rendered images, and ``truth.parquet``.
"""

from mars_pairs.synth.mission import generate_mission

__all__ = ["generate_mission"]
