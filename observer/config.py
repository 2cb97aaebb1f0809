"""Strict TOML configuration.

Every section is a frozen dataclass; the loader walks the TOML tables against
the dataclasses' type hints, so an unknown key, a wrong type or a value out of
range is rejected at start with a message naming the key and the file. Paths
(fields with ``metadata={"path": True}``) are taken relative to the config
file. There is no hidden merging from environment variables.

To add a section, add a dataclass field to :class:`Config` whose type is
another frozen dataclass with defaults.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import tomllib
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")

#: Largest swarm (particles): far beyond any useful size (100 is the default), and small
#: enough that a typo (1e11) is an error, not an allocation of terabytes.
MAX_PARTICLES = 10_000


class ConfigError(ValueError):
    """A configuration problem, with the file and key in its message."""


def _range(x: Any) -> str | None:
    if x is None:
        return None
    lo, hi = x
    if not (0 < lo < hi and math.isfinite(hi)):
        return f"needs 0 < low < high, got [{lo}, {hi}]"
    return None


@dataclass(frozen=True)
class SearchRangeConfig:
    """Optional bounds of one winding's swarm search; unset: derived from the data."""

    R: tuple[float, float] | None = dataclasses.field(
        default=None, metadata={"check": _range, "help": "resistance range [low, high] (ohm)"}
    )
    L: tuple[float, float] | None = dataclasses.field(
        default=None, metadata={"check": _range, "help": "inductance range [low, high] (H)"}
    )

    def __post_init__(self) -> None:
        if (self.R is None) != (self.L is None):
            raise ValueError("a search range needs both R and L (or neither)")


@dataclass(frozen=True)
class EstimateConfig:
    """Swarm settings of the estimators."""

    particles: int = dataclasses.field(default=100, metadata={"min": 2, "max": MAX_PARTICLES})
    iterations: int = dataclasses.field(default=100, metadata={"min": 1})
    schedule: str = dataclasses.field(
        default="s-k", metadata={"choices": ("s-k", "k-s", "social", "individual")}
    )
    inertia: float = dataclasses.field(default=0.7, metadata={"min": 0.0, "max": 1.2})
    seed: int = 0
    polish: bool = True
    field: SearchRangeConfig = SearchRangeConfig()
    armature: SearchRangeConfig = SearchRangeConfig()

    def replace(self, **changes: Any) -> EstimateConfig:
        return dataclasses.replace(self, **changes)


def _positive(x: Any) -> str | None:
    return None if x is not None and x > 0 else f"must be > 0, got {x!r}"


def _above_one(x: Any) -> str | None:
    return None if x > 1 else f"must be > 1, got {x!r}"


def _fraction(x: Any) -> str | None:
    return None if 0 < x < 1 else f"must be between 0 and 1 (exclusive), got {x!r}"


def _key_name(x: Any) -> str | None:
    if not x or any(c in x for c in "/*$?#\\ "):
        return f"must be a non-empty name without '/', '*', '$', '?', '#' or spaces, got {x!r}"
    return None


def _optional_key_name(x: Any) -> str | None:
    return _key_name(x) if x else None


# ------------------------------------------------------------- the measurement chain

#: Analog anti-aliasing filter families of a channel's front end.
FILTER_KINDS: tuple[str, ...] = ("none", "butter", "bessel", "rc")

MAX_FILTER_ORDER = 4

#: The voltage between samples, see :mod:`observer.estimation.intersample`.
INTERSAMPLE_MODELS: tuple[str, ...] = ("auto", "hold", "smooth", "switched", "averaged")

_FILTER_RE = re.compile(
    r"^\s*(?P<kind>[a-z]+?)(?P<order>\d+)?\s*(@\s*(?P<cutoff>[^@]+?))?\s*$", re.IGNORECASE
)
_FS_RE = re.compile(r"^fs\s*/\s*(?P<div>[0-9.eE+-]+)$", re.IGNORECASE)


