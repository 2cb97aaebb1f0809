"""The armature's estimator: ``(Ra, La, K)`` from ``va, ia`` and the measured ``if, omega``.

The voltage's intersample model is chosen from the data
(:func:`observer.estimation.intersample.choose_model`); the EMF regressor
``if*omega`` is smooth and reconstructed by a cubic on the same segments, its speed
first fitted by the shaft's equation (:func:`observer.estimation.mechanics.smooth_speed`:
a tachometer's noise, which the drive's speed loop answers, is no regressor).
Then the stages of :mod:`observer.estimation.stages` run: the swarm over
``log10 (Ra, La)`` with ``K`` and the initial currents solved in closed form,
Levenberg-Marquardt polish, errors-in-variables compensation, and the
uncertainty.
"""

from __future__ import annotations

import math

import numpy as np

from observer.estimation import dealias
from observer.estimation.frontend import FrontEnd, voltage_filtered
from observer.estimation.intersample import choose_model
from observer.estimation.lines import aliased_lines, notch, settle_samples
from observer.estimation.mechanics import smooth_speed
from observer.estimation.problem import WindingProblem, coverage_note, make_problem, pwm_note
from observer.estimation.ranges import (
    SearchRange,
    armature_search_range,
    check_signals,
    kernel_array,
)
from observer.estimation.result import CircuitEstimate
from observer.estimation.stages import (
    EivCorrection,
    SwarmSettings,
    corrected_point,
    eiv_stage,
    guard_stage,
    jump_stage,
    offset_stage,
    operating_point_part,
    operating_point_stage,
    search_and_polish,
    specification_stage,
    std_stage,
)

#: This winding's filtered jumps are put back between its samples (:mod:`.dealias`).
DEALIASED = "armature" in dealias.WINDINGS


def armature_problem(
    va: np.ndarray,
    ia: np.ndarray,
    i_f: np.ndarray,
    omega: np.ndarray,
    dt: float,
    *,
    emf_constant: float | None = None,
    intersample: str = "auto",
    fit_shift: bool = True,
    shift: float = 0.0,
    fit_lag: bool = False,
    lag: float = 0.0,
    front_ends: tuple[FrontEnd, FrontEnd] | None = None,
    mismatch: float | None = None,
    fit_speed: bool = True,
    voltage_alias: float | None = None,
    identified_filter: str | None = None,
) -> WindingProblem:
    """The armature's :class:`~observer.estimation.problem.WindingProblem` over a window
    (``fit_speed``: the EMF's speed from the shaft's equation, else the samples as measured)."""
    va = kernel_array(va)
    ia = kernel_array(ia)
    i_f = kernel_array(i_f)
    omega = kernel_array(omega)
    check_signals(va=va, ia=ia, i_f=i_f, omega=omega)
    model, switching = choose_model(va, intersample, dt, filtered=voltage_filtered(front_ends))
    # The EMF's speed as the shaft's equation explains it: the tachometer's noise, which the
    # drive's speed loop answers in va and ia, out of the regressor (:mod:`.mechanics`).
    speed = smooth_speed(omega, i_f, ia, dt).omega if fit_speed else omega
    return make_problem(
        va, ia, dt, model, switching=switching, emf=i_f * speed,
        emf_constant=emf_constant, fit_shift=fit_shift, shift=shift,
        fit_lag=fit_lag and model == "smooth", lag=lag if model == "smooth" else 0.0,
        also_checked=(i_f, omega), front_ends=front_ends, mismatch=mismatch,
        voltage_alias=voltage_alias, reconstruct_jumps=DEALIASED,
        identified_filter=identified_filter,
    )  # fmt: skip


def aliased_bands(
    problem: WindingProblem, va: np.ndarray, ia: np.ndarray, resistance: float, inductance: float
) -> list[tuple[float, float]]:
    """The bands (Hz) of ``va``'s lines that ``ia`` does not answer as the winding at
    ``(resistance, inductance)`` would (:func:`~observer.estimation.lines.aliased_lines`),
    where the armature's voltage is read as ``smooth`` and shows no jumps (a chopper's
    pulses); none elsewhere (a bridge's ripple below Nyquist is the winding's own)."""
    if problem.inp.model != "smooth" or any(problem.alias_v):
        return []
    return aliased_lines(
        kernel_array(va), kernel_array(ia), problem.dt,
        lambda f: complex(resistance, 2.0 * math.pi * f * inductance),
    )  # fmt: skip


