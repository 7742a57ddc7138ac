"""Build configuration: a YAML file validated into typed sections before any work starts.

Each section is a schema class (``config_schema``): every key's type, choices, bounds,
default and documentation are written once, in its field; ``docs/reference/config.md`` is
generated from them (``scripts/config_reference.py``). Relative paths in a config are
resolved against the config file's folder. Every error is one line naming the key
(``geometry.radius``), what was expected and, from ``load_config``, the file, line and column.
"""

from __future__ import annotations

import os
from collections.abc import Hashable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import AfterValidator, BeforeValidator, Field, PlainValidator, ValidationInfo
from pydantic import dataclasses as schema
from pydantic.functional_validators import model_validator

from mars_pairs.errors import ConfigError
from mars_pairs.geometry.body import MAX_RADIUS_M
from mars_pairs.pipeline.config_schema import (
    MAX_TEXT,
    SCHEMA,
    Expected,
    Flag,
    Integer,
    KeyProblem,
    Number,
    YamlMapping,
    base_of,
    read_section,
    shown,
)
from mars_pairs.pipeline.config_section import file_kind, regular_problem
from mars_pairs.store.members import DENSE_MEMBERS
from mars_pairs.store.splits import SPLIT_NAME

VIEWSHED_MODES = ("wedge", "raycast", "both")
#: View masks: "frustum" (default) = cells visible from the camera centre whose terrain point
#: projects inside the image; "band" = the study's mask, visible cells inside the image's
#: azimuth/elevation band (the rectangle the study used).
VIEW_MASKS = ("frustum", "band")
ORIENTATIONS = ("north-up", "heading-up")
IMAGE_ENCODINGS = ("png", "jpg")
SPLIT_STYLES = ("same-area", "cross-area")
SPLIT_GUARDS = ("chip", "footprint")
BUFFER_POLICIES = ("split", "drop")

MAX_CONFIG_BYTES = 1_000_000
# Upper bounds that keep one sample within memory and the numbers within meaning (metres).
MAX_OBSERVER_HEIGHT_M = 10_000.0
MAX_CHIP_SIZE_M = 200_000.0
MAX_CHIP_SIZE_PX = 8192  # 8192^2 float32 cells: 256 MB per chip
MAX_BLOCK_M = 10_000_000.0  # ~ Mars' circumference / 2
MAX_STRIDE_PX = 100_000
MAX_INT = 2**31 - 1
DEFAULT_MIN_COVERAGE = 0.5  # chips.min_coverage: a chip at least half on data
#: A synthetic mission's stops and images per stop: each image is rendered in memory and
#: written with its label, so these bound the generator's time and memory (the demo: 90 x 3).
MAX_SYNTHETIC_STOPS = 10_000
MAX_SYNTHETIC_IMAGES_PER_STOP = 64
#: An SPDX licence id or expression ("CC-BY-4.0", "MIT OR Apache-2.0"), in characters.
MAX_LICENSE_CHARS = 200


# --- value types of paths and names (the rest are config_schema's) ------------------------------


def _path(value: Any, info: ValidationInfo, *, folder: bool, exists: bool = False) -> Path:
    """A local path, relative to the config's folder, resolved; refused if it names a FIFO, a
    socket or a device (``regular_problem``) or, with ``exists``, nothing. A ``Path`` is
    taken as resolved already."""
    if isinstance(value, Path):
        return value
    if not isinstance(value, str) or not value.strip() or len(value) > MAX_TEXT:
        raise KeyProblem(f"expected a path, got {shown(value)}")
    base = base_of(info) or Path.cwd()
    try:
        resolved = (base / Path(value).expanduser()).resolve()
    except (OSError, RuntimeError) as exc:  # a symlink loop (RuntimeError before 3.13)
        raise KeyProblem(f"{value}: cannot resolve the path ({exc})") from None
    problem = regular_problem(resolved, folder=folder)
    if problem is not None:
        raise KeyProblem(problem)
    if exists and not resolved.exists():
        raise KeyProblem(f"{resolved}: no such {'folder' if folder else 'file'}")
    return resolved


def _file(value: Any, info: ValidationInfo) -> Path:
    return _path(value, info, folder=False)


def _folder(value: Any, info: ValidationInfo) -> Path:
    return _path(value, info, folder=True)


def _existing_folder(value: Any, info: ValidationInfo) -> Path:
    return _path(value, info, folder=True, exists=True)


