"""The contract every source honours. Each source's tests subclass :class:`SourceContract`.

A subclass implements ``make_source`` returning a fresh, unopened source that
will yield at least ``min_samples`` samples within ``timeout`` seconds of reads.
"""

from __future__ import annotations

import numpy as np
import pytest

from drivers.base import CHANNELS, SampleBlock, Source, SourceClosed


class SourceContract:
    min_samples: int = 10
    timeout: float = 10.0

    @pytest.fixture
    def source(self, request, tmp_path):
        src = self.make_source(request, tmp_path)
        yield src
        src.close()

    def make_source(self, request, tmp_path) -> Source:  # pragma: no cover - abstract
        raise NotImplementedError

    def _collect(self, source: Source) -> list[SampleBlock]:
        blocks: list[SampleBlock] = []
        total = 0
        import time

        deadline = time.monotonic() + self.timeout
        while total < self.min_samples and time.monotonic() < deadline:
            try:
                block = source.read(timeout=0.5)
            except SourceClosed:
                break
            if block is not None:
                blocks.append(block)
                total += len(block)
        return blocks

    def test_yields_blocks_of_known_channels_with_integer_ns_times(self, source):
        blocks = self._collect(source)
        assert sum(len(b) for b in blocks) >= self.min_samples
        for b in blocks:
            assert isinstance(b, SampleBlock)
            assert b.t_ns.dtype == np.int64
            assert set(b.channels) <= set(CHANNELS) and b.channels
            for values in b.signals.values():
                assert values.dtype == np.float64 and np.all(np.isfinite(values))
        t = np.concatenate([b.t_ns for b in blocks])
        assert np.all(np.diff(t) > 0), "timestamps must increase across blocks"

    def test_health_counts_what_was_read(self, source):
        blocks = self._collect(source)
        health = source.health()
        assert health["connected"] is True
        assert health["samples"] == sum(len(b) for b in blocks)
        for key in ("blocks", "dropped", "bad_samples", "errors", "reconnects"):
            assert key in health

    def test_close_is_idempotent_and_read_after_close_raises(self, source):
        self._collect(source)
        source.close()
        source.close()
        assert source.health()["connected"] is False
        with pytest.raises(SourceClosed):
            source.read(timeout=0.1)

    def test_context_manager_closes(self, request, tmp_path):
        with self.make_source(request, tmp_path) as src:
            self._collect(src)
        with pytest.raises(SourceClosed):
            src.read(timeout=0.1)
