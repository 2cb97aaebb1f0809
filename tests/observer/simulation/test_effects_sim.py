"""Simulated effects: magnitudes, metadata, and the physics each one adds."""

from __future__ import annotations

import numpy as np
import pytest

from observer.estimation.motor import P12
from observer.simulation.effects_sim import (
    DEFAULT_MAGNITUDES,
    delayed,
    parse_effects,
    plant_effects,
)
from observer.simulation.simulate import simulate


def test_parse_effects():
    assert parse_effects("brush_drop") == {"brush_drop": DEFAULT_MAGNITUDES["brush_drop"]}
    assert parse_effects("brush_drop=1.5, thermal_drift=0.2") == {
        "brush_drop": 1.5,
        "thermal_drift": 0.2,
    }
    with pytest.raises(ValueError, match="unknown effect 'x'"):
        parse_effects("x")
    with pytest.raises(ValueError, match="not a number"):
        parse_effects("brush_drop=a")
    with pytest.raises(ValueError, match=">= 0"):
        parse_effects("brush_drop=-1")


def test_plain_simulation_is_unchanged_and_effects_are_recorded():
    plain = simulate(P12, duration_s=1.0, seed=3)
    again = simulate(P12, duration_s=1.0, seed=3, effects=None)
    np.testing.assert_array_equal(plain["ia"], again["ia"])
    assert "effects" not in plain.metadata
    # A zero-magnitude effect goes through the effects plant: same physics.
    zero = simulate(P12, duration_s=1.0, seed=3, effects={"brush_drop": 0.0})
    np.testing.assert_allclose(zero["ia"], plain["ia"], atol=1e-6 * P12.rated_armature_current_a)
    fx = simulate(P12, duration_s=1.0, seed=3, effects={"sensor_offset": 0.01})
    assert fx.metadata["effects"]["physical"]["ia_offset_a"] == pytest.approx(0.03)


def test_sensor_effects_act_on_the_recorded_signals_only():
    clean = simulate(P12, duration_s=2.0, seed=4, noise=0.0)
    offset = simulate(P12, duration_s=2.0, seed=4, noise=0.0, effects={"sensor_offset": 0.01})
    np.testing.assert_allclose(offset["ia"] - clean["ia"], 0.03, atol=1e-9)
    np.testing.assert_array_equal(offset["va"], clean["va"])
    skew = simulate(P12, duration_s=2.0, seed=4, noise=0.0, effects={"sampling_skew": 1.0})
    np.testing.assert_allclose(skew["ia"][1:], clean["ia"][:-1], atol=1e-12)
    x = np.arange(10.0) ** 3
    np.testing.assert_allclose(delayed(x, 0.5)[2:-2], (np.arange(2, 8) - 0.5) ** 3, rtol=1e-12)


def test_thermal_drift_raises_the_resistance_over_the_recording():
    rec = simulate(P12, duration_s=6.0, seed=2, noise=0.0, effects={"thermal_drift": 0.3})
    fx = plant_effects(P12, {"thermal_drift": 0.3}, rec.dt)
    assert rec.metadata["effects"]["physical"]["thermal_rise_per_w"] == fx.thermal_rise_per_w
    # In steady field operation if = vf / Rf(t): the field current falls as it heats.
    early, late = slice(2000, 2600), slice(-2600, -2000)
    r_early = np.mean(rec["vf"][early]) / np.mean(rec["if"][early])
    r_late = np.mean(rec["vf"][late]) / np.mean(rec["if"][late])
    assert r_late > r_early * 1.005


def test_brush_drop_shows_in_the_steady_armature_balance():
    with_drop = simulate(P12, duration_s=4.0, seed=6, noise=0.0, effects={"brush_drop": 2.0})
    va, ia = with_drop["va"], with_drop["ia"]
    emf = P12.emf_constant_h * with_drop["if"] * with_drop["omega"]
    steady = np.abs(np.gradient(ia)) < 1e-4
    steady &= np.abs(ia) > 0.5
    drop = va[steady] - P12.armature_resistance_ohm * ia[steady] - emf[steady]
    np.testing.assert_allclose(drop, 2.0 * np.sign(ia[steady]), atol=0.1)