def _raster(value: Any, info: ValidationInfo) -> Path | str:
    """A raster: a local path, or a URL read window by window (``/vsicurl/``, ``/vsis3/``)."""
    from mars_pairs.raster.vsi import gdal_path, is_remote, use_remote_defaults

    if isinstance(value, str) and is_remote(value):
        use_remote_defaults()
        return gdal_path(value)
    return _path(value, info, folder=False)


def _output_dir(value: Any, info: ValidationInfo) -> Path | str:
    """An fsspec URL (``s3://bucket/prefix``, its trailing ``/`` removed) or a local folder."""
    from mars_pairs.store.fs import collapsed_url_problem, dataset_root, is_url

    if is_url(value):
        root = dataset_root(value)
        assert isinstance(root, str)
        return root
    problem = collapsed_url_problem(value) if isinstance(value, (str, Path)) else None
    if problem is not None:
        raise KeyProblem(problem)
    return _path(value, info, folder=True)


def _walks_everything(pattern: str) -> bool:
    """True for a recursive glob (``**``) rooted at the file system's root (``/**/*.xml``):
    listing it would walk every mounted file system."""
    if "**" not in pattern:
        return False
    fixed = []
    for part in Path(os.path.normpath(pattern)).parts:
        if any(c in part for c in "*?["):
            break
        fixed.append(part)
    return len(fixed) <= 1


def _labels(value: Any, info: ValidationInfo) -> tuple[str, ...]:
    """Glob patterns, absolute (relative ones against the config's folder)."""
    items = [value] if isinstance(value, str) else value
    ok = isinstance(items, (list, tuple)) and len(items) > 0
    ok = ok and all(isinstance(p, str) and p.strip() and len(p) <= MAX_TEXT for p in items)
    if not ok:
        raise KeyProblem(f"expected a glob or a list of globs, got {shown(value)}")
    base = base_of(info) or Path.cwd()
    patterns = tuple(str(base / Path(p).expanduser()) for p in items)
    for given, pattern in zip(items, patterns, strict=True):
        if _walks_everything(pattern):
            raise KeyProblem(
                f"{given!r} would walk the whole file system (a '**' from {os.sep}); "
                "start it at the labels' folder"
            )
    return patterns


def _members(value: Any) -> tuple[str, ...]:
    """``output.members``: a list of optional member names, or "all" (in the list or alone),
    in ``DENSE_MEMBERS`` order."""
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, (list, tuple)) or not all(isinstance(v, str) for v in items):
        raise KeyProblem(f"expected a list of member names, got {shown(value)}")
    unknown = [v for v in items if v != "all" and v not in DENSE_MEMBERS]
    if unknown:
        raise KeyProblem(
            f"unknown member {shown(unknown[0])}; expected some of {list(DENSE_MEMBERS)} or 'all'"
        )
    if "all" in items:
        return DENSE_MEMBERS
    return tuple(m for m in DENSE_MEMBERS if m in items)


LocalFile = Annotated[Path, PlainValidator(_file), Expected("a path (relative: to the config)")]
LocalFolder = Annotated[
    Path, PlainValidator(_folder), Expected("a folder (relative: to the config)")
]
Raster = Annotated[
    Path | str,
    PlainValidator(_raster),
    Expected("a path (relative: to the config) or an http(s):// or s3:// URL"),
]
Fraction = Annotated[Number, Field(ge=0.0, le=1.0)]
Box = tuple[Number, Number, Number, Number]


# --- the sections -------------------------------------------------------------------------------


@schema.dataclass(frozen=True, config=SCHEMA)
class SyntheticSpec:
    """Generate the synthetic mission into ``root`` when its files are absent (the demo)."""

    root: Annotated[Path, PlainValidator(_folder), Expected("a folder (relative: to the config)")]
    """The mission's folder: labels/, images/, places/ and orbital/ are written under it."""
    mission: Literal["m2020", "msl"] = "m2020"
    """Which rover's labels to write: m2020 (PDS4, Mastcam-Z/Navcam) or msl (PDS3, Mastcam)."""
    seed: Annotated[Integer, Field(ge=0, le=MAX_INT)] = 0
    """Random seed of the terrain, the traverse and the pointing."""
    stops: Annotated[Integer, Field(ge=1, le=MAX_SYNTHETIC_STOPS)] = 6
    """Rover stops along the traverse."""
    images_per_stop: Annotated[Integer, Field(ge=1, le=MAX_SYNTHETIC_IMAGES_PER_STOP)] = 4
    """Images taken at each stop."""
    size: Literal["small", "default", "demo"] = "small"
    """Raster and image sizes: small (tests), default, demo (a 3 km DEM, 0.5 m ortho)."""


