"""PDS3 labels through pdr's parser: the same fields as pvl reads, and no hang on damage."""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import pytest

from mars_pairs.errors import LabelError
from mars_pairs.pds import read_observation, read_pds3
from mars_pairs.pds.pds3 import load_label, observation_from_label
from support.label_seeds import PDS3_SEED
from support.observations import assert_same

SAMPLES = Path(__file__).resolve().parents[2].parent / "shared" / "pds-samples"


def _pvl_loads(text: str):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import pvl

        return pvl.loads(text)


def _real_pds3() -> list[Path]:
    if not SAMPLES.is_dir():
        pytest.skip(f"real PDS samples not found at {SAMPLES} (../shared beside the checkout)")
    labels = sorted(SAMPLES.glob("**/*.LBL"))
    assert len(labels) >= 11
    return labels


@pytest.mark.slow
def test_every_field_we_use_equals_what_pvl_reads_on_every_real_label() -> None:
    """The Observation built from pdr's parse equals the one built from pvl.loads."""
    for path in _real_pds3():
        text = path.read_text()
        ours = observation_from_label(load_label(path.read_bytes(), path), path)
        theirs = observation_from_label(_pvl_loads(text), path)
        assert_same(ours, theirs)
        assert ours.image_path == theirs.image_path == path.with_suffix(".jpg")
        # and the raw values behind them, for the keywords whose types pvl and pdr share
        label, reference = load_label(path.read_bytes(), path), _pvl_loads(text)
        for key in ("PRODUCT_ID", "INSTRUMENT_ID", "PLANET_DAY_NUMBER"):
            assert label[key] == reference[key], (path.name, key)
        assert list(label["ROVER_MOTION_COUNTER"]) == list(reference["ROVER_MOTION_COUNTER"])
        group = "GEOMETRIC_CAMERA_MODEL_PARMS"
        for key, value in reference[group].items():
            if key.startswith("MODEL_COMPONENT_") and key != "MODEL_COMPONENT_ID":
                assert list(label[group][key]) == list(value), (path.name, key)
        for key in ("LINES", "LINE_SAMPLES"):
            assert label["IMAGE"][key] == reference["IMAGE"][key]


def test_pdr_parses_faster_than_pvl() -> None:
    path = _real_pds3()[0]
    data, text = path.read_bytes(), path.read_text()
    start = time.perf_counter()
    for _ in range(5):
        load_label(data, path)
    ours = (time.perf_counter() - start) / 5
    start = time.perf_counter()
    _pvl_loads(text)
    theirs = time.perf_counter() - start
    assert ours < theirs, (ours, theirs)


def test_a_label_that_hung_pvl_fails_or_reads_quickly(tmp_path: Path) -> None:
    # one line lost: "GROUP = ROVER_COORDINATE_SYSTEL:SOLUTION_ID = telemetry"; pvl.loads
    # loops for ever on it (its permissive parser pushes the same token back and back)
    text = PDS3_SEED.replace("SYSTEM_PARMS\n MSL:SOLUTION_ID", "SYSTEL:SOLUTION_ID", 1)
    assert text != PDS3_SEED
    label = tmp_path / "damaged.LBL"
    label.write_text(text)
    start = time.perf_counter()
    try:
        read_pds3(label)
    except LabelError as err:
        assert "damaged.LBL" in str(err)
    assert time.perf_counter() - start < 1.0


def test_time_guard_stops_a_parse_that_does_not_end(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A parser that never returns is stopped at the time limit with a LabelError."""
    import pdr.parselabel.pds3

    def forever(text: str, *args: object, **kwargs: object) -> None:
        while True:
            time.sleep(0.01)

    monkeypatch.setattr(pdr.parselabel.pds3, "parse_pvl", forever)
    monkeypatch.setattr("mars_pairs.pds.pds3.PARSE_SECONDS", 0.3)
    label = tmp_path / "stuck.LBL"
    label.write_text(PDS3_SEED)
    start = time.perf_counter()
    with pytest.raises(LabelError, match=r"stuck\.LBL: parsing took longer than 0\.3 s"):
        read_observation(label)
    assert time.perf_counter() - start < 2.0


def test_time_guard_restores_an_outer_timer(tmp_path: Path) -> None:
    import signal

    fired: list[int] = []
    previous = signal.signal(signal.SIGALRM, lambda *_: fired.append(1))
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.6)
        label = tmp_path / "ok.LBL"
        label.write_text(PDS3_SEED)
        read_observation(label)
        remaining, _ = signal.getitimer(signal.ITIMER_REAL)
        assert 0.0 < remaining <= 0.6
        time.sleep(remaining + 0.1)
        assert fired == [1]
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


@pytest.mark.parametrize(
    "damage",
    [
        "A = " + "(" * 100_000,
        "A = " + "1+" * 200_000 + "1",
        "A = " + "[" * 50_000 + "]" * 50_000,
        "A = {" + "1," * 300_000 + "}",
        "A = " + "9" * 100_000,
        "/*" * 300_000,
        "GROUP = G\n" * 100_000,
        'A = "' + "x" * 1_000_000,
    ],
)
def test_pathological_labels_end_quickly(tmp_path: Path, damage: str) -> None:
    label = tmp_path / "bomb.LBL"
    label.write_text(PDS3_SEED.replace("END\n", damage + "\nEND\n"))
    start = time.perf_counter()
    try:
        read_observation(label)
    except LabelError as err:
        assert "bomb.LBL" in str(err)
    assert time.perf_counter() - start < 6.0


def test_label_size_limit(tmp_path: Path) -> None:
    from mars_pairs.pds.common import MAX_LABEL_BYTES

    label = tmp_path / "huge.LBL"
    label.write_text(PDS3_SEED.replace("END\n", "") + "/* pad */\n" * (MAX_LABEL_BYTES // 10))
    with pytest.raises(LabelError, match=r"huge\.LBL: no END line in the first"):
        read_observation(label)


@pytest.mark.parametrize("special", ["/dev/zero", "/dev/null"])
def test_special_files_are_refused_without_reading(special: str) -> None:
    if not Path(special).exists():
        pytest.skip(f"{special} absent")
    with pytest.raises(LabelError, match="not a regular file"):
        read_observation(special)


def test_fifo_is_refused_without_blocking(tmp_path: Path) -> None:
    import os

    fifo = tmp_path / "pipe.LBL"
    os.mkfifo(fifo)
    with pytest.raises(LabelError, match=r"pipe\.LBL: not a regular file"):
        read_observation(fifo)
