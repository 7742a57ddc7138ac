"""Orbital rasters are read by window: an 8192 x 8192 DEM builds under 1 GB peak RSS."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.windows import Window

from support.configs import config_file
from support.missions import MissionCache

#: builds, subprocesses or servers: more than ~3 s a test (`make test-fast` skips them)
pytestmark = pytest.mark.slow

BIG = 8192


def _embed(src_path: Path, dst_path: Path, size: int) -> None:
    """Write a size x size copy of ``src_path``'s grid with the source in the middle.

    Written block by block (tiled, compressed), so making it never holds the whole raster.
    """
    with rasterio.open(src_path) as src:
        profile = src.profile.copy()
        off = (size - src.width) // 2
        t = src.transform
        profile.update(
            width=size,
            height=size,
            tiled=True,
            blockxsize=512,
            blockysize=512,
            compress="deflate",
            transform=rasterio.Affine(t.a, t.b, t.c - off * t.a, t.d, t.e, t.f - off * t.e),
        )
        fill = np.float32(np.nanmedian(src.read(1, masked=True).filled(np.nan)))
        with rasterio.open(dst_path, "w", **profile) as dst:
            block = np.full((512, 512), fill, dtype=src.dtypes[0])
            for r in range(0, size, 512):
                for c in range(0, size, 512):
                    dst.write(block, 1, window=Window(c, r, 512, 512))
            dst.write(src.read(1), 1, window=Window(off, off, src.width, src.height))


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc")
def test_an_8192_dem_builds_under_one_gigabyte(missions: MissionCache, tmp_path: Path) -> None:
    mission = missions(seed=2, stops=2, images_per_stop=2)
    dem = tmp_path / "dem8k.tif"
    _embed(mission / "orbital" / "dem.tif", dem, BIG)
    config = config_file(
        tmp_path / "c.yaml", mission, tmp_path / "ds", inputs={"dem": str(dem)},
        geometry={"radius": 1000, "ray_stride": 8}, chips={"size_m": 256, "size_px": 512},
        output={"shard_size": 2}, splits=None,
    )  # fmt: skip
    # The build runs in one process (one worker) and reports its own peak resident set:
    # VmHWM, which starts afresh at exec (ru_maxrss would carry over the forked parent's). A
    # first, unmeasured run compiles the numba kernels into their on-disk cache: compiling
    # takes ~600 MB on a fresh machine, and that is not what this test measures.
    script = (
        "import sys\n"
        "from mars_pairs.cli.main import main\n"
        "code = main(['build', '--config', sys.argv[1], '--quiet', *sys.argv[2:]])\n"
        "status = open('/proc/self/status').read()\n"
        "print('PEAK_KIB', status.split('VmHWM:')[1].split()[0])\n"
        "sys.exit(code)\n"
    )
    command = [sys.executable, "-c", script, str(config)]
    warm = subprocess.run(
        [*command, "--limit", "1", "--out", str(tmp_path / "warm")],
        capture_output=True,
        text=True,
        check=False,
    )
    assert warm.returncode == 0, warm.stderr
    proc = subprocess.run(command, capture_output=True, text=True, check=False)
    assert proc.returncode == 0, proc.stderr
    assert "samples: 4" in proc.stdout and "failures: 0" in proc.stdout
    peak_kib = int(proc.stdout.split("PEAK_KIB")[1].split()[0])
    print(f"peak RSS of the build: {peak_kib / 1024:.0f} MiB")
    assert peak_kib < 1024 * 1024, f"peak RSS {peak_kib / 1024:.0f} MiB"
    with rasterio.open(dem) as src:  # the DEM alone would take 256 MiB as float32
        assert src.width == BIG and src.height == BIG
