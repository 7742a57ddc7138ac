"""Build configuration: a YAML file validated into typed dataclasses before any work starts.

Relative paths in a config are resolved against the config file's folder. Every error names
the key (``geometry.radius``) and what was expected.
"""

from __future__ import annotations

import os
from collections.abc import Hashable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

from mars_pairs.errors import ConfigError
from mars_pairs.pipeline.config_section import Section, file_kind, shown
from mars_pairs.store.members import DENSE_MEMBERS

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
MAX_RADIUS_M = 200_000.0  # viewshed radius: ~3.4 degrees of Mars
MAX_OBSERVER_HEIGHT_M = 10_000.0
MAX_CHIP_SIZE_M = 200_000.0
MAX_CHIP_SIZE_PX = 8192  # 8192^2 float32 cells: 256 MB per chip
MAX_BLOCK_M = 10_000_000.0  # ~ Mars' circumference / 2
DEFAULT_MIN_COVERAGE = 0.5  # chips.min_coverage: a chip at least half on data


@dataclass(frozen=True)
class SyntheticSpec:
    """Generate the synthetic mission into ``root`` when its files are absent (demo)."""

    root: Path
    mission: str = "m2020"
    seed: int = 0
    stops: int = 6
    images_per_stop: int = 4
    size: str = "small"


@dataclass(frozen=True)
class TerrainLabelsSpec:
    """Terrain labels of the ground images (``mars_pairs.terrain_labels``): ``format``
    ai4mars (the AI4Mars layout under ``root``) or folder (``root/<product id>.png`` with the
    ``classes`` table); ``max_range_m``: nothing farther from the camera is carried onto the
    map (ai4mars: 30 for Navcam labels, from the layout)."""

    format: str
    root: Path
    classes: dict[int, str] | None = None
    max_range_m: float | None = None
    test_set: str | None = None  # ai4mars: the gold test folder read (default min3)


@dataclass(frozen=True)
class InputsConfig:
    """Where the labels, images, PLACES table and orbital rasters are."""

    labels: tuple[str, ...]  # glob patterns (absolute after loading)
    places: Path
    dem: Path | str  # a local path, or a GDAL path to a remote raster ("/vsicurl/https://...")
    ortho: Path | str
    images: Path | None = None  # a folder to look for images in, besides the label's folder
    synthetic: SyntheticSpec | None = None
    terrain_labels: TerrainLabelsSpec | None = None


@dataclass(frozen=True)
class GeometryConfig:
    """Observer, viewshed and ray casting parameters (metres, degrees)."""

    observer_height: float | None = None  # above the terrain; None: the camera centre's height
    radius: float = 2000.0  # metres
    viewshed: str = "both"  # wedge | raycast | both
    view_mask: str = "frustum"  # frustum (what the image saw) | band (the study's az/el band)
    ray_stride: int = 8  # pixels


@dataclass(frozen=True)
class ChipsConfig:
    """Orbital chips: a square of ``size_m`` metres sampled at ``size_px`` pixels.

    ``min_coverage``: the least fraction (0..1) of an ortho or DEM chip's pixels with data;
    a sample below it (or with none at all) is a failure row (CoverageError).
    """

    size_m: float = 256.0
    size_px: int = 512
    orientation: str = "north-up"  # or heading-up (the camera azimuth points up)
    min_coverage: float = DEFAULT_MIN_COVERAGE
    offset_m: float | None = None  # largest chip-centre shift from the rover (per axis, metres)


@dataclass(frozen=True)
class OutputConfig:
    """Dataset folder, samples per shard and the encoding of decoded (IMG) ground images.

    ``license``: the SPDX id the dataset card and croissant.json give (None: CC0-1.0 for
    NASA PDS data, public domain; the project's MIT for the synthetic mission).
    ``keep_parts``: keep ``parts/`` (the chunk parts and build stamp) after a finished build,
    so that deleting a chunk's part and resuming redoes that chunk alone."""

    dir: Path | str  # a local folder, or an fsspec URL ("s3://bucket/prefix": store.fs)
    shard_size: int = 64
    image_encoding: str = "png"
    license: str | None = None
    keep_parts: bool = False
    members: tuple[str, ...] = ()  # optional dense members (store.members.DENSE_MEMBERS)
    dense_stride: int | None = None  # pixels of the dense grid (None: geometry.ray_stride)


