"""The abstract source: validation, bad-sample removal, health; the registry."""

from __future__ import annotations

import numpy as np
import pytest

from drivers import SourceError, source_class
from drivers.base import SampleBlock, Source, SourceClosed
from tests.drivers.contract import SourceContract


class ArraySource(Source):
    """Yields fixed blocks, then ends."""

    name = "array"

    def __init__(self, blocks):
        super().__init__()
        self._blocks = list(blocks)

    def _read_block(self, timeout):
        if not self._blocks:
            raise SourceClosed("end of data")
        return self._blocks.pop(0)


def _blocks(n_blocks=5, n=20):
    out = []
    for i in range(n_blocks):
        t = (np.arange(n) + i * n) * 1_000_000
        out.append(SampleBlock(t, {"va": np.full(n, 1.0), "ia": np.linspace(0, 1, n)}))
    return out


class TestArraySourceContract(SourceContract):
    def make_source(self, request, tmp_path):
        return ArraySource(_blocks())


def test_non_finite_samples_are_removed_and_counted():
    t = np.arange(4) * 1000
    src = ArraySource(
        [SampleBlock(t, {"va": [1.0, np.nan, 3.0, np.inf], "ia": [1.0, 2.0, 3.0, 4.0]})]
    )
    block = src.read()
    assert block is not None
    np.testing.assert_array_equal(block.t_ns, [0, 2000])
    assert src.health()["bad_samples"] == 2
    assert src.health()["samples"] == 2


def test_sample_block_rejects_mismatched_and_unknown_channels():
    with pytest.raises(ValueError, match="samples"):
        SampleBlock(np.arange(3), {"va": [1.0, 2.0]})
    with pytest.raises(ValueError, match="unknown channel"):
        SampleBlock(np.arange(2), {"volts": [1.0, 2.0]})


def test_unknown_source_name_lists_known_ones():
    with pytest.raises(SourceError, match="replay"):
        source_class("nonexistent")


def test_sample_block_carries_adc_counts_and_their_scale():
    from drivers.base import AdcScale

    scale = AdcScale(lsb=0.25, offset=-1.0, bits=12)
    block = SampleBlock.from_counts([0, 1, 2], {"ia": [-4, 0, 7]}, {"ia": scale}, {"va": [1, 2, 3]})
    assert block.signals["ia"].tolist() == [-2.0, -1.0, 0.75]
    assert block.counts("ia").tolist() == [-4, 0, 7] and block.counts("va") is None
    assert dict(block.scales) == {"ia": scale}
    with pytest.raises(ValueError, match="does not have"):
        SampleBlock([0], {"va": [1.0]}, {"ia": scale})
    with pytest.raises(ValueError, match="lsb must be > 0"):
        SampleBlock([0], {"va": [1.0]}, {"va": AdcScale(0.0)})
