"""The fetch section's numbers: a key given without a value (YAML null) is the default."""

from __future__ import annotations

from pathlib import Path

import pytest

from mars_pairs.errors import ConfigError
from mars_pairs.fetch.config import parse_fetch


def test_null_backoff_and_timeout_are_the_defaults(tmp_path: Path) -> None:
    config = parse_fetch({"cache": "c", "backoff_s": None, "timeout_s": None}, tmp_path, 2000.0)
    assert (config.policy.backoff_s, config.policy.read_timeout_s) == (0.5, 60.0)


def test_given_numbers_are_kept_and_negative_ones_refused(tmp_path: Path) -> None:
    config = parse_fetch({"cache": "c", "backoff_s": 2, "timeout_s": 5.5}, tmp_path, 2000.0)
    assert (config.policy.backoff_s, config.policy.read_timeout_s) == (2.0, 5.5)
    with pytest.raises(ConfigError, match=r"fetch\.backoff_s"):
        parse_fetch({"cache": "c", "backoff_s": -1}, tmp_path, 2000.0)
