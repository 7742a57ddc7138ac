"""``python -m mars_pairs.cli``."""

import sys

from mars_pairs.cli.main import main

sys.exit(main())
