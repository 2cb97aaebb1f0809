"""An endless, continuous stream of simulated drive samples, generated in chunks.

The fake drives (``dcobserver fake-drive``) need samples forever, in real
time. :class:`DriveStream` runs :func:`observer.simulation.kernels.simulate_drive` one
duty cycle (``chunk_s``) at a time and carries the plant state (field current,
armature current, speed) from one chunk to the next, so the motor's
trajectory is continuous: only the drive's controller integrators restart at
a chunk boundary, which changes the *applied* voltage (an input the estimator
measures) and never breaks the winding equations.

The stream starts with the field de-energised, as a drive does at power-up:
the first second carries a field-current rise with the field time constant,
the excitation field estimation needs.

With a ``drive`` (converters and measurement chain, :mod:`observer.simulation.converter`) the
chunks come from :class:`observer.simulation.converter_drive.ConverterDrive`, which carries its
whole state from chunk to chunk: controller integrators, converter modes, pending firings and
PWM edges, filter states and sample counters. That stream has no seam at all: its samples are
those one long simulation would give for the same references.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from observer.estimation.motor import P12, MotorParameters
from observer.simulation import kernels
from observer.simulation.simulate import (
    NoiseLevels,
    controller_gains,
    duty_cycle_profiles,
    noise_fractions,
    plant_array,
    substeps,
)

if TYPE_CHECKING:
    from observer.simulation.converter import DriveSpec

#: Column order of :meth:`DriveStream.take`.
STREAM_CHANNELS: tuple[str, ...] = ("va", "ia", "vf", "if", "omega")


class DriveStream:
    """Samples of a simulated drive, ``take(n)`` at a time, without end.

    Parameters
    ----------
    motor : MotorParameters
        The simulated motor (default the P-12).
    sample_rate_hz : float
        Sample rate (Hz); the drive's controllers run at this rate.
    noise : float or NoiseLevels
        Sensor noise (fraction of rated values, or per-channel levels).
    seed : int
        Seed of duty cycles and noise.
    chunk_s : float
        Simulated seconds generated per kernel call.
    drive : DriveSpec, optional
        Converters and measurement chain; ``None``: the ideal drive (voltages held per sample).
    """

    def __init__(
        self,
        motor: MotorParameters = P12,
        *,
        sample_rate_hz: float = 2000.0,
        noise: float | NoiseLevels = 0.002,
        seed: int = 0,
        chunk_s: float = 10.0,
        drive: DriveSpec | None = None,
    ) -> None:
        if not sample_rate_hz > 0:
            raise ValueError(f"sample_rate_hz must be > 0, got {sample_rate_hz}")
        self.motor = motor
        self.sample_rate_hz = float(sample_rate_hz)
        self.dt = 1.0 / self.sample_rate_hz
        self.levels = (
            noise if isinstance(noise, NoiseLevels) else NoiseLevels.relative(motor, noise)
        )
        self.chunk_n = max(2, int(round(chunk_s * sample_rate_hz)))
        self._rng = np.random.default_rng(seed)
        self._n_sub = substeps(motor, self.dt)
        self._motor_array = plant_array(motor)
        self._gains = controller_gains(motor, self.dt)
        self._state = np.zeros(3)  # if, ia, omega: at rest, field off
        self._pending = np.empty((0, 5))
        #: Index of the next sample :meth:`take` returns.
        self.index = 0
        self.drive = drive
        self._converter = None
        if drive is not None:
            from observer.simulation.converter_drive import ConverterDrive

            self._converter = ConverterDrive(
                motor, drive, sample_rate_hz=self.sample_rate_hz,
                noise=noise_fractions(motor, self.levels), rng=self._rng,
            )  # fmt: skip

    def _chunk(self) -> np.ndarray:
        n = self.chunk_n
        if self._converter is not None:
            speed, load, field = duty_cycle_profiles(self.motor, n, self.dt, self._rng)
            recorded, _, _ = self._converter.advance(speed, load, field)
            return recorded
        # One sample more than returned: its true state (if, ia, omega at the
        # instant after the chunk) is exactly where the next chunk starts.
        speed, load, field = duty_cycle_profiles(self.motor, n + 1, self.dt, self._rng)
        noise = self._rng.standard_normal((n + 1, 5)) * self.levels.as_array()
        true, measured = kernels.simulate_drive(
            self.dt, self._n_sub, self._motor_array, self._gains,
            speed, load, field, noise, self._state,
        )  # fmt: skip
        self._state = np.array([true[n, 3], true[n, 1], true[n, 4]])
        return measured[:n]

    def prefetch(self) -> None:
        """Generate the next chunk now (and compile the kernel), so :meth:`take` is fast."""
        if self._pending.shape[0] == 0:
            self._pending = self._chunk()

    def take(self, n: int) -> np.ndarray:
        """The next ``n`` samples, an ``(n, 5)`` array of ``va, ia, vf, if, omega`` (SI)."""
        while self._pending.shape[0] < n:
            self._pending = np.concatenate([self._pending, self._chunk()])
        out, self._pending = self._pending[:n], self._pending[n:]
        self.index += n
        return out
