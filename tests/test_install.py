"""The environment the project installs is the CPU one: no CUDA wheel (``nvidia-*``, triton)
and the torch build pinned in constraints.txt, whose CUDA runtime is absent. Every pip call of
the Makefile passes constraints.txt, so a later resolve cannot swap torch for a CUDA build; this
test is the check that it did not (it reads the installed distributions' metadata)."""

from __future__ import annotations

import importlib.metadata as md
import re
from pathlib import Path

CONSTRAINTS = Path(__file__).resolve().parents[1] / "constraints.txt"
#: Distributions only a CUDA build of torch pulls in.
_CUDA = re.compile(r"nvidia-.*|triton|pytorch-triton.*")


def _installed() -> dict[str, str]:
    """Normalised distribution name -> version, of every distribution on sys.path."""
    out = {}
    for dist in md.distributions():
        name = dist.metadata["Name"]
        if name:
            out[re.sub(r"[-_.]+", "-", name).lower()] = dist.version
    return out


def _pinned_torch() -> str:
    for line in CONSTRAINTS.read_text().splitlines():
        m = re.fullmatch(r"\s*torch\s*==\s*([^\s#]+)\s*(#.*)?", line)
        if m:
            return m[1]
    raise AssertionError(f"{CONSTRAINTS}: no torch== pin")


def test_no_cuda_wheel_is_installed() -> None:
    cuda = sorted(f"{n} {v}" for n, v in _installed().items() if _CUDA.fullmatch(n))
    assert cuda == [], f"CUDA wheels in the environment (a resolve replaced torch?): {cuda}"


def test_torch_is_the_pinned_cpu_build() -> None:
    import torch

    version = _installed()["torch"]
    pinned = _pinned_torch()
    assert version.split("+")[0] == pinned, f"torch {version} installed, constraints pin {pinned}"
    local = version.partition("+")[2]
    assert local in ("", "cpu"), f"torch {version}: not the CPU build"
    assert torch.version.cuda is None, f"torch {version} is built for CUDA {torch.version.cuda}"
