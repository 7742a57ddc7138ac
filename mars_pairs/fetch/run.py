"""``fetch products / places / orbital``: index -> labels -> images, in parallel, verified.

Products: the index files are fetched first (PDS3 ``INDEX/<index>.LBL`` + ``.TAB`` per volume;
PDS4 collection label + inventory), filtered on what they list, then each product's label is
fetched and read (image file, its size and MD5, site/drive where the index lacks them),
filtered again, and its image fetched. ``workers`` products go at once; a tqdm bar counts
them. A product that fails (404, retries exhausted, bad label, MD5), or an index row that
cannot be read (a path escaping the archive, a VID naming no file), becomes one failure row
in ``<cache>/fetch_failures.parquet`` and one line on stderr naming the URL (and the row);
the rest go on. A product left out on purpose (a filter, a thumbnail, a secondary member, an
older version, another camera) is one row of ``<cache>/fetch_skipped.parquet`` and is counted
by reason in the summary.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path, PurePosixPath

import pyarrow as pa
import pyarrow.parquet as pq
from tqdm import tqdm

from mars_pairs.errors import FetchError, MarsPairsError
from mars_pairs.fetch.cache import Cache, archive_path, join_url
from mars_pairs.fetch.config import FetchConfig, ProductsSpec, RemoteSpec
from mars_pairs.fetch.download import Downloader, RemoteFile
from mars_pairs.fetch.orbital import (
    Positions,
    WindowResult,
    cut_planned,
    rover_positions,
    source_info,
    write_vrt,
)
from mars_pairs.fetch.pds3_index import fetch_index, products_from_index
from mars_pairs.fetch.pds4_inventory import (
    inventory_delimiter,
    inventory_of,
    products_from_inventory,
)
from mars_pairs.fetch.products import (
    Failure,
    Listing,
    Product,
    ProductFilter,
    Skipped,
    newest_only,
    skip_counts,
    with_label_facts,
)
from mars_pairs.fetch.volumes import volumes_for_sols
from mars_pairs.fetch.windows import WindowPlan, dem_reach_m, ortho_reach_m, plan_windows
from mars_pairs.store.atomic import atomic_write_bytes

FAILURES = "fetch_failures.parquet"
SKIPPED = "fetch_skipped.parquet"


@dataclass
class ProductsReport:
    """What a products run found and moved, and what it left out (``skipped``, by reason)."""

    listed: int = 0  # products the index lists that pass the index-level filters
    selected: int = 0  # after the label-level filters
    image_bytes: int = 0  # bytes of the selected products' images (known sizes)
    to_fetch_bytes: int = 0  # of those, not in the cache yet
    downloaded: int = 0  # files downloaded (or resumed) in this run
    cached: int = 0  # files already in the cache
    bytes_received: int = 0
    failures: list[Failure] = field(default_factory=list)
    products: list[Product] = field(default_factory=list)
    skipped: list[Skipped] = field(default_factory=list)

    def format(self, dry_run: bool) -> str:
        """Human summary: one line, then one line per reason products were skipped."""
        tail = f"{len(self.failures)} failures, {len(self.skipped)} skipped"
        if dry_run:
            head = (
                f"dry run: {self.selected} products ({self.listed} listed), "
                f"{self.image_bytes} image bytes, {self.to_fetch_bytes} not yet in the cache; "
                + tail
            )
        else:
            head = (
                f"{self.selected} products ({self.listed} listed): {self.downloaded} files "
                f"downloaded ({self.bytes_received} bytes), {self.cached} already cached, " + tail
            )
        lines = [head] + [f"  skipped {n}: {why}" for why, n in skip_counts(self.skipped)]
        return "\n".join(lines)


# -- listing -------------------------------------------------------------------------------
def list_products(spec: ProductsSpec, dl: Downloader) -> Listing:
    """Fetch the index files and list the products passing the index-level filters.

    msl: the indexes of ``spec.volumes`` (default: every volume whose range in the sol-range
    table meets the filter's sols); one product per id, the newest version then the newest
    volume winning. m2020: the collection's inventory. The products the listing or the
    filters leave out are in ``skipped``, unreadable rows in ``failures``."""
    out = Listing()
    if spec.mission == "msl":
        volumes = spec.volumes
        if not volumes:
            if spec.filters.sols is None:
                raise FetchError("fetch.products.volumes", "no volumes and no sols to choose them")
            volumes = volumes_for_sols(spec.filters.sols)
        for volume in volumes:
            try:  # one volume's unusable index is a failure row; the other volumes go on
                index = fetch_index(dl, spec.archive, volume, spec.index)
            except FetchError as exc:
                out.failures.append(Failure(volume, exc.url, "index", "FetchError", exc.reason))
                continue
            out.extend(
                products_from_index(index.table, volume, spec.archive, str(index.label),
                                    spec.mission, index_url=index.url)
            )  # fmt: skip
        out.products, older = newest_only(out.products)
        out.skipped.extend(older)
    else:
        bundle = archive_path(spec.bundle or "", where="fetch.products.bundle")
        coll = bundle / archive_path(spec.collection, where="fetch.products.collection")
        try:  # an unreachable collection is a failure row, as an msl volume's index is
            dl.fetch(RemoteFile(coll, join_url(spec.archive, coll), mutable=True))
        except FetchError as exc:
            out.failures.append(Failure(str(bundle), exc.url, "index", "FetchError", exc.reason))
            return out
        coll_path = dl.cache.path(coll)
        inv = inventory_of(coll_path, coll)
        delimiter = inventory_delimiter(coll_path)  # an unusable label: before the download
        url = join_url(spec.archive, inv)
        dl.fetch(RemoteFile(inv, url, kind="inventory", mutable=True, label=coll_path))
        out.extend(
            products_from_inventory(
                dl.cache.path(inv),
                delimiter,
                bundle,
                spec.label_path,
                spec.archive,
                inventory_url=url,
                camera=spec.camera,
            )
        )
    kept = []
    for p in out.products:
        why = spec.filters.why_not(p, unknown_ok=True)
        if why is None:
            kept.append(p)
        else:
            out.skipped.append(Skipped(p.product_id, p.label.url, "index", *why))
    out.products = kept
    return out


# -- one product ---------------------------------------------------------------------------
@dataclass(frozen=True)
class _Outcome:
    product: Product | None  # None: filtered out by its label (``skipped``) or failed
    files: tuple[str, ...]  # statuses of the files fetched ("cached", "downloaded", ...)
    received: int
    to_fetch: int
    failure: Failure | None = None
    skipped: Skipped | None = None


def _one(
    p: Product, spec: ProductsSpec, dl: Downloader, filt: ProductFilter, dry_run: bool
) -> _Outcome:
    stage, url = "label", p.label.url
    try:
        got = dl.fetch(p.label)
        p = with_label_facts(p, got.path, spec.archive)
        why = filt.why_not(p, unknown_ok=False)
        if why is not None:
            skip = Skipped(p.product_id, p.label.url, "label", *why)
            return _Outcome(None, (got.status,), got.bytes_received, 0, skipped=skip)
        assert p.image is not None
        image = p.image
        stage, url = "image", image.url
        target = dl.cache.path(image.rel, where=url)
        cached = target.is_file() and (image.size in (None, target.stat().st_size))
        if dry_run:
            size = image.size if image.size is not None else dl.head_size(image.url)
            if image.size is None and size is not None:
                p = replace(p, image=replace(image, size=size))
            return _Outcome(p, (got.status,), got.bytes_received, 0 if cached else (size or 0))
        img = dl.fetch(replace(image, label=got.path))  # the label tells what it must be
        if image.size is None:
            p = replace(p, image=replace(image, size=img.path.stat().st_size))
        return _Outcome(p, (got.status, img.status), got.bytes_received + img.bytes_received, 0)
    except MarsPairsError as exc:
        reason = exc.reason if isinstance(exc, FetchError) else str(exc)
        return _Outcome(
            None, (), 0, 0, Failure(p.product_id, url, stage, type(exc).__name__, reason)
        )


def fetch_products(
    cfg: FetchConfig,
    *,
    filters: ProductFilter | None = None,
    dry_run: bool = False,
    progress: bool = True,
) -> ProductsReport:
    """List, filter and fetch the configured products into the cache."""
    if cfg.products is None:
        raise FetchError("fetch.products", "the config has no fetch.products section")
    spec = cfg.products
    if filters is not None:
        spec = replace(spec, filters=filters)
    cache = Cache(cfg.cache)
    dl = Downloader(cache, cfg.policy)
    report = ProductsReport()
    listing = list_products(spec, dl)
    listed = listing.products
    report.listed = len(listed)
    report.skipped.extend(listing.skipped)
    report.failures.extend(listing.failures)
    for failure in listing.failures:
        tqdm.write(f"mars-pairs fetch: {failure.url}: {failure.message}", file=sys.stderr)
    bar = tqdm(total=len(listed), unit="product", disable=not progress, file=sys.stderr)
    with _cancelled_on_interrupt(dl, ThreadPoolExecutor(max_workers=cfg.policy.workers)) as pool:
        futures = [pool.submit(_one, p, spec, dl, spec.filters, dry_run) for p in listed]
        for fut in as_completed(futures):
            out = fut.result()
            bar.update(1)
            if out.failure is not None:
                report.failures.append(out.failure)
                tqdm.write(
                    f"mars-pairs fetch: {out.failure.url}: {out.failure.message}", file=sys.stderr
                )
                continue
            report.downloaded += sum(s in ("downloaded", "resumed") for s in out.files)
            report.cached += sum(s == "cached" for s in out.files)
            report.bytes_received += out.received
            if out.skipped is not None:
                report.skipped.append(out.skipped)
            if out.product is not None:
                report.products.append(out.product)
                report.selected += 1
                assert out.product.image is not None  # a selected product has its image
                report.image_bytes += out.product.image.size or 0
                report.to_fetch_bytes += out.to_fetch
    bar.close()
    report.products.sort(key=lambda p: str(p.label.rel))
    report.failures.sort(key=lambda f: (f.product_id, f.stage))
    report.skipped.sort(key=lambda s: (s.reason, s.product_id))
    if not dry_run:  # a dry run writes no report files (they are printed)
        write_failures(cache, report.failures)
        write_skipped(cache, report.skipped)
    return report


def write_failures(cache: Cache, failures: list[Failure]) -> Path:
    """``<cache>/fetch_failures.parquet`` (atomic; empty when nothing failed)."""
    return _write_rows(
        cache, FAILURES, failures, ("product_id", "url", "stage", "error", "message")
    )


def write_skipped(cache: Cache, skipped: list[Skipped]) -> Path:
    """``<cache>/fetch_skipped.parquet``: one row per product or index row left out on
    purpose (columns product_id, url, stage, reason, detail; atomic, rewritten each run).

    Kept apart from ``fetch_failures.parquet`` so that an empty failures file still means
    "everything chosen was fetched" and a rerun retries failures, not choices."""
    return _write_rows(cache, SKIPPED, skipped, ("product_id", "url", "stage", "reason", "detail"))


def _write_rows(cache: Cache, name: str, rows: Sequence[object], cols: tuple[str, ...]) -> Path:
    """A string-columned Parquet table of ``rows``' attributes ``cols`` at ``<cache>/name``."""
    table = pa.table({c: pa.array([getattr(r, c) for r in rows], pa.string()) for c in cols})
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink)
    target = cache.path(name)
    atomic_write_bytes(target, sink.getvalue().to_pybytes())
    return target


