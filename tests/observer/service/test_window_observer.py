"""Sliding-window observer on simulated drives: convergence, held values, determinism, faults."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from drivers.base import SampleBlock
from observer.config import ObserverConfig, QualityConfig, SpeedConfig, TrackerConfig
from observer.estimation.motor import P12
from observer.service.ringbuffer import RingBuffer
from observer.service.window_observer import SlidingWindowObserver, check_window
from observer.simulation.effects_sim import Change
from observer.simulation.simulate import simulate

REPO = Path(__file__).resolve().parents[3]

FAST = dict(
    window_s=1.0, hop_s=0.5, cold_particles=30, cold_iterations=20,
    warm_particles=16, warm_iterations=12, buffer_s=4.0,
    # The ideal simulator's 1 s windows pin La to ~5 %: accept it at 10 %.
    quality=QualityConfig(L=0.10),
    # The winding temperatures need the resistances at 20 C: the simulated P-12's.
    tracker=TrackerConfig(
        field_r_ref_ohm=P12.field_resistance_ohm, armature_r_ref_ohm=P12.armature_resistance_ohm
    ),
)  # fmt: skip


def _blocks(rec, block_s=0.1, start_ns=0):
    t_ns = np.rint(rec.t * 1e9).astype(np.int64) + start_ns
    n = int(round(block_s / rec.dt))
    for i in range(0, rec.n_samples, n):
        yield SampleBlock(t_ns[i : i + n], {c: rec.signals[c][i : i + n] for c in rec.channels})


def _run(blocks, **cfg):
    config = ObserverConfig(**{**FAST, **cfg})
    ring = RingBuffer(20_000)
    obs = SlidingWindowObserver(ring, config)
    results = []
    for b in blocks:
        ring.write(b)
        results += obs.process_ready()
    obs.close()  # (an untold filter's identification still under way is dropped)
    return obs, results


@pytest.fixture(scope="module")
def p12_run(p12_recording):
    return _run(_blocks(p12_recording))


def test_estimates_converge_to_the_motor(p12_run):
    obs, results = p12_run
    estimates = [r.estimate for r in results if r.estimate is not None]
    assert len(estimates) == len(results) >= 20  # 12 s, 1 s windows, 0.5 s hop: 23 windows
    last = estimates[-1]
    assert last["armature"]["R"] == pytest.approx(P12.armature_resistance_ohm, rel=0.02)
    assert last["armature"]["K"] == pytest.approx(P12.emf_constant_h, rel=0.02)
    assert last["armature"]["L"] == pytest.approx(P12.armature_inductance_h, rel=0.15)
    assert last["field"]["R"] == pytest.approx(P12.field_resistance_ohm, rel=0.01)
    assert last["field"]["L"] == pytest.approx(P12.field_inductance_h, rel=0.05)
    # Warm start kicks in and shrinks the range after the first window.
    assert not estimates[0]["armature"]["warm"]
    assert any(e["armature"]["warm"] for e in estimates[1:])
    # Once the fits have agreed long enough the windows are settled: polished from the
    # tracked state, without a swarm (one cost evaluation).
    assert any(e["armature"]["evaluations"] == 1 for e in estimates[10:])
    assert any(e["field"]["evaluations"] == 1 for e in estimates[10:])
    assert estimates[0]["window"] == [0, 1_000_000_000]
    assert [r.index for r in results] == list(range(len(results)))


def test_same_seed_same_numbers_other_seed_other_numbers(p12_recording, p12_run):
    _, first = p12_run
    _, again = _run(_blocks(p12_recording, block_s=0.037))  # other block sizes, same windows
    assert all(_same(a.estimate, b.estimate) for a, b in zip(again, first, strict=True))
    _, other = _run(_blocks(p12_recording), seed=1)
    raw = [r.estimate["armature"]["raw"]["L"] for r in first]
    raw_other = [r.estimate["armature"]["raw"]["L"] for r in other]
    assert raw != raw_other


def _same(a, b):
    drop = {"elapsed_ms"}
    return {k: v for k, v in a.items() if k not in drop} == {
        k: v for k, v in b.items() if k not in drop
    }


def test_constant_field_voltage_holds_field_inductance(p12_recording):
    """A steady field (constant vf, if settled) identifies Rf but not Lf: Lf must not move."""
    n = 6000
    rng = np.random.default_rng(5)
    rf = P12.field_resistance_ohm
    vf = 220.0 + 0.4 * rng.standard_normal(n)
    i_f = 220.0 / rf + 0.002 * rng.standard_normal(n)
    t_ns = np.arange(n) * 500_000
    block = SampleBlock(t_ns, {"vf": vf, "if": i_f})
    obs, results = _run([block], circuits="field")
    field = [r.estimate["field"] for r in results]
    assert field and all(f["quality"]["L"] in ("none", "held") for f in field)
    assert all(f["L"] is None for f in field)  # never identified, so never reported
    assert field[-1]["R"] == pytest.approx(rf, rel=0.01) and field[-1]["quality"]["R"] == "ok"
    assert field[-1]["rel_std"]["L"] > QualityConfig().L


def test_a_field_inductance_not_yet_identified_does_not_keep_the_swarm_cold():
    """Under a constant field voltage no window identifies Lf; once Rf is tracked the field
    swarm is warm-started from it and the last window's Lf (the small swarm), not run cold
    over the full range in every window."""
    n = 12000
    rng = np.random.default_rng(6)
    rf = P12.field_resistance_ohm
    vf = 220.0 + 0.4 * rng.standard_normal(n)
    i_f = 220.0 / rf + 0.002 * rng.standard_normal(n)
    block = SampleBlock(np.arange(n) * 500_000, {"vf": vf, "if": i_f})
    _, results = _run([block], circuits="field")
    field = [r.estimate["field"] for r in results]
    assert all(f["L"] is None for f in field)  # Lf never tracked
    warm = [f["warm"] for f in field]
    assert True in warm, "the field swarm never warm-started"
    first = warm.index(True)
    # Warm from the window after the first that tracked Rf, and from then on.
    assert field[first - 1]["quality"]["R"] == "ok" and all(warm[first:])
    cold = FAST["cold_particles"] * (FAST["cold_iterations"] + 1)
    assert all(f["evaluations"] < cold for f in field[first:])
    assert field[-1]["R"] == pytest.approx(rf, rel=0.01)


def test_held_parameter_is_carried_forward_by_the_tracker(p12_run):
    """A window that is no evidence for a parameter does not move it: inductances and
    K (random walks) keep their value exactly, resistances move by their tracked rate
    only; its uncertainty grows meanwhile. Every estimate keeps the window's own fit."""
    _, results = p12_run
    seen_held = False
    previous: dict = {}
    for r in results:
        for circuit in ("field", "armature"):
            c = r.estimate[circuit]
            assert set(c["raw"]) == set(c["quality"])
            for p, q in c["quality"].items():
                key = (circuit, p)
                if q == "held" and key in previous:
                    value, std, rate = previous[key]
                    if p == "R":
                        # The published rate is at the last hop's loss; the thermal models
                        # weighed beside the level relax at this hop's (10-20 ppm apart on
                        # the armature's duty cycle; a window's fit moves it far more).
                        hop_min = (r.t1_ns - previous[(circuit, "t")]) / 60e9
                        assert c[p] == pytest.approx(value * (1 + rate * hop_min), rel=1e-4)
                    else:
                        assert c[p] == value
                    assert c["std"][p] > std
                    seen_held = True
                if c[p] is not None:
                    previous[key] = (c[p], c["std"][p], (c.get("rate_per_min") or {}).get("R"))
            previous[(circuit, "t")] = r.t1_ns
    assert seen_held  # the duty cycle has windows with a constant field voltage