def parse_filter(text: str) -> dict[str, Any]:
    """``none`` or ``KIND ORDER @ CUTOFF`` -> ``filter, order, cutoff_hz, cutoff_per_fs``.

    ``KIND`` is ``butter``, ``bessel`` or ``rc``, ``ORDER`` 1..4, ``CUTOFF`` the -3 dB
    frequency in Hz (``500``, ``500hz``) or a fraction of the sample rate (``fs/4``),
    e.g. ``butter2@fs/4``, ``rc1@500``. The one grammar of filters for the config,
    the estimator and the simulator. Raises ValueError with a one-line reason.
    """
    raw = text.strip().lower()
    if raw in ("none", "0", "off"):
        return {"filter": "none", "order": 0, "cutoff_hz": None, "cutoff_per_fs": None}
    m = _FILTER_RE.match(raw)
    if not m:
        raise ValueError(f"filter {text!r} is not KIND ORDER@CUTOFF, e.g. butter2@fs/4 or rc1@500")
    kind = m["kind"]
    if kind not in FILTER_KINDS or kind == "none":
        raise ValueError(
            f"unknown filter {kind!r} in {text!r} (expected none, butter, bessel or rc)"
        )
    if m["order"] is None:
        raise ValueError(f"filter {text!r} has no order (e.g. {kind}2@fs/4)")
    order = int(m["order"])
    if not 1 <= order <= MAX_FILTER_ORDER:
        raise ValueError(f"filter order must be 1..{MAX_FILTER_ORDER}, got {order} in {text!r}")
    if m["cutoff"] is None:
        raise ValueError(f"filter {text!r} has no cutoff (e.g. {kind}{order}@500 or @fs/4)")
    cutoff = m["cutoff"].strip()
    fs = _FS_RE.match(cutoff)
    if fs:
        try:
            div = float(fs["div"])
        except ValueError:
            raise ValueError(f"cutoff {cutoff!r} is not fs/NUMBER") from None
        if not (math.isfinite(div) and div > 0):
            raise ValueError(f"cutoff {cutoff!r}: the divisor must be > 0")
        return {"filter": kind, "order": order, "cutoff_hz": None, "cutoff_per_fs": 1.0 / div}
    if cutoff.endswith("hz"):
        cutoff = cutoff[:-2].strip()
    try:
        hz = float(cutoff)
    except ValueError:
        raise ValueError(f"cutoff {m['cutoff'].strip()!r} is not a number of Hz or fs/N") from None
    if not (math.isfinite(hz) and hz > 0):
        raise ValueError(f"cutoff must be > 0 Hz, got {hz:g}")
    return {"filter": kind, "order": order, "cutoff_hz": hz, "cutoff_per_fs": None}


def _filter_text(x: Any) -> str | None:
    if x is None:
        return None
    try:
        parse_filter(x)
    except ValueError as exc:
        return str(exc)
    return None


def _nonnegative(x: Any) -> str | None:
    return None if x >= 0 else f"must be >= 0, got {x!r}"


def _gain_tolerance(x: Any) -> str | None:
    return None if 0 <= x < 0.5 else f"must be a fraction in [0, 0.5), got {x!r}"


@dataclass(frozen=True)
class ChannelFrontEnd:
    """One channel's measurement front end, as far as it is known.

    ``filter`` unset means unknown: the estimator then decides from the data.
    """

    filter: str | None = dataclasses.field(
        default=None,
        metadata={
            "check": _filter_text,
            "help": "anti-aliasing filter: none, or KIND ORDER@CUTOFF (butter2@fs/4, rc1@500)",
        },
    )
    delay_us: float = dataclasses.field(
        default=0.0,
        metadata={
            "check": _nonnegative,
            "help": "sampled this long after the nominal instant (us)",
        },
    )
    averaging: bool = dataclasses.field(
        default=False, metadata={"help": "the sample is the mean over the period ending at it"}
    )
    gain_tolerance: float = dataclasses.field(
        default=0.0,
        metadata={
            "check": _gain_tolerance,
            "help": "the sensor's gain accuracy, relative one-sigma (0.005: 0.5 %); every "
            "estimate's std takes it as a bias all windows share",
        },
    )

    @property
    def known(self) -> bool:
        return self.filter is not None


@dataclass(frozen=True)
class ChainConfig:
    """The measurement chain: what happens to each signal between the motor and a number.

    Configure what you know (the data acquisition's anti-aliasing filters, an
    integrating voltage measurement); the estimator models a known front end
    exactly and decides the rest from the data.
    """

    intersample: str = dataclasses.field(
        default="auto",
        metadata={
            "choices": INTERSAMPLE_MODELS,
            "help": "the voltage between samples: auto, hold, smooth, switched or averaged",
        },
    )
    va: ChannelFrontEnd = ChannelFrontEnd()
    ia: ChannelFrontEnd = ChannelFrontEnd()
    vf: ChannelFrontEnd = ChannelFrontEnd()
    i_f: ChannelFrontEnd = dataclasses.field(default=ChannelFrontEnd(), metadata={"key": "if"})
    omega: ChannelFrontEnd = ChannelFrontEnd()