@dataclass(frozen=True)
class SplitsConfig:
    """Leak-free spatial splits (map units of the dataset CRS; see ``store/splits.py``).

    ``style`` same-area: blocks of ``block_m`` go whole into a split drawn by ``ratios``;
    cross-area: the ``areas`` (split -> map boxes xmin, ymin, xmax, ymax) are held out and
    everything else is train. ``guard``: what must not intersect across splits, the chips
    (``chip``) or the chips and footprints (``footprint``). ``buffer_m``: the gap kept
    between held-out regions and other splits' extents (None: the guard's reach, at least the
    chip size); samples in it become split ``buffer`` or are dropped (``buffer_policy``).
    """

    style: str = "same-area"
    block_m: float = 10000.0
    ratios: dict[str, float] = field(
        default_factory=lambda: {"train": 0.8, "val": 0.1, "test": 0.1}
    )
    seed: int = 0
    areas: dict[str, tuple[tuple[float, float, float, float], ...]] = field(default_factory=dict)
    guard: str = "footprint"
    buffer_m: float | None = None
    buffer_policy: str = "split"


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


def _inputs(data: Any, base: Path) -> InputsConfig:
    known = {"labels", "places", "dem", "ortho", "images", "synthetic", "terrain_labels"}
    sec = Section(data, "inputs", known)
    labels = sec.raw("labels")
    if isinstance(labels, str):
        labels = [labels]
    if not isinstance(labels, list) or not labels or not all(isinstance(x, str) for x in labels):
        raise ConfigError(f"inputs.labels: expected a glob or a list of globs, got {labels!r}")
    synthetic = None
    if sec.raw("synthetic", None) is not None:
        syn = Section(
            sec.raw("synthetic"),
            "inputs.synthetic",
            {"root", "mission", "seed", "stops", "images_per_stop", "size"},
        )
        synthetic = SyntheticSpec(
            root=syn.path("root", base),
            mission=syn.choice("mission", ("m2020", "msl"), "m2020"),
            seed=syn.integer("seed", 0, minimum=0),
            stops=syn.integer("stops", 6),
            images_per_stop=syn.integer("images_per_stop", 4),
            size=syn.choice("size", ("small", "default", "demo"), "small"),
        )
    return InputsConfig(
        labels=tuple(str(base / Path(p).expanduser()) for p in labels),
        places=sec.path("places", base, folder=False),
        dem=sec.raster("dem", base),
        ortho=sec.raster("ortho", base),
        images=sec.path("images", base, None),
        synthetic=synthetic,
        terrain_labels=_terrain_labels(sec.raw("terrain_labels", None), base),
    )


def _terrain_labels(data: Any, base: Path) -> TerrainLabelsSpec | None:
    """``inputs.terrain_labels``: {format: ai4mars | folder, root, classes, max_range_m}."""
    if data is None:
        return None
    from mars_pairs.terrain_labels import FORMATS, ClassTable

    key = "inputs.terrain_labels"
    sec = Section(data, key, {"format", "root", "classes", "max_range_m", "test_set"})
    fmt = sec.choice("format", FORMATS)
    classes = sec.raw("classes", None)
    if fmt == "folder" and classes is None:
        raise ConfigError(f"{key}.classes: a folder of masks needs its class table")
    if fmt == "ai4mars" and classes is not None:
        raise ConfigError(f"{key}.classes: the AI4Mars layout has its own class table")
    table = (
        None if classes is None else dict(ClassTable.from_mapping(classes, f"{key}.classes").names)
    )
    test_set = sec.raw("test_set", None)
    if test_set is not None and (fmt != "ai4mars" or not isinstance(test_set, str)):
        raise ConfigError(f"{key}.test_set: the AI4Mars gold test folder name (format ai4mars)")
    return TerrainLabelsSpec(
        format=fmt,
        root=sec.path("root", base),
        classes=table,
        max_range_m=sec.number("max_range_m", None, maximum=MAX_RADIUS_M),
        test_set=test_set,
    )


