"""bench/window_honesty.py's drives without its minutes."""

from __future__ import annotations

import pytest

from bench.window_honesty import _drive


def test_thyristor_variants_are_the_accuracy_benchs():
    assert _drive("thyristor-60hz").converter.mains_hz == 60.0
    skewed = dict(_drive("thyristor-skew", 5000.0).chain.items())
    assert skewed["va"].delay_s == 0.0 and skewed["ia"].delay_s == pytest.approx(0.25 / 5000.0)
    assert _drive("realistic").converter == _drive("thyristor-standard").converter
    with pytest.raises(SystemExit, match="unknown drive"):
        _drive("thyristor-warp")
