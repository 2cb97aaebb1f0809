"""Replay source: the shared source contract, pacing, looping, cut files, config."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import CompressionType, Writer

from drivers import source_class
from drivers.base import SourceClosed
from observer.config import ConfigError
from observer.recording import (
    SAMPLE_BLOCK_SCHEMA,
    SAMPLES_SCHEMA_NAME,
    SAMPLES_TOPIC,
    read_recording,
    write_csv,
)
from replay.source import ReplaySource
from tests.drivers.contract import SourceContract

GOLDEN = Path(__file__).parent / "data" / "p12_3s_1khz.mcap"


def _drain(src):
    blocks = []
    while True:
        try:
            b = src.read(timeout=5.0)
        except SourceClosed:
            return blocks
        if b is not None:
            blocks.append(b)


class TestReplayContract(SourceContract):
    min_samples = 500

    def make_source(self, request, tmp_path):
        return ReplaySource.of(GOLDEN, speed=0, block_s=0.05)


class TestReplayCsvContract(SourceContract):
    min_samples = 500

    def make_source(self, request, tmp_path):
        path = tmp_path / "rec.csv"
        write_csv(read_recording(GOLDEN), path)
        return ReplaySource.of(path, speed=0, block_s=0.1)


def test_replays_every_sample_exactly_in_blocks_of_block_s():
    rec = read_recording(GOLDEN)
    with ReplaySource.of(GOLDEN, speed=0, block_s=0.25) as src:
        blocks = _drain(src)
    t = np.concatenate([b.t_ns for b in blocks])
    assert np.array_equal(t, np.rint(rec.t * 1e9).astype(np.int64))
    for c in rec.channels:
        assert np.array_equal(np.concatenate([b.signals[c] for b in blocks]), rec.signals[c])
    # 1 kHz, 0.25 s blocks: 250 samples each except possibly the last.
    assert {len(b) for b in blocks[:-1]} == {250}


def test_real_time_pacing_follows_speed():
    # 3 s of data at 10x real time: about 0.3 s of wall time, not much less.
    start = time.monotonic()
    with ReplaySource.of(GOLDEN, speed=10.0, block_s=0.1) as src:
        blocks = _drain(src)
    elapsed = time.monotonic() - start
    assert sum(len(b) for b in blocks) == 3000
    assert 0.27 <= elapsed < 2.0


def test_read_returns_none_on_timeout_while_waiting_for_the_next_block():
    with ReplaySource.of(GOLDEN, speed=0.5, block_s=0.5) as src:
        assert src.read(timeout=0.01) is None  # the first block is due in ~1 s


def test_loop_continues_the_time_axis():
    with ReplaySource.of(GOLDEN, speed=0, block_s=0.5, loop=True) as src:
        blocks = [src.read(timeout=1.0) for _ in range(14)]
    t = np.concatenate([b.t_ns for b in blocks if b is not None])
    assert t.size == 7000
    assert np.all(np.diff(t) == 1_000_000)
    assert src.health()["loops"] == 2


def test_cut_mcap_replays_up_to_the_cut(tmp_path):
    rec = read_recording(GOLDEN)
    t_ns = np.rint(rec.t * 1e9).astype(np.int64)
    whole = tmp_path / "whole.mcap"
    messages = [
        {"t_ns": t_ns[i : i + 100].tolist(), "ia": rec["ia"][i : i + 100].tolist()}
        for i in range(0, rec.n_samples, 100)
    ]
    _write_raw_mcap(whole, messages, chunk_size=8192)
    data = whole.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    with ReplaySource.of(cut, speed=0) as src:
        blocks = _drain(src)
    n = sum(len(b) for b in blocks)
    assert 500 < n < 2500 and n % 100 == 0


def _write_raw_mcap(path, messages, chunk_size=1 << 20, compression=CompressionType.ZSTD):
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=chunk_size, compression=compression, enable_crcs=False)
        w.start()
        sid = w.register_schema(
            SAMPLES_SCHEMA_NAME, "jsonschema", json.dumps(SAMPLE_BLOCK_SCHEMA).encode()
        )
        cid = w.register_channel(SAMPLES_TOPIC, "json", sid)
        for m in messages:
            w.add_message(cid, m["t_ns"][0], json.dumps(m).encode(), m["t_ns"][0])
        w.finish()


def test_gaps_and_nonfinite_samples_replay_as_recorded(tmp_path):
    # A daemon log of a faulty source: a gap, and a NaN the source let through.
    path = tmp_path / "faulty.mcap"
    t1 = list(range(0, 10_000_000, 1_000_000))
    t2 = list(range(50_000_000, 60_000_000, 1_000_000))
    va2 = [1.0] * 10
    messages = [{"t_ns": t1, "va": [1.0] * 10}, {"t_ns": t2, "va": va2}]
    _write_raw_mcap(path, messages, compression=CompressionType.NONE)
    raw = path.read_bytes().replace(b"1.0]", b"NaN]", 1)
    path.write_bytes(raw)
    with ReplaySource.of(path, speed=0, block_s=1.0) as src:
        blocks = _drain(src)
        health = src.health()
    t = np.concatenate([b.t_ns for b in blocks])
    assert t.size == 19 and health["bad_samples"] == 1
    assert np.max(np.diff(t)) == 42_000_000  # the NaN was the 9 ms sample


def test_from_config_resolves_path_and_rejects_bad_values(tmp_path):
    cls = source_class("replay")
    src = cls.from_config(
        {"path": GOLDEN.name, "speed": 0.0}, source="x.toml", base_dir=GOLDEN.parent
    )
    assert isinstance(src, ReplaySource) and src.options.path == str(GOLDEN.resolve())
    src.close()
    with pytest.raises(ConfigError, match=r"x.toml: 'source.options.speed' must be >= 0"):
        cls.from_config({"path": "a.mcap", "speed": -1.0}, source="x.toml", base_dir=tmp_path)
    with pytest.raises(ConfigError, match=r"x.toml: unknown key 'source.options.sped'"):
        cls.from_config({"path": "a.mcap", "sped": 1.0}, source="x.toml", base_dir=tmp_path)
    with pytest.raises(ConfigError, match=r"x.toml: .*path"):
        cls.from_config({}, source="x.toml", base_dir=tmp_path)