def _class_table(value: Any) -> dict[int, str]:
    """``inputs.terrain_labels.classes``: {mask value: class name} (``ClassTable``)."""
    from mars_pairs.terrain_labels import ClassTable

    try:
        return dict(ClassTable.from_mapping(value, "classes").names)
    except ConfigError as exc:
        raise KeyProblem(str(exc).removeprefix("classes: ")) from None


@schema.dataclass(frozen=True, config=SCHEMA)
class TerrainLabelsSpec:
    """Terrain labels of the ground images (``mars_pairs.terrain_labels``), read by product id."""

    format: Literal["ai4mars", "folder"]
    """ai4mars: the AI4Mars release's layout under ``root``; folder: ``root/<product id>.png``
    class masks with the ``classes`` table."""
    root: LocalFolder
    """The labels' folder."""
    classes: (
        Annotated[
            dict[int, str],
            PlainValidator(_class_table),
            Expected("a mapping of mask value (0..254) to a lower-case class name"),
        ]
        | None
    ) = None
    """format folder: the class of each mask value (255: no label); ai4mars: its own table."""
    max_range_m: Annotated[Number, Field(gt=0.0, le=MAX_RADIUS_M)] | None = None
    """Nothing farther from the camera is carried onto the map (metres); null: the layout's
    own limit (AI4Mars Navcam labels: 30 m)."""
    test_set: Annotated[str, Field(min_length=1, max_length=200, strict=True)] | None = None
    """ai4mars: the gold test folder read (default masked-gold-min3-100agree)."""

    @model_validator(mode="before")
    @classmethod
    def _format_keys(cls, data: Any) -> Any:
        """A folder of masks needs its class table; the AI4Mars layout has its own."""
        if not isinstance(data, dict):
            return data
        fmt, classes = data.get("format"), data.get("classes")
        if fmt == "folder" and classes is None:
            raise KeyProblem("a folder of masks needs its class table", "classes")
        if fmt == "ai4mars" and classes is not None:
            raise KeyProblem("the AI4Mars layout has its own class table", "classes")
        if fmt != "ai4mars" and data.get("test_set") is not None:
            raise KeyProblem("the AI4Mars gold test folder name (format ai4mars)", "test_set")
        return data


@schema.dataclass(frozen=True, config=SCHEMA)
class InputsConfig:
    """Where the labels, images, PLACES table and orbital rasters are."""

    labels: Annotated[
        tuple[str, ...], PlainValidator(_labels), Expected("a glob or a list of globs")
    ]
    """PDS3 (.LBL) or PDS4 (.xml) labels: glob patterns (``**`` recurses), relative to the
    config's folder; a recursive glob from the file system's root is refused."""
    places: LocalFile
    """The PLACES localizations table (CSV; ``.csv.gz`` too) giving each site/drive's position."""
    dem: Raster
    """The orbital DEM (metres above the datum, a projected CRS): a local file or a URL."""
    ortho: Raster
    """The orbital orthoimage, in the DEM's CRS: a local file or a URL."""
    images: (
        Annotated[
            Path,
            PlainValidator(_existing_folder),
            Expected("an existing folder (relative: to the config)"),
        ]
        | None
    ) = None
    """A folder to look for images in, besides each label's own folder (null: none)."""
    synthetic: SyntheticSpec | None = None
    """Generate a synthetic mission before the build (the demo); null: none."""
    terrain_labels: TerrainLabelsSpec | None = None
    """Terrain labels of the ground images, carried onto the map (members ``terrain`` and
    ``terrain_on_map``); null: none."""


@schema.dataclass(frozen=True, config=SCHEMA)
class GeometryConfig:
    """Observer, viewshed and ray casting parameters (metres, degrees)."""

    observer_height: Annotated[Number, Field(gt=0.0, le=MAX_OBSERVER_HEIGHT_M)] | None = None
    """The observer's height above the terrain (metres); null: the camera centre's height
    from the label."""
    radius: Annotated[Number, Field(gt=0.0, le=MAX_RADIUS_M)] = 2000.0
    """Viewshed radius around the rover (metres)."""
    viewshed: Literal["wedge", "raycast", "both"] = "both"
    """Which viewshed to compute: the terrain wedge, the image's rays, or both."""
    view_mask: Literal["frustum", "band"] = "frustum"
    """frustum: the cells visible from the camera centre whose terrain point projects inside
    the image; band: the visible cells inside the image's azimuth/elevation band."""
    ray_stride: Annotated[Integer, Field(ge=1, le=MAX_STRIDE_PX)] = 8
    """Image pixels between cast rays (both axes)."""


