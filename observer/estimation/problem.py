"""One winding's output-error problem over a window: what the swarm and the polish minimise.

A :class:`WindingProblem` holds the measured current, the voltage's
intersample model (:mod:`observer.estimation.intersample`) and, for the
armature, the EMF regressor ``if*omega``. It gives the swarm its cost (eq. (1)
for a whole swarm, :func:`~observer.estimation.intersample_kernels.moment_swarm_costs`)
and the polish its residual, with every segment's initial current solved in
closed form. The nonlinear parameters are ``ln R``, ``ln L``, for the armature
``K`` (unless held), and, where the model has one, the relative delay of the
voltage behind the current (sample periods).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from observer.estimation import intersample_kernels as ik
from observer.estimation.dealias import (
    RESIDUAL_ALIAS,
    JumpReconstruction,
    identified_front_end,
)
from observer.estimation.dealias import reconstruction as reconstruct
from observer.estimation.frontend import (
    UNKNOWN_MISMATCH,
    FrontEnd,
    applied_mismatch,
    apply_relative,
    edge_samples,
    mismatch_response,
    parse_front_end,
    unknown_mismatch,
)
from observer.estimation.intersample import (
    PWM_CHANGES,
    InputModel,
    Segments,
    Switching,
    alias_bias,
    alias_factor,
    averaged_moments,
    build_input,
    find_switching,
    hold_moments,
    jump_runs,
    pwm_level_changes,
    rail_samples,
    settle_current,
    smooth_moments,
    smooth_moments_through,
)
from observer.estimation.pso import CostFunction

#: The relative delay is searched within this many sample periods either way.
SHIFT_LIMIT = 1.5

#: The voltage's relative first-order lag is searched up to this many sample periods.
LAG_LIMIT = 3.0


@dataclass
class WindingProblem:
    """The measured window of one winding and its input model.

    Attributes
    ----------
    voltage, current : (n,) arrays
        Winding voltage samples (V) and current samples (A).
    dt : float
        Sample period (s).
    inp : InputModel
        The voltage's intersample model (moments, segments).
    emf : (n,) array or None
        ``if*omega`` samples (A*rad/s) for the armature; None for the field.
    emf_constant : float or None
        ``K`` held at this value (armature without speed); None: fitted.
    fit_shift : bool
        Whether the relative delay is a parameter (``smooth`` and ``switched`` models).
    alias_v : tuple of float
        Per piece of the window (:data:`ALIAS_PIECES` equal ones), the one-sigma error of the
        piece's mean voltage that jumps seen through the front end leave in the samples (V;
        :func:`~observer.estimation.intersample.alias_bias_bound`). It changes where the
        converter's firing angle does, so each piece errs on its own.
    alias_locked : tuple of bool
        Per piece: its jumps are locked to the samples, so its alias error is a bias every
        window at that firing angle shares (:func:`~observer.estimation.intersample.alias_bias`).
    untold_front_end : bool
        A filtered voltage (``smooth``) whose channels' front ends are not configured:
        their relative response is unknown
        (:func:`~observer.estimation.frontend.unknown_mismatch`). A ``switched`` voltage
        shows clean jumps, so no filter; its current channel is taken alike.
    mismatch_applied : float
        Untold front ends: the size of the commonest mismatch the voltage was corrected by
        (:func:`~observer.estimation.frontend.applied_mismatch` of the size learned).
    jumps : tuple of (starts, sizes) arrays, or None
        A ``smooth`` voltage's jumps (:func:`~observer.estimation.intersample.jump_runs`):
        the first interval of each and its size (V).
    jump_alias : float
        The front end's aliasing factor those jumps are seen through
        (:func:`~observer.estimation.intersample.alias_factor`, or the identified one).
    reconstruction : JumpReconstruction or None
        The filtered jumps put back between the samples
        (:mod:`~observer.estimation.dealias`): every moment of the voltage is corrected by it.
    """

    voltage: np.ndarray
    current: np.ndarray
    dt: float
    inp: InputModel
    emf: np.ndarray | None = None
    emf_constant: float | None = None
    fit_shift: bool = False
    fit_lag: bool = False
    lag: float = 0.0
    alias_v: tuple[float, ...] = ()
    untold_front_end: bool = False
    alias_locked: tuple[bool, ...] = ()
    mismatch_applied: float = 0.0
    jumps: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)
    jump_alias: float = 0.0
    reconstruction: JumpReconstruction | None = field(default=None, repr=False)
    _mu_emf: np.ndarray | None = field(default=None, repr=False)
    _mu_cache: dict[tuple[float, float], np.ndarray] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if self.emf is not None:
            self._mu_emf = smooth_moments(self.emf, self.inp.segments, 0.0)
        if self.lag == 0.0:
            self._mu_cache[(self.inp.shift, 0.0)] = self.inp.mu
        if self.inp.model in ("hold", "averaged"):
            self.fit_shift = False
            self.fit_lag = False

    # ------------------------------------------------------------- layout
    @property
    def segments(self) -> Segments:
        return self.inp.segments

    @property
    def emf_mode(self) -> int:
        if self.emf is None:
            return ik.EMF_NONE
        return ik.EMF_FIT if self.emf_constant is None else ik.EMF_HELD

    @property
    def fits_k(self) -> bool:
        return self.emf_mode == ik.EMF_FIT

    @property
    def mu_emf(self) -> np.ndarray:
        return self._mu_emf if self._mu_emf is not None else self.inp.mu

    def mu(self, shift: float, lag: float | None = None) -> np.ndarray:
        """Voltage moments read ``shift`` periods late through a ``lag`` (periods), cached."""
        lag_ = self.lag if lag is None else float(lag)
        key = (float(shift), lag_)
        mu = self._mu_cache.get(key)
        if mu is None:
            seg = self.inp.segments
            mu = smooth_moments(self.voltage, seg, key[0])
            if lag_ > 0.0:
                lagged = np.array(self.voltage, dtype=np.float64)
                ik.lag_samples(mu, self.voltage, seg.starts, seg.ends, lag_, lagged)
                mu = smooth_moments(lagged, seg, 0.0)
            if self.reconstruction is not None:
                mu = self.reconstruction.correct(mu, key[0])
            if len(self._mu_cache) > 64:
                self._mu_cache.clear()
            self._mu_cache[key] = mu
        return mu

    def guards(self, shift: float) -> bool:
        """Whether a fit that found relative delay ``shift`` must be redone from it.

        A ``switched`` problem leaves out the first samples of each segment that a
        delay takes from across the jump before it (:func:`make_problem`); when the
        fitted delay leaves out more than the delay it started from, the fit used
        samples whose voltage came from across the jump.
        """
        if self.inp.model != "switched" or not self.fit_shift:
            return False
        return _guard(shift) > _guard(self.inp.shift)

    def with_shift(self, shift: float, lag: float | None = None) -> WindingProblem:
        """The same problem with the input model read at ``shift`` (and ``lag``)."""
        lag_ = self.lag if lag is None else float(lag)
        inp = InputModel(
            self.inp.model, self.mu(shift, lag_), self.inp.segments, shift, self.inp.switching
        )
        return WindingProblem(
            self.voltage, self.current, self.dt, inp, self.emf, self.emf_constant,
            self.fit_shift, self.fit_lag, lag_, self.alias_v, self.untold_front_end,
            self.alias_locked, self.mismatch_applied, self.jumps, self.jump_alias,
            self.reconstruction,
        )  # fmt: skip

    # ------------------------------------------------------------- the swarm
    def swarm_cost(self, input_noise_var: float = 0.0) -> CostFunction:
        """Eq. (1) for a whole swarm over ``log10 (R, L)``, at the model's present shift."""
        mu = self.inp.mu
        mu_emf = self.mu_emf
        seg = self.inp.segments
        k_arg = 0.0 if self.emf_constant is None else float(self.emf_constant)
        mode = self.emf_mode
        # Held inputs (zero higher moments) take the kernel's cheaper loop; decided once here.
        moments = 3 if mu[:, 1:].any() or (mode != ik.EMF_NONE and mu_emf[:, 1:].any()) else 1

        def cost(x: np.ndarray) -> np.ndarray:
            return ik.moment_swarm_costs(
                x, mu, mu_emf, self.current, seg.starts, seg.ends, self.dt, True,
                mode, k_arg, input_noise_var, moments,
            )  # fmt: skip

        return cost

    # ------------------------------------------------------------- the polish
    def theta0(
        self, resistance: float, inductance: float, emf_constant: float | None
    ) -> np.ndarray:
        """Starting parameters ``(ln R, ln L[, K][, shift])``."""
        theta = [math.log(resistance), math.log(inductance)]
        if self.fits_k:
            theta.append(0.0 if emf_constant is None else float(emf_constant))
        if self.fit_shift:
            theta.append(self.inp.shift)
        if self.fit_lag:
            theta.append(self.lag)
        return np.array(theta)

    def unpack(self, theta: np.ndarray) -> tuple[float, float, float, float]:
        """``(R, L, K, shift)`` from ``theta`` (K: the held value, or 0 for the field)."""
        resistance = math.exp(theta[0])
        inductance = math.exp(theta[1])
        i = 2
        if self.fits_k:
            k = float(theta[i])
            i += 1
        else:
            k = 0.0 if self.emf_constant is None else float(self.emf_constant)
        shift = float(theta[i]) if self.fit_shift else self.inp.shift
        return resistance, inductance, k, shift

    def lag_of(self, theta: np.ndarray) -> float:
        """The voltage's relative lag (periods) in ``theta``."""
        return float(theta[-1]) if self.fit_lag else self.lag

    def residual(self, theta: np.ndarray) -> np.ndarray:
        """Current residual (A) over the segments' samples, initial currents projected out."""
        resistance, inductance, k, shift = self.unpack(theta)
        out, _ = self.evaluate(resistance, inductance, k, shift, self.lag_of(theta))
        return out

    def residual_and_jacobian(
        self, theta: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`residual`, its Jacobian by ``theta``, ``J'J`` and ``J'r`` at ``theta``.

        The columns of ``ln R``, ``ln L`` (and ``K``) are exact, from the
        residual's own kernel pass
        (:func:`~observer.estimation.intersample_kernels.moment_residual_jacobian`):
        one evaluation where forward differences take one more per parameter.
        A fitted shift or lag moves the voltage's moments (a cubic reconstruction,
        a lag filter) and keeps its forward difference, as
        :func:`~observer.estimation.polish.jacobian` takes it.
        """
        resistance, inductance, k, shift = self.unpack(theta)
        mu = self.mu(shift, self.lag_of(theta))
        seg = self.inp.segments
        core = 2 + int(self.fits_k)
        out = np.empty(seg.covered)
        jac = np.empty((seg.covered, theta.size))
        initial = np.empty(seg.count)
        normal = np.empty((core, core + 1))
        ik.moment_residual_jacobian(
            resistance, inductance, k, mu, self.mu_emf, self.current, seg.starts, seg.ends,
            self.dt, self.emf_mode, out, jac, initial, normal,
        )  # fmt: skip
        if theta.size == core:
            return out, jac, normal[:, :core], normal[:, core]
        jtj = np.empty((theta.size, theta.size))
        grad = np.empty(theta.size)
        jtj[:core, :core] = normal[:, :core]
        grad[:core] = normal[:, core]
        for j in range(core, theta.size):
            h = 1e-6 * max(abs(theta[j]), 1e-3)
            up = theta.copy()
            up[j] += h
            column = (self.residual(up) - out) / h
            jac[:, j] = column
            # Products with a contiguous column (BLAS over the tall J' J takes longer).
            jtj[j, :j] = jtj[:j, j] = column @ jac[:, :j]
            jtj[j, j] = column @ column
            grad[j] = column @ out
        return out, jac, jtj, grad

    def evaluate(
        self,
        resistance: float,
        inductance: float,
        emf_constant: float,
        shift: float,
        lag: float | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Residual (A) and each segment's initial current (A) at these parameters."""
        return self._simulated(resistance, inductance, emf_constant, self.mu(shift, lag))

    def _simulated(
        self, resistance: float, inductance: float, emf_constant: float, mu: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Residual (A) and initial currents (A) for the voltage moments ``mu``."""
        seg = self.inp.segments
        out = np.empty(seg.covered)
        initial = np.empty(seg.count)
        ik.moment_residual(
            resistance, inductance, emf_constant, mu, self.mu_emf, self.current,
            seg.starts, seg.ends, self.dt, self.emf is not None, out, initial,
        )  # fmt: skip
        return out, initial

    def moment_columns(self, theta: np.ndarray, changes: Sequence[np.ndarray]) -> np.ndarray:
        """``(covered, len(changes))``: the residual's change at ``theta`` for each change of the
        voltage's interval moments.

        The residual is affine in the voltage (initial currents projected out
        again), so one more evaluation per change gives it exactly; the
        residual at ``theta`` is evaluated once for all of them.
        """
        resistance, inductance, k, shift = self.unpack(theta)
        mu = self.mu(shift, self.lag_of(theta))
        base = self.residual(theta)
        return np.column_stack(
            [self._simulated(resistance, inductance, k, mu + d)[0] - base for d in changes]
        )

    def jump_moments(self) -> np.ndarray:
        """The moments' change were every jump's interval mean raised by the jump's size
        (an error of each jump's area of one sample period times its size)."""
        d = np.zeros_like(self.inp.mu)
        if self.jumps is not None:
            starts, sizes = self.jumps
            d[starts, 0] = sizes
        return d

    def offset_moments(self, where: slice = slice(None)) -> np.ndarray:
        """The moments' change of every interval's mean raised by 1 V (only in ``where``)."""
        d = np.zeros_like(self.inp.mu)
        d[where, 0] = 1.0
        return d

    def input_moments(self, theta: np.ndarray, dv: np.ndarray) -> np.ndarray:
        """The moments' change of ``dv`` (V, per sample) added to the voltage, at ``theta``,
        read through the problem's own intersample model (held, averaged or band-limited)."""
        if self.inp.model == "hold":
            return hold_moments(dv)
        if self.inp.model == "averaged":
            return averaged_moments(dv)
        return smooth_moments(dv, self.inp.segments, self.unpack(theta)[3])

    def mismatch_moments(
        self, theta: np.ndarray, pairs: Sequence[tuple[str, str]]
    ) -> list[np.ndarray]:
        """The moments' change were the channels each of ``pairs`` (untold front ends; see
        :func:`~observer.estimation.frontend.unknown_mismatch`), read through the
        band-limited model at ``theta``'s shift, from one spectrum of each segment."""
        return smooth_moments_through(
            self.voltage, self.inp.segments, self.unpack(theta)[3],
            [mismatch_response(pair, self.dt) for pair in pairs],
        )  # fmt: skip

    def offset_column(self, theta: np.ndarray, where: slice = slice(None)) -> np.ndarray:
        """d(residual)/d(voltage offset) at ``theta``: the residual's change per volt added
        (:meth:`moment_columns`). ``where``: only the intervals in this slice."""
        return self.moment_columns(theta, [self.offset_moments(where)])[:, 0]

    def input_column(self, theta: np.ndarray, dv: np.ndarray) -> np.ndarray:
        """The residual's change at ``theta`` were ``dv`` (V, per sample) added to the voltage."""
        return self.moment_columns(theta, [self.input_moments(theta, dv)])[:, 0]

    def alias_pieces(self) -> list[tuple[slice, float]]:
        """The window's pieces (slices of intervals) and each one's :attr:`alias_v` bound."""
        if not self.alias_v:  # no smooth reconstruction of jumps: nothing aliased
            return []
        pieces = alias_pieces(self.inp.mu.shape[0])
        return [(where, v) for where, v in zip(pieces, self.alias_v, strict=True) if v > 0.0]

    def best_k(self, resistance: float, inductance: float, shift: float) -> float:
        """``K`` solved in closed form at ``(R, L, shift)`` (the held value if held)."""
        if not self.fits_k:
            return 0.0 if self.emf_constant is None else float(self.emf_constant)
        # The residual is affine in K: two evaluations give its slope.
        r0, _ = self.evaluate(resistance, inductance, 0.0, shift)
        r1, _ = self.evaluate(resistance, inductance, 1.0, shift)
        slope = r1 - r0
        denom = float(slope @ slope)
        return -float(r0 @ slope) / denom if denom > 0 else 0.0

    def limits(self, log_bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper limits of ``theta`` from the swarm's ``log10`` box."""
        size = 2 + int(self.fits_k) + int(self.fit_shift) + int(self.fit_lag)
        lower = np.full(size, -np.inf)
        upper = np.full(size, np.inf)
        lower[:2] = log_bounds[:, 0] * math.log(10.0)
        upper[:2] = log_bounds[:, 1] * math.log(10.0)
        i = 2 + int(self.fits_k)
        if self.fit_shift:
            lower[i] = -SHIFT_LIMIT
            upper[i] = SHIFT_LIMIT
            i += 1
        if self.fit_lag:
            lower[i] = 0.0
            upper[i] = LAG_LIMIT
        return lower, upper


#: A learned relative delay up to this many sample periods leaves a switched segment's
#: first interval in (see :func:`make_problem`).
DELAY_SLACK = 0.2


def _guard(shift: float) -> int:
    """Samples left out at the start of each switched segment for a relative delay ``shift``."""
    return max(0, math.ceil(abs(shift) - DELAY_SLACK))


#: A window with less than this share of its samples inside segments (a ``switched``
#: voltage whose jumps, and the current's settling after them, leave little between) does
#: not describe its circuit: an unfiltered 6-pulse voltage beside a current filtered at fs/4
#: leaves 0-3 % at 2 kHz (Ra +108 % at 2.7 std), 52-65 % at 5 kHz.
MIN_COVERAGE = 0.2


def coverage_note(share: float, circuit: str) -> str:
    """Why a window with ``share`` of its samples in segments cannot describe the
    ``circuit`` ("" when it can)."""
    if share >= MIN_COVERAGE:
        return ""
    return (
        f"only {100 * share:.0f} % of the window's samples lie between the voltage's jumps "
        f"where the current has settled, too few to describe the {circuit}: sample faster, "
        "or filter the voltage channel like the current one"
    )


def pwm_note(voltage: np.ndarray, circuit: str) -> str:
    """Why a window whose voltage is a PWM carrier sampled bare cannot describe the ``circuit``
    ("" when it can). Its estimates were confidently wrong: the P-12 behind a chopper at
    5 kHz without filters gave Rf -4.3 % at 19 std, Ra -93 %, K +28 % at 2.6 std."""
    share = pwm_level_changes(voltage)
    if share < PWM_CHANGES:
        return ""
    return (
        f"the {circuit} voltage's samples sit at its converter's levels and change level in "
        f"{100 * share:.0f} % of the intervals: a PWM voltage sampled without an anti-aliasing "
        "filter, whose samples do not show how long it stayed at each level; filter or "
        "average the voltage channel"
    )


#: Pieces of a window whose voltage errors from aliasing are bounded separately.
ALIAS_PIECES = 4


def alias_pieces(n_intervals: int) -> list[slice]:
    """The :data:`ALIAS_PIECES` equal pieces of a window's ``n_intervals`` intervals."""
    edges = np.linspace(0, n_intervals, ALIAS_PIECES + 1).astype(int)
    return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def _without_edges(valid: np.ndarray, edge: int) -> np.ndarray:
    """``valid`` with ``edge`` samples at each end (at most a quarter of the window) left
    out: what filtering the mirror-extended window spoils."""
    edge = min(edge, valid.shape[0] // 4)
    out = valid.copy()
    out[:edge] = False
    out[valid.shape[0] - edge :] = False
    return out


def make_problem(
    voltage: np.ndarray,
    current: np.ndarray,
    dt: float,
    model: str,
    *,
    switching: object = None,
    emf: np.ndarray | None = None,
    emf_constant: float | None = None,
    fit_shift: bool = True,
    shift: float = 0.0,
    fit_lag: bool = False,
    lag: float = 0.0,
    also_checked: tuple[np.ndarray, ...] = (),
    front_ends: tuple[FrontEnd, FrontEnd] | None = None,
    mismatch: float | None = None,
    voltage_alias: float | None = None,
    reconstruct_jumps: bool = False,
    identified_filter: str | None = None,
) -> WindingProblem:
    """A :class:`WindingProblem` for voltage samples under intersample ``model``.

    Samples where the voltage, the current or a channel of ``also_checked``
    (the armature's ``if`` and ``omega``) sits at its ADC's rail
    (:func:`~observer.estimation.intersample.rail_samples`) leave the segments.
    ``shift`` is the relative delay to start from (or to hold, without ``fit_shift``).
    ``front_ends`` ``(voltage, current)`` are the channels' known front ends: a
    filtered (``smooth``) voltage is then passed through ``H_i/H_v``
    (:func:`~observer.estimation.frontend.apply_relative`) and the window's
    edges, which that spoils, leave the segments. Not told them, a filtered voltage is
    corrected by the ``mismatch`` of the channels learned
    (:func:`~observer.estimation.frontend.applied_mismatch`), its edges likewise.
    ``reconstruct_jumps``: a filtered voltage's jumps are put back between its samples
    (:mod:`~observer.estimation.dealias`) through its configured filter or, untold, the one
    ``identified_filter`` names (:attr:`~observer.estimation.filter_id.FilterFit.best`).
    """
    raw_voltage = voltage
    valid = ~(rail_samples(voltage) | rail_samples(current))
    for x in also_checked:
        valid &= ~rail_samples(x)
    if (
        front_ends is not None
        and model in ("smooth", "hold")
        and not (front_ends[0] == front_ends[1])
    ):
        fe_v, fe_i = front_ends
        voltage = apply_relative(voltage, dt, fe_v, fe_i)
        # The EMF (``if*omega``) is taken as the current channel sees it: its inputs are slow,
        # and their own front ends are not applied (docs/drive_chain.md).
        valid = _without_edges(valid, edge_samples(fe_v, fe_i, dt))
        model = "smooth"
    applied = applied_mismatch(mismatch) if front_ends is None and model == "smooth" else 0.0
    if applied:
        voltage = voltage + applied * unknown_mismatch(voltage, dt)
        pair = [parse_front_end(text) for text in UNKNOWN_MISMATCH]
        valid = _without_edges(valid, edge_samples(pair[0], pair[1], dt))
    if front_ends is not None and model == "switched" and front_ends[0] != front_ends[1]:
        # A filtered jump settles over the voltage filter's response; where the
        # current's front end differs, the samples in it do not relate to the
        # current as the segment assumes (equal front ends relate exactly).
        sw = switching if isinstance(switching, Switching) else find_switching(voltage, dt)
        settle = edge_samples(front_ends[0], front_ends[0], dt) - 2
        if sw.transitions is not None:
            switching = sw.widened(settle)
    if model == "switched":
        sw = switching if isinstance(switching, Switching) else find_switching(voltage, dt)
        # A relative delay (up to a sample behind a current's filter), fitted or learned,
        # takes the voltage of a segment's first intervals from across the jump before it:
        # the field, whose bends are too small to show a filter, read Rf +1.6 % at 2 std at
        # 5 kHz. One of a fifth of a sample or less (channels filtered alike) takes too
        # little to pay for a sample of every segment at 2 kHz. A fitted delay is not known
        # before the fit: the fit starts from ``shift``, and is redone once if the delay
        # it finds asks for more (:meth:`WindingProblem.guards`).
        delay = _guard(shift)
        switching = settle_current(current, voltage, sw, at_least=delay)
    alias_v: tuple[float, ...] = ()
    alias_locked: tuple[bool, ...] = ()
    jumps: tuple[np.ndarray, np.ndarray] | None = None
    jump_alias = 0.0
    reconstruction: JumpReconstruction | None = None
    if model == "smooth":
        # Jumps between samples that a smooth reconstruction spreads over their intervals
        # (a switched model leaves them out of its segments; a held voltage has none).
        sw = switching if isinstance(switching, Switching) else find_switching(raw_voltage, dt)
        known_v = front_ends[0] if front_ends is not None else None
        factor = alias_factor(
            None if known_v is None else functools.partial(known_v.response, sample_rate_hz=1 / dt),
            1.0 / dt,
        )
        if known_v is None and voltage_alias is not None:
            # Untold, but identified from the converter's jumps (:mod:`.filter_id`).
            factor = voltage_alias
        t = sw.transition_mask
        jumps = jump_runs(raw_voltage, t)
        if reconstruct_jumps:
            seen = known_v if known_v is not None else identified_front_end(identified_filter)
            reconstruction = reconstruct(
                raw_voltage, dt, jumps[0], seen, front_ends[1] if front_ends is not None else None
            )
            if reconstruction is not None:
                # What the jumps' fit leaves of their alias.
                factor *= RESIDUAL_ALIAS
        bounds = [
            alias_bias(raw_voltage[p.start : p.stop + 1], t[p], factor)
            for p in alias_pieces(t.shape[0])
        ]
        alias_v = tuple(b for b, _ in bounds)
        alias_locked = tuple(locked for _, locked in bounds)
        jump_alias = factor
    inp = build_input(voltage, model, shift=shift, switching=switching, valid=valid, dt=dt)  # type: ignore[arg-type]
    if reconstruction is not None:
        inp = InputModel(
            inp.model, reconstruction.correct(inp.mu, inp.shift), inp.segments, inp.shift,
            inp.switching,
        )  # fmt: skip
    problem = WindingProblem(
        voltage, current, dt, inp, emf, emf_constant, fit_shift, fit_lag, lag, alias_v,
        untold_front_end=front_ends is None and model == "smooth", alias_locked=alias_locked,
        mismatch_applied=applied, jumps=jumps, jump_alias=jump_alias,
        reconstruction=reconstruction,
    )  # fmt: skip
    return problem.with_shift(shift, lag) if lag else problem
