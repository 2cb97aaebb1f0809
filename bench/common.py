"""Data and helpers shared by the benchmark scripts.

Every benchmark works on the same kind of data: a window of a simulated P-12
recording (the paper's motor) that contains a field-voltage step, so that both
windings are excited in the one window (the duty cycle's "lower" phase weakens
the field while the drive reverses and accelerates the hoist).
"""

from __future__ import annotations

import os
import platform
import subprocess
from dataclasses import dataclass

import numpy as np

from observer.estimation.motor import P12, MotorParameters
from observer.recording import quantise
from observer.simulation.simulate import NoiseLevels, simulate

#: The paper's table: "given" values and the estimates per column
#: (option A: 100 particles, 100/500/1000 iterations; option B: 500 iterations,
#: 50/100/200 particles).
PAPER_GIVEN = {"Rf": 185.0, "Lf": 50.0, "Ra": 3.5, "La": 0.02}
PAPER_COLUMNS = (("A", 100, 100), ("A", 100, 500), ("A", 100, 1000), ("B", 50, 500),
                 ("B", 100, 500), ("B", 200, 500))  # fmt: skip
PAPER_ESTIMATES = {
    "Rf": (332.0, 185.0, 185.0, 332.0, 185.0, 185.0),
    "Lf": (2.0, 50.1, 50.1, 2.0, 50.1, 50.1),
    "Ra": (3.32, 3.49, 3.49, 3.32, 3.346, 3.491),
    "La": (0.086, 0.021, 0.021, 0.086, 0.016, 0.021),
}

#: Sample rate (Hz) and window length (samples) of every benchmark unless stated.
SAMPLE_RATE_HZ = 2000.0
WINDOW_SAMPLES = 2000
#: The first field step (start of "lower") comes at most this long into a
#: recording: 7 s of duty cycle, each phase up to 25 % longer.
LATEST_FIRST_STEP_S = 8.75


@dataclass(frozen=True)
class Window:
    """One estimation window of a simulated recording (SI units)."""

    va: np.ndarray
    ia: np.ndarray
    vf: np.ndarray
    i_f: np.ndarray
    omega: np.ndarray
    dt: float
    start: int
    motor: MotorParameters
    seed: int

    @property
    def truth(self) -> dict[str, float]:
        """True ``Rf, Lf, Ra, La, K``."""
        m = self.motor
        return {
            "Rf": m.field_resistance_ohm,
            "Lf": m.field_inductance_h,
            "Ra": m.armature_resistance_ohm,
            "La": m.armature_inductance_h,
            "K": m.emf_constant_h,
        }


def field_step_index(vf: np.ndarray, fraction: float = 0.1, block: int = 20) -> int:
    """Index of the first field-voltage step larger than ``fraction`` of the median voltage.

    Steps are found as the difference between the means of the ``block``
    samples after and before each index, so sensor noise (even 2 % of rated)
    does not pass for a step; the index is where that difference peaks.
    """
    if vf.size < 2 * block + 1:
        raise ValueError("the recording is too short to find a field-voltage step")
    csum = np.concatenate([[0.0], np.cumsum(vf)])
    k = np.arange(block, vf.size - block + 1)
    jump = np.abs((csum[k + block] - csum[k]) - (csum[k] - csum[k - block])) / block
    threshold = fraction * float(np.median(np.abs(vf)))
    hits = np.nonzero(jump > threshold)[0]
    if hits.size == 0:
        raise ValueError("the recording has no field-voltage step")
    first = int(hits[0])
    return int(k[first + int(np.argmax(jump[first : first + 2 * block]))])


def p12_window(
    seed: int,
    *,
    noise: NoiseLevels | float = 0.002,
    n_samples: int = WINDOW_SAMPLES,
    sample_rate_hz: float = SAMPLE_RATE_HZ,
    motor: MotorParameters = P12,
    adc_bits: int | None = None,
) -> Window:
    """A ``n_samples`` window of a simulated recording, a quarter of it before a field step.

    With ``adc_bits``, the recording as a drive's ADC of that resolution measures
    it (full scale :func:`adc_full_scale`), after the sensors' ``noise``.
    """
    duration = LATEST_FIRST_STEP_S + n_samples / sample_rate_hz + 0.5
    rec = simulate(
        motor, duration_s=duration, sample_rate_hz=sample_rate_hz, noise=noise, seed=seed
    )
    if adc_bits is not None:
        rec = quantise(rec, adc_full_scale(motor), bits=adc_bits)
    step = field_step_index(rec["vf"])
    start = max(0, step - n_samples // 4)
    stop = start + n_samples
    if stop > rec.t.size:
        raise ValueError(f"window [{start}, {stop}) runs past the recording ({rec.t.size})")
    sl = slice(start, stop)

    def cut(name: str) -> np.ndarray:
        return np.ascontiguousarray(rec[name][sl], dtype=np.float64)

    return Window(
        va=cut("va"), ia=cut("ia"), vf=cut("vf"), i_f=cut("if"), omega=cut("omega"),
        dt=rec.dt, start=start, motor=motor, seed=seed,
    )  # fmt: skip


def current_noise_only(motor: MotorParameters, fraction: float) -> NoiseLevels:
    """Noise on the two current channels only (voltages and speed exact)."""
    full = NoiseLevels.relative(motor, fraction)
    return NoiseLevels(ia=full.ia, i_f=full.i_f)


def machine_description() -> str:
    """CPU model and clock (from ``lscpu``), core count and Python/numpy versions."""
    model = platform.processor() or "unknown CPU"
    mhz = ""
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
        for line in out.splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "Model name":
                model = value.strip()
            elif key.strip() in ("CPU MHz", "CPU max MHz") and not mhz:
                mhz = f"{float(value.strip()):.0f} MHz"
    except (OSError, subprocess.CalledProcessError, ValueError):
        pass
    if not mhz:
        try:
            with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
                for line in f:
                    if line.startswith("cpu MHz"):
                        mhz = f"{float(line.split(':')[1]):.0f} MHz"
                        break
        except (OSError, ValueError):
            pass
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    import numba

    return (
        f"{model}, {mhz or 'clock unknown'}, {os.cpu_count()} logical CPUs "
        f"(load average {load} at the start); Python {platform.python_version()}, "
        f"numpy {np.__version__}, numba {numba.__version__}"
    )


def relative_error(estimate: float, truth: float) -> float:
    return (estimate - truth) / truth


def adc_full_scale(motor: MotorParameters, factor: float = 2.5) -> dict[str, float]:
    """Full-scale magnitudes of a drive's ADC channels: ``factor`` x the motor's rated values.

    A drive measures to a few times rated (overloads, transients); 2.5x keeps a
    simulated duty cycle's current peaks (up to 2x rated) inside the range.
    Used with :func:`observer.recording.quantise` to make 12-bit recordings.
    """
    return {
        "va": factor * motor.rated_armature_voltage_v,
        "ia": factor * motor.rated_armature_current_a,
        "vf": factor * motor.rated_field_voltage_v,
        "if": factor * motor.rated_field_current_a,
        "omega": factor * motor.rated_speed_rad_s,
    }
