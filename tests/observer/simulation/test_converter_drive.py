"""The converter-fed drive: bridge voltages, ripple, discontinuous conduction, changeover, the
measurement chain's filters, sampling, averaging and ADC, and seamless chunking."""

from __future__ import annotations

import hashlib
import math
import time

import numpy as np
import pytest

from observer.estimation.motor import INDUSTRIAL_440V, P12, TRACTION_60V, MotorParameters
from observer.recording import read_recording, write_recording
from observer.simulation import converter_kernels as ck
from observer.simulation.chain import ChannelChain, MeasurementChain, filter_sections
from observer.simulation.converter import PRESETS, ConverterSpec, DriveSpec
from observer.simulation.converter_drive import ConverterDrive, simulate_converter
from observer.simulation.simulate import simulate

BARE = MeasurementChain()  # no filter, no ADC


def _drive(armature: str, field: str, chain: MeasurementChain = BARE, **kw) -> DriveSpec:
    return DriveSpec(ConverterSpec(armature=armature, field=field, **kw), chain)


# ------------------------------------------------------------------ converters, open loop


def _open_loop_armature(
    v_target: float,
    mains_hz: float,
    seconds: float = 0.3,
    source_inductance_h: float = 0.0,
    la: float = 0.5,
):
    """A 6-pulse bridge held at the firing angle of mean voltage ``v_target``, feeding a
    large-inductance motor at constant speed (continuous conduction)."""
    fs = 60_000.0
    dt = 1 / fs
    v_ll = 400.0
    amp = math.sqrt(2) * v_ll
    ra, k, i_f, ia = 1.0, 1.0, 1.0, 5.0
    # start at the steady state: the overlap takes 3*omega*Lc*Id/pi off the mean voltage
    emf = v_target - ra * ia - 3 * 2 * math.pi * mains_hz * source_inductance_h * ia / math.pi
    omega = emf / (k * i_f)
    motor = np.array([100.0, 10.0, ra, la, k, 1e12, 0.0])
    fx = np.zeros(13)
    fx[2], fx[4], fx[7], fx[11], fx[12] = 20.0, 1.0, 0.01, 1.0, 1.0
    arm = np.array([ck.ARM_THYRISTOR_6P, amp, 2 * math.pi * mains_hz, 0.7, source_inductance_h,
                    math.radians(5), math.radians(150), 0.002, 0.1])  # fmt: skip
    fld = np.array([ck.FLD_IDEAL, 0, 0, 0, 0, 0, 0.0])
    # no feedback: the back-EMF feed-forward alone sets v_ref = v_target
    ctrl = np.array([0.0, 0.0, 0.0, 0.0, 100.0, 1e4, 0.0, v_target / (i_f * omega)])
    filt = np.zeros((5, 2, 3))
    state = ck.initial_state(motor, fx, arm, fld, filt, dt, i_f, ia, omega)
    n = int(seconds * fs)
    _, truth = ck.advance(
        state, n, 5e-6, motor, fx, arm, fld, ctrl, filt, np.zeros(5), np.zeros(5),
        np.zeros(3), 1, np.zeros(n), np.zeros(n), np.full(n, 100.0), np.zeros((0, 6)), True,
    )  # fmt: skip
    return truth, fs, 3 * amp / math.pi