def test_tracked_state_temperatures_and_emf_speed_are_published(p12_run):
    """Each estimate: the tracked value with its std, the window's own fit beside it, the
    winding temperatures (the simulated motor is at 20 C) and the EMF speed next to the
    measured one; a clean recording raises no event."""
    _, results = p12_run
    last = results[-1].estimate
    for circuit in ("field", "armature"):
        c = last[circuit]
        for p in c["quality"]:
            assert c["std"][p] > 0 and c["raw"][p] is not None
            # The tracked std stays near the window's own: overlapping windows share samples.
            assert c["std"][p] / c[p] < 3 * c["rel_std"][p] or c["quality"][p] != "ok"
            # With the factor the windows' scatter calibrated their variances by.
            assert 0 < c["std_scale"][p] <= 100
        temp = last["temperature"][circuit]
        assert abs(temp["C"] - 20.0) < max(3.0, 3 * temp["std"]) and 0 < temp["std"] < 10
    speed = last["speed"]
    assert speed["tachometer"] == "ok"
    assert speed["emf_rad_s"] == pytest.approx(speed["measured_rad_s"], rel=0.02, abs=2.0)
    assert not any(r.events for r in results)
    assert not any(r.estimate["events"] for r in results)


def test_the_emf_speed_does_not_wait_for_a_tracked_la(p12_recording):
    """Some duty cycles go long without a window that pins La; its term in a window's mean
    EMF is small, so the window's own La fit stands in and the tachometer is checked as
    soon as Ra and K are tracked."""
    _, results = _run(_blocks(p12_recording), quality=QualityConfig(L=1e-9))  # La never ok
    estimates = [r.estimate for r in results if r.estimate is not None]
    assert all(e["armature"]["quality"]["L"] == "none" for e in estimates)
    known = [e for e in estimates if e["armature"]["K"] is not None and e["armature"]["R"]]
    assert len(known) > 10
    for e in known[1:]:  # the EMF speed is from the state before the window
        speed = e["speed"]
        assert speed["emf_rad_s"] is not None and speed["measured_rad_s"] is not None
        assert speed["emf_rad_s"] == pytest.approx(speed["measured_rad_s"], abs=2.0)