def estimate_armature(
    va: np.ndarray,
    ia: np.ndarray,
    i_f: np.ndarray,
    omega: np.ndarray,
    dt: float,
    *,
    emf_constant: float | None = None,
    search_range: SearchRange | None = None,
    n_particles: int = 100,
    max_iterations: int = 100,
    schedule: str | tuple[float, float] = "s-k",
    w: float = 0.7,
    rng: int | np.random.Generator | None = None,
    x0: tuple[float, float] | None = None,
    init_range: SearchRange | None = None,
    explore_fraction: float = 0.0,
    tol: float = 0.0,
    polish: bool = True,
    compensate_input_noise: bool = True,
    intersample: str = "auto",
    fit_shift: bool = True,
    shift: float = 0.0,
    fit_lag: bool = False,
    lag: float = 0.0,
    front_ends: tuple[FrontEnd, FrontEnd] | None = None,
    settled_rms: float | None = None,
    mismatch: float | None = None,
    fit_speed: bool = True,
    voltage_alias: float | None = None,
    identified_filter: str | None = None,
    notch_aliased: bool = True,
    split_by_voltage: bool = False,
) -> CircuitEstimate:
    """Estimate ``(Ra, La, K)`` of the armature from ``va, ia`` and measured ``if, omega``.

    Parameters
    ----------
    va, ia, i_f, omega : (n,) arrays
        Armature voltage (V), armature current (A), field current (A) and speed (rad/s).
    dt : float
        Sample period (s).
    emf_constant : float, optional
        Hold ``K`` at this value instead of fitting it (a window without speed).
    compensate_input_noise : bool
        Remove the errors-in-variables bias of output error (see
        :func:`observer.estimation.stages.eiv_stage`).
    intersample, fit_shift, shift
        The voltage's intersample model, whether to fit the relative delay of
        the voltage channel and its value (see :func:`observer.estimation.estimate_field`).
    settled_rms : float, optional
        With ``x0``: polish from ``x0`` without a swarm unless that fit's rms (A)
        exceeds this (see :func:`observer.estimation.estimate_field`).
    mismatch : float, optional
        The untold channels' mismatch learned (see :func:`observer.estimation.estimate_field`).
    fit_speed : bool
        Take the EMF's speed from the shaft's equation fitted to ``omega``
        (:func:`observer.estimation.mechanics.smooth_speed`; the default), or the samples
        as they are (a speed that is already an observer's clean estimate).
    voltage_alias : float, optional
        The untold voltage filter's aliasing factor identified from the converter's jumps
        (see :func:`observer.estimation.estimate_field`).
    identified_filter : str, optional
        The identified filter itself (see :func:`observer.estimation.estimate_field`).
    notch_aliased : bool
        Where the voltage is read as ``smooth`` and shows no jumps (a chopper's pulses),
        estimate again without the lines the current does not answer as the estimated
        winding would (aliases of the pulses, :mod:`observer.estimation.lines`): their
        bands removed from ``va`` and ``ia`` alike.
    split_by_voltage : bool
        Add the model error that depends on the operating point (the fits over the low- and
        high-voltage halves, :func:`~observer.estimation.stages.operating_point_stage`): for
        a whole recording.
    Other parameters
        As for :func:`estimate_field`.
    """
    arguments = dict(
        emf_constant=emf_constant, search_range=search_range, n_particles=n_particles,
        max_iterations=max_iterations, schedule=schedule, w=w, x0=x0, init_range=init_range,
        explore_fraction=explore_fraction, tol=tol, polish=polish,
        compensate_input_noise=compensate_input_noise, intersample=intersample,
        fit_shift=fit_shift, shift=shift, fit_lag=fit_lag, lag=lag, front_ends=front_ends,
        settled_rms=settled_rms, mismatch=mismatch, fit_speed=fit_speed,
        voltage_alias=voltage_alias, identified_filter=identified_filter,
        split_by_voltage=split_by_voltage,
    )  # fmt: skip
    problem = armature_problem(
        va, ia, i_f, omega, dt, emf_constant=emf_constant, intersample=intersample,
        fit_shift=fit_shift, shift=shift, fit_lag=fit_lag, lag=lag, front_ends=front_ends,
        mismatch=mismatch, fit_speed=fit_speed, voltage_alias=voltage_alias,
        identified_filter=identified_filter,
    )  # fmt: skip
    n = problem.current.shape[0]
    rng_ = np.random.default_rng(rng)
    bounds = (
        search_range
        if search_range is not None
        else armature_search_range(
            problem.voltage, problem.current, kernel_array(i_f), kernel_array(omega), dt
        )
    )
    settings = SwarmSettings(
        n_particles, max_iterations, schedule, w, x0, init_range, explore_fraction, tol
    )
    undecided = intersample == "auto" and problem.inp.model == "smooth" and front_ends is None

    def hold() -> WindingProblem:
        return make_problem(
            problem.voltage, problem.current, dt, "hold", switching=problem.inp.switching,
            emf=problem.emf, emf_constant=emf_constant,
            also_checked=(kernel_array(i_f), kernel_array(omega)),
        )  # fmt: skip

    problem, result, fit = search_and_polish(
        problem, bounds, settings, rng_, polish=polish, settled_rms=settled_rms,
        hold=hold if undecided else None,
    )  # fmt: skip
    problem, fit = guard_stage(
        problem, result, fit, bounds,
        lambda s: armature_problem(
            va, ia, i_f, omega, dt, emf_constant=emf_constant, intersample=problem.inp.model,
            fit_shift=fit_shift, shift=s, fit_lag=fit_lag, lag=lag, front_ends=front_ends,
            mismatch=mismatch, fit_speed=fit_speed, voltage_alias=voltage_alias,
            identified_filter=identified_filter,
        ),
        polish=polish,
    )  # fmt: skip
    if compensate_input_noise:
        eiv = eiv_stage(problem, fit.point, bounds, settings, rng_)
    else:
        eiv = EivCorrection(fit.point, 0.0, np.zeros(3))
    spec = specification_stage(problem, fit, bounds) if polish else None
    if spec is not None and split_by_voltage:
        spec = operating_point_stage(problem, fit, bounds, spec)
    jump = jump_stage(problem, fit) if polish else None
    offset = offset_stage(problem, fit) if polish else None
    std = std_stage(problem, fit, eiv, spec, jump, offset)
    point = corrected_point(eiv.point, jump)
    if notch_aliased:
        bands = aliased_bands(problem, va, ia, point.resistance_ohm, point.inductance_h)
        edge = settle_samples(bands, dt)
        if bands and n - 2 * edge >= n // 2:
            # Estimated again without them (and the notches' ringing at the ends).
            keep = slice(edge, n - edge)
            return estimate_armature(
                notch(kernel_array(va), dt, bands)[keep], notch(kernel_array(ia), dt, bands)[keep],
                kernel_array(i_f)[keep], kernel_array(omega)[keep], dt, rng=rng,
                notch_aliased=False, **arguments,  # type: ignore[arg-type]
            )  # fmt: skip
    coverage = problem.segments.covered / n
    note = pwm_note(va, "armature") or coverage_note(coverage, "armature")
    return CircuitEstimate(
        circuit="armature",
        resistance_ohm=point.resistance_ohm,
        inductance_h=point.inductance_h,
        emf_constant_h=point.emf_constant_h,
        initial_current_a=point.initial_current_a,
        rms_a=float(np.sqrt(np.mean(point.residual * point.residual))),
        std={"R": std["R"], "L": std["L"], "K": std["K"]},
        n_samples=n,
        search_range=bounds,
        pso=result,
        polished=polish,
        input_noise_var=eiv.input_noise_var,
        intersample=problem.inp.model,
        shift_samples=point.shift,
        shift_std=std.get("shift", 0.0),
        coverage=coverage,
        front_end_std=std.get("front_end_L", 0.0),
        mismatch_size=std.get("mismatch_size", math.nan),
        mismatch_shift=std.get("mismatch_shift", math.nan),
        shared_std={p: std[f"shared_{p}"] for p in ("R", "L", "K") if f"shared_{p}" in std},
        operating_point_std=operating_point_part(spec, ("R", "L", "K")),
        describes_window=not note,
        note=note,
    )
