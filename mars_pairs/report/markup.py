"""HTML pieces the report pages share (the dataset's page and the catalogue's): the style
sheet, escaping, tables, embedded PNGs, number formatting, and the failures section read from
a folder's ``failures.parquet``."""

from __future__ import annotations

import base64
import html
import io
import math
from collections import Counter
from collections.abc import Set
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from mars_pairs.errors import DatasetError

MAX_FAILURE_ROWS = 500  # failures listed on the page; the rest are counted

CSS = """
body{font:14px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0;
color:#1d1d1f;background:#f4f4f6}
main{max-width:1480px;margin:0 auto;padding:18px 28px 40px}
h1{font-size:24px;margin:8px 0 2px}h2{font-size:19px;margin:28px 0 8px;
border-bottom:2px solid #d0d0d8;padding-bottom:3px}
.sub{color:#555;margin:0 0 10px}
img{max-width:100%;height:auto;display:block;background:#fff}
table{border-collapse:collapse;background:#fff;font-size:13px;margin:6px 0}
th,td{border:1px solid #d6d6de;padding:3px 9px;text-align:left;vertical-align:top}
th{background:#ebebf0}td.n{text-align:right;font-variant-numeric:tabular-nums}
.row{display:flex;gap:28px;flex-wrap:wrap;align-items:flex-start}
.gallery{display:grid;grid-template-columns:repeat(auto-fill,minmax(440px,1fr));gap:14px}
figure{margin:0;background:#fff;border:1px solid #d6d6de;padding:6px}
figcaption{font-size:12px;color:#333;margin-top:4px;word-break:break-all}
.swatch{display:inline-block;width:11px;height:11px;border-radius:2px;margin-right:6px;
vertical-align:-1px}
pre{background:#fff;border:1px solid #d6d6de;padding:8px;font-size:12px;overflow:auto;
max-height:480px}
.msg{max-width:720px;word-break:break-word}.empty{color:#2a7a2a;font-weight:600}
"""


def esc(value: Any) -> str:
    return html.escape("" if value is None else str(value))


def img_html(png: bytes, alt: str, cls: str = "") -> str:
    from PIL import Image

    with Image.open(io.BytesIO(png)) as im:
        width, height = im.size
    data = base64.b64encode(png).decode("ascii")
    klass = f' class="{cls}"' if cls else ""
    return (
        f'<img{klass} alt="{esc(alt)}" width="{width}" height="{height}" '
        f'src="data:image/png;base64,{data}">'
    )


def table_html(header: list[str], rows: list[list[Any]], numeric: Set[int] = frozenset()) -> str:
    head = "".join(f"<th>{esc(h)}</th>" for h in header)
    body = "".join(
        "<tr>"
        + "".join(
            f'<td class="n">{esc(v)}</td>' if i in numeric else f"<td>{v}</td>"
            for i, v in enumerate(row)
        )
        + "</tr>"
        for row in rows
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def fmt(value: Any, spec: str = "") -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return format(value, spec)


def span(values: list[int]) -> str:
    """'a–b' of the smallest and largest value ('a' when they are equal, '–' for none)."""
    if not values:
        return "–"
    lo, hi = min(values), max(values)
    return f"{lo}" if lo == hi else f"{lo}–{hi}"


# -- reading ------------------------------------------------------------------------------------


def read_failures(root: Path) -> pa.Table | None:
    path = root / "failures.parquet"
    if not path.is_file():
        return None
    try:
        return pq.read_table(path)
    except (pa.ArrowException, OSError) as exc:
        raise DatasetError(path, None, f"unreadable Parquet: {exc}") from None


# -- sections -----------------------------------------------------------------------------------


def _file_name(path: Any) -> str:
    return Path(str(path)).name if path else ""


def failures_section(failures: pa.Table | None) -> str:
    head = '<section id="failures"><h2>Failures</h2>'
    if failures is None:
        return head + '<p class="sub">no failures.parquet in the dataset folder</p></section>'
    if failures.num_rows == 0:
        return head + '<p class="empty">no failures: every product became a sample</p></section>'
    rows = failures.to_pylist()
    reasons = Counter((r.get("stage"), r.get("error_type")) for r in rows)
    by_reason = table_html(
        ["stage", "error", "products"],
        [[esc(s), esc(e), n] for (s, e), n in reasons.most_common()],
        numeric={2},
    )
    listed = [
        [
            esc(r.get("product_id")),
            esc(r.get("stage")),
            esc(r.get("error_type")),
            f'<div class="msg">{esc(r.get("message"))}</div>',
            f'<span title="{esc(r.get("path"))}">{esc(_file_name(r.get("path")))}</span>',
        ]
        for r in rows[:MAX_FAILURE_ROWS]
    ]
    more = len(rows) - len(listed)
    note = f'<p class="sub">{more} more in failures.parquet</p>' if more > 0 else ""
    return (
        f'{head}<p class="sub">{len(rows)} products failed (failures.parquet)</p>{by_reason}'
        f"{table_html(['product', 'stage', 'error', 'message', 'file'], listed)}{note}</section>"
    )
