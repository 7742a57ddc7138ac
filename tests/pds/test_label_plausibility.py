"""A camera model is a checked contract: a model whose H, V or A are degenerate, or whose
field of view disagrees with the label's beyond the stated tolerance
(``pds.common.FOV_TOLERANCE_*``), is a LabelError naming the field, never a sample. On a real
Mars 2020 Mastcam-Z label (skipped when ../shared is absent)."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import pytest

from mars_pairs.errors import LabelError
from mars_pairs.pds import read_observation

LABEL = "m2020/ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01.xml"
VECTOR = (
    r"(<geom:Vector_{name}>\s*<geom:x_pixel>)([^<]+)(</geom:x_pixel>\s*<geom:y_pixel>)([^<]+)"
    r"(</geom:y_pixel>\s*<geom:z_pixel>)([^<]+)(</geom:z_pixel>)"
)


def _vector(text: str, name: str) -> list[float]:
    m = re.search(VECTOR.format(name=name), text)
    assert m is not None
    return [float(m[2]), float(m[4]), float(m[6])]


def _set(text: str, name: str, xyz: list[float]) -> str:
    def put(m: re.Match[str]) -> str:
        x, y, z = (repr(v) for v in xyz)
        return f"{m[1]}{x}{m[3]}{y}{m[5]}{z}{m[7]}"

    return re.sub(VECTOR.format(name=name), put, text, count=1)


def zero_h(text: str) -> str:
    return _set(text, "Horizontal", [0.0, 0.0, 0.0])


def scaled_hv(text: str) -> str:
    for name in ("Horizontal", "Vertical"):
        text = _set(text, name, [1e-6 * c for c in _vector(text, name)])
    return text


def v_equal_h(text: str) -> str:
    return _set(text, "Vertical", _vector(text, "Horizontal"))


def wide_fov(text: str) -> str:
    """The model's focal length a third of the label's: its field of view ~ 3x the label's."""
    for name in ("Horizontal", "Vertical"):
        h = _vector(text, name)
        text = _set(text, name, [c / 3 for c in h])
    return text


CASES: dict[str, tuple[Callable[[str], str], str]] = {
    "Vector_Horizontal all zeros": (zero_h, "degenerate CAHV"),
    "H and V scaled by 1e-6": (scaled_hv, "focal lengths"),
    "V equal to H": (v_equal_h, "image axes H and V are 0 deg apart"),
    "model FOV 3x the label's": (wide_fov, "the label says 6.357 deg"),
}


@pytest.fixture()
def label(samples_dir: Path, tmp_path: Path) -> tuple[str, Path]:
    text = (samples_dir / LABEL).read_text()
    return text, tmp_path / Path(LABEL).name


def test_the_real_label_is_plausible(label: tuple[str, Path]) -> None:
    text, path = label
    path.write_text(text)
    assert read_observation(path).camera.hs > 1000


@pytest.mark.parametrize("case", CASES)
def test_a_degenerate_or_disagreeing_model_is_a_label_error(
    label: tuple[str, Path], case: str
) -> None:
    text, path = label
    mutate, reason = CASES[case]
    path.write_text(mutate(text))
    with pytest.raises(LabelError, match=re.escape(reason)) as err:
        read_observation(path)
    assert str(path) in str(err.value)


def test_conflicting_duplicate_fields_are_refused(samples_dir: Path, tmp_path: Path) -> None:
    """A PDS3 keyword twice in one group with two values (``LINES``) is refused naming the
    field; the same value twice is read."""
    ml = samples_dir / "msl" / "2663ML0139550021002124C00_DRCX.LBL"
    text = ml.read_text(errors="replace")
    line = next(x for x in text.splitlines() if x.strip().startswith("LINES "))
    indent = line[: len(line) - len(line.lstrip())]
    twice = tmp_path / "twice.LBL"
    twice.write_text(text.replace(line, f"{line}\n{indent}LINES = 7777", 1))
    with pytest.raises(LabelError, match=r"LINES.*different values"):
        read_observation(twice)
    same = tmp_path / "same.LBL"
    same.write_text(text.replace(line, f"{line}\n{line}", 1))
    assert read_observation(same).height == read_observation(ml).height
