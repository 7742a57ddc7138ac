"""Load (or, on a cold cache, compile and save) the synthetic mission's numba kernels with
the types of a mission's calls, without running them: the ortho's composition and rocks
(the mission's own process) and the renderer's depth buffer, hit refinement and shading
(every render worker). Declared signatures (numba types), checked against the real calls by
``tests/test_warmup.py``, which runs a mission in a fresh process after the warm-up and
finds no compilation."""

from __future__ import annotations

from numba import types

from mars_pairs.synth.ortho import compose_ortho, stamp_rocks
from mars_pairs.synth.render import refine_hits, render_depth, shade

_F8, _F4, _I8 = types.float64, types.float32, types.int64
_F8_1 = types.Array(_F8, 1, "C")
_F8_2 = types.Array(_F8, 2, "C")
_F4_2 = types.Array(_F4, 2, "C")
_U1_1 = types.Array(types.uint8, 1, "C")

#: each kernel and the argument types of the mission's calls of it
SIGNATURES = (
    (render_depth, (_F8_2, _F8_2, _F8_2, *(_F8,) * 7, _F8_1, _I8, _I8, _F8, _F8_2, _F8_2)),
    (refine_hits, (_F8_2, _F8_2, _F8_2, *(_F8,) * 6, _F8_1)),
    (shade, (_F8_2, _F8_2, _F4_2, _I8, _U1_1, _F8_1)),
    (compose_ortho, (_F4_2, _F4_2, _F4_2, _F4_2, _I8)),
    (stamp_rocks, (_F4_2, _F8_1, _F8_1, _F8_1, _F8_1, _F8, _F8, _F8)),
)


def warm_mission_kernels() -> None:
    """Load every kernel of ``SIGNATURES`` for its argument types (compiled once per cache)."""
    for kernel, args in SIGNATURES:
        kernel.compile(args)