@dataclass(frozen=True)
class SourceConfig:
    """Where samples come from: ``kind`` names a registered source, ``options`` its settings."""

    kind: str = dataclasses.field(default="replay", metadata={"help": "registered source name"})
    options: dict[str, Any] = dataclasses.field(
        default_factory=dict, metadata={"help": "the source's own options, checked by it"}
    )


@dataclass(frozen=True)
class QualityConfig:
    """Largest one-sigma relative uncertainty for a window's fit to count as evidence.

    The uncertainty is the estimator's ``std``: noise (sandwich covariance),
    the errors-in-variables correction and the model error its specification
    test finds (see :mod:`observer.estimation.stages`). A parameter published
    as ``ok`` should be within its tolerance of the truth: the defaults are
    the issue's tolerances divided by 2.5 (Rf, Lf, K 1 %, Ra 2 %, La 5 %). A
    parameter whose window does not identify it this well does not update the
    tracked state (quality ``"held"``): the tracker only carries it forward.
    """

    R: float = dataclasses.field(
        default=0.008, metadata={"check": _positive, "help": "armature resistance"}
    )
    L: float = dataclasses.field(
        default=0.02, metadata={"check": _positive, "help": "armature inductance"}
    )
    K: float = dataclasses.field(
        default=0.004, metadata={"check": _positive, "help": "EMF constant"}
    )
    field_R: float = dataclasses.field(
        default=0.004, metadata={"check": _positive, "help": "field resistance"}
    )
    field_L: float = dataclasses.field(
        default=0.004, metadata={"check": _positive, "help": "field inductance"}
    )

    def limits(self, circuit: str) -> dict[str, float]:
        """The limits of one circuit's parameters ``R, L[, K]``."""
        if circuit == "field":
            return {"R": self.field_R, "L": self.field_L}
        return {"R": self.R, "L": self.L, "K": self.K}


@dataclass(frozen=True)
class AgreeConfig:
    """Relative difference of a window's fit from the tracked value still taken as agreement.

    A larger one widens the next window's swarm search around the tracked value
    (whether the parameter changed is for the tracker's change test to say).
    """

    R: float = dataclasses.field(default=0.03, metadata={"check": _positive})
    L: float = dataclasses.field(default=0.10, metadata={"check": _positive})
    K: float = dataclasses.field(default=0.03, metadata={"check": _positive})


def _non_negative(x: Any) -> str | None:
    return None if x >= 0 else f"must be >= 0, got {x!r}"


@dataclass(frozen=True)
class TrackerConfig:
    """The tracked motor state behind the window fits (:mod:`observer.service.tracker`).

    Process noise from physical rates, as the one-sigma relative change of a
    random walk per minute; change detection; optional thermal models; the
    winding temperature's reference.
    """

    # How far a resistance wanders per minute beyond its tracked rate of change.
    R_drift_per_min: float = dataclasses.field(default=0.005, metadata={"check": _positive})
    # Typical largest rate of change of a resistance (fraction per minute: heating
    # at full load); the tracked rate starts within it and wanders about this much per minute.
    R_rate_per_min: float = dataclasses.field(default=0.05, metadata={"check": _positive})
    # Inductances (saturation with the operating point) and the EMF constant drift slowly.
    L_drift_per_min: float = dataclasses.field(default=0.01, metadata={"check": _positive})
    K_drift_per_min: float = dataclasses.field(default=0.005, metadata={"check": _positive})
    # A window whose fit is further than this many sigma from the tracked state
    # does not update it (it still counts towards a change).
    gate_sigma: float = dataclasses.field(default=4.0, metadata={"check": _positive})
    # Smallest step announced as a change (relative); smaller ones are tracked.
    min_change_R: float = dataclasses.field(default=0.01, metadata={"check": _positive})
    min_change_L: float = dataclasses.field(default=0.05, metadata={"check": _positive})
    min_change_K: float = dataclasses.field(default=0.01, metadata={"check": _positive})
    # Log-likelihood ratio (of a step against none, observer.service.changes) that
    # confirms a change.
    change_threshold: float = dataclasses.field(default=10.0, metadata={"check": _positive})
    # Longest wait (s) after a change is confirmed for a window that shows its size.
    change_wait_s: float = dataclasses.field(default=3.0, metadata={"check": _positive})
    # Thermal time constants of the windings (s), motor data; 0: no thermal model,
    # the resistance is tracked as a level with a rate of change.
    # With no thermal time constant: weigh thermal models of time constants 20 s - 43 min
    # against the level with a rate, by how well each predicts the windows, and publish
    # their mixture (observer.service.tracker.ThermalBank); false: the level with a rate.
    identify_thermal: bool = True
    field_thermal_tau_s: float = dataclasses.field(default=0.0, metadata={"check": _non_negative})
    armature_thermal_tau_s: float = dataclasses.field(
        default=0.0, metadata={"check": _non_negative}
    )
    # Winding resistances at the reference temperature (ohm); 0: no temperature published.
    field_r_ref_ohm: float = dataclasses.field(default=0.0, metadata={"check": _non_negative})
    armature_r_ref_ohm: float = dataclasses.field(default=0.0, metadata={"check": _non_negative})
    reference_c: float = 20.0
    alpha_per_k: float = dataclasses.field(default=0.00393, metadata={"check": _positive})


