"""Which Curiosity Mastcam PDS3 volumes hold a sol's products: the shipped sol-range table.

``data/mslmst_volume_sol_ranges.csv`` gives the first and last sol of the products in each
volume ``MSLMST_0001..0024`` (origin in its header: the public MATLAB toolbox
yukiitohand/msl_toolbox). The ranges overlap, so a sol's products lie in every volume whose
range covers it (sol 1429: MSLMST_0014 and MSLMST_0015 by the table; MSLMST_0013 ends at sol
1417). When ``fetch.products.volumes`` is absent, these are the volumes read.

Refreshing the table (when the archive adds volumes): ``ranges_from_archive`` fetches each
volume's ``INDEX/RDRINDEX.LBL`` + ``.TAB`` and takes its first and last sol
(``sol_range_of_index``); ``write_volume_ranges`` writes the rows over the shipped file, their
origin as the ``comment``.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from mars_pairs.errors import FetchError
from mars_pairs.store.atomic import atomic_write_bytes

TABLE = "mslmst_volume_sol_ranges.csv"
HEADER = ("volume_id", "first_sol", "last_sol")


@dataclass(frozen=True)
class VolumeRange:
    """A PDS3 volume and the first and last sol (inclusive) of the products it holds."""

    volume: str
    first_sol: int
    last_sol: int

    def covers(self, first: int, last: int) -> bool:
        """Whether any sol of [first, last] lies in this volume's range."""
        return self.first_sol <= last and first <= self.last_sol


def shipped_table() -> Path:
    """The path of the sol-range table shipped with the package."""
    return Path(str(resources.files("mars_pairs.fetch") / "data" / TABLE))


def load_volume_ranges(path: str | Path | None = None) -> tuple[VolumeRange, ...]:
    """The rows of a sol-range table (``#`` lines are comments), in volume order."""
    path = Path(path) if path is not None else shipped_table()
    try:
        lines = [ln for ln in path.read_text().splitlines() if ln.strip() and ln[0] != "#"]
    except OSError as exc:
        raise FetchError(path, f"cannot read the volume sol-range table: {exc}") from None
    rows = list(csv.reader(lines))
    if not rows or tuple(c.strip() for c in rows[0]) != HEADER:
        raise FetchError(path, f"expected the header {','.join(HEADER)}")
    out = []
    for number, row in enumerate(rows[1:], 2):
        try:
            volume, first, last = (c.strip() for c in row)
            out.append(VolumeRange(volume, int(first), int(last)))
        except ValueError:
            raise FetchError(path, f"row {number}: expected volume,first,last: {row!r}") from None
        if out[-1].first_sol > out[-1].last_sol:
            raise FetchError(path, f"row {number}: first sol after last sol: {row!r}")
    return tuple(sorted(out, key=lambda r: r.volume))


def volumes_for_sols(
    sols: tuple[int, int], ranges: tuple[VolumeRange, ...] | None = None
) -> tuple[str, ...]:
    """Every volume whose sol range meets [first, last] (inclusive), in volume order.

    Raises ``FetchError`` when a sol of the range lies past the table's last sol (its
    products would be in volumes the table does not know: name them in
    ``fetch.products.volumes``)."""
    ranges = load_volume_ranges() if ranges is None else ranges
    first, last = sols
    known = max(r.last_sol for r in ranges)
    if last > known:
        raise FetchError(
            "fetch.products.volumes",
            f"sols [{first}, {last}] reach past sol {known}, the last of the volume table "
            f"{TABLE}: name the volumes",
        )
    return tuple(r.volume for r in ranges if r.covers(first, last))


def sol_range_of_index(table: Any, volume: str) -> VolumeRange:
    """A volume's sol range from its index table (the ``PLANET_DAY_NUMBER`` column, by name)."""
    from mars_pairs.fetch.pds3_index import COLUMNS

    name = next((c for c in COLUMNS["sol"] if c in table.columns), None)
    if name is None:
        raise FetchError(volume, f"the index has no sol column ({', '.join(COLUMNS['sol'])})")
    sols = [int(str(v).strip()) for v in table[name] if str(v).strip().lstrip("-").isdigit()]
    if not sols:
        raise FetchError(volume, f"the index column {name} holds no sol")
    return VolumeRange(volume, min(sols), max(sols))


def ranges_from_archive(
    archive: str, volumes: Iterable[str], dl: Any, index: str = "RDRINDEX"
) -> list[VolumeRange]:
    """Each volume's sol range read from its own index, fetched into ``dl``'s cache as a
    product listing fetches it (``pds3_index.fetch_index``: revalidated, checked).

    ``archive`` is the root URL of the volumes (e.g. ``.../img/data/msl``), ``dl`` a
    ``download.Downloader``; each index is ~75 MB for the real volumes."""
    from mars_pairs.fetch.pds3_index import fetch_index

    return [sol_range_of_index(fetch_index(dl, archive, v, index).table, v) for v in volumes]


def write_volume_ranges(rows: list[VolumeRange], path: str | Path, comment: str = "") -> None:
    """Write a sol-range table atomically; ``comment`` lines are written first with ``# ``."""
    buf = io.StringIO()
    for line in comment.splitlines():
        buf.write(f"# {line}\n".replace("# \n", "#\n"))
    buf.write(",".join(HEADER) + "\n")
    for r in sorted(rows, key=lambda r: r.volume):
        buf.write(f"{r.volume},{r.first_sol},{r.last_sol}\n")
    atomic_write_bytes(Path(path), buf.getvalue().encode())
