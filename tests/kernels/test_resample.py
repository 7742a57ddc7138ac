"""The chip resampler: an axis-aligned map gives the values of the general path, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from mars_pairs.kernels.resample import _sample_general, _sample_separable, sample_affine


@pytest.mark.parametrize("nearest", [False, True])
def test_axis_aligned_maps_sample_as_the_general_path_bit_for_bit(nearest):
    rng = np.random.default_rng(0)
    for trial in range(300):
        h, w = (int(v) for v in rng.integers(1, 30, 2))
        src = rng.normal(size=(h, w)).astype(np.float32)
        src[rng.random((h, w)) < 0.05] = np.nan
        a, e = (float(rng.choice([0.5, 1.0, 2.0, rng.uniform(0.1, 3.0)]) * rng.choice([1, -1]))
                for _ in range(2))  # fmt: skip
        c, f = float(rng.uniform(-5.0, w + 5.0)), float(rng.uniform(-5.0, h + 5.0))
        if trial % 5 == 0:  # source positions on pixel centres and edges
            c, f = float(rng.integers(-3, 5)), float(rng.integers(-3, 5))
        b, d = float(rng.choice([0.0, -0.0])), float(rng.choice([0.0, -0.0]))
        rows, cols = (int(v) for v in rng.integers(1, 40, 2))
        general = _sample_general(src, a, b, c, d, e, f, rows, cols, nearest)
        separable = _sample_separable(src, a, b, c, d, e, f, rows, cols, nearest)
        np.testing.assert_array_equal(general.view(np.uint32), separable.view(np.uint32))
        assert np.array_equal(sample_affine(src, a, b, c, d, e, f, rows, cols, nearest),
                              general, equal_nan=True)  # fmt: skip


def test_a_rotated_map_samples_the_source_where_it_lands():
    src = np.arange(36, dtype=np.float32).reshape(6, 6)
    # a quarter turn: output column q, row r reads source row q, column 6 - r - 1
    out = sample_affine(src, 0.0, -1.0, 6.0, 1.0, 0.0, 0.0, 6, 6, True)
    np.testing.assert_array_equal(out, src.T[::-1, :])