@schema.dataclass(frozen=True, config=SCHEMA)
class ChipsConfig:
    """Orbital chips: a square of ``size_m`` metres sampled at ``size_px`` pixels."""

    size_m: Annotated[Number, Field(gt=0.0, le=MAX_CHIP_SIZE_M)] = 256.0
    """A chip's side on the ground (metres)."""
    size_px: Annotated[Integer, Field(ge=8, le=MAX_CHIP_SIZE_PX)] = 512
    """A chip's side in pixels."""
    orientation: Literal["north-up", "heading-up"] = "north-up"
    """north-up, or heading-up (the camera azimuth points up)."""
    min_coverage: Fraction = DEFAULT_MIN_COVERAGE
    """The least fraction of an ortho or DEM chip's pixels with data; a sample below it (or
    with none at all) is a failure row (CoverageError)."""
    offset_m: Annotated[Number, Field(ge=0.0, le=MAX_CHIP_SIZE_M)] | None = None
    """The largest chip-centre shift from the rover, per axis (metres); null: none."""


@schema.dataclass(frozen=True, config=SCHEMA)
class OutputConfig:
    """The dataset folder, samples per shard, and what the samples hold."""

    dir: Annotated[
        Path | str,
        PlainValidator(_output_dir),
        Expected("a folder (relative: to the config) or an s3:// (fsspec) URL"),
    ]
    """The dataset folder: a local folder, or an fsspec URL (``s3://bucket/prefix``)."""
    shard_size: Annotated[Integer, Field(ge=1, le=MAX_INT)] = 64
    """Samples per tar shard."""
    image_encoding: Literal["png", "jpg"] = "png"
    """The encoding of decoded (IMG) ground images; JPEG/PNG images are kept as they are."""
    license: (
        Annotated[
            str,
            Field(min_length=1, max_length=MAX_LICENSE_CHARS, pattern=r"\S", strict=True),
            Expected(f"an SPDX licence id of at most {MAX_LICENSE_CHARS} characters"),
        ]
        | None
    ) = None
    """The SPDX id the dataset card and croissant.json give; null: CC0-1.0 for NASA PDS data
    (public domain), MIT (the project's) for the synthetic mission."""
    keep_parts: Flag = False
    """Keep ``parts/`` (the chunk parts and the build stamp) after a finished build, so that
    deleting a chunk's part and resuming redoes that chunk alone."""
    pairs: Flag = False
    """Also write ``pairs.parquet``: every pair of samples whose footprints overlap, with the
    two samples' splits and ``cross_split`` (the pair spans a split boundary)."""
    members: Annotated[
        tuple[str, ...],
        PlainValidator(_members),
        Expected(f"a list of some of {list(DENSE_MEMBERS)}, or 'all'"),
    ] = ()
    """Optional dense members each sample also holds."""
    dense_stride: Annotated[Integer, Field(ge=1, le=MAX_STRIDE_PX)] | None = None
    """Image pixels between the dense members' grid points; null: ``geometry.ray_stride``."""


def _ratios(value: dict[str, float]) -> dict[str, float]:
    if not value or abs(sum(value.values()) - 1.0) > 1e-6:
        raise KeyProblem(
            f"expected a mapping of split name to a fraction, summing to 1, got {shown(value)}"
        )
    if "buffer" in value:
        raise KeyProblem("'buffer' is reserved for the samples in the buffer")
    _split_names(value)
    return value


def _split_names(names: Any) -> None:
    """Split names name the split's shards: lowercase letters, digits and '_'."""
    for name in names:
        if not SPLIT_NAME.fullmatch(str(name)):
            raise KeyProblem(
                f"split name {name!r}: expected lowercase letters, digits and '_', starting "
                "with a letter (it names the split's shards)",
                name,
            )


def _one_box(value: Any) -> Any:
    """``{test: [x0, y0, x1, y1]}`` is ``{test: [[x0, y0, x1, y1]]}``."""
    if isinstance(value, dict):
        return {
            k: [v] if isinstance(v, list) and v and not isinstance(v[0], list) else v
            for k, v in value.items()
        }
    return value