def test_parse_changes():
    from observer.simulation.effects_sim import Change, parse_changes

    assert parse_changes("Ra=+0.03@30, tach=-0.1@40") == (
        Change("Ra", 0.03, 30.0),
        Change("tach", -0.1, 40.0),
    )
    with pytest.raises(ValueError, match="unknown change target 'x'"):
        parse_changes("x=0.1@2")
    with pytest.raises(ValueError, match="TARGET=RELATIVE@SECONDS"):
        parse_changes("Ra=0.03")
    with pytest.raises(ValueError, match="> -1"):
        parse_changes("K=-1@3")


def test_a_step_of_ra_and_a_tachometer_losing_its_reading_act_from_their_time():
    from observer.simulation.effects_sim import Change
    from observer.simulation.simulate import true_parameters

    changes = (Change("Ra", 0.03, 1.0), Change("tach", -0.1, 2.0))
    rec = simulate(P12, duration_s=3.0, seed=6, noise=0.0, changes=changes)
    plain = simulate(P12, duration_s=3.0, seed=6, noise=0.0, effects={"brush_drop": 0.0})
    n1, n2 = int(1.0 / rec.dt), int(2.0 / rec.dt)
    np.testing.assert_allclose(rec["ia"][: n1 + 1], plain["ia"][: n1 + 1], rtol=1e-9, atol=1e-12)
    # After the step the armature balance holds with the higher Ra.
    va, ia, emf = rec["va"], rec["ia"], P12.emf_constant_h * rec["if"] * rec["omega"]
    k = np.arange(n1 + 10, n2 - 10)
    steady = k[np.abs(ia[k + 1] - ia[k]) < 1e-5]
    steady = steady[np.abs(ia[steady]) > 0.5]
    ra = (va[steady] - emf[steady]) / ia[steady]
    np.testing.assert_allclose(ra, 3.5 * 1.03, rtol=2e-3)
    # The tachometer reads 10 % low from 2 s: the measured speed, not the plant's.
    truth = true_parameters(rec.metadata, rec.t)
    assert truth["tach"][n2 - 1] == 1.0 and truth["tach"][n2 + 1] == pytest.approx(0.9)
    assert truth["Ra"][n1 + 1] == pytest.approx(3.5 * 1.03) and truth["Ra"][0] == 3.5
    assert rec.metadata["changes"][1] == {"target": "tach", "relative": -0.1, "t_s": 2.0}


def test_thermal_truth_is_recorded_with_its_time_constant():
    from observer.simulation.simulate import true_parameters

    fast = simulate(P12, duration_s=6.0, seed=2, noise=0.0, effects={"thermal_drift": 0.3},
                    thermal_time_constant_s=5.0)  # fmt: skip
    slow = simulate(P12, duration_s=6.0, seed=2, noise=0.0, effects={"thermal_drift": 0.3},
                    thermal_time_constant_s=60.0)  # fmt: skip
    t = np.array([0.0, 3.0, 5.9])
    rise_fast = true_parameters(fast.metadata, t)["theta"]
    rise_slow = true_parameters(slow.metadata, t)["theta"]
    assert rise_fast[0] == 0.0 and rise_fast[-1] > 3 * rise_slow[-1] > 0
    truth = true_parameters(fast.metadata, t)
    np.testing.assert_allclose(truth["Rf"], 185.0 * (1 + rise_fast))
    # In steady field operation if = vf / Rf(t): the recorded rise is the plant's.
    late = slice(-300, -100)
    r_late = np.mean(fast["vf"][late]) / np.mean(fast["if"][late])
    theta = true_parameters(fast.metadata, fast.t[late])["theta"].mean()
    assert r_late == pytest.approx(185.0 * (1 + theta), rel=2e-3)


