"""The ``mars-pairs`` command line."""

from mars_pairs.cli.main import main

__all__ = ["main"]