@dataclass(frozen=True)
class SpeedConfig:
    """EMF speed and the tachometer cross-check (:mod:`observer.service.speed`)."""

    # Raise a tachometer event when the measured speed reads below the EMF speed.
    check_tachometer: bool = True
    # Model error of the EMF speed (relative) on top of its statistical uncertainty.
    tolerance: float = dataclasses.field(default=0.02, metadata={"check": _positive})
    # A window disagrees when the measured speed is below the EMF speed by more than
    # tolerance * |EMF speed| + n_sigma * sigma.
    n_sigma: float = dataclasses.field(default=4.0, metadata={"check": _positive})
    # Only windows where a reading this much low (relative) would show count, for or against.
    min_loss: float = dataclasses.field(default=0.05, metadata={"check": _fraction})
    # Disagreement this long (s) raises the event (and as long an agreement clears it); a
    # window short by k margins counts k times, at most half of this (never one window alone).
    alarm_s: float = dataclasses.field(default=0.5, metadata={"check": _positive})
    # Without a speed channel the armature is not estimated (K and the speed cannot be
    # told apart): the EMF speed then uses these (0: no EMF speed).
    Ra_ohm: float = dataclasses.field(default=0.0, metadata={"check": _non_negative})
    La_h: float = dataclasses.field(default=0.0, metadata={"check": _non_negative})
    K_h: float = dataclasses.field(default=0.0, metadata={"check": _non_negative})


