"""The report page of a footprint catalogue folder (``mars-pairs report CATALOG``): the map of
footprints and pairs (``viz.catalog_map``) coloured by sol and by instrument, the images per
instrument, the pairs with the highest IoU, the failures and catalog.json. Every image is
inline (base64 PNG): no external URL, no script."""

from __future__ import annotations

import io
import json
from collections import Counter
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq

from mars_pairs.errors import DatasetError
from mars_pairs.report.markup import (
    CSS,
    esc,
    failures_section,
    fmt,
    img_html,
    read_failures,
    span,
    table_html,
)
from mars_pairs.viz.catalog_map import catalog_figure

TOP_PAIRS = 25  # pairs listed on the page, highest IoU first


def _png(fig: Any, dpi: int) -> bytes:
    from mars_pairs.viz.common import pyplot

    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=dpi)
    finally:
        pyplot().close(fig)
    return buf.getvalue()


def catalog_report_html(root: str | Path, dpi: int) -> str:
    """The page of catalogue ``root``, figures at ``dpi`` dots per inch."""
    root = Path(root)
    path = root / "catalog.parquet"
    try:
        cat = pq.read_table(path, columns=["key", "instrument", "sol", "visible_area_m2"])
    except (OSError, ValueError) as exc:
        raise DatasetError(path, None, f"unreadable Parquet: {exc}") from None
    try:
        doc = json.loads((root / "catalog.json").read_text())
    except (OSError, ValueError):
        doc = {}
    failures = read_failures(root)
    sols = [int(s) for s in cat["sol"].to_pylist() if s is not None]
    title = f"mars-pairs footprint catalogue {root}"
    n_failed = failures.num_rows if failures is not None else 0
    sub = f"{cat.num_rows} images, {n_failed} failures, sols {span(sols)}"
    maps = "".join(
        img_html(_png(catalog_figure(root, colour_by=by), dpi), f"footprints coloured by {by}")
        for by in ("sol", "instrument")
    ) if cat.num_rows else '<p class="sub">no images: nothing to draw</p>'  # fmt: skip
    counts = Counter(cat["instrument"].to_pylist())
    by_instrument = table_html(
        ["instrument", "images"], [[esc(k), v] for k, v in sorted(counts.items())], numeric={1}
    )
    body = [
        f'<h1>{esc(title)}</h1><p class="sub">{esc(sub)}</p>',
        '<section id="map"><h2>Map</h2><p class="sub">visible footprints over the orthoimage, '
        "pairs of images that saw the same ground as lines between the camera centres; map "
        f"coordinates of {esc(doc.get('crs_name', ''))}</p>{maps}</section>",
        f'<section id="instruments"><h2>Images</h2>{by_instrument}</section>',
        _pairs_section(root),
        failures_section(failures),
        '<section id="provenance"><h2>Provenance</h2><p class="sub">catalog.json</p>'
        f"<pre>{esc(json.dumps(doc, indent=2))}</pre></section>",
    ]
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{esc(title)}</title>"
        '<meta name="viewport" content="width=device-width,initial-scale=1">'
        f"<style>{CSS}</style></head><body><main>{''.join(body)}</main></body></html>\n"
    )


def _pairs_section(root: Path) -> str:
    head = '<section id="pairs"><h2>Pairs</h2>'
    path = root / "pairs.parquet"
    if not path.is_file():
        return head + '<p class="sub">no pairs.parquet (made without pairs)</p></section>'
    pairs = pq.read_table(path)
    top = pairs.sort_by([("iou", "descending"), ("key_a", "ascending")]).slice(0, TOP_PAIRS)
    rows = [
        [esc(r["key_a"]), esc(r["key_b"]), fmt(r["iou"], ".3f"),
         fmt(r["intersection_m2"], ".0f"), fmt(r["distance_m"], ".1f"),
         fmt(r["heading_diff_deg"], ".0f"), "yes" if r["same_position"] else "no"]
        for r in top.to_pylist()
    ]  # fmt: skip
    same = sum(bool(v) for v in pairs["same_position"].to_pylist())
    return (
        f'{head}<p class="sub">{pairs.num_rows} pairs of images whose footprints overlap '
        f"({same} from one rover position); the {len(rows)} with the highest IoU</p>"
        + table_html(
            ["image a", "image b", "IoU", "overlap m²", "apart m", "heading Δ°", "one position"],
            rows,
            numeric={2, 3, 4, 5},
        )
        + "</section>"
    )
