"""Deterministic mutation fuzzing of the label readers: PDS3, attached-label IMG and PDS4.

    python tests/pds/fuzz_labels.py [--cases 10000] [--seed 0] [--out DIR]

Each case takes one seed product (a Mastcam-style PDS3 label, a MIPL-style CAHVORE PDS3
label, an attached-label IMG, a Mastcam-Z PDS4 label, a CAHVORE PDS4 label), applies 1-4
random mutations (byte edits, deleted / duplicated / swapped spans and lines, inserted
syntax tokens, replaced numbers, truncation) from a seeded generator, and reads it with
``read_observation``. The contract: an Observation or a LabelError naming the file, never
another exception, never the reader's "unexpected" safety net, never longer than
``--max-seconds``. Exit status 1 on any breach, with the case number to replay it.
``tests/pds/test_fuzz_mutations.py`` runs the first cases of the same sequence in the suite.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

if __name__ == "__main__":  # run as a script: pytest's pythonpath (tests/) is not set
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mars_pairs.errors import LabelError
from mars_pairs.geometry.camera import CameraModel
from mars_pairs.pds import read_observation
from support.label_seeds import PDS3_SEED, PDS4_SEED

TOKENS = [
    b"=", b"(", b")", b'"', b"/*", b"*/", b"END", b"END_GROUP", b"END_OBJECT", b"GROUP = X",
    b"OBJECT = IMAGE", b"<", b">", b"#", b"&", b"\x00", b"1e999", b"NaN", b"-", b"\n", b"\r",
    b"{", b"}", b",", b"'", b"<deg>", b"2#1#", b"16#FF#", b"NULL", b"UNK", b"1_000", b"0x10",
    b"9" * 400, b"((((((((((", b"</geom:CAHVORE_Model>", b"<geom:c0>", b"&amp;", b"&lt;",
    b"<!--", b"-->", b"<![CDATA[", b"]]>", b"<!DOCTYPE x [<!ENTITY e 'x'>]>", b"&e;",
    b"\xef\xbb\xbf", b"\xff", b"MODEL_TYPE = CAHVORE", b"MODEL_COMPONENT_8 = 7.0",
]  # fmt: skip
_NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:[eE][+-]?\d+)?")


@dataclass(frozen=True)
class Seed:
    """One seed product: its bytes, file suffix, and how many leading bytes are label text."""

    name: str
    data: bytes
    suffix: str
    label_bytes: int


def seeds(workdir: Path) -> list[Seed]:
    """The seed products (written with the synthetic label writers where they can)."""
    from mars_pairs.synth.labels import write_pds3_img, write_pds3_label, write_pds4_label

    base = read_observation(_write(workdir / "seed3.LBL", PDS3_SEED.encode()))
    cam = base.camera
    ore = CameraModel("CAHVORE", cam.c, cam.a, cam.h, cam.v, o=cam.o, r=cam.r,
                      e=np.array([0.001, 0.01, -0.004]), mtype=3, mparm=0.4)  # fmt: skip
    small = replace(base, width=24, height=16, camera=cam.scaled(24 / 1152, 16 / 432))
    mipl = write_pds3_label(replace(base, camera=ore), workdir / "mipl.LBL", style="mipl")
    pixels = (np.arange(16 * 24, dtype=np.uint16).reshape(16, 24) * 97).astype(np.uint16)
    img = write_pds3_img(small, workdir / "att.IMG", pixels)
    img_bytes = img.read_bytes()
    label_len = img_bytes.index(b"\nEND") + 6
    four = read_observation(_write(workdir / "seed4.xml", PDS4_SEED.encode()))
    ore4 = write_pds4_label(replace(four, camera=ore), workdir / "ore4.xml")
    return [
        Seed("pds3", PDS3_SEED.encode(), ".LBL", len(PDS3_SEED)),
        Seed("pds3-mipl-cahvore", mipl.read_bytes(), ".LBL", mipl.stat().st_size),
        Seed("img-attached", img_bytes, ".IMG", label_len),
        Seed("pds4", PDS4_SEED.encode(), ".xml", len(PDS4_SEED)),
        Seed("pds4-cahvore", ore4.read_bytes(), ".xml", ore4.stat().st_size),
    ]


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def mutate(rng: np.random.Generator, seed: Seed) -> bytes:
    """1-4 random mutations of the seed (mostly inside its label text)."""
    data = bytearray(seed.data)
    for _ in range(int(rng.integers(1, 5))):
        limit = seed.label_bytes if rng.random() < 0.9 else len(data)
        limit = max(1, min(limit, len(data)))
        at = int(rng.integers(0, limit))
        op = int(rng.integers(0, 8))
        if op == 0:  # overwrite bytes
            for _ in range(int(rng.integers(1, 9))):
                data[int(rng.integers(0, limit))] = int(rng.integers(0, 256))
        elif op == 1:  # delete a span
            del data[at : at + int(rng.integers(1, 200))]
        elif op == 2:  # duplicate a span
            span = bytes(data[at : at + int(rng.integers(1, 300))])
            data[at:at] = span
        elif op == 3:  # insert a syntax token
            data[at:at] = TOKENS[int(rng.integers(0, len(TOKENS)))]
        elif op == 4:  # replace a number
            numbers = list(_NUMBER.finditer(bytes(data[:limit])))
            if numbers:
                m = numbers[int(rng.integers(0, len(numbers)))]
                values = [b"0", b"-1", b"1e308", b"-0.0", b"4294967296", b"1" * 30]
                values.append(repr(float(rng.normal() * 10.0 ** int(rng.integers(-5, 9)))).encode())
                new = values[int(rng.integers(0, len(values)))]
                data[m.start() : m.end()] = new
        elif op == 5:  # truncate
            del data[at:]
        elif op == 6:  # swap two lines
            lines = bytes(data).split(b"\n")
            i, j = rng.integers(0, len(lines), size=2)
            lines[i], lines[j] = lines[j], lines[i]
            data = bytearray(b"\n".join(lines))
        else:  # drop a whole line
            lines = bytes(data).split(b"\n")
            del lines[int(rng.integers(0, len(lines)))]
            data = bytearray(b"\n".join(lines))
    return bytes(data)


@dataclass
class Report:
    cases: int = 0
    observations: int = 0
    errors: int = 0
    slowest: float = 0.0
    slowest_case: int = -1
    breaches: list[str] | None = None
    reasons: Counter | None = None


def run(cases: int, seed: int, workdir: Path, max_seconds: float = 2.0) -> Report:
    """Run ``cases`` mutation cases; every breach of the contract is listed in the report."""
    rng = np.random.default_rng(seed)
    products = seeds(workdir)
    report = Report(breaches=[], reasons=Counter())
    for case in range(cases):
        product = products[case % len(products)]
        path = _write(workdir / f"case_{case % 7}{product.suffix}", mutate(rng, product))
        start = time.perf_counter()
        try:
            read_observation(path)
            report.observations += 1
        except LabelError as err:
            report.errors += 1
            report.reasons[(err.field or "-", err.reason.split(":")[0][:40])] += 1
            if err.reason.startswith("unexpected") or err.path != str(path):
                report.breaches.append(f"case {case} ({product.name}): {err}")
        except BaseException as exc:  # the contract: nothing but LabelError
            report.breaches.append(f"case {case} ({product.name}): {type(exc).__name__}: {exc}")
        took = time.perf_counter() - start
        if took > report.slowest:
            report.slowest, report.slowest_case = took, case
        if took > max_seconds:
            report.breaches.append(f"case {case} ({product.name}): took {took:.2f} s")
        report.cases += 1
    return report


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-seconds", type=float, default=2.0)
    args = parser.parse_args()
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        report = run(args.cases, args.seed, Path(tmp), args.max_seconds)
    took = time.perf_counter() - start
    print(f"{report.cases} cases in {took:.1f} s (load average {os.getloadavg()[0]:.1f}): "
          f"{report.observations} read, {report.errors} LabelError, "
          f"slowest {report.slowest * 1000:.0f} ms (case {report.slowest_case})")  # fmt: skip
    assert report.reasons is not None and report.breaches is not None
    for (field, reason), count in report.reasons.most_common(8):
        print(f"  {count:6d}  {field}: {reason}")
    for breach in report.breaches:
        print("BREACH", breach)
    return 1 if report.breaches else 0


if __name__ == "__main__":
    sys.exit(main())