Areas = dict[str, tuple[Box, ...]]


def _areas(value: Areas) -> Areas:
    _split_names(value)
    for name, boxes in value.items():
        if name in ("train", "buffer"):
            raise KeyProblem(f"expected a held-out split name (not {name!r})", name)
        if not boxes or not all(b[0] < b[2] and b[1] < b[3] for b in boxes):
            raise KeyProblem(
                "expected a list of map boxes [xmin, ymin, xmax, ymax] with xmin < xmax and "
                f"ymin < ymax, got {shown([list(b) for b in boxes])}",
                name,
            )
    names = list(value)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            for p in value[a]:
                for q in value[b]:
                    if p[0] < q[2] and q[0] < p[2] and p[1] < q[3] and q[1] < p[3]:
                        raise KeyProblem(f"{a} box {list(p)} overlaps {b} {list(q)}")
    return value


@schema.dataclass(frozen=True, config=SCHEMA)
class SplitsConfig:
    """Leak-free spatial splits (map units of the dataset CRS; see ``store/splits.py``).

    same-area: blocks of ``block_m`` go whole into a split drawn by ``ratios``; cross-area:
    the ``areas`` are held out and everything else is train. Samples in the buffer between
    held-out regions and the other splits become split ``buffer`` or are dropped."""

    style: Literal["same-area", "cross-area"] = "same-area"
    """same-area (blocks drawn by ratios) or cross-area (held-out areas)."""
    block_m: Annotated[Number, Field(gt=0.0, le=MAX_BLOCK_M)] = 10000.0
    """same-area: the side of the square blocks (map units)."""
    ratios: Annotated[
        dict[Annotated[str, Field(strict=True)], Annotated[Number, Field(ge=0.0)]],
        AfterValidator(_ratios),
        Expected("a mapping of split name to a fraction >= 0, the fractions summing to 1"),
    ] = field(default_factory=lambda: {"train": 0.8, "val": 0.1, "test": 0.1})
    """same-area: split name -> the fraction of blocks drawn into it (summing to 1)."""
    seed: Annotated[Integer, Field(ge=0, le=MAX_INT)] = 0
    """same-area: the seed of the blocks' draw."""
    areas: Annotated[
        dict[Annotated[str, Field(strict=True)], tuple[Box, ...]],
        BeforeValidator(_one_box),
        AfterValidator(_areas),
        Expected(
            "a mapping of held-out split name to a list of map boxes [xmin, ymin, xmax, ymax]"
        ),
    ] = field(default_factory=dict)
    """cross-area: held-out split name -> map boxes [xmin, ymin, xmax, ymax] (dataset CRS);
    the boxes of different splits may not overlap."""
    guard: Literal["chip", "footprint"] = "footprint"
    """What must not intersect across splits: the chips (chip), or the chips and the images'
    footprints (footprint)."""
    buffer_m: Annotated[Number, Field(ge=0.0, le=MAX_BLOCK_M)] | None = None
    """The gap kept between held-out regions and the other splits (map units); null: the
    guard's reach, at least the chip size."""
    buffer_policy: Literal["split", "drop"] = "split"
    """split: samples in the buffer get split ``buffer``; drop: they are left out."""

    @model_validator(mode="before")
    @classmethod
    def _style_keys(cls, data: Any) -> Any:
        """Keys of one style given with the other are refused; cross-area needs areas."""
        if not isinstance(data, dict):
            return data
        style = data.get("style", "same-area")
        if not isinstance(style, str):
            return data  # refused as a choice
        unused = {"same-area": ("areas",), "cross-area": ("block_m", "ratios")}.get(style, ())
        for key in unused:
            if data.get(key) is not None:
                raise KeyProblem(f"not used with splits.style {style!r}", key)
        if style == "cross-area" and not data.get("areas"):
            raise KeyProblem(
                "expected a mapping of held-out split name to a list of map boxes "
                f"[xmin, ymin, xmax, ymax] (style cross-area), got {shown(data.get('areas'))}",
                "areas",
            )
        return data


