"""The field winding's estimator: ``(Rf, Lf)`` from ``vf`` and ``if``.

The voltage's intersample model is chosen from the data
(:func:`observer.estimation.intersample.choose_model`), then the stages of
:mod:`observer.estimation.stages` run: swarm over ``log10 (R, L)`` with the
initial currents projected out, Levenberg-Marquardt polish (with the relative
delay of the voltage channel where the model has one), optional
errors-in-variables compensation, and the uncertainty at the optimum.
"""

from __future__ import annotations

import math

import numpy as np

from observer.estimation import dealias
from observer.estimation.frontend import FrontEnd, voltage_filtered
from observer.estimation.intersample import choose_model
from observer.estimation.problem import coverage_note, make_problem, pwm_note
from observer.estimation.ranges import SearchRange, check_signals, field_search_range, kernel_array
from observer.estimation.result import CircuitEstimate
from observer.estimation.stages import (
    EivCorrection,
    SwarmSettings,
    eiv_stage,
    guard_stage,
    operating_point_part,
    operating_point_stage,
    search_and_polish,
    specification_stage,
    std_stage,
)

#: This winding's filtered jumps are put back between its samples (:mod:`.dealias`).
DEALIASED = "field" in dealias.WINDINGS


def estimate_field(
    vf: np.ndarray,
    i_f: np.ndarray,
    dt: float,
    *,
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
    intersample: str = "auto",
    fit_shift: bool = True,
    shift: float = 0.0,
    compensate_input_noise: bool = False,
    front_ends: tuple[FrontEnd, FrontEnd] | None = None,
    settled_rms: float | None = None,
    mismatch: float | None = None,
    voltage_alias: float | None = None,
    identified_filter: str | None = None,
    split_by_voltage: bool = False,
) -> CircuitEstimate:
    """Estimate ``(Rf, Lf)`` of the field winding from ``vf`` (V) and ``if`` (A).

    Parameters
    ----------
    vf, i_f : (n,) arrays
        Field voltage and field current samples.
    dt : float
        Sample period (s).
    search_range : SearchRange, optional
        Defaults to :func:`field_search_range` of the data.
    n_particles, max_iterations, schedule, w, rng, tol
        Swarm settings, see :class:`observer.estimation.pso.ParticleSwarm`.
    x0, init_range, explore_fraction
        Warm start: previous ``(R, L)``, the shrunken range to initialise most
        particles in, and the fraction that still explores all of ``search_range``.
    polish : bool
        Refine the swarm's best by Levenberg-Marquardt (default). Off, the
        estimate is the swarm's alone, as in the paper.
    intersample : {"auto", "hold", "smooth", "switched"}
        The voltage between samples (see :mod:`observer.estimation.intersample`);
        ``auto`` decides from the data.
    fit_shift : bool
        Fit the relative delay of the voltage channel behind the current channel.
    shift : float
        That delay (sample periods): the start of the fit, or its value when
        not fitted (a chain calibrated beforehand).
    compensate_input_noise : bool
        Remove the errors-in-variables bias of noise on ``vf``.
    settled_rms : float, optional
        With ``x0``: polish from ``x0`` without a swarm, and run the swarm only
        if that fit's rms (A) exceeds this
        (:func:`~observer.estimation.stages.settled_stage`).
    mismatch : float, optional
        Front ends not told: the size of the commonest mismatch of the channels learned
        (a whole recording's or the first windows' ``mismatch_size``); a filtered voltage
        is corrected by it (:func:`~observer.estimation.frontend.applied_mismatch`).
    voltage_alias : float, optional
        Front ends not told: the voltage filter's aliasing factor identified from the
        converter's jumps (:func:`~observer.estimation.filter_id.identify_voltage_filter`);
        None: the weakest filter in use is assumed.
    identified_filter : str, optional
        Front ends not told: the identified filter itself
        (:attr:`~observer.estimation.filter_id.FilterFit.best`), through which the voltage's
        jumps are put back between its samples (:mod:`~observer.estimation.dealias`; a
        configured filter is used so without it).
    split_by_voltage : bool
        Add the model error that depends on the operating point (the fits over the low- and
        high-voltage halves, :func:`~observer.estimation.stages.operating_point_stage`): for
        a whole recording.
    """
    vf = kernel_array(vf)
    i_f = kernel_array(i_f)
    n = check_signals(vf=vf, i_f=i_f)
    rng_ = np.random.default_rng(rng)
    bounds = search_range if search_range is not None else field_search_range(vf, i_f, dt)
    model, switching = choose_model(vf, intersample, dt, filtered=voltage_filtered(front_ends))
    problem = make_problem(
        vf, i_f, dt, model, switching=switching, fit_shift=fit_shift, shift=shift,
        front_ends=front_ends, mismatch=mismatch, voltage_alias=voltage_alias,
        reconstruct_jumps=DEALIASED, identified_filter=identified_filter,
    )  # fmt: skip
    settings = SwarmSettings(
        n_particles, max_iterations, schedule, w, x0, init_range, explore_fraction, tol
    )
    undecided = intersample == "auto" and problem.inp.model == "smooth" and front_ends is None
    problem, result, fit = search_and_polish(
        problem, bounds, settings, rng_, polish=polish, settled_rms=settled_rms,
        hold=(lambda: make_problem(vf, i_f, dt, "hold", switching=switching))
        if undecided else None,
    )  # fmt: skip
    problem, fit = guard_stage(
        problem, result, fit, bounds,
        lambda s: make_problem(
            vf, i_f, dt, model, switching=switching, fit_shift=fit_shift, shift=s,
            front_ends=front_ends, mismatch=mismatch, voltage_alias=voltage_alias,
            reconstruct_jumps=DEALIASED, identified_filter=identified_filter,
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
    std = std_stage(problem, fit, eiv, spec)
    point = eiv.point
    coverage = problem.segments.covered / n
    note = pwm_note(vf, "field") or coverage_note(coverage, "field")
    return CircuitEstimate(
        circuit="field",
        resistance_ohm=point.resistance_ohm,
        inductance_h=point.inductance_h,
        emf_constant_h=None,
        initial_current_a=point.initial_current_a,
        rms_a=float(np.sqrt(np.mean(point.residual * point.residual))),
        std={"R": std["R"], "L": std["L"]},
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
        shared_std={p: std[f"shared_{p}"] for p in ("R", "L") if f"shared_{p}" in std},
        operating_point_std=operating_point_part(spec, ("R", "L")),
        describes_window=not note,
        note=note,
    )
