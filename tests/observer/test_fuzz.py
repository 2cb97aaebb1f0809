"""Fuzzing the commands' inputs (issue 14): CSV and MCAP recordings and config files.

Whatever the input, ``dcobserver estimate`` ends either in a clean one-line
error (exit 2) or in an estimate whose parameters the data does not identify
are flagged (quality ``none``), never in a traceback. Inputs are a real
recording mangled the ways a tester would (units, signs, swapped or stuck
channels, NaN/Inf/huge values, duplicated or shuffled times, separators, BOM,
truncation, corrupt gzip, cut or flipped MCAP bytes, topics missing) plus
plain garbage. The commands run in this process (tens of milliseconds per
example), with a small swarm.
"""

from __future__ import annotations

import gzip
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from observer.estimation import MOTORS
from observer.recording import CHANNELS, Recording, write_mcap
from observer.simulation.simulate import simulate
from tests.observer.clirun import in_process

SWARM = ("--particles", "6", "--iterations", "3")
#: More examples, drawn afresh each run: DCOBSERVER_FUZZ_EXAMPLES=2000 python -m pytest FILE
_MORE = int(os.environ.get("DCOBSERVER_FUZZ_EXAMPLES", "0"))
FUZZ = settings(
    max_examples=_MORE or 120,
    deadline=None,
    derandomize=not _MORE,  # by default the same examples in every run: CI is reproducible
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


def cli(*argv: str) -> tuple[int, str, str]:
    """Run the CLI in this process; any exception but the CLI's own exit is a failure."""
    res = in_process(*argv)
    return res.returncode, res.stdout, res.stderr


def assert_clean_outcome(code: int, out: str, err: str) -> None:
    """A one-line error, or an estimate whose unidentified parameters are flagged."""
    assert "Traceback" not in err, err
    assert "Warning:" not in err, err  # numpy's RuntimeWarnings are not for the user
    event(f"exit {code}")
    if code == 2:
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("dcobserver estimate: error: "), err
        event(lines[0].split(": ")[-1][:40])
        return
    assert code == 0, (code, err)
    report = json.loads(out)
    limits = report["limits"]["rel_std"]  # per circuit: [observer.quality] of the config
    for circuit in ("field", "armature"):
        if circuit not in report:
            continue
        c = report[circuit]
        for p, quality in c["quality"].items():
            assert quality in ("ok", "suspect", "none"), quality
            rel = c["rel_std"].get(p)
            not_evidence = not c["describes_window"] or rel is None or rel > limits[circuit][p]
            if not_evidence:
                assert quality == "none", (circuit, p, quality, rel)
            else:
                assert c[p] is not None and math.isfinite(c[p])
    assert isinstance(report["warnings"], list) and report["units"]["R"] == "ohm"


@pytest.fixture(scope="module")
def base() -> Recording:
    """0.2 s of a simulated P-12 at 2 kHz: the material the tester mangles."""
    return simulate(MOTORS["p12"], duration_s=0.2, sample_rate_hz=2000.0, noise=0.002, seed=0)


@pytest.fixture(scope="module")
def folder():
    with tempfile.TemporaryDirectory(prefix="dcobserver-fuzz-") as d:
        yield Path(d)


def one_in(draw: Any, k: int) -> bool:
    """True with probability 1/k: most inputs stay plausible, so estimates are reached."""
    # Hypothesis favours the first choice (it shrinks towards it): make that "no".
    return bool(draw(st.sampled_from([False] * (k - 1) + [True])))


SPECIAL = st.sampled_from(
    ["nan", "NaN", "inf", "-inf", "1e300", "-1e308", "1e-320", "", " ", "abc", "1,5", "0x10",
     "1e", "--1", "1_000", '"2"', "\x00", "9" * 400]
)  # fmt: skip


@st.composite
def mangled_table(draw: Any, rec: Recording) -> tuple[list[str], list[list[str]]]:
    """Columns and rows of text: a real recording, mangled as a tester would."""
    n = draw(st.one_of(st.just(rec.n_samples), st.integers(0, rec.n_samples)))
    t = np.array(rec.t[:n])
    if one_in(draw, 4):
        t = t * draw(st.sampled_from([1e-3, 1e3, 1e6, 60.0]))
    columns = {"t": t}
    chosen = list(CHANNELS)
    if one_in(draw, 4):
        chosen = draw(st.lists(st.sampled_from(CHANNELS), unique=True, max_size=5)) or chosen
    for c in chosen:
        columns[c] = np.array(rec[c][:n])
    for c in list(columns):
        if c != "t" and one_in(draw, 4):
            kind = draw(st.sampled_from(["scale", "sign", "constant", "zero", "swap"]))
            if kind == "scale":
                columns[c] = columns[c] * 10.0 ** draw(st.integers(-6, 6))
            elif kind == "sign":
                columns[c] = -columns[c]
            elif kind == "constant":
                columns[c] = np.full(n, draw(st.floats(-1e3, 1e3)))
            elif kind == "zero":
                columns[c] = np.zeros(n)
            else:
                other = draw(st.sampled_from(list(columns)))
                columns[c], columns[other] = columns[other], columns[c]
    if n > 2 and one_in(draw, 4):
        kind = draw(st.sampled_from(["duplicate", "shuffle", "jitter", "reverse"]))
        i = draw(st.integers(1, n - 1))
        t = columns["t"].copy()
        if kind == "duplicate":
            t[i] = t[i - 1]
        elif kind == "shuffle":
            t[[i - 1, i]] = t[[i, i - 1]]
        elif kind == "jitter":
            t = t + draw(st.floats(0, 1e-3)) * np.sin(np.arange(n))
        else:
            t = t[::-1].copy()
        columns["t"] = t
    names = list(columns)
    if one_in(draw, 3):
        names = draw(st.permutations(names))
    rows = [[repr(float(columns[c][i])) for c in names] for i in range(n)]
    for _ in range(draw(st.integers(1, 3)) if one_in(draw, 3) else 0):
        if rows:
            i, j = draw(st.integers(0, len(rows) - 1)), draw(st.integers(0, len(names) - 1))
            rows[i][j] = draw(SPECIAL)
    header = list(names)
    if one_in(draw, 15):
        header = draw(st.lists(st.sampled_from(["t", "T", "Va", "x", "", "ia ", "omega"]),
                               max_size=6))  # fmt: skip
    return header, rows


@st.composite
def csv_file(draw: Any, rec: Recording) -> tuple[str, bytes]:
    """(file name, bytes) of a CSV recording, mostly plausible, sometimes garbage."""
    if one_in(draw, 15):
        return draw(st.sampled_from(["g.csv", "g.csv.gz"])), draw(st.binary(max_size=300))
    header, rows = draw(mangled_table(rec))
    sep = draw(st.sampled_from([";", "\t"])) if one_in(draw, 10) else ","
    newline = draw(st.sampled_from(["\n", "\r\n"]))
    lines = [sep.join(header)] + [sep.join(r) for r in rows]
    if one_in(draw, 3):
        lines.insert(0, "# a comment")
    if one_in(draw, 15):
        lines.insert(0, "# dcobserver-metadata: " + draw(st.sampled_from(["{", "[]", '{"a": 1}'])))
    if rows and one_in(draw, 10):
        lines.insert(draw(st.integers(1, len(lines))), "")
    text = newline.join(lines) + (newline if draw(st.booleans()) else "")
    data = (b"\xef\xbb\xbf" if one_in(draw, 6) else b"") + text.encode()
    misnamed = one_in(draw, 8)
    if one_in(draw, 4):
        data = gzip.compress(data, mtime=0)
        if one_in(draw, 2):
            cut = draw(st.integers(0, len(data)))
            data = bytearray(data)
            if draw(st.booleans()):
                data = data[:cut]
            elif cut < len(data):
                data[cut] ^= draw(st.integers(1, 255))
            data = bytes(data)
        return ("r.csv" if misnamed else "r.csv.gz"), data
    return ("r.csv.gz" if misnamed else "r.csv"), data


@st.composite
def mcap_file(draw: Any, rec: Recording, folder: Path) -> bytes:
    """Bytes of an MCAP recording: valid, cut at any byte, flipped, or not MCAP at all."""
    kind = draw(st.sampled_from(["valid"] * 4 + ["cut", "cut", "flip", "other_topic", "garbage"]))
    if kind == "garbage":
        return draw(st.sampled_from([b"", b"\x89MCAP0\r\n"])) + draw(st.binary(max_size=200))
    n = draw(st.one_of(st.just(rec.n_samples), st.integers(2, rec.n_samples)))
    signals = {c: np.array(rec[c][:n]) for c in rec.channels}
    for c in draw(st.lists(st.sampled_from(CHANNELS), unique=True, max_size=2)) * one_in(draw, 3):
        signals[c] = signals[c] * 10.0 ** draw(st.integers(-6, 6))
    scale = draw(st.sampled_from([1e-3, 1e3])) if one_in(draw, 4) else 1.0
    path = folder / "base.mcap"
    if kind == "other_topic":
        from mcap.writer import Writer

        with open(path, "wb") as f:
            w = Writer(f)
            w.start()
            s = w.register_schema("x", "jsonschema", b"{}")
            ch = w.register_channel(draw(st.sampled_from(["/other", "/samples"])), "json", s)
            w.add_message(
                ch, 0, draw(st.sampled_from([b"{}", b"[1]", b"not json", b'{"t_ns":1}'])), 0
            )
            w.finish()
        return path.read_bytes()
    write_mcap(Recording(rec.t[:n] * scale, signals), path, block_s=0.01)
    data = bytearray(path.read_bytes())
    if kind == "cut":
        data = data[: draw(st.integers(0, len(data)))]
    elif kind == "flip":
        for _ in range(draw(st.integers(1, 4))):
            data[draw(st.integers(0, len(data) - 1))] ^= draw(st.integers(1, 255))
    return bytes(data)


@given(data=st.data())
@FUZZ
def test_fuzzed_csv_recordings_end_in_an_error_line_or_flagged_estimates(base, folder, data):
    name, content = data.draw(csv_file(base))
    path = folder / name
    path.write_bytes(content)
    circuit = data.draw(st.sampled_from(["both", "both", "field", "armature"]))
    assert_clean_outcome(*cli("estimate", str(path), "--json", "--circuit", circuit, *SWARM))


@given(data=st.data())
@FUZZ
def test_fuzzed_mcap_recordings_end_in_an_error_line_or_flagged_estimates(base, folder, data):
    content = data.draw(mcap_file(base, folder))
    path = folder / "r.mcap"
    path.write_bytes(content)
    assert_clean_outcome(*cli("estimate", str(path), "--json", *SWARM))


TOML_VALUES = st.one_of(
    st.integers(-(2**40), 2**40).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(
        lambda x: "nan" if math.isnan(x) else ("inf" if x > 0 else "-inf")
        if math.isinf(x) else repr(x)
    ),
    st.sampled_from(['"s-k"', '"both"', '"x"', '""', "true", "false", "[]", "[1, 2]",
                     "[0.1, 0.2, 0.3]", "[2.0, 1.0]", '["a"]', "{}", "{ a = 1 }", "1979-05-27"]),
)  # fmt: skip
SECTIONS = {
    "estimate": ["particles", "iterations", "schedule", "inertia", "seed", "polish", "bogus"],
    "estimate.field": ["R", "L", "C"],
    "estimate.armature": ["R", "L"],
    "observer": ["window_s", "hop_s", "circuits", "drive_id", "decimate", "confirm_windows"],
    "observer.quality": ["R", "L", "K", "X"],
    "source": ["kind", "options"],
    "zenoh": ["mode", "listen", "enabled"],
    "log": ["dir", "rotate_mb"],
    "nonsense": ["a"],
}


@st.composite
def config_text(draw: Any) -> str:
    """A TOML config: right and wrong keys, types and ranges; sometimes not TOML at all."""
    if draw(st.integers(0, 9)) == 0:
        return draw(st.text(max_size=80))
    parts = []
    for section in draw(st.lists(st.sampled_from(sorted(SECTIONS)), unique=True, max_size=4)):
        parts.append(f"[{section}]")
        for key in draw(st.lists(st.sampled_from(SECTIONS[section]), unique=True, max_size=3)):
            parts.append(f"{key} = {draw(TOML_VALUES)}")
    return "\n".join(parts) + "\n"


@pytest.fixture(scope="module")
def good_csv(base, folder) -> Path:
    from observer.recording import write_recording

    path = folder / "good.csv"
    write_recording(base, path)
    return path


@given(text=config_text(), encoding=st.sampled_from(["utf-8"] * 4 + ["utf-16", "latin-1"]))
@FUZZ
def test_fuzzed_config_files_end_in_an_error_line_or_an_estimate(good_csv, folder, text, encoding):
    cfg = folder / "c.toml"
    # Saved by another editor: UTF-16 (with its BOM) or Latin-1 is not TOML's UTF-8.
    cfg.write_bytes(text.encode(encoding, errors="replace"))
    code, out, err = cli("estimate", str(good_csv), "--json", "--config", str(cfg), *SWARM)
    if code == 2:
        assert "c.toml" in err or "--particles" in err, err  # names the file
    assert_clean_outcome(code, out, err)


def test_a_missing_config_file_is_one_line(good_csv, folder):
    code, out, err = cli("estimate", str(good_csv), "--config", str(folder / "none.toml"))
    assert code == 2 and "none.toml" in err and "not found" in err
    assert len(err.strip().splitlines()) == 1