@dataclass(frozen=True)
class BuildConfig:
    """A whole build configuration."""

    inputs: InputsConfig
    geometry: GeometryConfig
    chips: ChipsConfig
    output: OutputConfig
    splits: SplitsConfig
    source: Path | None = None

    def to_dict(self) -> dict[str, Any]:
        """Plain values (paths as strings) for dataset.json."""

        def plain(value: Any) -> Any:
            if isinstance(value, Path):
                return str(value)
            if isinstance(value, dict):
                return {k: plain(v) for k, v in value.items()}
            if isinstance(value, (list, tuple)):
                return [plain(v) for v in value]
            return value

        doc: dict[str, Any] = plain(asdict(self))
        # opt-in keys appear only when set: a default config's fingerprint stays as it was
        for section, key, unset in _OPT_IN_KEYS:
            if doc[section].get(key) == unset:
                doc[section].pop(key)
        return doc


#: (section, key, unset value) of the opt-in keys left out of ``BuildConfig.to_dict``.
_OPT_IN_KEYS: tuple[tuple[str, str, object], ...] = (
    ("chips", "offset_m", None),
    ("output", "members", []),
    ("output", "dense_stride", None),
    ("inputs", "terrain_labels", None),
)

#: The build config's sections, in order: (YAML key, schema class, required).
SECTIONS: tuple[tuple[str, type, bool], ...] = (
    ("inputs", InputsConfig, True),
    ("geometry", GeometryConfig, False),
    ("chips", ChipsConfig, False),
    ("output", OutputConfig, True),
    ("splits", SplitsConfig, False),
)
#: Top-level keys besides the build's sections: "fetch" is read by ``mars_pairs.fetch.config``.
OTHER_TOP_KEYS = ("fetch",)


def parse_config(data: Any, base: Path, source: Path | None = None) -> BuildConfig:
    """Validate a config mapping (relative paths against ``base``) into a BuildConfig."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"expected a mapping at the top level, got {type(data).__name__}")
    known = [name for name, _, _ in SECTIONS] + list(OTHER_TOP_KEYS)
    lines = data.lines if isinstance(data, YamlMapping) else {}
    for key in data:
        if key not in known:
            name = key if isinstance(key, str) and len(key) <= 120 else shown(key)
            raise ConfigError(
                f"{name}: unknown key (expected one of {sorted(known)})", line=lines.get(key)
            )
    read: dict[str, Any] = {}
    for name, cls, required in SECTIONS:
        if required and data.get(name) is None:
            raise ConfigError(f"{name}: required section is missing", line=lines.get(name))
        read[name] = read_section(cls, data.get(name), name, base, line=lines.get(name))
    return BuildConfig(**read, source=source)


#: A config's YAML may use anchors and aliases, but the document they expand to is bounded:
#: nodes plus scalar characters, counted with every alias expanded (a ~300-byte "billion
#: laughs" document expands to 10^9 nodes and would hang whatever formats it).
MAX_CONFIG_EXPANDED = 2 * MAX_CONFIG_BYTES


class _ConfigLoader(yaml.SafeLoader):
    """PyYAML's SafeLoader that refuses a key given twice in one mapping (naming the key and
    both lines) and a document whose aliases expand beyond ``MAX_CONFIG_EXPANDED`` or into
    themselves."""

    def construct_document(self, node: yaml.Node) -> Any:
        _check_expansion(node)
        return super().construct_document(node)

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Hashable, Any]:
        if isinstance(node, yaml.MappingNode):
            first: dict[Any, str] = {}
            for key_node, _ in node.value:  # before flattening: merged keys are not here
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue  # "<<": merged keys may be overridden, as YAML says
                key = self.construct_object(key_node, deep=True)
                mark = key_node.start_mark
                where = f"{mark.line + 1}:{mark.column + 1}"
                try:
                    seen = first.setdefault(key, where)
                except TypeError:  # an unhashable key: SafeLoader names it
                    continue
                if seen != where:
                    raise ConfigError(
                        f"duplicate key {shown(key)} at line:column {seen} and {where} "
                        "(a key may appear once in a mapping)"
                    )
        return super().construct_mapping(node, deep=deep)

    def construct_marked_mapping(self, node: yaml.MappingNode) -> Any:
        """A mapping as a ``YamlMapping``: its keys' lines and columns kept, for errors."""
        data = YamlMapping()
        data.start = (node.start_mark.line + 1, node.start_mark.column + 1)
        yield data
        data.update(self.construct_mapping(node))
        for key_node, _ in node.value:  # flattened by now: merged keys point at their anchor
            try:
                key = self.construct_object(key_node)
                data.lines.setdefault(key, (key_node.start_mark.line + 1,
                                            key_node.start_mark.column + 1))  # fmt: skip
            except TypeError:  # an unhashable key (SafeLoader refused it already)
                continue


