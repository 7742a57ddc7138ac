"""A sample's key: its name in the shards (the WebDataset key) and in the manifest."""

from __future__ import annotations

from mars_pairs.observation import Observation


def sample_key(obs: Observation) -> str:
    """The WebDataset key of an observation: mission and product id, no dots."""
    return f"{obs.mission}_{obs.product_id}".replace(".", "_").lower()