@pytest.mark.parametrize(
    ("v_target", "mains_hz"), [(400.0, 50.0), (150.0, 50.0), (-250.0, 50.0), (300.0, 60.0)]
)
def test_six_pulse_bridge_mean_voltage_is_1_35_vll_cos_alpha(v_target, mains_hz):
    truth, fs, vd0 = _open_loop_armature(v_target, mains_hz)
    alpha = math.acos(v_target / vd0)
    assert vd0 == pytest.approx(1.35 * 400.0, rel=1e-3)
    per = int(round(fs / mains_hz))
    va = truth[per : per * 11, ck.T_VA_MEAN]  # ten whole mains periods after the first
    assert np.all(truth[per:, ck.T_CONDUCTING] == 1)  # continuous conduction
    assert va.mean() == pytest.approx(3 * math.sqrt(2) / math.pi * 400.0 * math.cos(alpha),
                                      abs=1e-4 * vd0)  # fmt: skip
    # the ripple is at 6x mains, and the terminal voltage jumps at each firing
    spectrum = np.abs(np.fft.rfft(va - va.mean()))
    f = np.fft.rfftfreq(va.size, 1 / fs)
    assert f[np.argmax(spectrum)] == pytest.approx(6 * mains_hz)
    assert np.max(np.abs(np.diff(truth[per:, ck.T_VA]))) > 0.1 * vd0 * math.sin(alpha) - 1


@pytest.mark.parametrize(("field", "ripple_x"), [("bridge-1p", 2), ("half-3p", 3)])
def test_field_bridges_mean_voltage_and_ripple(field, ripple_x):
    fs = 50_000.0
    motor = MotorParameters(**(P12.to_dict() | {"field_inductance_h": 500.0}))
    sim = ConverterDrive(
        motor, _drive("ideal", field), sample_rate_hz=fs, noise=0.0,
        rng=np.random.default_rng(1), initial=(1.0, 0.0, 0.0),
    )  # fmt: skip
    n = int(0.4 * fs)
    per = int(fs / 50)
    for vf_ref in (200.0, 60.0):
        _, _, truth = sim.advance(np.zeros(n), np.zeros(n), np.full(n, vf_ref), want_truth=True)
        assert truth is not None
        vf = truth.vf_mean[per : per * 16]
        supply = sim.setup.metadata["field"]
        if field == "bridge-1p":
            alpha = math.acos(vf_ref / (0.9 * supply["supply_v"]))
            expected = 0.9 * supply["supply_v"] * math.cos(alpha)
            assert truth.vf.min() < 0  # negative segments after each zero crossing
        else:
            alpha = math.acos(2 * vf_ref / (1.35 * supply["line_voltage_v"]) - 1)
            expected = 1.35 * supply["line_voltage_v"] * (1 + math.cos(alpha)) / 2
            assert truth.vf.min() >= 0  # the freewheeling diode clamps at zero
        assert vf.mean() == pytest.approx(expected, rel=1e-3)
        assert vf.mean() == pytest.approx(vf_ref, rel=1e-3)
        spectrum = np.abs(np.fft.rfft(vf - vf.mean()))
        f = np.fft.rfftfreq(vf.size, 1 / fs)
        assert f[np.argmax(spectrum)] == pytest.approx(ripple_x * 50.0)


