"""Label read times on the real labels in ../shared/pds-samples: pdr's PDS3 parser, pvl.loads,
and the whole read (``read_observation``: parse + typed fields), median ms per label.

    python benchmarks/bench_labels.py [--rounds 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
import warnings
from pathlib import Path

from mars_pairs.pds import read_observation
from mars_pairs.pds.pds3 import load_label

SAMPLES = Path(__file__).resolve().parents[1].parent / "shared" / "pds-samples"


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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    pds3 = sorted(SAMPLES.glob("msl/*.LBL"))
    pds4 = sorted(SAMPLES.glob("m2020/*.xml"))
    if not pds3:
        raise SystemExit(f"no real labels at {SAMPLES}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import pvl

        def parse(path: Path) -> object:
            return load_label(path.read_bytes(), path)

        rows = [
            ("PDS3 parse, pdr (parselabel.pds3)", _median_ms(parse, pds3, args.rounds)),
            ("PDS3 parse, pvl.loads", _median_ms(lambda p: pvl.loads(p.read_text()), pds3, 1)),
            ("PDS3 read_observation", _median_ms(read_observation, pds3, args.rounds)),
            ("PDS4 read_observation", _median_ms(read_observation, pds4, args.rounds)),
        ]
    print(f"load average {os.getloadavg()[0]:.1f}; {len(pds3)} PDS3 and {len(pds4)} PDS4 labels")
    print("| label read | ms per label (median) |\n|---|---:|")
    for name, ms in rows:
        print(f"| {name} | {ms:.1f} |")


if __name__ == "__main__":
    main()