@dataclass(frozen=True)
class ObserverConfig:
    """The sliding-window observer."""

    drive_id: str = dataclasses.field(
        default="drive1", metadata={"check": _key_name, "help": "name in the Zenoh key"}
    )
    # One daemon observes one motor; a drive with several motors runs one daemon per motor,
    # each with its motor_id: keys dcobserver/<drive_id>/<motor_id>/...
    # ("": dcobserver/<drive_id>/...).
    motor_id: str = dataclasses.field(
        default="", metadata={"check": _optional_key_name, "help": "motor name in the Zenoh key"}
    )
    window_s: float = dataclasses.field(default=1.0, metadata={"check": _positive})
    hop_s: float = dataclasses.field(default=0.1, metadata={"check": _positive})
    circuits: str = dataclasses.field(
        default="both", metadata={"choices": ("both", "field", "armature")}
    )
    seed: int = 0
    cold_particles: int = dataclasses.field(default=60, metadata={"min": 2, "max": MAX_PARTICLES})
    cold_iterations: int = dataclasses.field(default=40, metadata={"min": 1})
    warm_particles: int = dataclasses.field(default=24, metadata={"min": 2, "max": MAX_PARTICLES})
    warm_iterations: int = dataclasses.field(default=20, metadata={"min": 1})
    explore_fraction: float = dataclasses.field(default=0.2, metadata={"check": _fraction})
    initial_range_factor: float = dataclasses.field(default=2.0, metadata={"check": _above_one})
    min_range_factor: float = dataclasses.field(default=1.05, metadata={"check": _above_one})
    max_range_factor: float = dataclasses.field(default=4.0, metadata={"check": _above_one})
    shrink: float = dataclasses.field(default=0.7, metadata={"check": _fraction})
    widen: float = dataclasses.field(default=3.0, metadata={"check": _above_one})
    degrade_ratio: float = dataclasses.field(default=2.0, metadata={"check": _above_one})
    min_field_taus: float = dataclasses.field(default=3.0, metadata={"check": _positive})
    max_gap_periods: float = dataclasses.field(default=3.0, metadata={"check": _above_one})
    decimate: int = dataclasses.field(default=1, metadata={"min": 1})
    buffer_s: float = dataclasses.field(default=10.0, metadata={"check": _positive})
    stall_s: float = dataclasses.field(default=1.0, metadata={"check": _positive})
    health_s: float = dataclasses.field(default=1.0, metadata={"check": _positive})
    max_lag_windows: int = dataclasses.field(default=20, metadata={"min": 1})
    # The armature's estimate in a second process while this one estimates the field
    # (same numbers, about half the latency on two free cores). auto: on where the
    # daemon may use two or more CPUs; off suits several daemons sharing the cores.
    parallel_circuits: str = dataclasses.field(
        default="auto",
        metadata={
            "choices": ("auto", "on", "off"),
            "help": "estimate the armature in a second process (auto: with 2+ CPUs)",
        },
    )
    chain_windows: int = dataclasses.field(
        default=10,
        metadata={
            "min": 1,
            "help": "estimated windows that decide the measurement chain (unless [chain] does)",
        },
    )
    quality: QualityConfig = QualityConfig()
    agree: AgreeConfig = AgreeConfig()
    tracker: TrackerConfig = TrackerConfig()
    speed: SpeedConfig = SpeedConfig()

    def __post_init__(self) -> None:
        if self.hop_s > self.window_s:
            raise ValueError(f"hop_s ({self.hop_s}) must not exceed window_s ({self.window_s})")
        if self.buffer_s < 2 * self.window_s:
            raise ValueError(f"buffer_s ({self.buffer_s}) must be >= 2 * window_s")
        if not self.min_range_factor < self.max_range_factor:
            raise ValueError("min_range_factor must be < max_range_factor")


def _pem_file(x: Any) -> str | None:
    if not x:
        return None
    try:
        with open(x, "rb") as fh:
            head = fh.read(1 << 16)
    except OSError as exc:
        return f"cannot read {x}: {exc.strerror or exc}"
    return None if b"-----BEGIN " in head else f"{x} is not a PEM file (no '-----BEGIN' line)"


def _readable_file(x: Any) -> str | None:
    if not x:
        return None
    try:
        with open(x, "rb"):
            return None
    except OSError as exc:
        return f"cannot read {x}: {exc.strerror or exc}"


def _key_names(x: Any) -> str | None:
    for name in x:
        problem = _key_name(name)
        if problem:
            return problem
    return None


@dataclass(frozen=True)
class TlsConfig:
    """TLS on the Zenoh links (``tls/HOST:PORT`` endpoints); on when ``root_ca`` is set.

    One certificate serves both directions: presented when listening and, with
    ``mutual``, when connecting. Its common name is this party's identity in
    ``[zenoh.access]`` (``identify_by = "common_name"``). A listener's
    certificate must name the host others connect to (subjectAltName
    ``DNS:`` or ``IP:``) when they verify names.
    """

    root_ca: str = dataclasses.field(
        default="", metadata={"path": True, "check": _pem_file, "help": "CA certificate (PEM)"}
    )
    certificate: str = dataclasses.field(
        default="", metadata={"path": True, "check": _pem_file, "help": "own certificate (PEM)"}
    )
    private_key: str = dataclasses.field(
        default="", metadata={"path": True, "check": _pem_file, "help": "its private key (PEM)"}
    )
    # Ask the other side of every link for a certificate signed by root_ca (mutual TLS).
    mutual: bool = True
    # When connecting, check that the listener's certificate names the host in the endpoint.
    verify_name: bool = True

    @property
    def enabled(self) -> bool:
        return bool(self.root_ca)

    def __post_init__(self) -> None:
        if bool(self.certificate) != bool(self.private_key):
            raise ValueError("certificate and private_key go together: set both or neither")
        if self.certificate and not self.root_ca:
            raise ValueError("a certificate needs root_ca, the CA that signed the certificates")
        if self.root_ca and self.mutual and not self.certificate:
            raise ValueError(
                "mutual = true needs this party's own certificate and private_key "
                "(mutual = false: connect to a listener that asks for none)"
            )