def test_chopper_pulses_at_twice_the_carrier_with_the_commanded_mean():
    fs = 100_000.0
    sim = ConverterDrive(
        P12, _drive("chopper", "chopper", switching_hz=1500.0), sample_rate_hz=fs, noise=0.0,
        rng=np.random.default_rng(2), initial=(P12.rated_field_current_a, 0.0, 0.0),
    )  # fmt: skip
    n = int(0.2 * fs)
    _, _, truth = sim.advance(np.zeros(n), np.zeros(n), np.full(n, 150.0), want_truth=True)
    assert truth is not None
    vdc = sim.setup.metadata["field"]["dc_link_v"]
    levels = np.unique(np.round(truth.vf, 6))
    assert set(levels) <= {-vdc, 0.0, vdc}
    per = 200  # whole carrier periods: 3 of 1500 Hz are 200 samples
    vf = truth.vf_mean[: (n // per) * per]
    assert vf.mean() == pytest.approx(150.0, rel=1e-3)
    spectrum = np.abs(np.fft.rfft(vf - vf.mean()))
    f = np.fft.rfftfreq(vf.size, 1 / fs)
    assert f[np.argmax(spectrum)] == pytest.approx(3000.0)


# ------------------------------------------------------------------ the closed-loop drive


@pytest.fixture(scope="module")
def thyristor_run():
    """12 s of the P-12 on the dual bridge, recorded at 20 kHz without filter, ADC or noise."""
    rec, truth = simulate_converter(
        P12, _drive("thyristor-6p", "bridge-1p"), duration_s=12.0, sample_rate_hz=20_000.0,
        noise=0.0, seed=4, want_truth=True,
    )  # fmt: skip
    return rec, truth


@pytest.mark.slow
def test_discontinuous_conduction_at_light_load_shows_the_back_emf(thyristor_run):
    rec, truth = thyristor_run
    blocked = truth.conducting == 0
    assert 0.01 < blocked.mean() < 0.5
    # while the bridge blocks, the current is zero and the terminals show K*if*omega
    assert np.all(rec["ia"][blocked] == 0.0)
    emf = P12.emf_constant_h * rec["if"] * rec["omega"]
    np.testing.assert_allclose(rec["va"][blocked], emf[blocked], rtol=1e-9, atol=1e-9)
    # it happens at light load: the current averaged over 10 ms
    load = np.convolve(np.abs(truth.ia), np.ones(200) / 200, mode="same")
    light = load < 0.3 * P12.rated_armature_current_a
    heavy = load > 1.0 * P12.rated_armature_current_a
    assert blocked[light].mean() > 0.3
    assert blocked[heavy].mean() < 0.01


def test_bridge_changeover_only_at_zero_current_after_the_dead_time(thyristor_run):
    rec, truth = thyristor_run
    fs = rec.sample_rate_hz
    changes = np.flatnonzero(np.diff(truth.bridge) != 0) + 1
    assert changes.size >= 4
    assert set(truth.bridge[changes]) == {-1.0, 1.0}
    before = int(0.002 * fs)  # the dead time, in samples
    for k in changes:
        window = slice(k - before + 1, k)
        assert np.all(truth.ia[window] == 0.0), f"current flowed within the dead time at {k}"
        assert np.all(truth.conducting[window] == 0)
    # and the current changes sign only through such a changeover
    signs = np.sign(truth.ia[truth.ia != 0])
    flips = np.count_nonzero(np.diff(signs))
    assert flips <= changes.size


def test_commutation_overlap_lowers_the_mean_by_3_omega_lc_id_over_pi():
    lc = 3e-3
    # the textbook drop assumes a ripple-free current: a large inductance
    truth, fs, vd0 = _open_loop_armature(300.0, 50.0, source_inductance_h=lc, la=50.0)
    per = int(round(fs / 50.0))
    va = truth[per * 5 : per * 15, ck.T_VA_MEAN]
    i_d = truth[per * 5 : per * 15, ck.T_IA].mean()
    alpha = math.acos(300.0 / vd0)
    drop = 3 * (2 * math.pi * 50.0) * lc * i_d / math.pi
    assert drop > 0.005 * vd0
    assert va.mean() == pytest.approx(vd0 * math.cos(alpha) - drop, abs=2e-4 * vd0)


# ------------------------------------------------------------------ the measurement chain


@pytest.mark.parametrize(("kind", "order"), [("butter", 2), ("butter", 3), ("bessel", 4),
                                             ("rc", 1), ("rc", 4)])  # fmt: skip
def test_filter_step_response_matches_the_analog_filter(kind, order):
    signal = pytest.importorskip("scipy.signal")
    fs = 4000.0
    chain = MeasurementChain().with_channel("vf", filter=kind, order=order, cutoff_hz=500.0)
    sim = ConverterDrive(
        P12, _drive("ideal", "ideal", chain), sample_rate_hz=fs, noise=0.0,
        rng=np.random.default_rng(0), initial=(1.0, 0.0, 0.0),
    )  # fmt: skip
    n = 200
    vf_ref = np.where(np.arange(n) < 40, 0.0, 200.0)  # a step at sample 40
    recorded, _, _ = sim.advance(np.zeros(n), np.zeros(n), vf_ref)
    num, den = np.array([1.0]), np.array([1.0])
    for sec_kind, w0, q in filter_sections(kind, order, 500.0):
        if sec_kind == 1:
            num, den = num * w0, np.polymul(den, [1.0, w0])
        elif sec_kind == 2:
            num, den = num * w0 * w0, np.polymul(den, [1.0, w0 / q, w0 * w0])
    # the field voltage is held from each sample to the next: a zero-order hold
    _, expected, _ = signal.lsim((num, den), vf_ref, np.arange(n) / fs, interp=False)
    np.testing.assert_allclose(recorded[:, 2], expected, atol=2e-5 * 200.0)
    # the held value reaches the output only through the filter: nothing yet at the step
    assert abs(recorded[40, 2]) < 1e-9 and recorded[41, 2] < 150.0


def test_averaging_channel_is_the_mean_over_the_period_ending_at_the_sample():
    chain = MeasurementChain().with_channel("va", averaging=True)
    rec, truth = simulate_converter(
        P12, _drive("thyristor-6p", "bridge-1p", chain), duration_s=1.0, sample_rate_hz=2000.0,
        noise=0.0, seed=3, want_truth=True,
    )  # fmt: skip
    np.testing.assert_allclose(rec["va"][1:], truth.va_mean[:-1], rtol=1e-9, atol=1e-9)
    assert rec["va"][0] == truth.va[0]  # the stream's first sample has no period behind it
    assert rec.metadata["chain"]["va"]["averaging"] is True


def test_sampling_delay_reads_the_signal_later():
    fs = 10_000.0
    d = 0.3 / fs
    chain = MeasurementChain().with_channel("ia", delay_s=d)
    rec, truth = simulate_converter(
        P12, _drive("ideal", "ideal", chain), duration_s=2.0, sample_rate_hz=fs, noise=0.0,
        seed=5, want_truth=True,
    )  # fmt: skip
    ia = truth.ia
    lerp = ia[:-1] + 0.3 * (ia[1:] - ia[:-1])
    delayed = rec["ia"][:-1]
    step = np.sqrt(np.mean(np.diff(ia) ** 2))
    assert np.sqrt(np.mean((delayed - ia[:-1]) ** 2)) > 0.25 * step
    assert np.sqrt(np.mean((delayed - lerp) ** 2)) < 0.02 * step
    assert rec.metadata["chain"]["ia"]["delay_s"] == d


def test_adc_metadata_makes_counts_exact(tmp_path):
    chain = MeasurementChain.uniform(ChannelChain(bits=12)).with_channel(
        "ia", bits=10, full_scale=4.0
    )
    rec = simulate(P12, duration_s=2.0, drive=_drive("thyristor-6p", "bridge-1p", chain), seed=1)
    path = tmp_path / "r.mcap"
    write_recording(rec, path)
    back = read_recording(path)
    for name, adc in back.metadata["adc"].items():
        x = back[name]
        counts = np.rint((x - adc["offset"]) / adc["lsb"])
        np.testing.assert_array_equal(adc["offset"] + adc["lsb"] * counts, x)
        half = 2 ** (adc["bits"] - 1)
        assert -half <= counts.min() and counts.max() <= half - 1
    assert back.metadata["adc"]["ia"] == {"lsb": 8.0 / 2**10, "offset": 0.0, "bits": 10}
    # 4 A full scale clips the P-12's 6 A current limit: the ADC saturates
    assert back["ia"].max() == pytest.approx((2**9 - 1) * 8.0 / 2**10)


def test_gain_error_offset_and_noise_act_on_the_recorded_values():
    chain = MeasurementChain().with_channel("ia", gain_error=0.02, offset=0.1)
    kw = {"duration_s": 1.0, "sample_rate_hz": 2000.0, "seed": 8, "want_truth": True}
    plain, _ = simulate_converter(P12, _drive("chopper", "ideal"), noise=0.0, **kw)
    sensed, _ = simulate_converter(P12, _drive("chopper", "ideal", chain), noise=0.0, **kw)
    np.testing.assert_allclose(sensed["ia"], 1.02 * plain["ia"] + 0.1, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(sensed["va"], plain["va"])
    noisy, _ = simulate_converter(
        P12, _drive("chopper", "ideal", chain.with_channel("omega", noise=0.01)), noise=0.0, **kw
    )
    err = noisy["omega"] - plain["omega"]
    assert np.std(err) == pytest.approx(0.01 * P12.rated_speed_rad_s, rel=0.1)
    assert noisy.metadata["noise"]["omega"] == pytest.approx(0.01 * P12.rated_speed_rad_s)


# ------------------------------------------------------------------ continuity, identity, speed


@pytest.mark.parametrize(
    ("armature", "field"),
    [("thyristor-6p", "bridge-1p"), ("chopper", "chopper"), ("ideal", "half-3p")],
)
def test_chunked_drive_equals_one_long_run(armature, field):
    chain = (
        MeasurementChain.uniform(ChannelChain("butter", 2, cutoff_per_fs=0.25, bits=12))
        .with_channel("va", averaging=True, filter="rc", order=1, cutoff_per_fs=0.1)
        .with_channel("ia", delay_s=3e-5)
    )
    drive = _drive(armature, field, chain, source_inductance_h=1e-4)
    fs, n = 5000.0, 5000
    rng = np.random.default_rng(9)
    speed = np.repeat(rng.uniform(-1, 1, 10), n // 10) * P12.rated_speed_rad_s
    load = np.repeat(rng.uniform(-1, 1, 10), n // 10) * P12.rated_torque_nm
    field_v = np.repeat(rng.uniform(0.7, 1.3, 10), n // 10) * P12.rated_field_voltage_v

    def make():
        return ConverterDrive(P12, drive, sample_rate_hz=fs, noise=0.002,
                              rng=np.random.default_rng(1))  # fmt: skip

    steps = np.ones((n, 6))
    steps[1200:, 2] = 1.05  # Ra +5 % from sample 1200
    steps[3000:, 5] = 0.9  # the tachometer reads 10 % low from sample 3000
    whole = make()
    _, analog, truth = whole.advance(speed, load, field_v, schedule=steps, want_truth=True)
    parts = make()
    pieces, truths = [], []
    for a, b in [(0, 1), (1, 777), (777, 2500), (2500, 2501), (2501, n)]:
        _, piece, t = parts.advance(
            speed[a:b], load[a:b], field_v[a:b], schedule=steps[a:b], want_truth=True
        )
        pieces.append(piece)
        truths.append(t)
    np.testing.assert_array_equal(np.concatenate(pieces), analog)
    assert truth is not None
    np.testing.assert_array_equal(np.concatenate([t.ia for t in truths]), truth.ia)
    np.testing.assert_array_equal(np.concatenate([t.va_mean for t in truths]), truth.va_mean)
    np.testing.assert_array_equal(parts.state, whole.state)
    # the truth is a by-product: asking for it changes nothing
    _, again, _ = make().advance(speed, load, field_v, schedule=steps)
    np.testing.assert_array_equal(again, analog)


def _digest(rec) -> str:
    h = hashlib.sha256()
    for c in rec.channels:
        h.update(np.ascontiguousarray(rec[c]).tobytes())
    return h.hexdigest()[:16]


def test_the_ideal_simulator_is_bit_identical_to_before():
    # digests of these recordings made before the converter drive existed (main at ff497c2)
    assert _digest(simulate(P12, duration_s=2.0, seed=5)) == "4b344cc697f1099f"
    rec = simulate(TRACTION_60V, duration_s=1.0, sample_rate_hz=10000, noise=0.01, seed=1)
    assert _digest(rec) == "4c89d80c633427b9"
    fx = {"brush_drop": 1.0, "sensor_offset": 0.01, "sampling_skew": 0.5, "eddy_currents": 0.2}
    assert _digest(simulate(P12, duration_s=2.0, seed=6, effects=fx)) == "fb77771e53fca613"
    assert "converter" not in simulate(P12, duration_s=0.5).metadata


def test_same_seed_same_duty_cycle_whatever_the_drive():
    ideal = simulate(P12, duration_s=3.0, seed=11, noise=0.0)
    real = simulate(P12, duration_s=3.0, seed=11, noise=0.0, drive=PRESETS["realistic"],
                    drive_name="realistic")  # fmt: skip
    assert real.metadata["drive"] == "realistic"
    # the same speed profile: the speeds agree to a few percent of rated
    err = np.abs(real["omega"] - ideal["omega"])
    assert np.median(err) < 0.05 * P12.rated_speed_rad_s


def test_second_test_motor_runs_on_the_realistic_drive():
    rec = simulate(INDUSTRIAL_440V, duration_s=2.0, sample_rate_hz=5000.0,
                   drive=PRESETS["realistic"], seed=2)  # fmt: skip
    assert rec.metadata["motor"]["armature_inductance_h"] == 0.06
    assert np.abs(rec["ia"]).max() > INDUSTRIAL_440V.rated_armature_current_a
    assert rec.metadata["converter"]["armature"]["line_voltage_v"] > 380


def test_realistic_drive_is_faster_than_real_time_at_10_khz():
    simulate(P12, duration_s=0.05, sample_rate_hz=10_000.0, drive=PRESETS["realistic"])
    start = time.perf_counter()
    simulate(P12, duration_s=4.0, sample_rate_hz=10_000.0, drive=PRESETS["realistic"], seed=3)
    assert time.perf_counter() - start < 4.0


def test_changes_and_heating_on_a_converter_drive():
    from observer.simulation.effects_sim import Change
    from observer.simulation.simulate import true_parameters

    changes = (Change("tach", -0.1, 1.0), Change("Ra", 0.05, 0.5))
    rec, truth = simulate_converter(
        P12, _drive("thyristor-6p", "bridge-1p"), duration_s=2.0, sample_rate_hz=2000.0,
        noise=0.0, seed=1, changes=changes, effects={"thermal_drift": 0.3},
        thermal_time_constant_s=5.0, want_truth=True,
    )  # fmt: skip
    assert truth is not None
    k = 2000  # t = 1 s
    np.testing.assert_allclose(rec["omega"][:k], truth.omega[:k], rtol=1e-12)
    np.testing.assert_allclose(rec["omega"][k:], 0.9 * truth.omega[k:], rtol=1e-12)
    assert [c["target"] for c in rec.metadata["changes"]] == ["tach", "Ra"]
    true = true_parameters(rec.metadata, np.array([0.2, 1.5]))
    assert true["Ra"][1] > 1.05 * P12.armature_resistance_ohm > true["Ra"][0]
    assert rec.metadata["thermal"]["theta"][-1] == pytest.approx(truth.theta[-200], rel=0.05)


def test_a_converter_fed_winding_heats_by_the_loss_at_its_hot_resistance():
    rec, truth = simulate_converter(
        P12, _drive("ideal", "ideal"), duration_s=3.0, sample_rate_hz=10_000.0, noise=0.0,
        seed=2, effects={"thermal_drift": 0.3}, thermal_time_constant_s=2.0, want_truth=True,
    )  # fmt: skip
    assert truth is not None
    k = rec.metadata["effects"]["physical"]["thermal_rise_per_w"]
    cold = P12.armature_resistance_ohm * truth.ia**2 + P12.field_resistance_ohm * truth.i_f**2
    theta = np.zeros(cold.size)
    for n in range(1, cold.size):
        loss = 0.5 * (cold[n - 1] + cold[n]) * (1.0 + theta[n - 1])
        theta[n] = theta[n - 1] + rec.dt * (k * loss - theta[n - 1]) / 2.0
    assert truth.theta[-1] > 0.02
    np.testing.assert_allclose(truth.theta[1000:], theta[1000:], rtol=2e-3)