@contextmanager
def _cancelled_on_interrupt(
    dl: Downloader, pool: ThreadPoolExecutor
) -> Iterator[ThreadPoolExecutor]:
    """``pool``, shut down on leaving; on an interrupt (Ctrl-C) or any error, the queued
    downloads are cancelled and those in flight stopped at once (``Downloader.cancel``) before
    the exception goes on, instead of the whole queue being downloaded first."""
    try:
        yield pool
    except BaseException:
        dl.cancel()
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


# -- single files --------------------------------------------------------------------------
def fetch_remote(
    cfg: FetchConfig, spec: RemoteSpec, *, kind: str | None = None, mutable: bool = False
) -> Path:
    """One archive file (e.g. the PLACES table) into the cache; its path there.

    ``kind``: what it must be (``validate.KINDS``; None: by its name); ``mutable``: revalidate
    it on every fetch (an archive table that changes between releases)."""
    rel = archive_path(spec.path, where="fetch.places.path")
    dl = Downloader(Cache(cfg.cache), cfg.policy)
    remote = RemoteFile(PurePosixPath(rel), join_url(spec.archive, rel), kind=kind, mutable=mutable)
    return dl.fetch(remote).path


def fetch_places(cfg: FetchConfig) -> Path:
    """The configured PLACES table, in the cache."""
    if cfg.places is None:
        raise FetchError("fetch.places", "the config has no fetch.places section")
    return fetch_remote(cfg, cfg.places, kind="places", mutable=True)