def _splits(data: Any) -> SplitsConfig:
    known = {"style", "block_m", "ratios", "seed", "areas", "guard", "buffer_m", "buffer_policy"}
    sec = Section(data, "splits", known)
    style = sec.choice("style", SPLIT_STYLES, "same-area")
    only = {"same-area": ("areas",), "cross-area": ("block_m", "ratios")}[style]
    for key in only:
        if sec.raw(key, None) is not None:
            raise ConfigError(f"splits.{key}: not used with splits.style {style!r}")
    ratios = sec.raw("ratios", {"train": 0.8, "val": 0.1, "test": 0.1})
    ok = (
        isinstance(ratios, dict)
        and ratios
        and all(
            isinstance(k, str)
            and isinstance(v, (int, float))
            and not isinstance(v, bool)
            and v >= 0
            for k, v in ratios.items()
        )
    )
    if not ok or abs(sum(ratios.values()) - 1.0) > 1e-6:
        raise ConfigError(
            f"splits.ratios: expected a mapping of split name to a fraction, summing to 1, "
            f"got {ratios!r}"
        )
    areas = _areas(sec.raw("areas", None)) if style == "cross-area" else {}
    for name in (*ratios, *areas):
        if name == "buffer":
            raise ConfigError("splits: 'buffer' is reserved for the samples in the buffer")
    buffer_m = sec.number("buffer_m", None, positive=False)
    if buffer_m is not None and buffer_m < 0:
        raise ConfigError(f"splits.buffer_m: expected a distance >= 0, got {buffer_m!r}")
    return SplitsConfig(
        style=style,
        block_m=sec.number("block_m", 10000.0, maximum=MAX_BLOCK_M),
        ratios={str(k): float(v) for k, v in ratios.items()},
        seed=sec.integer("seed", 0, minimum=0),
        areas=areas,
        guard=sec.choice("guard", SPLIT_GUARDS, "footprint"),
        buffer_m=buffer_m,
        buffer_policy=sec.choice("buffer_policy", BUFFER_POLICIES, "split"),
    )


def _members(value: Any) -> tuple[str, ...]:
    """``output.members``: a list of optional member names, or "all" (in the list or alone)."""
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, list) or not all(isinstance(v, str) for v in items):
        raise ConfigError(f"output.members: expected a list of member names, got {shown(value)}")
    unknown = [v for v in items if v != "all" and v not in DENSE_MEMBERS]
    if unknown:
        raise ConfigError(
            f"output.members: unknown member {unknown[0]!r}; expected some of "
            f"{list(DENSE_MEMBERS)} or 'all'"
        )
    if "all" in items:
        return DENSE_MEMBERS
    return tuple(m for m in DENSE_MEMBERS if m in items)


def _output_dir(out: Section, base: Path) -> Path | str:
    """``output.dir``: an fsspec URL (``s3://bucket/prefix``, its trailing ``/`` removed) or a
    local folder relative to ``base``."""
    from mars_pairs.store.fs import dataset_root, is_url

    value = out.raw("dir")
    if is_url(value):
        return dataset_root(value)
    return out.path("dir", base)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _areas(data: Any) -> dict[str, tuple[tuple[float, float, float, float], ...]]:
    """Cross-area held-out areas: split name -> list of map boxes [xmin, ymin, xmax, ymax]."""
    if not isinstance(data, dict) or not data:
        raise ConfigError(
            "splits.areas: expected a mapping of held-out split name to a list of map boxes "
            f"[xmin, ymin, xmax, ymax] (style cross-area), got {data!r}"
        )
    areas: dict[str, tuple[tuple[float, float, float, float], ...]] = {}
    for name, boxes in data.items():
        key = f"splits.areas.{name}"
        if not isinstance(name, str) or name == "train":
            raise ConfigError(f"{key}: expected a held-out split name (not 'train')")
        if isinstance(boxes, list) and boxes and not isinstance(boxes[0], list):
            boxes = [boxes]
        good = isinstance(boxes, list) and boxes
        out: list[tuple[float, float, float, float]] = []
        for box in boxes if good else []:
            nums = isinstance(box, list) and len(box) == 4
            nums = nums and all(_is_number(v) for v in box)
            if not nums or not (box[0] < box[2] and box[1] < box[3]):
                good = False
                break
            xmin, ymin, xmax, ymax = (float(v) for v in box)
            out.append((xmin, ymin, xmax, ymax))
        if not good:
            raise ConfigError(
                f"{key}: expected a list of map boxes [xmin, ymin, xmax, ymax] with xmin < xmax "
                f"and ymin < ymax, got {boxes!r}"
            )
        areas[name] = tuple(out)
    names = list(areas)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            for p in areas[a]:
                for q in areas[b]:
                    if p[0] < q[2] and q[0] < p[2] and p[1] < q[3] and q[1] < p[3]:
                        raise ConfigError(f"splits.areas: {a} box {list(p)} overlaps {b} {list(q)}")
    return areas


