"""Fitting a candidate extension of the plain model on some segments of a recording.

:class:`FitData` holds the recording's arrays as the kernels of
:mod:`observer.diagnosis.kernels` take them; :class:`CandidateModel` maps the
swarm's coordinates (the base parameters in log10, then the effect's) to the
kernels' full parameter vector; :func:`fit_candidate` runs the paper's swarm
and the Levenberg-Marquardt polish on the fit segments of
:func:`split_segments`, the other half held out for scoring.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from observer.diagnosis import kernels as dk
from observer.diagnosis.effects import DataContext, Effect, Parameter
from observer.estimation import CircuitEstimate, EstimationError
from observer.estimation.intersample import MIN_SEGMENT, InputModel, Segments, hold_moments
from observer.estimation.polish import levenberg_marquardt
from observer.estimation.pso import ParticleSwarm


def interval_moments(v: np.ndarray, inp: InputModel | None) -> np.ndarray:
    """The kernels' voltage moments per interval: ``inp``'s, and its gaps filled.

    Intervals outside ``inp``'s segments (a converter's jump, a clipped
    sample) are not simulated over by the fits, only crossed by the eddy
    path's warm-up: they get the interval's mean of its two samples, held.
    Without ``inp`` the voltage is held (the zero-order hold).
    """
    if inp is None or inp.model == "hold":
        return np.ascontiguousarray(hold_moments(v))
    mu = np.array(inp.mu, dtype=np.float64)
    known = np.zeros(mu.shape[0], dtype=bool)
    for s, e in zip(inp.segments.starts, inp.segments.ends, strict=True):
        known[s:e] = True
    gap = ~known
    mu[gap, 0] = 0.5 * (v[:-1][gap] + v[1:][gap])
    mu[gap, 1:] = 0.0
    return np.ascontiguousarray(mu)


def split_by(
    starts: np.ndarray, stops: np.ndarray, known: Segments | None
) -> tuple[np.ndarray, np.ndarray]:
    """The parts of segments ``[starts, stops)`` inside ``known``'s (inclusive) segments.

    The fits restart the simulation, with its own initial current, after every
    interval the intersample model does not know (see
    :mod:`observer.estimation.intersample`); parts shorter than
    :data:`~observer.estimation.intersample.MIN_SEGMENT` samples are dropped.
    """
    if known is None:
        return starts, stops
    ks, ke = known.starts, known.ends + 1
    out_s: list[np.ndarray] = []
    out_e: list[np.ndarray] = []
    for a, b in zip(starts, stops, strict=True):
        lo = int(np.searchsorted(ke, a, side="right"))
        hi = int(np.searchsorted(ks, b, side="left"))
        s_ = np.maximum(ks[lo:hi], a)
        e_ = np.minimum(ke[lo:hi], b)
        keep = e_ - s_ >= MIN_SEGMENT
        out_s.append(s_[keep])
        out_e.append(e_[keep])
    if not out_s:
        return starts[:0], stops[:0]
    return (
        np.ascontiguousarray(np.concatenate(out_s), dtype=np.int64),
        np.ascontiguousarray(np.concatenate(out_e), dtype=np.int64),
    )


class FitData:
    """The recording's arrays, the fixed inputs of the kernels, and residual helpers.

    ``inputs`` are the circuits' intersample models (``"field"``,
    ``"armature"``), as the estimator chose them for the baseline: the
    voltages enter the kernels as their moments, and the simulation restarts
    after every interval a model does not know. Without them the voltages are
    held over each period.
    """

    def __init__(
        self,
        rec: Any,
        base_full: np.ndarray,
        ctx: DataContext,
        inputs: dict[str, InputModel] | None = None,
    ) -> None:
        self.dt = rec.dt
        self.n = rec.n_samples
        self.va = np.ascontiguousarray(rec["va"], dtype=np.float64)
        self.ia = np.ascontiguousarray(rec["ia"], dtype=np.float64)
        self.vf = np.ascontiguousarray(rec["vf"], dtype=np.float64)
        self.i_f = np.ascontiguousarray(rec["if"], dtype=np.float64)
        self.omega = np.ascontiguousarray(rec["omega"], dtype=np.float64)
        inputs = inputs or {}
        self.inputs = inputs
        self.mu_f = interval_moments(self.vf, inputs.get("field"))
        self.mu_a = interval_moments(self.va, inputs.get("armature"))
        self.held_f = "field" not in inputs or inputs["field"].model == "hold"
        self.held_a = "armature" not in inputs or inputs["armature"].model == "hold"
        self.emf_slope = not self.held_a
        self._known = {
            c: (inp.segments if inp.segments.covered < self.n else None)
            for c, inp in inputs.items()
        }
        self._split_cache: dict[tuple[str, bytes, bytes], tuple[np.ndarray, np.ndarray]] = {}
        self.loss = base_full[dk.I_RA] * self.ia**2 + base_full[dk.I_RF] * self.i_f**2
        self.brush_width_a = 0.01 * ctx.ia_peak_a
        self._theta = np.empty(self.n)
        #: Variance (V^2) of white noise on the armature's input voltage, whose
        #: expected share of the cost is subtracted (errors-in-variables).
        self.va_noise_var = 0.0

    def split(
        self, circuit: str, starts: np.ndarray, stops: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``circuit``'s simulated parts of the segments ``[starts, stops)`` (cached)."""
        known = self._known.get(circuit)
        if known is None:
            return starts, stops
        key = (circuit, starts.tobytes(), stops.tobytes())
        parts = self._split_cache.get(key)
        if parts is None:
            parts = split_by(starts, stops, known)
            self._split_cache[key] = parts
        return parts

    @property
    def whole_record(self) -> tuple[np.ndarray, np.ndarray]:
        """``(starts, stops)`` of one segment over every sample."""
        return np.array([0]), np.array([self.n])

    def input_noise_energy(
        self, full: np.ndarray, starts: np.ndarray, stops: np.ndarray
    ) -> np.ndarray:
        """Expected armature SSE from unit input-voltage noise, per row of ``full`` (A^2/V^2)."""
        full = np.atleast_2d(full)
        starts, stops = self.split("armature", starts, stops)
        a = np.exp(-full[:, dk.I_RA] * self.dt / full[:, dk.I_LA])
        b = (1.0 - a) / full[:, dk.I_RA]
        out = np.zeros(full.shape[0])
        for length in stops - starts:
            out += b * b / (1.0 - a * a) * (length - (1.0 - a ** (2 * length)) / (1.0 - a * a))
        return out

    def residuals(
        self, full: np.ndarray, starts: np.ndarray, stops: np.ndarray, k_fixed: float = math.nan
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """Field and armature residual (A) at every sample (NaN outside the segments) and K."""
        rf = np.full(self.n, np.nan)
        ra = np.full(self.n, np.nan)
        fs, fe = self.split("field", starts, stops)
        dk.field_residual(
            full, self.mu_f, self.i_f, self.loss, fs, fe, self.dt, self._theta, rf, self.held_f
        )
        as_, ae = self.split("armature", starts, stops)
        _, k = dk.armature_residual(
            full, self.mu_a, self.ia, self.i_f, self.omega, self.loss, as_, ae, self.dt,
            self.brush_width_a, k_fixed, self._theta, ra, self.emf_slope, self.held_a,
        )  # fmt: skip
        return rf, ra, float(k)

    def swarm_cost(
        self,
        full: np.ndarray,
        starts: np.ndarray,
        stops: np.ndarray,
        weights: dict[str, float],
    ) -> np.ndarray:
        out = np.zeros(full.shape[0])
        if "field" in weights:
            fs, fe = self.split("field", starts, stops)
            out += weights["field"] * dk.field_swarm_costs(
                full, self.mu_f, self.i_f, self.loss, fs, fe, self.dt, self.held_f
            )
        if "armature" in weights:
            as_, ae = self.split("armature", starts, stops)
            sse = dk.armature_swarm_costs(
                full, self.mu_a, self.ia, self.i_f, self.omega, self.loss, as_, ae, self.dt,
                self.brush_width_a, self.emf_slope, self.held_a,
            )  # fmt: skip
            if self.va_noise_var > 0:
                sse -= self.va_noise_var * self.input_noise_energy(full, starts, stops)
            out += weights["armature"] * sse
        return out


@dataclass(frozen=True)
class Fit:
    full: np.ndarray
    k: float
    x: np.ndarray
    cost: float


class CandidateModel:
    """The PSO coordinates of one candidate: base parameters in log10, then the effect's."""

    def __init__(
        self,
        effect: Effect | None,
        ctx: DataContext,
        base_full: np.ndarray,
        *,
        warm_effect: bool = False,
    ) -> None:
        self.effect = effect
        self.ctx = ctx
        self.circuits = effect.circuits if effect is not None else ("field", "armature")
        self.params: tuple[Parameter, ...] = effect.parameters(ctx) if effect is not None else ()
        self.base_full = base_full
        base_idx: list[int] = []
        if "field" in self.circuits:
            base_idx += [dk.I_RF, dk.I_LF]
        if "armature" in self.circuits:
            base_idx += [dk.I_RA, dk.I_LA]
        self.base_idx = base_idx
        self.effect_idx = [dk.FULL_PARAMS.index(p.name) for p in self.params]
        lo, hi, x0 = [], [], []
        for i in base_idx:
            v = math.log10(base_full[i])
            lo.append(v - 0.2)
            hi.append(v + 0.2)
            x0.append(v)
        for p in self.params:
            # Warm: start the effect's parameters where base_full has them (a
            # pair starts from its members' fits); else at the neutral value.
            start = base_full[dk.FULL_PARAMS.index(p.name)] if warm_effect else p.neutral
            start = min(max(start, p.low), p.high)
            if p.log:
                lo.append(math.log10(p.low))
                hi.append(math.log10(p.high))
                x0.append(math.log10(start))
            else:
                lo.append(p.low)
                hi.append(p.high)
                x0.append(start)
        self.lower = np.array(lo)
        self.upper = np.array(hi)
        self.x0 = np.array(x0)

    @property
    def n_params(self) -> int:
        return len(self.params)

    def to_full(self, x: np.ndarray) -> np.ndarray:
        """``(n, d)`` PSO positions -> ``(n, N_FULL)`` physical vectors."""
        x = np.atleast_2d(x)
        x = np.clip(x, self.lower, self.upper)
        full = np.tile(self.base_full, (x.shape[0], 1))
        nb = len(self.base_idx)
        for j, i in enumerate(self.base_idx):
            full[:, i] = 10.0 ** x[:, j]
        for j, (i, p) in enumerate(zip(self.effect_idx, self.params, strict=True)):
            v = x[:, nb + j]
            full[:, i] = 10.0**v if p.log else v
        return np.ascontiguousarray(full)

    def init_bounds(self) -> np.ndarray:
        lo, hi = self.lower.copy(), self.upper.copy()
        nb = len(self.base_idx)
        lo[:nb] = self.x0[:nb] - 0.01
        hi[:nb] = self.x0[:nb] + 0.01
        return np.column_stack([lo, hi])


def fit_candidate(
    model: CandidateModel,
    data: FitData,
    starts: np.ndarray,
    stops: np.ndarray,
    weights: dict[str, float],
    *,
    n_particles: int,
    iterations: int,
    rng: np.random.Generator,
    polish: bool = True,
) -> Fit:
    w = {c: weights[c] for c in model.circuits}

    def cost(x: np.ndarray) -> np.ndarray:
        return data.swarm_cost(model.to_full(x), starts, stops, w)

    swarm = ParticleSwarm(
        cost, np.column_stack([model.lower, model.upper]), n_particles=n_particles,
        x0=model.x0, init_bounds=model.init_bounds(), rng=rng, v_max=0.3,
    )  # fmt: skip
    res = swarm.run(iterations)
    x = res.x
    mask = np.zeros(data.n, dtype=bool)
    for a, b in zip(starts, stops, strict=True):
        mask[a:b] = True
    scale = {c: math.sqrt(v) for c, v in w.items()}

    compensate = "armature" in scale and data.va_noise_var > 0
    # Errors-in-variables compensation in least-squares form: the subtracted
    # expected noise share becomes one more residual sqrt(C - s2*E(theta)).
    c_comp = (
        2.0 * data.va_noise_var * float(data.input_noise_energy(model.to_full(x), starts, stops)[0])
    )

    def residual(theta: np.ndarray) -> np.ndarray:
        full = model.to_full(theta)[0]
        rf, ra, _ = data.residuals(full, starts, stops)
        parts = []
        # Samples the intersample model restarts at are NaN: no residual there.
        if "field" in scale:
            parts.append(scale["field"] * np.nan_to_num(rf[mask]))
        if "armature" in scale:
            parts.append(scale["armature"] * np.nan_to_num(ra[mask]))
        if compensate:
            e = data.va_noise_var * float(data.input_noise_energy(full, starts, stops)[0])
            parts.append(np.array([scale["armature"] * math.sqrt(max(c_comp - e, 0.0))]))
        return np.concatenate(parts)

    if polish:
        x, r, _ = levenberg_marquardt(residual, x.copy(), max_iterations=40)
        x = np.clip(x, model.lower, model.upper)
    full = model.to_full(x)[0]
    rf, ra, k = data.residuals(full, starts, stops)
    c = 0.0
    if "field" in w:
        c += w["field"] * float(np.nansum(rf**2))
    if "armature" in w:
        c += w["armature"] * float(np.nansum(ra**2))
    return Fit(full, k, x, c)


def segment_sse(r: np.ndarray, starts: np.ndarray, stops: np.ndarray) -> np.ndarray:
    """Per segment, the sum of squared residuals over its simulated samples."""
    return np.array([float(np.nansum(r[a:b] ** 2)) for a, b in zip(starts, stops, strict=True)])


def split_segments(n: int, dt: float, max_fit_samples: int) -> tuple[np.ndarray, ...]:
    duration = n * dt
    seg_len = int(round(min(max(duration / 40.0, 0.2), 0.5) / dt))
    seg_len = max(seg_len, 20)
    starts = np.arange(0, n - seg_len // 2, seg_len)
    if starts.size < 4:  # before stops[-1]: a recording shorter than half a segment has none
        raise EstimationError(
            f"recording too short for a diagnosis: {duration:.3g} s, need at least "
            f"{4 * seg_len * dt:.3g} s (four segments to fit and hold out)"
        )
    stops = np.minimum(starts + seg_len, n)
    stops[-1] = n
    fit = np.arange(starts.size) % 2 == 0
    n_fit = int(np.sum(stops[fit] - starts[fit]))
    if n_fit > max_fit_samples:
        idx = np.flatnonzero(fit)
        keep = idx[
            np.round(np.linspace(0, idx.size - 1, max(2, max_fit_samples // seg_len))).astype(int)
        ]
        fit[:] = False
        fit[np.unique(keep)] = True
    hold = ~fit
    return starts[fit], stops[fit], starts[hold], stops[hold]


def baseline_full_vector(field_est: CircuitEstimate, arm_est: CircuitEstimate) -> np.ndarray:
    full = np.zeros(dk.N_FULL)
    full[dk.I_RF] = field_est.resistance_ohm
    full[dk.I_LF] = field_est.inductance_h
    full[dk.I_RA] = arm_est.resistance_ohm
    full[dk.I_LA] = arm_est.inductance_h
    full[dk.I_TTH] = 1.0
    full[dk.I_TE] = 1.0
    return full