@dataclass(frozen=True)
class OrbitalPlan:
    """The windows planned for each configured raster, and the positions they serve."""

    positions: Positions
    plans: tuple[WindowPlan, ...]

    def format(self) -> list[str]:
        """Lines: each window (source, bounds, CRS, cells, verdict), positions left out."""
        lines = [f"{len(self.positions.x)} rover positions ({self.positions.crs})"]
        for plan in self.plans:
            lines.append(
                f"{plan.kind}: {len(plan.windows)} window(s), reach {plan.reach_m:.1f} m, "
                f"from {plan.source}"
            )
            lines += [f"  {w.describe()}" for w in plan.windows]
            if plan.off_raster:
                names = [self.positions.names[i] for i in plan.off_raster if self.positions.names]
                lines.append(
                    f"  {len(plan.off_raster)} positions off the {plan.kind} raster (left out): "
                    + ", ".join(names[:10])
                    + (" ..." if len(names) > 10 else "")
                )
        return lines


def _window_files(cache: Cache, kind: str, n: int) -> list[Path]:
    """``orbital/<kind>.tif`` for one window, ``orbital/<kind>-000.tif``, ... for several."""
    if n == 1:
        return [cache.path(f"orbital/{kind}.tif")]
    return [cache.path(f"orbital/{kind}-{i:03d}.tif") for i in range(n)]