def _rise_from_currents(ia, i_f, dt, k, tau, *, hot):
    """theta per sample by tau*dtheta/dt = k*P - theta, P at the hot or the cold resistances."""
    cold = P12.armature_resistance_ohm * ia**2 + P12.field_resistance_ohm * i_f**2
    theta = np.zeros(ia.size)
    for n in range(1, ia.size):
        th = theta[n - 1]
        loss = 0.5 * (cold[n - 1] + cold[n]) * ((1.0 + th) if hot else 1.0)
        theta[n] = th + dt * (k * loss - th) / tau
    return theta


def test_the_windings_heat_by_the_loss_at_their_hot_resistances():
    fx = {"thermal_drift": 0.3}
    rec = simulate(P12, duration_s=6.0, seed=2, noise=0.0, effects=fx, thermal_time_constant_s=5.0)
    k = rec.metadata["effects"]["physical"]["thermal_rise_per_w"]
    at = np.searchsorted(rec.t, rec.metadata["thermal"]["t_s"])
    true = np.asarray(rec.metadata["thermal"]["theta"])
    hot = _rise_from_currents(rec["ia"], rec["if"], rec.dt, k, 5.0, hot=True)[at]
    cold = _rise_from_currents(rec["ia"], rec["if"], rec.dt, k, 5.0, hot=False)[at]
    late = rec.t[at] > 1.0
    assert true[-1] > 0.02
    np.testing.assert_allclose(true[late], hot[late], rtol=2e-3)
    # The cold loss would fall short by about the rise itself.
    assert np.max(np.abs(cold[late] / true[late] - 1.0)) > 0.01
    # The magnitude is the steady rise at rated currents, the loss growing with it.
    rated = (
        P12.armature_resistance_ohm * P12.rated_armature_current_a**2
        + P12.field_resistance_ohm * P12.rated_field_current_a**2
    )
    assert k * rated * 1.3 == pytest.approx(0.3)


def test_effects_outside_the_library_need_no_converter_and_say_so():
    from observer.simulation.converter import ConverterSpec, DriveSpec
    from observer.simulation.converter_drive import simulate_converter
    from observer.simulation.effects_sim import EMF_RIPPLE_PER_REV, OUTSIDE_LIBRARY

    assert parse_effects("emf_ripple,tacho_error=0.02") == {
        "emf_ripple": DEFAULT_MAGNITUDES["emf_ripple"],
        "tacho_error": 0.02,
    }
    rec = simulate(P12, duration_s=1.0, seed=3, effects={"emf_ripple": 0.03})
    meta = rec.metadata["effects"]
    assert meta["outside_library"] == ["emf_ripple"] and set(OUTSIDE_LIBRARY) >= {"emf_ripple"}
    assert meta["physical"]["emf_ripple"] == 0.03
    assert rec.metadata["converter"]["armature"]["kind"] == "ideal"
    # the back-EMF carries the ripple, periodic in shaft angle
    fx = {"emf_ripple": 0.05, "tacho_error": 0.04}
    drive = DriveSpec(ConverterSpec(armature="ideal", field="ideal"))
    rec, truth = simulate_converter(
        P12, drive, duration_s=3.0, sample_rate_hz=2000.0, noise=0.0, seed=2, effects=fx,
        want_truth=True,
    )  # fmt: skip
    assert truth is not None
    plain_emf = P12.emf_constant_h * truth.i_f * truth.omega
    moving = np.abs(truth.omega) > 10
    np.testing.assert_allclose(
        truth.emf[moving] / plain_emf[moving] - 1,
        0.05 * np.cos(EMF_RIPPLE_PER_REV * truth.angle[moving]),
        atol=1e-12,
    )
    # the recorded speed reads low in proportion to the armature current
    expected = truth.omega * (1 - 0.04 * np.abs(truth.ia) / P12.rated_armature_current_a)
    np.testing.assert_allclose(rec["omega"], expected, rtol=1e-12, atol=1e-12)
    assert np.max(np.abs(rec["omega"] - truth.omega)) > 0.01 * P12.rated_speed_rad_s
