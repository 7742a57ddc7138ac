"""``python -m mars_pairs``: the ``mars-pairs`` command line (:func:`mars_pairs.cli.main`)."""

import sys

from mars_pairs.cli.main import main

if __name__ == "__main__":
    sys.exit(main())
