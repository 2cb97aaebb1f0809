"""observer.recording.units: recordings in other units than SI (--units)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from observer.recording import RecordingError, parse_units, to_si
from tests.observer.recording.helpers import make_recording


def test_parse_units_gives_factors_to_si():
    f = parse_units("t=ms, ia=mA,omega=rpm,va=kV,vf=-V")
    assert f == {
        "t": 1e-3, "ia": 1e-3, "omega": pytest.approx(2 * math.pi / 60), "va": 1e3, "vf": -1.0
    }  # fmt: skip
    assert parse_units("t=\u00b5s") == {"t": 1e-6}
    assert parse_units("omega=Hz")["omega"] == pytest.approx(2 * math.pi)


@pytest.mark.parametrize(
    ("spec", "fragment"),
    [
        ("t", "expected COLUMN=UNIT"),
        ("x=ms", "unknown column 'x'"),
        ("ia=furlong", "allowed: A, mA, kA"),
        ("t=ms,t=s", "given twice"),
        ("t=-s", "cannot be inverted"),
        ("", "no COLUMN=UNIT"),
    ],
)
def test_bad_unit_specifications_are_named(spec: str, fragment: str):
    with pytest.raises(ValueError, match=fragment):
        parse_units(spec)


def test_to_si_rescales_and_notes_it():
    rec = make_recording(100)
    out = to_si(rec, parse_units("t=ms,ia=-mA"))
    np.testing.assert_allclose(out.t, rec.t * 1e-3)
    np.testing.assert_allclose(out["ia"], -rec["ia"] * 1e-3)
    np.testing.assert_array_equal(out["va"], rec["va"])
    assert out.metadata["units_converted"] == {"t": 1e-3, "ia": -1e-3}


def test_to_si_of_a_missing_column_is_an_error():
    rec = make_recording(100, channels=("vf", "if"))
    with pytest.raises(RecordingError, match="'omega'"):
        to_si(rec, {"omega": 1.0})
