"""GDAL's viewshed in a long-lived process, for bench_viewshed.py's in-process anchor.

Run with the Python that has the GDAL bindings (Debian's python3-gdal: ``/usr/bin/python3``);
bench_viewshed.py starts it once and talks to it over its stdin/stdout, one JSON object a line:

    {"dem": "/tmp/x/dem.tif"}                      -> {"ok": true, "gdal": "3.6.2"}
    {"x": .., "y": .., "height": 2, "radius": 2000, "out": "/tmp/x/g.npy" or null}
                                        -> {"ms": 161.2, "cpu_ms": 160.8, "gt": [6 floats]}

The DEM GeoTIFF is copied once into a MEM dataset (not timed); each request times
``gdal.ViewshedGenerate`` alone (wall ``ms``, and ``cpu_ms`` of the worker's process CPU time;
MEM output, curvature coefficient 1, observer at map (x, y) of the DEM's CRS, ``height`` metres
above the ground, ``radius`` map units), so neither process start nor file I/O is counted.
With ``out``, the visible mask (uint8, 1 = visible, on the output's grid, geotransform ``gt``)
is saved there as .npy after the timing.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np
from osgeo import gdal


def main() -> None:
    gdal.UseExceptions()
    band = None
    out_stream = sys.stdout
    for line in sys.stdin:
        req = json.loads(line)
        if "dem" in req:
            src = gdal.Open(req["dem"])
            mem = gdal.GetDriverByName("MEM").CreateCopy("", src)
            band = mem.GetRasterBand(1)
            reply: dict[str, object] = {"ok": True, "gdal": gdal.__version__}
        else:
            assert band is not None, "send the DEM first"
            t, c = time.perf_counter(), time.process_time()
            ds = gdal.ViewshedGenerate(
                band, "MEM", "", [], req["x"], req["y"], req["height"], 0.0,
                255, 0, 0, -1, 1.0, gdal.GVM_Edge, req["radius"],
            )  # fmt: skip
            ms = (time.perf_counter() - t) * 1e3
            cpu_ms = (time.process_time() - c) * 1e3
            if req.get("out"):
                np.save(req["out"], (ds.GetRasterBand(1).ReadAsArray() == 255).astype(np.uint8))
            reply = {"ms": ms, "cpu_ms": cpu_ms, "gt": list(ds.GetGeoTransform())}
            ds = None
        out_stream.write(json.dumps(reply) + "\n")
        out_stream.flush()


if __name__ == "__main__":
    main()