def plan_orbital(
    cfg: FetchConfig,
    *,
    filters: ProductFilter | None = None,
    margin_m: float | None = None,
    dry_run: bool = False,
) -> OrbitalPlan:
    """Plan the DEM/ortho windows around the PLACES rover positions (sols/sites of ``filters``).

    Reads the PLACES table (fetched into the cache; on a dry run the cached copy as it is, else
    fetched into a temporary folder, so that a dry run writes nothing) and each raster's
    header (cached beside the windows as ``orbital/<kind>.source.json``; a dry run only reads
    it).
    """
    import tempfile

    if cfg.orbital is None:
        raise FetchError("fetch.orbital", "the config has no fetch.orbital section")
    if cfg.places is None:
        raise FetchError("fetch.places", "orbital windows need the PLACES table (fetch.places)")
    cache = Cache(cfg.cache)
    filt = filters or (cfg.products.filters if cfg.products else ProductFilter())
    cached = cache.path(archive_path(cfg.places.path, where="fetch.places.path"))
    with tempfile.TemporaryDirectory(prefix="mars-pairs-plan-") as tmp:
        if not dry_run:
            places = fetch_places(cfg)  # revalidated: a mutable archive table
        elif cached.is_file():
            places = cached  # as cached: a dry run neither fetches nor rewrites it
        else:
            places = fetch_remote(replace(cfg, cache=Path(tmp)), cfg.places, kind="places")
        pos = rover_positions(places, sols=filt.sols, sites=filt.sites)
    margin = cfg.orbital.margin_m if margin_m is None else margin_m
    reach = {
        "dem": dem_reach_m(cfg.radius_m, cfg.chip_size_m, margin),
        "ortho": ortho_reach_m(cfg.chip_size_m, margin),
    }
    plans = []
    for kind in ("dem", "ortho"):
        source = getattr(cfg.orbital, kind)
        if source is None:
            continue
        sidecar = cache.path(f"orbital/{kind}.source.json")
        if not dry_run:
            _check_same_source(cache, kind, source)
        info = source_info(source, sidecar, write=not dry_run)
        limit = cfg.orbital.max_cells
        plans.append(
            plan_windows(
                pos.x,
                pos.y,
                pos.crs,
                info.grid,
                reach[kind],
                kind=kind,
                source=source,
                max_cells=limit,
            )
        )
    return OrbitalPlan(pos, tuple(plans))


