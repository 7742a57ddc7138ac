"""The ``fetch:`` section of a build config: archive roots, what to fetch, the cache root.

```yaml
fetch:
  cache: ../data/archive          # one root; the archive's paths are mirrored under it
  retries: 4                      # per file, exponential backoff from backoff_s
  backoff_s: 0.5
  timeout_s: 60                   # read timeout (seconds)
  deadline_s: 900                 # the most one file may take, every attempt included
  workers: 4                      # parallel downloads
  products:
    mission: msl                  # msl (PDS3 volumes) | m2020 (PDS4 bundle)
    archive: https://...          # archive root URL (or a local folder)
    volumes: [MSLMST_0014]        # msl, optional: volumes whose INDEX/<index>.LBL/.TAB list
                                  # products; default: every volume whose sol range in
                                  # fetch/data/mslmst_volume_sol_ranges.csv meets sols
    index: RDRINDEX               # msl: RDRINDEX or EDRINDEX
    bundle: mars2020_mastcamz_ops_calibrated              # m2020
    collection: data/collection_data.xml                  # m2020, inside the bundle
    label_path: data/sol/{sol:05d}/ids/rdr/zcam/{product_id}.xml   # m2020, inside the bundle
    sols: [1429, 1429]            # inclusive; optional filters below
    instruments: [MAST_LEFT]
    product_types: [DRCL]
    sites: [56]
    drives: [1632]
    thumbnails: false             # thumbnail products (id flag T) are skipped unless true
  places: {archive: https://..., path: MSLPLC_1XXX/DATA/LOCALIZATIONS/localized_interp.csv}
  orbital:
    dem: https://.../m20_orbital_dem.img   # remote (or local) rasters to cut windows from:
    ortho: https://.../m20_orbital_map.img # GeoTIFF, VICAR, PDS3/PDS4 (label beside a .img)
    margin_m: 10                  # ground metres past what the build reads (see below)
    max_cells: 200000000          # per window; a larger window is refused, naming this key
```
Orbital windows are sized by what the build reads around each rover position: the DEM by
``geometry.radius`` (the view), the ortho by the chip (``0.71 x chips.size_m``, any heading),
each plus ``margin_m``; positions far apart get separate windows (``fetch/windows.py``).
Relative ``cache`` and local archive roots resolve against the config file's folder. Each
key's type, bounds, default and meaning are written once, in the schema classes below
(``pipeline.config_schema``; ``docs/reference/config.md`` is generated from them).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BeforeValidator, Field, PlainValidator, ValidationInfo
from pydantic import dataclasses as schema
from pydantic.functional_validators import model_validator

from mars_pairs.errors import ConfigError
from mars_pairs.fetch.download import FetchPolicy
from mars_pairs.fetch.products import ProductFilter
from mars_pairs.fetch.windows import MAX_CELLS
from mars_pairs.pipeline.config import ChipsConfig, GeometryConfig, in_file, read_yaml
from mars_pairs.pipeline.config_schema import (
    MAX_TEXT,
    SCHEMA,
    Expected,
    Flag,
    Integer,
    KeyProblem,
    Number,
    Text,
    base_of,
    line_of,
    read_section,
    shown,
    subset,
)

MISSIONS = ("msl", "m2020")
#: MSLMST volumes: RDRINDEX, EDRINDEX; the Navcam volume MSLNAV_1XXX: INDEX (a public PDS
#: indexer reads ``run_indexer("MSLNAV_1XXX", "INDEX")`` beside ``("MSLMST_000N", "EDRINDEX")``)
INDEXES = ("RDRINDEX", "EDRINDEX", "INDEX")
#: ``fetch.products.camera`` per mission: the mast camera (the default) or Navcam
CAMERAS = {"msl": ("mcam", "ncam"), "m2020": ("zcam", "ncam")}
#: Curiosity Navcam: one PDS3 volume, ``MSLNAV_1XXX`` (``DATA_V1/SOL<5-digit sol>/`` before
#: sol 1870, ``DATA/SOL<5-digit sol>/`` after, as its index's PATH_NAME gives), EDR labels
#: ``NLA_397681455EDR_F0020000AUT_04096M1.LBL``-style (public download code citing
#: ``MSLNAV_1XXX/DOCUMENT/MSL_CAMERA_SIS.PDF``; a real label's DATA_SET_ID
#: ``MSL-M-NAVCAM-2-EDR-V1.0``)
MSL_NAVCAM_VOLUMES = ("MSLNAV_1XXX",)
#: Perseverance Navcam: bundle ``mars2020_navcam_ops_raw``, labels at
#: ``data/sol/<5-digit sol>/ids/edr/ncam/<FILE ID>.xml`` (public download code building
#: ``.../mars2020_navcam_ops_raw/data/sol/{sol:05d}/ids/edr/ncam``; the calibrated bundle
#: ``mars2020_navcam_ops_calibrated`` uses ``ids/fdr/ncam``)
M2020_NAVCAM_LABEL_PATH = "data/sol/{sol:05d}/ids/edr/ncam/{product_id}.xml"
M2020_LABEL_PATH = "data/sol/{sol:05d}/ids/rdr/zcam/{product_id}.xml"
#: Bounds of the download policy: a retry count, a backoff and a read timeout (seconds) past
#: these would leave a fetch waiting for hours on one file; a timeout under a millisecond
#: fails every read.
MAX_RETRIES = 100
MAX_BACKOFF_S = 3600.0
MIN_TIMEOUT_S = 0.001
MAX_TIMEOUT_S = 3600.0
MAX_WORKERS = 256
MAX_MARGIN_M = 200_000.0  # as geometry.radius: ~3.4 degrees of Mars
MAX_WINDOW_CELLS = 2**32  # 16 GiB of float32 in one window


def _local(value: str, info: ValidationInfo) -> Path:
    return ((base_of(info) or Path.cwd()) / Path(value).expanduser()).resolve()


def _text(value: Any) -> str:
    if not isinstance(value, str) or not value.strip() or len(value) > MAX_TEXT:
        raise KeyProblem(f"expected a URL or a path, got {shown(value)}")
    return value


def _root(value: Any, info: ValidationInfo) -> str:
    """An archive root: an http(s) URL (its trailing ``/`` removed), or a local folder as a
    ``file://`` URL (relative: to the config's folder)."""
    text = _text(value)
    if text.startswith(("http://", "https://")):
        return text.rstrip("/")
    if text.startswith("file://"):  # a root read already
        return text
    return _local(text, info).as_uri()


