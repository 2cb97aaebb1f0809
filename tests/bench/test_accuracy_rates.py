"""bench/accuracy_rates.py without its minutes: the drives it simulates and its table."""

from __future__ import annotations

import pytest

from bench.accuracy_rates import PARAMETERS, drive_spec, front_end_drive, jobs, main, table


def _row(rate: float, drive: str, seed: int, error: float, describes: bool) -> dict:
    row = {"motor": "p12", "rate": rate, "drive": drive, "seed": seed,
           "field_describes": describes, "armature_describes": True}  # fmt: skip
    for name in PARAMETERS:
        row[name] = {"error_pct": error * (1 if seed else -1), "z": 2.0 * error}
    return row


def test_the_drives_are_the_realistic_chain_behind_each_converter():
    thyristor, chopper = drive_spec("thyristor"), drive_spec("chopper")
    converters = (thyristor.converter.armature, thyristor.converter.field)
    assert converters == ("thyristor-6p", "bridge-1p")
    assert (chopper.converter.armature, chopper.converter.field) == ("chopper", "chopper")
    for _, ch in chopper.chain.items():
        assert (ch.filter_text(), ch.bits) == ("butter2@fs/4", 12)
    config = chopper.chain.to_config()
    assert config.ia.filter == "butter2@fs/4" and not config.va.averaging


def test_the_table_has_a_row_per_rate_drive_and_parameter():
    rows = [_row(2000.0, "chopper", s, e, s != 1) for s, e in enumerate((1.0, 3.0, 2.0))]
    rows.append(_row(5000.0, "thyristor", 0, 0.5, True))
    lines = table(rows).splitlines()
    assert len(lines) == 2 + 2 * len(PARAMETERS)
    cells = [c.strip() for c in lines[2].strip("|").split("|")]
    assert cells == [
        "p12",
        "butter2",
        "2 kHz",
        "chopper",
        "Rf",
        "3",
        "2.00 %",
        "3.00 %",
        "4.00",
        "1",
    ]
    assert lines[-1].startswith("| p12 | butter2 | 5 kHz | thyristor | K | 1 | 0.50 %")
    # another carrier is its own row (a row without one has the default)
    other = [dict(r, carrier_hz=1500.0) for r in rows[:1]]
    assert "| chopper 1.5 kHz carrier | Rf |" in table(rows[:1] + other)
    assert len(table(rows[:1] + other).splitlines()) == 2 + 2 * len(PARAMETERS)


@pytest.mark.slow
def test_a_carrier_reaches_the_simulated_chopper():
    """A case's carrier is the simulated chopper's (read back from the recording)."""
    from bench.accuracy_rates import carrier_of, run_case

    job = {"motor": "p12", "rate": 2000.0, "drive": "chopper", "front_end": "butter2-untold",
           "seed": 0, "duration": 3.0, "noise": 0.002, "carrier_hz": 3000.0}  # fmt: skip
    row = run_case(job)
    assert row["carrier_hz"] == 3000.0
    assert carrier_of({"drive": "chopper"}) == drive_spec("chopper").converter.switching_hz
    assert carrier_of({"drive": "thyristor"}) is None


def test_front_ends_put_their_filters_on_the_channels():
    mixed = front_end_drive(drive_spec("thyristor"), "mixed")
    filters = {name: ch.filter_text() for name, ch in mixed.chain.items()}
    assert filters == {"va": "rc1@fs/4", "vf": "rc1@fs/4", "ia": "butter2@fs/4",
                       "if": "butter2@fs/4", "omega": "butter2@fs/4"}  # fmt: skip
    bare = front_end_drive(drive_spec("chopper"), "none")
    assert {ch.filter_text() for _, ch in bare.chain.items()} == {"none"}
    assert bare.converter == drive_spec("chopper").converter


def test_jobs_and_bad_arguments(capsys):
    import argparse

    args = argparse.Namespace(motors=["p12"], front_ends=["butter2", "none"], rates=[2e3, 5e3],
                              drives=["chopper", "thyristor"], seeds=3, duration=30.0,
                              noise=0.002, carriers=[2e3, 1.5e3])  # fmt: skip
    todo = jobs(args)
    # the chopper once per carrier, the thyristor drive once
    assert len(todo) == 12 * 3
    assert {j.get("carrier_hz") for j in todo if j["drive"] == "chopper"} == {2e3, 1.5e3}
    assert all("carrier_hz" not in j for j in todo if j["drive"] == "thyristor")
    for bad in (["--front-ends", "fancy"], ["--motors", "p13"]):
        with pytest.raises(SystemExit) as exc:
            main([*bad, "--no-progress"])
        assert exc.value.code == 2
    with pytest.raises(SystemExit) as exc:
        main(["--drives", "magic", "--no-progress"])
    assert exc.value.code == 2
    assert "--drives" in capsys.readouterr().err


def test_variants_change_the_drive_beyond_the_front_end():
    """Each variant changes what it names, on top of the front end; rows carry it and the
    table gives it its own row; an unknown one is a usage error."""
    import argparse

    from bench.accuracy_rates import VARIANTS

    base = front_end_drive(drive_spec("thyristor"), "butter2-untold")
    changed = {name: change(base, 5000.0) for name, (_, change) in VARIANTS.items()}
    assert changed["standard"] == base
    assert changed["60hz"].converter.mains_hz == 60.0
    assert changed["overlap"].converter.source_inductance_h > 0
    filters = {name: ch.filter_text() for name, ch in changed["butter4-v"].chain.items()}
    assert filters["va"] == filters["vf"] == "butter4@fs/3" and filters["ia"] == "butter2@fs/4"
    assert {ch.filter_text() for _, ch in changed["bessel4"].chain.items()} == {"bessel4@fs/5"}
    delays = {name: ch.delay_s for name, ch in changed["skew"].chain.items()}
    assert delays["va"] == delays["vf"] == 0.0
    assert delays["ia"] < delays["if"] < delays["omega"] < 1 / 5000.0
    assert {ch.bits for _, ch in changed["16bit"].chain.items()} == {16}
    assert {ch.bits for _, ch in base.chain.items()} == {12}

    args = argparse.Namespace(motors=["p12"], front_ends=["butter2-untold"], rates=[2e3],
                              drives=["thyristor"], seeds=2, duration=30.0, noise=0.002,
                              carriers=[2e3], variants=["standard", "skew"])  # fmt: skip
    todo = jobs(args)
    assert [j.get("variant") for j in todo] == [None, None, "skew", "skew"]
    rows = [_row(2000.0, "thyristor", 0, 1.0, True), {**_row(2000.0, "thyristor", 0, 1.0, True),
                                                       "variant": "skew"}]  # fmt: skip
    assert "| thyristor, skew | Rf |" in table(rows)
    with pytest.raises(SystemExit) as exc:
        main(["--variants", "warp", "--no-progress"])
    assert exc.value.code == 2
