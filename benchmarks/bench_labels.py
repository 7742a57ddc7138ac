"""Label read times: the real labels in ../shared/pds-samples (the anchor), then pathological
labels (the reliability sweep's shapes, ``tests/pds/label_shapes.py``) read on a worker thread,
where no SIGALRM guard runs, each until its LabelError, and the slowest label the structural
bounds accept (``mars_pairs.pds.pds3.check_structure``); with the tracemalloc peak of a second
read of each (Python allocations, lxml's tree aside).

    python benchmarks/bench_labels.py [--rounds 5]

Real labels: pdr's PDS3 parser, pvl.loads, and the whole read (``read_observation``: parse +
typed fields), best of ``--rounds`` per label, median ms over labels. Shapes: one read each.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import sys
import tempfile
import threading
import time
import tracemalloc
import warnings
from collections.abc import Callable
from pathlib import Path

from mars_pairs.errors import LabelError
from mars_pairs.pds import read_observation
from mars_pairs.pds.pds3 import load_label

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT.parent / "shared" / "pds-samples"
sys.path.insert(0, str(ROOT / "tests" / "pds"))
from label_shapes import SHAPES, densest_accepted, slowest_accepted  # noqa: E402

PDS4_ROOT = '<Product_Observational xmlns="http://pds.nasa.gov/pds4/pds/v1">'
PDS4_SHAPES: dict[str, Callable[[], str]] = {
    "PDS4: 1M empty elements": lambda: PDS4_ROOT + "<a/>" * 1_000_000 + "</Product_Observational>",
    "PDS4: 10k nested elements": lambda: (
        PDS4_ROOT + "<a>" * 10_000 + "</a>" * 10_000 + "</Product_Observational>"
    ),
}
#: A shape still reading after this long on its thread is reported as such and left behind.
GIVE_UP_S = 60.0


def _median_ms(fn, items, rounds: int) -> float:
    times = []
    for item in items:
        best = float("inf")
        for _ in range(rounds):
            start = time.perf_counter()
            fn(item)
            best = min(best, time.perf_counter() - start)
        times.append(best)
    return 1000.0 * statistics.median(times)


def _on_a_thread(fn: Callable[[], object]) -> tuple[float, str]:
    """Seconds and outcome of ``fn`` on a daemon thread (given up after GIVE_UP_S)."""
    box: list[str] = []

    def run() -> None:
        try:
            fn()
            box.append("read")
        except LabelError as exc:
            box.append(f"LabelError: {exc.field + ': ' if exc.field else ''}{exc.reason}")
        except Exception as exc:  # reported, not raised: the table goes on
            box.append(f"{type(exc).__name__}: {exc}")

    thread = threading.Thread(target=run, daemon=True)
    start = time.perf_counter()
    thread.start()
    thread.join(GIVE_UP_S)
    seconds = time.perf_counter() - start
    return seconds, box[0] if box else f"still reading after {GIVE_UP_S:.0f} s"


def _peak_mib(fn: Callable[[], object]) -> float:
    """The tracemalloc peak (MiB) of ``fn``, whatever it raises."""
    tracemalloc.start()
    with contextlib.suppress(Exception):  # the outcome is measured on the thread
        fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak / 2**20


def real_labels(rounds: int) -> list[tuple[str, float]]:
    """(what, median ms per label) on the real labels."""
    pds3 = sorted(SAMPLES.glob("msl/*.LBL"))
    pds4 = sorted(SAMPLES.glob("m2020/*.xml"))
    if not pds3:
        raise SystemExit(f"no real labels at {SAMPLES}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import pvl

        def parse(path: Path) -> object:
            return load_label(path.read_bytes(), path)

        return [
            (f"PDS3 parse, pdr ({len(pds3)} real labels)", _median_ms(parse, pds3, rounds)),
            ("PDS3 parse, pvl.loads", _median_ms(lambda p: pvl.loads(p.read_text()), pds3, 1)),
            ("PDS3 read_observation", _median_ms(read_observation, pds3, rounds)),
            (f"PDS4 read_observation ({len(pds4)})", _median_ms(read_observation, pds4, rounds)),
        ]


def shapes(folder: Path) -> list[tuple[str, int, float, float, str]]:
    """(shape, bytes, seconds on a worker thread, peak MiB, outcome) of every shape."""
    rows = []
    cases = [(name, make, ".LBL") for name, make in SHAPES.items()]
    cases += [(name, make, ".xml") for name, make in PDS4_SHAPES.items()]
    for name, make, suffix in cases:
        path = folder / f"shape{suffix}"
        path.write_text(make())
        seconds, outcome = _on_a_thread(lambda p=path: read_observation(p))
        peak = _peak_mib(lambda p=path: read_observation(p)) if seconds < GIVE_UP_S else 0.0
        rows.append((name, path.stat().st_size, seconds, peak, outcome))
    for name, make in (("slowest", slowest_accepted), ("densest", densest_accepted)):
        path = folder / f"{name}.LBL"
        path.write_text(make())
        seconds, outcome = _on_a_thread(lambda p=path: load_label(p.read_bytes(), p))
        peak = _peak_mib(lambda p=path: load_label(p.read_bytes(), p))
        label = f"{name} accepted (parse only)"
        rows.append((label, path.stat().st_size, seconds, peak, outcome))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    real = real_labels(args.rounds)
    with tempfile.TemporaryDirectory() as tmp:
        rows = shapes(Path(tmp))
    print(f"load average {os.getloadavg()[0]:.1f}")
    print("| label read (real labels) | ms per label (median) |\n|---|---:|")
    for name, ms in real:
        print(f"| {name} | {ms:.1f} |")
    print("\n| shape, read on a worker thread | bytes | s | peak MiB | outcome |")
    print("|---|---:|---:|---:|---|")
    for name, size, seconds, peak, outcome in rows:
        print(f"| {name} | {size:,} | {seconds:.2f} | {peak:.0f} | {outcome[:70]} |")


if __name__ == "__main__":
    main()