@dataclass(frozen=True)
class AuthConfig:
    """User/password authentication of Zenoh links (on top of TLS or without it).

    ``user`` and ``password_file`` are what this party presents when it opens
    a link; ``dictionary_file`` (``user:password`` lines) is what a listener (a
    router, a daemon that subscribers connect to) accepts from others: a link
    with a wrong or missing password is refused.
    """

    user: str = ""
    password_file: str = dataclasses.field(
        default="", metadata={"path": True, "check": _readable_file, "help": "password, one line"}
    )
    dictionary_file: str = dataclasses.field(
        default="", metadata={"path": True, "check": _readable_file, "help": "user:password lines"}
    )

    def __post_init__(self) -> None:
        if bool(self.user) != bool(self.password_file):
            raise ValueError("user and password_file go together: set both or neither")


@dataclass(frozen=True)
class AccessConfig:
    """Who may publish a drive's keys and who may subscribe, enforced by this session.

    Identities are certificate common names (``identify_by = "common_name"``,
    needs mutual TLS) or user names (``"username"``, needs
    ``auth.dictionary_file``). Everything not granted here is denied, and Zenoh
    drops denied messages silently.
    """

    enabled: bool = False
    identify_by: str = dataclasses.field(
        default="common_name", metadata={"choices": ("common_name", "username")}
    )
    # drive_id -> identities allowed to publish dcobserver/<drive_id>/** (estimates, health,
    # the latest queryable); nobody else may.
    publishers: dict[str, list[str]] = dataclasses.field(default_factory=dict)
    # Identities allowed to subscribe to and query dcobserver/** (never to publish).
    subscribers: list[str] = dataclasses.field(default_factory=list)

    def __post_init__(self) -> None:
        for drive, identities in self.publishers.items():
            problem = _key_name(drive) or _key_names(identities)
            if problem:
                raise ValueError(f"publishers.{drive}: {problem}")
        problem = _key_names(self.subscribers)
        if problem:
            raise ValueError(f"subscribers: {problem}")


@dataclass(frozen=True)
class ZenohLinkConfig:
    """Endpoints and security of a Zenoh session: the ``[zenoh]`` table of every command.

    ``dcobserver router --config`` and ``dcobserver subscribe --config`` read
    files with only this table; the daemon's :class:`ZenohConfig` adds its own
    keys.
    """

    listen: list[str] = dataclasses.field(default_factory=list)
    connect: list[str] = dataclasses.field(default_factory=list)
    multicast_scouting: bool = False
    tls: TlsConfig = TlsConfig()
    auth: AuthConfig = AuthConfig()
    access: AccessConfig = AccessConfig()

    def __post_init__(self) -> None:
        for name in ("listen", "connect"):
            for endpoint in getattr(self, name):
                problem = _endpoint(endpoint)
                if problem:
                    raise ValueError(f"{name}: {problem}")
                if endpoint.startswith(("tls/", "quic/")) and not self.tls.enabled:
                    raise ValueError(f"{name}: {endpoint!r} needs [zenoh.tls]")
        if self.tls.enabled and not self.tls.certificate and self.listen:
            raise ValueError("listening on TLS needs tls.certificate and tls.private_key")
        access = self.access
        mutual_tls = self.tls.certificate and self.tls.mutual
        if access.enabled and access.identify_by == "common_name" and not mutual_tls:
            raise ValueError('access.identify_by = "common_name" needs mutual TLS ([zenoh.tls])')
        if access.enabled and access.identify_by == "username" and not self.auth.dictionary_file:
            raise ValueError('access.identify_by = "username" needs auth.dictionary_file')


def _endpoint(x: str) -> str | None:
    protocol, _, address = x.partition("/")
    if protocol not in ("tcp", "tls", "udp", "quic", "unixsock-stream") or not address:
        return f"{x!r} is not an endpoint like 'tcp/HOST:PORT' or 'tls/HOST:PORT'"
    if protocol != "unixsock-stream":
        port = address.split("#", 1)[0].rpartition(":")[2]
        if not port.isdigit() or int(port) > 65535:
            return f"{x!r}: the port must be a number 0-65535 ('{protocol}/HOST:PORT')"
    return None


