#!/usr/bin/env python
"""Build a mars-pairs dataset: the same arguments as ``mars-pairs build``.

python scripts/build_dataset.py --config configs/demo.yaml [--out DIR] [--workers N]
    [--resume] [--limit N] [--strict]
"""

from __future__ import annotations

import sys

from mars_pairs.cli.main import main

if __name__ == "__main__":
    sys.exit(main(["build", *sys.argv[1:]]))