def test_a_tachometer_losing_a_tenth_of_its_reading_is_flagged_within_2_s():
    """The EMF speed from the tracked parameters disagrees with the measured one: an event,
    and K is not learnt from the faulty speed (it would rise 11 %), nor Ra and La, whose
    window fits use the same wrong speed (La's made the tracker announce a 2.8 % rise on a
    converter-fed P-12 once its windows were weighed by their calibrated variance)."""
    rec = simulate(P12, duration_s=12.0, seed=3, changes=(Change("tach", -0.10, 7.0),))
    _, results = _run(_blocks(rec), hop_s=0.25, speed=SpeedConfig(alarm_s=0.5))
    events = [e for r in results for e in r.events]
    faults = [e for e in events if e["kind"] == "tachometer" and e["state"] == "fault"]
    assert faults, events
    assert 7.0 < faults[0]["t_ns"] / 1e9 <= 9.0
    assert faults[0]["relative"] < -0.03 and "tachometer" in faults[0]["message"]
    assert not [e for e in events if e["kind"] == "change"], events
    last = results[-1].estimate
    assert last["speed"]["tachometer"] == "fault"
    assert last["armature"]["K"] == pytest.approx(P12.emf_constant_h, rel=0.01)
    after = [r.estimate for r in results if r.t1_ns > faults[0]["t_ns"]]
    assert after and all(
        e["armature"]["quality"][p] == "held" for e in after for p in ("R", "L", "K")
    )


def test_without_a_speed_channel_the_emf_speed_uses_configured_parameters(p12_recording):
    """No omega: the armature cannot be estimated (K and the speed are one product); the
    field is, and the EMF speed comes from the configured Ra, La, K, with a note saying so."""
    blocks = [
        SampleBlock(b.t_ns, {**b.signals, "omega": np.full(len(b), np.nan)})
        for b in _blocks(p12_recording)
    ]
    speed = SpeedConfig(
        Ra_ohm=P12.armature_resistance_ohm, La_h=P12.armature_inductance_h, K_h=P12.emf_constant_h
    )
    _, results = _run(blocks, speed=speed)
    last = results[-1].estimate
    assert "armature" not in last and last["field"]["R"] is not None
    assert last["speed"]["tachometer"] == "none" and last["speed"]["measured_rad_s"] is None
    assert "cannot be separated" in last["speed"]["note"]
    assert "configured" in last["speed"]["note"]
    n = int(round(1.0 / p12_recording.dt))
    window = slice(p12_recording.n_samples - n, p12_recording.n_samples)
    true_mean = float(np.mean(p12_recording["omega"][window]))
    assert last["speed"]["emf_rad_s"] == pytest.approx(true_mean, rel=0.03, abs=3.0)
    _, unset = _run(blocks[:30])
    assert unset[-1].estimate["speed"]["emf_rad_s"] is None
    assert "set [observer.speed] K_h" in unset[-1].estimate["speed"]["note"]