def _raster(value: Any, info: ValidationInfo) -> str:
    """A raster to cut windows from: an http(s) URL, a GDAL ``/vsi`` path, or a local path."""
    text = _text(value)
    if text.startswith(("http://", "https://", "/vsi")):
        return text
    return str(_local(text, info))


def _cache(value: Any, info: ValidationInfo) -> Path:
    if isinstance(value, Path):
        return value
    if not isinstance(value, str) or not value.strip() or len(value) > MAX_TEXT:
        raise KeyProblem(f"expected a folder, got {shown(value)}")
    return _local(value, info)


def _named_ids(value: Any, info: ValidationInfo) -> frozenset[str]:
    """``fetch.products.terrain_labels: {format, root[, classes]}``: the product ids (upper
    case) the label source names (``mars_pairs.terrain_labels``)."""
    from mars_pairs.errors import TerrainLabelError
    from mars_pairs.terrain_labels import FORMATS, ClassTable, open_source

    if not isinstance(value, dict) or set(value) - {"format", "root", "classes"}:
        raise KeyProblem(f"expected {{format, root[, classes]}}, got {shown(value)}")
    fmt, root = value.get("format"), value.get("root")
    if fmt not in FORMATS:
        raise KeyProblem(f"format: expected one of {list(FORMATS)}, got {shown(fmt)}")
    if not isinstance(root, str) or not root.strip():
        raise KeyProblem(f"root: expected a folder, got {shown(root)}")
    try:
        table = ClassTable.from_mapping(value["classes"], "classes") if "classes" in value else None
        ids = open_source(fmt, _local(root, info), table).product_ids()
    except (TerrainLabelError, ConfigError) as exc:
        raise KeyProblem(str(exc)) from None
    if not ids:
        raise KeyProblem(f"the terrain labels under {root} name no product")
    return frozenset(i.upper() for i in ids)