@dataclass(frozen=True)
class ZenohConfig(ZenohLinkConfig):
    """The daemon's Zenoh session; by default a peer listening on loopback only."""

    enabled: bool = True
    mode: str = dataclasses.field(default="peer", metadata={"choices": ("peer", "client")})
    listen: list[str] = dataclasses.field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    retry_s: float = dataclasses.field(default=5.0, metadata={"check": _positive})
    # At start, wait up to this long for a subscriber of the estimates to be matched
    # before the source is read, so the first estimates are not published to nobody.
    # 0: never wait (a drive must not depend on a subscriber); demos and tests set it.
    wait_for_subscriber_s: float = dataclasses.field(default=0.0, metadata={"min": 0.0})


def _not_negative(x: Any) -> str | None:
    return None if x >= 0 else f"must be >= 0 (0: no limit), got {x!r}"


@dataclass(frozen=True)
class LogConfig:
    """MCAP log of raw samples, estimates and health; ``dir = ""`` turns it off.

    Retention keeps the files of this drive (``<prefix>-<drive_id>-*.mcap`` in
    ``dir``) within ``max_total_gb`` and ``max_age_days``, deleting the oldest
    first and never the file being written; 0 turns a limit off.
    """

    dir: str = dataclasses.field(
        default="", metadata={"path": True, "help": "folder of the log files; empty: no log"}
    )
    prefix: str = dataclasses.field(
        default="dcobserver", metadata={"check": _key_name, "help": "start of the file names"}
    )
    rotate_mb: float = dataclasses.field(
        default=256.0, metadata={"check": _positive, "help": "start a new file at this size (MB)"}
    )
    rotate_s: float = dataclasses.field(
        default=3600.0, metadata={"check": _positive, "help": "or after this long (s)"}
    )
    flush_s: float = dataclasses.field(
        default=0.5,
        metadata={"check": _positive, "help": "write the data to disk this often (s)"},
    )
    block_s: float = dataclasses.field(
        default=0.1, metadata={"check": _positive, "help": "samples per /samples message (s)"}
    )
    max_total_gb: float = dataclasses.field(
        default=10.0,
        metadata={"check": _not_negative, "help": "delete the oldest files beyond (GB); 0: never"},
    )
    max_age_days: float = dataclasses.field(
        default=0.0,
        metadata={"check": _not_negative, "help": "delete files older than this; 0: never"},
    )

    def __post_init__(self) -> None:
        if self.max_total_gb and self.rotate_mb > self.max_total_gb * 1000 / 2:
            raise ValueError(
                f"rotate_mb ({self.rotate_mb:g}) must be at most half of max_total_gb "
                f"({self.max_total_gb:g} GB), so that older files can make room"
            )


@dataclass(frozen=True)
class Config:
    """The whole configuration file."""

    estimate: EstimateConfig = EstimateConfig()
    chain: ChainConfig = ChainConfig()
    source: SourceConfig = SourceConfig()
    observer: ObserverConfig = ObserverConfig()
    zenoh: ZenohConfig = ZenohConfig()
    log: LogConfig = LogConfig()


@dataclass(frozen=True)
class ZenohFileConfig:
    """A file with only a ``[zenoh]`` table: ``dcobserver router`` and ``subscribe --config``."""

    zenoh: ZenohLinkConfig = ZenohLinkConfig()


def load_config(path: str | os.PathLike[str], cls: type[T] = Config) -> T:  # type: ignore[assignment]
    """Read and validate a TOML config file.

    Raises
    ------
    ConfigError
        Naming the file and the offending key.
    """
    p = Path(path)
    return build(cls, read_toml(p), source=str(p), base_dir=p.parent)


