"""``mars-pairs report``: one self-contained HTML page describing a built dataset.

The page holds the map of footprints and traverse over the ortho (held-out areas and buffer
drawn), the counts per split, histograms of the view statistics, a gallery of samples
(ground image and its view on the ortho chip), the failures table and the provenance from
``dataset.json``. Every image is inline (base64 PNG): no external URL, no script.
"""

from __future__ import annotations

import json
from collections import Counter
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from mars_pairs.errors import MarsPairsError, UsageError
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
from mars_pairs.report.meta import camera_centres
from mars_pairs.store.atomic import atomic_write_bytes
from mars_pairs.store.beside import beside, outside
from mars_pairs.store.dataset_info import (
    DatasetInfo,
    dataset_json_path,
    read_dataset_info,
)
from mars_pairs.store.geoparquet import describe_crs
from mars_pairs.store.query import Manifest
from mars_pairs.viz.common import DPI, split_colours
from mars_pairs.viz.report_figures import histograms_figure, map_figure, sample_card

COLUMNS = (
    "key", "mission", "instrument", "product_id", "sol", "site", "drive", "split", "easting",
    "northing", "azimuth_deg", "elevation_deg", "hfov_deg", "max_visible_range_m",
    "viewshed_area_m2", "footprint",
)  # fmt: skip
DEFAULT_SAMPLES = 12
REPORT_SUFFIX = "report.html"  # the default page: <dataset>-report.html beside the folder


def _for_people(key: str, value: Any) -> str:
    """A value of dataset.json's split report as a person reads it: no Python or JSON
    spelling (``True``, ``[]``, ``None``)."""
    if key == "guaranteed" and isinstance(value, bool):
        return (
            "yes: buffer ≥ reach, no extents of two splits can meet"
            if value
            else "no: buffer < reach, extents of two splits may meet (see the leak check)"
        )
    if isinstance(value, bool):
        return "yes" if value else "no"
    if value is None:
        return "–"
    if isinstance(value, dict):
        return ", ".join(f"{k.replace('_', ' ')} {_for_people(k, v)}" for k, v in value.items())
    if isinstance(value, (list, tuple)):
        if key == "warnings" and not value:
            return "none"
        return "; ".join(_for_people(key, v) for v in value) if value else "none"
    return str(value)


def _split_section(rows: list[dict[str, Any]], info: DatasetInfo, n_failed: int) -> str:
    splits = [str(r["split"]) for r in rows]
    colours = split_colours(splits)
    counts = Counter(splits)
    table_rows = []
    for name in sorted(counts, key=lambda s: (-counts[s], s)):
        mine = [r for r in rows if str(r["split"]) == name]
        sols = [int(r["sol"]) for r in mine if r["sol"] is not None]
        stops = {(r["easting"], r["northing"]) for r in mine}
        colour = colours[name]
        table_rows.append(
            [
                f'<span class="swatch" style="background:{colour}"></span>{esc(name)}',
                counts[name],
                f"{100 * counts[name] / len(rows):.1f} %",
                len(stops),
                span(sols),
                esc(", ".join(sorted({str(r["instrument"]) for r in mine}))),
            ]
        )
    table_rows.append(["<b>all</b>", len(rows), "100 %" if rows else "–",
                       len({(r["easting"], r["northing"]) for r in rows}), "", ""])  # fmt: skip
    parts = [
        table_html(
            ["split", "samples", "share", "rover positions", "sols", "instruments"],
            table_rows,
            numeric={1, 2, 3},
        )
    ]
    rep = info.splits
    if rep:
        kv = []
        for key, value in rep.items():
            name = f"{key[:-2]} (m)" if key.endswith("_m") else key
            kv.append([esc(name.replace("_", " ")), esc(_for_people(key, value))])
        parts.append(table_html(["split rule and leak check (dataset.json)", "value"], kv))
    summary = f"{len(rows)} samples, {n_failed} failures"
    return (
        f'<section id="splits"><h2>Samples per split</h2><p class="sub">{esc(summary)}</p>'
        f'<div class="row">{"".join(parts)}</div></section>'
    )


def _gallery_section(root: Path, rows: list[dict[str, Any]], n: int, dpi: int = DPI) -> str:
    from mars_pairs.torch import MarsPairsDataset

    head = '<section id="gallery"><h2>Samples</h2>'
    if not rows or n == 0:
        return head + '<p class="sub">no samples shown</p></section>'
    order = sorted(range(len(rows)), key=lambda i: (rows[i]["sol"] or 0, str(rows[i]["key"])))
    spread = np.linspace(0, len(rows) - 1, min(n, len(rows)))
    picks = sorted({order[round(float(k))] for k in spread})
    centres = camera_centres(root, [str(rows[i]["key"]) for i in picks])  # the wedges' apexes

    cards = []
    with MarsPairsDataset(root, fields=("ground", "ortho", "viewshed"), pad=False) as ds:
        for i in sorted(picks, key=lambda i: order.index(i)):
            r = rows[i]
            centre = centres[str(r["key"])]
            png = sample_card(ds[ds.index_of(str(r["key"]))], camera_center_map=centre, dpi=dpi)
            caption = (
                f"<b>{esc(r['key'])}</b><br>{esc(r['instrument'])}, sol {esc(r['sol'])}, "
                f"split <b>{esc(r['split'])}</b><br>camera az {fmt(r['azimuth_deg'], '.1f')}°, "
                f"el {fmt(r['elevation_deg'], '.1f')}°; farthest visible "
                f"{fmt(r['max_visible_range_m'], '.0f')} m, visible area "
                f"{fmt(r['viewshed_area_m2'], ',.0f')} m²"
            )
            cards.append(
                f"<figure>{img_html(png, 'sample ' + str(r['key']), 'card')}"
                f"<figcaption>{caption}</figcaption></figure>"
            )
    return (
        f'{head}<p class="sub">{len(cards)} of {len(rows)} samples, spread over the sols: the '
        "ground image and its view on the ortho chip (viewshed green, camera wedge orange, "
        f'rover ▲)</p><div class="gallery">{"".join(cards)}</div></section>'
    )


