"""Can this be a DC motor? Checks of a recording and of its estimates against physics.

A recording in the wrong units (time in ms, current in mA, speed in rpm),
with swapped or inverted channels, or with a stuck sensor still gives numbers;
these checks stop such numbers from passing silently. Each :class:`Finding`
is an ``"error"`` (the data cannot be a DC motor's: estimating would only
produce nonsense) or a ``"warning"`` (unusual for any DC motor: the values are
given, but the likely cause is named), with the units the data is probably in
(:attr:`Finding.suggest`), so the command line can say how to read it instead.

The bounds are what DC motors with a separately excited field are, from small
drives to mill motors, not what one motor is:

=============================  ==============================================
sample rate                    >= 100 Hz for an armature (time constants of
                               0.1-200 ms), >= 20 Hz for a field (50 ms - 10 s)
voltages                       <= 3 kV (warning), <= 20 kV (error); a peak
                               >= 1 V (warning below: a wound field and an
                               armature under load need volts)
armature current               <= 20 kA (warning), <= 100 kA (error)
field current                  <= 1 kA (warning), <= 10 kA (error)
speed                          <= 1000 rad/s = 9550 rpm (warning), 10000 (error)
field resistance               0.1 ohm - 10 kohm
armature resistance            0.1 mohm - 1 kohm
time constants                 field 5 ms - 30 s, armature 10 us - 0.5 s
field power / armature power   1e-3 - 100 (rating: about 1-40 %)
Lf / K                         1 - 2000 (the field has more turns)
fit residual                   <= 10 % of the current's rms or <= 20 times its
                               white noise (a correct model leaves a few times)
=============================  ==============================================

What cannot be told from the data: a uniform rescaling of the speed (rpm or Hz
instead of rad/s) only rescales ``K``, and the equations hold exactly as well;
the speed check catches rpm at the usual speeds, Hz not. Compare ``K*if`` (the
EMF constant at the present field, V*s/rad) with the motor's data sheet.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Final, Literal

import numpy as np

from observer.estimation.identifiability import Identification
from observer.estimation.result import CircuitEstimate

Severity = Literal["error", "warning"]

MIN_RATE_ARMATURE_HZ: Final = 100.0
MIN_RATE_FIELD_HZ: Final = 20.0
MIN_RATE_HZ: Final = 10.0
MAX_RATE_HZ: Final = 1e6
MIN_SAMPLES: Final = 100
ESTIMATOR_MIN_SAMPLES: Final = 10
#: channel -> (warning above, error above), in SI units.
PEAK_LIMITS: Final[dict[str, tuple[float, float]]] = {
    "va": (3e3, 2e4),
    "vf": (3e3, 2e4),
    "ia": (2e4, 1e5),
    "if": (1e3, 1e4),
    "omega": (1e3, 1e4),
}
#: A winding's voltage peaks at least this (V) while its current flows (warning below).
MIN_VOLTAGE_PEAK_V: Final = 1.0
FIELD_RESISTANCE_OHM: Final = (0.1, 1e4)
ARMATURE_RESISTANCE_OHM: Final = (1e-4, 1e3)
FIELD_TAU_S: Final = (5e-3, 30.0)
ARMATURE_TAU_S: Final = (1e-5, 0.5)
#: Largest relative std of L at which a time constant outside these spans is reported.
TAU_KNOWN: Final = 0.25
POWER_RATIO: Final = (1e-3, 100.0)
LF_OVER_K: Final = (1.0, 2000.0)
MAX_RESIDUAL_SHARE: Final = 0.1
MAX_RESIDUAL_NOISE: Final = 20.0

_SMALLER = {"t": "ms", "va": "mV", "vf": "mV", "ia": "mA", "if": "mA", "omega": "rpm"}
_LARGER = {"t": "ms", "va": "kV", "vf": "kV", "ia": "kA", "if": "kA"}


@dataclass(frozen=True)
class Finding:
    """One thing a DC motor cannot be or rarely is.

    Attributes
    ----------
    severity : {"error", "warning"}
    code : str
        Stable short name, e.g. ``"sample_rate"``, ``"peak"``, ``"stuck"``.
    text : str
        One line that names the channel or parameter and the likely cause.
    channel : str or None
    suggest : dict
        Channel -> the unit its values are probably in (e.g. ``{"t": "ms"}``),
        or a sign-inverted unit (``{"ia": "-A"}``); empty when no single cause.
    circuits : tuple of str
        The circuits whose estimates it puts in doubt (default: from ``channel``).
    """

    severity: Severity
    code: str
    text: str
    channel: str | None = None
    suggest: Mapping[str, str] = field(default_factory=dict)
    circuits: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not self.circuits:
            object.__setattr__(self, "circuits", _CIRCUITS_OF.get(self.channel, _BOTH))


_BOTH: Final = ("field", "armature")
_CIRCUITS_OF: Final[dict[str | None, tuple[str, ...]]] = {
    "va": ("armature",),
    "ia": ("armature",),
    "omega": ("armature",),
    "vf": ("field",),
}


def _si(value: float, unit: str) -> str:
    """A short engineering-notation quantity, e.g. ``_si(0.0002, "H") == "200 uH"``."""
    if value == 0 or not math.isfinite(value):
        return f"{value:g} {unit}"
    exp3 = int(math.floor(math.log10(abs(value)) / 3))
    if not -4 <= exp3 <= 3:
        return f"{value:.3g} {unit}"
    prefix = {-4: "p", -3: "n", -2: "u", -1: "m", 0: "", 1: "k", 2: "M", 3: "G"}[exp3]
    return f"{value / 10 ** (3 * exp3):.3g} {prefix}{unit}"


def _rate_finding(dt: float, circuits: Sequence[str]) -> Finding | None:
    rate = 1.0 / dt
    period = f"sample period {_si(dt, 's')} ({_si(rate, 'Hz')})"
    if rate < MIN_RATE_HZ:
        # The first time unit that makes the rate a drive's (integer nanoseconds are what
        # MCAP tools and loggers export).
        hint, suggest = "", {}
        for factor, unit, word in ((1e3, "ms", "milli"), (1e6, "us", "micro"), (1e9, "ns", "nano")):
            if MIN_RATE_ARMATURE_HZ <= rate * factor <= MAX_RATE_HZ:
                hint, suggest = f"; is t in {word}seconds?", {"t": unit}
                break
        return Finding(
            "error", "sample_rate",
            f"{period}: far too slow for a DC motor's windings (time constants of "
            f"milliseconds to seconds: an armature needs >= {MIN_RATE_ARMATURE_HZ:g} Hz, "
            f"a field >= {MIN_RATE_FIELD_HZ:g} Hz){hint}",
            "t", suggest,
        )  # fmt: skip
    needs = MIN_RATE_ARMATURE_HZ if "armature" in circuits else MIN_RATE_FIELD_HZ
    if rate < needs:
        what = "an armature (time constants 0.1-200 ms)" if needs == MIN_RATE_ARMATURE_HZ else (
            "a field winding (time constants 50 ms - 10 s)"
        )  # fmt: skip
        return Finding(
            "warning", "sample_rate",
            f"{period} is too slow for {what}: its inductance will not be identified; "
            "is t in milliseconds?",
            "t", {"t": "ms"}, ("armature" if needs == MIN_RATE_ARMATURE_HZ else "field",),
        )  # fmt: skip
    if rate > MAX_RATE_HZ:
        return Finding(
            "warning", "sample_rate",
            f"{period} is faster than a drive's converters sample (<= 1 MHz): is t in seconds?",
            "t",
        )  # fmt: skip
    return None


def _peak_findings(signals: Mapping[str, np.ndarray], t: np.ndarray | None) -> list[Finding]:
    out: list[Finding] = []
    units = {"va": "V", "vf": "V", "ia": "A", "if": "A", "omega": "rad/s"}
    kinds = {
        "va": "armature voltage", "vf": "field voltage", "ia": "armature current",
        "if": "field current", "omega": "speed",
    }  # fmt: skip
    for name, (warn, error) in PEAK_LIMITS.items():
        if name not in signals or signals[name].size == 0:
            continue
        magnitude = np.abs(signals[name])
        at = int(np.argmax(magnitude))
        peak = float(magnitude[at])
        if peak <= warn:
            continue
        severity: Severity = "error" if peak > error else "warning"
        unit = _SMALLER[name]
        where = f" at t = {float(t[at]):.6g} s" if t is not None and t.size > at else ""
        # Only a value a unit prefix would bring into range suggests that unit.
        plausible = peak / (9.55 if name == "omega" else 1e3) <= warn
        hint = f"; is {name} in {unit}?" if plausible else "; a corrupt value?"
        if name == "omega":
            rpm = peak * 60 / (2 * math.pi)
            text = (
                f"{name} reaches {peak:.4g} rad/s ({rpm:.0f} rpm){where}: faster than DC motors "
                f"run (<= {warn:g} rad/s){hint}"
            )
        else:
            text = (
                f"{name} reaches {_si(peak, units[name])}{where}: no DC motor's {kinds[name]} "
                f"is that large (<= {_si(warn, units[name])}){hint}"
            )
        out.append(Finding(severity, "peak", text, name, {name: unit} if plausible else {}))
    return out


def _low_voltage_findings(signals: Mapping[str, np.ndarray]) -> list[Finding]:
    """Voltages in kV read as V: a winding whose current flows but whose voltage peaks
    below a volt (its resistance and inductance come out 1000 times too small, and plausible)."""
    out: list[Finding] = []
    for voltage, current, what in (("va", "ia", "an armature"), ("vf", "if", "a wound field")):
        if voltage not in signals or current not in signals or signals[voltage].size == 0:
            continue
        peak = float(np.max(np.abs(signals[voltage])))
        flows = float(np.max(np.abs(signals[current]))) > 0
        if flows and 0 < peak < MIN_VOLTAGE_PEAK_V:
            text = (
                f"{voltage} peaks at {_si(peak, 'V')} while {current} flows: {what} needs "
                f"volts (>= {MIN_VOLTAGE_PEAK_V:g} V); is {voltage} in kV?"
            )
            out.append(Finding("warning", "peak", text, voltage, {voltage: "kV"}))
    return out


def _stuck_findings(signals: Mapping[str, np.ndarray]) -> list[Finding]:
    out = []
    for name, x in signals.items():
        if x.size < 10 or np.ptp(x) != 0:
            continue
        if name == "omega" and x[0] == 0:
            text = "omega is 0 in every sample: the motor stands still, so K is not identified"
        else:
            text = (
                f"{name} has the same value ({x[0]:.6g}) in all {x.size} samples: "
                "a stuck or disconnected sensor?"
            )
        out.append(Finding("warning", "stuck", text, name))
    return out


#: The static fit takes means over blocks this long (s): a whole period of 50 Hz mains, six of
#: a 6-pulse bridge's ripple. A converter's ripple voltage is hundreds of volts; its current,
#: behind the inductance and a current channel's filter, lags it by more than a quarter
#: period, so sample by sample the two correlate negatively (Ra = -0.78 ohm on a P-12 at
#: 2 kHz with an unfiltered voltage beside a filtered current).
STATIC_BLOCK_S = 0.02
#: ... and needs at least this many blocks.
STATIC_MIN_BLOCKS = 10


def _block_means(x: np.ndarray, block: int) -> np.ndarray:
    n = (x.size // block) * block
    return x[:n].reshape(-1, block).mean(axis=1)


def _static_armature_fit(
    signals: Mapping[str, np.ndarray], dt: float
) -> tuple[float, float, float, float] | None:
    """Least squares of ``va = Ra*ia + k*(if*omega)`` over block means
    (:data:`STATIC_BLOCK_S`): (Ra, std, k, std), or None."""
    block = max(1, round(STATIC_BLOCK_S / dt))
    va, ia, i_f, omega = (
        _block_means(np.asarray(signals[c], dtype=np.float64), block)
        for c in ("va", "ia", "if", "omega")
    )
    design = np.column_stack([ia, i_f * omega])
    if not np.all(np.isfinite(design)) or va.size < STATIC_MIN_BLOCKS:
        return None
    coef, _, rank, _ = np.linalg.lstsq(design, va, rcond=None)
    if rank < 2:
        return None
    resid = va - design @ coef
    s2 = float(resid @ resid) / max(va.size - 2, 1)
    cov = s2 * np.linalg.inv(design.T @ design)
    return (
        float(coef[0]),
        math.sqrt(max(cov[0, 0], 0)),
        float(coef[1]),
        math.sqrt(max(cov[1, 1], 0)),
    )


#: Below this correlation of the field's voltage with its current (in magnitude) the two do not
#: go together at all: not an inverted sign (-1), a voltage that does not read the winding's.
UNCORRELATED = 0.3


def _sign_findings(
    signals: Mapping[str, np.ndarray], dt: float, circuits: Sequence[str]
) -> list[Finding]:
    out: list[Finding] = []
    if "field" in circuits and "vf" in signals and "if" in signals:
        vf, i_f = signals["vf"], signals["if"]
        power = float(np.dot(i_f, i_f))
        v_power = float(np.dot(vf, vf))
        if power > 0:
            rf = float(np.dot(vf, i_f)) / power
            # How far the two go together (1: in proportion): an inverted channel reads -1;
            # a voltage that reads next to nothing of the current's (a field chopper sampled
            # bare in step with its pulses, always at one phase of them) reads near 0.
            together = float(np.dot(vf, i_f)) / math.sqrt(power * v_power) if v_power > 0 else 0
            if rf < 0 and abs(together) < UNCORRELATED:
                out.append(
                    Finding(
                        "error",
                        "sign",
                        f"field voltage does not follow the field current (vf/if = {rf:.3g} "
                        f"ohm, correlation {together:.2f}): check the vf channel's wiring and "
                        "scaling; a chopper's voltage sampled without a filter in step with its "
                        "pulses reads one phase of them, not the voltage (filter it, or sample "
                        "at a rate that is not a multiple of the pulse frequency)",
                        "vf",
                        {},
                        ("field",),
                    )  # fmt: skip
                )
            elif rf < 0:
                out.append(
                    Finding(
                        "error",
                        "sign",
                        f"field voltage and current correlate negatively (vf/if = {rf:.3g} "
                        "ohm): is the sign of if (or of vf) inverted?",
                        "if",
                        {"if": "-A"},
                        ("field",),
                    )  # fmt: skip
                )
    if "if" in signals:
        i_f = signals["if"]
        top = float(np.max(np.abs(i_f))) if i_f.size else 0.0
        if top > 0 and np.min(i_f) < -0.1 * top and np.max(i_f) > 0.1 * top:
            out.append(
                Finding(
                    "warning",
                    "sign",
                    "if changes sign: a separately excited field's current does not reverse "
                    "in normal operation; are ia and if swapped?",
                    "if",
                )  # fmt: skip
            )
    armature = all(c in signals for c in ("va", "ia", "if", "omega"))
    # The static fit ignores La*dia/dt: over a few samples its signs mean nothing.
    if "armature" in circuits and armature and signals["va"].size >= MIN_SAMPLES:
        fit = _static_armature_fit(signals, dt)
        if fit is not None:
            ra, ra_std, k, k_std = fit
            if ra < 0 and abs(ra) > 5 * ra_std:
                out.append(
                    Finding(
                        "error",
                        "sign",
                        "armature voltage and current correlate negatively once the EMF "
                        f"K*if*omega is taken out (static fit Ra = {ra:.3g} ohm): is the sign "
                        "of ia (or of va) inverted?",
                        "ia",
                        {"ia": "-A"},
                    )  # fmt: skip
                )
            elif k < 0 and abs(k) > 5 * k_std:
                out.append(
                    Finding(
                        "warning",
                        "sign",
                        "the EMF K*if*omega opposes va (static fit K < 0): omega (or if) "
                        "is measured with the opposite sign; K is reported negative",
                        "omega",
                        {"omega": "-rad/s"},
                    )  # fmt: skip
                )
    return out


def _power_findings(signals: Mapping[str, np.ndarray]) -> list[Finding]:
    if not all(c in signals for c in ("va", "ia", "vf", "if")):
        return []
    vf, i_f, va, ia = (signals[c] for c in ("vf", "if", "va", "ia"))
    p_field = float(np.mean(vf * i_f))
    p_arm = float(np.percentile(np.abs(va * ia), 99))
    if not (p_field > 0 and p_arm > 0):
        return []
    ratio = p_field / p_arm
    rf = p_field / float(np.mean(i_f * i_f))
    lo, hi = POWER_RATIO
    share = (
        f"the field takes {_si(p_field, 'W')}, the armature at most {_si(p_arm, 'W')} "
        "(a field takes about 1-40 % of the armature's rating)"
    )
    if ratio > hi:
        if rf < FIELD_RESISTANCE_OHM[0] * 10:
            return [
                Finding("warning", "power", f"{share}: is if in mA?", "if", {"if": "mA"}, _BOTH)
            ]
        if rf > FIELD_RESISTANCE_OHM[1]:
            return [
                Finding("warning", "power", f"{share}: is vf in mV?", "vf", {"vf": "mV"}, _BOTH)
            ]
        return [Finding("warning", "power", f"{share}: is va in kV or ia in kA?", "va", {}, _BOTH)]
    if ratio < lo:
        if rf > FIELD_RESISTANCE_OHM[1]:
            return [
                Finding("warning", "power", f"{share}: is if in kA?", "if", {"if": "kA"}, _BOTH)
            ]
        if rf < FIELD_RESISTANCE_OHM[0] * 10:
            return [
                Finding("warning", "power", f"{share}: is vf in kV?", "vf", {"vf": "kV"}, _BOTH)
            ]
        return [Finding("warning", "power", f"{share}: is ia in mA or va in mV?", "ia", {}, _BOTH)]
    return []


def check_data(
    signals: Mapping[str, np.ndarray],
    dt: float,
    circuits: Sequence[str],
    *,
    t: np.ndarray | None = None,
) -> list[Finding]:
    """Findings about a recording before anything is estimated; errors first.

    Parameters
    ----------
    signals : mapping
        Channel name (``va``, ``ia``, ``vf``, ``if``, ``omega``) -> samples, SI units.
    dt : float
        Sample period (s).
    circuits : sequence of {"field", "armature"}
        What is to be estimated (the sample rate an armature needs is higher).
    t : array, optional
        Sample times (s), to say where a value is out of range.

    Returns
    -------
    list of Finding
        Errors before warnings; within each, in the order a user should fix them
        (time base, magnitudes, signs, stuck channels, power balance).
    """
    findings: list[Finding] = []
    if not (math.isfinite(dt) and dt > 0):
        return [Finding("error", "sample_rate", f"sample period {dt!r} s is not positive", "t")]
    rate = _rate_finding(dt, circuits)
    if rate is not None:
        findings.append(rate)
    n = min((x.size for x in signals.values()), default=0)
    if n < ESTIMATOR_MIN_SAMPLES:
        return [
            Finding(
                "error",
                "too_short",
                f"only {n} samples: too short to estimate anything (at least "
                f"{ESTIMATOR_MIN_SAMPLES}; a few hundred over several time constants to identify)",
            )  # fmt: skip
        ]
    if n < MIN_SAMPLES:
        findings.append(
            Finding(
                "warning",
                "too_short",
                f"only {n} samples ({_si(n * dt, 's')}): too short to identify a winding; "
                "record a few hundred samples or more, over several time constants",
            )  # fmt: skip
        )
    # A magnitude beyond (or below) any motor's names its channel and unit: the power
    # balance below would only say "va or ia" about the same cause.
    peaks = _peak_findings(signals, t) + _low_voltage_findings(signals)
    findings += peaks
    if not any(f.severity == "error" for f in findings):
        # Magnitudes beyond any motor's would overflow the products below.
        with np.errstate(all="ignore"):
            findings += _sign_findings(signals, dt, circuits)
            findings += _stuck_findings(signals)
            if not peaks and n >= MIN_SAMPLES:
                findings += _power_findings(signals)
    return sorted(findings, key=lambda f: f.severity != "error")


def _resistance_finding(est: CircuitEstimate) -> Finding | None:
    r = est.resistance_ohm
    if est.circuit == "field":
        lo, hi = FIELD_RESISTANCE_OHM
        name = "Rf"
        low, high = {"if": "mA"}, {"vf": "mV"}
        low_text, high_text = "is if in mA (or vf in kV)?", "is vf in mV (or if in kA)?"
    else:
        lo, hi = ARMATURE_RESISTANCE_OHM
        name = "Ra"
        low, high = {"ia": "mA"}, {"va": "mV"}
        low_text, high_text = "is ia in mA (or va in kV)?", "is va in mV (or ia in kA)?"
    if not (math.isfinite(r) and r > 0):
        return None
    if r < lo:
        text = f"{name} = {_si(r, 'ohm')} is below any DC motor's ({_si(lo, 'ohm')}): {low_text}"
        return Finding("warning", "resistance", text, None, low, (est.circuit,))
    if r > hi:
        text = f"{name} = {_si(r, 'ohm')} is above any DC motor's ({_si(hi, 'ohm')}): {high_text}"
        return Finding("warning", "resistance", text, None, high, (est.circuit,))
    return None


def _tau_finding(est: CircuitEstimate, ident: Identification) -> Finding | None:
    # A time constant known to within a quarter is enough to see that no motor has it,
    # even where it is too uncertain to be reported as identified.
    rel = est.relative_std("L")
    known = ident.identified.get("L", False) or (est.describes_window and rel <= TAU_KNOWN)
    tau = est.time_constant_s
    if not known or not math.isfinite(tau):
        return None
    lo, hi = FIELD_TAU_S if est.circuit == "field" else ARMATURE_TAU_S
    what = "a field winding" if est.circuit == "field" else "an armature"
    span = f"{_si(lo, 's')} - {_si(hi, 's')}"
    margin = 1.0 + 2.0 * (rel if math.isfinite(rel) else 0.0)
    if tau / margin > hi:
        return Finding(
            "warning", "time_constant",
            f"{est.circuit} time constant {_si(tau, 's')} is longer than {what} has "
            f"({span}): is t in milliseconds, or are field and armature channels swapped?",
            "t", {"t": "ms"}, (est.circuit,),
        )  # fmt: skip
    if tau * margin < lo:
        return Finding(
            "warning", "time_constant",
            f"{est.circuit} time constant {_si(tau, 's')} is shorter than {what} has "
            f"({span}): are field and armature channels swapped, or t not in seconds?",
            "t", {}, (est.circuit,),
        )  # fmt: skip
    return None


def white_noise_std(x: np.ndarray) -> float:
    """The std of white noise on a smooth signal: robust spread of its second differences.

    The second difference of white noise has variance ``6 sigma^2``; a signal
    smooth at the sample rate adds little, and the median absolute deviation
    ignores the few steps.
    """
    if x.size < 5:
        return 0.0
    d2 = np.diff(x, 2)
    mad = float(np.median(np.abs(d2 - np.median(d2))))
    return 1.4826 * mad / math.sqrt(6.0)


def check_estimates(
    estimates: Mapping[str, CircuitEstimate],
    identification: Mapping[str, Identification],
    signals: Mapping[str, np.ndarray],
) -> list[Finding]:
    """Findings about the estimates of a recording (warnings only).

    Parameters
    ----------
    estimates : mapping
        Circuit -> its estimate.
    identification : mapping
        Circuit -> :func:`~observer.estimation.identifiability.identify` of it.
    signals : mapping
        The recording's channels (SI units), for the fit residual's scale.
    """
    out: list[Finding] = []
    current = {"field": "if", "armature": "ia"}
    for circuit, est in estimates.items():
        ident = identification[circuit]
        for finding in (_resistance_finding(est), _tau_finding(est, ident)):
            if finding is not None:
                out.append(finding)
        name = current[circuit]
        if name in signals and est.describes_window:
            x = signals[name]
            rms = float(np.sqrt(np.mean(np.square(x))))
            noise = white_noise_std(x)
            share = est.rms_a / rms if rms > 0 else 0.0
            if share > MAX_RESIDUAL_SHARE and est.rms_a > MAX_RESIDUAL_NOISE * noise:
                times = f"{est.rms_a / noise:.3g} times its noise" if noise > 0 else "no noise"
                out.append(
                    Finding(
                        "warning",
                        "fit",
                        f"the {circuit} model leaves {100 * share:.0f} % of {name}'s rms "
                        f"unexplained ({times}): channels swapped, inverted or mis-scaled, "
                        "or a signal the model does not describe (dcobserver diagnose tells)?",
                        name,
                        {},
                        (circuit,),
                    )  # fmt: skip
                )
    field_est, arm = estimates.get("field"), estimates.get("armature")
    if (
        field_est is not None
        and arm is not None
        and arm.emf_constant_h
        and identification["field"].identified.get("L")
        and identification["armature"].identified.get("K")
    ):
        ratio = field_est.inductance_h / abs(arm.emf_constant_h)
        lo, hi = LF_OVER_K
        if not lo <= ratio <= hi:
            out.append(
                Finding(
                    "warning",
                    "lf_over_k",
                    f"Lf is {ratio:.3g} times K (a field has more turns than the armature: "
                    f"{lo:g}-{hi:g}); is if, va or omega in other units?",
                )  # fmt: skip
            )
    return out
