#!/usr/bin/env python
"""Write the configuration reference page, generated from the config schemas.

python scripts/config_reference.py [--check] [--out docs/reference/config.md]

``--check``: exit 1 (naming the file) when the page on disk differs from the generated one.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mars_pairs.config_reference import reference_page

PAGE = Path(__file__).resolve().parents[1] / "docs" / "reference" / "config.md"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=PAGE, help="the page (default: %(default)s)")
    parser.add_argument("--check", action="store_true", help="compare, do not write")
    args = parser.parse_args(argv)
    text = reference_page()
    if args.check:
        if not args.out.is_file() or args.out.read_text() != text:
            print(f"{args.out}: differs from the schema; run scripts/config_reference.py")
            return 1
        return 0
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
