"""The tracked motor state behind the window fits: one Kalman filter per parameter.

Each window's swarm fit is a *measurement* of the motor's parameters; the
published values are a tracked state that weighs every window by its
uncertainty, so a weak window barely moves it and a strong one corrects it.

Per parameter (``Rf, Lf, Ra, La, K``) the state lives in log units (relative
changes are what physics bounds) and follows

* ``L`` and ``K``: a random walk, ``x' = x + w``, ``var(w) = q * dt``;
* ``R``: a level and its rate of change (the windings heat and cool), or, with
  a thermal time constant configured, a first-order thermal model driven by
  the machine's I^2R losses (:class:`Thermal`), so the resistance is carried
  between informative windows too. Without one, thermal models of time
  constants from 20 s to 43 min are weighed beside the level by their
  likelihood and the published value is their mixture (:class:`ThermalBank`).

The process noise ``q`` comes from physical rates (``[observer.tracker]``): how
far a parameter can wander per minute. A window's fit enters with variance
``overlap * rel_std^2``: consecutive windows share ``1 - hop/window`` of their
samples, so ``overlap = window_s / hop_s`` windows carry the information of one
(treating them as independent would count each sample ``overlap`` times). The
first window after a held stretch of a window or more shares no sample with
any the state holds and weighs whole (:meth:`MotorTracker._repeats`). The step
test weighs windows as the filter does for a resistance, except that a window much
sharper than the last one taken in counts what it adds
(:meth:`MotorTracker._test_variance`), and every other parameter's window as one
of a run. A
fit stands for the middle of the samples that inform it, not the window's end:
models with a rate say so in their observation row.

Part of a window's std may be a bias every window at the same operating point
shares (:attr:`Evidence.shared_rel_std`: the alias of a converter's jumps locked
to the samples, a voltage sensor's offset). Weighing windows cannot average it
down, so it enters the published std whole: ``std^2 = P + shared^2``, ``P``
the state's variance, ``shared`` that of the latest window taken in. The
state, the innovations and the change test are as without it.

Windows that are not evidence -- the estimator says its model does not
describe them, the parameter's relative std is not finite or zero, or above its
``[observer.quality]`` limit -- only advance the state (``held``). An
innovation beyond ``gate_sigma`` is not used to update (``outlier``) but goes to
the change test (:mod:`observer.service.changes`). A confirmed change freezes
the circuit's parameters until windows wholly after it (windows across a step
describe neither side; those already seen count) agree on the new level, then
re-starts the changed parameter there and reports the size of the step as a
:class:`ChangeEvent`; a change they do not bear out is dropped.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from observer.config import TrackerConfig
from observer.service.changes import Alarm, StepGlr

#: The tracked parameters, and where each sits in the estimate message.
PARAMETERS = ("Rf", "Lf", "Ra", "La", "K")
LOCATION: dict[str, tuple[str, str]] = {
    "Rf": ("field", "R"),
    "Lf": ("field", "L"),
    "Ra": ("armature", "R"),
    "La": ("armature", "L"),
    "K": ("armature", "K"),
}

#: Statuses of a tracked parameter in one window.
STATUSES = ("ok", "held", "outlier", "change", "none")


@dataclass(frozen=True)
class Evidence:
    """One window's fit of one parameter.

    Attributes
    ----------
    value : float
        The fit (SI units), > 0.
    rel_std : float
        Its one-sigma relative uncertainty (the estimator's ``std / value``).
    shared_rel_std : float
        The part of ``rel_std`` every window at the same operating point shares (a
        bias; the estimator's ``shared_std / value``); 0: none known.
    """

    value: float
    rel_std: float
    shared_rel_std: float = 0.0

    @property
    def shared_var(self) -> float:
        """The shared part's relative variance: ``shared_rel_std`` squared, within
        ``[0, rel_std^2]`` (0 where it is not finite)."""
        shared = self.shared_rel_std if math.isfinite(self.shared_rel_std) else 0.0
        return min(max(shared, 0.0), self.rel_std) ** 2

    @property
    def own_var(self) -> float:
        """The relative variance of the window's own error: ``rel_std^2`` less the shared
        part (>= 0)."""
        return self.rel_std**2 - self.shared_var


@dataclass
class Gaussian:
    """Mean ``x`` and covariance ``P`` of a state (log units)."""

    x: np.ndarray
    P: np.ndarray

    def copy(self) -> Gaussian:
        return Gaussian(self.x.copy(), self.P.copy())


def predict(state: Gaussian, transition: np.ndarray, noise: np.ndarray) -> None:
    """Kalman prediction in place: ``x = F x``, ``P = F P F' + Q``."""
    state.x = transition @ state.x
    state.P = transition @ state.P @ transition.T + noise


def innovation(
    model: Model,
    state: Gaussian,
    z: float,
    r: float,
    lag_s: float,
    losses: Sequence[tuple[float, float]],
) -> tuple[np.ndarray, float, float]:
    """A fit ``z`` (log, measurement variance ``r``) standing ``lag_s`` before now against
    ``state``: the observation row, the innovation and its variance."""
    row, predicted = model.observe(state, lag_s, losses)
    return row, z - predicted, float(row @ state.P @ row + r)


def update(state: Gaussian, row: np.ndarray, nu: float, s: float) -> None:
    """Kalman update in place with innovation ``nu`` of variance ``s`` (Joseph form)."""
    gain = state.P @ row / s
    a = np.eye(state.x.size) - np.outer(gain, row)
    state.x = state.x + gain * nu
    state.P = a @ state.P @ a.T + np.outer(gain, gain) * (s - row @ state.P @ row)
    state.P = 0.5 * (state.P + state.P.T)


class Model(Protocol):
    """How one parameter's log state evolves and is observed."""

    def initial(self, z: float, r: float, loss_w: float) -> Gaussian: ...

    def predict(self, state: Gaussian, dt: float, loss_w: float) -> np.ndarray:
        """Carry ``state`` over ``dt``; the transition (linearised at ``state``)."""
        ...

    def step_direction(self, state: Gaussian) -> np.ndarray:
        """The state's change per unit step (log units) of the parameter at once."""
        ...

    def forget_rate(self, state: Gaussian) -> None:
        """Back to the prior on whatever the state holds beside the level (a tracked rate
        shown wrong); the level and its variance stay."""
        ...

    def observe(
        self, state: Gaussian, lag_s: float, losses: Sequence[tuple[float, float]]
    ) -> tuple[np.ndarray, float]:
        """The observation row (linearised at ``state``) and the fit it predicts, of a
        fit that stands for the parameter ``lag_s`` before the window's end;
        ``losses``: ``(dt, loss_w)`` of the latest hops, the last one ending now."""
        ...

    def rate(self, state: Gaussian, loss_w: float) -> float: ...

    def shift(self, state: Gaussian, step: float, r: float) -> None: ...


class _Linear:
    """A model whose transition and observation are linear: the plain Kalman filter."""

    def transition(self, dt: float, loss_w: float) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def observation(self, lag_s: float) -> np.ndarray:
        raise NotImplementedError

    def predict(self, state: Gaussian, dt: float, loss_w: float) -> np.ndarray:
        transition, noise = self.transition(dt, loss_w)
        predict(state, transition, noise)
        return transition

    def step_direction(self, state: Gaussian) -> np.ndarray:
        direction = np.zeros(state.x.size)
        direction[0] = 1.0  # the level; a rate does not jump
        return direction

    def forget_rate(self, state: Gaussian) -> None:
        return None

    def observe(
        self, state: Gaussian, lag_s: float, losses: Sequence[tuple[float, float]]
    ) -> tuple[np.ndarray, float]:
        row = self.observation(lag_s)
        return row, float(row @ state.x)


class RandomWalk(_Linear):
    """``x' = x + w``: a parameter that only wanders (``q``: variance per second)."""

    def __init__(self, q: float) -> None:
        self.q = q

    def initial(self, z: float, r: float, loss_w: float) -> Gaussian:
        return Gaussian(np.array([z]), np.array([[r]]))

    def transition(self, dt: float, loss_w: float) -> tuple[np.ndarray, np.ndarray]:
        return np.eye(1), np.array([[self.q * dt]])

    def observation(self, lag_s: float) -> np.ndarray:
        return np.ones(1)

    def rate(self, state: Gaussian, loss_w: float) -> float:
        return 0.0

    def shift(self, state: Gaussian, step: float, r: float) -> None:
        state.x[0] += step
        state.P[0, 0] = r


class Trend(_Linear):
    """Level and rate of change: ``x' = x + v dt``, the rate ``v`` a random walk.

    Parameters
    ----------
    q_level, q_rate : float
        Variance per second of the level's own wander (1/s) and of the rate (1/s^3).
    rate_std : float
        Prior one-sigma rate before any window (1/s).
    """

    def __init__(self, q_level: float, q_rate: float, rate_std: float) -> None:
        self.q_level = q_level
        self.q_rate = q_rate
        self.rate_std = rate_std

    def initial(self, z: float, r: float, loss_w: float) -> Gaussian:
        return Gaussian(np.array([z, 0.0]), np.diag([r, self.rate_std**2]))

    def transition(self, dt: float, loss_w: float) -> tuple[np.ndarray, np.ndarray]:
        q = self.q_rate
        noise = np.array(
            [[self.q_level * dt + q * dt**3 / 3, q * dt**2 / 2], [q * dt**2 / 2, q * dt]]
        )
        return np.array([[1.0, dt], [0.0, 1.0]]), noise

    def observation(self, lag_s: float) -> np.ndarray:
        return np.array([1.0, -lag_s])

    def rate(self, state: Gaussian, loss_w: float) -> float:
        return float(state.x[1])

    def shift(self, state: Gaussian, step: float, r: float) -> None:
        state.x[0] += step
        state.P[0, :] = 0.0
        state.P[:, 0] = 0.0
        state.P[0, 0] = r

    def forget_rate(self, state: Gaussian) -> None:
        state.x[1] = 0.0
        state.P[1, :] = 0.0
        state.P[:, 1] = 0.0
        state.P[1, 1] = self.rate_std**2


class Thermal:
    """A winding's resistance heated by the copper losses: a first-order thermal model.

    Copper's resistance is linear in its temperature, and the temperature rise
    relaxes with time constant ``tau`` towards one proportional to the loss; so
    does the resistance itself:

        tau dR/dt = R0 + c P / P_ref - R,

    ``R0`` the cold (ambient) resistance, ``P`` the machine's I^2R loss (W)
    over the last hop, ``c`` the steady rise at the reference loss ``P_ref``
    (the loss of the first window). ``R0`` and ``c`` are states too, learnt
    from the windows, so only ``tau`` is motor data. The state is ``(y, c,
    r0)``: ``y = ln R`` (log units, as every parameter's) and ``c, r0`` in units
    of the first window's fit ``R_1`` (so of order 0.1 and 1 for any motor).
    The model is linear in ``R, c, R0`` but observed in ``ln R``: an extended
    Kalman filter, whose transition is exact for a loss constant over a hop.
    (Relaxing ``ln R`` linearly instead misses the rate by the share of the
    rise still to come: 10 % of the rate of a winding 10 % below its steady
    rise, more than a precise fit's tolerance over a few seconds without
    informative windows.) ``c`` and ``R0`` enter every row in the ratio of the
    loss, as in the linear model: what a constant loss cannot tell apart, the
    filter does not pretend to.

    Parameters
    ----------
    tau : float
        Thermal time constant (s).
    q_level : float
        Variance per second of what the model leaves out (1/s).
    gain_std : float
        Prior one-sigma of ``c`` (relative rise at the first window's loss).
    cold_std : float
        Prior one-sigma of ``R0 / R_1 - 1``.
    """

    def __init__(
        self, tau: float, q_level: float, gain_std: float = 0.3, cold_std: float = 0.1
    ) -> None:
        self.tau = tau
        self.q_level = q_level
        self.gain_std = gain_std
        self.cold_std = cold_std
        self.reference_w = 1.0
        self.log_r1 = 0.0  # ln R_1

    def initial(self, z: float, r: float, loss_w: float) -> Gaussian:
        self.reference_w = loss_w if loss_w > 0 else 1.0
        self.log_r1 = z
        return Gaussian(np.array([z, 0.0, 1.0]), np.diag([r, self.gain_std**2, self.cold_std**2]))

    def _steady(self, x: np.ndarray, loss_w: float) -> tuple[float, float, float]:
        """``R_steady / R``, and its derivatives by ``c`` and ``r0`` (``R_1 / R`` times the
        loss ratio and 1); a negative steady resistance is taken as none."""
        unit = math.exp(self.log_r1 - float(x[0]))  # R_1 / R
        p = loss_w / self.reference_w
        return max(unit * (float(x[2]) + float(x[1]) * p), 1e-6), unit * p, unit

    def predict(self, state: Gaussian, dt: float, loss_w: float) -> np.ndarray:
        a = math.exp(-dt / self.tau)
        steady, d_c, d_r0 = self._steady(state.x, loss_w)
        m = a + (1.0 - a) * steady  # R after dt / R now
        f = np.array([[a / m, (1.0 - a) * d_c / m, (1.0 - a) * d_r0 / m], [0, 1, 0], [0, 0, 1]])
        state.x = np.array([state.x[0] + math.log(m), state.x[1], state.x[2]])
        state.P = f @ state.P @ f.T + np.diag([self.q_level * dt, 0.0, 0.0])
        return f

    def step_direction(self, state: Gaussian) -> np.ndarray:
        # As :meth:`shift`: a step moves the cold value and the rise with the present one.
        return np.array([1.0, float(state.x[1]), float(state.x[2])])

    def forget_rate(self, state: Gaussian) -> None:
        return None  # the rate follows the losses: nothing of its own to forget

    def observe(
        self, state: Gaussian, lag_s: float, losses: Sequence[tuple[float, float]]
    ) -> tuple[np.ndarray, float]:
        # R lag_s ago in units of R_1, back through the hops' losses (each step back
        # inverts one hop's relaxation): alpha * R/R_1 - beta_c * c - beta_0 * r0.
        alpha, beta_c, beta_0 = 1.0, 0.0, 0.0
        left = lag_s
        hops = list(losses)
        while left > 1e-12:
            # Beyond the hops kept: the earliest one's loss.
            dt, loss_w = hops.pop() if hops else (left, losses[0][1])
            a = math.exp(-min(dt, left) / self.tau)
            p = loss_w / self.reference_w
            alpha, beta_c, beta_0 = alpha / a, (beta_c + (1 - a) * p) / a, (beta_0 + 1 - a) / a
            left -= min(dt, left)
        now = math.exp(float(state.x[0]) - self.log_r1)
        then = max(alpha * now - beta_c * float(state.x[1]) - beta_0 * float(state.x[2]), 1e-6)
        row = np.array([alpha * now / then, -beta_c / then, -beta_0 / then])
        return row, self.log_r1 + math.log(then)

    def rate(self, state: Gaussian, loss_w: float) -> float:
        return (self._steady(state.x, loss_w)[0] - 1.0) / self.tau

    def shift(self, state: Gaussian, step: float, r: float) -> None:
        # A step (a loose connection) moves the cold value with the present one.
        scale = math.exp(step)
        state.x[0] += step
        state.x[1:] *= scale
        state.P[1:, 1:] *= scale**2
        state.P[0, :] = 0.0
        state.P[:, 0] = 0.0
        state.P[0, 0] = r


#: Thermal time constants (s) weighed against a resistance's level with a rate where none is
#: configured (:class:`ThermalBank`): a factor of two apart, from a fast-heating test
#: winding's 20 s to a large motor's 43 min.
THERMAL_TAUS_S = (20.0, 40.0, 80.0, 160.0, 320.0, 640.0, 1280.0, 2560.0)


#: The weight at which a model of :class:`ThermalBank` is said (in the log) to lead.
THERMAL_LEAD = 0.9

#: A leading thermal model is said to show heating where its learnt rise is this many of
#: its stds above zero: on an hour of clean recordings a model of 20 s without a rise came
#: to lead Ra (weight 0.91), predicting a constant as well as the level with a rate.
HEATING_SIGMAS = 3.0


def _loglik(nu: float, s: float) -> float:
    """Log-likelihood of an innovation ``nu`` of variance ``s``."""
    return -0.5 * (math.log(2.0 * math.pi * s) + nu * nu / s)


@dataclass
class _Candidate:
    model: Model
    state: Gaussian
    loglik: float = 0.0


def _heating(model: Model, state: Gaussian) -> float:
    """``model``'s time constant where it is a thermal model whose learnt rise is clear
    (:data:`HEATING_SIGMAS` of its std above zero), else 0."""
    if not isinstance(model, Thermal):
        return 0.0
    rise, var = float(state.x[1]), float(state.P[1, 1])
    return model.tau if rise > HEATING_SIGMAS * math.sqrt(max(var, 0.0)) else 0.0


class ThermalBank:
    """First-order thermal models of several time constants beside a resistance's level with a
    rate, weighed by how well each predicted the windows (a static multiple-model estimator).

    A winding's thermal time constant is motor data few users have. A level with a rate of
    change follows heating, but where the rate itself bends fast (a winding far below its
    steady rise, heating with a time constant of a minute) it lags: on a 120 s recording
    whose windings rise 14 % with a 40 s time constant, Rf was within 0.1 % of the truth in
    84 % of the windows and its std read 1.4 times too small; with the time constant told,
    100 %. Every candidate (:class:`Thermal`, time constants :data:`THERMAL_TAUS_S`) takes
    the windows the track takes, with the same variances, and adds up the log-likelihood of
    its innovations; the published value is the mixture of the candidates and the track's
    own model, each weighed by its likelihood (variance: the weighed variances and the
    spread of the levels). On a motor that does not heat, no thermal model predicts better
    than the level: the mixture stays with it. Changes are tested on the track's own model
    alone; a confirmed one moves every candidate to the new level.
    """

    def __init__(self, candidates: Sequence[_Candidate]) -> None:
        self.candidates = list(candidates)  # started with the track's first fit
        self.loglik = 0.0  # the track's own model's
        self.noted_tau_s = 0.0  # the time constant last said to lead (0: the own model)

    def predict(self, dt: float, loss_w: float) -> None:
        for c in self.candidates:
            c.model.predict(c.state, dt, loss_w)

    def weights(self) -> np.ndarray:
        """Weights of the track's own model and of each candidate."""
        lls = np.array([self.loglik] + [c.loglik for c in self.candidates])
        w = np.exp(lls - lls.max())
        return np.asarray(w / w.sum())

    def mixture(self, own: tuple[float, float]) -> tuple[float, float]:
        """The mixture's log value and variance, given the own model's."""
        levels = [own] + [(float(c.state.x[0]), float(c.state.P[0, 0])) for c in self.candidates]
        w = self.weights()
        x = np.array([v for v, _ in levels])
        p = np.array([v for _, v in levels])
        mean = float(w @ x)
        return mean, float(w @ (p + (x - mean) ** 2))

    def rate(self, own: float, loss_w: float) -> float:
        """The mixture's rate of change (1/s), given the own model's."""
        rates = [own] + [c.model.rate(c.state, loss_w) for c in self.candidates]
        return float(self.weights() @ np.array(rates))

    def widen(self, variance: float) -> None:
        for c in self.candidates:
            c.state.P[0, 0] += variance

    def shift_to(self, z: float, r: float) -> None:
        """A confirmed change: every candidate's level moves to ``z`` (variance ``r``)."""
        for c in self.candidates:
            c.model.shift(c.state, z - float(c.state.x[0]), r)

    def leader(self) -> tuple[_Candidate | None, float]:
        """The most likely model (None: the track's own) and its weight."""
        w = self.weights()
        i = int(np.argmax(w))
        return (None if i == 0 else self.candidates[i - 1]), float(w[i])

    def news(self, name: str, own: Model, own_state: Gaussian) -> str | None:
        """A line for the log when a thermal model whose learnt rise is clear
        (:data:`HEATING_SIGMAS`) has come to lead (:data:`THERMAL_LEAD` of the weight), or
        has stopped leading; else None. ``own``: the track's own model and state. A
        resistance that does not move is predicted as well by a thermal model without a
        rise as by the level, and is not called heated."""
        leader, weight = self.leader()
        model, state = (own, own_state) if leader is None else (leader.model, leader.state)
        tau = _heating(model, state) if weight >= THERMAL_LEAD else 0.0
        if tau == self.noted_tau_s or (tau == 0.0 and weight < THERMAL_LEAD):
            return None
        before, self.noted_tau_s = self.noted_tau_s, tau
        if tau == 0.0:
            return f"{name}: the heating model of {before:.0f} s no longer leads"
        return (
            f"{name}: the windows follow a winding heated by its losses with a thermal time "
            f"constant of about {tau:.0f} s (weight {weight:.2f}); the published value "
            f"follows the models weighed by their likelihood, and changes are tested "
            f"against this one"
        )


def model_for(name: str, config: TrackerConfig, *, thermal_tau_s: float = 0.0) -> Model:
    """The state model of parameter ``name`` under ``config``."""
    per_minute = {"R": config.R_drift_per_min, "L": config.L_drift_per_min}
    per_minute["K"] = config.K_drift_per_min
    q = per_minute[name[0]] ** 2 / 60.0
    if name[0] != "R":
        return RandomWalk(q)
    if thermal_tau_s > 0:
        return Thermal(thermal_tau_s, q)
    rate = config.R_rate_per_min / 60.0  # 1/s
    # The rate wanders by about its typical size per minute.
    return Trend(q, rate**2 / 60.0, rate)


@dataclass(frozen=True)
class TrackedParameter:
    """The tracked state of one parameter after a window.

    Attributes
    ----------
    value, std : float or None
        Tracked value and one-sigma (SI units); None before any evidence.
    status : str
        ``ok`` (the window updated it), ``held`` (the window was no evidence
        for it), ``outlier`` (beyond the gate: not used, but tested for a
        change), ``change`` (a change is being confirmed: frozen), ``none``
        (no evidence yet).
    rate_per_min : float or None
        Relative rate of change per minute (resistances), else None.
    std_scale : float
        The factor the windows' own variances are taken at (:meth:`MotorTracker._calibrate`:
        1 until enough windows have shown how far they scatter).
    """

    value: float | None
    std: float | None
    status: str
    rate_per_min: float | None = None
    std_scale: float = 1.0


@dataclass(frozen=True)
class ChangeEvent:
    """A confirmed step of one parameter.

    Attributes
    ----------
    parameter : str
        ``Rf``, ``Lf``, ``Ra``, ``La`` or ``K``.
    relative, relative_std : float
        Size of the step (``after / before - 1``) and its one-sigma.
    before, after : float
        Tracked value before the change and the first window's fit after it.
    t_change_ns : int
        When it happened (within a hop).
    t_detected_ns : int
        End of the window that confirmed it.
    """

    parameter: str
    relative: float
    relative_std: float
    before: float
    after: float
    t_change_ns: int
    t_detected_ns: int


#: The windows whose fits must agree to show the level after a change (those seen wholly
#: after its onset, not necessarily consecutive) span at least this long (s), and are at
#: least three.
SETTLE_S = 0.3

#: How far back (s) the step test looks for the onset of a change: a step the windows
#: have not confirmed by then (a drive that stood still, a weak stretch) is left to the
#: tracker to follow as a drift (at least two windows).
CHANGE_HORIZON_S = 10.0

#: Hops before a change's onset as the step test dates it whose windows still count as
#: before it (the onset is the most likely one; a weak step's can be a hop or two late).
ONSET_MARGIN_HOPS = 3


#: A window beyond its parameter's quality limit counts towards a confirmed change's level
#: (:meth:`MotorTracker._shows_level`) only within this many times the limit: far beyond it
#: a window does not identify the parameter and its std, taken at wherever the fit came to
#: rest, says little. On a 440 V motor's heating recording the field's Lf windows, where the
#: field voltage stood still, ran off to 4-44 times the truth at stds of 6-38 % (15-95 times
#: Lf's limit) and "showed" a change of Lf of +360 %.
WEAK_FACTOR = 5.0

#: A change the step test confirmed is reported once the windows after it differ from the
#: state before it by this many of the difference's stds. The step test has already
#: weighed every window since the onset (log-likelihood ratio ``change_threshold``, about
#: 4.5 sigma); this asks only that the settled level bear it out. At the outlier gate (4)
#: a 3 % step of Ra at 2 kHz behind a thyristor bridge, seen by its window fits to +-0.6 %,
#: was dropped as "not borne out" in 2 of 20 recordings.
CONFIRM_SIGMA = 3.0

#: Triples of window fits a window apart (no sample in common) that calibrate the windows'
#: stds: their second difference squared over the variance their own (unshared) parts
#: give it, the latest this many. Consecutive triples share most samples: 300 (30 s at a
#: 0.1 s hop) hold about 30 independent ones, whose median is known to within ~25 %.
CALIBRATION_TRIPLES = 300

#: Before this many triples the windows' variances are taken as they say.
CALIBRATION_MIN_TRIPLES = 50

#: The calibration's range (a factor on the variance of a window's own error).
CALIBRATION_RANGE = (0.01, 100.0)

#: Median of a chi-square variable of one degree of freedom (honest triples' ratios).
_CHI2_1_MEDIAN = 0.454936423119572


@dataclass
class _Transition:
    """A change confirmed by the step test, waiting for windows that show the new level."""

    parameter: str
    alarm: Alarm
    before: Gaussian  # the state before the change ...
    detected_ns: int
    before_ns: int  # ... at this time
    # (window end ns, log fit, its variance alone) of the latest windows with evidence
    recent: deque[tuple[int, float, float]] = field(default_factory=lambda: deque(maxlen=3))
    # What the last windows with evidence before the change measured: (log fit,
    # variance), None if there were none.
    fits_before: tuple[float, float] | None = None
    # The circuit's other parameters whose step test confirmed a change meanwhile: the
    # alarm and the window that raised it (end ns, log fit, variance alone).
    pending: dict[str, tuple[Alarm, tuple[int, float, float]]] = field(default_factory=dict)


@dataclass
class _Track:
    name: str
    model: Model
    test: StepGlr
    state: Gaussian | None = None
    # Relative variance of the bias the latest window taken in shares with its neighbours.
    shared_var: float = 0.0
    # (window end ns, state before that window's update) of the latest windows: a
    # change is measured from the state before it.
    history: deque[tuple[int, Gaussian]] = field(default_factory=lambda: deque(maxlen=64))
    # (window end ns, log fit, its variance alone) of the latest windows with evidence.
    fits: deque[tuple[int, float, float]] = field(default_factory=lambda: deque(maxlen=64))
    # (window end ns, log fit, the variance of its own error as the window says) of the
    # latest windows with evidence, and the calibration of that variance they give
    # (:meth:`MotorTracker._calibrate`); sized by the tracker (two windows' worth).
    own: deque[tuple[int, float, float]] = field(default_factory=deque)
    ratios: deque[float] = field(default_factory=lambda: deque(maxlen=CALIBRATION_TRIPLES))
    scale: float = 1.0
    # End of the latest window taken in as evidence (ns), None before the first, and the
    # variance of its own error as it said (None: not known).
    last_in_ns: int | None = None
    last_in_own: float | None = None
    # A resistance without a configured thermal time constant: thermal models beside it.
    bank: ThermalBank | None = None

    def fits_before(self, end_ns: int, start_ns: int, count: int) -> tuple[float, float] | None:
        """The latest ``count`` fits of windows that ended in ``[start_ns, end_ns)``, weighed
        by their precision, with the variance of the best alone (overlapping windows are
        correlated: together worth no more than it); None if there were none."""
        kept = [(z, v) for t, z, v in self.fits if start_ns <= t < end_ns][-count:]
        return _weighed(kept) if kept else None

    def before(self, t_ns: int) -> tuple[int, Gaussian]:
        """The state before the first window that ended at or after ``t_ns``, and that time.

        The oldest kept state if all are later.
        """
        for when, state in self.history:
            if when >= t_ns:
                return when, state.copy()
        assert self.state is not None and self.history
        return self.history[-1][0], self.history[-1][1].copy()


def _weighed(fits: Sequence[tuple[float, float]]) -> tuple[float, float]:
    """Fits ``(log value, variance alone)`` of overlapping windows weighed by their precision,
    and the variance of the best alone: correlated, together they are worth no more."""
    weights = [1.0 / v for _, v in fits]
    z = sum(w * zi for w, (zi, _) in zip(weights, fits, strict=True)) / sum(weights)
    return z, min(v for _, v in fits)


@dataclass(frozen=True)
class TrackerStep:
    """What one window did to the tracked state.

    Attributes
    ----------
    parameters : dict
        Parameter name -> :class:`TrackedParameter`.
    changes : list of ChangeEvent
        Changes confirmed in this window.
    notes : list of str
        Other decisions worth a line in the log (a change not borne out, a
        change put down to the speed sensor).
    """

    parameters: dict[str, TrackedParameter]
    changes: list[ChangeEvent] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


class MotorTracker:
    """The tracked state of ``Rf, Lf, Ra, La, K``, window by window.

    Parameters
    ----------
    config : TrackerConfig
    window_s, hop_s : float
        The sliding windows' length and hop (s): their overlap weighs the fits.
    limits : mapping
        Largest relative std of a window's fit, per parameter (``Rf`` ...), for
        it to count as evidence.
    """

    def __init__(
        self,
        config: TrackerConfig,
        *,
        window_s: float,
        hop_s: float,
        limits: Mapping[str, float],
    ) -> None:
        self.config = config
        self.window_s = window_s
        self.hop_s = hop_s
        self.overlap = max(1.0, window_s / hop_s)
        self.settle_windows = max(3, 1 + math.ceil(SETTLE_S / hop_s - 1e-9))
        self.limits = dict(limits)
        taus = {"Rf": config.field_thermal_tau_s, "Ra": config.armature_thermal_tau_s}
        min_change = {"R": config.min_change_R, "L": config.min_change_L, "K": config.min_change_K}
        self.tracks = {
            name: _Track(
                name,
                model_for(name, config, thermal_tau_s=taus.get(name, 0.0)),
                StepGlr(
                    math.log1p(min_change[name[0]]),
                    config.change_threshold,
                    horizon_s=max(CHANGE_HORIZON_S, 2.0 * window_s),
                    window_s=window_s,
                    hop_s=hop_s,
                ),
                # The calibration's triples span two windows (and a hop or two more).
                own=deque(maxlen=2 * math.ceil(self.overlap) + 4),
            )
            for name in PARAMETERS
        }
        # Resistances without a thermal time constant: thermal models beside their level,
        # started with their first fit (:class:`ThermalBank`).
        self._banked = {n for n, tau in taus.items() if config.identify_thermal and not tau > 0}
        self.transitions: dict[str, _Transition] = {}  # circuit -> change being confirmed
        # Log K of an apparent rise put down to a sensor (None: none pending), and the
        # highest K tracked: the flux per field ampere does not rise by itself.
        self._k_sensor_level: float | None = None
        self._k_highest: float | None = None
        self._last_ns: int | None = None
        self._last_loss_w = 0.0
        self._losses: deque[tuple[float, float]] = deque(maxlen=256)  # (dt, loss) per hop
        self.counts: dict[str, int] = {
            "changes": 0, "changes_not_borne_out": 0, "drift_corrected": 0
        }  # fmt: skip

    # ----------------------------------------------------------------- queries

    def value(self, name: str) -> float | None:
        """Tracked value of ``name`` (SI units), None before any evidence."""
        level = self._level(self.tracks[name])
        return None if level is None else math.exp(level[0])

    def rel_std(self, name: str) -> float | None:
        """Tracked one-sigma relative uncertainty of ``name``."""
        track = self.tracks[name]
        level = self._level(track)
        if level is None:
            return None
        return math.sqrt(max(level[1], 0.0) + track.shared_var)

    @staticmethod
    def _level(track: _Track) -> tuple[float, float] | None:
        """The tracked log value and its variance: the track's own model's, or with a
        :class:`ThermalBank`, the mixture of its models weighed by their likelihood."""
        if track.state is None:
            return None
        own = (float(track.state.x[0]), float(track.state.P[0, 0]))
        if track.bank is None:
            return own
        return track.bank.mixture(own)

    def in_transition(self, circuit: str) -> bool:
        """Whether a change of ``circuit`` is being confirmed (its parameters frozen)."""
        return circuit in self.transitions

    # ----------------------------------------------------------------- one window

    def step(
        self,
        t_ns: int,
        evidence: Mapping[str, Evidence | None],
        *,
        loss_w: float | None = None,
        distrust: frozenset[str] = frozenset(),
    ) -> TrackerStep:
        """Advance to ``t_ns`` (the window's end) and take in the window's fits.

        Parameters
        ----------
        t_ns : int
            End of the window (ns); windows come in increasing time.
        evidence : mapping
            Parameter -> its fit in this window, or None (not evidence).
        loss_w : float, optional
            The machine's copper loss over the last hop (W), for thermal models;
            None: as in the last window.
        distrust : frozenset of str
            Parameters whose fits are known to be misled this window (``K``
            while the speed sensor reads low): they are held, and a rise of
            theirs confirmed meanwhile is not taken as a change.
        """
        if loss_w is not None and math.isfinite(loss_w):
            self._last_loss_w = loss_w
        loss = self._last_loss_w
        dt = 0.0 if self._last_ns is None else max(0.0, (t_ns - self._last_ns) / 1e9)
        self._last_ns = t_ns
        if dt > 0:
            self._losses.append((dt, loss))
        # Before a hop has passed, the loss now stands for the loss before.
        losses: Sequence[tuple[float, float]] = self._losses or [(0.0, loss)]
        step = TrackerStep(parameters={})
        for track in self.tracks.values():
            if track.state is not None and dt > 0:
                track.test.predict(track.model.predict(track.state, dt, loss))
                if track.bank is not None:
                    track.bank.predict(dt, loss)
                # A step may have happened within the hop: test that onset too.
                onset = t_ns - int(round(0.5 * dt * 1e9))
                track.test.open(onset, track.model.step_direction(track.state))
        status: dict[str, str] = {}
        for circuit in ("field", "armature"):
            if circuit in self.transitions:
                self._continue_transition(
                    circuit, t_ns, evidence, loss, losses, distrust, step, status
                )
        for name, track in self.tracks.items():
            if name in status:
                continue
            ev = evidence.get(name)
            if ev is None or name in distrust or not self._usable(name, ev):
                status[name] = "held" if track.state is not None else "none"
                continue
            if name == "K" and self._k_sensor_level is not None and track.state is not None:
                # After an apparent rise of K put down to a sensor: fits nearer that
                # level than the tracked K are the sensor's error, not the motor.
                z_fit = math.log(ev.value)
                if abs(z_fit - self._k_sensor_level) < abs(z_fit - float(track.state.x[0])):
                    status[name] = "held"
                    continue
                self._k_sensor_level = None
            z = math.log(ev.value)
            self._calibrate(track, t_ns, z, ev)
            r, alone = self._measurement_variance(ev, track.scale, self._repeats(track, t_ns))
            if track.state is None:
                track.state = self._first(track.model, name, z, r, loss, losses)
                track.last_in_ns = t_ns
                track.last_in_own = ev.own_var
                if name in self._banked and loss > 0:  # (losses known to drive them)
                    q = self.config.R_drift_per_min**2 / 60.0
                    models = [Thermal(tau, q) for tau in THERMAL_TAUS_S]
                    track.bank = ThermalBank(
                        [_Candidate(m, self._first(m, name, z, r, loss, losses)) for m in models]
                    )
                status[name] = "ok"
                continue
            row, nu, s = innovation(track.model, track.state, z, r, self._fit_lag(name), losses)
            track.history.append((t_ns, track.state.copy()))
            track.fits.append((t_ns, z, alone))
            outlier = self._outlier(name, nu, s - r + alone)
            gain = None if outlier else track.state.P @ row / s
            # The step test weighs a window as the filter does: the first after a held
            # stretch whole, since the filter takes it whole and moves most of the way to it.
            # Weighed as a tenth there, a step that fell in the held stretch was swallowed by
            # the filter before the test saw it (Ra +3 % behind the thyristor bridges at
            # 2 kHz: 4 of 20 never announced), and a window sharper than the last counts what
            # it adds (_test_variance). Only the resistances: the other fits are more
            # exposed to an operating point's bias, and are tested as a tenth in every
            # window. Counted whole, La windows of one operating point of an ideal 2 kHz
            # recording, 7-10 % off for 1.5 s at stds of 1.4-4 %, raised a false "La rose" in
            # an hour of clean recordings, and a K window after a held stretch a false "K fell
            # 70.7 %" behind a real 5 % step (ideal, 2 kHz).
            s_test = (
                self._test_variance(track, ev, row, t_ns)
                if name[0] == "R"
                else float(
                    row @ track.state.P @ row + self._measurement_variance(ev, track.scale)[0]
                )
            )
            alarm = track.test.observe(t_ns, row, nu, s_test, gain)
            if alarm is not None:
                self._open_transition(name, alarm, t_ns, (t_ns, z, alone), status)
                continue
            if outlier:
                status[name] = "outlier"
                continue
            update(track.state, row, nu, s)
            track.last_in_ns = t_ns
            track.last_in_own = ev.own_var
            if track.bank is not None:
                track.bank.loglik += _loglik(nu, s)
                lag = self._fit_lag(name)
                for c in track.bank.candidates:
                    row_c, nu_c, s_c = innovation(c.model, c.state, z, r, lag, losses)
                    c.loglik += _loglik(nu_c, s_c)
                    update(c.state, row_c, nu_c, s_c)
                self._promote(track)
                news = track.bank.news(name, track.model, track.state)
                if news is not None:
                    step.notes.append(news)
            status[name] = "ok"
        # A change confirmed this window whose level the windows already seen wholly after
        # its onset show (:meth:`_open_transition`) is reported now, not a window later.
        for circuit, tr in list(self.transitions.items()):
            if tr.detected_ns == t_ns:
                self._continue_transition(circuit, t_ns, {}, loss, losses, distrust, step, status)
        k_state = self.tracks["K"].state
        if k_state is not None and status.get("K") == "ok" and "armature" not in self.transitions:
            level = float(k_state.x[0])
            self._k_highest = level if self._k_highest is None else max(self._k_highest, level)
        for name, track in self.tracks.items():
            ev = evidence.get(name)
            if status[name] == "ok" and ev is not None:
                track.shared_var = ev.shared_var
            st = track.state
            value = self.value(name)
            rel = self.rel_std(name)
            std = None if value is None or rel is None else value * rel
            rate = None
            if st is not None and name[0] == "R":
                rate = track.model.rate(st, loss)
                if track.bank is not None:
                    rate = track.bank.rate(rate, loss)
                rate *= 60.0
            step.parameters[name] = TrackedParameter(value, std, status[name], rate, track.scale)
        return step

    @staticmethod
    def _promote(track: _Track) -> None:
        """Where a thermal model of the bank leads (:data:`THERMAL_LEAD`) with a clear rise,
        it becomes the track's own model: the change test runs on it. A level with a rate
        expects a rate that wanders by 5 %/min per minute; a winding heating with a time
        constant of a minute bends faster, and the test took the bends for steps (a 440 V
        motor's heating recording: Rf and Ra "rose" 0.8-1.7 % five times after 80 s). The
        level with a rate stays in the bank, weighed as before."""
        assert track.bank is not None and track.state is not None
        leader, weight = track.bank.leader()
        if leader is None or weight < THERMAL_LEAD or not _heating(leader.model, leader.state):
            return
        leader.model, track.model = track.model, leader.model
        leader.state, track.state = track.state, leader.state
        leader.loglik, track.bank.loglik = track.bank.loglik, leader.loglik
        track.test.reset()
        track.history.clear()  # states of the other model

    def _open_transition(
        self,
        name: str,
        alarm: Alarm,
        t_ns: int,
        shown: tuple[int, float, float] | None,
        status: dict[str, str],
    ) -> None:
        """Freeze ``name``'s circuit on a change the step test confirmed, from ``t_ns``;
        ``shown``: a window (end ns, log fit, variance alone) that counts towards its level."""
        track = self.tracks[name]
        circuit = LOCATION[name][0]
        # Windows ending before the onset hold no sample after the change, and the
        # step test dates it within a hop or two: the state after the windows
        # ending ONSET_MARGIN_HOPS before it is the level before the change.
        clean_ns = alarm.started_ns - int(round(ONSET_MARGIN_HOPS * self.hop_s * 1e9)) + 1
        # What the windows measured before it: the last window's worth of them.
        count = math.ceil(self.overlap)
        fits_before = track.fits_before(clean_ns, clean_ns - track.test.horizon_ns, count)
        clean_ns, before = track.before(clean_ns)
        tr = _Transition(name, alarm, before, t_ns, clean_ns, fits_before=fits_before)
        tr.recent = deque(maxlen=self.settle_windows)
        # Windows already seen wholly after the onset count towards the level: they hold
        # no sample from before it, so they cannot be sliding across it. Waiting for
        # ``settle_windows`` new ones after the alarm cost 0.3 s on every change.
        window_ns = int(round(self.window_s * 1e9))
        for seen in track.fits:
            if seen[0] - window_ns >= alarm.started_ns and seen[0] < t_ns:
                tr.recent.append(seen)
        if shown is not None:
            tr.recent.append(shown)
        self.transitions[circuit] = tr
        # The circuit's other tests go on meanwhile (:meth:`_test_others`): windows
        # across a step of Ra also move K's fits, and K's alarm may come first.
        track.test.reset()
        for other in self._circuit(circuit):
            status[other] = "change"

    def _test_others(
        self,
        tr: _Transition,
        t_ns: int,
        evidence: Mapping[str, Evidence | None],
        distrust: frozenset[str],
        losses: Sequence[tuple[float, float]],
    ) -> None:
        """While a change of ``tr.parameter`` waits for its level, the step tests of
        its circuit's other parameters go on with their frozen states (no update), and
        the first alarm of each is kept: should the change not be borne out, the change
        that made it (a step of Ra seen first in K's fits) is taken up at once instead
        of being tested again from nothing."""
        for name in self._circuit(LOCATION[tr.parameter][0]):
            track = self.tracks[name]
            ev = evidence.get(name)
            if (
                name == tr.parameter or name in distrust or ev is None
                or track.state is None or not self._usable(name, ev)
            ):  # fmt: skip
                continue
            z = math.log(ev.value)
            r, alone = self._measurement_variance(ev, track.scale)
            row, nu, s = innovation(track.model, track.state, z, r, self._fit_lag(name), losses)
            alarm = track.test.observe(t_ns, row, nu, s, None)
            if alarm is not None and name not in tr.pending:
                tr.pending[name] = (alarm, (t_ns, z, alone))

    def _take_pending(self, tr: _Transition, t_ns: int, status: dict[str, str]) -> None:
        """After a change not borne out: open the first change another parameter's test
        confirmed meanwhile (:meth:`_test_others`)."""
        if not tr.pending:
            return
        name, (alarm, _) = next(iter(tr.pending.items()))
        # Its level is shown by the windows from now on (the one that raised the alarm
        # may still have straddled the step).
        self._open_transition(name, alarm, t_ns, None, status)

    def _usable(self, name: str, ev: Evidence) -> bool:
        """A fit with a positive, finite value and a std that is finite, > 0 and within
        the parameter's quality limit (a zero std would claim infinite weight)."""
        limit = self.limits[name]
        return (
            math.isfinite(ev.value) and ev.value > 0 and math.isfinite(ev.rel_std)
            and 0 < ev.rel_std <= limit
        )  # fmt: skip

    def _shows_level(self, tr: _Transition, ev: Evidence) -> bool:
        """Whether a window after a confirmed change counts towards its new level.

        A window within the quality limit does; so does a weaker one that shows
        the step by itself (its fit ``gate_sigma`` of its std or more from the
        level before): after a step the drive may well stop or run steadily,
        and the fits that then separate ``Ra`` from ``K`` are weak but plain.
        """
        if self._usable(tr.parameter, ev):
            return True
        if not (math.isfinite(ev.value) and ev.value > 0 and math.isfinite(ev.rel_std)):
            return False
        if ev.rel_std > WEAK_FACTOR * self.limits[tr.parameter]:
            return False
        shown = abs(math.log(ev.value) - float(tr.before.x[0]))
        return 0 < ev.rel_std * self.config.gate_sigma <= shown

    def _first(
        self,
        model: Model,
        name: str,
        z: float,
        r: float,
        loss: float,
        losses: Sequence[tuple[float, float]],
    ) -> Gaussian:
        """The state from a parameter's first fit.

        The fit stands for a moment before the window's end, and the parameter
        may move meanwhile at a rate not yet known: the level now is the fit
        carried over that lag (an update of a level not known at all).
        """
        state = model.initial(z, r, loss)
        state.P[0, 0] += 1.0
        update(state, *innovation(model, state, z, r, self._fit_lag(name), losses))
        return state

    def _fit_lag(self, name: str) -> float:
        """How long before the window's end its fit of ``name`` stands (s).

        A window's fit of a moving parameter is an average over the samples that
        carry information on it. The estimator frees each segment's initial
        current, so the samples of the first time constant ``L / R`` of the
        circuit settle that transient and say little about ``R``: a resistance
        fit stands for the middle of the rest of the window. (On a field
        winding, ``Lf / Rf`` is a good part of a window: on a field heating
        at 0.1-0.5 %/s, the window fits were on average 1.0 of their std above
        the truth at the window's middle, 0.1 above it there.)
        """
        half = 0.5 * self.window_s
        if name[0] != "R":
            return half
        inductance = self.value("Lf" if name == "Rf" else "La")
        resistance = self.value(name)
        if inductance is None or resistance is None:
            return half
        return 0.5 * (self.window_s - min(self.window_s, inductance / resistance))

    def _repeats(self, track: _Track, t_ns: int) -> float:
        """How many times over the state has already taken in this window's samples
        (at most ``overlap``): the window's length over the time since the last window
        taken in (a window that follows a held stretch of a window or more is new)."""
        if track.last_in_ns is None:
            return self.overlap
        since = (t_ns - track.last_in_ns) / 1e9
        return min(self.overlap, max(1.0, self.window_s / since)) if since > 0 else self.overlap

    def _test_variance(self, track: _Track, ev: Evidence, row: np.ndarray, t_ns: int) -> float:
        """A resistance window's innovation variance for the step test, its own error
        counted once for the samples the last window taken in cannot have held.

        Of a window's information (the inverse of its own variance), at most the last
        window's can be in the samples they share, so at least ``1 - I_last / I_now`` of
        it is new; and at least the share of its samples that are new
        (:meth:`_repeats`). Where the windows' precision is steady that is the
        filter's tenth; where the drive turns informative, the windows that gain most
        over the last weigh most (behind a thyristor bridge at 2 kHz a Ra step's
        windows go from 0.7 % to 0.3 % in four hops, and weighed as a tenth the test
        took 0.7 s to see 3 % at 4-10 sigma each)."""
        assert track.state is not None
        share = 1.0 / self._repeats(track, t_ns)
        if track.last_in_own is not None and ev.own_var > 0.0:
            share = max(share, 1.0 - ev.own_var / track.last_in_own)
        r, _ = self._measurement_variance(ev, track.scale, 1.0 / share)
        return float(row @ track.state.P @ row + r)

    def _measurement_variance(
        self, ev: Evidence, scale: float = 1.0, repeats: float | None = None
    ) -> tuple[float, float]:
        """Variance of a fit as one of overlapping windows (for weighing), and alone.

        Weighed, a window counts as ``1 / repeats`` of an independent one, ``repeats``
        the share of its samples the windows taken in before it already hold
        (:meth:`_repeats`: ``overlap`` in a run of windows; 1 after a held stretch
        of a window or more, where counting the first window back as a tenth of
        one let the state creep after a step for seconds); alone (comparing one
        window with the state) it has its own variance. The step test keeps weighing
        each window as a tenth: counted whole, the La windows of one operating point
        of an ideal recording (2 kHz), 7-10 % off for 1.5 s at stds of 1.4-4 %, raised
        a false change of La (one in an hour of clean recordings); a resistance's test
        counts what a window adds (:meth:`_test_variance`).
        The part of it that is the window's own error (not shared) is calibrated by
        ``scale`` (:meth:`_calibrate`).
        A moving parameter adds nothing here: the observation row already
        places the fit at the window's middle. (Adding the parameter's spread
        over the window as well weighed the precise Rf fits of a heating field
        down until the state lagged the heating by twice the 0.1 % tolerance.)
        """
        own = scale * ev.own_var
        weigh = self.overlap if repeats is None else repeats
        return weigh * own + ev.shared_var, own + ev.shared_var

    def _calibrate(self, track: _Track, t_ns: int, z: float, ev: Evidence) -> None:
        """Learn how far the windows' own errors are from what their stds say.

        A window's std is the estimator's bound on its error, model error included,
        and is wide wherever the model might not hold; whether it does shows in the
        fits themselves. Three windows a window apart share no sample, and the second
        difference of their fits, ``d = z_1 - 2 z_2 + z_3``, holds their own errors
        and nothing of a parameter that moves steadily (a winding heating or cooling:
        a first difference took the heating for error, and the wider windows then
        let the state lag it). ``d^2 / (own_1 + 4 own_2 + own_3)`` is a chi-square of
        one degree of freedom where the stds are honest; the median of the latest
        :data:`CALIBRATION_TRIPLES` of these (robust to a step or a bad window) over the
        chi-square's median is the factor on the windows' own variances. Nothing of
        the tracked state enters (a state that follows the fits would confirm any
        factor). The shared part of a window's std (a bias every window at the same
        operating point has) cancels in such differences, so nothing here can
        confirm it: it is kept as the window says.
        """
        own = ev.own_var
        if not own > 0.0:
            return
        apart_ns = int(round(self.window_s * 1e9))
        middle = [e for e in track.own if apart_ns <= t_ns - e[0] < 2 * apart_ns]
        track.own.append((t_ns, z, own))
        if not middle:
            return
        t_j, z_j, own_j = middle[-1]
        first = [e for e in track.own if apart_ns <= t_j - e[0] < 2 * apart_ns]
        if not first:
            return
        _, z_i, own_i = first[-1]
        d = z - 2.0 * z_j + z_i
        track.ratios.append(d * d / (own + 4.0 * own_j + own_i))
        if len(track.ratios) >= CALIBRATION_MIN_TRIPLES:
            ratio = float(np.median(np.asarray(track.ratios))) / _CHI2_1_MEDIAN
            track.scale = min(max(ratio, CALIBRATION_RANGE[0]), CALIBRATION_RANGE[1])

    def _outlier(self, name: str, nu: float, variance: float) -> bool:
        """Beyond the gate of a window alone, and beyond half the smallest change.

        Innovations below half the smallest change are always taken: the change
        test ignores them, so gating them would leave a tracker that has fallen
        behind stuck there.
        """
        half = 0.5 * math.log1p(self._min_change(name))
        return abs(nu) > half and nu * nu > self.config.gate_sigma**2 * variance

    @staticmethod
    def _circuit(circuit: str) -> list[str]:
        return [p for p in PARAMETERS if LOCATION[p][0] == circuit]

    def _continue_transition(
        self,
        circuit: str,
        t_ns: int,
        evidence: Mapping[str, Evidence | None],
        loss: float,
        losses: Sequence[tuple[float, float]],
        distrust: frozenset[str],
        step: TrackerStep,
        status: dict[str, str],
    ) -> None:
        """Hold the circuit until windows show the new level; then confirm the change or drop it.

        The new level shows in the last windows seen wholly after the onset (with
        evidence, as many as span ``SETTLE_S``; those from before the alarm need not
        be consecutive) that agree within their noise and closer than windows
        sliding across the step would:
        windows across a step describe neither side and slide from one to the
        other, so until then the circuit's parameters are frozen. Fits that keep
        sliding (a parameter the windows no longer identify drifting off) never
        settle: after ``change_wait_s`` the parameter's uncertainty is widened
        instead of a change being reported.
        """
        tr = self.transitions[circuit]
        names = self._circuit(circuit)
        self._test_others(tr, t_ns, evidence, distrust, losses)
        m = math.log1p(self._min_change(tr.parameter))
        ev = evidence.get(tr.parameter)
        if ev is not None and self._shows_level(tr, ev):
            tr.recent.append((t_ns, math.log(ev.value), ev.rel_std**2))
        zs = [z for _, z, _ in tr.recent]
        # The level's windows agreeing within their noise, and closer than windows sliding
        # across the step would be (they move by a share hop/window of it per window).
        settled = False
        if len(zs) == tr.recent.maxlen:
            noise = 3.0 * math.sqrt(max(v for _, _, v in tr.recent))
            size = abs(sum(zs) / len(zs) - float(tr.before.x[0]))
            settled = max(zs) - min(zs) <= min(noise, max(0.5 * m, 0.25 * size))
        if not settled:
            if (t_ns - tr.detected_ns) / 1e9 <= self.config.change_wait_s:
                for name in names:
                    status[name] = "change"
                return
            # No window after the change has shown the parameter: let it re-converge.
            del self.transitions[circuit]
            track = self.tracks[tr.parameter]
            assert track.state is not None
            track.state.P[0, 0] += m**2
            if track.bank is not None:
                track.bank.widen(m**2)
            step.notes.append(
                f"{tr.parameter}: a change was seen but no window after it identified "
                f"{tr.parameter}; its uncertainty is widened instead"
            )
            self._take_pending(tr, t_ns, status)
            return
        del self.transitions[circuit]
        # The settled windows weighed by their precision (a weak one that shows the step
        # must not size it).
        z, alone = _weighed([(zi, v) for _, zi, v in tr.recent])
        first_ns = tr.recent[0][0]
        r = self.overlap * alone
        track = self.tracks[tr.parameter]
        assert track.state is not None
        before = tr.before  # carried to now: the change is the difference of levels now
        gap = (t_ns - tr.before_ns) / 1e9
        if gap > 0:
            track.model.predict(before, gap, loss)
            tr.before_ns = t_ns
        d = z - float(before.x[0])
        var_d = float(before.P[0, 0]) + alone
        beyond_highest = (
            tr.parameter == "K" and self._k_highest is not None
            and z > self._k_highest + 0.5 * m
        )  # fmt: skip
        if d > 0 and (tr.parameter in distrust or beyond_highest):
            # K*if*omega is all the armature equation knows: a speed (or field current)
            # sensor reading low looks like a higher K, which a field does not do.
            step.notes.append(
                f"{tr.parameter} seemed to rise {100 * math.expm1(d):+.1f} % above any level "
                f"tracked: put down to the speed or field current sensor reading low, "
                f"{tr.parameter} kept"
            )
            if tr.parameter == "K":
                self._k_sensor_level = z
            for name in names:
                self.tracks[name].test.reset()
                status[name] = "held"
            return
        # The windows after the "change" measuring what those before it did: it is the
        # tracked state that had moved away from them (a rate taken up from a step never
        # confirmed carries it on), not the motor.
        drift = False
        if tr.fits_before is not None and abs(d) >= 0.5 * m:
            z_fits, var_fits = tr.fits_before
            drift = abs(z - z_fits) < 0.5 * m and d * d >= self.config.gate_sigma**2 * (
                alone + var_fits
            )
        if not drift and abs(d) >= 0.5 * m and d * d < CONFIRM_SIGMA**2 * var_d:
            # Large but not yet sure (a weak window): wait for a better one.
            if (t_ns - tr.detected_ns) / 1e9 <= self.config.change_wait_s:
                self.transitions[circuit] = tr
                for name in names:
                    status[name] = "change"
                return
        if not drift and (abs(d) < 0.5 * m or d * d < CONFIRM_SIGMA**2 * var_d):
            self.counts["changes_not_borne_out"] += 1
            step.notes.append(
                f"{tr.parameter}: a change was signalled but the windows after it differ by "
                f"only {100 * math.expm1(d):+.2f} %; tracking goes on"
            )
            # This window is then used as any other (its status set by the caller), unless
            # another parameter's change is taken up.
            self._take_pending(tr, t_ns, status)
            return
        # From the state before the change (the windows across it may have bent its rate).
        track.state = before.copy()
        track.model.shift(track.state, d, r)
        track.last_in_ns = t_ns
        track.last_in_own = None
        for name in names:
            self.tracks[name].test.reset()
        status[tr.parameter] = "ok"  # the circuit's others take this window as usual
        if drift:
            # Re-start at the windows, quietly, and without the rate that carried it off.
            track.model.forget_rate(track.state)
            self.counts["drift_corrected"] += 1
            step.notes.append(
                f"{tr.parameter}: the tracked value had moved {100 * math.expm1(-d):+.1f} % "
                f"away from what the windows measure, which did not change; re-started "
                f"at them (no change of the motor)"
            )
            return
        self.counts["changes"] += 1
        # Fits from before the step would make triples across it for the calibration: a
        # second difference holding the step, not the windows' error.
        track.own.clear()
        if track.bank is not None:
            track.bank.shift_to(z, r)
        # The first window showing the new level wholly started after the change.
        wholly_after = first_ns - int(round(self.window_s * 1e9))
        step.changes.append(
            ChangeEvent(
                parameter=tr.parameter,
                relative=math.expm1(d),
                relative_std=math.sqrt(var_d) * math.exp(d),
                before=math.exp(float(before.x[0])),
                after=math.exp(z),
                t_change_ns=max(
                    min(tr.alarm.started_ns, wholly_after),
                    wholly_after - int(round(0.5 * self.window_s * 1e9)),
                ),
                t_detected_ns=t_ns,
            )
        )

    def _min_change(self, name: str) -> float:
        c = self.config
        return {"R": c.min_change_R, "L": c.min_change_L, "K": c.min_change_K}[name[0]]


def winding_temperature(
    resistance_ohm: float, rel_std: float, r_ref_ohm: float, alpha_per_k: float, t_ref_c: float
) -> tuple[float, float]:
    """Winding temperature (deg C) and its one-sigma from the resistance.

    ``R = R_ref * (1 + alpha * (T - T_ref))`` (copper: ``alpha = 0.00393 /K`` at 20 deg C).
    """
    temperature = t_ref_c + (resistance_ohm / r_ref_ohm - 1.0) / alpha_per_k
    return temperature, resistance_ohm * rel_std / (r_ref_ohm * alpha_per_k)