def test_check_window_reasons():
    from observer.service.ringbuffer import Window

    t = np.arange(100, dtype=np.int64) * 1000
    ok = {"va": np.sin(np.arange(100.0)), "vf": np.full(100, np.nan)}
    w = Window(t, ok, t, 0)
    assert check_window(w, 3.0)[0] == ""
    t_gap = t.copy()
    t_gap[50:] += 10_000
    assert check_window(Window(t_gap, ok, t, 0), 3.0)[0] == "gap"
    t_back = t.copy()
    t_back[50:] -= 60_000
    assert check_window(Window(t_back, ok, t, 0), 3.0)[0] == "time_jump"
    stuck = {"va": np.full(100, 2.0)}
    assert check_window(Window(t, stuck, t, 0), 3.0)[0] == "stuck:va"
    assert check_window(Window(t[:5], {"va": ok["va"][:5]}, t[:5], 0), 3.0)[0] == (
        "too_few_samples"
    )


def test_faults_skip_windows_flag_them_and_estimation_resumes(p12_recording):
    """NaN samples (dropped by the source -> a gap), a stuck channel, a forward time jump and
    a backward one: the windows that contain them are skipped with their reason, the rest
    are estimated as usual."""
    from drivers.base import Source, SourceClosed

    rec = p12_recording
    blocks = list(_blocks(rec, block_s=0.1))  # 120 blocks of 0.1 s

    class FaultySource(Source):
        name = "faulty"

        def __init__(self, blocks):
            super().__init__()
            self._blocks = blocks

        def _read_block(self, timeout):
            if not self._blocks:
                raise SourceClosed("end")
            return self._blocks.pop(0)

    def with_nan(b):
        ia = b.signals["ia"].copy()
        ia[10:30] = np.nan
        return SampleBlock(b.t_ns, {**b.signals, "ia": ia})

    def stuck(b):
        return SampleBlock(b.t_ns, {**b.signals, "va": np.full(len(b), 100.0)})

    faulty = []
    for i, b in enumerate(blocks):
        if i == 25:
            b = with_nan(b)
        if 45 <= i < 60:
            b = stuck(b)
        if i >= 80:  # the device clock jumps 1 h forward at 8 s
            b = SampleBlock(b.t_ns + 3600 * 10**9, b.signals)
        faulty.append(b)
    src = FaultySource(faulty)
    obs, results = _run(src)
    assert src.health()["bad_samples"] == 20
    reasons = [r.skip_reason for r in results if r.estimate is None]
    assert "gap" in reasons
    assert "stuck:va" in reasons
    counts = obs.health()["windows"]
    assert counts["skipped:gap"] >= 2 and counts["skipped:stuck"] >= 3
    # After the 1 h jump the schedule moved on instead of walking 7200 empty windows...
    assert len(results) < 60
    # ...and estimation resumed on the data after it.
    after = [r for r in results if r.t0_ns >= 3600 * 10**9]
    assert after and all(r.estimate is not None for r in after[1:])
    assert after[-1].estimate["armature"]["R"] == pytest.approx(3.5, rel=0.03)

    # A clock stepping back (1 h) restarts the schedule on the new time axis.
    back = [SampleBlock(b.t_ns + 3600 * 10**9, b.signals) for b in blocks[:60]]
    back += [SampleBlock(b.t_ns - 10**9, b.signals) for b in blocks[60:]]
    obs2, results2 = _run(back)
    assert obs2.health()["windows"].get("skipped:time_jump", 0) >= 1
    late = [r for r in results2 if r.t1_ns < 3600 * 10**9 and r.estimate is not None]
    assert late, "estimates resume on the stepped-back clock"