def _listed(value: Any) -> Any:
    """One value given alone is a list of one."""
    return [value] if isinstance(value, (str, int, float)) else value


def _upper(value: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(v.upper() for v in value)


def _upper_text(value: Any) -> Any:
    return value.upper() if isinstance(value, str) else value


def _sol_pair(value: Any) -> Any:
    """``52`` or ``[52]`` is ``[52, 52]``."""
    if isinstance(value, int) and not isinstance(value, bool):
        return [value, value]
    if isinstance(value, list) and len(value) == 1:
        return [value[0], value[0]]
    return value


def _ordered(value: tuple[int, int]) -> tuple[int, int]:
    if value[0] > value[1]:
        raise KeyProblem(f"expected [first, last] with first <= last, got {list(value)}")
    return value


Root = Annotated[
    str, PlainValidator(_root), Expected("an http(s):// URL or a folder (relative: to the config)")
]
Names = Annotated[tuple[Text, ...], BeforeValidator(_listed), Expected("a name or a list of names")]
UpperNames = Annotated[
    tuple[Text, ...],
    BeforeValidator(_listed),
    AfterValidator(_upper),
    Expected("a name or a list of names (any case)"),
]
Integers = Annotated[
    tuple[Integer, ...], BeforeValidator(_listed), Expected("an integer or a list of integers")
]
Sols = Annotated[
    tuple[Integer, Integer],
    BeforeValidator(_sol_pair),
    AfterValidator(_ordered),
    Expected("a sol, or [first, last] (inclusive)"),
]
RasterSource = Annotated[
    str, PlainValidator(_raster), Expected("an http(s):// URL, a GDAL /vsi path or a local path")
]


@schema.dataclass(frozen=True, config=SCHEMA)
class ProductsSection:
    """Where the products are listed (PDS3 volumes' index tables for msl, the PDS4 bundle's
    inventory for m2020) and which to take; the filters left out take any product."""

    mission: Literal["msl", "m2020"]
    """msl (PDS3 volumes) or m2020 (a PDS4 bundle)."""
    archive: Root
    """The archive root URL (or a local folder) the volumes or the bundle are under."""
    volumes: Names = ()
    """msl: the PDS3 volumes whose ``INDEX/<index>.LBL/.TAB`` list products (e.g.
    MSLMST_0014); none: every volume whose sol range meets ``sols`` (required without sols)."""
    index: (
        Annotated[Literal["RDRINDEX", "EDRINDEX", "INDEX"], BeforeValidator(_upper_text)] | None
    ) = None
    """msl: which index table of each volume to read; null: RDRINDEX (Mastcam), INDEX
    (Navcam)."""
    bundle: Text | None = None
    """m2020: the PDS4 bundle's folder under the archive (required for m2020)."""
    collection: Text = "data/collection_data.xml"
    """m2020: the collection label inside the bundle (its inventory lists the products)."""
    label_path: Text | None = None
    """m2020: where a product's label is inside the bundle ({sol}, {product_id}); null:
    ``ids/rdr/zcam`` for Mastcam-Z, ``ids/edr/ncam`` for Navcam."""
    camera: Literal["mcam", "zcam", "ncam"] | None = None
    """The camera: msl mcam (Mastcam, the default) or ncam (Navcam); m2020 zcam (Mastcam-Z,
    the default) or ncam (Navcam)."""
    terrain_labels: (
        Annotated[
            frozenset[str],
            PlainValidator(_named_ids),
            Expected("a terrain label source {format: ai4mars | folder, root[, classes]}"),
        ]
        | None
    ) = None
    """Fetch only the products a terrain label source names (``inputs.terrain_labels``'s
    form); null: every product the filters take."""
    sols: Sols | None = None
    """The sols to take, inclusive; null: any."""
    instruments: UpperNames = ()
    """Instrument ids to take (e.g. MAST_LEFT); none: any."""
    product_types: UpperNames = ()
    """Product types to take (e.g. DRCL, RAD); none: any."""
    sites: Integers = ()
    """Rover sites to take; none: any."""
    drives: Integers = ()
    """Rover drives to take; none: any."""
    thumbnails: Flag = False
    """Take thumbnail products (an id's thumbnail flag) too."""

    @model_validator(mode="after")
    def _mission_keys(self) -> ProductsSection:
        if self.camera is not None and self.camera not in CAMERAS[self.mission]:
            raise KeyProblem(
                f"expected one of {list(CAMERAS[self.mission])} for {self.mission}, got "
                f"{self.camera!r}",
                "camera",
            )
        navcam = self.camera == "ncam"  # one volume, MSLNAV_1XXX, when none is named
        if self.mission == "msl" and not self.volumes and self.sols is None and not navcam:
            raise KeyProblem(
                "required for msl without sols (PDS3 volumes, e.g. MSLMST_0014; with sols "
                "they come from the volume sol-range table)",
                "volumes",
            )
        if self.mission == "m2020" and self.bundle is None:
            raise KeyProblem("required for m2020 (the PDS4 bundle folder)", "bundle")
        return self


@dataclass(frozen=True)
class ProductsSpec:
    """Where the products are listed and which to take (``ProductsSection``, read)."""

    mission: str
    archive: str
    volumes: tuple[str, ...]  # msl; () = the table's volumes for the filter's sols
    index: str
    bundle: str | None
    collection: str
    label_path: str
    filters: ProductFilter = field(default_factory=ProductFilter)
    camera: str = "zcam"  # m2020: zcam | ncam; msl: mcam | ncam


@schema.dataclass(frozen=True, config=SCHEMA)
class RemoteSpec:
    """One file: an archive root and the path inside it (mirrored under the cache)."""

    archive: Root
    """The archive root URL (or a local folder)."""
    path: Text
    """The file's path inside the archive."""


@schema.dataclass(frozen=True, config=SCHEMA)
class OrbitalSpec:
    """Rasters to cut windows from (GeoTIFF, VICAR, PDS3/PDS4 with the label beside the .img):
    the DEM's windows reach ``geometry.radius`` past each rover position, the ortho's the
    chip's half-diagonal (0.71 x ``chips.size_m``), each plus ``margin_m``."""

    dem: RasterSource | None = None
    """The DEM to cut windows from: a URL or a local path; null: none."""
    ortho: RasterSource | None = None
    """The orthoimage to cut windows from: a URL or a local path; null: none."""
    margin_m: Annotated[Number, Field(ge=0.0, le=MAX_MARGIN_M)] = 10.0
    """Ground metres past what the build reads."""
    max_cells: Annotated[Integer, Field(ge=1, le=MAX_WINDOW_CELLS)] = MAX_CELLS
    """The largest window (cells) accepted; a larger one is refused, naming this key."""


@schema.dataclass(frozen=True, config=SCHEMA)
class FetchSection:
    """What ``mars-pairs fetch`` downloads, from where, into which cache, and how."""

    cache: Annotated[Path, PlainValidator(_cache), Expected("a folder (relative: to the config)")]
    """The cache root: the archive's paths are mirrored under it."""
    retries: Annotated[Integer, Field(ge=0, le=MAX_RETRIES)] = FetchPolicy.retries
    """Attempts after the first, per file."""
    backoff_s: Annotated[Number, Field(ge=0.0, le=MAX_BACKOFF_S)] = FetchPolicy.backoff_s
    """The wait before the first retry (seconds), doubled per retry."""
    timeout_s: Annotated[Number, Field(ge=MIN_TIMEOUT_S, le=MAX_TIMEOUT_S)] = (
        FetchPolicy.read_timeout_s
    )
    """The read timeout (seconds)."""
    deadline_s: Annotated[Number, Field(ge=MIN_TIMEOUT_S, le=7 * 86400.0)] = FetchPolicy.deadline_s
    """The total time one file may take (seconds), every attempt and wait included."""
    workers: Annotated[Integer, Field(ge=1, le=MAX_WORKERS)] = FetchPolicy.workers
    """Parallel downloads."""
    products: ProductsSection | None = None
    """The labels and images to fetch; null: none."""
    places: RemoteSpec | None = None
    """The PLACES table to fetch; null: none."""
    orbital: OrbitalSpec | None = None
    """The orbital rasters to cut windows from; null: none."""


@dataclass(frozen=True)
class FetchConfig:
    """The validated ``fetch:`` section."""

    cache: Path
    policy: FetchPolicy
    products: ProductsSpec | None
    places: RemoteSpec | None
    orbital: OrbitalSpec | None
    radius_m: float  # geometry.radius of the build config (the DEM windows' reach)
    chip_size_m: float = 256.0  # chips.size_m of the build config (the ortho windows' reach)


def _products(p: ProductsSection | None) -> ProductsSpec | None:
    if p is None:
        return None
    filters = ProductFilter(
        sols=p.sols,
        instruments=p.instruments,
        product_types=p.product_types,
        sites=p.sites,
        drives=p.drives,
        thumbnails=p.thumbnails,
        product_ids=p.terrain_labels or frozenset(),
    )
    camera = p.camera or CAMERAS[p.mission][0]
    navcam = camera == "ncam"
    return ProductsSpec(
        mission=p.mission,
        archive=p.archive,
        volumes=p.volumes or (MSL_NAVCAM_VOLUMES if navcam and p.mission == "msl" else ()),
        index=p.index or ("INDEX" if navcam else "RDRINDEX"),
        bundle=p.bundle,
        collection=p.collection,
        label_path=p.label_path or (M2020_NAVCAM_LABEL_PATH if navcam else M2020_LABEL_PATH),
        filters=filters,
        camera=camera,
    )


def parse_fetch(
    data: Any,
    base: Path,
    radius_m: float,
    chip_size_m: float = 256.0,
    *,
    line: tuple[int, int] | None = None,
) -> FetchConfig:
    """Validate a ``fetch:`` mapping (relative paths against ``base``)."""
    if data is None or data == {}:
        raise ConfigError("fetch: the config has no fetch section", line=line)
    d = read_section(FetchSection, data, "fetch", base, line=line)
    return FetchConfig(
        cache=d.cache,
        policy=FetchPolicy(
            retries=d.retries,
            backoff_s=d.backoff_s,
            read_timeout_s=d.timeout_s,
            deadline_s=d.deadline_s,
            workers=d.workers,
        ),
        products=_products(d.products),
        places=d.places,
        orbital=d.orbital,
        radius_m=radius_m,
        chip_size_m=chip_size_m,
    )


def load_fetch_config(path: str | Path) -> FetchConfig:
    """Read the ``fetch:`` section of a YAML build config, with the build's
    ``geometry.radius`` and ``chips.size_m`` (the windows' reach, checked as the build does)."""
    path = Path(path)
    data = read_yaml(path)  # ConfigError naming the file: unreadable, bad YAML, duplicate keys
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level")
    try:
        geometry = _only(data, "geometry", "radius", GeometryConfig)
        chips = _only(data, "chips", "size_m", ChipsConfig)
        return parse_fetch(
            data.get("fetch"),
            path.resolve().parent,
            geometry.radius,
            chips.size_m,
            line=line_of(data, "fetch"),
        )
    except ConfigError as exc:
        raise in_file(path, exc) from None


def _only(data: dict[Any, Any], section: str, key: str, cls: type[Any]) -> Any:
    """The build section ``cls`` read from ``data[section]``'s ``key`` alone (the build reads
    the whole section: its other keys are the build's to check)."""
    block = data.get(section)
    if isinstance(block, dict):
        block = subset(block, (key,))
    return read_section(cls, block, section, line=line_of(data, section))