_ConfigLoader.add_constructor("tag:yaml.org,2002:map", _ConfigLoader.construct_marked_mapping)


def _check_expansion(root: yaml.Node) -> None:
    """ConfigError if the document under ``root``, every alias expanded, holds more than
    ``MAX_CONFIG_EXPANDED`` nodes plus scalar characters, or an alias inside its own anchor.
    Each node is sized once (an alias is the node it names), so a bomb is refused at once."""
    size: dict[int, int] = {}
    open_: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, done = stack.pop()
        ident = id(node)
        if isinstance(node, yaml.ScalarNode):
            size[ident] = 1 + len(node.value)
            continue
        children = (
            [n for pair in node.value for n in pair]
            if isinstance(node, yaml.MappingNode)
            else list(node.value)
        )
        if done:
            open_.discard(ident)
            size[ident] = 1 + sum(size[id(c)] for c in children)
            if size[ident] > MAX_CONFIG_EXPANDED:
                raise ConfigError(
                    f"line {node.start_mark.line + 1}: its aliases expand the config beyond "
                    f"{MAX_CONFIG_EXPANDED} nodes and characters"
                )
            continue
        if ident in size:
            continue
        if ident in open_:
            raise ConfigError(
                f"line {node.start_mark.line + 1}: an alias inside its own anchor (a recursive "
                "value)"
            )
        open_.add(ident)
        stack.append((node, True))
        stack.extend((c, False) for c in children if id(c) not in size)


def _yaml_problem(exc: yaml.YAMLError) -> str:
    """A PyYAML error on one line: ``LINE:COLUMN: not valid YAML: problem (context at line
    N)`` (PyYAML's own takes 4 or 5 lines)."""
    if isinstance(exc, yaml.MarkedYAMLError):
        mark = exc.problem_mark or exc.context_mark
        text = " ".join(str(exc.problem or exc.context or "").split())
        where = f"{mark.line + 1}:{mark.column + 1}:" if mark is not None else ""
        if exc.problem and exc.context:
            context = " ".join(str(exc.context).split())
            at = f" at line {exc.context_mark.line + 1}" if exc.context_mark is not None else ""
            text += f" ({context}{at})"
        return f"{where} not valid YAML: {text}"
    return f" not valid YAML: {' '.join(str(exc).split())}"


def read_yaml(path: str | Path) -> Any:
    """The YAML document of the config file at ``path``: a regular file (checked on the open
    file: a FIFO or a device is refused, never read) of at most ``MAX_CONFIG_BYTES`` of UTF-8,
    without a key twice in one mapping, its aliases expanding within ``MAX_CONFIG_EXPANDED``.
    Every error is one ConfigError line naming the file (and the line and column)."""
    path = Path(path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)  # a FIFO opens without a writer
        with open(fd, "rb") as f:
            kind = file_kind(os.fstat(fd).st_mode)
            if kind is not None:
                raise ConfigError(f"{path}: cannot read config: not a regular file ({kind})")
            raw = f.read(MAX_CONFIG_BYTES + 1)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read config: {exc.strerror or exc}") from None
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{path}: cannot read config: larger than {MAX_CONFIG_BYTES} bytes")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{path}: not UTF-8 text (byte {exc.start}: {raw[exc.start : exc.start + 4]!r})"
        ) from None
    try:
        return yaml.load(text, Loader=_ConfigLoader)  # a SafeLoader
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}:{_yaml_problem(exc)}") from None
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    except RecursionError:
        raise ConfigError(f"{path}: not valid YAML: nested too deeply") from None


def in_file(path: Path, exc: ConfigError) -> ConfigError:
    """``exc`` about the config file ``path``: ``path:LINE:COLUMN: message`` (``path:
    message`` when the line is not known)."""
    where = f"{path}:{exc.line[0]}:{exc.line[1]}" if exc.line else str(path)
    return ConfigError(f"{where}: {exc}", line=exc.line)


def load_config(path: str | Path) -> BuildConfig:
    """Read and validate a YAML build config (``read_yaml``)."""
    path = Path(path)
    data = read_yaml(path)
    try:
        return parse_config(data, path.resolve().parent, source=path.resolve())
    except ConfigError as exc:
        raise in_file(path, exc) from None