def test_window_shorter_than_a_few_field_time_constants_is_reported():
    from observer.estimation import kernels

    rng = np.random.default_rng(2)
    dt, n = 1e-3, 4000
    vf = np.where((np.arange(n) // 200) % 2 == 0, 220.0, 120.0)  # steps every 0.2 s
    i_f = kernels.simulate_rl(185.0, 55.0, 1.0, vf, dt) + 1e-4 * rng.standard_normal(n)
    vf = vf + 0.05 * rng.standard_normal(n)  # measured: never exactly repeated (else "stuck")
    block = SampleBlock(np.arange(n) * 1_000_000, {"vf": vf, "if": i_f})
    obs, results = _run([block], circuits="field", window_s=0.5, hop_s=0.25)
    fields = [r.estimate["field"] for r in results]
    assert fields[-1]["L"] == pytest.approx(55.0, rel=0.02)  # tau = 0.3 s
    assert "window_short_for_field" in obs.health()["warnings"]
    obs_ok, _ = _run([block], circuits="field", window_s=1.0, hop_s=0.5)
    assert "window_short_for_field" not in obs_ok.health()["warnings"]


def test_warm_up_compiles_every_kernel_signature_the_observer_runs():
    """On a cold numba cache a window must not wait for a compilation (live mode would skip
    windows): after the warm-up, running the observer compiles nothing more. In a fresh
    process, so that no other test has compiled a signature for it."""
    code = textwrap.dedent(
        """
        from observer.estimation import kernels
        from observer.service.window_observer import warm_up_kernels
        from tests.observer.service.test_window_observer import _blocks, _run

        def compiled():
            return {
                name: set(f.signatures)
                for name, f in vars(kernels).items() if hasattr(f, "signatures")
            }

        warm_up_kernels()
        before = compiled()
        from observer.estimation.motor import P12
        from observer.simulation.simulate import simulate

        rec = simulate(P12, duration_s=4.0, sample_rate_hz=2000.0, noise=0.002, seed=3)
        _, results = _run(_blocks(rec))
        assert sum(r.estimate is not None for r in results) >= 5, results
        after = compiled()
        added = {name: after[name] - before[name] for name in after if after[name] - before[name]}
        assert not added, f"compiled after the warm-up: {added}"
        """
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr[-3000:]


@pytest.mark.slow
def test_untold_channels_that_differ_are_learned_and_corrected_for():
    """RC voltage front ends beside 2nd-order Butterworth current ones (fs/4, 5 kHz), the
    chain not told: La reads 2.7 % small, the ripple current being 2.7 % large for its
    voltage. The first windows measure the mismatch (about the commonest pair's size), the
    decided chain corrects every later window's voltage for it, and La comes right, its
    std still covering the error."""
    from bench.accuracy_rates import drive_spec
    from observer.simulation.chain import MeasurementChain
    from observer.simulation.converter import REALISTIC_CHANNEL

    chain = MeasurementChain.uniform(REALISTIC_CHANNEL).with_channel("va", filter="rc", order=1)
    rec = simulate(
        P12, duration_s=6.0, sample_rate_hz=5000.0, seed=4,
        drive=drive_spec("thyristor").replace(chain=chain), drive_name="thyristor",
    )  # fmt: skip
    obs, results = _run(_blocks(rec), hop_s=0.25, chain_windows=6, circuits="armature")
    state = obs.health()["chain"]["armature"]
    assert state["model"] == "smooth"
    assert 0.6 < state["mismatch"] < 1.4
    after = [r.estimate["armature"] for r in results if r.estimate["armature"]["chain"]["decided"]]
    assert len(after) >= 6
    assert all(a["chain"]["mismatch_corrected"] == state["mismatch"] for a in after)
    truth = P12.armature_inductance_h
    errors = np.array([a["raw"]["L"] / truth - 1 for a in after])
    rel_std = np.array([a["rel_std"]["L"] for a in after])
    assert np.median(np.abs(errors)) < 0.01  # 2.7 % before the correction
    assert np.all(np.abs(errors) < 2.5 * rel_std)


@pytest.mark.slow
def test_an_untold_voltage_filter_is_identified_and_narrows_the_std(monkeypatch):
    """The realistic chain (2nd-order Butterworth at fs/4, 2 kHz) not told: once the chain is
    decided, the field voltage's filter is identified from the bridge's jumps, and the
    windows' Rf std carries its alias (a quarter of the RC's assumed before), still covering
    the error; with identification off, the std is the RC's. The armature's is identified
    too (filter_id.IDENTIFIED_WINDINGS)."""
    from observer.service import window_observer
    from observer.simulation.converter import PRESETS

    rec = simulate(
        P12, duration_s=8.0, sample_rate_hz=2000.0, seed=5, drive=PRESETS["realistic"],
        drive_name="realistic",
    )  # fmt: skip
    cfg = dict(hop_s=0.25, chain_windows=6)

    def decided_windows(results):
        return [r.estimate["field"] for r in results if r.estimate["field"]["chain"]["decided"]]

    obs, results = _run(_blocks(rec), **cfg)
    chain = obs.health()["chain"]
    fit = chain["field"]["voltage_filter"]
    assert fit["best"].startswith(("butter2", "bessel2")), fit
    assert 0.0141 < fit["alias"] < 0.0142 * 1.2
    assert chain["armature"]["voltage_filter"]["best"].startswith(("butter2", "bessel2"))
    after = decided_windows(results)
    truth = P12.field_resistance_ohm
    errors = np.array([a["raw"]["R"] / truth - 1 for a in after])
    rel_std = np.array([a["rel_std"]["R"] for a in after])
    assert len(after) >= 12
    assert np.mean(np.abs(errors) < 2.5 * rel_std) >= 0.95

    monkeypatch.setattr(window_observer, "FILTER_TRIES", 0)
    obs_rc, results_rc = _run(_blocks(rec), **cfg)
    assert obs_rc.health()["chain"]["field"]["voltage_filter"] is None
    rel_std_rc = np.array([a["rel_std"]["R"] for a in decided_windows(results_rc)])
    assert np.median(rel_std_rc) > 2.0 * np.median(rel_std)


@pytest.mark.slow
def test_the_filter_is_identified_beside_the_windows_and_used_from_a_fixed_window(monkeypatch):
    """The untold filter's identification (0.5 s of CPU a winding at 10 kHz) runs in a thread:
    the windows after the one it starts from are estimated while it runs (here it is held
    until they are), and its result is used from FILTER_DUE_S later however long it took, so
    a slow identification and a quick one give the same numbers (a replay, the live ones)."""
    import threading

    from observer.service import window_observer
    from observer.simulation.converter import PRESETS

    rec = simulate(
        P12, duration_s=8.0, sample_rate_hz=2000.0, seed=5, drive=PRESETS["realistic"],
        drive_name="realistic",
    )  # fmt: skip
    cfg = dict(hop_s=0.25, chain_windows=6, circuits="field")
    _, quick = _run(_blocks(rec), **cfg)

    identify = window_observer.identify_voltage_filter
    gate = threading.Event()
    held = []

    def held_identify(v, dt):
        assert gate.wait(120), "the observer never reached the window before the filter's"
        return identify(v, dt)

    monkeypatch.setattr(window_observer, "identify_voltage_filter", held_identify)
    obs = SlidingWindowObserver(RingBuffer(20_000), ObserverConfig(**{**FAST, **cfg}))
    slow = []
    for block in _blocks(rec):
        obs.ring.write(block)
        for r in obs.process_ready():
            slow.append(r)
            pending = obs._chain_state["field"].pending
            if pending is not None and r.index == pending[1] - 1:
                held.append(r.index)
                gate.set()  # every window before the filter's ran without it
    obs.close()
    assert held, "no identification was started"

    used = [r.estimate["field"]["chain"]["identified_filter"] for r in slow]
    start = next(i for i, r in enumerate(slow) if r.estimate["field"]["chain"]["decided"])
    due = held[0] + 1
    assert due - start == 6  # 1.5 s at a 0.25 s hop
    assert all(u is None for u in used[:due])
    assert all(u is not None and u.startswith(("butter2", "bessel2")) for u in used[due:])
    assert len(used) > due + 5

    assert [r.estimate["field"] for r in slow] == [r.estimate["field"] for r in quick]


def test_sensor_noise_is_not_learned_as_a_mismatch_of_the_channels(monkeypatch):
    """Channels filtered alike at 2 % sensor noise, the chain not told: the voltage's noise
    reads as the commonest mismatch of the channels (a correction for it took La ~6 % high
    at 2 kHz). The deciding window measures the size again with as much noise more on its
    voltage and takes off the growth: nothing is corrected for."""
    from bench.accuracy_rates import drive_spec
    from observer.estimation.frontend import MISMATCH_APPLIED
    from observer.service.window_observer import SlidingWindowObserver

    rec = simulate(
        P12, duration_s=6.0, sample_rate_hz=2000.0, noise=0.02, seed=0,
        drive=drive_spec("thyristor"), drive_name="thyristor",
    )  # fmt: skip
    obs, _ = _run(_blocks(rec), hop_s=0.25, chain_windows=6, circuits="armature")
    state = obs.health()["chain"]["armature"]
    assert state["model"] == "smooth"
    assert state["mismatch"] < MISMATCH_APPLIED
    # Without taking the noise's share off, the same windows would be corrected.
    monkeypatch.setattr(SlidingWindowObserver, "_noise_share", lambda self, prep, est: 0.0)
    fooled, _ = _run(_blocks(rec), hop_s=0.25, chain_windows=6, circuits="armature")
    assert fooled.health()["chain"]["armature"]["mismatch"] >= MISMATCH_APPLIED


@pytest.mark.slow
def test_a_voltage_reading_that_follows_a_curve_holds_the_armature():
    """The P-12 behind a chopper whose 4 kHz pulses the 4 kHz ADC samples in step (filters
    at fs/4, not configured): every sample meets the filter's ripple at one phase and reads
    the voltage through a curve. A measured voltage without mains ripple is held until the
    first seconds are tested (a window read as held, and the field beside it, too, where most
    of the armature's windows read it as measured); once they show the curve, the armature's
    windows and the field chopper's beside it say their model does not describe them, and
    nothing of them reaches the tracker. A chopper at 5 kHz (its pulses alias to a line) is
    published once tested."""
    from bench.accuracy_rates import drive_spec

    def run(fs, circuits):
        rec = simulate(
            P12, duration_s=13.0, sample_rate_hz=fs, seed=1, drive=drive_spec("chopper"),
            drive_name="chopper",
        )  # fmt: skip
        return _run(_blocks(rec), circuits=circuits)

    def windows(results, circuit, after):
        """The windows after the first test's result is in (11.5 s on), or before it."""
        return [
            r.estimate[circuit]
            for r in results
            if (r.t1_ns > 11.75e9 if after else r.t1_ns < 11.25e9)
        ]

    obs, results = run(4000.0, "both")
    verdict = obs.health()["voltage_linearity"]
    assert verdict is not None and verdict["linear"] is False and verdict["share"] > 0.9
    for circuit in ("armature", "field"):
        # (the first window has no armature windows before it to say its voltage is measured)
        untested, held = windows(results, circuit, False)[1:], windows(results, circuit, True)
        assert held and all(not a["describes_window"] for a in held)
        assert untested and all(
            not a["describes_window"] and "held until then" in a["note"] for a in untested
        )
    assert all("curve of the voltage" in a["note"] for a in windows(results, "armature", True))
    assert all("no mains ripple" in a["note"] for a in windows(results, "field", True))
    for a in windows(results, "armature", True):
        assert a["quality"]["R"] != "ok" and a["quality"]["L"] != "ok"
    obs, results = run(5000.0, "armature")
    assert obs.health()["voltage_linearity"]["linear"] is True
    assert all(a["describes_window"] for a in windows(results, "armature", True))
    before = windows(results, "armature", False)
    assert all(not a["describes_window"] for a in before if a["chain"]["intersample"] == "smooth")


@pytest.mark.slow
def test_an_in_step_chopper_read_as_held_is_still_held_until_tested():
    """The traction motor behind a 2.5 kHz chopper whose pulses the 5 kHz ADC samples in step,
    RC voltage filters beside Butterworth currents (not configured): the first window reads
    its voltage as measured, not described; later ones read it as held, as an in-step
    chopper's steady stretches do. Their values are a curve's (Ra 20 % and K 28 % low in the
    daemon), and no window may publish them before the linearity test has answered: the
    question of whether the voltage is measured counts every window before, not only the
    described ones (a majority of those published the second window's as ``ok``)."""
    import dataclasses

    from bench.window_honesty import _drive
    from observer.estimation.motor import TRACTION_60V

    drive = _drive("chopper-rc-voltages", 5000.0)
    drive = drive.replace(
        converter=dataclasses.replace(drive.converter, field="bridge-1p", switching_hz=2500.0)
    )
    rec = simulate(
        TRACTION_60V, duration_s=4.0, sample_rate_hz=5000.0, noise=0.002, seed=31, drive=drive,
        drive_name="chopper",
    )  # fmt: skip
    ring = RingBuffer(40_000)
    obs = SlidingWindowObserver(ring, ObserverConfig(buffer_s=4.0))
    results = []
    for b in _blocks(rec):
        ring.write(b)
        results += obs.process_ready()
    obs.close()
    armature = [r.estimate["armature"] for r in results if r.estimate is not None]
    assert len(armature) >= 25 and obs.health()["voltage_linearity"] is None  # not yet tested
    reads = [a["chain"]["intersample"] for a in armature]
    assert reads[0] == "smooth" and "hold" in reads[1:]  # the case: read held after the first
    assert not any(a["describes_window"] for a in armature)
    assert all(a["quality"][p] != "ok" for a in armature for p in ("R", "L", "K"))


@pytest.mark.slow
def test_pulses_folded_onto_the_reading_are_taken_out_of_the_windows(caplog):
    """The 440 V motor behind a chopper sampled at 10 kHz: its pulses' 5th harmonic folds onto
    the reading as a curve periodic in the voltage, too small to hold the armature for. Once
    the first test has fitted it, every window's armature voltage is read without it (and
    said so once in the log); the windows are described."""
    from bench.window_honesty import _drive
    from observer.estimation.motor import MOTORS
    from observer.simulation.converter_drive import simulate_converter

    rec, _ = simulate_converter(
        MOTORS["industrial-440v"], _drive("chopper", 10000.0), duration_s=12.5,
        sample_rate_hz=10000.0, noise=0.002, seed=0,
    )  # fmt: skip
    caplog.set_level("INFO", logger="observer")
    obs, results = _run(_blocks(rec), circuits="armature")
    verdict = obs.health()["voltage_linearity"]
    assert verdict is not None and verdict["linear"] is True
    assert verdict["fold"]["taken_out"] is True and verdict["fold"]["share"] > 0.8
    assert 150.0 < verdict["fold"]["period_v"] < 300.0  # 2 V_dc / 5
    lines = [r.getMessage() for r in caplog.records if "fold onto it" in r.getMessage()]
    assert len(lines) == 1 and "taken out of the samples" in lines[0]
    after = [r.estimate["armature"] for r in results if r.t1_ns > 11.75e9]
    assert after and all(a["describes_window"] for a in after)


@pytest.mark.parametrize("drive", ["thyristor", "chopper"])
@pytest.mark.slow
def test_a_change_of_the_motor_is_not_read_as_a_curve_of_the_voltage(drive):
    """A field fault (K -5 % at 15 s, after the first linearity test), the drive running
    on. Samples from both sides of it under one set of parameters leave an error that
    follows the operating point, and the linearity test read it as a curve of the voltage
    (0.6-0.8 % of the largest, 5-7 s after the step) and held every armature window for as
    long as the step stayed in the tested stretch. Behind a bridge the test does not run
    (its jumps and their fold are modelled); behind a chopper it starts again after the
    confirmed change. Either way the armature's windows go on describing the motor."""
    from bench.accuracy_rates import drive_spec

    rec = simulate(
        P12, duration_s=28.0, sample_rate_hz=5000.0, seed=1000, drive=drive_spec(drive),
        drive_name=drive, changes=(Change("K", -0.05, 15.0),),
    )  # fmt: skip
    obs, results = _run(_blocks(rec), circuits="armature")
    events = [e for r in results for e in r.events if e.get("kind") == "change"]
    assert [e["parameter"] for e in events] == ["K"]
    after = [r.estimate["armature"] for r in results if r.t1_ns > events[0]["t_ns"] + 1e9]
    assert after and all(a["describes_window"] for a in after), [
        a.get("note") for a in after if not a["describes_window"]
    ][:1]
    verdict = obs.health()["voltage_linearity"]
    assert verdict is None if drive == "thyristor" else verdict["linear"]
    if drive == "thyristor":
        # A bridge's voltage is never held for the test, not even in a window without ripple.
        notes = [r.estimate["armature"].get("note") or "" for r in results]
        assert not [n for n in notes if "held until then" in n]
