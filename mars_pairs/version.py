"""The package version (one home: ``mars_pairs.__version__`` re-exports it)."""

__version__ = "0.1.0"