def cut_orbital(cfg: FetchConfig, plan: OrbitalPlan) -> list[WindowResult]:
    """Cut every planned window into the cache and mosaic each raster's into a VRT.

    Writes ``orbital/<kind>.tif`` (one window) or ``orbital/<kind>-NNN.tif`` (several) and
    always ``orbital/<kind>.vrt`` (what ``inputs.dem`` / ``inputs.ortho`` name); window files
    of an earlier plan that this one does not use are removed. Raises ``FetchError`` naming
    ``fetch.orbital.max_cells`` before reading anything if a window is above it.
    """
    for p in plan.plans:
        p.check()
    cache = Cache(cfg.cache)
    for p in plan.plans:
        _check_same_source(cache, p.kind, p.source)
    out: list[WindowResult] = []
    for p in plan.plans:
        info = source_info(p.source, cache.path(f"orbital/{p.kind}.source.json"))
        files = _window_files(cache, p.kind, len(p.windows))
        for win, file in zip(p.windows, files, strict=True):
            out.append(cut_planned(win, info, file))
        write_vrt(cache.path(f"orbital/{p.kind}.vrt"), info, list(p.windows), files)
        keep = set(files)
        folder = cache.path("orbital")
        for stale in [*folder.glob(f"{p.kind}.tif"), *folder.glob(f"{p.kind}-[0-9][0-9][0-9].tif")]:
            if stale not in keep:
                stale.unlink()
    return out


def _check_same_source(cache: Cache, kind: str, source: str) -> None:
    """FetchError naming ``fetch.cache`` when ``orbital/<kind>.vrt`` holds windows of another
    source (two configs sharing one cache would replace each other's maps)."""
    sidecar = cache.path(f"orbital/{kind}.source.json")
    if not sidecar.is_file():
        return
    try:
        earlier = json.loads(sidecar.read_text()).get("source")
    except (ValueError, OSError, AttributeError):
        return
    if earlier not in (None, source):
        raise FetchError(
            "fetch.cache",
            f"{cache.path('orbital')} holds {kind} windows of {earlier}; this config's "
            f"fetch.orbital.{kind} is {source}: give each config its own fetch.cache (or "
            "remove that folder to replace them)",
        )


def fetch_orbital(
    cfg: FetchConfig, *, filters: ProductFilter | None = None, margin_m: float | None = None
) -> list[WindowResult]:
    """Plan, then cut, the DEM/ortho windows around the PLACES rover positions."""
    return cut_orbital(cfg, plan_orbital(cfg, filters=filters, margin_m=margin_m))
