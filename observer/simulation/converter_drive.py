"""A converter-fed drive with its measurement chain, simulated chunk by chunk without seams.

:class:`ConverterDrive` owns the kernel state of :mod:`observer.simulation.converter_kernels`
(motor, converters, controllers, pending events, filters, sample counters) and advances it one
chunk of sample periods at a time: the samples of many chunks are exactly those of one long
chunk. :func:`simulate_converter` makes a whole recording (what
:func:`observer.simulation.simulate.simulate` calls when given a drive);
:class:`observer.simulation.drive_stream.DriveStream` uses the same object for the fake drives.

The drive's own controller measures ``ia, if, omega`` with the recording's noise level (a
counter-based generator, so chunking does not change it); the recorded values pass through the
chain of :mod:`observer.simulation.chain`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from observer.estimation.motor import MotorParameters
from observer.recording import Recording
from observer.simulation import converter_kernels as ck
from observer.simulation.chain import CHANNELS, ResolvedChannel, resolve_chain
from observer.simulation.converter import DriveSpec, size_converter

if TYPE_CHECKING:
    from observer.simulation.effects_sim import Change

#: Longest integration step (s): 200 kHz, far finer than any sample rate in use.
MAX_STEP_S = 5e-6


@dataclass(frozen=True)
class DriveTruth:
    """Noise-free truth per sample ``k`` of a converter-fed recording (SI units).

    Attributes
    ----------
    va_mean, vf_mean : arrays
        Mean terminal voltages over ``[kT, (k+1)T)``.
    va_moments, vf_moments : (n, 2) arrays
        Means of ``v*u`` and ``v*u^2`` over the period, ``u = (t - kT)/T``: with ``va_mean`` the
        first three moments of the intersample waveform.
    ia, i_f, omega, theta, angle : arrays
        Currents, speed, winding temperature rise (fraction) and shaft angle (rad) at ``kT``.
    va, vf : arrays
        Terminal voltages at ``kT`` (before that instant's events).
    emf : array
        Back-EMF at ``kT``.
    bridge, conducting : arrays
        Active armature bridge (+1/-1) and whether it conducts (1/0) at ``kT``; for the chopper
        and the ideal converter ``conducting`` is always 1.
    """

    va_mean: np.ndarray
    vf_mean: np.ndarray
    va_moments: np.ndarray
    vf_moments: np.ndarray
    ia: np.ndarray
    i_f: np.ndarray
    omega: np.ndarray
    theta: np.ndarray
    angle: np.ndarray
    va: np.ndarray
    vf: np.ndarray
    emf: np.ndarray
    bridge: np.ndarray
    conducting: np.ndarray

    @classmethod
    def from_array(cls, a: np.ndarray) -> DriveTruth:
        m = ck.T_MOMENTS
        return cls(
            va_mean=a[:, ck.T_VA_MEAN], vf_mean=a[:, ck.T_VF_MEAN],
            va_moments=a[:, m : m + 2], vf_moments=a[:, m + 2 : m + 4],
            ia=a[:, ck.T_IA], i_f=a[:, ck.T_IF], omega=a[:, ck.T_OMEGA],
            theta=a[:, ck.T_THETA], angle=a[:, ck.T_ANGLE], va=a[:, ck.T_VA], vf=a[:, ck.T_VF],
            emf=a[:, ck.T_EMF], bridge=a[:, ck.T_BRIDGE], conducting=a[:, ck.T_CONDUCTING],
        )  # fmt: skip


class ConverterDrive:
    """The kernel state of one converter-fed drive, advanced chunk by chunk.

    Parameters
    ----------
    motor : MotorParameters
        The motor.
    drive : DriveSpec
        Converters and measurement chain.
    sample_rate_hz : float
        Sample rate (Hz).
    noise : float or mapping of channel name to float
        Noise fraction of rated values, for the channels whose chain leaves it unset and for
        the drive's own sensors (``ia, if, omega``).
    rng : numpy.random.Generator
        Mains and carrier phases, the drive sensors' seed and the recorded noise.
    effects : mapping of str to float, optional
        Effects of :mod:`observer.simulation.effects_sim` by name with magnitude.
    initial : (float, float, float)
        ``if, ia, omega`` at t = 0.
    thermal_time_constant_s : float, optional
        The windings' thermal time constant of ``thermal_drift`` (default: the simulator's).

    Raises
    ------
    ValueError
        A chain that cannot work at this rate (naming the key), a bad effect.
    """

    def __init__(
        self,
        motor: MotorParameters,
        drive: DriveSpec,
        *,
        sample_rate_hz: float,
        noise: float | Mapping[str, float],
        rng: np.random.Generator,
        effects: Mapping[str, float] | None = None,
        initial: tuple[float, float, float] = (0.0, 0.0, 0.0),
        thermal_time_constant_s: float | None = None,
    ) -> None:
        from observer.simulation import effects_sim
        from observer.simulation.simulate import plant_array

        if not sample_rate_hz > 0:
            raise ValueError(f"sample_rate_hz must be > 0, got {sample_rate_hz}")
        self.motor = motor
        self.drive = drive
        self.sample_rate_hz = float(sample_rate_hz)
        self.dt = 1.0 / self.sample_rate_hz
        fractions = noise if isinstance(noise, Mapping) else dict.fromkeys(CHANNELS, noise)
        for name in CHANNELS:
            if not fractions[name] >= 0:
                raise ValueError(f"noise must be >= 0, got {fractions[name]}")
        self._rng = rng
        self.setup = size_converter(drive.converter, motor, self.sample_rate_hz, rng)
        self.channels: tuple[ResolvedChannel, ...] = resolve_chain(
            drive.chain, self.sample_rate_hz, full_scale=self.setup.full_scale,
            rated=self.setup.rated, noise=fractions,
        )  # fmt: skip
        effects = dict(effects or {})
        kw = (
            {}
            if thermal_time_constant_s is None
            else {"thermal_time_constant_s": thermal_time_constant_s}
        )
        fx = effects_sim.plant_effects(motor, effects, self.dt, **kw)
        self.plant_effects = fx
        self.effects_metadata = effects_sim.effects_metadata(effects, fx) if effects else None
        self._fx = np.concatenate(
            [fx.plant_array(), effects_sim.outside_library_array(motor, effects), [1.0]]
        )
        self._offsets = np.array([ch.offset for ch in self.channels])
        self._offsets[1] += fx.ia_offset_a
        self._offsets[3] += fx.if_offset_a
        self._delays = np.array([ch.delay_s for ch in self.channels])
        if fx.current_delay_s:
            # Currents read behind the voltages (i(t_k - delay)): the voltages sampled that
            # much after them, as the ideal drive's sampling_skew relates the two.
            for c in (0, 2):
                self._delays[c] += fx.current_delay_s
                if self._delays[c] >= self.dt:
                    raise ValueError(
                        f"sampling_skew: with a converter the {CHANNELS[c]} channel's delay "
                        f"({self._delays[c]:g} s) must stay below one sample period ({self.dt:g} s)"
                    )
        self._filt = np.stack([ch.sections() for ch in self.channels])
        self._averaging = np.array([1.0 if ch.averaging else 0.0 for ch in self.channels])
        self.h_max = min(MAX_STEP_S, self.dt / 4)
        w0_max = float(self._filt[:, :, 1].max())
        if w0_max > 0:
            # RK4 on a filter section: h*w0 <= 1/4 keeps its error near 1e-5
            self.h_max = min(self.h_max, 1.0 / (4 * w0_max))
        rated = self.setup.rated
        self._drive_noise = np.array(
            [fractions["ia"] * rated["ia"], fractions["if"] * rated["if"],
             fractions["omega"] * rated["omega"]]
        )  # fmt: skip
        self._seed = int(rng.integers(0, 2**62))
        self._motor = plant_array(motor)
        self.state = ck.initial_state(
            self._motor, self._fx, self.setup.arm, self.setup.fld, self._filt, self.dt,
            float(initial[0]), float(initial[1]), float(initial[2]),
        )  # fmt: skip
        # the gain and offset the recorded values carry, effects included
        self._resolved_measure = tuple(
            ch if ch.offset == off else _with_offset(ch, off)
            for ch, off in zip(self.channels, self._offsets, strict=True)
        )

    @property
    def index(self) -> int:
        """Absolute index of the next sample :meth:`advance` returns."""
        return int(self.state[ck.C_K])

    def advance(
        self,
        speed_ref: np.ndarray,
        torque_load: np.ndarray,
        field_ref: np.ndarray,
        *,
        schedule: np.ndarray | None = None,
        want_truth: bool = False,
    ) -> tuple[np.ndarray, np.ndarray, DriveTruth | None]:
        """Simulate ``len(speed_ref)`` more sample periods.

        Parameters
        ----------
        speed_ref, torque_load, field_ref : (n,) arrays
            Speed reference (rad/s), load torque (N*m), field voltage reference (V) per period.
        schedule : (n, 6) array, optional
            Multipliers of ``Rf, Lf, Ra, La, K`` and the tachometer's gain per period
            (:func:`observer.simulation.effects_sim.change_schedule`).
        want_truth : bool
            Also return the noise-free :class:`DriveTruth`.

        Returns
        -------
        recorded : (n, 5) array
            ``va, ia, vf, if, omega`` as recorded (after the whole chain).
        analog : (n, 5) array
            The same after the analog filters and sampling, before gain, noise and ADC.
        truth : DriveTruth or None
        """
        n = int(np.asarray(speed_ref).shape[0])
        steps = np.zeros((0, 6)) if schedule is None else np.ascontiguousarray(schedule, float)
        if steps.shape[0] not in (0, n):
            raise ValueError(f"schedule has {steps.shape[0]} rows for {n} periods")
        analog, truth = ck.advance(
            self.state, n, self.h_max, self._motor, self._fx, self.setup.arm, self.setup.fld,
            self.setup.ctrl, self._filt, self._delays, self._averaging, self._drive_noise,
            self._seed, np.ascontiguousarray(speed_ref, dtype=float),
            np.ascontiguousarray(torque_load, dtype=float),
            np.ascontiguousarray(field_ref, dtype=float), steps, want_truth,
        )  # fmt: skip
        recorded = np.empty_like(analog)
        for c, ch in enumerate(self._resolved_measure):
            recorded[:, c] = ch.measure(analog[:, c], self._rng)
        return recorded, analog, DriveTruth.from_array(truth) if want_truth else None

    def metadata(self) -> dict[str, Any]:
        """What a recording says about this drive: converter, chain per channel, ADC scales."""
        chain = {}
        adc = {}
        for name, ch, delay in zip(CHANNELS, self.channels, self._delays, strict=True):
            chain[name] = ch.to_dict() | {"delay_s": float(delay)}
            scale = ch.adc_metadata()
            if scale is not None:
                adc[name] = scale
        out: dict[str, Any] = {
            "converter": self.setup.metadata,
            "chain": chain,
            "adc": adc,
            "noise": {name: ch.noise_std for name, ch in zip(CHANNELS, self.channels,
                                                              strict=True)},
            "integration": {"method": "RK4 with exact converter, controller and sampling "
                            "events", "max_step_s": self.h_max},
        }  # fmt: skip
        if self.effects_metadata is not None:
            out["effects"] = self.effects_metadata
        return out


def _with_offset(ch: ResolvedChannel, offset: float) -> ResolvedChannel:
    return dataclasses.replace(ch, offset=float(offset))


def simulate_converter(
    motor: MotorParameters,
    drive: DriveSpec,
    *,
    duration_s: float,
    sample_rate_hz: float,
    noise: float | Mapping[str, float],
    seed: int | None,
    effects: Mapping[str, float] | None = None,
    changes: Sequence[Change] = (),
    thermal_time_constant_s: float | None = None,
    want_truth: bool = False,
    drive_name: str | None = None,
) -> tuple[Recording, DriveTruth | None]:
    """A recording of ``motor`` fed by ``drive`` in rope-shovel-like operation.

    The duty cycle is drawn first from ``numpy.random.default_rng(seed)``, exactly as for the
    ideal drive, so the same seed gives the same duty cycle whatever the drive. Arguments as
    :func:`observer.simulation.simulate.simulate`; ``drive_name`` is recorded as the preset.

    Returns
    -------
    recording : Recording
        Metadata: the true motor, the converter, the chain per channel, ``adc`` scales
        (value = offset + lsb * count exactly), noise, seed and sample rate.
    truth : DriveTruth or None
        With ``want_truth``.
    """
    from observer.simulation.effects_sim import change_schedule
    from observer.simulation.simulate import duty_cycle_profiles, thermal_truth

    if not duration_s > 0:
        raise ValueError(f"duration_s must be > 0, got {duration_s}")
    if not sample_rate_hz > 0:
        raise ValueError(f"sample_rate_hz must be > 0, got {sample_rate_hz}")
    n = int(round(duration_s * sample_rate_hz))
    if n < 2:
        raise ValueError(f"a recording needs at least 2 samples, got {n}")
    dt = 1.0 / sample_rate_hz
    rng = np.random.default_rng(seed)
    speed, load, field = duty_cycle_profiles(motor, n, dt, rng)
    # start at rest with the field established, as a drive does after pre-excitation
    sim = ConverterDrive(
        motor, drive, sample_rate_hz=sample_rate_hz, noise=noise, rng=rng, effects=effects,
        initial=(field[0] / motor.field_resistance_ohm, 0.0, 0.0),
        thermal_time_constant_s=thermal_time_constant_s,
    )  # fmt: skip
    heating = sim.plant_effects.thermal_rise_per_w > 0
    schedule = change_schedule(changes, n, dt) if changes else None
    recorded, _, truth = sim.advance(
        speed, load, field, schedule=schedule, want_truth=want_truth or heating
    )
    signals = {name: recorded[:, c].copy() for c, name in enumerate(CHANNELS)}
    metadata: dict[str, Any] = {
        "generator": "dcobserver simulate",
        "motor": motor.to_dict(),
        "drive": drive_name,
        **sim.metadata(),
        "seed": seed,
        "sample_rate_hz": sample_rate_hz,
    }
    if changes:
        metadata["changes"] = [c.to_dict() for c in changes]
    if heating and truth is not None:
        metadata["thermal"] = thermal_truth(truth.theta, dt)
    if not math.isfinite(float(np.abs(recorded).max())):
        raise ValueError("the simulation diverged (non-finite samples)")  # pragma: no cover
    rec = Recording(t=np.arange(n) * dt, signals=signals, metadata=metadata)
    return rec, truth if want_truth else None
