"""The in-memory recording: :class:`Recording`, its validation and :class:`RecordingError`.

A :class:`Recording` is a frozen, validated set of uniformly sampled signals:
the time base ``t`` (s) plus any non-empty subset of the channels in
:data:`CHANNELS` (armature voltage and current, field voltage and current,
shaft speed), all in SI units (see :data:`UNITS`).

Every problem found, in memory or in a file, raises :class:`RecordingError`,
whose one-line message names the file and, where known, the row (CSV: the
1-based line number in the file) or the message (MCAP) and the column. The
file formats locate their problems through the underscore helpers here
(:class:`_Problem`, :func:`_raise_problem`), shared within this package only.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property, partial
from types import MappingProxyType
from typing import Any, Final, NoReturn

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
PathArg = str | os.PathLike[str]

CHANNELS: Final[tuple[str, ...]] = ("va", "ia", "vf", "if", "omega")
"""Signal channels a recording may carry, in the order they are written."""

UNITS: Final[dict[str, str]] = {
    "t": "s",
    "va": "V",
    "ia": "A",
    "vf": "V",
    "if": "A",
    "omega": "rad/s",
}
"""SI unit of the time column and of every channel."""

_TIME: Final = "t"
_COLUMNS: Final[tuple[str, ...]] = (_TIME, *CHANNELS)
_MIN_SAMPLES: Final = 2
_DEFAULT_REL_TOL: Final = 0.01


# --------------------------------------------------------------------------- errors


class RecordingError(ValueError):
    """A recording (file or in-memory) is unreadable or invalid.

    ``str(err)`` is one user-facing line naming the file and, where known, the
    location and column, e.g. ``"recording.csv: row 17, column 'ia': value is NaN"``.

    Parameters
    ----------
    problem : str
        What is wrong, without the location.
    path : str or os.PathLike, optional
        The file, if the recording came from one.
    row : int, optional
        1-based row: for CSV the line number in the file (header and comment
        lines included); for in-memory data the 1-based sample number.
    column : str, optional
        The column (``"t"`` or a channel) concerned.
    where : str, optional
        A location description used instead of ``row N`` (MCAP messages).
    message_index : int, optional
        1-based index of the MCAP message on :data:`SAMPLES_TOPIC` concerned.

    Attributes
    ----------
    path, row, column, message_index, problem
        As given; ``path`` as a ``str``.
    """

    def __init__(
        self,
        problem: str,
        *,
        path: PathArg | None = None,
        row: int | None = None,
        column: str | None = None,
        where: str | None = None,
        message_index: int | None = None,
    ) -> None:
        self.problem = problem
        self.path: str | None = None if path is None else os.fspath(path)
        self.row = row
        self.column = column
        self.where = where
        self.message_index = message_index
        location = where if where is not None else (f"row {row}" if row is not None else None)
        if column is not None:
            location = f"{location}, column {column!r}" if location else f"column {column!r}"
        text = ": ".join(part for part in (self.path, location, problem) if part)
        super().__init__(" ".join(text.splitlines()))

    def __reduce__(self) -> tuple[Any, ...]:
        # The keyword-only arguments would be lost by the default exception pickling.
        rebuild = partial(
            RecordingError,
            self.problem,
            path=self.path,
            row=self.row,
            column=self.column,
            where=self.where,
            message_index=self.message_index,
        )
        return (rebuild, ())


@dataclass(frozen=True)
class _Problem:
    """A validation failure before it is given a location."""

    text: str
    index: int | None = None  # 0-based sample index, if the problem is at one sample
    column: str | None = None


@dataclass(frozen=True)
class _Location:
    row: int | None = None
    where: str | None = None
    message_index: int | None = None


_Locator = Callable[[int], _Location]


def _raise_problem(problem: _Problem, path: PathArg | None, locate: _Locator) -> NoReturn:
    location = _Location() if problem.index is None else locate(problem.index)
    raise RecordingError(
        problem.text,
        path=path,
        row=location.row,
        column=problem.column,
        where=location.where,
        message_index=location.message_index,
    )


def _row_locator(row_offset: int) -> _Locator:
    return lambda index: _Location(row=row_offset + index + 1)


# --------------------------------------------------------------------------- validation


def _nonfinite_text(value: float) -> str:
    return "value is NaN" if math.isnan(value) else f"value is {value}"


def _first_nonfinite(columns: Sequence[tuple[str, FloatArray]]) -> _Problem | None:
    """First non-finite cell in row-major order (ties go to the earlier column)."""
    found: _Problem | None = None
    for name, values in columns:
        bad = ~np.isfinite(values)
        if bad.any():
            index = int(np.argmax(bad))
            if found is None or (found.index is not None and index < found.index):
                found = _Problem(_nonfinite_text(float(values[index])), index, name)
    return found


def _timebase_problem(t: FloatArray, rel_tol: float) -> _Problem | None:
    if t.size < _MIN_SAMPLES:
        return _Problem(f"fewer than {_MIN_SAMPLES} samples (found {t.size})")
    nonfinite = _first_nonfinite([(_TIME, t)])
    if nonfinite is not None:
        return nonfinite
    periods = np.diff(t)
    not_increasing = periods <= 0
    if not_increasing.any():
        i = int(np.argmax(not_increasing))
        return _Problem(
            f"time not strictly increasing: t = {t[i + 1]:.9g} s follows t = {t[i]:.9g} s",
            i + 1,
            _TIME,
        )
    median_period = float(np.median(periods))
    off = np.abs(periods - median_period) > rel_tol * median_period
    if off.any():
        i = int(np.argmax(off))
        return _Problem(
            f"non-uniform sampling: period {periods[i]:.6g} s since the previous sample, "
            f"expected {median_period:.6g} s (the median period) within {rel_tol * 100:g}%",
            i + 1,
            _TIME,
        )
    return None


def _samples_problem(
    t: FloatArray, signals: Sequence[tuple[str, FloatArray]], rel_tol: float = _DEFAULT_REL_TOL
) -> _Problem | None:
    """The first problem with a table of samples, in the order a reader meets them."""
    if t.size < _MIN_SAMPLES:
        return _Problem(f"fewer than {_MIN_SAMPLES} samples (found {t.size})")
    nonfinite = _first_nonfinite([(_TIME, t), *signals])
    if nonfinite is not None:
        return nonfinite
    return _timebase_problem(t, rel_tol)


def validate_timebase(
    t: npt.ArrayLike,
    *,
    path: PathArg | None = None,
    rel_tol: float = _DEFAULT_REL_TOL,
    row_offset: int = 0,
) -> None:
    """Check that ``t`` is a usable time base.

    It must hold at least 2 finite samples, be strictly increasing, and every
    sample period must be within ``rel_tol`` of the median period.

    Parameters
    ----------
    t : array_like
        Sample times (s), 1-D.
    path : str or os.PathLike, optional
        File named in the error message.
    rel_tol : float
        Largest allowed relative deviation of one sample period from the median.
    row_offset : int
        Number of rows before the first sample (e.g. header and comment lines of
        a CSV file): sample ``i`` (0-based) is reported as row ``row_offset + i + 1``.

    Raises
    ------
    RecordingError
        Naming the first offending row, with the period found and expected for
        non-uniform sampling.
    ValueError
        If ``rel_tol`` is not positive.
    """
    if not rel_tol > 0:
        raise ValueError(f"rel_tol must be > 0, got {rel_tol!r}")
    times = _as_float_vector(t, _TIME, path=path)
    problem = _timebase_problem(times, rel_tol)
    if problem is not None:
        _raise_problem(problem, path, _row_locator(row_offset))


def _as_float_vector(values: object, name: str, *, path: PathArg | None = None) -> FloatArray:
    """A fresh read-only float64 1-D copy of ``values``; numbers only (no strings)."""
    try:
        array = np.asarray(values)
    except (TypeError, ValueError) as exc:
        raise RecordingError(f"not an array of numbers: {exc}", path=path, column=name) from exc
    if array.dtype.kind not in "iuf":
        raise RecordingError(
            f"must hold numbers, got an array of dtype {array.dtype}", path=path, column=name
        )
    if array.ndim != 1:
        raise RecordingError(
            f"must be 1-D, got an array of shape {array.shape}", path=path, column=name
        )
    result = array.astype(np.float64, copy=True)
    result.setflags(write=False)
    return result


def _normalized_metadata(metadata: object, *, path: PathArg | None = None) -> dict[str, Any]:
    """A deep copy of ``metadata`` exactly as it reads back from a file (JSON)."""
    if not isinstance(metadata, Mapping):
        raise RecordingError(
            f"metadata must be a mapping, got {type(metadata).__name__}", path=path
        )
    try:
        text = json.dumps(dict(metadata), allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise RecordingError(f"metadata is not JSON-serializable: {exc}", path=path) from exc
    result: dict[str, Any] = json.loads(text)
    return result


def _allowed_columns_text() -> str:
    return ", ".join(_COLUMNS)


def _reject_json_constant(constant: str) -> NoReturn:
    raise ValueError(f"{constant} is not valid JSON")


def _loads_strict(text: str | bytes) -> Any:
    """``json.loads`` without the non-standard NaN/Infinity constants."""
    return json.loads(text, parse_constant=_reject_json_constant)


# --------------------------------------------------------------------------- Recording


@dataclass(frozen=True, eq=False, repr=False)
class Recording:
    """A validated, immutable recording of DC-motor winding signals.

    Parameters
    ----------
    t : numpy.ndarray
        Sample times (s): at least 2, strictly increasing, uniformly sampled
        (every period within 1 % of the median period).
    signals : Mapping[str, numpy.ndarray]
        A non-empty subset of :data:`CHANNELS` mapped to 1-D arrays of the length
        of ``t``, in SI units (:data:`UNITS`); all values finite.
    metadata : Mapping[str, Any]
        Free-form JSON-serializable description (motor, seed, generator, ...).

    Notes
    -----
    The arrays are stored as read-only float64 copies and ``signals`` as a
    read-only mapping in :data:`CHANNELS` order. ``metadata`` is stored as a
    read-only mapping of a deep copy normalised through JSON (tuples become
    lists, keys strings), i.e. exactly as it reads back from a file.
    Two recordings are equal when all their arrays and metadata are equal.

    Raises
    ------
    RecordingError
        If any of the rules above is broken; rows are 1-based sample numbers.
    """

    t: np.ndarray
    signals: Mapping[str, np.ndarray]
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = _as_float_vector(self.t, _TIME)
        if not isinstance(self.signals, Mapping):
            raise RecordingError(
                f"signals must be a mapping of channel name to array, "
                f"got {type(self.signals).__name__}"
            )
        for name in self.signals:
            if name not in CHANNELS:
                raise RecordingError(
                    f"unknown channel {name!r}; allowed: {', '.join(CHANNELS)}", column=str(name)
                )
        if not self.signals:
            raise RecordingError(f"no signal channel; need at least one of {', '.join(CHANNELS)}")
        signals: dict[str, FloatArray] = {}
        for name in CHANNELS:
            if name in self.signals:
                values = _as_float_vector(self.signals[name], name)
                if values.size != t.size:
                    raise RecordingError(
                        f"has {values.size} samples but t has {t.size}", column=name
                    )
                signals[name] = values
        problem = _samples_problem(t, list(signals.items()))
        if problem is not None:
            _raise_problem(problem, None, _row_locator(0))
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "signals", MappingProxyType(signals))
        object.__setattr__(self, "metadata", MappingProxyType(_normalized_metadata(self.metadata)))

    # ------------------------------------------------------------------ properties

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return int(self.t.size)

    @cached_property
    def dt(self) -> float:
        """Sample period (s): the median of the differences of ``t``."""
        return float(np.median(np.diff(self.t)))

    @property
    def sample_rate_hz(self) -> float:
        """Sample rate (Hz), ``1 / dt``."""
        return 1.0 / self.dt

    @property
    def duration_s(self) -> float:
        """Time covered (s), counting one period per sample: ``n_samples * dt``."""
        return self.n_samples * self.dt

    @property
    def channels(self) -> tuple[str, ...]:
        """Names of the channels present, in :data:`CHANNELS` order."""
        return tuple(self.signals)

    # ------------------------------------------------------------------ access

    def __getitem__(self, name: str) -> FloatArray:
        """The read-only array of ``"t"`` or of a channel.

        Raises
        ------
        KeyError
            If the recording has no such column.
        """
        if name == _TIME:
            return self.t
        try:
            return self.signals[name]
        except KeyError:
            raise KeyError(
                f"recording has no column {name!r}; it has {', '.join((_TIME, *self.channels))}"
            ) from None

    def has(self, *names: str) -> bool:
        """Whether every one of ``names`` (``"t"`` or channels) is present."""
        return all(name == _TIME or name in self.signals for name in names)

    def require(self, *names: str, path: PathArg | None = None, purpose: str | None = None) -> None:
        """Raise unless every one of ``names`` is present.

        Parameters
        ----------
        *names : str
            Required columns (``"t"`` or channels).
        path : str or os.PathLike, optional
            File named in the message.
        purpose : str, optional
            What the columns are needed for, e.g. ``"the field circuit"``.

        Raises
        ------
        RecordingError
            e.g. ``"run.csv: column 'vf': missing column 'vf' (needed for the
            field circuit); the recording has t, va, ia"``.
        ValueError
            If a name is not ``"t"`` or one of :data:`CHANNELS` (a programming error).
        """
        for name in names:
            if name not in _COLUMNS:
                raise ValueError(f"unknown column {name!r}; allowed: {_allowed_columns_text()}")
        missing = [name for name in names if not self.has(name)]
        if not missing:
            return
        listed = ", ".join(repr(name) for name in missing)
        text = f"missing column{'s' if len(missing) > 1 else ''} {listed}"
        if purpose:
            text += f" (needed for {purpose})"
        text += f"; the recording has {', '.join((_TIME, *self.channels))}"
        raise RecordingError(text, path=path, column=missing[0])

    def slice_time(self, t0: float, t1: float) -> Recording:
        """The samples with ``t0 <= t < t1`` (s), with the same channels and metadata.

        Raises
        ------
        RecordingError
            If fewer than 2 samples fall in the interval.
        """
        start = int(np.searchsorted(self.t, t0, side="left"))
        stop = int(np.searchsorted(self.t, t1, side="left"))
        count = max(0, stop - start)
        if count < _MIN_SAMPLES:
            raise RecordingError(
                f"slice [{t0:g}, {t1:g}) s holds {count} samples, fewer than {_MIN_SAMPLES} "
                f"(the recording spans {self.t[0]:g} to {self.t[-1]:g} s)"
            )
        return Recording(
            t=self.t[start:stop],
            signals={name: values[start:stop] for name, values in self.signals.items()},
            metadata=self.metadata,
        )

    def select(self, *names: str) -> Recording:
        """A recording with only the channels ``names`` (``"t"`` is accepted and ignored).

        Raises
        ------
        KeyError
            If a channel is absent.
        ValueError
            If no channel is named.
        """
        for name in names:
            if not self.has(name):
                raise KeyError(
                    f"recording has no channel {name!r}; it has {', '.join(self.channels)}"
                )
        chosen = {name: self.signals[name] for name in CHANNELS if name in names}
        if not chosen:
            raise ValueError(f"select() needs at least one channel of {', '.join(self.channels)}")
        return Recording(t=self.t, signals=chosen, metadata=self.metadata)

    # ------------------------------------------------------------------ dunder

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Recording):
            return NotImplemented
        return (
            self.channels == other.channels
            and np.array_equal(self.t, other.t)
            and all(np.array_equal(self.signals[c], other.signals[c]) for c in self.channels)
            and dict(self.metadata) == dict(other.metadata)
        )

    def __repr__(self) -> str:
        return (
            f"Recording(n_samples={self.n_samples}, sample_rate_hz={self.sample_rate_hz:.6g}, "
            f"t0={self.t[0]:.9g}, duration_s={self.duration_s:.6g}, channels={self.channels}, "
            f"metadata_keys={tuple(self.metadata)})"
        )

    def __reduce__(self) -> tuple[Any, ...]:
        # MappingProxyType cannot be pickled; rebuild (and re-validate) from plain dicts.
        return (Recording, (self.t, dict(self.signals), dict(self.metadata)))
