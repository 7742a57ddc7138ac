"""The synthetic mission's rendering bar opens after the first image (mostly the renderer's
compile on a first run), so its rate and ETA count the images after it only."""

from __future__ import annotations

import io

from mars_pairs.synth.mission import render_bar


def test_the_first_images_time_is_not_in_the_eta() -> None:
    bar = render_bar(100, "m2020", disable=False)
    bar.fp = io.StringIO()  # keep the test's output clean
    try:
        assert bar.n == 1  # the first image, rendered before the bar opened
        meter = dict(bar.format_dict, n=2, elapsed=2.0)  # one more image in 2 s
        text = bar.format_meter(**meter)
        # 98 images left at 0.5 image/s: 196 s (a rate over both images would say 98 s)
        assert "2/100" in text and "03:16" in text, text
    finally:
        bar.close()
