"""The ``fetch:`` section of a build config: archive roots, what to fetch, the cache root.

```yaml
fetch:
  cache: ../data/archive          # one root; the archive's paths are mirrored under it
  retries: 4                      # per file, exponential backoff from backoff_s
  backoff_s: 0.5
  timeout_s: 60                   # read timeout (seconds)
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
Relative ``cache`` and local archive roots resolve against the config file's folder.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mars_pairs.errors import ConfigError
from mars_pairs.fetch.download import FetchPolicy
from mars_pairs.fetch.products import ProductFilter
from mars_pairs.fetch.windows import MAX_CELLS
from mars_pairs.pipeline.config import read_yaml

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


@dataclass(frozen=True)
class ProductsSpec:
    """Where the products are listed and which to take."""

    mission: str
    archive: str
    volumes: tuple[str, ...] = ()  # msl; () = the table's volumes for the filter's sols
    index: str = "RDRINDEX"
    bundle: str | None = None
    collection: str = "data/collection_data.xml"
    label_path: str = "data/sol/{sol:05d}/ids/rdr/zcam/{product_id}.xml"
    filters: ProductFilter = field(default_factory=ProductFilter)
    camera: str = "zcam"  # m2020: zcam | ncam; msl: mcam | ncam


@dataclass(frozen=True)
class RemoteSpec:
    """One file: archive root URL and the path inside it (mirrored in the cache)."""

    archive: str
    path: str


@dataclass(frozen=True)
class OrbitalSpec:
    """Rasters to cut windows from; ``margin_m`` ground metres past the build's reach,
    ``max_cells`` the largest window (cells) accepted."""

    dem: str | None = None
    ortho: str | None = None
    margin_m: float = 10.0
    max_cells: int = MAX_CELLS


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


def _root(value: Any, key: str, base: Path) -> str:
    if not isinstance(value, str) or not value:
        raise ConfigError(f"{key}: expected a URL or folder, got {value!r}")
    if value.startswith(("http://", "https://")):
        return value.rstrip("/")
    return (base / Path(value).expanduser()).resolve().as_uri()


def _mapping(value: Any, key: str, known: set[str]) -> dict[str, Any]:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ConfigError(f"{key}: expected a mapping, got {type(value).__name__}")
    unknown = sorted(set(value) - known)
    if unknown:
        raise ConfigError(f"{key}.{unknown[0]}: unknown key (expected one of {sorted(known)})")
    return value


def _ints(value: Any, key: str) -> tuple[int, ...]:
    if value is None:
        return ()
    if isinstance(value, int) and not isinstance(value, bool):
        return (value,)
    if not isinstance(value, list) or not all(
        isinstance(v, int) and not isinstance(v, bool) for v in value
    ):
        raise ConfigError(f"{key}: expected an integer or a list of integers, got {value!r}")
    return tuple(value)


def _strs(value: Any, key: str) -> tuple[str, ...]:
    if value is None:
        return ()
    if isinstance(value, str):
        return (value,)
    if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
        raise ConfigError(f"{key}: expected a string or a list of strings, got {value!r}")
    return tuple(value)


def _bool(value: Any, key: str) -> bool:
    if not isinstance(value, bool):
        raise ConfigError(f"{key}: expected true or false, got {value!r}")
    return value


def _sols(value: Any, key: str) -> tuple[int, int] | None:
    if value is None:
        return None
    sols = _ints(value, key)
    if len(sols) == 1:
        return (sols[0], sols[0])
    if len(sols) != 2 or sols[0] > sols[1]:
        raise ConfigError(f"{key}: expected [first, last] with first <= last, got {value!r}")
    return (sols[0], sols[1])


def _products(data: Any, base: Path) -> ProductsSpec | None:
    key = "fetch.products"
    known = {"mission", "archive", "volumes", "index", "bundle", "collection", "label_path",
             "sols", "instruments", "product_types", "sites", "drives", "thumbnails",
             "camera", "terrain_labels"}  # fmt: skip
    d = _mapping(data, key, known)
    if not d:
        return None
    mission = d.get("mission")
    if mission not in MISSIONS:
        raise ConfigError(f"{key}.mission: expected one of {list(MISSIONS)}, got {mission!r}")
    filters = ProductFilter(
        sols=_sols(d.get("sols"), f"{key}.sols"),
        instruments=tuple(s.upper() for s in _strs(d.get("instruments"), f"{key}.instruments")),
        product_types=tuple(
            s.upper() for s in _strs(d.get("product_types"), f"{key}.product_types")
        ),
        sites=_ints(d.get("sites"), f"{key}.sites"),
        drives=_ints(d.get("drives"), f"{key}.drives"),
        thumbnails=_bool(d.get("thumbnails", False), f"{key}.thumbnails"),
        product_ids=_named_ids(d.get("terrain_labels"), f"{key}.terrain_labels", base),
    )
    camera = d.get("camera", CAMERAS[mission][0])
    if camera not in CAMERAS[mission]:
        raise ConfigError(
            f"{key}.camera: expected one of {list(CAMERAS[mission])} for {mission}, got {camera!r}"
        )
    navcam = camera == "ncam"
    default_volumes = MSL_NAVCAM_VOLUMES if navcam and mission == "msl" else ()
    default_path = M2020_NAVCAM_LABEL_PATH if navcam else ProductsSpec.label_path
    spec = ProductsSpec(
        mission=mission,
        archive=_root(d.get("archive"), f"{key}.archive", base),
        volumes=_strs(d.get("volumes"), f"{key}.volumes") or default_volumes,
        index=str(d.get("index", "INDEX" if navcam else "RDRINDEX")).upper(),
        bundle=d.get("bundle"),
        collection=str(d.get("collection", ProductsSpec.collection)),
        label_path=str(d.get("label_path", default_path)),
        filters=filters,
        camera=camera,
    )
    if mission == "msl" and not spec.volumes and filters.sols is None:
        raise ConfigError(
            f"{key}.volumes: required for msl without sols (PDS3 volumes, e.g. MSLMST_0014; "
            "with sols they come from the volume sol-range table)"
        )
    if mission == "msl" and spec.index not in INDEXES:
        raise ConfigError(f"{key}.index: expected one of {list(INDEXES)}, got {spec.index!r}")
    if mission == "m2020" and not isinstance(spec.bundle, str):
        raise ConfigError(f"{key}.bundle: required for m2020 (the PDS4 bundle folder)")
    return spec


def _named_ids(data: Any, key: str, base: Path) -> frozenset[str]:
    """``fetch.products.terrain_labels: {format, root[, classes]}``: the product ids (upper
    case) the label source names (``mars_pairs.terrain_labels``); empty when absent."""
    if data is None:
        return frozenset()
    from mars_pairs.errors import TerrainLabelError
    from mars_pairs.terrain_labels import FORMATS, ClassTable, open_source

    d = _mapping(data, key, {"format", "root", "classes"})
    fmt = d.get("format")
    if fmt not in FORMATS:
        raise ConfigError(f"{key}.format: expected one of {list(FORMATS)}, got {fmt!r}")
    root = d.get("root")
    if not isinstance(root, str) or not root:
        raise ConfigError(f"{key}.root: expected a folder, got {root!r}")
    table = ClassTable.from_mapping(d["classes"], f"{key}.classes") if "classes" in d else None
    try:
        ids = open_source(fmt, base / Path(root).expanduser(), table).product_ids()
    except TerrainLabelError as exc:
        raise ConfigError(f"{key}: {exc}") from None
    if not ids:
        raise ConfigError(f"{key}: the terrain labels under {root} name no product")
    return frozenset(i.upper() for i in ids)


def _number(d: dict[str, Any], name: str, key: str, default: float) -> float:
    """A non-negative number; ``default`` when the key is absent or null."""
    value = _optional_number(d, name, key)
    return default if value is None else value


def _optional_number(d: dict[str, Any], name: str, key: str) -> float | None:
    """A non-negative number, None when the key is absent or null; else ConfigError."""
    value = d.get(name)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0:
        raise ConfigError(f"{key}.{name}: expected a non-negative number, got {value!r}")
    return float(value)


def _orbital(data: Any, base: Path) -> OrbitalSpec:
    key = "fetch.orbital"
    o = _mapping(data, key, {"dem", "ortho", "margin_m", "max_cells"})
    rasters = {}
    for name in ("dem", "ortho"):
        value = o.get(name)
        if value is not None and (not isinstance(value, str) or not value):
            raise ConfigError(f"{key}.{name}: expected a URL or path, got {value!r}")
        if isinstance(value, str) and not value.startswith(("http://", "https://", "/vsi")):
            value = str((base / value).resolve())
        rasters[name] = value
    max_cells = o.get("max_cells", MAX_CELLS)
    if isinstance(max_cells, bool) or not isinstance(max_cells, int) or max_cells < 1:
        raise ConfigError(f"{key}.max_cells: expected a positive integer, got {max_cells!r}")
    margin = _optional_number(o, "margin_m", key)
    if margin is None:
        margin = OrbitalSpec.margin_m
    return OrbitalSpec(rasters["dem"], rasters["ortho"], margin, max_cells)


def parse_fetch(data: Any, base: Path, radius_m: float, chip_size_m: float = 256.0) -> FetchConfig:
    """Validate a ``fetch:`` mapping (relative paths against ``base``)."""
    known = {"cache", "retries", "backoff_s", "timeout_s", "workers", "products", "places",
             "orbital"}  # fmt: skip
    d = _mapping(data, "fetch", known)
    if not d:
        raise ConfigError("fetch: the config has no fetch section")
    cache = d.get("cache")
    if not isinstance(cache, str) or not cache:
        raise ConfigError(f"fetch.cache: expected a folder, got {cache!r}")
    retries = d.get("retries", 4)
    workers = d.get("workers", 4)
    for name, value in (("retries", retries), ("workers", workers)):
        if isinstance(value, bool) or not isinstance(value, int) or value < (name == "workers"):
            raise ConfigError(f"fetch.{name}: expected a non-negative integer, got {value!r}")
    policy = FetchPolicy(
        retries=retries,
        backoff_s=_number(d, "backoff_s", "fetch", 0.5),
        read_timeout_s=_number(d, "timeout_s", "fetch", 60.0),
        workers=workers,
    )
    places = None
    if d.get("places") is not None:
        p = _mapping(d["places"], "fetch.places", {"archive", "path"})
        if not isinstance(p.get("path"), str):
            raise ConfigError(f"fetch.places.path: expected a path, got {p.get('path')!r}")
        places = RemoteSpec(_root(p.get("archive"), "fetch.places.archive", base), p["path"])
    orbital = _orbital(d["orbital"], base) if d.get("orbital") is not None else None
    return FetchConfig(
        cache=(base / Path(cache).expanduser()).resolve(),
        policy=policy,
        products=_products(d.get("products"), base),
        places=places,
        orbital=orbital,
        radius_m=radius_m,
        chip_size_m=chip_size_m,
    )


def load_fetch_config(path: str | Path) -> FetchConfig:
    """Read the ``fetch:`` section of a YAML build config."""
    path = Path(path)
    data = read_yaml(path)  # ConfigError naming the file: unreadable, bad YAML, duplicate keys
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level")
    try:
        radius = _section_number(data, "geometry", "radius", 2000.0)
        chip = _section_number(data, "chips", "size_m", 256.0)
        return parse_fetch(data.get("fetch"), path.resolve().parent, radius, chip)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def _section_number(data: dict[str, Any], section: str, key: str, default: float) -> float:
    """``data[section][key]`` as a positive number (metres), ``default`` when absent;
    ConfigError naming ``section.key`` otherwise (the build config checks it fully)."""
    block = data.get(section) or {}
    if not isinstance(block, dict):
        raise ConfigError(f"{section}: expected a mapping, got {type(block).__name__}")
    value = block.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
        raise ConfigError(f"{section}.{key}: expected a positive number, got {value!r}")
    return float(value)
