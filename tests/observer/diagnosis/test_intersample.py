"""The diagnosis sees the voltage between samples as the estimator does (issue 10, section 4).

The recording is made here: a winding voltage with ripple between the samples
(a converter's, band-limited), the currents integrated on a fine grid and then
sampled. On an intersample model the diagnosis kernels' residual is the
estimator's own, and not the zero-order hold's.
"""

from __future__ import annotations

import numpy as np

from observer.diagnosis.diagnose import fit_baseline
from observer.diagnosis.fitting import FitData, split_by
from observer.estimation.armature import armature_problem
from observer.estimation.intersample import Segments
from observer.estimation.motor import P12
from observer.estimation.problem import make_problem
from observer.recording import Recording
from observer.simulation.simulate import simulate

RATE_HZ = 2000.0
SUB = 32


def _first_order(v_fine: np.ndarray, emf_fine: np.ndarray, r: float, ell: float, h: float):
    a = np.exp(-r * h / ell)
    b = (1 - a) / r
    i = np.empty(v_fine.size)
    x = 0.0
    for k in range(v_fine.size):
        i[k] = x
        x = a * x + b * (v_fine[k] - emf_fine[k])
    return i


def _ripple_recording(seed: int = 3) -> Recording:
    """P-12's slow signals from the simulator; voltages with intersample ripple, currents exact."""
    base = simulate(P12, duration_s=2.0, sample_rate_hz=RATE_HZ, seed=seed, noise=0.0)
    n = base.n_samples
    dt = base.dt
    h = dt / SUB
    t_f = np.arange(n * SUB) * h
    tb = base.t - base.t[0]
    ripple = 0.15 * np.sin(2 * np.pi * 300.0 * t_f) + 0.08 * np.sin(2 * np.pi * 610.0 * t_f + 1)
    i_f = np.interp(t_f, tb, base["if"])
    omega = np.interp(t_f, tb, base["omega"])
    # Band-limited voltages: a slow excitation, and the ripple between samples.
    slow = np.sin(2 * np.pi * 3.0 * t_f) + 0.5 * np.sin(2 * np.pi * 17.0 * t_f)
    va_f = (np.max(np.abs(base["va"])) * 0.5 * slow) * (1 + ripple) + 5.0 * ripple
    vf_f = np.mean(base["vf"]) * (1 + 0.2 * slow) * (1 + 0.5 * ripple)
    m = P12
    ia = _first_order(va_f, m.emf_constant_h * i_f * omega, m.armature_resistance_ohm,
                      m.armature_inductance_h, h)  # fmt: skip
    iff = _first_order(vf_f, 0 * vf_f, m.field_resistance_ohm, m.field_inductance_h, h)
    rng = np.random.default_rng(seed)
    noise = 1e-4

    def sample(x: np.ndarray) -> np.ndarray:
        return x[::SUB] + noise * np.max(np.abs(x)) * rng.standard_normal(n)

    return Recording(
        base.t,
        {"va": sample(va_f), "ia": sample(ia), "vf": sample(vf_f), "if": sample(iff),
         "omega": omega[::SUB].copy()},
    )  # fmt: skip


def test_the_kernels_on_a_smooth_voltage_are_the_estimators_model():
    rec = _ripple_recording()
    base = fit_baseline(rec, n_particles=30, iterations=30, seed=0)
    arm = base.armature
    prob = armature_problem(
        rec["va"], rec["ia"], rec["if"], rec["omega"], rec.dt, intersample="smooth",
        fit_shift=False, shift=0.2,
    )  # fmt: skip
    field = make_problem(rec["vf"], rec["if"], rec.dt, "smooth", fit_shift=False)
    data = FitData(rec, base.full, base.context, {"field": field.inp, "armature": prob.inp})
    _, ra, k = data.residuals(base.full, *data.whole_record)
    r_est, _ = prob.evaluate(arm.resistance_ohm, arm.inductance_h, k, 0.2)
    r_diag = ra[prob.segments.mask()]
    rms = float(np.sqrt(np.mean(r_est**2)))
    # Same voltage between samples (the EMF: linear here, cubic there).
    agree = float(np.sqrt(np.mean((r_diag - r_est) ** 2)))
    assert agree < 0.05 * rms
    # ... and not the zero-order hold's.
    held = FitData(rec, base.full, base.context)
    _, ra_hold, _ = held.residuals(base.full, *held.whole_record)
    assert np.sqrt(np.mean((ra_hold - ra) ** 2)) > 10 * agree


def test_segments_are_split_where_the_intersample_model_restarts():
    known = Segments(np.array([0, 10, 40]), np.array([7, 30, 99]), 100)
    s, e = split_by(np.array([0, 50]), np.array([50, 100]), known)
    assert s.tolist() == [0, 10, 40, 50] and e.tolist() == [8, 31, 50, 100]
    s, e = split_by(np.array([0]), np.array([100]), None)
    assert s.tolist() == [0] and e.tolist() == [100]