def parse_config(data: Any, base: Path, source: Path | None = None) -> BuildConfig:
    """Validate a config mapping (relative paths against ``base``) into a BuildConfig."""
    # "fetch" is read by mars_pairs.fetch.config (mars-pairs fetch), not by the build
    top = Section(data, "", {"inputs", "geometry", "chips", "output", "splits", "fetch"})
    geo = Section(
        top.raw("geometry", {}),
        "geometry",
        {"observer_height", "radius", "viewshed", "view_mask", "ray_stride"},
    )
    chips = Section(
        top.raw("chips", {}),
        "chips",
        {"size_m", "size_px", "orientation", "min_coverage", "offset_m"},
    )
    min_coverage = chips.number("min_coverage", DEFAULT_MIN_COVERAGE, positive=False, maximum=1.0)
    if min_coverage < 0.0:
        raise ConfigError(f"chips.min_coverage: expected a fraction in [0, 1], got {min_coverage}")
    out = Section(
        top.raw("output"),
        "output",
        {"dir", "shard_size", "image_encoding", "license", "keep_parts", "members", "dense_stride"},
    )
    license = out.raw("license", None)
    if license is not None and (not isinstance(license, str) or not license.strip()):
        raise ConfigError(f"output.license: expected an SPDX licence id, got {license!r}")
    keep_parts = out.raw("keep_parts", False)
    if not isinstance(keep_parts, bool):
        raise ConfigError(f"output.keep_parts: expected true or false, got {keep_parts!r}")
    offset_m = chips.number("offset_m", None, positive=False, maximum=MAX_CHIP_SIZE_M)
    if offset_m is not None and offset_m < 0.0:
        raise ConfigError(f"chips.offset_m: expected a distance >= 0 (metres), got {offset_m}")
    return BuildConfig(
        inputs=_inputs(top.raw("inputs"), base),
        geometry=GeometryConfig(
            observer_height=geo.number("observer_height", None, maximum=MAX_OBSERVER_HEIGHT_M),
            radius=geo.number("radius", 2000.0, maximum=MAX_RADIUS_M),
            viewshed=geo.choice("viewshed", VIEWSHED_MODES, "both"),
            view_mask=geo.choice("view_mask", VIEW_MASKS, "frustum"),
            ray_stride=geo.integer("ray_stride", 8, maximum=100_000),
        ),
        chips=ChipsConfig(
            size_m=chips.number("size_m", 256.0, maximum=MAX_CHIP_SIZE_M),
            size_px=chips.integer("size_px", 512, minimum=8, maximum=MAX_CHIP_SIZE_PX),
            orientation=chips.choice("orientation", ORIENTATIONS, "north-up"),
            min_coverage=min_coverage,
            offset_m=offset_m,
        ),
        output=OutputConfig(
            dir=_output_dir(out, base),
            shard_size=out.integer("shard_size", 64),
            image_encoding=out.choice("image_encoding", IMAGE_ENCODINGS, "png"),
            license=license,
            keep_parts=keep_parts,
            members=_members(out.raw("members", [])),
            dense_stride=None
            if out.raw("dense_stride", None) is None
            else out.integer("dense_stride", maximum=100_000),
        ),
        splits=_splits(top.raw("splits", {})),
        source=source,
    )


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


def load_config(path: str | Path) -> BuildConfig:
    """Read and validate a YAML build config (``read_yaml``)."""
    path = Path(path)
    data = read_yaml(path)
    try:
        return parse_config(data, path.resolve().parent, source=path.resolve())
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