def read_toml(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The tables of a TOML file.

    Raises
    ------
    ConfigError
        One line naming the file: not found, unreadable, or not TOML.
    """
    p = Path(path)
    try:
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{p}: config file not found") from None
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read config: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None
    except UnicodeDecodeError as exc:  # TOML is UTF-8: a file saved as UTF-16 or Latin-1
        raise ConfigError(
            f"{p}: not valid TOML: not UTF-8 text (byte {exc.object[exc.start]:#04x} at offset "
            f"{exc.start}); save it as UTF-8"
        ) from None


def build(
    cls: type[T], table: dict[str, Any], *, source: str, base_dir: Path, prefix: str = ""
) -> T:
    """Instantiate dataclass ``cls`` from a TOML table, strictly."""
    hints = typing.get_type_hints(cls)
    # A field's TOML key is its name, or its "key" metadata where the name
    # cannot be a Python identifier (e.g. the channel "if").
    by_key = {f.metadata.get("key", f.name): f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    fields = by_key
    unknown = sorted(set(table) - set(fields))
    if unknown:
        where = f"[{prefix}]" if prefix else "the top level"
        raise ConfigError(
            f"{source}: unknown key '{_join(prefix, unknown[0])}' "
            f"(allowed in {where}: {', '.join(sorted(fields))})"
        )
    values: dict[str, Any] = {}
    for name, raw in table.items():
        key = _join(prefix, name)
        f = fields[name]
        value = _convert(hints[f.name], raw, key=key, source=source, base_dir=base_dir)
        if f.metadata.get("path") and isinstance(value, str):
            value = str((base_dir / value).resolve()) if value else value
        _check(f, value, key=key, source=source)
        values[f.name] = value
    try:
        return cls(**values)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{source}: [{prefix or 'top level'}] {exc}") from None


def _join(prefix: str, name: str) -> str:
    return f"{prefix}.{name}" if prefix else name


def _convert(hint: Any, raw: Any, *, key: str, source: str, base_dir: Path) -> Any:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if raw is None:
            return None
        options = [a for a in args if a is not type(None)]
        errors = []
        for option in options:
            try:
                return _convert(option, raw, key=key, source=source, base_dir=base_dir)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0])
    if dataclasses.is_dataclass(hint):
        if not isinstance(raw, dict):
            raise ConfigError(f"{source}: '{key}' must be a table [{key}]")
        return build(typing.cast(type, hint), raw, source=source, base_dir=base_dir, prefix=key)
    if origin is tuple:
        if not isinstance(raw, list) or len(raw) != len(args):
            raise ConfigError(
                f"{source}: '{key}' must be a list of {len(args)} values, got {raw!r}"
            )
        return tuple(
            _convert(a, r, key=key, source=source, base_dir=base_dir)
            for a, r in zip(args, raw, strict=True)
        )
    if origin is dict:
        if not isinstance(raw, dict):
            raise ConfigError(f"{source}: '{key}' must be a table")
        return {
            str(k): _convert(args[1], v, key=f"{key}.{k}", source=source, base_dir=base_dir)
            for k, v in raw.items()
        }
    if origin is list:
        if not isinstance(raw, list):
            raise ConfigError(f"{source}: '{key}' must be a list, got {raw!r}")
        return [_convert(args[0], r, key=key, source=source, base_dir=base_dir) for r in raw]
    if hint is bool:
        if not isinstance(raw, bool):
            raise ConfigError(f"{source}: '{key}' must be true or false, got {raw!r}")
        return raw
    if hint is int:
        if isinstance(raw, bool) or not isinstance(raw, int):
            raise ConfigError(f"{source}: '{key}' must be an integer, got {raw!r}")
        return raw
    if hint is float:
        if isinstance(raw, bool) or not isinstance(raw, int | float):
            raise ConfigError(f"{source}: '{key}' must be a number, got {raw!r}")
        if not math.isfinite(raw):
            raise ConfigError(f"{source}: '{key}' must be finite, got {raw!r}")
        return float(raw)
    if hint is str:
        if not isinstance(raw, str):
            raise ConfigError(f"{source}: '{key}' must be a string, got {raw!r}")
        return raw
    if hint is Any:
        return raw
    raise ConfigError(f"{source}: '{key}' has an unsupported type {hint!r}")  # pragma: no cover


def _check(f: dataclasses.Field[Any], value: Any, *, key: str, source: str) -> None:
    meta = f.metadata
    if "choices" in meta and value not in meta["choices"]:
        raise ConfigError(
            f"{source}: '{key}' must be one of "
            f"{', '.join(map(repr, meta['choices']))}, got {value!r}"
        )
    if "min" in meta and value is not None and value < meta["min"]:
        raise ConfigError(f"{source}: '{key}' must be >= {meta['min']}, got {value!r}")
    if "max" in meta and value is not None and value > meta["max"]:
        raise ConfigError(f"{source}: '{key}' must be <= {meta['max']}, got {value!r}")
    check = meta.get("check")
    if check is not None:
        problem = check(value)
        if problem:
            raise ConfigError(f"{source}: '{key}' {problem}")
