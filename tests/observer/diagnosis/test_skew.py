"""The current channels' delay against the voltages, either way round (``sampling_skew``).

A multiplexed ADC reads its channels one after another, in either order: a current read
behind its voltage is a positive delay, one read after it a negative one. The ideal drive's
voltage is held over each period, so the delay the kernels fit is the one made. Which sign the
diagnosis tries is the baseline's relative delay's (``DataContext.current_read_after``).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from observer.diagnosis import kernels as dk
from observer.diagnosis.diagnose import fit_baseline
from observer.diagnosis.effects import LIBRARY
from observer.diagnosis.fitting import CandidateModel, fit_candidate
from observer.estimation.motor import P12
from observer.simulation.effects_sim import delayed
from observer.simulation.simulate import simulate


def _read(delay_samples: float):
    """The P-12 at 2 kHz, its currents read ``delay_samples`` behind the voltages."""
    rec = simulate(P12, duration_s=3.0, sample_rate_hz=2000.0, seed=2, noise=1e-4)
    signals = dict(rec.signals)
    for name in ("ia", "if"):
        signals[name] = delayed(np.asarray(rec[name]), delay_samples)
    return dataclasses.replace(rec, signals=signals)


@pytest.mark.parametrize("made", [-0.5, -1.4, 0.5])
def test_the_delay_is_fitted_with_its_sign(made):
    rec = _read(made)
    baseline = fit_baseline(rec, n_particles=30, iterations=30, seed=0)
    # The sign is the baseline's relative delay's (a held voltage, as here, fits none): told.
    ctx = dataclasses.replace(baseline.context, current_read_after=made < 0)
    model = CandidateModel(LIBRARY["sampling_skew"], ctx, baseline.full)
    fit = fit_candidate(
        model, baseline.data, *baseline.data.whole_record, {"field": 1.0, "armature": 1.0},
        n_particles=24, iterations=30, rng=np.random.default_rng(0),
    )  # fmt: skip
    assert fit.full[dk.I_SKEW] / rec.dt == pytest.approx(made, abs=0.1)
    _, ra, _ = baseline.data.residuals(fit.full, *baseline.data.whole_record)
    assert np.sqrt(np.nanmean(ra**2)) < 0.85 * baseline.rms["armature"]


def test_a_negative_delay_answers_every_sample_but_the_records_last():
    rec = _read(-0.5)
    baseline = fit_baseline(rec, n_particles=30, iterations=30, seed=0)
    full = baseline.full.copy()
    full[dk.I_SKEW] = -1.5 * rec.dt
    starts, stops = np.array([0, 2000]), np.array([1500, rec.n_samples])
    rf, ra, _ = baseline.data.residuals(full, starts, stops)
    cost = baseline.data.swarm_cost(full[None, :], starts, stops, {"field": 1.0, "armature": 1.0})
    assert np.isfinite(cost).all()
    # Inside the record every segment sample is answered; the last two samples (the model's
    # state 1.5 periods later does not exist) carry no residual.
    assert np.isfinite(ra[:1500]).all() and np.isnan(ra[1500:2000]).all()
    assert np.isfinite(rf[2000:]).all()
    assert (ra[-2:] == 0.0).all() and (ra[-3] != 0.0)


def test_the_sign_tried_is_the_one_the_baseline_s_delay_shows():
    rec = _read(0.0)
    ctx = fit_baseline(rec, n_particles=30, iterations=30, seed=0).context
    assert not ctx.current_read_after  # a held voltage: no relative delay fitted
    lag = LIBRARY["sampling_skew"].parameters(ctx)[0]
    lead = LIBRARY["sampling_skew"].parameters(dataclasses.replace(ctx, current_read_after=True))[0]
    assert lag.low == 0.0 < lag.high and lead.low < 0.0 == lead.high