def _provenance_section(root: Path, info: DatasetInfo, crs_name: str) -> str:
    from mars_pairs.version import __version__

    head = '<section id="provenance"><h2>Provenance</h2>'
    if not info.exists:
        return head + '<p class="sub">no dataset.json in the dataset folder</p></section>'
    written = datetime.fromtimestamp(dataset_json_path(root).stat().st_mtime, tz=timezone.utc)
    seconds = info.build_seconds
    facts = [
        ["dataset", esc(root.resolve())],
        ["built (dataset.json written)", esc(written.strftime("%Y-%m-%d %H:%M:%S UTC"))],
        ["build time", esc(f"{seconds:.1f} s" if isinstance(seconds, (int, float)) else "–")],
        ["CRS", esc(crs_name)],
        ["chip", esc(", ".join(f"{k} {v}" for k, v in info.chip.items()))],
    ]
    for key, value in info.counts.items():
        if isinstance(value, dict):
            value = ", ".join(f"{k} {v}" for k, v in value.items())
        facts.append([esc(f"count: {key.replace('_', ' ')}"), esc(value)])
    for key, value in info.failures_by_reason.items():
        facts.append([esc(f"failures: {key}"), esc(value)])
    versions = [[esc(k), esc(v)] for k, v in info.versions.items()]
    generated = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
    versions.append(["report written by", esc(f"mars_pairs {__version__}, {generated}")])
    config = json.dumps(info.config, indent=2)
    return (
        f'{head}<div class="row">{table_html(["build", ""], facts)}'
        f"{table_html(['versions', ''], versions)}</div>"
        f"<h3>Build configuration</h3><pre>{esc(config)}</pre></section>"
    )


# -- the page -----------------------------------------------------------------------------------


def report_html(root: str | Path, samples: int = DEFAULT_SAMPLES, dpi: int = DPI) -> str:
    """The report page of the dataset folder ``root`` with ``samples`` gallery samples, its
    figures drawn at ``dpi`` dots per inch; of a footprint catalogue folder, its map of
    footprints and pairs (``report.catalog_page``)."""
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 0:
        raise UsageError(f"samples: expected a whole number >= 0, got {samples!r}")
    root = Path(root)
    if not root.is_dir():
        raise MarsPairsError(f"{root}: no such dataset folder")
    if (root / "catalog.parquet").is_file() and not (root / "manifest.parquet").exists():
        from mars_pairs.report.catalog_page import catalog_report_html

        return catalog_report_html(root, dpi)
    manifest = Manifest.open(root).require(COLUMNS)
    rows = manifest.to_table(columns=list(COLUMNS)).to_pylist()
    info = read_dataset_info(root, required=False)
    failures = read_failures(root)
    n_failed = failures.num_rows if failures is not None else 0
    crs_name, unit = describe_crs(info.crs or manifest.crs)
    ortho_path = info.build_input(root, "ortho")

    title = f"mars-pairs dataset {root}"
    missions = ", ".join(sorted({str(r["mission"]) for r in rows}))
    sols = [int(r["sol"]) for r in rows if r["sol"] is not None]
    sol_text = f"sols {span(sols)}" if sols else ""
    sub = ", ".join(
        x for x in (f"{len(rows)} samples", f"{n_failed} failures", missions, sol_text) if x
    )
    if rows:
        the_map = img_html(
            map_figure(rows, info, ortho_path, crs_name, unit, dpi=dpi), "map of the footprints"
        )
        hists = img_html(histograms_figure(rows, dpi), "histograms of the view statistics")
    else:
        the_map = hists = '<p class="sub">no samples: nothing to draw</p>'
    body = [
        f'<h1>{esc(title)}</h1><p class="sub">{esc(sub)}</p>',
        f'<section id="map"><h2>Map</h2><p class="sub">rover positions (red ▲) joined in '
        f"(sol, site, drive) order, footprints (the visible area's hull) coloured by split, "
        f"over the orthoimage; map coordinates of {esc(crs_name)}</p>{the_map}</section>",
        _split_section(rows, info, n_failed),
        f'<section id="histograms"><h2>View statistics</h2>{hists}</section>',
        _gallery_section(root, rows, samples, dpi),
        failures_section(failures),
        _provenance_section(root, info, crs_name),
    ]
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{esc(title)}</title>"
        '<meta name="viewport" content="width=device-width,initial-scale=1">'
        f"<style>{CSS}</style></head><body><main>{''.join(body)}</main></body></html>\n"
    )


def write_report(
    root: str | Path,
    out: str | Path | None = None,
    samples: int = DEFAULT_SAMPLES,
    dpi: int = DPI,
) -> Path:
    """Write the report page of dataset ``root`` to ``out`` (default ``<root>-report.html``
    beside the folder: ``store.beside``; a path inside the folder is refused), atomically;
    returns its path."""
    root = Path(root)
    path = outside(root, out, REPORT_SUFFIX) if out is not None else beside(root, REPORT_SUFFIX)
    page = report_html(root, samples, dpi)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, page.encode("utf-8"))
    return path
